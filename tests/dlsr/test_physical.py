"""Physical features, the lattice detector and models that weigh both."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.datasets import GraspSample
from dlsr.detection import (
    PHYSICAL_FEATURES,
    DLSRDetector,
    LatticeDetector,
    PhysicalEncoder,
    lattice_candidates,
    max_width_px,
    object_region,
    physical_features,
    table_surface,
    train_detector,
)
from dlsr.rectangles import GraspRectangle

H, W = 120, 160
F = 200.0
K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])
COL = {name: j for j, name in enumerate(PHYSICAL_FEATURES)}


def _scene(seed=0):
    """A flat table 0.8 m away with a 3 cm high bar (long axis along x, 16 px wide)."""
    rng = np.random.default_rng(seed)
    rgb = (90 + 100 * rng.random((H, W, 3))).astype(np.uint8)
    depth = np.full((H, W), 0.8, np.float32)
    mask = np.zeros((H, W), bool)
    mask[52:68, 40:120] = True
    depth[mask] -= 0.03
    rgb[mask] = (200, 30, 30)
    return {"rgb": rgb, "depth": depth, "depth_valid": np.ones((H, W), bool), "K": K.copy(),
            "mask": mask}


def _features(obs, rects):
    region = np.asarray(obs["mask"], bool)
    return physical_features(obs, np.asarray(rects, float), region,
                             table_surface(obs["depth"], obs["depth_valid"]))


def test_physical_features_tell_a_grasp_across_the_bar_from_one_along_it():
    obs = _scene()
    across = (80.0, 60.0, np.pi / 2, 30.0, 12.0)  # closing along y, over the 16 px width
    along = (80.0, 60.0, 0.0, 30.0, 12.0)  # closing along x: both fingers land on the bar
    P = _features(obs, [across, along])
    assert P.shape == (2, len(PHYSICAL_FEATURES))
    z = 0.77  # the bar's top under the centre
    assert P[0, COL["opening_m"]] == pytest.approx(30 * z / F, rel=1e-6)
    assert P[0, COL["jaw_m"]] == pytest.approx(12 * z / F, rel=1e-6)
    assert P[:, COL["centre_height_m"]] == pytest.approx([0.03, 0.03], abs=1e-3)
    assert P[0, COL["jaw_height_m"]] == pytest.approx(0.0, abs=1e-3)
    assert P[1, COL["jaw_height_m"]] == pytest.approx(0.03, abs=1e-3)
    assert P[0, COL["jaw_on_object"]] == 0.0 and P[1, COL["jaw_on_object"]] == 1.0
    assert P[0, COL["jaw_above_centre_m"]] < -0.02 < P[1, COL["jaw_above_centre_m"]]
    assert (P[:, COL["centre_on_object"]] == 1).all()
    assert P[0, COL["angle_to_minor"]] == pytest.approx(0.0, abs=1e-6)
    assert P[1, COL["angle_to_minor"]] == pytest.approx(1.0, abs=1e-6)


def test_offset_along_the_major_axis_runs_from_the_centroid_to_the_end():
    obs = _scene()
    rects = [(79.5, 59.5, np.pi / 2, 30, 12), (119.0, 59.5, np.pi / 2, 30, 12),
             (20.0, 20.0, np.pi / 2, 30, 12)]
    P = _features(obs, rects)
    assert P[0, COL["offset_major"]] == pytest.approx(0.0, abs=1e-6)
    assert P[1, COL["offset_major"]] == pytest.approx(1.0, abs=1e-6)
    assert P[2, COL["centre_on_object"]] == 0 and P[2, COL["centre_height_m"]] == pytest.approx(
        0.0, abs=1e-3)


def test_missing_depth_and_empty_region_give_defined_values():
    obs = _scene()
    obs["depth_valid"] = obs["depth_valid"].copy()
    obs["depth_valid"][55:65, 75:85] = False  # a hole under the centre
    P = _features(obs, [(80.0, 60.0, np.pi / 2, 30.0, 12.0)])
    assert np.isfinite(P).all()
    assert P[0, COL["centre_height_m"]] == pytest.approx(0.03, abs=1e-3)  # the region's median
    empty = physical_features(obs, np.array([[80.0, 60.0, 0.0, 30.0, 12.0]]),
                              np.zeros((H, W), bool), None)
    assert empty[0, COL["offset_major"]] == 1 and empty[0, COL["angle_to_minor"]] == 1
    assert empty[0, COL["centre_on_object"]] == 0
    assert physical_features(obs, np.zeros((0, 5)), obs["mask"]).shape == (0, 9)
    with pytest.raises(ValueError, match="region"):
        physical_features(obs, np.zeros((1, 5)), np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="K"):
        physical_features({k: v for k, v in obs.items() if k != "K"},
                          np.array([[80.0, 60.0, 0.0, 30.0, 12.0]]), obs["mask"])


def test_physical_encoder_gives_one_indicator_per_column():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.normal(size=200), rng.integers(0, 2, 200), np.zeros(200)])
    enc = PhysicalEncoder(n_bins=4).fit(X)
    assert [len(e) for e in enc.edges_] == [3, 1, 0]  # ties merge bins; no empty bin
    E = enc.transform(X)
    assert E.shape == (200, enc.n_output) == (200, 4 + 2 + 1)
    starts = np.cumsum([0, 4, 2])
    for s, n in zip(starts, (4, 2, 1), strict=True):
        assert (E[:, s:s + n].sum(axis=1) == 1).all()
    assert np.array_equal(E[:, 0:4].sum(axis=0) > 30, np.ones(4, bool))  # quantile bins
    assert np.array_equal(X, np.column_stack([X[:, 0], X[:, 1], X[:, 2]]))  # input untouched
    with pytest.raises(ValueError, match="non-finite"):
        PhysicalEncoder().fit(np.array([[np.nan], [1.0]]))
    with pytest.raises(ValueError, match="n_bins"):
        PhysicalEncoder(n_bins=1).fit(X)
    with pytest.raises(ValueError, match="shape"):
        enc.transform(X[:, :2])


def test_lattice_candidates_fit_the_object_and_the_reach():
    obs = _scene()
    rects = lattice_candidates(obs["mask"], obs["depth"], K, np.zeros(2), max_opening=None)
    A = np.array([r.as_array() for r in rects])
    assert len(A) > 100
    across = np.isclose(np.abs(np.sin(A[:, 2])), 1.0)
    # closing across the bar: the chord is the bar's width (16 px, 15 between end pixels)
    assert np.isclose(A[across, 3].min(), 15 + 4.0)
    narrow = lattice_candidates(obs["mask"], obs["depth"], K, np.zeros(2), max_opening=0.05)
    widths_m = np.array([r.w for r in narrow]) * 0.77 / F
    assert len(narrow) < len(rects) and (widths_m <= 0.95 * 0.05 + 1e-9).all()
    assert lattice_candidates(np.zeros((H, W), bool), obs["depth"], K, np.zeros(2), None) == []


def test_widest_in_reach_adds_the_opening_with_all_the_clearance_the_gripper_has():
    """The bar's chord across it is 15 px: a tight opening of 19 px and a wide one of 27.5 px,
    beyond the reach of a 10 cm gripper at 0.77 m (0.95 x 26 px); the option adds the widest
    opening in reach instead of nothing."""
    obs = _scene()

    def across(**kw):
        rects = lattice_candidates(obs["mask"], obs["depth"], K, np.zeros(2), max_opening=0.1,
                                   **kw)
        A = np.array([r.as_array() for r in rects])
        return A, A[np.isclose(np.abs(np.sin(A[:, 2])), 1.0)]

    reach = 0.95 * float(max_width_px(0.77, np.pi / 2, K, 0.1))
    assert 19.0 < reach < 27.5
    plain, plain_across = across()
    wide, wide_across = across(widest_in_reach=True)
    assert np.allclose(plain_across[:, 3], 19.0)
    assert np.isclose(wide_across[:, 3], 19.0).any()
    assert np.isclose(wide_across[:, 3], reach).any() and (wide_across[:, 3] <= reach).all()
    # every plain candidate is still there; only openings in reach were added
    assert {tuple(r) for r in plain.round(6)} <= {tuple(r) for r in wide.round(6)}
    assert len(wide) > len(plain)
    # without a reach there is nothing to add
    a = lattice_candidates(obs["mask"], obs["depth"], K, np.zeros(2), None, widest_in_reach=True)
    b = lattice_candidates(obs["mask"], obs["depth"], K, np.zeros(2), None)
    assert np.array_equal([r.as_array() for r in a], [r.as_array() for r in b])


@pytest.mark.parametrize("bad", [np.full((3, 3), np.nan), np.diag([-F, F, 1.0]), np.eye(2)])
def test_the_reach_needs_a_valid_camera_matrix(bad):
    """With a NaN camera matrix every reach is NaN, and as comparisons with NaN are False every
    candidate would pass, however wide: a clear error instead, as for any matrix that is not a
    camera's."""
    obs = _scene()
    with pytest.raises(ValueError, match="intrinsics"):
        lattice_candidates(obs["mask"], obs["depth"], bad, np.zeros(2), max_opening=0.05)
    with pytest.raises(ValueError, match="intrinsics"):
        max_width_px(0.7, 0.0, bad, 0.08)
    # without a reach the matrix is not read
    assert lattice_candidates(obs["mask"], obs["depth"], bad, np.zeros(2), max_opening=None)


