"""Baseline detectors on synthetic depth (no pybullet)."""

from __future__ import annotations

import numpy as np
import pytest

from graspsim.detectors import (
    MaskPCADetector,
    OracleDetector,
    RandomDetector,
    object_mask_from_depth,
)


def tilted_table_with_box(angle_deg=30.0):
    """A slightly tilted table at ~0.7 m with a 40 x 120 px box 5 cm proud, rotated."""
    v, u = np.mgrid[0:480, 0:640]
    inv = 1 / 0.7 + 1e-5 * (u - 320) - 5e-6 * (v - 240)
    depth = (1 / inv).astype(np.float32)
    a = np.radians(angle_deg)
    du, dv = u - 300, v - 220
    along = du * np.cos(a) - dv * np.sin(a)  # long axis at +30 deg CCW as displayed
    across = du * np.sin(a) + dv * np.cos(a)
    box = (np.abs(along) <= 60) & (np.abs(across) <= 20)
    depth[box] -= 0.05
    return depth, np.ones_like(depth, dtype=bool), box


def test_mask_from_depth_finds_the_box():
    depth, valid, box = tilted_table_with_box()
    mask = object_mask_from_depth(depth, valid)
    iou = (mask & box).sum() / (mask | box).sum()
    assert iou > 0.95


def test_mask_pca_grasps_across_the_minor_axis():
    depth, valid, box = tilted_table_with_box(30.0)
    rects = MaskPCADetector(margin_px=6).predict(
        {"rgb": np.zeros((480, 640, 3), np.uint8), "depth": depth, "depth_valid": valid})
    assert len(rects) == 1
    r = rects[0]
    assert (r.x, r.y) == pytest.approx((300, 220), abs=1.5)
    # Closing across the long axis (30 deg): theta = 30 - 90 = -60 degrees.
    d = np.degrees(abs(np.mod(r.theta - np.radians(-60) + np.pi / 2, np.pi) - np.pi / 2))
    assert d < 2
    assert r.w == pytest.approx(40 + 6, abs=3)


def test_mask_pca_on_an_empty_table_proposes_nothing():
    depth, valid, _ = tilted_table_with_box()
    flat = np.full_like(depth, 0.7)
    assert MaskPCADetector().predict({"depth": flat, "depth_valid": valid}) == []


def test_random_is_seeded_by_obs_and_oracle_needs_labels():
    obs = {"depth": np.zeros((480, 640), np.float32), "seed": 4}
    assert RandomDetector().predict(obs) == RandomDetector().predict(obs)
    assert RandomDetector().predict(obs) != RandomDetector().predict({**obs, "seed": 5})
    with pytest.raises(ValueError, match="positives"):
        OracleDetector().predict({"depth": obs["depth"]})


def _look_down_obs(height=0.75):
    """A box 6 cm tall (40 x 120 px at the top) on a table 0.75 m under a camera looking
    straight down, with its pinhole camera."""
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = np.diag([1.0, -1.0, -1.0])  # image x = world x, optical axis down
    T_world_cam[2, 3] = height
    depth = np.full((480, 640), height, np.float32)
    depth[220:260, 260:380] = height - 0.06  # long axis along the image x
    return {"rgb": np.zeros((480, 640, 3), np.uint8), "depth": depth,
            "depth_valid": np.ones((480, 640), np.uint8),
            "K": np.array([[550.0, 0, 319.5], [0, 550.0, 239.5], [0, 0, 1]]),
            "T_world_cam": T_world_cam, "seed": 0}


class _Fixed:
    def __init__(self, rects):
        self.rects = rects

    def predict(self, obs):
        return list(self.rects)


