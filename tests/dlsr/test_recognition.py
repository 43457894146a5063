"""Recognition: features, the Pipeline, nested cross-validation, resume and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sklearn.model_selection import GroupKFold, cross_val_score

from dlsr import recognition as rec
from dlsr.features import (
    ENCODER_GRIDS,
    ENCODERS,
    DLSRFeatures,
    fit_representation,
    pack_images,
    rectangle_features,
    rectangle_features_multi,
)

SMALL = {"n_atoms": 12, "n_patches": 3000}


def _choose_and_test(feats, y_tr, y_te, inner, C_grid):
    """The benchmark's inner choice then outer test, on (training, test) features per
    parameter."""
    choice = rec.inner_choice({param: tr for param, (tr, _) in feats.items()}, y_tr, inner,
                              C_grid)
    Ftr, Fte = feats[choice[1]]
    return rec.outer_test(Ftr, Fte, y_tr, y_te, choice)


def _bar_images(n, vertical, rng):
    """24x24x8 rectangle images with a bright bar across (vertical) or along the crop."""
    img = rng.normal(0, 0.05, size=(n, 24, 24, 8)).astype(np.float32)
    pos = rng.integers(8, 16, size=n)
    for i, p in enumerate(pos):
        if vertical:
            img[i, :, p - 2:p + 2, :] += 1.0
        else:
            img[i, p - 2:p + 2, :, :] += 1.0
    masks = np.ones_like(img, dtype=bool)
    masks[:, :3] = False  # padding rows, as a rectangle with jaw < opening has
    img[~masks] = 0
    return img, masks


@pytest.fixture(scope="module")
def separable():
    rng = np.random.default_rng(0)
    a, ma = _bar_images(60, True, rng)
    b, mb = _bar_images(60, False, rng)
    images = np.concatenate([a, b])
    masks = np.concatenate([ma, mb])
    labels = np.r_[np.ones(60, int), np.zeros(60, int)]
    # 12 images, each with 5 positives and 5 negatives; 6 objects of 2 images each.
    image_ids = np.array([f"img{i % 12}" for i in range(120)], dtype=object)
    object_ids = np.array([f"obj{(i % 12) // 2}" for i in range(120)], dtype=object)
    return rec.RecognitionData(images, masks, labels, image_ids, object_ids)


@pytest.mark.parametrize(("learner", "encoder", "per_atom"), [
    ("NKM", "Natural", 4),   # triangle codes, no polarity split: 4 quadrants x d
    ("NKM", "SC", 8),        # polarity split doubles: 4 x 2d
    ("RP", "ST", 8),
    ("GSVQ", "Natural", 8),
    ("R", "mOMP", 8),
])
def test_feature_dimensions(separable, learner, encoder, per_atom):
    rep = fit_representation(separable.images, separable.masks, learner, random_state=0,
                             **SMALL)
    assert rep.dictionary.shape == (SMALL["n_atoms"], 288)
    param = {"ST": 0.5, "mOMP": 2, "SC": 0.5}.get(encoder)
    polarity = not (learner == "NKM" and encoder == "Natural")
    F = rectangle_features(separable.images[:7], separable.masks[:7], rep, encoder, param,
                           polarity=polarity, chunk_size=3)
    assert F.shape == (7, per_atom * SMALL["n_atoms"])
    assert F.dtype == np.float32 and np.all(np.isfinite(F))


def test_paper_dimensions_for_300_atoms(separable):
    rep = fit_representation(separable.images, separable.masks, "RP", n_atoms=300,
                             n_patches=3000, random_state=0)
    F = rectangle_features(separable.images[:2], separable.masks[:2], rep, "ST", 1.0)
    assert F.shape == (2, 2400)


def test_chunking_does_not_change_features(separable):
    rep = fit_representation(separable.images, separable.masks, "NKM", random_state=1, **SMALL)
    a = rectangle_features(separable.images[:10], separable.masks[:10], rep, "Natural",
                           polarity=False, chunk_size=3)
    b = rectangle_features(separable.images[:10], separable.masks[:10], rep, "Natural",
                           polarity=False, chunk_size=64)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_a_fold_is_learned_from_its_rows_as_from_a_copy_of_them(separable):
    """The CV folds learn from the whole (memory-mapped) set and the fold's rows, not from a
    copy of the fold: the same representation."""
    train = np.flatnonzero(separable.groups("object") != "obj2")[::-1]
    a = fit_representation(separable.images, separable.masks, "NKM", random_state=1,
                           rows=train, **SMALL)
    b = fit_representation(separable.images[train], separable.masks[train], "NKM",
                           random_state=1, **SMALL)
    for x, y in zip(a.to_arrays().values(), b.to_arrays().values(), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)


def test_pipeline_beats_chance_with_group_cv(separable):
    X = pack_images(separable.images, separable.masks)
    model = rec.make_recognition_model("NKM", "Natural", C=1.0, random_state=0, **SMALL)
    scores = cross_val_score(model, X, separable.labels, groups=separable.groups("object"),
                             cv=GroupKFold(3))
    assert scores.mean() > 0.9


def test_nested_cv_beats_chance_and_keeps_folds_clean(separable):
    out = rec.nested_cv_cell(separable, "NKM", "Natural", split="object", n_folds=3,
                             inner_folds=2, random_state=0, **SMALL)
    assert out["accuracy"] > 0.9
    assert len(out["folds"]) == 3
    assert sum(f["n_test"] for f in out["folds"]) == len(separable)
    for f in out["folds"]:
        assert f["C"] in rec.C_GRID


def test_memory_mapped_data_gives_the_same_cross_validation(separable, tmp_path):
    mapped = separable.memory_mapped(tmp_path / "data")
    for name in ("images", "masks"):
        a = getattr(mapped, name)
        assert isinstance(a, np.memmap) and not a.flags.writeable
        assert Path(a.filename) == (tmp_path / "data" / f"{name}.npy").resolve()
        np.testing.assert_array_equal(a, getattr(separable, name))
    assert mapped.labels is separable.labels
    runs = [rec.nested_cv_cell(d, "NKM", "Natural", split="object", n_folds=2, inner_folds=2,
                               random_state=0, n_jobs=2, **SMALL) for d in (separable, mapped)]
    assert runs[0]["accuracy"] == runs[1]["accuracy"]
    for a, b in zip(runs[0]["folds"], runs[1]["folds"], strict=True):
        assert a["predictions"] == b["predictions"]


def test_outer_folds_never_share_a_group(separable):
    for split in ("image", "object"):
        groups = separable.groups(split)
        folds = rec.outer_folds(groups, 3, separable.labels)
        seen = np.zeros(len(groups), int)
        for tr, te in folds:
            assert not set(groups[tr]) & set(groups[te])
            seen[te] += 1
        assert np.all(seen == 1)


def test_too_few_groups_for_the_inner_folds_fails_before_learning(separable, monkeypatch):
    # 6 objects in 3 outer folds leave 4 objects per training fold: 5 inner folds cannot work,
    # and that must be said before any dictionary is learned
    def no_learning(*args, **kwargs):
        raise AssertionError("a representation was fitted before the fold check")

    monkeypatch.setattr(rec, "_fold_representation", no_learning)
    with pytest.raises(ValueError, match="outer training fold 0 holds only 4 objects"):
        rec.nested_cv_cell(separable, "RP", "ST", split="object", n_folds=3, inner_folds=5,
                           **SMALL)


def test_fast_path_equals_refitting_the_pipeline(separable):
    """The factored nested CV predicts what the Pipeline predicts with the chosen parameters."""
    out = rec.nested_cv_cell(separable, "RP", "ST", split="image", n_folds=3, inner_folds=2,
                             random_state=3, **SMALL)
    folds = rec.outer_folds(separable.groups("image"), 3, separable.labels)
    seeds = np.random.SeedSequence(3).generate_state(3)
    X = pack_images(separable.images, separable.masks)
    for k, ((tr, te), f) in enumerate(zip(folds, out["folds"], strict=True)):
        model = rec.make_recognition_model("RP", "ST", encoder_param=f["encoder_param"],
                                           C=f["C"], random_state=int(seeds[k]), **SMALL)
        # fit_representation draws its patch and dictionary seeds from random_state.
        model.fit(X[tr], separable.labels[tr])
        pred = model.predict(X[te])
        assert np.mean(pred == np.asarray(f["predictions"])) >= 0.97


def test_features_transformer_validates(separable):
    X = pack_images(separable.images[:20], separable.masks[:20])
    with pytest.raises(ValueError, match="unknown encoder"):
        DLSRFeatures(encoder="XYZ", **SMALL).fit(X)
    with pytest.raises(ValueError, match="packed rectangle images"):
        DLSRFeatures(**SMALL).fit(np.zeros((4, 10)))


def test_benchmark_saves_each_cell_and_resumes(separable, tmp_path, monkeypatch):
    kw = dict(learners=["NKM", "RP"], encoders=["Natural"], split="image", n_folds=3,
              inner_folds=2, random_state=0, progress=False, **SMALL)
    first = rec.run_recognition_benchmark(separable, tmp_path, **kw)
    lines = (tmp_path / "results.jsonl").read_text().splitlines()
    assert len(lines) == 2
    assert {(c["learner"], c["encoder"]) for c in first["cells"]} == {
        ("NKM", "Natural"), ("RP", "Natural")}
    table = (tmp_path / "table1.md").read_text()
    assert "| NKM |" in table and "| RP |" in table
    # Drop the second cell, as if the run had been killed; the rerun computes only that one.
    (tmp_path / "results.jsonl").write_text(lines[0] + "\n")
    dropped = json.loads(lines[1])["learner"]
    calls, fitted = [], []
    real_fold, real_rep = rec._learner_fold, rec._fold_representation

    def counting(*a, **k):
        calls.append((a[3].learner, tuple(a[4])))
        return real_fold(*a, **k)

    def counting_rep(*a, **k):
        fitted.append(a[2])
        return real_rep(*a, **k)

    monkeypatch.setattr(rec, "_learner_fold", counting)
    monkeypatch.setattr(rec, "_fold_representation", counting_rep)
    # Its folds were saved: the cell is made again from them, nothing is computed.
    assert rec.run_recognition_benchmark(separable, tmp_path, **kw)["cells"] == first["cells"]
    assert calls == [] and fitted == []
    # Without its saved folds, only its three outer folds are computed.
    (tmp_path / "results.jsonl").write_text(lines[0] + "\n")
    for path in (tmp_path / "folds").rglob(f"{dropped}_fold*.json"):
        path.unlink()
    again = rec.run_recognition_benchmark(separable, tmp_path, **kw)
    assert calls == [(dropped, ("Natural",))] * 3  # its three outer folds, nothing else
    assert fitted == []  # the representations saved by the first run are reused
    assert ({(c["learner"], c["accuracy"]) for c in again["cells"]}
            == {(c["learner"], c["accuracy"]) for c in first["cells"]})
    saved = json.loads((tmp_path / "recognition.json").read_text())
    assert len(saved["cells"]) == 2
    # the machine's BLAS (its kernels weigh on the run's time) is recorded with it
    blas = saved["machine"]["blas"]
    assert blas and all(lib["internal_api"] and "architecture" in lib for lib in blas)
    # Another configuration in the same folder does not reuse those cells.
    calls.clear()
    rec.run_recognition_benchmark(separable, tmp_path, **{**kw, "learners": ["NKM"],
                                                          "n_folds": 2})
    assert calls == [("NKM", ("Natural",))] * 2
    assert fitted == ["NKM", "NKM"]


class _Killed(Exception):
    pass


def test_killed_benchmark_resumes_at_the_fold_where_it_stopped(separable, tmp_path,
                                                                monkeypatch):
    kw = dict(learners=["NKM", "RP"], encoders=["Natural", "ST"], split="image", n_folds=3,
              inner_folds=2, random_state=0, progress=False, **SMALL)
    whole = rec.run_recognition_benchmark(separable, tmp_path / "whole", **kw)
    # Kill a run after its fourth (learner, outer fold) task: one learner's cells may be
    # finished, the other learner has folds done and folds to go.
    real_fold = rec._learner_fold
    calls = []

    def killing(*a, **k):
        if len(calls) == 4:
            raise _Killed
        calls.append((a[3].learner, len(a[1])))
        return real_fold(*a, **k)

    monkeypatch.setattr(rec, "_learner_fold", killing)
    with pytest.raises(_Killed):
        rec.run_recognition_benchmark(separable, tmp_path / "killed", **kw)
    saved = sorted(p.name for p in (tmp_path / "killed" / "folds").rglob("*.json"))
    assert len(saved) == 4
    # The rerun computes only the two folds not saved, and every cell is the whole run's.
    calls.clear()
    monkeypatch.setattr(rec, "_learner_fold", lambda *a, **k: (
        calls.append(a[3].learner), real_fold(*a, **k))[1])
    again = rec.run_recognition_benchmark(separable, tmp_path / "killed", **kw)
    assert len(calls) == 6 - 4
    key = lambda c: (c["learner"], c["encoder"])  # noqa: E731
    assert sorted(map(key, again["cells"])) == sorted(map(key, whole["cells"]))
    by_cell = {key(c): c for c in whole["cells"]}
    for cell in again["cells"]:
        ref = by_cell[key(cell)]
        assert cell["accuracy"] == ref["accuracy"]
        assert [f["encoder_param"] for f in cell["folds"]] == [
            f["encoder_param"] for f in ref["folds"]]
        assert [f["C"] for f in cell["folds"]] == [f["C"] for f in ref["folds"]]
    # A fold saved for other encoders is computed again, not reused without them.
    folds_dir = next((tmp_path / "killed" / "folds").iterdir())
    assert rec.saved_fold(folds_dir, "NKM", 0, ["Natural"]) is not None
    assert rec.saved_fold(folds_dir, "NKM", 0, ["Natural", "SC"]) is None
    # A damaged fold file is an error naming it, not a crash deep in json.
    (folds_dir / "NKM_fold0.json").write_text("{not json")
    with pytest.raises(ValueError, match="NKM_fold0.json"):
        rec.saved_fold(folds_dir, "NKM", 0, ["Natural"])


def test_progress_counts_folds_and_cells(separable, tmp_path):
    import io

    from tqdm.auto import tqdm

    text = io.StringIO()
    bar = tqdm(total=6, file=text)
    state = rec._Progress(bar, n_cells=4, cells_done=1)
    state.config = "d=12"
    state.fold("NKM", 0)
    state.cell("NKM", "Natural")
    assert bar.n == 1
    assert state.cells_done == 2
    assert state.last == "NKM fold 1 d=12"
    bar.close()
    assert "cells 2/4, NKM fold 1 d=12" in text.getvalue()


def test_figure5_points_are_cells_that_resume_and_reuse_the_table(separable, tmp_path,
                                                                   monkeypatch):
    combos = (("NKM", "Natural"), ("RP", "Natural"))
    monkeypatch.setattr(rec, "FIGURE5_COMBINATIONS", combos)
    calls = []
    real_fold = rec._learner_fold

    def counting(*a, **k):
        rep = a[3]
        calls.append((rep.learner, rep.dictionary.shape[0], rep.zca_matrix is not None))
        return real_fold(*a, **k)

    monkeypatch.setattr(rec, "_learner_fold", counting)
    kw = dict(learners=["NKM"], encoders=["Natural"], split="image", n_folds=2, inner_folds=2,
              random_state=0, progress=False, figure5_sizes=(6, 12), **SMALL)
    first = rec.run_recognition_benchmark(separable, tmp_path, **kw)
    points = {(p["learner"], p["encoder"], p["n_atoms"], p["whiten"]): p
              for p in first["figure5"]}
    assert set(points) == {(lrn, enc, d, w) for lrn, enc in combos for d in (6, 12)
                           for w in (True, False)}
    # the table's cell (12 atoms, whitened) is the figure's point, computed once
    table_cell = first["cells"][0]
    assert points[("NKM", "Natural", 12, True)]["accuracy"] == table_cell["accuracy"]
    assert points[("NKM", "Natural", 12, True)]["config_key"] == first["key"]
    assert calls.count(("NKM", 12, True)) == 2
    assert calls.count(("NKM", 12, False)) == 2 and calls.count(("RP", 6, False)) == 2
    assert len(calls) == 2 * 8  # eight (learner, size, whitening) configurations, 2 folds
    assert points[("NKM", "Natural", 6, False)]["config_key"] != points[
        ("NKM", "Natural", 6, True)]["config_key"]
    assert (tmp_path / "figure5.png").stat().st_size > 0
    md = (tmp_path / "figure5.md").read_text()
    assert "| NKM-Natural | no |" in md and "d = 6" in md and "d = 12" in md
    saved = json.loads((tmp_path / "recognition.json").read_text())
    assert len(saved["figure5"]) == 8
    # a rerun computes nothing and gives the same points
    calls.clear()
    again = rec.run_recognition_benchmark(separable, tmp_path, **kw)
    assert calls == []
    assert again["figure5"] == first["figure5"]
    assert again["cpu_seconds_this_run"] == 0.0
    # sizes in another order, one repeated: the same points, once each
    shuffled = rec.run_recognition_benchmark(separable, tmp_path,
                                             **{**kw, "figure5_sizes": (12, 6, 12)})
    assert calls == [] and len(shuffled["figure5"]) == 8
    with pytest.raises(ValueError, match="sizes must be positive"):
        rec.run_recognition_benchmark(separable, tmp_path, **{**kw, "figure5_sizes": (0, 6)})


def test_cells_together_equal_cells_alone(separable):
    """Scheduling several cells together, sharing a learner's codes, changes no cell's result."""
    kw = dict(split="image", n_folds=3, inner_folds=2, random_state=0, **SMALL)
    together = list(rec.nested_cv_cells(separable, [("RP", "ST"), ("NKM", "Natural"),
                                                    ("RP", "Natural")], n_jobs=2, **kw))
    # a learner's cells come out together, in the order given (learners as they finish)
    got = [(c["learner"], c["encoder"]) for c in together]
    assert got in ([("RP", "ST"), ("RP", "Natural"), ("NKM", "Natural")],
                   [("NKM", "Natural"), ("RP", "ST"), ("RP", "Natural")])
    for cell in together:
        alone = rec.nested_cv_cell(separable, cell["learner"], cell["encoder"], **kw)
        assert cell["accuracy"] == alone["accuracy"]
        assert [f["predictions"] for f in cell["folds"]] == [
            f["predictions"] for f in alone["folds"]]
        assert [f["encoder_param"] for f in cell["folds"]] == [
            f["encoder_param"] for f in alone["folds"]]
    # a learner's representation cost is charged once, to its first cell
    rp = [c for c in together if c["learner"] == "RP"]
    assert rp[0]["representation_cpu_seconds"] > 0 and rp[1]["representation_cpu_seconds"] == 0
    assert all(f["cpu_seconds"] > 0 for c in together for f in c["folds"])


def test_a_subset_of_rectangles_is_the_same_draw_from_all_of_them(box_samples):
    """``max_rectangles`` draws from all the labelled rectangles and computes only their
    images: the same data as taking those rows of the whole set."""
    samples = box_samples(4)
    full = rec.recognition_data(samples, random_state=3)
    k = len(full) // 2
    sub = rec.recognition_data(samples, random_state=3, max_rectangles=k, subset_random_state=7)
    idx = np.sort(np.random.default_rng(7).choice(len(full), k, replace=False))
    assert len(sub) == k and len(set(sub.image_ids)) > 1
    for field in ("images", "masks", "labels", "image_ids", "object_ids"):
        np.testing.assert_array_equal(getattr(sub, field), getattr(full, field)[idx])
    everything = rec.recognition_data(samples, random_state=3, max_rectangles=10 * len(full))
    np.testing.assert_array_equal(everything.images, full.images)
    with pytest.raises(ValueError, match="max_rectangles"):
        rec.recognition_data(samples, max_rectangles=0)


def test_bad_input_is_a_clear_error(separable):
    one_class = rec.RecognitionData(separable.images[:60], separable.masks[:60],
                                    separable.labels[:60], separable.image_ids[:60],
                                    separable.object_ids[:60])
    with pytest.raises(ValueError, match="only class"):
        rec.run_recognition_benchmark(one_class, "unused", learners=["NKM"],
                                      encoders=["Natural"], progress=False)
    with pytest.raises(ValueError, match="at least 50 groups"):
        rec.nested_cv_cell(separable, "NKM", "Natural", n_folds=50, **SMALL)
    with pytest.raises(ValueError, match="unknown learner"):
        rec.nested_cv_cell(separable, "KSVD", "Natural")
    no_objects = rec.RecognitionData(separable.images, separable.masks, separable.labels,
                                     separable.image_ids,
                                     np.array([None] * len(separable), dtype=object))
    with pytest.raises(ValueError, match="object id"):
        no_objects.groups("object")
    with pytest.raises(ValueError, match="no labelled rectangles"):
        rec.recognition_data([])


def test_inner_cv_fits_all_C_of_a_fold_at_once(monkeypatch):
    """One standardiser and one solver call per (parameter, inner fold), same choice as fitting
    ``SquaredHingeSVC`` per (parameter, C, inner fold); ties go to the earlier candidate."""
    from dlsr.svm import FeatureStandardizer, SquaredHingeSVC

    rng = np.random.default_rng(0)
    n_tr, n_te, d = 150, 50, 30
    y = (rng.random(n_tr + n_te) < 0.5).astype(int)

    def features(signal):
        F = rng.normal(size=(n_tr + n_te, d)).astype(np.float32)
        F[:, :3] += signal * (2 * y[:, None] - 1)
        return F[:n_tr], F[n_tr:]
    same = features(0.3)
    feats = {0.5: same, 1.0: same, 2.0: features(0.0)}  # 0.5 and 1.0 tie, 2.0 is noise
    y_tr, y_te = y[:n_tr], y[n_tr:]
    inner = rec.outer_folds(np.arange(n_tr) % 10, 3)
    C_grid = (1.0, 10.0)
    calls = []
    real_fit = rec.squared_hinge_fit

    def counting(X, y_pm, Cs, **kw):
        calls.append(list(Cs))
        return real_fit(X, y_pm, Cs, **kw)

    monkeypatch.setattr(rec, "squared_hinge_fit", counting)
    out = _choose_and_test(feats, y_tr, y_te, inner, C_grid)
    assert calls == [list(C_grid)] * (len(feats) * len(inner)) + [[out["C"]]]
    # the reference: one estimator per (parameter, C, inner fold), as the benchmark did
    best = None
    for param, (Ftr, _) in feats.items():
        for C in C_grid:
            accs = []
            for itr, iva in inner:
                scaler = FeatureStandardizer().fit(Ftr[itr])
                svm = SquaredHingeSVC(C=C).fit(scaler.transform(Ftr[itr]), y_tr[itr])
                accs.append(np.mean(svm.predict(scaler.transform(Ftr[iva])) == y_tr[iva]))
            if best is None or np.mean(accs) > best[0] + 1e-12:
                best = (float(np.mean(accs)), param, C)
    assert (out["inner_accuracy"], out["encoder_param"], out["C"]) == best
    assert out["encoder_param"] == 0.5  # ties with 1.0, and comes first
    Ftr, Fte = feats[best[1]]
    scaler = FeatureStandardizer().fit(Ftr)
    svm = SquaredHingeSVC(C=best[2]).fit(scaler.transform(Ftr), y_tr)
    pred = svm.predict(scaler.transform(Fte))
    assert out["predictions"] == pred.tolist()
    assert out["accuracy"] == np.mean(pred == y_te) and out["n_test"] == n_te


@pytest.mark.parametrize("learner", ["SC", "OMP"])
def test_test_fold_encoded_at_the_chosen_parameters_only_gives_the_grids_results(separable,
                                                                                  learner):
    """The outer test fold is encoded for the chosen parameters only; the results are exactly
    those of encoding it over the whole grids (the lasso and OMP paths record solutions
    without changing course)."""
    groups = separable.groups("image")
    train, test = rec.outer_folds(groups, 3, separable.labels)[0]
    rep = fit_representation(separable.images[train], separable.masks[train], learner,
                             random_state=0, **SMALL)
    got = rec._learner_fold(separable, train, test, rep, list(ENCODERS), groups, 2, rec.C_GRID)
    grids = {enc: ENCODER_GRIDS[enc] for enc in ENCODERS}
    both = np.r_[train, test]
    F = rectangle_features_multi(separable.images[both], separable.masks[both], rep, grids)
    inner = rec.outer_folds(groups[train], 2)
    y_tr, y_te = separable.labels[train], separable.labels[test]
    for enc in ENCODERS:
        feats = {p: (A[: len(train)], A[len(train):]) for p, A in zip(grids[enc], F[enc],
                                                                    strict=True)}
        want = _choose_and_test(feats, y_tr, y_te, inner, rec.C_GRID)
        for key in ("encoder_param", "C", "inner_accuracy", "predictions", "accuracy"):
            assert got[enc][key] == want[key], (enc, key)



def test_encoders_sharing_features_run_one_inner_cv_and_one_refit(separable, monkeypatch):
    """SC-Natural reads the SC lasso codes at the dictionary's penalty: the same feature
    arrays, so its inner CV and refit are SC's at that penalty, run once. Its record is the
    one it gets alone."""
    groups = separable.groups("image")
    train, test = rec.outer_folds(groups, 3, separable.labels)[0]
    rep = fit_representation(separable.images[train], separable.masks[train], "SC",
                             random_state=0, **SMALL)
    assert rep.natural_param in ENCODER_GRIDS["SC"]
    calls, fits = [], []
    real_scores, real_fit = rec._inner_scores, rec._fit_svms

    def scores(Ftr, *a):
        calls.append(id(Ftr))
        return real_scores(Ftr, *a)

    def fit(F, y, C_grid, start=None):
        fits.append(start is not None)
        return real_fit(F, y, C_grid, start=start)

    monkeypatch.setattr(rec, "_inner_scores", scores)
    monkeypatch.setattr(rec, "_fit_svms", fit)
    both = rec._learner_fold(separable, train, test, rep, ["SC", "Natural"], groups, 2,
                             rec.C_GRID)
    assert len(calls) == len(set(calls)) == len(ENCODER_GRIDS["SC"])  # Natural's: a repeat
    # every inner fold but the first starts from its neighbour; refits from the last fold
    per_param = [False, True]
    assert fits[:8] == per_param * 4
    calls.clear()
    alone = rec._learner_fold(separable, train, test, rep, ["Natural"], groups, 2, rec.C_GRID)
    assert len(calls) == 1
    for key in ("encoder_param", "C", "inner_accuracy", "predictions", "accuracy"):
        assert both["Natural"][key] == alone["Natural"][key], key
    if both["SC"]["encoder_param"] == rep.natural_param and both["SC"]["C"] == \
            both["Natural"]["C"]:
        assert both["SC"]["predictions"] == both["Natural"]["predictions"]


def test_cells_run_on_the_callers_joblib_backend_with_the_same_results(separable):
    """With ``n_jobs=None`` the (learner, outer fold) tasks go to the active joblib
    configuration (what an executor's ``activate`` sets: local processes here, Ray alike);
    every cell is the same as in one process."""
    from joblib import parallel_config

    kw = dict(split="image", n_folds=3, inner_folds=2, random_state=0, **SMALL)
    cells = [("NKM", "ST"), ("GSVQ", "Natural")]
    alone = list(rec.nested_cv_cells(separable, cells, n_jobs=1, **kw))
    with parallel_config(backend="loky", n_jobs=2):
        pooled = list(rec.nested_cv_cells(separable, cells, n_jobs=None, **kw))
    by = {(c["learner"], c["encoder"]): c for c in pooled}
    for cell in alone:
        other = by[(cell["learner"], cell["encoder"])]
        for key in ("encoder_param", "C", "inner_accuracy", "predictions", "accuracy"):
            assert [f[key] for f in cell["folds"]] == [f[key] for f in other["folds"]], key
