"""Trials harness, dataset and patch files: resume, n_jobs invariance, oracle/random gap."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dlsr.datasets import load_cornell
from dlsr.patches import load_patch_file
from graspsim.data.datagen import make_dataset, make_patches
from graspsim.detectors import load_detector
from graspsim.eval.stats import wilson_interval
from graspsim.eval.trials import TrialConfig, campaign_execution_params, run_trials
from graspsim.sim.execution import ExecutionParams

pytestmark = pytest.mark.sim



def strip(records):
    return [{k: v for k, v in r.items() if k not in ("seconds", "planning_seconds")}
            for r in records]


def test_wilson_interval():
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    lo, hi = wilson_interval(10, 10)
    assert hi == pytest.approx(1.0) and lo == pytest.approx(0.7225, abs=1e-4)
    lo, hi = wilson_interval(50, 100)
    assert (lo, hi) == pytest.approx((0.4038, 0.5962), abs=1e-4)
    assert all(np.isnan(wilson_interval(0, 0)))


def test_resume_after_a_kill_repeats_and_loses_nothing(tmp_path, easy_objects):
    cfg = TrialConfig(n_candidates=0)
    full = run_trials("mask-pca", easy_objects, n=4, seed=3, out=tmp_path / "a", config=cfg)
    # Simulate a kill: two complete lines and a torn third one.
    out = tmp_path / "b"
    run_trials("mask-pca", easy_objects, n=4, seed=3, out=out, config=cfg)
    lines = (out / "trials.jsonl").read_text().splitlines()
    (out / "trials.jsonl").write_text(lines[0] + "\n" + lines[1] + "\n" + lines[2][:25])
    resumed = run_trials("mask-pca", easy_objects, n=4, seed=3, out=out, config=cfg)
    recs = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert sorted(r["index"] for r in recs) == [0, 1, 2, 3]
    assert strip(resumed["records"]) == strip(full["records"])
    # A rerun with everything done runs nothing new.
    again = run_trials("mask-pca", easy_objects, n=4, seed=3, out=out, config=cfg)
    assert again["trials_per_second"] is None
    assert len((out / "trials.jsonl").read_text().splitlines()) == 4
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n"] == 4 and "success_ci95" in summary
    assert "| rectangle metric" in (out / "summary.md").read_text()
    # Another configuration in the same folder is refused.
    with pytest.raises(ValueError, match="another configuration"):
        run_trials("random", easy_objects, n=4, seed=3, out=out, config=cfg)


def test_execution_parameters_belong_to_the_campaign(tmp_path, easy_objects):
    cfg, out = TrialConfig(n_candidates=0), tmp_path / "settle"
    params = ExecutionParams(min_grip=0.01)
    run_trials("mask-pca", easy_objects, n=2, seed=3, out=out, config=cfg, params=params)
    assert json.loads((out / "config.json").read_text())["execution"]["min_grip"] == 0.01
    assert campaign_execution_params(out) == params
    assert "min_grip = 0.01" in (out / "summary.md").read_text()
    # Resuming it with the harness's defaults would mix two harnesses in one folder.
    with pytest.raises(ValueError, match="another configuration"):
        run_trials("mask-pca", easy_objects, n=2, seed=3, out=out, config=cfg)
    again = run_trials("mask-pca", easy_objects, n=2, seed=3, out=out, config=cfg,
                       params=params)
    assert again["trials_per_second"] is None
    # A folder written before the parameters were recorded ran the defaults.
    plain = tmp_path / "plain"
    run_trials("mask-pca", easy_objects, n=2, seed=3, out=plain, config=cfg)
    assert "execution parameters" not in (plain / "summary.md").read_text()
    meta = json.loads((plain / "config.json").read_text())
    del meta["execution"]
    (plain / "config.json").write_text(json.dumps(meta))
    assert campaign_execution_params(plain) == ExecutionParams()
    assert run_trials("mask-pca", easy_objects, n=2, seed=3, out=plain,
                      config=cfg)["trials_per_second"] is None
    with pytest.raises(ValueError, match="another configuration"):
        run_trials("mask-pca", easy_objects, n=2, seed=3, out=plain, config=cfg, params=params)
    with pytest.raises(FileNotFoundError, match="not a trial folder"):
        campaign_execution_params(tmp_path / "nowhere")


def test_results_do_not_depend_on_n_jobs(easy_objects):
    cfg = TrialConfig(n_candidates=4)
    one = run_trials("random", easy_objects, n=4, seed=5, n_jobs=1, config=cfg)
    two = run_trials("random", easy_objects, n=4, seed=5, n_jobs=2, config=cfg)
    assert strip(one["records"]) == strip(two["records"])
    # Trial i does not depend on n either.
    three = run_trials("random", easy_objects, n=3, seed=5, n_jobs=1, config=cfg)
    assert strip(three["records"]) == strip(one["records"])[:3]


def test_oracle_random_gap(easy_objects):
    cfg = TrialConfig(n_candidates=16)
    oracle = run_trials("oracle", easy_objects, n=6, seed=0, config=cfg)
    rand = run_trials("random", easy_objects, n=6, seed=0, config=cfg)
    assert oracle["success_rate"] >= 5 / 6
    assert rand["success_rate"] <= 1 / 6
    assert oracle["metric_accuracy"] == oracle["success_rate"]  # its rectangle is a positive
    t = rand["verdict_vs_outcome"]
    assert sum(v for row in t.values() for v in row.values()) == 6


def test_detector_loader_errors(tmp_path):
    assert type(load_detector("mask-pca")).__name__ == "MaskPCADetector"
    with pytest.raises(FileNotFoundError, match="unknown detector"):
        load_detector("no-such-detector")
    model = tmp_path / "model.npz"
    model.write_bytes(b"")
    with pytest.raises(FileNotFoundError, match="model.json"):
        load_detector(model)


def test_saved_dlsr_model_plugs_into_trials(tmp_path, box_samples):
    from dlsr.detection import DenseDetector, train_detector

    model = train_detector(box_samples(6), n_atoms=8, n_patches=2000, random_state=0)
    model.save(tmp_path / "m")
    det = load_detector(tmp_path / "m.npz")
    assert isinstance(det, DenseDetector)
    s = box_samples(1)[0]
    obs = {"rgb": s.rgb, "depth": s.depth, "depth_valid": s.depth_valid.astype(np.uint8)}
    a = det.predict(obs)
    b = load_detector(tmp_path / "m").predict(obs)
    assert a and [r.as_array().tolist() for r in a] == [r.as_array().tolist() for r in b]


def test_dataset_in_cornell_layout_loads(tmp_path, easy_objects):
    stats = make_dataset(n_scenes=3, objects=easy_objects, out=tmp_path / "ds", seed=1,
                         n_candidates=8)
    samples = load_cornell(tmp_path / "ds")
    assert len(samples) == 3
    assert sum(len(s.positives) for s in samples) == stats["positives"]
    assert sum(len(s.negatives) for s in samples) == stats["negatives"]
    assert stats["positives"] + stats["negatives"] == 3 * 8
    names = {s.name for s in easy_objects}
    for s in samples:
        assert s.object_id in names
        assert s.rgb.shape == (480, 640, 3)
        assert s.depth.dtype == np.float32
        assert np.all(s.depth[s.depth_valid] > 0) and np.all(s.depth[~s.depth_valid] == 0)


def test_dataset_resumes_after_a_kill(tmp_path, easy_objects):
    full = make_dataset(n_scenes=3, objects=easy_objects, out=tmp_path / "a", seed=2,
                        n_candidates=6)
    # Simulate a kill after the first scene: keep one finished line and a truncated one.
    part = tmp_path / "b"
    make_dataset(n_scenes=1, objects=easy_objects, out=part, seed=2, n_candidates=6)
    with (part / "scenes.jsonl").open("a") as fh:
        fh.write('{"index": 1, "mapp')
    resumed = make_dataset(n_scenes=3, objects=easy_objects, out=part, seed=2, n_candidates=6)
    lines = (part / "scenes.jsonl").read_text().splitlines()
    assert sorted(json.loads(ln)["index"] for ln in lines if ln.endswith("}")) == [0, 1, 2]
    assert resumed["positives"] == full["positives"]
    assert resumed["negatives"] == full["negatives"]
    a, b = load_cornell(tmp_path / "a"), load_cornell(part)
    for sa, sb in zip(a, b, strict=True):
        np.testing.assert_array_equal(sa.depth, sb.depth)
        assert [r.as_array().tolist() for r in sa.positives] == \
            [r.as_array().tolist() for r in sb.positives]
    with pytest.raises(ValueError, match="another configuration"):
        make_dataset(n_scenes=3, objects=easy_objects, out=part, seed=3, n_candidates=6)


def test_patch_file_reads_back(tmp_path, easy_objects):
    out = tmp_path / "p.npz"
    info = make_patches(n=300, out=out, objects=easy_objects, seed=0, n_scenes=2,
                        rects_per_scene=4)
    P, M = load_patch_file(out)
    assert P.shape == (300, 6, 6, 8) and M.shape == P.shape and M.dtype == bool
    assert info["n"] == 300
    assert np.all(np.isfinite(P))


def test_trials_cli(tmp_path, capsys):
    from graspsim.cli import main

    assert main(["trials", "--detector", "no-such", "--n", "1", "--out", str(tmp_path / "x")]) == 2
    assert "unknown detector" in capsys.readouterr().err
    out = tmp_path / "t"
    assert main(["trials", "--detector", "mask-pca", "--objects", "test", "--n", "2",
                 "--candidates", "0", "--out", str(out)]) == 0
    assert len((out / "trials.jsonl").read_text().splitlines()) == 2
    assert json.loads((out / "summary.json").read_text())["n"] == 2
    # --gripper-aware wraps the detector: the same scenes, every proposal executable.
    aware = tmp_path / "aware"
    assert main(["trials", "--detector", "mask-pca", "--gripper-aware", "--objects", "test",
                 "--n", "2", "--candidates", "0", "--out", str(aware)]) == 0
    assert json.loads((aware / "config.json").read_text())["detector"] == "mask-pca+aware"
    plain = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    wrapped = [json.loads(x) for x in (aware / "trials.jsonl").read_text().splitlines()]
    assert [r["object"] for r in plain] == [r["object"] for r in wrapped]
    assert all(r["rectangle"] is None or r["reason"] != "too wide for the gripper"
               for r in wrapped)
    # --min-grip is recorded with the folder and refused below zero, in one line.
    settle = tmp_path / "settle"
    assert main(["trials", "--detector", "mask-pca", "--gripper-aware", "--min-grip", "0.01",
                 "--objects", "test", "--n", "1", "--candidates", "0",
                 "--out", str(settle)]) == 0
    assert campaign_execution_params(settle) == ExecutionParams(min_grip=0.01)
    capsys.readouterr()
    assert main(["trials", "--detector", "mask-pca", "--min-grip", "-0.01", "--n", "1",
                 "--out", str(tmp_path / "z")]) == 2
    err = capsys.readouterr().err
    assert "--min-grip" in err and err.count("\n") == 1
    # The executor flags of every long command.
    assert main(["trials", "--detector", "mask-pca", "--n", "1", "--address", "127.0.0.1:1",
                 "--out", str(tmp_path / "y")]) == 2
    assert "--address needs --backend ray" in capsys.readouterr().err


@pytest.mark.slow  # about 20 s on 2 cores, most of it starting Ray
def test_ray_backend_gives_the_records_of_loky(easy_objects):
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install '.[ray]')")
    from graspsim.runtime.executor import Executor

    cfg = TrialConfig(n_candidates=2)
    loky = run_trials("random", easy_objects, n=3, seed=6, config=cfg,
                      executor=Executor("loky", n_jobs=2, progress=False))
    ray_ = run_trials("random", easy_objects, n=3, seed=6, config=cfg,
                      executor=Executor("ray", n_jobs=2, progress=False))
    assert strip(ray_["records"]) == strip(loky["records"])
    assert [r["index"] for r in ray_["records"]] == [0, 1, 2]


def test_dense_sampler_in_trials_and_old_config_folders_resume(tmp_path, easy_objects):
    out = tmp_path / "t"
    s = run_trials("oracle", objects=easy_objects, n=1, seed=3, out=out,
                   config=TrialConfig(n_candidates=24, sampler="dense"))
    assert s["records"][0]["n_labelled"] <= 24
    assert json.loads((out / "config.json").read_text())["config"]["sampler"] == "dense"
    with pytest.raises(ValueError, match="another configuration"):
        run_trials("oracle", objects=easy_objects, n=1, seed=3, out=out,
                   config=TrialConfig(n_candidates=24))
    # a folder written before the sampler existed ran the mixed sampler: it resumes
    old = tmp_path / "old"
    run_trials("random", objects=easy_objects, n=1, seed=3, out=old,
               config=TrialConfig(n_candidates=0))
    cfg = json.loads((old / "config.json").read_text())
    del cfg["config"]["sampler"]
    (old / "config.json").write_text(json.dumps(cfg))
    again = run_trials("random", objects=easy_objects, n=2, seed=3, out=old,
                       config=TrialConfig(n_candidates=0))
    assert again["n"] == 2


def test_objects_by_name_keep_the_built_in_order_and_name_the_unknown():
    from graspsim.labels.graspability import resolve_objects
    from graspsim.sim.objects import builtin_objects

    train = [s.name for s in builtin_objects("train")]
    a, b = train[3], train[7]
    assert [s.name for s in resolve_objects(f"{b}, {a}")] == [a, b]
    assert [s.name for s in resolve_objects(f"{a},{b}")] == [a, b]
    assert [s.name for s in resolve_objects("test")] == [s.name for s in builtin_objects("test")]
    with pytest.raises(ValueError, match="no built-in object named teapot; .*" + a):
        resolve_objects(f"{a},teapot")
    with pytest.raises(ValueError, match="no objects"):
        resolve_objects(" , ")


def test_object_folds_partition_the_objects_reproducibly():
    from graspsim.eval.trials import object_folds
    from graspsim.sim.objects import builtin_objects

    train = [s.name for s in builtin_objects("train")]
    folds = object_folds("train", 3, seed=5)
    assert sorted(n for f in folds for n in f) == sorted(train)  # every object, once
    assert max(map(len, folds)) - min(map(len, folds)) <= 1
    assert all(f == sorted(f, key=train.index) for f in folds)  # built-in order
    assert object_folds("train", 3, seed=5) == folds
    assert object_folds("train", 3, seed=6) != folds
    four = train[:4]
    assert sorted(map(len, object_folds(",".join(four), 4))) == [1, 1, 1, 1]
    for bad in (1, 5, 2.5, True):
        with pytest.raises(ValueError, match="n_folds must be an integer between 2 and the 4"):
            object_folds(",".join(four), bad)
