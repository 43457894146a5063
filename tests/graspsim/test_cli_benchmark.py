"""`graspsim benchmark recognition` and `detection` on Cornell-format fixtures."""

from __future__ import annotations

import json

import pytest

from dlsr.datasets import write_cornell
from graspsim.cli import main


def test_recognition_benchmark_cli_writes_and_resumes(tmp_path, box_samples, capsys):
    root = write_cornell(box_samples(6), tmp_path / "cornell")
    out = tmp_path / "out"
    args = ["benchmark", "recognition", "--data", str(root), "--format", "cornell",
            "--learners", "NKM", "RP", "--encoders", "Natural", "--atoms", "8",
            "--patches", "2000", "--split", "object", "--folds", "3", "--inner-folds", "2",
            "--out", str(out)]
    assert main(args) == 0
    assert "2 cells" in capsys.readouterr().out
    summary = json.loads((out / "recognition.json").read_text())
    assert summary["config"]["split"] == "object"
    assert {c["learner"] for c in summary["cells"]} == {"NKM", "RP"}
    for cell in summary["cells"]:
        assert 0.0 <= cell["accuracy"] <= 1.0
        assert len(cell["folds"]) == 3
    assert (out / "table1.md").read_text().count("|") > 10
    before = (out / "results.jsonl").read_text()
    assert main(args) == 0  # everything is done: nothing recomputed, nothing appended
    assert (out / "results.jsonl").read_text() == before


def test_recognition_benchmark_cli_asks_for_figure5(tmp_path, box_samples, monkeypatch, capsys):
    import dlsr.recognition

    root = write_cornell(box_samples(4), tmp_path / "cornell")
    seen = []

    def fake_run(data, out, **kw):
        seen.append(kw)
        return {"cells": [], "seconds_this_run": 0.0}

    monkeypatch.setattr(dlsr.recognition, "run_recognition_benchmark", fake_run)
    base = ["benchmark", "recognition", "--data", str(root), "--format", "cornell", "--out",
            str(tmp_path / "o")]
    assert main(base + ["--figure5", "--no-whiten"]) == 0
    assert main(base) == 0
    assert seen[0]["figure5_sizes"] == (50, 100, 200, 300, 400)
    assert seen[0]["whiten"] is False
    assert seen[1]["figure5_sizes"] is None and seen[1]["whiten"] is True


def test_recognition_benchmark_cli_bad_input(tmp_path, capsys):
    code = main(["benchmark", "recognition", "--data", str(tmp_path / "nope"), "--format",
                 "cornell", "--out", str(tmp_path / "o")])
    assert code == 2
    assert "dataset folder not found" in capsys.readouterr().err
    code = main(["benchmark", "recognition", "--data", str(tmp_path), "--format", "cornell",
                 "--learners", "KSVD", "--out", str(tmp_path / "o")])
    assert code == 2


def test_detection_benchmark_cli_passes_the_mining_options(tmp_path, box_samples, monkeypatch,
                                                           capsys):
    import dlsr.detection

    root = write_cornell(box_samples(5), tmp_path / "cornell")
    seen = []

    class Stop(Exception):
        pass

    def fake_train(samples, **kw):
        seen.append(kw)
        raise Stop

    monkeypatch.setattr(dlsr.detection, "train_detector", fake_train)
    base = ["benchmark", "detection", "--data", str(root), "--format", "cornell", "--split",
            "image", "--hard-negatives", "5", "--out", str(tmp_path / "o")]
    with pytest.raises(Stop):
        main(base + ["--hard-rounds", "2"])
    with pytest.raises(Stop):
        main(base)
    assert [(kw["hard_negatives"], kw["hard_rounds"]) for kw in seen] == [(5, 2), (5, 1)]
    assert main(base + ["--hard-rounds", "-1"]) == 2
    assert "hard_rounds must be an integer >= 0" in capsys.readouterr().err