def _samples(n=3, with_K=True):
    out = []
    for seed in range(n):
        obs = _scene(seed)
        pos = [GraspRectangle(x, 60.0, np.pi / 2, 22.0, 12.0) for x in range(50, 112, 8)]
        neg = [GraspRectangle(x, 60.0, 0.0, 30.0, 12.0) for x in range(50, 112, 8)]
        neg += [GraspRectangle(x, 60.0, np.pi / 2, 12.0, 12.0) for x in range(50, 112, 16)]
        out.append(GraspSample(str(seed), "bar", obs["rgb"], obs["depth"], obs["depth_valid"],
                               pos, neg, mask=obs["mask"], K=K.copy() if with_K else None))
    return out


@pytest.fixture(scope="module")
def physical_model():
    return train_detector(_samples(), "NKM", "Natural", n_atoms=16, n_patches=3000,
                          random_state=0, grid_negatives=0.0, physical=True,
                          detector="lattice")


def test_a_physical_model_prefers_grasps_across_the_bar_and_round_trips(physical_model,
                                                                         tmp_path):
    model = physical_model
    assert model.physical and model.config["physical"] is True
    obs = _scene(seed=5)
    det = model.detector(top_k=3)
    assert isinstance(det, LatticeDetector)
    d = det.detect(obs)
    assert len(d.rects) == 3
    assert abs(np.sin(d.rects[0, 2])) > 0.85  # closing across the bar (within 31.8 deg)
    model.save(tmp_path / "m")
    loaded = DLSRDetector.load(tmp_path / "m")
    assert loaded.physical
    rects = d.rects
    np.testing.assert_allclose(loaded.physical_scores(obs, rects),
                               model.physical_scores(obs, rects), rtol=1e-12)
    np.testing.assert_array_equal(loaded.detector(top_k=3).detect(obs).rects, d.rects)
    # the grid search adds the same physical term
    assert model.detector("dense", top_k=1).detect(obs).rects.shape == (1, 5)


