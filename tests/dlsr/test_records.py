"""Files of long runs: JSON-lines results (torn last line vs corruption), JSON and npz readers
that name the file, writers that never leave a half-written file."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from dlsr.records import (
    CorruptFileError,
    atomic_write,
    load_npz,
    read_json,
    read_jsonl,
    write_json_atomic,
)


def test_a_torn_last_line_is_dropped_with_a_warning(tmp_path, caplog):
    path = tmp_path / "r.jsonl"
    path.write_text('{"a": 1}\n\n{"a": 2}\n{"a": 3, "b"')
    with caplog.at_level(logging.WARNING):
        assert read_jsonl(path) == [{"a": 1}, {"a": 2}]
    assert "r.jsonl:4" in caplog.text
    assert path.read_text().endswith('"b"')  # reading alone does not touch the file


@pytest.mark.parametrize("tail", ['{"a": 3, "b"', '{"a": 3, "b"\n', "\0\0\0\0", '{"a"\n\n'])
def test_repair_cuts_the_torn_line_so_appends_start_a_line(tmp_path, tail):
    path = tmp_path / "r.jsonl"
    path.write_text('{"a": 1}\n{"a": 2}\n' + tail)
    assert read_jsonl(path, repair=True) == [{"a": 1}, {"a": 2}]
    assert path.read_text() == '{"a": 1}\n{"a": 2}\n'
    with path.open("a") as fh:
        fh.write('{"a": 3}\n')
    assert read_jsonl(path) == [{"a": 1}, {"a": 2}, {"a": 3}]
    assert not list(tmp_path.glob(".*tmp"))


def test_repair_ends_a_complete_last_record_with_a_newline(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text('{"a": 1}\n{"a": 2}')
    assert read_jsonl(path, repair=True) == [{"a": 1}, {"a": 2}]
    assert path.read_text() == '{"a": 1}\n{"a": 2}\n'


@pytest.mark.parametrize("content, line", [
    ('{"a": 1}\n{"a": 2, "b"\n{"a": 3}\n', 2),   # torn in the middle: later records exist
    ('{"a": 1}\n[3]\n{"a": 3}\n', 2),             # a JSON value that is not a record
    ('{"a": 1}\nnot json at all\n', 2),           # garbage last line: not a torn record
    ('\x89PNG\r\n\x1a\n', 1),                     # another file's bytes
    ('{"a": 1}\n{"b": 2}\n', 2),                  # a record without a required key
])
def test_anything_else_is_an_error_naming_file_and_line(tmp_path, content, line):
    path = tmp_path / "r.jsonl"
    path.write_bytes(content.encode("latin-1"))
    before = path.read_bytes()
    with pytest.raises(CorruptFileError, match=rf"r\.jsonl:{line}: "):
        read_jsonl(path, required=("a",), repair=True)
    assert path.read_bytes() == before  # never "repaired" away


def test_missing_and_empty_files_have_no_records(tmp_path):
    assert read_jsonl(tmp_path / "absent.jsonl") == []
    (tmp_path / "empty.jsonl").write_text("")
    assert read_jsonl(tmp_path / "empty.jsonl", repair=True) == []
    assert (tmp_path / "empty.jsonl").read_text() == ""


@pytest.mark.parametrize("content, message", [
    (b"", "empty file"),
    (b'{"a": [1, 2', "Expecting"),
    (b"\xff\xfe\x00garbage", "not a text file"),
    (b"[1, 2]", "expected a JSON object, got list"),
])
def test_read_json_names_the_file(tmp_path, content, message):
    path = tmp_path / "x.json"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message) as info:
        read_json(path, "thing")
    assert str(info.value).startswith(f"thing {path}: ") and "\n" not in str(info.value)
    with pytest.raises(FileNotFoundError, match="absent.json"):
        read_json(tmp_path / "absent.json")


def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("corrupt, message", [
    (lambda b: b[:1000], "truncated"),
    (lambda b: b"", "empty file"),
    (lambda b: b"garbage" * 50, r"not an \.npz archive \(it starts with b'garbag'\)"),
    (lambda b: b[:-30] + b"\0" * 30, "truncated"),
])
def test_load_npz_names_the_file(tmp_path, corrupt, message):
    path = _npz(tmp_path / "a.npz", x=np.arange(5000.0), y=np.ones(3))
    assert sorted(load_npz(path, ("x",))) == ["x", "y"]
    path.write_bytes(corrupt(path.read_bytes()))
    with pytest.raises(ValueError, match=message) as info:
        load_npz(path, what="model file")
    assert str(info.value).startswith(f"model file {path}: ")


def test_load_npz_wrong_content(tmp_path):
    np.save(tmp_path / "one.npy", np.ones(3))
    (tmp_path / "one.npy").rename(tmp_path / "one.npz")
    with pytest.raises(ValueError, match=r"one\.npz: not an \.npz archive"):
        load_npz(tmp_path / "one.npz")
    path = _npz(tmp_path / "b.npz", x=np.ones(2))
    with pytest.raises(ValueError, match=r"b\.npz: missing array\(s\) \['y'\]"):
        load_npz(path, ("x", "y"))
    np.savez(tmp_path / "p.npz", x=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError, match=r"p\.npz: .*pickle"):
        load_npz(tmp_path / "p.npz")


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    path = tmp_path / "sub" / "s.json"
    write_json_atomic(path, {"a": 1})
    assert json.loads(path.read_text()) == {"a": 1}
    with pytest.raises(RuntimeError), atomic_write(path) as fh:
        fh.write('{"a": ')
        raise RuntimeError("killed")
    assert json.loads(path.read_text()) == {"a": 1}
    assert [p.name for p in path.parent.iterdir()] == ["s.json"]
    with atomic_write(path, "wb") as fh:
        np.savez(fh, x=np.ones(2))
    assert load_npz(path)["x"].tolist() == [1.0, 1.0]
