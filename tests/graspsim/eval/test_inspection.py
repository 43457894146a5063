"""Replaying a trial folder phase by phase (graspsim.eval.inspection, scripts/inspect_grasps.py)."""

from __future__ import annotations

import pytest

from graspsim.eval.inspection import inspect_folder
from graspsim.eval.trials import TrialConfig, run_trials

pytestmark = pytest.mark.sim


def test_a_replay_executes_what_the_trials_executed(tmp_path, easy_objects):
    run_trials("mask-pca", easy_objects, n=3, seed=2, out=tmp_path / "t",
               config=TrialConfig(n_candidates=0))
    rows = list(inspect_folder(tmp_path / "t"))
    assert rows, "mask-pca proposed nothing"
    for row in rows:
        assert row["reason"] == row["recorded_reason"]  # the same scene, the same harness
        assert set(row["phases"]) >= {"approach"}
        assert "contacts" in row["phases"]["approach"]
        for phase in row["phases"].values():
            assert set(phase["pads"]) == {0, 1}
    names = {o.name for o in easy_objects}
    none = list(inspect_folder(tmp_path / "t", objects=["not_an_object"]))
    assert none == [] and names


def test_a_folder_without_config_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="config.json"):
        next(inspect_folder(tmp_path))
