"""Candidate sampling (dense, Jacquard-like) and the fast labelling path."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.metrics import rectangle_metric_many
from dlsr.rectangles import GraspRectangle
from graspsim.labels.labelling import (
    dense_candidates,
    label_rectangles,
    max_width_px,
    sample_candidates,
)
from graspsim.sim.camera import CameraIntrinsics
from graspsim.sim.grasp import TOO_WIDE, rectangle_to_grasp

INTR = CameraIntrinsics()
OBJ = 7


def box_view(angle=0.4, length=110.0, width=40.0):
    """A box seen from above: segmentation (id 7 on -1), clean depth (0.62 m on a 0.70 m table)."""
    rows, cols = np.mgrid[0:480, 0:640]
    dx, dy = cols - 320.0, rows - 240.0
    c, s = np.cos(angle), np.sin(angle)
    along, across = dx * c - dy * s, dx * s + dy * c
    box = (np.abs(along) < length / 2) & (np.abs(across) < width / 2)
    seg = np.where(box, OBJ, -1).astype(np.int32)
    depth = np.where(box, 0.62, 0.70).astype(np.float32)
    return seg, depth, box


def test_max_width_px_is_the_widest_opening_rectangle_to_grasp_accepts(rng):
    K = np.array([[520.0, 0, 320], [0, 560.0, 240], [0, 0, 1]])
    depth = np.full((480, 640), 0.6, np.float32)
    valid = np.ones_like(depth, bool)
    for theta in rng.uniform(-np.pi / 2, np.pi / 2, 5):
        w = float(max_width_px(0.6, theta, K))
        ok = rectangle_to_grasp(GraspRectangle(320, 240, theta, 0.999 * w, 15), depth, valid, K,
                                np.eye(4))
        wide = rectangle_to_grasp(GraspRectangle(320, 240, theta, 1.001 * w, 15), depth, valid,
                                  K, np.eye(4))
        assert ok.failure is None and wide.failure == TOO_WIDE


def test_dense_candidates_span_angles_jaws_and_stay_within_reach():
    seg, depth, box = box_view()
    cands = dense_candidates(seg, [OBJ], np.random.default_rng(0), depth, INTR)
    arr = np.array([r.as_array() for r in cands])
    assert len(arr) > 100
    k = (arr[:, 2] + np.pi / 2) / (np.pi / 12)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)  # every 15 degrees ...
    assert len(np.unique(np.round(k))) == 12  # ... all of them
    assert len(np.unique(arr[:, 4])) == 2  # two jaw sizes
    ix, iy = np.rint(arr[:, 0]).astype(int), np.rint(arr[:, 1]).astype(int)
    assert box[iy, ix].all()  # centred on the object
    z = depth[iy, ix]
    assert (arr[:, 3] <= max_width_px(z, arr[:, 2], INTR) + 1e-9).all()  # gripper can open
    # The long side (110 px, 8.6 cm at 0.62 m) is out of reach: no candidate closes along it.
    along = np.abs(np.cos(arr[:, 2] - 0.4)) > np.cos(np.radians(20))
    assert not (along & (arr[:, 3] > 100)).any()


def test_dense_candidates_match_every_good_grasp_by_the_rectangle_metric(rng):
    seg, depth, _ = box_view()
    cands = dense_candidates(seg, [OBJ], np.random.default_rng(1), depth, INTR)
    # Grasps across the 40 px side anywhere along the box, a little off-centre and off-angle,
    # opening 2-20 px wider than the box, any jaw size of the sampler's range.
    m = 30
    t = rng.uniform(-45, 45, m)
    off = rng.uniform(-3, 3, m)
    axis, normal = np.array([np.cos(0.4), -np.sin(0.4)]), np.array([np.sin(0.4), np.cos(0.4)])
    centres = np.array([320.0, 240.0]) + t[:, None] * axis + off[:, None] * normal
    theta = np.mod(0.4 + np.pi + rng.uniform(-0.17, 0.17, m), np.pi) - np.pi / 2
    good = np.column_stack([centres, theta, 40 + rng.uniform(2, 20, m), rng.uniform(10, 28, m)])
    assert rectangle_metric_many(good, cands).all()


def test_dense_budget_is_a_seeded_subset():
    seg, depth, _ = box_view()
    full = dense_candidates(seg, [OBJ], np.random.default_rng(3), depth, INTR)
    some = sample_candidates(seg, [OBJ], np.random.default_rng(3), 50, depth=depth,
                             mode="dense", intrinsics=INTR)
    again = sample_candidates(seg, [OBJ], np.random.default_rng(3), 50, depth=depth,
                              mode="dense", intrinsics=INTR)
    assert len(some) == 50 and some == again
    keys = {tuple(r.as_array()) for r in full}
    assert all(tuple(r.as_array()) in keys for r in some)
    assert dense_candidates(np.full_like(seg, -1), [OBJ], np.random.default_rng(0), depth,
                            INTR) == []


def test_dense_candidates_refuse_bad_input():
    seg, depth, _ = box_view()
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="intrinsics"):
        sample_candidates(seg, [OBJ], rng, 10, depth=depth, mode="dense")
    with pytest.raises(ValueError, match="mode"):
        sample_candidates(seg, [OBJ], rng, 10, depth=depth, mode="grid")
    with pytest.raises(ValueError, match="budget"):
        dense_candidates(seg, [OBJ], rng, depth, INTR, n=0)
    with pytest.raises(ValueError, match="same"):
        dense_candidates(seg, [OBJ], rng, depth[:10], INTR)


@pytest.mark.sim
def test_fast_labelling_gives_the_reference_verdicts():
    from graspsim.labels.graspability import resolve_objects
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.observe import observe_scene

    sim = Simulation()
    try:
        scene, bodies, frame, st = observe_scene(sim, resolve_objects("train"), 5, 0)
        cands = sample_candidates(frame.segmentation, bodies.objects, st["label"], 12,
                                  depth=frame.depth_clean, mode="dense",
                                  intrinsics=frame.intrinsics)
        fast = label_rectangles(sim, scene, frame, cands)
        ref = label_rectangles(sim, scene, frame, cands, fast=False)
    finally:
        sim.close()
    assert [(r.success, r.reason) for r in fast.results] == \
        [(r.success, r.reason) for r in ref.results]
    decided = [r.steps == 0 for r in fast.results]
    assert any(decided) and not all(decided)  # both paths were taken
    assert fast.success.any()
    assert all(r.steps > 0 for r in ref.results if r.reason != TOO_WIDE)
    # The early end of the hold saves steps on successes.
    assert sum(r.steps for r in fast.results if r.success) < \
        sum(r.steps for r in ref.results if r.success)
