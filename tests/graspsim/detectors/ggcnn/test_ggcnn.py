"""GG-CNN with torch: the network's size, training (loss, determinism, resume), the model files
(weights-only, checksummed, one-line errors), the plug-in in trials, the CLI, bad input, and
the one-line hint when torch is missing. Tiny nets and images keep the file fast."""

from __future__ import annotations

import builtins
import json

import numpy as np
import pytest

from dlsr.datasets import GraspSample, write_cornell
from dlsr.rectangles import GraspRectangle

torch = pytest.importorskip("torch")

from graspsim.cli import main  # noqa: E402
from graspsim.detectors import (  # noqa: E402
    GripperAwareDetector,
    check_detector,
    load_detector,
)
from graspsim.detectors.ggcnn.detector import GGCNNDetector, crop_input  # noqa: E402
from graspsim.detectors.ggcnn.maps import grasp_maps  # noqa: E402
from graspsim.detectors.ggcnn.model import (  # noqa: E402
    INSTALL_HINT,
    build_network,
    load_model,
    model_paths,
    n_parameters,
    require_torch,
)
from graspsim.detectors.ggcnn.train import augment, prepare_samples, train_ggcnn  # noqa: E402

TINY = {"input_size": 48, "crop": 72, "filters": (4, 4, 4, 4, 4, 4), "crop_method": "centre",
        "threads": 1, "progress": False}


def tiny_samples(n=4):
    """72 x 72 depth images of a bar on a table, grasped across it."""
    out = []
    rows, cols = np.mgrid[0:72, 0:72]
    for i in range(n):
        a = (0.0, 0.8, -0.6, 1.3)[i % 4]
        c, s = np.cos(a), np.sin(a)
        dx, dy = cols - 36.0, rows - 36.0
        bar = (np.abs(dx * c - dy * s) < 20) & (np.abs(dx * s + dy * c) < 6)
        depth = np.where(bar, 0.62, 0.70).astype(np.float32)
        valid = np.ones(depth.shape, bool)
        valid[:2] = False
        depth[~valid] = 0
        rgb = np.repeat((255 * (depth > 0.65)).astype(np.uint8)[..., None], 3, axis=2)
        pos = [GraspRectangle(36 + t * c, 36 - t * s, a + np.pi / 2, 24, 8) for t in (-10, 0, 10)]
        out.append(GraspSample(f"{100 + i:04d}", f"bar{i}", rgb, depth, valid, pos, []))
    return out


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    path = tmp_path_factory.mktemp("ggcnn") / "model"
    meta = train_ggcnn(tiny_samples(), path, steps=320, seed=3, checkpoint_every=32, lr=5e-3,
                       **TINY)
    return path, meta


def test_the_papers_network_has_62420_parameters_and_keeps_the_size():
    net = build_network()
    assert n_parameters(net) == 62_420
    with torch.no_grad():
        assert net(torch.zeros(1, 1, 300, 300)).shape == (1, 4, 300, 300)
        assert build_network((4,) * 6)(torch.zeros(2, 1, 48, 48)).shape == (2, 4, 48, 48)


def test_augment_moves_rectangles_with_the_image(rng):
    r = np.array([[30.0, 20.0, 0.3, 18.0, 6.0]])
    maps = grasp_maps(r, (48, 48))[0]
    x2, r2 = augment(maps, r, rng)
    # the rotated label image and the labels drawn from the moved rectangle overlap well
    drawn = grasp_maps(r2, (48, 48))[0] > 0
    warped = x2 > 0.5
    assert (drawn & warped).sum() >= 0.7 * max(drawn.sum(), warped.sum())


def test_training_lowers_the_loss_and_saves_weights_only(trained):
    path, meta = trained
    curve = meta["training"]["loss_curve"]
    assert meta["training"]["sample_steps"] == 320 and len(curve) == 10
    assert curve[-1][1] < 0.9 * curve[0][1]
    pt, js = model_paths(path)
    record = json.loads(js.read_text())
    assert record["format"] == "ggcnn" and len(record["sha256"]) == 64
    state = torch.load(pt, weights_only=True)  # a plain state dict, no pickled objects
    assert all(isinstance(v, torch.Tensor) for v in state.values())


