"""The Franka hand: loads from pybullet_data, opens to 8 cm, lifts an easy object; its geometry
reaches the depth checks; recorded with the campaign and named by compare."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import graspsim  # noqa: F401 - registers the environment
from dlsr.rectangles import GraspRectangle
from graspsim.execution import (
    ExecutionParams,
    describe_changes,
    execution_changes,
    execution_params_from_dict,
)
from graspsim.grasp import fingers_collide, rectangle_to_grasp
from graspsim.gripper import Gripper, GripperParams, hand_params
from graspsim.hands import BUILTIN, FRANKA, FRANKA_FORCE, hand_geometry, hand_urdf
from graspsim.sim import Simulation
from graspsim.trials import TrialConfig, campaign_execution_params, run_trials

pytestmark = pytest.mark.sim

FRANKA_PARAMS = ExecutionParams(gripper=hand_params("franka"))


def _down(z):
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = z
    return T


def test_franka_hand_opens_to_8_cm_and_closes():
    sim = Simulation()
    try:
        g = Gripper(sim, _down(0.4), opening=0.08, params=hand_params("franka"))
        assert sim.client.getNumJoints(g.body) == 2
        sim.step(30)
        assert g.opening() == pytest.approx(0.08, abs=1e-3)
        g.set_opening(0.2)  # clipped to the stroke
        sim.step(30)
        assert g.opening() == pytest.approx(0.08, abs=1e-3)
        g.close()
        sim.step(240)
        assert g.opening() < 0.002
        # its fingertips (collision surface) end 1 cm beyond the TCP, as the built-in hand's
        c = sim.client
        floor = c.createMultiBody(0, c.createCollisionShape(c.GEOM_BOX, halfExtents=[.3, .3, .01]),
                                  -1, [0, 0, 0.1])
        tip = min(cp[8] for j in (0, 1)
                  for cp in c.getClosestPoints(g.body, floor, 1.0, linkIndexA=j))
        assert tip == pytest.approx(0.4 - 0.11 - FRANKA.tip_offset, abs=5e-4)
    finally:
        sim.close()


def test_franka_parameters_and_bad_names():
    p = hand_params("franka")
    assert p.hand == "franka" and p.finger_force == FRANKA_FORCE == 70.0
    assert hand_params("builtin") == GripperParams()
    assert hand_geometry("franka") is FRANKA and GripperParams().geometry is BUILTIN
    assert FRANKA.max_opening == 0.08 and FRANKA.finger_thickness > BUILTIN.finger_thickness
    assert hand_urdf("franka").is_file()
    with pytest.raises(ValueError, match="unknown gripper 'robotiq'; use one of builtin, franka"):
        GripperParams(hand="robotiq")
    with pytest.raises(ValueError, match="unknown gripper"):
        hand_params("robotiq")
    with pytest.raises(ValueError, match="cfg.json: the execution parameters do not match"):
        execution_params_from_dict({"gripper": {"hand": "robotiq"}}, "cfg.json")


def test_the_hands_finger_geometry_reaches_the_depth_check():
    """A second block 1.1 cm beyond the open pads: clear of the built-in 8 mm fingers, under the
    Franka hand's 15 mm ones."""
    F, CX, CY = 550.0, 319.5, 239.5
    K = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1.0]])
    depth = np.full((480, 640), 0.75, np.float32)
    depth[200:280, 300:340] = 0.65  # the block grasped, 4.7 cm wide
    depth[200:280, 359:380] = 0.65  # its neighbour
    valid = np.ones(depth.shape, bool)
    table = np.full(depth.shape, 0.75)
    rect = GraspRectangle(CX, CY, 0.0, 52.0, 20.0)
    verdicts = {}
    for geo in (BUILTIN, FRANKA):
        g = rectangle_to_grasp(rect, depth, valid, K, _down(0.75), geometry=geo)
        assert g.failure is None
        verdicts[geo] = fingers_collide(g, depth, valid, K, _down(0.75), table, geometry=geo)
    assert verdicts == {BUILTIN: False, FRANKA: True}


def test_franka_lifts_an_easy_object_and_is_recorded(tmp_path, easy_objects):
    from graspsim.compare import compare_pair, comparison_text

    can = [s for s in easy_objects if s.name == "can_tall"]
    cfg = TrialConfig(n_candidates=12)
    franka = tmp_path / "franka"
    s = run_trials("oracle", can, n=1, seed=0, out=franka, config=cfg, params=FRANKA_PARAMS)
    assert s["successes"] == 1  # the oracle's best labelled grasp lifts the can
    assert json.loads((franka / "config.json").read_text())["execution"]["gripper"]["hand"] == (
        "franka")
    assert campaign_execution_params(franka) == FRANKA_PARAMS
    assert "gripper.hand = franka" in (franka / "summary.md").read_text()
    with pytest.raises(ValueError, match="another configuration"):
        run_trials("oracle", can, n=1, seed=0, out=franka, config=cfg)
    builtin = tmp_path / "builtin"
    run_trials("oracle", can, n=1, seed=0, out=builtin, config=cfg)
    c = compare_pair(franka, builtin)
    assert c["execution"]["a"] == {"gripper.finger_force": 70.0, "gripper.hand": "franka"}
    assert "gripper.hand = franka" in comparison_text(c)
    assert describe_changes(execution_changes(FRANKA_PARAMS)) == (
        "gripper.finger_force = 70.0, gripper.hand = franka")


def test_gripper_cli_and_env(tmp_path, capsys, easy_objects):
    from graspsim.cli import main

    with pytest.raises(SystemExit):
        main(["trials", "--detector", "random", "--gripper", "robotiq",
              "--out", str(tmp_path / "x")])
    assert "invalid choice" in capsys.readouterr().err
    out = tmp_path / "cli"
    assert main(["trials", "--detector", "mask-pca", "--gripper-aware", "--gripper", "franka",
                 "--objects", "can_tall", "--n", "1", "--candidates", "0",
                 "--out", str(out)]) == 0
    assert campaign_execution_params(out) == FRANKA_PARAMS
    env = gym.make("graspsim/Grasp-v0", objects=[s for s in easy_objects
                                                 if s.name == "box_matches"],
                   gripper="franka")
    try:
        assert env.unwrapped._params.gripper.hand == "franka"
        obs, info = env.reset(seed=0)
        _, reward, terminated, _, step = env.step(env.action_space.sample())
        assert terminated and reward in (0.0, 1.0) and "failure_reason" in step
    finally:
        env.close()


def test_clutter_rounds_with_the_franka_hand(tmp_path, easy_objects):
    from graspsim.declutter import run_rounds

    out = tmp_path / "rounds"
    s = run_rounds("mask-pca", easy_objects, n=1, seed=1, out=out, params=FRANKA_PARAMS,
                   config=TrialConfig(n_candidates=0, n_objects=2, scene="packed"))
    assert s["rounds"] == 1 and s["attempts"] >= 1
    assert campaign_execution_params(out) == FRANKA_PARAMS
    assert "gripper.hand = franka" in (out / "summary.md").read_text()
