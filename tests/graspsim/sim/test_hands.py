"""The hands: the Franka hand loads from pybullet_data, opens to 8 cm, lifts an easy object; its
geometry reaches the depth checks; recorded with the campaign and named by compare. The WSG 50
and the Robotiq 2F-85: their URDFs load, their fingers open to their stroke and close, their
opening limits reach the gripper-aware check, their graspable flags are committed, a short
trial runs with each."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import graspsim  # noqa: F401 - registers the environment
from dlsr.rectangles import GraspRectangle
from graspsim.eval.trials import TrialConfig, campaign_execution_params, run_trials
from graspsim.sim.bullet import Simulation
from graspsim.sim.execution import (
    ExecutionParams,
    describe_changes,
    execution_changes,
    execution_params_from_dict,
)
from graspsim.sim.grasp import fingers_collide, rectangle_to_grasp
from graspsim.sim.gripper import Gripper, GripperParams, hand_params
from graspsim.sim.hands import (
    BUILTIN,
    FRANKA,
    FRANKA_FORCE,
    HAND_NAMES,
    ROBOTIQ_2F85,
    ROBOTIQ_2F85_FORCE,
    WSG50,
    WSG50_FORCE,
    hand_force,
    hand_geometry,
    hand_urdf,
)

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
    with pytest.raises(ValueError, match="unknown gripper 'robotiq'; use one of builtin, franka, "
                                         "wsg50, robotiq-2f85"):
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
    from graspsim.eval.compare import compare_pair, comparison_text

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
    from graspsim.eval.declutter import run_rounds

    out = tmp_path / "rounds"
    s = run_rounds("mask-pca", easy_objects, n=1, seed=1, out=out, params=FRANKA_PARAMS,
                   config=TrialConfig(n_candidates=0, n_objects=2, scene="packed"))
    assert s["rounds"] == 1 and s["attempts"] >= 1
    assert campaign_execution_params(out) == FRANKA_PARAMS
    assert "gripper.hand = franka" in (out / "summary.md").read_text()


NEW_HANDS = ("wsg50", "robotiq-2f85")


@pytest.mark.parametrize("hand", HAND_NAMES)
def test_every_hand_loads_with_two_prismatic_fingers_at_half_its_stroke(hand):
    import pybullet as pb

    geo = hand_geometry(hand)
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(hand_urdf(hand)), physicsClientId=client)
        assert pb.getNumJoints(body, physicsClientId=client) == 2
        for j in (0, 1):
            info = pb.getJointInfo(body, j, physicsClientId=client)
            assert info[2] == pb.JOINT_PRISMATIC
            assert (info[8], info[9]) == pytest.approx((0.0, geo.max_opening / 2))
        # the left finger (joint 0) opens towards -x, the right (joint 1) towards +x
        axes = [pb.getJointInfo(body, j, physicsClientId=client)[13] for j in (0, 1)]
        assert axes[0][0] == pytest.approx(-1.0) and axes[1][0] == pytest.approx(1.0)
    finally:
        pb.disconnect(client)


@pytest.mark.parametrize("hand", NEW_HANDS)
def test_new_hands_open_to_their_stroke_close_and_reach_1_cm_beyond_the_tcp(hand):
    geo = hand_geometry(hand)
    sim = Simulation()
    try:
        g = Gripper(sim, _down(0.4), opening=geo.max_opening, params=hand_params(hand))
        sim.step(30)
        assert g.opening() == pytest.approx(geo.max_opening, abs=1e-3)
        g.set_opening(0.3)  # clipped to the stroke
        sim.step(30)
        assert g.opening() == pytest.approx(geo.max_opening, abs=1e-3)
        g.set_opening(0.05)
        sim.step(60)
        assert g.opening() == pytest.approx(0.05, abs=1e-3)
        g.close()
        sim.step(240)
        assert g.opening() < 0.002
        c = sim.client
        floor = c.createMultiBody(0, c.createCollisionShape(c.GEOM_BOX, halfExtents=[.3, .3, .01]),
                                  -1, [0, 0, 0.1])
        tip = min(cp[8] for j in (0, 1)
                  for cp in c.getClosestPoints(g.body, floor, 1.0, linkIndexA=j))
        assert tip == pytest.approx(0.4 - 0.11 - geo.tip_offset, abs=5e-4)
        # nothing of the palm lies nearer the fingertips than the geometry's palm face
        palm = min(cp[8] for cp in c.getClosestPoints(g.body, floor, 1.0, linkIndexA=-1))
        assert palm >= 0.4 - 0.11 + geo.palm_offset - 5e-4
    finally:
        sim.close()


def test_new_hands_dimensions_and_forces():
    assert (WSG50.max_opening, ROBOTIQ_2F85.max_opening) == (0.110, 0.085)
    assert (WSG50_FORCE, ROBOTIQ_2F85_FORCE) == (80.0, 235.0)
    assert hand_force("builtin") is None and hand_force("franka") == FRANKA_FORCE
    for hand, geo, force in (("wsg50", WSG50, WSG50_FORCE),
                             ("robotiq-2f85", ROBOTIQ_2F85, ROBOTIQ_2F85_FORCE)):
        p = hand_params(hand)
        assert (p.hand, p.finger_force, p.geometry) == (hand, force, geo)
        assert geo.pad_length == pytest.approx(geo.tip_offset + geo.palm_offset)
        assert ExecutionParams.with_hand(hand).gripper == p
    assert ROBOTIQ_2F85.pad_width == 0.022 and WSG50.pad_width == 0.020


def _wide_rectangle_scene():
    """A 4.7 cm block on a table 0.75 m below the camera and a rectangle 10.4 cm wide at the
    block's top: within the WSG 50's 110 mm, beyond the other hands' reach."""
    F, CX, CY = 550.0, 319.5, 239.5
    K = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1.0]])
    depth = np.full((480, 640), 0.75, np.float32)
    depth[200:280, 300:340] = 0.65
    obs = {"depth": depth, "depth_valid": np.ones(depth.shape, bool), "K": K}
    return obs, GraspRectangle(CX, CY, 0.0, 88.0, 20.0)


