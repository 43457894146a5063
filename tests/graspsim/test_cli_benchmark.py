"""`graspsim benchmark recognition` from the command line, on a Cornell-format fixture."""

from __future__ import annotations

import json

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


def test_recognition_benchmark_cli_bad_input(tmp_path, capsys):
    code = main(["benchmark", "recognition", "--data", str(tmp_path / "nope"), "--format",
                 "cornell", "--out", str(tmp_path / "o")])
    assert code == 2
    assert "dataset folder not found" in capsys.readouterr().err
    code = main(["benchmark", "recognition", "--data", str(tmp_path), "--format", "cornell",
                 "--learners", "KSVD", "--out", str(tmp_path / "o")])
    assert code == 2