def test_same_seed_same_weights_and_a_resumed_run_matches(tmp_path, trained):
    path, _ = trained
    ref = torch.load(model_paths(path)[0], weights_only=True)
    # stopped at 160 sample-steps, then resumed to 320 from the checkpoint
    out = tmp_path / "m"
    train_ggcnn(tiny_samples(), out, steps=160, seed=3, checkpoint_every=32, lr=5e-3, **TINY)
    meta = train_ggcnn(tiny_samples(), out, steps=320, seed=3, checkpoint_every=32, lr=5e-3,
                       **TINY)
    assert meta["training"]["sample_steps"] == 320
    got = torch.load(model_paths(out)[0], weights_only=True)
    assert all(torch.equal(ref[k], got[k]) for k in ref)
    other = tmp_path / "other"
    train_ggcnn(tiny_samples(), other, steps=32, seed=4, checkpoint_every=32, lr=5e-3, **TINY)
    diff = torch.load(model_paths(other)[0], weights_only=True)
    assert not all(torch.equal(ref[k], diff[k]) for k in ref)


def test_detector_returns_ranked_rectangles_in_image_pixels(trained):
    path, _ = trained
    det = GGCNNDetector(path, top_k=3)
    s = tiny_samples(1)[0]
    rects, scores = det.predict({"depth": s.depth, "depth_valid": s.depth_valid})
    assert rects.shape[1] == 5 and 1 <= len(rects) <= 3
    assert np.all(np.diff(scores) <= 0)
    assert np.all((rects[:, 0] >= 0) & (rects[:, 0] < 72) & (rects[:, 1] >= 0)
                  & (rects[:, 1] < 72))
    assert np.allclose(rects[:, 4], rects[:, 3] / 2)
    assert isinstance(load_detector(str(path)), GGCNNDetector)
    check_detector(str(path) + ".json")
    aware = load_detector(str(path) + "+aware")  # as run configs list it
    assert isinstance(aware, GripperAwareDetector) and aware.detector.top_k == 40
    check_detector(str(path) + "+aware")
    with pytest.raises(FileNotFoundError, match="unknown detector"):
        check_detector(str(path) + "_missing+aware")


def test_truncated_and_foreign_files_give_one_line_errors(tmp_path, trained):
    path, _ = trained
    pt, js = model_paths(path)
    bad = tmp_path / "bad"
    bpt, bjs = model_paths(bad)
    bjs.write_text(js.read_text())
    bpt.write_bytes(pt.read_bytes()[:100])  # truncated
    with pytest.raises(ValueError, match="do not match the sha256") as e:
        load_model(bad)
    assert "\n" not in str(e.value)
    foreign = tmp_path / "foreign"
    fpt, fjs = model_paths(foreign)
    fpt.write_bytes(b"not a torch file at all")
    record = json.loads(js.read_text())
    import hashlib

    record["sha256"] = hashlib.sha256(fpt.read_bytes()).hexdigest()
    fjs.write_text(json.dumps(record))
    with pytest.raises(ValueError, match="not a readable weights file"):
        load_model(foreign)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something"}))
    with pytest.raises(FileNotFoundError):
        load_detector(str(tmp_path / "other"))
    assert main(["trials", "--detector", str(bad), "--n", "1", "--out",
                 str(tmp_path / "t")]) == 2