@pytest.mark.parametrize("hand", HAND_NAMES)
def test_opening_limits_reach_the_pose_and_the_gripper_aware_check(hand):
    from graspsim.detectors import executable, gripper_aware
    from graspsim.sim.grasp import TOO_WIDE

    obs, rect = _wide_rectangle_scene()
    geo = hand_geometry(hand)
    g = rectangle_to_grasp(rect, obs["depth"], obs["depth_valid"], obs["K"], np.eye(4),
                           max_opening=geo.max_opening, geometry=geo)
    assert g.width == pytest.approx(0.104, abs=1e-3)
    assert g.opening <= geo.max_opening  # the commanded opening is clamped to the stroke
    assert (g.failure == TOO_WIDE) == (hand != "wsg50")
    fits = executable([rect], obs, hand=hand)
    assert list(fits) == [hand == "wsg50"]

    class Fixed:  # a detector proposing the wide rectangle, then a narrow one
        def predict(self, obs):
            return [rect, GraspRectangle(rect.x, rect.y, 0.0, 60.0, 20.0)]

        def detect(self, obs):
            from dlsr.detection import Detection
            from dlsr.rectangles import rects_to_array

            return Detection(rects_to_array(self.predict(obs)), np.array([2.0, 1.0]))

    aware = gripper_aware(Fixed(), hand=hand)
    assert aware.hand == hand
    kept = aware.predict(obs)
    assert (rect in kept) == (hand == "wsg50")
    assert len(aware.detect(obs).rects) == len(kept)


