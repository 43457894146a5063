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
