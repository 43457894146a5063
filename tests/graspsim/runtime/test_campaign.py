"""Resumable campaigns (graspsim.runtime.campaign) with items that are not trials: the
plumbing knows nothing of what it runs."""

from __future__ import annotations

import json

import pytest

from dlsr.records import CorruptFileError
from graspsim.runtime.campaign import (
    make_executor,
    open_campaign,
    read_done,
    run_campaign,
    run_missing,
)

CALLS: list[int] = []


def _square(index: int, offset: int) -> dict:
    CALLS.append(index)
    return {"index": index, "value": index * index + offset}


def _summary(records):
    return {"total": sum(r["value"] for r in records), "n": len(records)}


def _markdown(summary):
    return f"# {summary['n']} items\n"


def _run(out, n, offset=0, **kw):
    return run_campaign(_square, "items", {"offset": offset}, out, n, lambda i: (i, offset),
                        _summary, _markdown, **kw)


def test_a_campaign_runs_only_the_missing_items_and_resumes(tmp_path):
    CALLS.clear()
    first = _run(tmp_path, 3)
    assert CALLS == [0, 1, 2] and first["total"] == 0 + 1 + 4
    assert [r["index"] for r in first["records"]] == [0, 1, 2]
    assert json.loads((tmp_path / "config.json").read_text()) == {"offset": 0}
    assert (tmp_path / "summary.md").read_text() == "# 3 items\n"
    CALLS.clear()
    second = _run(tmp_path, 5)
    assert CALLS == [3, 4]  # nothing repeated, nothing lost
    assert second["total"] == sum(i * i for i in range(5))
    assert second["items_per_second"] is not None
    CALLS.clear()
    again = _run(tmp_path, 5)
    assert CALLS == [] and again["items_per_second"] is None
    assert json.loads((tmp_path / "summary.json").read_text())["total"] == second["total"]


def test_another_configuration_is_refused_unless_upgrade_says_it_is_the_same(tmp_path):
    _run(tmp_path, 2)
    with pytest.raises(ValueError, match="another configuration"):
        _run(tmp_path, 2, offset=1)

    def upgrade(old, meta, path):
        assert path == tmp_path / "config.json"
        return {**old, "offset": meta["offset"]}  # a field whose old value means the new one

    out = _run(tmp_path, 3, offset=1, upgrade=upgrade)
    assert [r["value"] for r in out["records"]] == [0, 1, 5]  # old records kept


def test_a_torn_last_line_is_dropped_and_that_item_runs_again(tmp_path):
    _run(tmp_path, 3)
    path = tmp_path / "items.jsonl"
    text = path.read_text()
    path.write_text(text[: text.rindex("{") + 5])  # a kill in the middle of the last write
    CALLS.clear()
    out = _run(tmp_path, 3)
    assert CALLS == [2] and len(out["records"]) == 3
    assert len(read_done(path)) == 3


def test_a_bad_index_names_the_file(tmp_path):
    path = tmp_path / "items.jsonl"
    path.write_text('{"index": -1}\n')
    with pytest.raises(CorruptFileError, match="items.jsonl.*-1"):
        read_done(path)


def test_in_memory_campaigns_and_on_record(tmp_path):
    assert open_campaign(None, {"a": 1}, "x.jsonl") == (None, None, {})
    seen, done = [], {}
    n = run_missing(_square, [(0, 1), (1, 1)], done, None, make_executor(None, 1, False),
                    "items", on_record=lambda rec: seen.append(rec["index"]))
    assert n == 2 and seen == [0, 1] and sorted(done) == [0, 1]
    assert run_missing(_square, [], done, None, None, "items") == 0
    out = _run(None, 2)
    assert out["n"] == 2 and not list(tmp_path.iterdir())