def test_bad_input_no_positives_all_masked_wrong_shape(trained):
    path, _ = trained
    s = tiny_samples(2)
    for x in s:
        x.positives.clear()
    with pytest.raises(ValueError, match="none of the 2 images has"):
        train_ggcnn(s, path.parent / "none", steps=8, **TINY)
    masked = tiny_samples(1)[0]
    masked.depth[:] = 0
    masked.depth_valid[:] = False
    with pytest.raises(ValueError, match="none of the 1 images"):
        prepare_samples([masked], 72, 48, "centre")
    det = GGCNNDetector(path)
    with pytest.raises(ValueError, match="no valid pixel"):
        det.predict({"depth": masked.depth, "depth_valid": masked.depth_valid})
    with pytest.raises(ValueError, match=r"2-D image \(H, W\)"):
        det.predict({"depth": np.ones((72, 72, 3), np.float32)})
    with pytest.raises(ValueError, match="depth_valid has shape"):
        crop_input(np.ones((72, 72)), np.ones((70, 72), bool), 72, 48)
    with pytest.raises(ValueError, match="multiple of 12"):
        train_ggcnn(tiny_samples(), path.parent / "x", steps=8, **{**TINY, "input_size": 50})


def test_cli_train_then_trials_as_a_plugin(tmp_path, easy_objects, capsys):
    from graspsim.eval.trials import TrialConfig, run_trials

    data = write_cornell(tiny_samples(), tmp_path / "data")
    model = tmp_path / "ggcnn"
    assert main(["train", "ggcnn", "--data", str(data), "--out", str(model), "--steps", "16",
                 "--input-size", "48", "--crop", "72", "--threads", "1"]) == 0
    assert "GG-CNN, 16 sample-steps on 4 images" in capsys.readouterr().out
    s = run_trials(str(model), easy_objects, n=2, seed=0, config=TrialConfig(n_candidates=0))
    assert s["n"] == 2
    assert all(r["rectangle"] is not None for r in s["records"])
    assert not any(str(r["reason"]).startswith("detector error") for r in s["records"])