def test_physical_term_separates_reachable_from_blocked_jaws(physical_model):
    obs = _scene(seed=6)
    good = (80.0, 60.0, np.pi / 2, 22.0, 12.0)
    blocked = (80.0, 60.0, 0.0, 30.0, 12.0)
    s = physical_model.physical_scores(obs, np.array([good, blocked]))
    assert s[0] > s[1]


def test_physical_training_and_scoring_need_the_camera_matrix(physical_model):
    with pytest.raises(ValueError, match="image 0 .*camera matrix|camera matrix.*image 0"):
        train_detector(_samples(with_K=False), "NKM", "Natural", n_atoms=16, n_patches=3000,
                       grid_negatives=0.0, physical=True)
    with pytest.raises(ValueError, match="physical_weight"):
        train_detector(_samples(), "NKM", "Natural", n_atoms=16, n_patches=3000,
                       grid_negatives=0.0, physical=True, physical_weight=0.0)
    obs = {k: v for k, v in _scene().items() if k != "K"}
    with pytest.raises(ValueError, match="'K'"):
        physical_model.physical_scores(obs, np.array([[80.0, 60.0, 0.0, 30.0, 12.0]]))
    with pytest.raises(ValueError, match="'K'"):
        physical_model.detector("lattice").detect(obs)


