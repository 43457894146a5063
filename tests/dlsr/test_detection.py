"""Grasp detection: candidates, exact and dense scores, persistence, bad input."""

from __future__ import annotations

import dataclasses
import logging

import cv2
import numpy as np
import pytest

from dlsr import patches, whitening
from dlsr.detection import (
    DenseDetector,
    DLSRDetector,
    ExactGridDetector,
    SearchGrid,
    enumerate_candidates,
    jaws_clear,
    object_region,
    opening_widths,
    table_plane_mask,
)
from dlsr.detection.dense import _PatchScorer, window_statistics
from dlsr.features import Representation, rectangle_features
from dlsr.metrics import rectangle_metric, rectangle_metric_many
from dlsr.preprocess import rectangle_images
from dlsr.rectangles import GraspRectangle, corners_from_array
from dlsr.svm import FeatureStandardizer, SquaredHingeSVC

H, W = 120, 160
SMALL_GRID = SearchGrid(angles_deg=(0, 45, 90, 135), openings=(20, 30, 40), jaws=(10, 20),
                        step=6.0, dilate=8)


def _scene(seed=0, bar=True):
    """A textured tilted table with a raised, red bar (long axis along x) in the middle."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    noise = cv2.GaussianBlur(rng.random((H, W, 3)).astype(np.float32), (0, 0), 2.0)
    rgb = 90 + 120 * noise + 20 * np.sin(xx / 9.0)[..., None]
    depth = (0.8 + 0.0004 * xx + 0.0002 * yy).astype(np.float32)
    mask = np.zeros((H, W), bool)
    if bar:
        mask[52:68, 40:120] = True
        depth[mask] -= 0.03
        rgb[mask] = rgb[mask] * 0.3 + np.array([200.0, 30.0, 30.0]) * 0.7
    return {"rgb": np.clip(rgb, 0, 255).astype(np.uint8), "depth": depth,
            "depth_valid": np.ones((H, W), bool), "mask": mask}


def _model(images, masks, labels, n_atoms=24, seed=0, C=1.0):
    """A small NKM-Natural model: centroids are random whitened training patches."""
    X, M = patches.extract_patches(images, masks, 6)
    X, M = X.reshape(-1, 288), M.reshape(-1, 288)
    Xs = whitening.standardize_patches(X, M)
    mean, P = whitening.fit_zca(Xs, M)
    Xw = whitening.apply_zca(Xs, M, mean, P)
    rng = np.random.default_rng(seed)
    full = np.flatnonzero(M.all(1))
    cents = Xw[rng.choice(full, n_atoms, replace=False)].astype(np.float32)
    D = cents / np.maximum(np.linalg.norm(cents, axis=1, keepdims=True), 1e-9)
    rep = Representation("NKM", D, cents, mean, P, None)
    F = rectangle_features(images, masks, rep, "Natural", None, polarity=False)
    scaler = FeatureStandardizer().fit(F)
    svm = SquaredHingeSVC(C=C).fit(scaler.transform(F), labels)
    return DLSRDetector(rep, "Natural", None, False, scaler.mean_, scaler.scale_,
                        np.asarray(svm.coef_[0]), float(svm.intercept_[0]))


def _random_model(obs, seed=0):
    rng = np.random.default_rng(seed)
    R = np.column_stack([rng.uniform(40, 120, 60), rng.uniform(40, 80, 60),
                         rng.uniform(-1.5, 1.5, 60), np.full(60, 30.0), np.full(60, 20.0)])
    im, mk = rectangle_images(obs["rgb"], obs["depth"], obs["depth_valid"], R)
    return _model(im, mk, (np.arange(60) % 2), seed=seed)


def _bar_training(obs, rng):
    """Positives across the bar; negatives: grid candidates that fail the rectangle metric."""
    pos = []
    for x in np.arange(50, 112, 4.0):
        for w, h in ((30, 10), (30, 20), (40, 10), (40, 20)):
            pos.append((x + rng.uniform(-1, 1), 60 + rng.uniform(-1, 1),
                        np.pi / 2 + rng.uniform(-0.2, 0.2), w, h))
    pos = np.array(pos)
    cand = enumerate_candidates(obs["mask"], SMALL_GRID)
    cand = cand[~rectangle_metric_many(cand, pos)]
    neg = cand[rng.choice(len(cand), min(len(cand), 2 * len(pos)), replace=False)]
    rects = np.concatenate([pos, neg])
    labels = np.r_[np.ones(len(pos), int), np.zeros(len(neg), int)]
    im, mk = rectangle_images(obs["rgb"], obs["depth"], obs["depth_valid"], rects)
    return pos, im, mk, labels


# ------------------------------------------------------------------------------------------
# candidates and region


def test_enumerate_candidates_respects_the_grid_coverage_and_image():
    region = np.zeros((H, W), bool)
    region[50:70, 60:100] = True
    grid = SearchGrid(dilate=5)
    cand = enumerate_candidates(region, grid)
    assert len(cand) > 0
    assert np.all(cand[:, 3] >= cand[:, 4])
    assert set(np.round(np.degrees(cand[:, 2]) % 180).astype(int)) <= set(range(0, 180, 15))
    assert set(cand[:, 3]) <= set(range(10, 100, 10))
    assert np.all(cand[:, 0] % 10 == 0) and np.all(cand[:, 1] % 10 == 0)
    corners = corners_from_array(cand)
    assert corners[..., 0].min() >= 0 and corners[..., 0].max() <= W - 1
    assert corners[..., 1].min() >= 0 and corners[..., 1].max() <= H - 1
    # coverage: every candidate has >= 50 % of its area (sampled) on the dilated region
    dil = cv2.dilate(region.astype(np.uint8), cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (11, 11))).astype(bool)
    u = np.linspace(-0.45, 0.45, 10)
    for x, y, t, w, h in cand[:: max(1, len(cand) // 200)]:
        a, b = np.meshgrid(u * w, u * h)
        px = x + a * np.cos(t) + b * np.sin(t)
        py = y - a * np.sin(t) + b * np.cos(t)
        frac = dil[np.clip(np.rint(py).astype(int), 0, H - 1),
                   np.clip(np.rint(px).astype(int), 0, W - 1)].mean()
        assert frac >= 0.35
    # a big rectangle far from the region is never a candidate
    assert not np.any(np.abs(cand[:, 1] - 60) > 60)


def test_empty_region_gives_no_candidates():
    assert enumerate_candidates(np.zeros((H, W), bool)).shape == (0, 5)


def test_table_plane_mask_finds_the_raised_object():
    obs = _scene()
    found = table_plane_mask(obs["depth"], obs["depth_valid"])
    inter = (found & obs["mask"]).sum()
    assert inter / obs["mask"].sum() > 0.9
    assert (found & ~obs["mask"]).sum() < 0.05 * obs["mask"].sum()
    region, how = object_region({k: v for k, v in obs.items() if k != "mask"})
    assert how == "depth" and (region & obs["mask"]).sum() > 0.9 * obs["mask"].sum()
    region, how = object_region(obs)
    assert how == "mask"


def _range_scene(seed=0, holes=True):
    """A Kinect-like range image (the distance to the camera, as Cornell's depth files: not
    ``z``) of a table tilted 40 degrees, a 2 cm box on it, a board standing on its far edge, the
    floor 0.7 m below beyond its right edge; 2 mm noise, 5 % missing pixels and round holes."""
    rng = np.random.default_rng(seed)
    Hs, Ws, f = 240, 320, 262.5  # a 640x480 Kinect at half size
    v, u = np.mgrid[0:Hs, 0:Ws]
    x, y = (u - (Ws - 1) / 2) / f, (v - (Hs - 1) / 2) / f
    a = np.radians(40)
    n = np.array([0.1, -np.cos(a), -np.sin(a)])
    n /= np.linalg.norm(n)

    def plane_z(d):  # z of the plane n . P = d along each pixel's ray
        return d / (n[0] * x + n[1] * y + n[2])

    z = plane_z(-0.9)
    floor = u > 0.8 * Ws
    z[floor] = plane_z(-1.6)[floor]
    board = v < 0.15 * Hs
    z[board] = np.minimum(z[board], np.percentile(z[~board & ~floor], 95))
    box = (np.abs(u - 0.45 * Ws) < 0.12 * Ws) & (np.abs(v - 0.55 * Hs) < 0.05 * Hs)
    z[box] = plane_z(-0.88)[box]
    r = z * np.sqrt(1 + x ** 2 + y ** 2) + rng.normal(0, 0.002, (Hs, Ws))
    valid = np.ones((Hs, Ws), np.uint8)
    if holes:
        valid[rng.random((Hs, Ws)) < 0.05] = 0
        for _ in range(10):
            cv2.circle(valid, (int(rng.integers(0, Ws)), int(rng.integers(0, Hs))),
                       int(rng.integers(2, 8)), 0, -1)
    valid = valid.astype(bool)
    return np.where(valid, r, 0).astype(np.float32), valid, box


@pytest.mark.parametrize("seed,holes", [(0, True), (1, False)])
def test_table_plane_mask_finds_the_object_in_a_range_image(seed, holes):
    # a plane in 1/z alone missed the box here (the table is curved in 1/range by centimetres)
    depth, valid, box = _range_scene(seed, holes)
    found = table_plane_mask(depth, valid)
    assert (found & box).sum() > 0.9 * box.sum()
    assert (found & ~box).sum() < 0.1 * box.sum()  # not the board, not the floor


def test_table_plane_mask_rejects_a_bad_degree():
    depth, valid, _ = _range_scene()
    with pytest.raises(ValueError, match="degree"):
        table_plane_mask(depth, valid, degree=0)


def test_jaws_clear_needs_the_opening_to_span_the_object():
    region = np.zeros((H, W), bool)
    region[50:70, 40:120] = True  # a bar 20 px thick, long axis along x
    up = np.pi / 2  # closing along y, across the bar
    rects = np.array([
        [80, 60, up, 40, 20],    # across, jaws beside the bar: passes
        [80, 60, up, 16, 20],    # across, narrower than the bar: jaws on it
        [80, 60, 0.0, 40, 20],   # along the bar: jaws on it
        [80, 80, up, 40, 20],    # centre off the bar
        [80, 60, up, 22, 20],    # jaws 1 px from the bar: within the clearance
    ], dtype=float)
    assert jaws_clear(region, rects).tolist() == [True, False, False, False, False]
    assert jaws_clear(region, rects, clearance=0)[4]
    with pytest.raises(ValueError, match="n_samples"):
        jaws_clear(region, rects, n_samples=2)


def test_clear_jaws_grid_keeps_the_candidates_whose_jaws_are_clear():
    region = np.zeros((H, W), bool)
    region[50:70, 40:120] = True
    grid = SearchGrid(dilate=5)
    every = enumerate_candidates(region, grid)
    clear = enumerate_candidates(region, dataclasses.replace(grid, clear_jaws=True))
    assert 0 < len(clear) < len(every)
    assert jaws_clear(region, clear).all()
    assert {tuple(r) for r in clear} <= {tuple(r) for r in every}
    across = np.abs(np.abs(clear[:, 2]) - np.pi / 2) < 1e-6
    assert across.any() and np.all(clear[across, 3] > 20)  # the opening spans the 20 px bar


def test_search_grid_round_trips_clear_jaws():
    grid = SearchGrid(openings=(30, 40), clear_jaws=True)
    assert SearchGrid.from_dict(grid.to_dict()) == grid
    old = grid.to_dict()
    del old["clear_jaws"]  # a model saved before the option: the paper's search
    assert SearchGrid.from_dict(old).clear_jaws is False


def test_opening_widths_measure_the_opening_at_the_depth_under_the_centre():
    f = 200.0
    obs = {"depth": np.full((H, W), 0.8, np.float32), "depth_valid": np.ones((H, W), bool),
           "K": np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])}
    obs["depth"][40:80, 60:100] = 0.6
    obs["depth_valid"][10, 10] = False  # a hole: the region's (else the image's) median depth
    rects = np.array([[80, 60, 0.0, 40, 10], [20, 20, np.pi / 2, 40, 10],
                      [10, 10, 0.3, 40, 10]])
    widths = opening_widths(obs, rects)
    np.testing.assert_allclose(widths[:2], [40 * 0.6 / f, 40 * 0.8 / f], rtol=1e-6)
    region = np.zeros((H, W), bool)
    region[40:80, 60:100] = True
    assert opening_widths(obs, rects[2:], region)[0] == pytest.approx(40 * 0.6 / f, rel=1e-6)
    # Non-square pixels: the closing direction's own focal length.
    obs2 = dict(obs, K=np.array([[f, 0, W / 2], [0, 2 * f, H / 2], [0, 0, 1.0]]))
    assert opening_widths(obs2, rects[1:2])[0] == pytest.approx(40 * 0.8 / (2 * f), rel=1e-6)
    with pytest.raises(ValueError, match="'K'"):
        opening_widths({k: v for k, v in obs.items() if k != "K"}, rects)
    with pytest.raises(ValueError, match="camera matrix"):
        opening_widths(dict(obs, K=np.zeros((3, 3))), rects)


def test_max_width_grid_drops_the_openings_a_gripper_cannot_reach(bar_model):
    model, _ = bar_model
    obs = dict(_scene(seed=3), K=np.array([[400.0, 0, W / 2], [0, 400.0, H / 2], [0, 0, 1]]))
    det = ExactGridDetector(model, grid=SMALL_GRID)
    every, _ = det.candidates(obs)
    det.grid = dataclasses.replace(SMALL_GRID, max_width=0.06)  # 30 px at 0.77 m is 0.058 m
    kept, reason = det.candidates(obs)
    assert reason is None and 0 < len(kept) < len(every)
    assert kept[:, 3].max() <= 30 and every[:, 3].max() == 40
    assert {tuple(r) for r in kept} <= {tuple(r) for r in every}
    dense = DenseDetector(model, grid=det.grid, rescore=10, top_k=50, coarse_to_fine=True,
                          coarse_grid=dataclasses.replace(SMALL_GRID, step=12.0))
    assert dense.detect(obs).rects[:, 3].max() <= 30
    det.grid = dataclasses.replace(SMALL_GRID, max_width=0.01)
    kept, reason = det.candidates(obs)
    assert len(kept) == 0 and "at most 0.01 m" in reason
    with pytest.raises(ValueError, match="'K'"):
        ExactGridDetector(model, grid=det.grid).candidates(_scene(seed=3))


def test_search_grid_round_trips_max_width():
    grid = SearchGrid(openings=(30, 40), max_width=0.08)
    assert SearchGrid.from_dict(grid.to_dict()) == grid
    old = grid.to_dict()
    del old["max_width"]  # a model saved before the option: every size
    assert SearchGrid.from_dict(old).max_width is None


def test_background_subtraction_region():
    obs = _scene()
    bg = _scene(bar=False)["rgb"]
    region, how = object_region(obs, background=bg)
    assert how == "background"
    assert (region & obs["mask"]).sum() > 0.8 * obs["mask"].sum()


# ------------------------------------------------------------------------------------------
# scores


def test_quadrant_weights_fold_the_standardisation_and_svm():
    obs = _scene()
    model = _random_model(obs)
    R = np.array([[80.0, 60.0, 0.3, 40.0, 20.0], [70.0, 55.0, -1.0, 30.0, 30.0]])
    im, mk = rectangle_images(obs["rgb"], obs["depth"], obs["depth_valid"], R)
    F = model.features(im, mk).astype(np.float64)
    V, const = model.quadrant_weights()
    k = model.n_codes
    folded = const + sum(F[:, q * k:(q + 1) * k] @ V[:, q] for q in range(4))
    np.testing.assert_allclose(model.image_scores(im, mk), folded, rtol=1e-4, atol=1e-4)


def test_dense_scores_equal_exact_scores_without_padding():
    """Candidates on the canvas grid (90-degree angles, half-pixel centres, w = h = 24): the
    dense score is the exact score up to float rounding."""
    obs = _scene(bar=False)
    model = _random_model(obs)
    cand = np.array([(x, y, t, 24.0, 24.0) for t in (0.0, -np.pi / 2)
                     for x in np.arange(20.5, 140, 13) for y in np.arange(20.5, 100, 11)])
    exact = model.rectangle_scores(obs, cand)
    dense = DenseDetector(model).score(obs, cand)
    scale = np.abs(exact).mean() + 1.0
    np.testing.assert_allclose(dense, exact, rtol=0, atol=1e-4 * scale)


def test_dense_scores_track_exact_scores_in_general():
    obs = _scene()
    model = _random_model(obs)
    rng = np.random.default_rng(1)
    n = 120
    cand = np.column_stack([rng.uniform(45, 115, n), rng.uniform(45, 75, n),
                            rng.uniform(-np.pi / 2, np.pi / 2, n), rng.choice([20.0, 30.0], n),
                            np.zeros(n)])
    cand[:, 4] = cand[:, 3]
    exact = model.rectangle_scores(obs, cand)
    dense = DenseDetector(model).score(obs, cand)
    assert np.corrcoef(exact, dense)[0, 1] > 0.9


# ------------------------------------------------------------------------------------------
# detectors


@pytest.fixture(scope="module")
def bar_model():
    obs = _scene()
    rng = np.random.default_rng(0)
    pos, im, mk, labels = _bar_training(obs, rng)
    return _model(im, mk, labels, n_atoms=32), pos


def test_detectors_find_the_grasp_on_a_separable_fixture(bar_model):
    model, pos = bar_model
    obs = _scene(seed=3)  # same layout, new texture
    truths = [GraspRectangle(x, 60.0, np.pi / 2, w, h) for x in range(50, 112, 6)
              for w, h in ((30, 10), (40, 20))]
    for det in (DenseDetector(model, grid=SMALL_GRID, rescore=50, top_k=3),
                ExactGridDetector(model, grid=SMALL_GRID, top_k=3)):
        d = det.detect(obs)
        assert d.reason is None and len(d.rects) == 3
        assert np.all(np.diff(d.scores) <= 1e-12)  # best first
        rects = d.rectangles() if isinstance(det, ExactGridDetector) else det.predict(obs)
        assert all(isinstance(r, GraspRectangle) for r in rects)
        assert rectangle_metric(rects[0], truths), (type(det).__name__, rects[0])


def test_coarse_to_fine_finds_the_grasp(bar_model):
    model, _ = bar_model
    obs = _scene(seed=4)
    truths = [GraspRectangle(x, 60.0, np.pi / 2, 30, 15) for x in range(50, 112, 6)]
    coarse = SearchGrid(angles_deg=(0, 90), openings=(20, 40), jaws=(10, 20), step=12.0,
                        dilate=8)
    det = DenseDetector(model, grid=SMALL_GRID, coarse_to_fine=True, coarse_grid=coarse,
                        rescore=20)
    rects = det.predict(obs)
    assert rects and rectangle_metric(rects[0], truths)


def test_save_load_round_trip_gives_identical_predictions(bar_model, tmp_path):
    model, _ = bar_model
    model.config.update(grid=SMALL_GRID.to_dict(), rescore=30, top_k=4)
    paths = model.save(tmp_path / "model")
    assert {p.suffix for p in paths} == {".npz", ".json"}
    loaded = DLSRDetector.load(tmp_path / "model.json")
    obs = _scene(seed=5)
    a = model.detector("dense").detect(obs)
    b = loaded.detector("dense").detect(obs)
    np.testing.assert_array_equal(a.rects, b.rects)
    np.testing.assert_array_equal(a.scores, b.scores)
    assert len(loaded.predict(obs)) == 4
    with np.load(tmp_path / "model.npz", allow_pickle=False) as z:  # no pickled objects
        assert "coef" in z.files


def test_load_reports_missing_and_foreign_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="model"):
        DLSRDetector.load(tmp_path / "absent")
    (tmp_path / "x.json").write_text('{"format": "other"}')
    np.savez(tmp_path / "x.npz", a=np.zeros(1))
    with pytest.raises(ValueError, match="not a DLSR detector"):
        DLSRDetector.load(tmp_path / "x")


@pytest.mark.parametrize("kind", ["dense", "exact"])
def test_all_masked_depth_gives_an_empty_result_with_a_reason(bar_model, kind, caplog):
    model, _ = bar_model
    obs = _scene()
    obs["depth_valid"] = np.zeros((H, W), bool)
    with caplog.at_level(logging.WARNING, logger="dlsr.detection"):
        d = model.detector(kind, grid=SMALL_GRID).detect(obs)
    assert len(d.rects) == 0 and "no valid pixel" in d.reason
    assert "no valid pixel" in caplog.text


@pytest.mark.parametrize("kind", ["dense", "exact"])
def test_empty_object_region_gives_an_empty_result_with_a_reason(bar_model, kind, caplog):
    model, _ = bar_model
    obs = _scene()
    obs["mask"] = np.zeros((H, W), bool)
    with caplog.at_level(logging.WARNING, logger="dlsr.detection"):
        rects = model.detector(kind, grid=SMALL_GRID).predict(obs)
    assert rects == [] and "empty object region" in caplog.text


def test_bad_observation_raises_a_clear_error(bar_model):
    model, _ = bar_model
    with pytest.raises(ValueError, match="do not match"):
        model.detector("dense").predict({"rgb": np.zeros((10, 10, 3), np.uint8),
                                         "depth": np.ones((8, 8), np.float32)})


def _variant_model(obs, kind, seed=0):
    """Models whose patch scores take each path of the dense scorer: NKM-Natural with and
    without whitening (triangle kernels), soft threshold with polarity (generic path)."""
    if kind == "nkm":
        return _random_model(obs, seed)
    rng = np.random.default_rng(seed)
    R = np.column_stack([rng.uniform(40, 120, 30), rng.uniform(40, 80, 30),
                         rng.uniform(-1.5, 1.5, 30), np.full(30, 30.0), np.full(30, 20.0)])
    im, mk = rectangle_images(obs["rgb"], obs["depth"], obs["depth_valid"], R)
    X, M = patches.extract_patches(im, mk, 6)
    X, M = X.reshape(-1, 288), M.reshape(-1, 288)
    Xs = whitening.standardize_patches(X, M)
    full = np.flatnonzero(M.all(1))
    if kind == "nkm-unwhitened":
        cents = Xs[rng.choice(full, 20, replace=False)].astype(np.float32)
        D = cents / np.linalg.norm(cents, axis=1, keepdims=True)
        rep = Representation("NKM", D, cents, None, None, None)
        encoder, param, polarity, k = "Natural", None, False, 20
    else:  # "st"
        mean, P = whitening.fit_zca(Xs, M)
        Xw = whitening.apply_zca(Xs, M, mean, P)
        D = Xw[rng.choice(full, 20, replace=False)].astype(np.float32)
        D /= np.linalg.norm(D, axis=1, keepdims=True)
        rep = Representation("RP", D, None, mean, P, None)
        encoder, param, polarity, k = "ST", 0.5, True, 40
    return DLSRDetector(rep, encoder, param, polarity, np.zeros(4 * k), np.ones(4 * k),
                        rng.normal(size=4 * k), 0.3)


@pytest.mark.parametrize("kind", ["nkm", "nkm-unwhitened", "st"])
def test_dense_patch_scores_match_the_reference_pipeline_with_masked_entries(kind):
    """Running-sum standardisation + folded whitening/encoding (the Cholesky form of the
    whitened norm for NKM) = the reference functions, also for patches with masked entries
    (depth holes, image border)."""
    from dlsr.features import encode_patches

    obs = _scene()
    model = _variant_model(obs, kind)
    rng = np.random.default_rng(2)
    img = rng.normal(size=(30, 40, 8)).astype(np.float32)
    img[..., 4] *= 30.0  # depth-like spread
    msk = np.ones(img.shape, bool)
    msk[5:12, 8:15, 4:] = False  # a depth hole
    msk[:, :3, :] = False  # outside the image
    msk[20, 30, 4:] = False
    img *= msk
    V = rng.normal(size=(model.n_codes, 4)).astype(np.float32)
    stats = {"n_encodings": 0, "encode_seconds": 0.0, "encode_flops": 0.0}
    S = DenseDetector(model, chunk_size=100)._score_maps(img, msk, _PatchScorer(model, V), stats)
    S1 = DenseDetector(model)._score_maps(img, msk, _PatchScorer(model, V, n_blocks=1), stats)
    np.testing.assert_allclose(S1, S, rtol=1e-4, atol=1e-4 * np.abs(S).max())
    S2 = DenseDetector(model)._score_maps(img, msk, _PatchScorer(model, V, colour_only=True),
                                          dict(stats))  # patches inside the hole: colour only
    np.testing.assert_allclose(S2, S, rtol=1e-4, atol=1e-4 * np.abs(S).max())
    X, M = patches.extract_patches(img[None], msk[None], 6)
    X, M = X[0], M[0]
    rep = model.representation
    Xw = whitening.standardize_patches(X, M)
    if rep.zca_mean is not None:
        Xw = whitening.apply_zca(Xw, M, rep.zca_mean, rep.zca_matrix)
    ref = encode_patches(Xw, M, rep, model.encoder, model.encoder_param,
                         polarity=model.polarity) @ V
    assert (~M.all(1)).sum() > 100 and M.all(1).sum() > 100  # both kinds of patches
    np.testing.assert_allclose(S.reshape(-1, 4), ref, rtol=1e-3, atol=1e-3 * np.abs(ref).max())
    assert stats["n_encodings"] == 2 * 25 * 35


def test_dense_exact_scores_equal_the_recognition_scores():
    """The rescoring (recognition's rectangle images through the dense kernels) gives
    DLSRDetector.rectangle_scores, with padding, rotation and depth holes."""
    obs = _scene()
    obs["depth_valid"] = obs["depth_valid"].copy()
    obs["depth_valid"][55:60, 70:78] = False
    model = _random_model(obs)
    rng = np.random.default_rng(3)
    n = 40
    R = np.column_stack([rng.uniform(30, 130, n), rng.uniform(30, 90, n),
                         rng.uniform(-np.pi / 2, np.pi / 2, n), rng.uniform(12, 50, n),
                         rng.uniform(8, 30, n)])
    ref = model.rectangle_scores(obs, R)
    got = DenseDetector(model, n_threads=2, chunk_size=1000).exact_scores(obs, R)
    assert got.shape == (n,) and np.ptp(ref) > 0
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-4 * (np.abs(ref).max() + 1.0))


def test_dense_scores_do_not_depend_on_the_number_of_threads(bar_model):
    model, _ = bar_model
    obs = _scene(seed=3)
    one = DenseDetector(model, grid=SMALL_GRID, n_threads=1)
    three = DenseDetector(model, grid=SMALL_GRID, n_threads=3)
    cand, _ = one.candidates(obs)
    np.testing.assert_array_equal(one.score(obs, cand), three.score(obs, cand))
    a, b = one.detect(obs), three.detect(obs)
    np.testing.assert_array_equal(a.rects, b.rects)
    np.testing.assert_array_equal(a.scores, b.scores)


def test_train_detector_from_samples_gives_a_working_model(tmp_path):
    from dlsr.datasets import GraspSample
    from dlsr.detection import train_detector

    samples = []
    for seed in range(3):
        obs = _scene(seed=seed)
        pos = [GraspRectangle(x, 60.0, np.pi / 2, 30.0, 15.0) for x in range(50, 112, 10)]
        neg = [GraspRectangle(x, 60.0, 0.0, 30.0, 15.0) for x in range(50, 112, 10)]
        neg += [GraspRectangle(x, 25.0, 0.5, 30.0, 15.0) for x in range(40, 120, 20)]
        samples.append(GraspSample(str(seed), "bar", obs["rgb"], obs["depth"],
                                   obs["depth_valid"], pos, neg, mask=obs["mask"]))
    model = train_detector(samples, "NKM", "Natural", n_atoms=16, n_patches=3000,
                           random_state=0, grid=SMALL_GRID, rescore=20)
    # 18 labelled rectangles per image plus as many negatives from the grid (the default)
    assert model.config["n_train_rectangles"] == 3 * 18 * 2
    assert model.config["grid"]["step"] == 6.0
    assert model.representation.centroids is not None
    rects = model.predict(_scene(seed=7))
    assert rects and isinstance(rects[0], GraspRectangle)
    model.save(tmp_path / "m")
    assert DLSRDetector.load(tmp_path / "m").predict(_scene(seed=7)) == rects


def test_table_fits_are_memoised_by_content_and_change_no_result():
    from dlsr.detection import table as grid
    from dlsr.detection.table import table_surface

    depth, valid, _ = _range_scene(2)
    plain = np.zeros_like(depth)  # all missing: no table
    grid._TABLE_FITS.clear()
    grid._REGIONS.clear()
    first = [table_plane_mask(depth, valid, return_surface=True), table_surface(depth, valid),
             table_plane_mask(plain, plain > 0, return_surface=True)]
    assert len(grid._TABLE_FITS._items) == 1 and len(grid._REGIONS._items) == 2
    calls = []
    real = grid._table_surface
    try:
        grid._table_surface = lambda *a, **k: calls.append(1) or real(*a, **k)
        again = [table_plane_mask(depth, valid, return_surface=True),
                 table_surface(depth, valid),
                 table_plane_mask(plain, plain > 0, return_surface=True)]
        assert calls == []  # every fit came from the memo
        (r1, s1), t1, (r0, s0) = first
        (r2, s2), t2, (r3, s3) = again
        assert np.array_equal(r1, r2) and r1.any() and s2.tobytes() == s1.tobytes()
        assert t2.tobytes() == t1.tobytes() and s0 is None and s3 is None and not r3.any()
        assert np.array_equal(table_plane_mask(depth, valid), r1)  # the region alone
        # another image (one pixel changed), other options, or a generator: fitted again
        moved = depth.copy()
        moved[5, 5] += 0.01
        table_surface(moved, valid)
        table_surface(depth, valid, degree=2)
        table_surface(depth, valid, random_state=np.random.default_rng(0))
        assert len(calls) == 3
    finally:
        grid._table_surface = real
    # the memo is what a fresh fit gives
    grid._TABLE_FITS.clear()
    grid._REGIONS.clear()
    r4, s4 = table_plane_mask(depth, valid, return_surface=True)
    assert np.array_equal(r4, r1) and s4.tobytes() == s1.tobytes()


def test_patches_with_every_entry_masked_score_as_the_all_masked_patch():
    """The scorer gives a crop's padding (every entry masked) the all-masked patch's scores
    without encoding it: what encoding each of them gives."""
    obs = _scene()
    model = _random_model(obs)
    rng = np.random.default_rng(4)
    img = rng.normal(size=(40, 24, 8)).astype(np.float32)
    msk = np.ones(img.shape, bool)
    msk[:9] = False  # padding rows above a crop's content
    msk[30:] = False  # and below
    msk[15:19, 5:11, 4:] = False  # a depth hole
    img *= msk
    V = rng.normal(size=(model.n_codes, 4)).astype(np.float32)
    scorer = _PatchScorer(model, V)
    mean, inv, full = window_statistics(img, msk)
    Hp, Wp = full.shape
    rows, cols = np.divmod(np.arange(Hp * Wp), Wp)
    S = scorer.scores(img, msk, rows, cols, mean, inv, full)
    bad = ~full[rows, cols]
    X = scorer._gather(img, msk, rows[bad], cols[bad], mean, inv, full)
    ref = scorer._triangle_whitened(X, scorer._masks(msk, rows[bad], cols[bad]))
    blank = rows[bad] + 5 < 9
    assert blank.sum() >= 3 * Wp and (~blank).sum() > 100
    np.testing.assert_array_equal(S[bad][blank], ref[blank])
    np.testing.assert_allclose(S[bad], ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_masked_patches_whitened_on_their_valid_rows_score_as_the_whole_products():
    """``by_rows``: a masked patch whitened on the rows holding its valid entries (the
    padding's rows dropped, a depth hole kept as a mask) scores as the whole 288 x 288
    whitening and centroid products give, up to float rounding; patches without a valid entry
    get the all-masked patch's scores; image masks that are not whole rows are right too."""
    from dlsr import _dense

    obs = _scene()
    model = _random_model(obs)
    rng = np.random.default_rng(5)
    img = rng.normal(size=(44, 24, 8)).astype(np.float32)
    msk = np.ones(img.shape, bool)
    msk[:9] = False  # padding rows above a crop's content
    msk[30:] = False  # and below
    msk[15:19, 5:11, 4:] = False  # a depth hole
    msk[20:24, :3, :] = False  # outside the source image: part of some rows
    msk[34:40, 10:12, :4] = True  # a few valid entries in padding rows (not a crop's pattern)
    img *= msk
    V = rng.normal(size=(model.n_codes, 4)).astype(np.float32)
    rows_scorer = _PatchScorer(model, V, by_rows=True)
    whole = _PatchScorer(model, V)
    mean, inv, full = window_statistics(img, msk)
    Hp, Wp = full.shape
    rows, cols = np.divmod(np.arange(Hp * Wp), Wp)
    S = rows_scorer.scores(img, msk, rows, cols, mean, inv, full)
    ref = whole.scores(img, msk, rows, cols, mean, inv, full)
    np.testing.assert_array_equal(S[full[rows, cols]], ref[full[rows, cols]])
    np.testing.assert_allclose(S, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())
    spans = np.empty((2, len(rows)), np.int64)
    M = whole._masks(msk, rows, cols)
    _dense.valid_row_spans(M, spans[0], spans[1])
    assert len({tuple(s) for s in spans.T}) >= 8  # several row patterns were grouped
    for t in rng.choice(len(rows), 50, replace=False):
        valid_rows = np.flatnonzero(M[t].reshape(6, 48).any(axis=1))
        expected = (valid_rows[0], valid_rows[-1] + 1) if len(valid_rows) else (0, 0)
        assert tuple(spans[:, t]) == expected
    # the spans read from the canvas, and the rows gathered alone, are the gathered ones
    direct = np.empty_like(spans)
    _dense.patch_row_spans(msk, rows, cols, direct[0], direct[1])
    np.testing.assert_array_equal(direct, spans)
    X = whole._gather(img, msk, rows, cols, mean, inv, full)
    bad = ~full[rows, cols]
    for a, b in ((0, 6), (1, 4), (2, 3), (5, 6)):
        sel = np.flatnonzero(bad)
        Xg = np.empty((len(sel), (b - a) * 48), np.float32)
        Mg = np.empty_like(Xg)
        _dense.gather_patch_rows(img, msk, rows[sel], cols[sel], mean, inv, a, b, Xg, Mg)
        np.testing.assert_array_equal(Xg, X[sel, a * 48:b * 48])
        np.testing.assert_array_equal(Mg, M[sel, a * 48:b * 48])


def test_patches_without_depth_whitened_on_their_colour_entries_score_as_the_whole_products():
    """``colour_only``: a masked patch whose depth entries are all masked and colour entries
    all valid (a canvas patch in a depth hole) is whitened on its 144 colour entries; it
    scores as the whole 288 x 288 whitening and centroid products give, up to float rounding,
    and so do the other masked patches (part of a hole, off the image, no valid entry)."""
    from dlsr import _dense

    obs = _scene()
    model = _random_model(obs)
    rng = np.random.default_rng(6)
    img = rng.normal(size=(40, 36, 8)).astype(np.float32)
    msk = np.ones(img.shape, bool)
    msk[8:24, 6:26, 4:] = False  # a large depth hole: many patches without depth
    msk[30:, 28:, 4:] = False  # a hole at the corner
    msk[:, :3, :] = False  # outside the source image
    msk[34:, :8, :] = False  # no valid entry at all
    img *= msk
    V = rng.normal(size=(model.n_codes, 4)).astype(np.float32)
    colour = _PatchScorer(model, V, colour_only=True)
    whole = _PatchScorer(model, V)
    mean, inv, full = window_statistics(img, msk)
    Hp, Wp = full.shape
    rows, cols = np.divmod(np.flatnonzero(~full.ravel()), Wp)
    S, flops = colour.masked_scores(img, msk, rows, cols, mean, inv, full, 64)
    ref = whole.scores(img, msk, rows, cols, mean, inv, full)
    M = whole._masks(msk, rows, cols).reshape(len(rows), 36, 8)
    expected = M[..., :4].all(axis=(1, 2)) & ~M[..., 4:].any(axis=(1, 2))
    got = np.empty(len(rows), bool)
    _dense.colour_only(msk, rows, cols, got)
    np.testing.assert_array_equal(got, expected)
    assert 50 < expected.sum() < len(rows) - 50
    assert flops < whole.flops_masked * len(rows)
    np.testing.assert_allclose(S, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())
    X = whole._gather(img, msk, rows, cols, mean, inv, full).reshape(len(rows), 36, 8)
    Xc = np.empty((expected.sum(), 144), np.float32)
    _dense.gather_colour(img, rows[expected], cols[expected], mean, inv, Xc)
    np.testing.assert_array_equal(Xc, X[expected, :, :4].reshape(-1, 144))