def test_without_torch_one_line_and_other_commands_work(monkeypatch, trained, capsys):
    path, _ = trained
    real_import = builtins.__import__

    def no_torch(name, *args, **kwargs):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError("No module named 'torch'", name="torch")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_torch)
    for mod in [m for m in list(__import__("sys").modules) if m == "torch"
                or m.startswith("torch.")]:
        monkeypatch.delitem(__import__("sys").modules, mod)
    with pytest.raises(ValueError, match=r"pip install -e \.\[cnn\]"):
        require_torch()
    assert main(["trials", "--detector", str(path), "--n", "1", "--out",
                 str(path.parent / "t")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and INSTALL_HINT in err
    assert main(["train", "ggcnn", "--data", str(path.parent), "--out", "x"]) == 2
    load_detector("mask-pca")  # the other detectors need no torch


def test_offline_benchmark_uses_dlsrs_object_wise_folds(tmp_path, capsys):
    from dlsr.datasets import object_wise_folds

    data = write_cornell(tiny_samples(), tmp_path / "data")
    out = tmp_path / "bench"
    args = ["benchmark", "detection", "--data", str(data), "--format", "cornell",
            "--detector", "ggcnn", "--folds", "2", "--ggcnn-steps", "8",
            "--ggcnn-input-size", "48", "--out", str(out)]
    assert main(args) == 0
    assert "GG-CNN accuracy" in capsys.readouterr().out
    s = json.loads((out / "ggcnn.json").read_text())
    assert s["n"] == 4 and len(s["folds"]) == 2
    from graspsim.data.samples import load_samples

    folds = object_wise_folds(load_samples(data, "cornell"), 2, 0)
    by_fold = {r["image_id"]: r["fold"] for r in s["per_image"]}
    samples = load_samples(data, "cornell")
    for k, (_, test) in enumerate(folds):
        assert {by_fold[samples[i].image_id] for i in test} == {k}
    lines = (out / "ggcnn_results.jsonl").read_text().splitlines()
    assert main(args) == 0  # a rerun resumes: nothing detected again
    assert (out / "ggcnn_results.jsonl").read_text().splitlines() == lines
    assert main([*args[:-2], "--paired", "--detector", "dense", "--out", str(out)]) == 2


def test_run_configs_accept_ggcnn_raw_and_aware(trained, monkeypatch):
    from graspsim.pipeline import RunConfig
    from graspsim.pipeline.plan import trial_names

    path, _ = trained
    monkeypatch.chdir(path.parent)
    cfg = RunConfig(baselines=["mask-pca", "model", "model+aware"]).validated()
    assert trial_names(cfg)[-2:] == ["model", "model+aware"]
    with pytest.raises(ValueError, match="baselines: unknown detector 'nomodel'"):
        RunConfig(baselines=["nomodel+aware"]).validated()


def test_curve_table_and_figure(tmp_path):
    from graspsim.eval.data_efficiency import curve_figure, curve_markdown

    row = {"successes": 3, "n": 4, "ci95": [0.3, 0.95], "train_seconds": 12.0,
           "planning_seconds": 0.5, "rect": {"correct": 2, "n": 5}}
    result = {"config": {"budgets": [80, 160]},
              "rows": {"10": {"dlsr": row, "ggcnn": {**row, "successes": 1, "budget": 80,
                                                      "ci95": [0.05, 0.7]}}},
              "validation": {"10": {"80": {"successes": 2, "n": 5}}},
              "comparisons": {"10": {"dlsr vs ggcnn": {"counts": {"only_a": 2, "only_b": 0},
                                                       "mcnemar_p": 0.5}}}}
    md = curve_markdown(result)
    assert "| 10 | dlsr | 3/4 | 30.0-95.0 % | 2/5 | 12 | 0.50 |  |" in md
    assert "| 10 | ggcnn | 1/4 |" in md and "| 10 | dlsr vs ggcnn | 2 | 0 | 0.5 |" in md
    assert "| 10 | 2/5 |  |" in md
    assert "Catching up: no size measured yet." in md  # no ggcnn+aware row here
    curve_figure(result, tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_perfect_maps_decode_to_the_labelled_rectangle_in_image_pixels(trained):
    # The training labels (crop, resize) and the detector's way back are inverses: maps drawn
    # from a positive in input pixels come back as that positive in image pixels.
    path, _ = trained
    s = tiny_samples(1)[0]
    _, box = crop_input(s.depth, s.depth_valid, 60, 48, "centre")
    row0, col0, scale = box
    truth = s.positives[1]
    r = np.array([[(truth.x - col0) * scale, (truth.y - row0) * scale, truth.theta,
                   truth.w * scale, truth.h * scale]])
    det = GGCNNDetector(path, top_k=1)
    det.meta_ = {"sigma": 3.0}
    det.maps = lambda obs: (grasp_maps(r, (48, 48)), box)
    (got,), _ = det.predict({"depth": s.depth})
    assert np.hypot(got[0] - truth.x, got[1] - truth.y) < 1.5
    assert abs((got[2] - truth.theta + np.pi / 2) % np.pi - np.pi / 2) < 1e-6
    assert got[3] == pytest.approx(truth.w, rel=1e-4)


def test_step_snapshot_is_named_by_the_steps_asked_for(tmp_path):
    """A budget the batch size does not divide is saved at the first batch past it, under
    the budget's name (the plateau search looks it up by that name)."""
    full = tmp_path / "full"
    train_ggcnn(tiny_samples(), full, steps=48, seed=5, checkpoint_every=32,
                snapshots=[20, 24], **TINY)
    for budget, reached in ((20, 24), (24, 24)):
        meta = json.loads(model_paths(tmp_path / f"full_step{budget}")[1].read_text())
        assert meta["training"]["sample_steps"] == reached
    assert not model_paths(tmp_path / "full_step24")[0].samefile(
        model_paths(tmp_path / "full_step20")[0])


def test_timed_snapshot_is_the_run_at_that_step_and_equal_time_falls_back(tmp_path):
    from graspsim.eval.data_efficiency import equal_time_model

    full = tmp_path / "full"
    meta = train_ggcnn(tiny_samples(), full, steps=96, seed=5, checkpoint_every=32,
                       snapshot_seconds=[1e-9, 1e9], **TINY)
    snap = tmp_path / "full_time0s"
    assert model_paths(snap)[1].is_file()  # reached at the first batch
    assert not model_paths(tmp_path / "full_time1000000000s")[1].is_file()  # never reached
    smeta = json.loads(model_paths(snap)[1].read_text())["training"]
    assert smeta["sample_steps"] == 8 and smeta["seconds"] <= meta["training"]["seconds"]
    # the snapshot is what a run stopped at that step gives (same seed and batches)
    alone = tmp_path / "alone"
    train_ggcnn(tiny_samples(), alone, steps=8, seed=5, checkpoint_every=32, **TINY)
    a = torch.load(model_paths(alone)[0], weights_only=True)
    b = torch.load(model_paths(snap)[0], weights_only=True)
    assert all(torch.equal(a[k], b[k]) for k in a)
    # equal time: the snapshot when there is one, the full model when it took no longer ...
    assert equal_time_model(full, 1e-9, tiny_samples(), seed=5) == snap
    assert equal_time_model(full, 1e9, tiny_samples(), seed=5) == full
    # ... else the sample-steps that fit at the full run's rate, trained with its seed
    half = meta["training"]["seconds"] / 2
    eq = equal_time_model(full, half, tiny_samples(), seed=5, progress=False)
    steps = json.loads(model_paths(eq)[1].read_text())["training"]["sample_steps"]
    assert eq.name.startswith("full_eq") and 8 <= steps < 96 and steps % 8 == 0


def _curve_result(dlsr, gg, p, only=(5, 1)):
    def row(k):
        return {"successes": k, "n": 20, "ci95": [0.1, 0.9], "train_seconds": 1.0}

    return {"config": {"budgets": [80]},
            "rows": {str(n): {"dlsr": row(a), "ggcnn+aware": row(b)}
                     for n, a, b in zip((10, 30, 100), dlsr, gg, strict=False)},
            "validation": {},
            "comparisons": {str(n): {"dlsr vs ggcnn+aware": {
                "counts": {"only_a": only[0], "only_b": only[1]}, "mcnemar_p": q}}
                for n, q in zip((10, 30, 100), p, strict=False)}}


def test_catch_up_reads_the_fixed_pair_along_the_curve():
    from graspsim.eval.data_efficiency import catch_up

    c = catch_up(_curve_result((15, 16, 17), (5, 12, 17), (0.001, 0.2, 1.0)))
    assert c["sizes"] == [10, 30, 100] and c["level"] == 100 and c["not_separated"] == 30
    assert "catches up" in c["sentence"] and "100" in c["sentence"]
    c = catch_up(_curve_result((15, 16, 17), (5, 6, 14), (0.001, 0.01, 0.3)))
    assert c["level"] is None and c["not_separated"] == 100
    assert "not separated" in c["sentence"]
    c = catch_up(_curve_result((15, 16, 17), (5, 6, 7), (0.001, 0.3, 0.01)))
    assert c["level"] is None and c["not_separated"] is None
    assert "does not catch up" in c["sentence"]
    assert catch_up({"rows": {}})["sentence"] == "no size measured yet"


def test_data_efficiency_resumes_from_its_committed_files_alone(tmp_path):
    """The campaign's folder without its datasets (what is committed) continues on another
    machine: the datasets come back from the seed and nothing is trained or tried again."""
    import shutil

    from graspsim.eval.data_efficiency import data_efficiency

    out = tmp_path / "curve"
    kw = dict(sizes=[2], budgets=[8, 16], test_trials=2, val_trials=2, heldout_images=2,
              candidates=16, n_jobs=1, n_atoms=16, n_patches=2000, progress=False)
    first = data_efficiency(out, **kw)
    assert set(first["rows"]["2"]) >= {"dlsr", "dlsr-paper", "ggcnn", "mask-pca"}
    kept = {p: p.stat().st_mtime_ns
            for p in [*(out / "models").iterdir(), *out.glob("*/*/trials.jsonl")]}
    assert len(kept) > 10  # the models, the validation trials and the test trials
    shutil.rmtree(out / "dataset")
    shutil.rmtree(out / "heldout")
    again = data_efficiency(out, **kw)
    assert again["rows"] == first["rows"] and again["validation"] == first["validation"]
    changed = [p for p, t in kept.items() if p.stat().st_mtime_ns != t]
    assert not changed, f"trained or tried again: {changed}"
