"""JSON-lines results files: torn lines from a kill are skipped, named in the log."""

from __future__ import annotations

import logging

from dlsr.records import read_jsonl


def test_reads_objects_and_skips_a_torn_line(tmp_path, caplog):
    path = tmp_path / "r.jsonl"
    path.write_text('{"a": 1}\n\n{"a": 2}\n[3]\n{"a": 3, "b"')
    with caplog.at_level(logging.WARNING):
        assert read_jsonl(path) == [{"a": 1}, {"a": 2}]
    assert "r.jsonl:4" in caplog.text and "r.jsonl:5" in caplog.text


def test_missing_file_has_no_records(tmp_path):
    assert read_jsonl(tmp_path / "absent.jsonl") == []
