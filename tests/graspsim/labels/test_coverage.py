"""Label coverage (graspsim.labels.coverage, scripts/label_coverage.py)."""

from __future__ import annotations

import pytest

from graspsim.labels.coverage import coverage_summary, labelling_names, scene_coverage


def test_labelling_names():
    assert labelling_names([128, 0]) == ["mixed", "dense_128", "dense_all"]


def _scene(ref, **labellings):
    return {"reference_successes": ref,
            **{k: {"labelled": v[0], "positives": v[1], "covered": v[2], "cpu_seconds": v[3]}
               for k, v in labellings.items()}}


def test_coverage_is_pooled_over_scenes():
    scenes = [_scene(4, mixed=(10, 3, 2, 0.5)), _scene(0, mixed=(10, 1, 0, 0.5)),
              _scene(6, mixed=(20, 5, 6, 1.0))]
    s = coverage_summary(scenes, ["mixed"])["mixed"]
    assert s["coverage"] == pytest.approx(8 / 10) and s["covered"] == 8
    assert s["labelled_per_scene"] == pytest.approx(40 / 3, abs=0.05)
    assert s["positives_per_scene"] == 3.0
    assert s["cpu_ms_per_labelled_grasp"] == pytest.approx(1000 * 2.0 / 40)
    assert coverage_summary([_scene(0, mixed=(5, 0, 0, 0.1))], ["mixed"])["mixed"][
        "coverage"] is None
    with pytest.raises(ValueError, match="no scene"):
        coverage_summary([], ["mixed"])


@pytest.mark.sim
def test_one_scene_is_labelled_by_each_labelling():
    out = scene_coverage(seed=5, index=0, n_reference=12, mixed_n=8, budgets=[16])
    assert out["reference_candidates"] == 12
    for name, n in (("mixed", 8), ("dense_16", 16)):
        assert out[name]["labelled"] <= n
        assert 0 <= out[name]["covered"] <= out["reference_successes"]
        assert out[name]["positives"] <= out[name]["labelled"]
    again = scene_coverage(seed=5, index=0, n_reference=12, mixed_n=8, budgets=[16])
    assert {k: v for k, v in again.items() if k != "mixed" and k != "dense_16"} == {
        k: v for k, v in out.items() if k != "mixed" and k != "dense_16"}
    assert again["mixed"]["covered"] == out["mixed"]["covered"]