def test_gripper_aware_keeps_the_executable_rectangles_in_order():
    from dlsr.rectangles import GraspRectangle
    from graspsim.detectors import GripperAwareDetector, executable

    obs = _look_down_obs()
    up = np.pi / 2  # closing along the image y axis: across the box
    on_top = GraspRectangle(320, 240, up, 20, 20)  # fingers land on the box
    too_wide = GraspRectangle(320, 240, 0.0, 140, 20)  # 140 px at 0.69 m: 18 cm
    across = GraspRectangle(320, 240, up, 52, 20)  # fingers beside the box
    across2 = GraspRectangle(300, 240, up, 56, 20)
    off_image = GraspRectangle(320, 5, up, 52, 20)  # a finger above the top edge
    rects = [on_top, too_wide, across, off_image, across2]
    assert executable(rects, obs).tolist() == [False, False, True, False, True]
    det = GripperAwareDetector(_Fixed(rects), keep=1)
    assert det.predict(obs) == [across]
    assert GripperAwareDetector(_Fixed(rects)).predict(obs) == [across, across2]
    assert GripperAwareDetector(_Fixed([on_top])).predict(obs) == []
    assert GripperAwareDetector(_Fixed([])).predict(obs) == []
    with pytest.raises(ValueError, match="'K'"):
        executable(rects, {k: v for k, v in obs.items() if k != "K"})


def test_fingers_must_miss_the_unseen_surface_of_the_object():
    """The box's top returns depth only on a band through its centre and at its two ends: the
    fingers of a narrow grasp come down where the sensor saw nothing, which the plain check
    takes for empty space; the object's completed region says it is the box."""
    from dlsr.rectangles import GraspRectangle
    from graspsim.detectors import GripperAwareDetector, executable

    obs = _look_down_obs()
    valid = obs["depth_valid"].astype(bool)
    valid[220:236, 280:361] = False
    valid[245:260, 280:361] = False
    obs.update(depth_valid=valid.astype(np.uint8),
               depth=np.where(valid, obs["depth"], 0.0).astype(np.float32))
    up = np.pi / 2
    on_unseen = GraspRectangle(320, 240, up, 20, 20)  # fingers on the unseen top
    across = GraspRectangle(320, 240, up, 52, 20)  # fingers beside the box
    rects = [on_unseen, across]
    assert executable(rects, obs, unseen_surface=False).tolist() == [True, True]
    assert executable(rects, obs).tolist() == [False, True]
    assert GripperAwareDetector(_Fixed(rects), keep=1).predict(obs) == [across]
    assert GripperAwareDetector(_Fixed(rects), keep=1,
                                unseen_surface=False).predict(obs) == [on_unseen]
    # when no rectangle misses the unseen surface, the plain check decides
    assert executable([on_unseen], obs).tolist() == [True]


def test_gripper_aware_tells_a_dlsr_detector_to_search_clear_jaws_within_reach(saved_model):
    from dlsr.detection import DLSRDetector
    from graspsim.detectors import GripperAwareDetector, gripper_aware
    from graspsim.sim.gripper import MAX_OPENING

    path, _ = saved_model
    inner = DLSRDetector.load(path).detector()
    det = gripper_aware(inner, top_k=30)
    assert isinstance(det, GripperAwareDetector)
    assert det.detector.grid.clear_jaws and det.detector.grid.max_width == MAX_OPENING
    assert det.detector.top_k == 30 and det.detector.rescore >= 30
    assert not inner.grid.clear_jaws and inner.grid.max_width is None  # not changed
    other = gripper_aware(MaskPCADetector())
    assert isinstance(other.detector, MaskPCADetector) and not other.requires_labels
    assert gripper_aware(OracleDetector()).requires_labels  # the harness then labels the scene


def test_gripper_aware_judges_grasps_whose_fingers_settle_as_the_harness_executes_them():
    """A 2 cm block on a 2 cm plate that reaches beyond the fingers: the fingers of a grasp
    across the block come down 2.5 cm past its top and meet the plate, unless (``min_grip``)
    they stop above it, still gripping 1.8 cm of the block."""
    from dlsr.rectangles import GraspRectangle
    from graspsim.detectors import GripperAwareDetector, executable

    obs = _look_down_obs()
    depth = np.full((480, 640), 0.75, np.float32)
    depth[140:340, 200:440] = 0.73  # the plate
    depth[220:260, 300:340] = 0.71  # the block, 40 px = 5.2 cm square at its top
    obs["depth"] = depth
    across = GraspRectangle(320, 240, 0.0, 52, 20)
    assert executable([across], obs).tolist() == [False]
    assert executable([across], obs, min_grip=0.01).tolist() == [True]
    assert executable([across], obs, min_grip=0.025).tolist() == [False]  # too little left
    assert GripperAwareDetector(_Fixed([across])).predict(obs) == []
    assert GripperAwareDetector(_Fixed([across]), min_grip=0.01).predict(obs) == [across]
