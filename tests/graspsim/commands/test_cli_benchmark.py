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


def test_recognition_benchmark_runs_its_tasks_on_the_executor(tmp_path, box_samples,
                                                              monkeypatch):
    """--backend/--jobs reach recognition_benchmark as an executor, whose joblib backend and
    worker count the benchmark's tasks then take (n_jobs=None defers to them)."""
    import joblib

    import graspsim.eval.offline.recognition as gr

    root = write_cornell(box_samples(4), tmp_path / "cornell")
    seen = {}

    def fake_run(rd, out, n_jobs, **kw):
        backend, n = joblib.parallel.get_active_backend()
        seen.update(n_jobs=n_jobs, backend=type(backend).__name__, workers=n)
        return {"cells": [], "seconds_this_run": 0.0}

    monkeypatch.setattr(gr.rec, "run_recognition_benchmark", fake_run)
    assert main(["benchmark", "recognition", "--data", str(root), "--format", "cornell",
                 "--backend", "loky", "--jobs", "2", "--out", str(tmp_path / "o")]) == 0
    assert seen == {"n_jobs": None, "backend": "LokyBackend", "workers": 2}
    assert main(["benchmark", "recognition", "--data", str(root), "--format", "cornell",
                 "--out", str(tmp_path / "o")]) == 0  # one job: in this process
    assert seen["n_jobs"] is None and seen["backend"] == "SequentialBackend"


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

    root = write_cornell(box_samples(5), tmp_path / "cornell")
    seen = []

    class Stop(Exception):
        pass

    def fake_train(samples, **kw):
        seen.append(kw)
        raise Stop

    monkeypatch.setattr("graspsim.eval.offline.detection.train_detector", fake_train)
    base = ["benchmark", "detection", "--data", str(root), "--format", "cornell", "--split",
            "image", "--hard-negatives", "5", "--out", str(tmp_path / "o"), "--preset", "paper"]
    with pytest.raises(Stop):
        main(base + ["--hard-rounds", "2"])
    with pytest.raises(Stop):
        main(base)
    assert [(kw["hard_negatives"], kw["hard_rounds"]) for kw in seen] == [(5, 2), (5, 1)]
    assert main(base + ["--hard-rounds", "-1"]) == 2
    assert "hard_rounds must be an integer >= 0" in capsys.readouterr().err


# --- detection: self-taught patches, extra training data, saved models, executors ----------

# the paper's configuration (the real-data default needs camera matrices, which the box
# samples do not have)
TINY = ["--scale", "0.5", "--atoms", "8", "--patches", "1500", "--rescore", "0",
        "--coarse-to-fine", "--overlays", "0", "--preset", "paper"]


def _patch_file(path, n=600, seed=0):
    import numpy as np

    from dlsr.patches import save_patch_file

    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, 6, 6, 8)).astype(np.float32)
    save_patch_file(path, P, np.ones(P.shape, bool))
    return path


def test_detection_extra_patches_change_the_dictionary_not_the_svm_training(
        tmp_path, box_samples, monkeypatch):
    import numpy as np

    import dlsr.features
    import dlsr.svm
    from dlsr.detection import DLSRDetector

    root = write_cornell(box_samples(4), tmp_path / "cornell")
    patches = _patch_file(tmp_path / "extra.npz")
    seen = {"rep": [], "svm": []}
    real_fit_rep = dlsr.features.fit_representation
    real_svm_fit = dlsr.svm.SquaredHingeSVC.fit

    def spy_rep(images, masks, learner, **kw):
        seen["rep"].append((np.array(images), kw.get("extra")))
        return real_fit_rep(images, masks, learner, **kw)

    def spy_svm(self, X, y, *a, **kw):
        seen["svm"].append(np.array(y))
        return real_svm_fit(self, X, y, *a, **kw)

    monkeypatch.setattr(dlsr.features, "fit_representation", spy_rep)
    monkeypatch.setattr(dlsr.svm.SquaredHingeSVC, "fit", spy_svm)
    base = ["benchmark", "detection", "--data", str(root), "--format", "cornell", "--split",
            "image", "--folds", "2", "--max-images", "3", *TINY]
    assert main(base + ["--out", str(tmp_path / "std")]) == 0
    assert main(base + ["--extra-patches", str(patches), "--out", str(tmp_path / "st")]) == 0
    std_extra, st_extra = seen["rep"][0][1], seen["rep"][2][1]
    assert std_extra is None and len(st_extra[0]) == 600
    # the labelled training rectangles and labels are the same, fold by fold ...
    assert len(seen["rep"]) == len(seen["svm"]) == 4
    for k in range(2):
        np.testing.assert_array_equal(seen["rep"][k][0], seen["rep"][k + 2][0])
        np.testing.assert_array_equal(seen["svm"][k], seen["svm"][k + 2])
    # ... the dictionaries are not
    summary = json.loads((tmp_path / "st" / "detection.json").read_text())
    assert summary["config"]["extra_patches"]["n"] == 600
    d_std = [DLSRDetector.load(p).representation.dictionary
             for p in sorted((tmp_path / "std" / "models").glob("*.json"))]
    d_st = [DLSRDetector.load(p).representation.dictionary
            for p in sorted((tmp_path / "st" / "models").glob("*.json"))]
    assert len(d_std) == len(d_st) == 2
    for a, b in zip(d_std, d_st, strict=True):
        assert a.shape == b.shape and not np.allclose(a, b)
    assert DLSRDetector.load(sorted((tmp_path / "st" / "models").glob("*.json"))[0]) \
        .config["n_extra_patches"] == 600


