"""graspsim.eval.comparison_grid: detectors on protocol rows, grown in steps, paired with
mask-pca."""

from __future__ import annotations

import json

import pytest

from graspsim.detectors import load_detector
from graspsim.eval.comparison_grid import Row, grow, results_markdown

pytestmark = pytest.mark.sim


def _make(name, row):
    return load_detector(name)


def test_grid_grows_pairs_and_resumes(tmp_path):
    rows = [Row("drop", objects="test", sizes=(2, 3)),
            Row("pile", objects="test", scene="pile", n_objects=2, sizes=(1,))]
    dets = ["mask-pca", "random"]
    res = grow(rows, dets, _make, tmp_path, steps=1)
    assert res["drop"]["n"] == 2 and res["pile"]["n"] == 1  # the first step of each row
    res = grow(rows, dets, _make, tmp_path)
    drop = res["drop"]
    assert drop["n"] == 3 and drop["unit"] == "trials" and drop["hand"] == "builtin"
    # every detector on the same scenes: trial i shows the same object to both
    recs = {d: [json.loads(x) for x in
                (tmp_path / "drop" / d / "trials.jsonl").read_text().splitlines()]
            for d in dets}
    assert [r["object"] for r in recs["mask-pca"]] == [r["object"] for r in recs["random"]]
    for d in dets:
        c = drop["cells"][d]
        assert c["successes"] == sum(r["success"] for r in recs[d])
        assert sum(c["reasons"].values()) == 3
    assert "vs_reference" in drop["cells"]["random"]
    assert "vs_reference" not in drop["cells"]["mask-pca"]
    pile = res["pile"]["cells"]["random"]
    assert res["pile"]["unit"] == "rounds" and pile["placed"] == 2
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["drop"]["n"] == 3
    md = (tmp_path / "results.md").read_text()
    assert md == results_markdown(saved) and "## drop (3 paired trials" in md
    # grown a row at a time, the results still cover every row it has grown, and a column
    # not run on a row yet is left out of that row
    part = grow(rows[:1], [*dets, "oracle"], _make, tmp_path, steps=1, report=rows)
    assert set(part) == {"drop", "pile"} and part["pile"]["n"] == 1
    assert "oracle" in part["drop"]["cells"] and "oracle" not in part["pile"]["cells"]
    res = grow(rows, dets, _make, tmp_path)
    # a rerun finds every cell done: nothing is run again
    sizes = {d: (tmp_path / "drop" / d / "trials.jsonl").stat().st_size for d in dets}
    grow(rows, dets, _make, tmp_path)
    assert sizes == {d: (tmp_path / "drop" / d / "trials.jsonl").stat().st_size for d in dets}


def test_pick_reads_a_list_and_names_the_unknown():
    from graspsim.eval.comparison_grid import pick

    assert pick(" a, b ,,a", ("a", "b"), "rows") == ["a", "b", "a"]
    with pytest.raises(ValueError, match=r"unknown rows c, d; choose from a, b"):
        pick("a,d,c", ("a", "b"), "rows")