@pytest.mark.parametrize("hand", NEW_HANDS)
def test_new_hands_graspable_flags_are_committed(hand):
    from graspsim.labels.graspability import graspability_flags, gripper_key

    params = ExecutionParams.with_hand(hand)
    assert gripper_key(params)["gripper"]["max_opening"] == hand_geometry(hand).max_opening
    assert gripper_key(params)["execution"]["gripper"]["hand"] == hand
    flags = graspability_flags("test", params=params)
    assert flags is not None and len(flags) == 15
    assert all(isinstance(v, bool) for v in flags.values())
    # the builtin hand's key is what it was (the committed builtin flags are read back)
    assert gripper_key()["gripper"]["max_opening"] == 0.08
    assert graspability_flags("test") is not None


@pytest.mark.parametrize("hand", NEW_HANDS)
def test_a_short_trial_with_each_new_hand(tmp_path, hand):
    from graspsim.cli import build_parser
    from graspsim.sim.object_sets import as_object_set

    parser = build_parser()
    for command in (["trials", "--detector", "mask-pca", "--declutter", "--out", "o"],
                    ["dataset", "--out", "o", "--scenes", "1"],
                    ["objects", "test"]):
        assert parser.parse_known_args([*command, "--gripper", hand])[0].gripper == hand

    params = ExecutionParams.with_hand(hand)
    out = tmp_path / hand
    s = run_trials("mask-pca", as_object_set("test").specs(), n=2, seed=0, out=out,
                   config=TrialConfig(n_candidates=0), params=params)
    assert s["n"] == 2 and 0 <= s["successes"] <= 2
    assert campaign_execution_params(out) == params
    assert f"gripper.hand = {hand}" in (out / "summary.md").read_text()


def test_hands_picture_draws_each_hand_at_one_scale():
    from graspsim.eval.trialviz import hands_picture

    img = hands_picture(["builtin", "wsg50"], spacing=0.2, px_per_mm=0.5, height=0.3)
    assert img.shape == (150, 200, 3) and img.dtype == np.uint8
    drawn = np.any(np.abs(img.astype(int) - img[0, 0].astype(int)) > 30, axis=2)
    body = drawn[40:130]  # between the names and the ruler
    # the widest part of each hand at 0.5 px per mm: the built-in palm (110 mm), the WSG 50's
    # open jaws with the fingers' roots (110 mm between the pads + 2 x 23 mm)
    for half, mm in ((body[:, :100], BUILTIN.palm_length * 1000),
                     (body[:, 100:], WSG50.max_opening * 1000 + 46)):
        cols = np.flatnonzero(half.any(axis=0))
        assert cols[-1] - cols[0] + 1 == pytest.approx(mm * 0.5, abs=2)
    with pytest.raises(ValueError, match="unknown gripper"):
        hands_picture(["robotiq"])


def test_new_hands_in_the_environment_clutter_rounds_and_run_configs(tmp_path, easy_objects):
    from graspsim.eval.declutter import run_rounds
    from graspsim.pipeline import RunConfig

    env = gym.make("graspsim/Grasp-v0", objects=[s for s in easy_objects
                                                 if s.name == "can_tall"],
                   gripper="wsg50")
    try:
        assert env.unwrapped._params.gripper == hand_params("wsg50")
        env.reset(seed=0)
        _, reward, terminated, _, step = env.step(env.action_space.sample())
        assert terminated and reward in (0.0, 1.0) and "failure_reason" in step
    finally:
        env.close()
    params = ExecutionParams.with_hand("robotiq-2f85")
    out = tmp_path / "rounds"
    s = run_rounds("mask-pca", easy_objects, n=1, seed=1, out=out, params=params,
                   config=TrialConfig(n_candidates=0, n_objects=2, scene="packed"))
    assert s["rounds"] == 1 and s["attempts"] >= 1
    assert campaign_execution_params(out) == params
    assert RunConfig(gripper="robotiq-2f85").validated().execution_params() == params
    with pytest.raises(ValueError, match="gripper must be one of builtin, franka, wsg50, "
                                         "robotiq-2f85"):
        RunConfig(gripper="robotiq").validated()