def test_detection_extra_train_joins_training_folds_only(tmp_path, box_samples, monkeypatch):
    import dlsr.detection
    from graspsim.eval.offline.detection import detection_benchmark

    boxes = box_samples(6)
    root = write_cornell(boxes[:4], tmp_path / "real")
    extra_root = write_cornell(boxes[4:], tmp_path / "extra")
    seen = []
    real_train = dlsr.detection.train_detector

    def spy(samples, **kw):
        seen.append([s.image_id for s in samples])
        return real_train(samples, **kw)

    monkeypatch.setattr("graspsim.eval.offline.detection.train_detector", spy)
    s = detection_benchmark(root, "cornell", tmp_path / "o", scale=0.5, split="image",
                            n_folds=2, n_atoms=8, n_patches=1500, rescore=0,
                            coarse_to_fine=True, n_overlays=0, extra_train=extra_root,
                            extra_format="cornell", extra_scale=0.5, progress=False)
    extra_ids = {b.image_id for b in boxes[4:]}
    assert len(seen) == 2
    tested = {r["image_id"] for r in s["per_image"]}
    assert tested == {b.image_id for b in boxes[:4]}
    for k, ids in enumerate(seen):
        assert extra_ids <= set(ids)  # every training fold has the extra images ...
        fold_test = {r["image_id"] for r in s["per_image"] if r["fold"] == k}
        assert not fold_test & set(ids)  # ... and none of its test images
        assert len(ids) == 2 + len(extra_ids)
    assert s["config"]["extra_train"]["n_images"] == 2
    with pytest.raises(FileNotFoundError, match="dataset folder not found"):
        detection_benchmark(root, "cornell", tmp_path / "o", extra_train=tmp_path / "nope",
                            progress=False)


def test_detection_with_a_saved_model_trains_nothing(tmp_path, box_samples, monkeypatch,
                                                    capsys):
    from dlsr.detection import train_detector
    from graspsim.data.samples import load_samples

    boxes = box_samples(5)
    train_root = write_cornell(boxes[:2], tmp_path / "train")
    root = write_cornell(boxes[2:], tmp_path / "test")
    model = train_detector(load_samples(train_root, "cornell", 0.5), n_atoms=8,
                           n_patches=1500, random_state=0)
    model.save(tmp_path / "m")

    def no_training(*a, **kw):
        raise AssertionError("a saved model must not be retrained")

    monkeypatch.setattr("graspsim.eval.offline.detection.train_detector", no_training)
    args = ["benchmark", "detection", "--data", str(root), "--format", "cornell", "--model",
            str(tmp_path / "m"), "--scale", "0.5", "--rescore", "0", "--coarse-to-fine",
            "--overlays", "1", "--out", str(tmp_path / "o"), "--preset", "paper"]
    assert main(args) == 0
    assert "saved model, no training" in capsys.readouterr().out
    summary = json.loads((tmp_path / "o" / "detection.json").read_text())
    assert summary["config"]["split"] == "model"
    assert [r["image_id"] for r in summary["per_image"]] == [b.image_id for b in boxes[2:]]
    for r in summary["per_image"]:
        assert set(r["baselines"]) == {"random", "mask-pca"}
    acc = sum(r["success"] for r in summary["per_image"]) / 3
    assert summary["accuracy"] == pytest.approx(acc)
    for name, t in summary["vs_baselines"].items():
        wins = [r["baselines"][name] for r in summary["per_image"]]
        assert t["n"] == 3 and t["b"] == pytest.approx(sum(wins) / 3)
        assert 0 < t["p_value"] <= 1
    assert "Cross-dataset" in (tmp_path / "o" / "table2.md").read_text()
    assert not (tmp_path / "o" / "models").exists()
    before = (tmp_path / "o" / "results.jsonl").read_text()
    assert main(args) == 0  # resumes: every image is done
    assert (tmp_path / "o" / "results.jsonl").read_text() == before
    # bad input: a missing model, training options beside a model
    assert main(args[:7] + [str(tmp_path / "nope"), "--out", str(tmp_path / "o2")]) == 2
    assert "detector model file not found" in capsys.readouterr().err
    assert main(args + ["--extra-patches", "x.npz"]) == 2
    assert "extra_patches cannot be used with it" in capsys.readouterr().err
    assert main(args + ["--learner", "SC"]) == 2
    assert "learner 'SC' given, but the model" in capsys.readouterr().err