def test_lattice_detector_reports_empty_observations(physical_model, caplog):
    obs = _scene()
    obs["depth_valid"] = np.zeros((H, W), bool)
    d = physical_model.detector("lattice").detect(obs)
    assert len(d.rects) == 0 and "no valid pixel" in d.reason
    obs = _scene()
    obs["mask"] = np.zeros((H, W), bool)
    d = physical_model.detector("lattice").detect(obs)
    assert len(d.rects) == 0 and "empty object region" in d.reason
    with pytest.raises(ValueError, match="budget"):
        physical_model.detector("lattice", budget=0).detect(_scene())


def test_a_model_without_physical_features_scores_as_before():
    samples = _samples()
    model = train_detector(samples, "NKM", "Natural", n_atoms=16, n_patches=3000,
                           random_state=0, grid_negatives=0.0)
    assert not model.physical
    obs = _scene(seed=5)
    rects = np.array([[80.0, 60.0, np.pi / 2, 22.0, 12.0]])
    assert (model.physical_scores(obs, rects) == 0).all()
    region, _ = object_region(obs)
    assert region.any()


def test_detect_files_passes_the_camera_to_a_physical_model(physical_model, tmp_path):
    import json

    from PIL import Image

    from dlsr.detection import detect_files

    obs = _scene(seed=8)
    Image.fromarray(obs["rgb"]).save(tmp_path / "r.png")
    np.save(tmp_path / "d.npy", obs["depth"])
    (tmp_path / "camera.json").write_text(json.dumps({"K": K.tolist()}))
    args = (physical_model, tmp_path / "r.png", tmp_path / "d.npy")
    with pytest.raises(ValueError, match="--intrinsics"):
        detect_files(*args)
    by_file = detect_files(*args, K=tmp_path / "camera.json", top_k=2)
    by_matrix = detect_files(*args, K=K, top_k=2)
    assert len(by_file.rects) == 2
    np.testing.assert_array_equal(by_file.rects, by_matrix.rects)
    with pytest.raises(ValueError, match="3x3"):
        detect_files(*args, K=np.eye(2))
    with pytest.raises(ValueError, match="span the object"):
        detect_files(*args, K=K, clear_jaws=False)


def test_lattice_fills_depth_holes_in_the_region_before_laying_the_lattice(physical_model):
    obs = _scene()
    obs["depth_valid"] = obs["depth_valid"].copy()
    obs["depth_valid"][52:68, 60:100] = False  # the middle of the bar unseen
    obs["depth"] = np.where(obs["depth_valid"], obs["depth"], 0.0).astype(np.float32)
    det = physical_model.detector("lattice", budget=None)
    filled, _, _ = det.candidates(obs)
    det.fill_holes = False
    holey, _, _ = det.candidates(obs)
    inside = lambda c: ((c[:, 0] > 62) & (c[:, 0] < 98)).sum()  # noqa: E731
    assert inside(holey) < inside(filled)  # lattice points on the hole come back
    assert np.array_equal(obs["depth"][60, 80], np.float32(0.0))  # the input is untouched


