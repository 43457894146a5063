"""`graspsim run` end to end on a tiny configuration: stages, report, resume, config files."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from graspsim import pipeline
from graspsim.cli import main

pytestmark = pytest.mark.sim

TINY = {
    "name": "tiny", "scenes": 6, "candidates": 12, "n_atoms": 8, "n_patches": 6000, "folds": 2,
    "inner_folds": 2, "trials": 3, "trial_candidates": 8, "baselines": ["mask-pca"],
    "detection_images": 4, "jobs": 1, "fit_grid": 0.05, "hard_negatives": 2,
}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    config = pipeline.load_config(**TINY)
    report = pipeline.run_job(config, out=out, progress=False)
    return out, report


def test_run_writes_every_stage_and_the_report(tiny_run):
    out, report = tiny_run
    stages = json.loads((out / "stages.json").read_text())
    assert set(stages) == {"dataset", "recognition", "detection", "model", "trials/dlsr",
                           "trials/mask-pca"}
    assert stages["dataset"]["images"] == 6
    assert 0.0 <= stages["recognition"]["accuracy"] <= 1.0
    for name in ("dlsr", "mask-pca"):
        s = stages[f"trials/{name}"]
        assert s["n"] == 3 and 0 <= s["successes"] <= 3
        assert len((out / "trials" / name / "trials.jsonl").read_text().splitlines()) == 3
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["scenes"] == 6 and "numpy" in run["versions"]
    # the detector training options reach the detection benchmark and the final model
    det = json.loads((out / "detection" / "detection.json").read_text())
    assert (det["config"]["fit_grid"], det["config"]["hard_negatives"]) == (0.05, 2)
    model = json.loads((out / "model" / "dlsr.json").read_text())
    assert (model["config"]["fit_grid"], model["config"]["hard_negatives"]) == (0.05, 2)
    md = report.read_text()
    assert "Physical grasp success" in md and "| dlsr |" in md and "| mask-pca |" in md
    html = (out / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and "data:image/png;base64," in html
    assert "<img" in html and 'src="pictures/' not in html  # self-contained


def test_resume_redoes_nothing_finished(tiny_run, monkeypatch):
    out, _ = tiny_run
    before = (out / "trials" / "dlsr" / "trials.jsonl").read_text()

    def boom(*a, **k):
        raise AssertionError("a finished stage was run again")

    monkeypatch.setattr("graspsim.datagen.make_dataset", boom)
    monkeypatch.setattr("graspsim.trials.run_trials", boom)
    report = pipeline.resume_job(out, progress=False)
    assert report.exists()
    assert (out / "trials" / "dlsr" / "trials.jsonl").read_text() == before


def test_interrupted_trials_continue(tiny_run, tmp_path):
    out, _ = tiny_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    # As if killed during the mask-pca trials: one trial on disk, the stage not finished.
    stages = json.loads((copy / "stages.json").read_text())
    del stages["trials/mask-pca"]
    (copy / "stages.json").write_text(json.dumps(stages))
    log = copy / "trials" / "mask-pca" / "trials.jsonl"
    lines = log.read_text().splitlines()
    log.write_text(lines[0] + "\n")
    pipeline.resume_job(copy, progress=False)
    again = [json.loads(x) for x in log.read_text().splitlines()]
    first = [json.loads(x) for x in lines]
    assert [r["index"] for r in again] == [0, 1, 2]
    timings = ("seconds", "planning_seconds")
    strip = [{k: v for k, v in r.items() if k not in timings} for r in again]
    assert strip == [{k: v for k, v in r.items() if k not in timings} for r in first]


def test_other_configuration_in_the_same_folder_is_refused(tiny_run, tmp_path, monkeypatch):
    out, _ = tiny_run
    with pytest.raises(ValueError, match="another configuration"):
        pipeline.run_job(pipeline.load_config(**{**TINY, "seed": 1}), out=out, progress=False)
    # a run recorded before a setting existed resumes, the setting at its default
    copy = tmp_path / "older"
    shutil.copytree(out, copy)
    run = json.loads((copy / "run.json").read_text())
    run["config"] = {k: v for k, v in run["config"].items() if k != "hard_rounds"}
    (copy / "run.json").write_text(json.dumps(run))
    monkeypatch.setattr("graspsim.trials.run_trials", lambda *a, **k: (_ for _ in ()).throw(
        AssertionError("a finished stage was run again")))
    assert pipeline.resume_job(copy, progress=False).exists()


def test_config_files_and_bad_settings(tmp_path):
    toml = tmp_path / "c.toml"
    toml.write_text('[run]\nname = "x"\nscenes = 7\nbaselines = ["random"]\n')
    cfg = pipeline.load_config(toml, quick=True)
    assert cfg.scenes == 7 and cfg.name == "x" and cfg.baselines == ["random"]
    assert cfg.n_atoms == pipeline.QUICK["n_atoms"]
    (tmp_path / "bad.toml").write_text("[run]\nscenez = 3\n")
    with pytest.raises(ValueError, match="unknown settings"):
        pipeline.load_config(tmp_path / "bad.toml")
    with pytest.raises(ValueError, match="learner"):
        pipeline.load_config(learner="KSVD")
    with pytest.raises(ValueError, match="hard_negatives"):
        pipeline.load_config(hard_negatives=-1)
    with pytest.raises(ValueError, match="fit_grid"):
        pipeline.load_config(fit_grid=0.7)
    with pytest.raises(FileNotFoundError):
        pipeline.load_config(tmp_path / "absent.toml")
    assert main(["run", "--resume", str(tmp_path / "nothing")]) == 2


def test_report_html_renders_in_headless_chromium(tiny_run, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    out, _ = tiny_run
    shot = tmp_path / "page.png"
    subprocess.run(
        [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
         "--window-size=1100,1600", f"--screenshot={shot}",
         (out / "report.html").as_uri()],
        check=True, capture_output=True, timeout=120,
    )
    from PIL import Image

    img = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert img.std() > 10  # text, tables and pictures, not a blank page
