"""The simulation-settings study's library (graspsim.eval.sim_settings)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from graspsim.eval.sim_settings import (
    VARIANTS,
    image_stats,
    measure_settings,
    percentile_summary,
    study_markdown,
)


def test_each_variant_changes_one_setting_of_the_default():
    default = VARIANTS["default"]
    for name, v in VARIANTS.items():
        changed = [f.name for f in dataclasses.fields(v)
                   if f.name != "name" and getattr(v, f.name) != getattr(default, f.name)]
        assert len(changed) == (0 if name == "default" else
                                2 if name == "jacquard_look" else 1), (name, changed)


def test_image_stats_of_a_drawn_scene():
    H, W = 40, 60
    rgb = np.full((H, W, 3), 100, np.uint8)
    rgb[..., 0] = 130  # saturation 30 on the background
    depth = np.full((H, W), 0.8, np.float32)
    valid = np.ones((H, W), bool)
    mask = np.zeros((H, W), bool)
    mask[10:20, 5:35] = True
    depth[mask] = 0.75
    valid[10:12, 5:35] = False  # 60 of the 300 object pixels missing
    valid[30:, :] = False
    s = image_stats(rgb, depth, valid, mask)
    assert s["object_px"] == 300 and s["bbox_long_px"] == 30
    assert s["object_depth_m"] == pytest.approx(0.75) and s["table_depth_m"] == pytest.approx(0.8)
    assert s["missing_object"] == pytest.approx(0.2)
    assert s["missing_elsewhere"] == pytest.approx(10 * 60 / (H * W - 300))
    assert s["background_saturation"] == 30.0
    empty = image_stats(rgb, depth, valid, np.zeros((H, W), bool))
    assert empty["object_px"] == 0 and empty["missing_object"] is None
    summary = percentile_summary([s, empty])
    assert summary["images"] == 2 and summary["missing_object"] == [0.2, 0.2, 0.2]
    with pytest.raises(ValueError, match="no image"):
        percentile_summary([])


def test_unknown_variants_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown variants"):
        measure_settings(tmp_path, tmp_path, variants=["sunny"])


def test_study_table():
    info = {"default": {"accuracy": 0.5, "n_correct": 5, "positives": 40,
                        "opening_px_median": 30.0},
            "closer": {"accuracy": 0.7, "n_correct": 7, "positives": 50,
                       "opening_px_median": 45.0}}
    tests = {"closer": {"a_only": 3, "b_only": 1, "p_value": 0.625}}
    text = study_markdown(info, tests, {"default": 10, "closer": 10})
    assert "| closer | 70.0 (7/10) | 3 / 1 | 0.625 | 50 (45.0) |" in text
    assert "| default | 50.0 (5/10) |  |  | 40 (30.0) |" in text