def test_paired_accuracy_test():
    from scipy.stats import binomtest

    from graspsim.eval.stats import paired_accuracy_test as mcnemar_exact

    a = [True, True, True, False, True, False]
    b = [False, False, True, False, True, True]
    t = mcnemar_exact(a, b)
    assert (t["a_only"], t["b_only"], t["n"]) == (2, 1, 6)
    assert t["p_value"] == pytest.approx(binomtest(2, 3, 0.5).pvalue)
    assert mcnemar_exact(a, a)["p_value"] == 1.0
    with pytest.raises(ValueError, match="paired outcomes"):
        mcnemar_exact(a, b[:3])


def test_detection_ray_matches_loky(tmp_path, box_samples):
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install '.[ray]')")
    from dlsr.detection import train_detector
    from graspsim.data.samples import load_samples
    from graspsim.eval.offline.detection import detection_benchmark
    from graspsim.runtime.executor import Executor

    boxes = box_samples(5)
    model = train_detector(load_samples(write_cornell(boxes[:2], tmp_path / "tr"), "cornell",
                                        0.5), n_atoms=8, n_patches=1500, random_state=0)
    model.save(tmp_path / "m")
    root = write_cornell(boxes[2:], tmp_path / "te")
    runs = {}
    for backend in ("loky", "ray"):
        s = detection_benchmark(root, "cornell", tmp_path / backend, scale=0.5,
                                model=tmp_path / "m", rescore=0, coarse_to_fine=True,
                                n_overlays=0, progress=False,
                                executor=Executor(backend, n_jobs=2, progress=False))
        runs[backend] = s["per_image"]
    assert runs["ray"] == runs["loky"]


def test_selftaught_benchmark_pairs_standard_and_selftaught(tmp_path, monkeypatch):
    import graspsim.eval.offline.selftaught as gb
    from graspsim.eval.stats import paired_detection_test

    patches = _patch_file(tmp_path / "extra.npz", n=50)
    calls = []

    def fake(data, format, out, learner, encoder, extra_patches, progress, **kw):
        calls.append((learner, encoder, extra_patches, kw))
        wins = [True, True, False, False] if extra_patches is None else [True, False, True, True]
        return {"accuracy": sum(wins) / 4, "baselines": {"random": 0.25},
                "config": {"encoder_param": None},
                "per_image": [{"image_id": f"i{k}", "success": w}
                              for k, w in enumerate(wins)]}

    monkeypatch.setattr(gb, "detection_benchmark", fake)
    res = gb.selftaught_benchmark("d", "jacquard", patches, tmp_path / "o",
                                  combinations=["NKM-Natural", "GSVQ-ST"], n_atoms=12,
                                  split="object")
    assert [(c[0], c[1], c[2] is not None) for c in calls] == [
        ("NKM", "Natural", False), ("NKM", "Natural", True),
        ("GSVQ", "ST", False), ("GSVQ", "ST", True)]
    assert all(c[3] == {"n_atoms": 12, "split": "object"} for c in calls)
    row = res["rows"][0]
    assert (row["standard"], row["selftaught"]) == (0.5, 0.75)
    assert (row["selftaught_only"], row["standard_only"]) == (2, 1)
    assert res["config"]["n_extra_patches"] == 50
    md = (tmp_path / "o" / "table3.md").read_text()
    assert "| GSVQ-ST | 50.0 (2/4) | 75.0 (3/4) | +25.0 | 2 vs 1 |" in md
    with pytest.raises(ValueError, match="LEARNER-ENCODER"):
        gb.selftaught_benchmark("d", "jacquard", patches, tmp_path / "o",
                                combinations=["NKM_SC"])
    with pytest.raises(ValueError, match="different images"):
        paired_detection_test({"per_image": [{"image_id": "a", "success": True}]},
                                 {"per_image": [{"image_id": "b", "success": True}]})


