"""`graspsim run` end to end on a tiny configuration: stages, report, resume, config files."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from graspsim.cli import main
from graspsim.pipeline import job as pipeline

pytestmark = pytest.mark.sim

TINY = {
    "name": "tiny", "scenes": 6, "candidates": 12, "n_atoms": 8, "n_patches": 6000, "folds": 2,
    "inner_folds": 2, "trials": 3, "trial_candidates": 8, "baselines": ["mask-pca"],
    "detection_images": 4, "jobs": 1, "fit_grid": 0.05,
    # a few named objects, the trial objects held out (as in object-wise validation)
    "train_objects": "mug_classic,can_soda,box_small,block_t,wooden_spoon",
    "trial_objects": "box_tea,bowl_small",
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
    assert set(stages) == {"dataset", "recognition", "detection", "model", "model-paper",
                           "trials/dlsr", "trials/dlsr-paper", "trials/mask-pca"}
    assert stages["dataset"]["images"] == 6
    seen = {line.split()[1] for line in (out / "dataset" / "image_objects.txt").read_text()
            .splitlines() if not line.startswith("#")}
    assert seen <= set(TINY["train_objects"].split(","))
    assert 0.0 <= stages["recognition"]["accuracy"] <= 1.0
    assert not (out / "recognition" / "data").exists()  # the workers' mapped copy is removed
    for name in ("dlsr", "dlsr-paper", "mask-pca"):
        s = stages[f"trials/{name}"]
        assert s["n"] == 3 and 0 <= s["successes"] <= 3
        lines = (out / "trials" / name / "trials.jsonl").read_text().splitlines()
        assert len(lines) == 3
        assert {json.loads(t)["object"][0] for t in lines} <= set(TINY["trial_objects"].split(","))
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["scenes"] == 6 and "numpy" in run["versions"]
    # the detector training options reach the detection benchmark and the final model
    det = json.loads((out / "detection" / "detection.json").read_text())
    assert det["config"]["fit_grid"] == 0.05 and det["config"]["physical"] is True
    assert det["config"]["clear_jaws"] is True  # gripper-aware: the offline search too
    assert det["config"]["detector"] == "lattice"
    assert det["config"]["grid_negatives"] == pipeline.RunConfig().grid_negatives
    model = json.loads((out / "model" / "dlsr.json").read_text())
    assert model["config"]["fit_grid"] == 0.05 and model["physical"]["n_columns"] == 9
    assert model["config"]["detector"] == "lattice"
    paper = json.loads((out / "model" / "dlsr-paper.json").read_text())
    assert "physical" not in paper and paper["config"]["detector"] == "dense"
    md = report.read_text()
    assert "5 built-in objects (mug_classic, can_soda, box_small, wooden_spoon, block_t)" in md
    assert "trials on 2 built-in objects (box_tea, bowl_small)" in md
    assert "Physical grasp success" in md and "| dlsr |" in md and "| mask-pca |" in md
    assert "| dlsr-paper |" in md and "gripper-aware" in md and "physical features" in md
    assert "DLSR against each baseline, scene by scene" in md and "| mask-pca | 3 |" in md
    assert (out / "pictures" / "success_rates.png").exists()
    html = (out / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and "data:image/png;base64," in html
    assert "<img" in html and 'src="pictures/' not in html  # self-contained


def test_resume_redoes_nothing_finished(tiny_run, monkeypatch):
    out, _ = tiny_run
    before = (out / "trials" / "dlsr" / "trials.jsonl").read_text()

    def boom(*a, **k):
        raise AssertionError("a finished stage was run again")

    monkeypatch.setattr("graspsim.pipeline.job.make_dataset", boom)
    monkeypatch.setattr("graspsim.pipeline.job.run_trials", boom)
    report = pipeline.resume_job(out, progress=False)
    assert report.exists()
    assert (out / "trials" / "dlsr" / "trials.jsonl").read_text() == before


def test_offline_false_skips_the_offline_benchmarks(tiny_run, tmp_path, monkeypatch):
    """A run with ``offline = false`` (as object-wise validation's fold runs) never starts the
    recognition or detection CV, and its report says so (a copy of the tiny run without those
    stages, resumed)."""
    out, _ = tiny_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("recognition", "detection"))
    stages = json.loads((copy / "stages.json").read_text())
    del stages["recognition"], stages["detection"]
    (copy / "stages.json").write_text(json.dumps(stages))
    run = json.loads((copy / "run.json").read_text())
    run["config"]["offline"] = False
    (copy / "run.json").write_text(json.dumps(run))

    def boom(*a, **k):
        raise AssertionError("an offline benchmark ran")

    monkeypatch.setattr("dlsr.recognition.run_recognition_benchmark", boom)
    monkeypatch.setattr("graspsim.pipeline.job.detection_benchmark", boom)
    config = pipeline.load_config(**TINY, offline=False)
    report = pipeline.run_job(config, out=copy, progress=False)
    assert set(json.loads((copy / "stages.json").read_text())) == set(stages)
    assert not (copy / "recognition").exists() and not (copy / "detection").exists()
    md = report.read_text()
    assert "Not run (`offline = false`)" in md and "| dlsr |" in md
    assert "Not run" not in (out / "report.md").read_text()


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
    monkeypatch.setattr("graspsim.pipeline.job.run_trials", lambda *a, **k: (_ for _ in ()).throw(
        AssertionError("a finished stage was run again")))
    assert pipeline.resume_job(copy, progress=False).exists()


def test_a_run_continues_on_other_workers_and_backends(tiny_run, tmp_path, monkeypatch, caplog):
    # jobs, backend and address do not change the results: not part of the run's identity
    out, _ = tiny_run
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    monkeypatch.setattr("graspsim.pipeline.job.run_trials", lambda *a, **k: (_ for _ in ()).throw(
        AssertionError("a finished stage was run again")))
    with caplog.at_level("INFO", logger="graspsim.pipeline"):
        pipeline.run_job(pipeline.load_config(**{**TINY, "jobs": 2}), out=copy, progress=False)
    assert "jobs 1 -> 2" in caplog.text
    seen = {}
    real_run_job = pipeline.run_job

    def spy(config, **kw):
        seen["config"] = config
        return real_run_job(config, **kw)

    monkeypatch.setattr(pipeline, "run_job", spy)
    assert main(["run", "--resume", str(copy), "--jobs", "2"]) == 0
    assert seen["config"].jobs == 2 and seen["config"].seed == TINY.get("seed", 0)
    pipeline.resume_job(copy, progress=False, jobs=None)  # None keeps the recorded value
    assert seen["config"].jobs == 1
    with pytest.raises(TypeError, match="only"):
        pipeline.resume_job(copy, progress=False, seed=1)  # what it computes: not here


def test_ctrl_c_says_how_to_continue_in_one_line(tmp_path, monkeypatch, capsys):
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    def run_cli(argv):  # an interrupt that escapes would stop the whole test session
        try:
            return main(argv)
        except KeyboardInterrupt:
            pytest.fail("KeyboardInterrupt escaped graspsim's main")

    monkeypatch.setattr("graspsim.pipeline.run_job", interrupted)
    monkeypatch.setattr("graspsim.pipeline.resume_job", interrupted)
    assert run_cli(["run", "--quick", "--out", str(tmp_path / "r")]) == 130
    err = capsys.readouterr().err.strip()
    assert err == (f"graspsim run: interrupted; what was finished is saved, continue with "
                   f"`graspsim run --resume {tmp_path / 'r'}`")
    assert run_cli(["run", "--quick", "--name", "mine"]) == 130
    assert "`graspsim run --resume runs/mine`" in capsys.readouterr().err
    assert run_cli(["run", "--resume", str(tmp_path / "r")]) == 130
    assert f"--resume {tmp_path / 'r'}`" in capsys.readouterr().err
    # any other command: one line, no traceback
    monkeypatch.setattr("graspsim.eval.compare.compare_folders", interrupted)
    assert run_cli(["compare", "a", "b"]) == 130
    assert capsys.readouterr().err.strip() == "graspsim compare: interrupted"


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
    with pytest.raises(ValueError, match="physical features and hard_negatives"):
        pipeline.load_config(hard_negatives=2)
    with pytest.raises(ValueError, match="detector"):
        pipeline.load_config(detector="grid")
    paper = pipeline.load_config(detector="dense", physical=False, gripper_aware=False,
                                 hard_negatives=2)
    assert pipeline.trial_names(paper)[:2] == ["dlsr", "mask-pca"]  # no dlsr-paper twin
    assert pipeline.trial_names(pipeline.load_config(gripper_aware=False))[1] == "dlsr-paper"
    with pytest.raises(FileNotFoundError):
        pipeline.load_config(tmp_path / "absent.toml")
    assert main(["run", "--resume", str(tmp_path / "nothing")]) == 2
    with pytest.raises(ValueError, match="trial_objects: no built-in object named teapot"):
        pipeline.load_config(trial_objects="brush,teapot")
    with pytest.raises(ValueError, match="train_objects must be a string"):
        pipeline.load_config(train_objects=["brush"])


def test_objectwise_validation_runs_every_fold_and_pools_the_trials(tmp_path, monkeypatch):
    """Each fold's run trains on the other folds' objects and tries its own; the pooled
    comparison is that of every trial of every fold (a stand-in for run_job writes the
    trial folders)."""
    runs = []

    def fake_run_job(config, out, resume=True, progress=True):
        runs.append(config)
        train, trial = config.train_objects.split(","), config.trial_objects.split(",")
        for name in pipeline.trial_names(config):
            d = out / "trials" / name
            d.mkdir(parents=True)
            (d / "config.json").write_text(json.dumps({"detector": name}))
            # DLSR succeeds on the first trial object's scenes, mask-pca on every scene
            recs = [{"index": i, "object": [trial[i % len(trial)]], "graspable": True,
                     "success": name == "mask-pca" or (name == "dlsr" and i % len(trial) == 0)}
                    for i in range(4)]
            for r in recs:
                r["reason"] = None if r["success"] else "collision on approach"
            (d / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
        assert not set(train) & set(trial)
        return out / "report.md"

    monkeypatch.setattr(pipeline, "run_job", fake_run_job)
    objects = "mug_classic,can_soda,box_small,block_t,wooden_spoon"
    config = pipeline.load_config(name="v", train_objects=objects, baselines=["mask-pca"],
                                  gripper_aware=False, physical=False, detector="dense")
    result = pipeline.objectwise_validation(config, n_folds=2, fold_seed=1, out=tmp_path)
    assert len(runs) == 2 and [r.name for r in runs] == ["v-fold0", "v-fold1"]
    assert not any(r.offline for r in runs)  # the folds skip the offline benchmarks
    tried = [r.trial_objects.split(",") for r in runs]
    assert sorted(tried[0] + tried[1]) == sorted(objects.split(","))
    for r, t in zip(runs, tried, strict=True):
        assert sorted(r.train_objects.split(",") + t) == sorted(objects.split(","))
    det = result["detectors"]
    assert det["mask-pca"]["successes"] == 8 and det["mask-pca"]["n"] == 8
    dlsr_ok = sum(len(range(0, 4, len(t))) for t in tried)  # i % len(trial) == 0, i < 4
    assert det["dlsr"]["successes"] == dlsr_ok
    (c,) = result["comparisons"]
    assert c["b"] == "mask-pca" and c["counts"]["only_b"] == 8 - dlsr_ok
    assert c["counts"]["only_a"] == 0 and c["n"] == 8
    saved = json.loads((tmp_path / "objectwise.json").read_text())
    assert saved["detectors"]["dlsr"]["successes"] == dlsr_ok
    assert "| mask-pca | 8/8 |" in (tmp_path / "objectwise.md").read_text()
    with pytest.raises(ValueError, match="n_folds"):
        pipeline.objectwise_validation(config, n_folds=6, out=tmp_path / "x")


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


def _synthetic_trials(root, name, success_of, planning=None):
    """A trial folder as run_trials writes it, 40 trials on 4 objects; returns its summary
    (``planning(i)``: trial i's planning seconds, not recorded when None)."""
    from graspsim.eval.summary import summarize

    folder = root / "trials" / name
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({
        "detector": name, "objects": "test", "seed": 7,
        "config": {"n_candidates": 8, "n_objects": 1, "label_with_clean_depth": False}}))
    objects = ["mug", "bowl", "box_long_name", "plate"]
    records = []
    for i in range(40):
        ok = success_of(i)
        records.append({"index": i, "seed": 7, "object": [objects[i % 4]],
                        "graspable": objects[i % 4] != "plate", "success": ok,
                        "reason": None if ok else "slipped", "rectangle": None,
                        "metric": i % 3 == 0, "seconds": 0.1})
        if planning is not None:
            records[-1]["planning_seconds"] = planning(i)
    (folder / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return summarize(records) | {"seconds": 4.0}


def test_report_compares_dlsr_with_each_baseline_and_draws(tmp_path):
    from graspsim.pipeline.report import write_report

    config = pipeline.load_config(**{**TINY, "baselines": ["mask-pca", "random"]})
    stages = {
        "trials/dlsr": _synthetic_trials(tmp_path, "dlsr", lambda i: i % 4 != 0),
        "trials/mask-pca": _synthetic_trials(tmp_path, "mask-pca", lambda i: i % 4 == 1),
        "trials/random": _synthetic_trials(tmp_path, "random", lambda i: False),
    }
    md = write_report(tmp_path, config, stages).read_text()
    assert "## DLSR against each baseline, scene by scene" in md
    # dlsr wins trials i % 4 in {1, 2, 3}, mask-pca only i % 4 == 1: both 10, only DLSR 20
    row = next(ln for ln in md.splitlines() if ln.startswith("| mask-pca | 40 |"))
    assert row.startswith("| mask-pca | 40 | 10 | 20 | 0 | 10 | +50.0 [")
    assert row.endswith("| DLSR better |")
    # On the 30 trials of graspable objects (the plate is not): both 10, only DLSR 10.
    assert "| 30: +33.3 [" in row
    assert "dlsr is better than mask-pca at the 5 % level" in md
    assert "| random | 40 | 0 | 30 | 0 | 10 |" in md
    pictures = ["success_rates.png", "success_per_object.png", "verdict_vs_outcome.png",
                "paired_differences.png"]
    for pic in pictures:
        assert (tmp_path / "pictures" / pic).stat().st_size > 1000
        assert f"](pictures/{pic})" in md
    html = (tmp_path / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len(pictures)
    saved = json.loads((tmp_path / "comparisons.json").read_text())["comparisons"]
    assert [(c["a"]["name"], c["b"]["name"]) for c in saved] == [("dlsr", "mask-pca"),
                                                                ("dlsr", "random")]


def test_report_says_why_a_pair_was_not_compared(tmp_path):
    from graspsim.pipeline.report import write_report

    config = pipeline.load_config(**{**TINY, "baselines": ["mask-pca"]})
    stages = {"trials/dlsr": _synthetic_trials(tmp_path, "dlsr", lambda i: i % 2 == 0),
              "trials/mask-pca": _synthetic_trials(tmp_path, "mask-pca", lambda i: i % 3 == 0)}
    cfg = tmp_path / "trials" / "mask-pca" / "config.json"
    cfg.write_text(cfg.read_text().replace('"seed": 7', '"seed": 8'))
    md = write_report(tmp_path, config, stages).read_text()
    assert "dlsr against mask-pca: not compared" in md and "seed 7 vs 8" in md
    assert (tmp_path / "pictures" / "success_rates.png").exists()


def test_report_gives_each_detectors_plan_time(tmp_path):
    from graspsim.pipeline.report import write_report

    config = pipeline.load_config(**{**TINY, "baselines": ["mask-pca"]})
    stages = {"trials/dlsr": _synthetic_trials(tmp_path, "dlsr", lambda i: i % 2 == 0,
                                               planning=lambda i: 0.1 + 0.01 * i),
              "trials/mask-pca": _synthetic_trials(tmp_path, "mask-pca", lambda i: i % 3 == 0)}
    md = write_report(tmp_path, config, stages).read_text()
    assert "| plan time median (s) | plan time p95 (s) |" in md
    x = 0.1 + 0.01 * np.arange(40)
    row = next(ln for ln in md.splitlines() if ln.startswith("| dlsr | 20/40 |"))
    assert row.endswith(f"| {np.median(x):.3f} | {np.percentile(x, 95):.3f} |")
    row = next(ln for ln in md.splitlines() if ln.startswith("| mask-pca | 14/40 |"))
    assert row.endswith("| n/a | n/a |")  # trials that recorded no planning time


@pytest.mark.parametrize("name", ["full.toml", "trials500.toml"])
def test_committed_configs_load(name):
    from pathlib import Path

    path = Path(pipeline.__file__).resolve().parents[2] / "configs" / name
    if not path.exists():
        pytest.skip(f"{path} is not in this installation (configs/ lives in the repository)")
    cfg = pipeline.load_config(path)
    assert cfg.trials == 500 and cfg.name == path.stem
    assert cfg.gripper_aware and cfg.grid_negatives == 0.0  # the defaults they build on
    assert cfg.physical and cfg.detector == "lattice"


def test_scene_and_gripper_reach_the_dataset_and_the_trials(tmp_path, monkeypatch):
    class Stop(Exception):
        pass

    seen = {}

    def fake_dataset(**kw):
        seen.update(kw)
        raise Stop

    monkeypatch.setattr("graspsim.pipeline.job.make_dataset", fake_dataset)
    cfg = pipeline.load_config(**{**TINY, "scene": "packed", "gripper": "franka"})
    with pytest.raises(Stop):
        pipeline.run_job(cfg, out=tmp_path / "run", progress=False)
    assert seen["scene"] == "packed" and seen["n_objects"] == 5
    assert seen["params"].gripper.hand == "franka"
    recorded = json.loads((tmp_path / "run" / "run.json").read_text())["config"]
    assert (recorded["scene"], recorded["gripper"]) == ("packed", "franka")

    calls = []
    monkeypatch.setattr(pipeline, "trial_detector",
                        lambda name, path, config, hand="builtin": (name, hand))
    monkeypatch.setattr("graspsim.pipeline.job.run_trials",
                        lambda det, **kw: calls.append((det, kw)) or {"n": 0})
    pipeline.trial_stage(tmp_path, cfg, pipeline._Stages(tmp_path), tmp_path / "m", 0, None,
                         progress=False)
    assert [d for d, _ in calls] == [(n, "franka") for n in pipeline.trial_names(cfg)]
    for _, kw in calls:
        assert kw["params"].gripper.hand == "franka"
        assert (kw["config"].scene, kw["config"].n_objects) == ("packed", 5)
    with pytest.raises(ValueError, match="unknown scene 'heap'"):
        pipeline.load_config(scene="heap")
    with pytest.raises(ValueError, match="gripper must be one of builtin, franka"):
        pipeline.load_config(gripper="robotiq")
