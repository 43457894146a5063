"""Execution parameters as campaigns and datasets save them (no simulation)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict

import pytest

from graspsim.sim.execution import ExecutionParams, execution_changes, execution_params_from_dict
from graspsim.sim.gripper import GripperParams


def test_params_survive_json():
    p = ExecutionParams(min_grip=0.01, approach_speed=0.05,
                        gripper=GripperParams(finger_force=30.0))
    back = execution_params_from_dict(json.loads(json.dumps(asdict(p))), "config.json")
    assert back == p and back != ExecutionParams()


def test_missing_fields_take_their_defaults():
    assert execution_params_from_dict({}, "config.json") == ExecutionParams()
    p = execution_params_from_dict({"min_grip": 0.02}, "config.json")
    assert p.min_grip == 0.02 and p.gripper == GripperParams()
    p = execution_params_from_dict({"gripper": {"finger_force": 20.0}}, "config.json")
    assert p.gripper.finger_force == 20.0 and p.gripper.arm_force == GripperParams().arm_force


@pytest.mark.parametrize("d, what", [
    ({"speed_of_light": 1.0}, "speed_of_light"),
    ({"gripper": {"finger_force": 1.0, "colour": "red"}}, "colour"),
    ({"min_grip": -0.001}, "min_grip"),
    ({"gripper": 3}, "not a JSON object"),
    ([0.1, 0.5], "not a JSON object"),
])
def test_bad_parameters_name_the_file(d, what):
    with pytest.raises(ValueError, match="runs/x/config.json") as err:
        execution_params_from_dict(d, "runs/x/config.json")
    assert what in str(err.value)


@pytest.mark.parametrize("bad", [-0.01, math.nan])
def test_min_grip_must_be_a_length(bad):
    with pytest.raises(ValueError, match="min_grip"):
        ExecutionParams(min_grip=bad)
    assert ExecutionParams(min_grip=0.0).min_grip == 0.0


def test_changes_name_what_differs_from_the_defaults():
    assert execution_changes(None) == {}
    assert execution_changes(ExecutionParams()) == {}
    p = ExecutionParams(min_grip=0.01, gripper=GripperParams(finger_force=30.0))
    assert execution_changes(p) == {"min_grip": 0.01, "gripper.finger_force": 30.0}