def test_detection_benchmark_interrupted_keeps_images_and_fold_models(tmp_path, box_samples,
                                                                      monkeypatch):
    """An SC run (the Table 3 NKM-SC path) stopped mid-fold keeps what it finished: the images
    already detected (results.jsonl) and the trained fold model; the rerun trains only the
    missing folds, detects only the missing images and ends as an uninterrupted run."""
    import dlsr.detection
    import graspsim.eval.offline.detection as gb

    root = write_cornell(box_samples(4), tmp_path / "cornell")
    opts = dict(scale=0.5, split="image", n_folds=2, learner="NKM", encoder="SC",
                n_atoms=8, n_patches=1500, rescore=0, coarse_to_fine=True, n_overlays=0,
                progress=False)
    trained, detected = [], []
    real_train, real_detect = dlsr.detection.train_detector, gb._detect_one

    class Stop(Exception):
        pass

    def spy_train(samples, **kw):
        trained.append(kw["random_state"])
        return real_train(samples, **kw)

    def stop_after_first(det, s, *a):
        if detected:
            raise Stop
        detected.append(s.image_id)
        return real_detect(det, s, *a)

    monkeypatch.setattr(gb, "train_detector", spy_train)
    monkeypatch.setattr(gb, "_detect_one", stop_after_first)
    out = tmp_path / "o"
    with pytest.raises(Stop):
        gb.detection_benchmark(root, "cornell", out, **opts)
    lines = (out / "results.jsonl").read_text().splitlines()
    assert [json.loads(r)["image_id"] for r in lines] == detected  # written before the stop
    # the folds' models are trained first (side by side on the workers), each saved
    assert trained == [0, 1] and len(list((out / "models").glob("*_fold[01].json"))) == 2

    def spy_detect(det, s, *a):
        detected.append(s.image_id)
        return real_detect(det, s, *a)

    monkeypatch.setattr(gb, "_detect_one", spy_detect)
    resumed = gb.detection_benchmark(root, "cornell", out, **opts)
    assert trained == [0, 1]  # the saved models are reused: nothing trained again
    assert len(detected) == len(set(detected)) == 4  # every image once, over both runs
    whole = gb.detection_benchmark(root, "cornell", tmp_path / "whole", **opts)
    assert [(r["image_id"], r["fold"], r["success"]) for r in resumed["per_image"]] == \
        [(r["image_id"], r["fold"], r["success"]) for r in whole["per_image"]]


def test_selftaught_benchmark_adds_its_rows_to_the_table_of_the_same_configuration(
        tmp_path, monkeypatch):
    import graspsim.eval.offline.selftaught as gb
    from dlsr.records import CorruptFileError

    patches = _patch_file(tmp_path / "extra.npz", n=50)
    outcome = {"standard": [True, True, False, False], "selftaught": [True, False, True, True]}

    def fake(data, format, out, learner, encoder, extra_patches, progress, **kw):
        wins = outcome["standard" if extra_patches is None else "selftaught"]
        return {"accuracy": sum(wins) / 4, "baselines": {"random": 0.25},
                "config": {"encoder_param": None},
                "per_image": [{"image_id": f"i{k}", "success": w} for k, w in enumerate(wins)]}

    monkeypatch.setattr(gb, "detection_benchmark", fake)
    out = tmp_path / "o"

    def run(combos, **kw):
        gb.selftaught_benchmark("d", "jacquard", patches, out, combinations=combos,
                                **{"n_atoms": 12, **kw})
        table = json.loads((out / "table3.json").read_text())
        return [(r["combination"], r["selftaught"]) for r in table["rows"]]

    assert run(["NKM-Natural", "GSVQ-ST"]) == [("NKM-Natural", 0.75), ("GSVQ-ST", 0.75)]
    outcome["selftaught"] = [False] * 4
    # one combination later: the other rows stay, its own is added or replaced in place
    assert run(["NKM-SC"]) == [("NKM-Natural", 0.75), ("GSVQ-ST", 0.75), ("NKM-SC", 0.0)]
    assert run(["NKM-Natural"]) == [("NKM-Natural", 0.0), ("GSVQ-ST", 0.75), ("NKM-SC", 0.0)]
    md = (out / "table3.md").read_text()
    assert md.count("| NKM-SC |") == md.count("| GSVQ-ST |") == md.count("| NKM-Natural |") == 1
    # another configuration starts a new table
    assert run(["GSVQ-ST"], n_atoms=20) == [("GSVQ-ST", 0.0)]
    (out / "table3.json").write_text('{"config": {"data": "d"')
    with pytest.raises(CorruptFileError, match="table3.json"):
        run(["GSVQ-ST"], n_atoms=20)