def _dark_top(seed=0):
    """A 40 px disc 5 cm above the table whose top the sensor hardly returns: valid depth on
    four small islands of it only, and a projector shadow (missing depth) beside it."""
    obs = _scene(seed)
    yy, xx = np.mgrid[:H, :W]
    disc = (xx - 80) ** 2 + (yy - 60) ** 2 <= 20**2
    islands = np.zeros((H, W), bool)
    for cx, cy in ((64, 60), (96, 60), (80, 44), (80, 76)):
        islands |= (np.abs(xx - cx) <= 2) & (np.abs(yy - cy) <= 2)
    valid = ~disc | islands
    valid[50:70, 40:58] = False  # the shadow, left of the disc
    depth = np.where(disc, 0.75, 0.8).astype(np.float32)
    obs.update(depth=np.where(valid, depth, 0.0).astype(np.float32), depth_valid=valid,
               mask=islands)
    return obs, disc


def test_complete_region_adds_the_unseen_top_inside_the_hull():
    from dlsr.detection import complete_region

    obs, _ = _dark_top()
    region, valid = obs["mask"], obs["depth_valid"]
    before = region.copy()
    full = complete_region(region, valid)
    np.testing.assert_array_equal(region, before)  # the input is untouched
    assert full[region].all() and not full[valid & ~region].any()  # no table pixel joins
    # the disc's unseen pixels between the islands join (the hull is the islands' diamond)
    assert full[58:63, 66:95].all() and full[46:75, 78:83].all()
    assert not full[50:70, 40:58].any()  # the shadow outside the hull stays out
    assert not complete_region(np.zeros((H, W), bool), valid).any()
    # the physical features measure the completed region: a centre on the unseen top is on it
    P = physical_features(obs, np.array([[80.0, 60.0, 0.0, 50.0, 12.0]]), region,
                          table_surface(obs["depth"], valid))
    assert P[0, COL["centre_on_object"]] == 1.0
    assert P[0, COL["offset_major"]] < 0.2
    with pytest.raises(ValueError, match="same"):
        complete_region(region, valid[:10])


def test_fill_unseen_surface_gives_the_hull_the_nearest_seen_depth_of_the_object():
    from dlsr.detection import complete_region, fill_unseen_surface

    obs, _ = _dark_top()
    region, valid = obs["mask"], obs["depth_valid"]
    depth = obs["depth"].copy()
    depth[56:65, 62:67] = np.where(region[56:65, 62:67], 0.74, depth[56:65, 62:67])  # left
    depth[56:65, 94:99] = np.where(region[56:65, 94:99], 0.76, depth[56:65, 94:99])  # right
    before = depth.copy()
    filled, seen = fill_unseen_surface(depth, valid, region)
    np.testing.assert_array_equal(depth, before)  # the input is untouched
    unseen = complete_region(region, valid) & ~valid
    assert unseen.sum() > 100
    np.testing.assert_array_equal(seen, valid | unseen)
    np.testing.assert_array_equal(filled[valid], depth[valid])  # seen depth unchanged
    assert filled[60, 68] == np.float32(0.74) and filled[60, 92] == np.float32(0.76)
    assert not valid[50, 80] and filled[50, 80] == np.float32(0.75)  # nearest: the top island
    assert not seen[50:70, 40:58].any() and (filled[50:70, 40:58] == 0).all()  # the shadow
    # no seen object pixel: nothing to fill from
    f0, s0 = fill_unseen_surface(depth, valid, np.zeros((H, W), bool))
    np.testing.assert_array_equal(f0, depth)
    np.testing.assert_array_equal(s0, valid)
    with pytest.raises(ValueError, match="same"):
        fill_unseen_surface(depth, valid[:10], region)


def test_lattice_spans_an_object_whose_top_the_sensor_missed(physical_model):
    obs, _ = _dark_top()
    det = physical_model.detector("lattice", budget=None)
    whole, _, _ = det.candidates(obs)
    det.complete = False
    islands, _, _ = det.candidates(obs)
    # closing through the disc's centre spans its 40 px only with the unseen top counted
    assert whole[:, 3].max() >= 30 > islands[:, 3].max()
