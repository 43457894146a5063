"""Simulator wrapper, scenes and grasp execution: determinism, isolation, physical outcomes."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.rectangles import GraspRectangle
from graspsim.sim.bullet import Simulation
from graspsim.sim.camera import DepthNoise
from graspsim.sim.execution import COLLISION, NOTHING, ExecutionParams, precheck_grasps, run_grasp
from graspsim.sim.grasp import TOO_WIDE, rectangle_to_grasp
from graspsim.sim.objects import ObjectSpec
from graspsim.sim.scene import PlacedObject, Scene, build_scene, capture, make_scene

pytestmark = pytest.mark.sim

BOX_URDF = """<?xml version="1.0"?>
<robot name="box">
  <link name="box">
    <inertial><origin xyz="0 0 0"/><mass value="0.1"/>
      <inertia ixx="5e-5" ixy="0" ixz="0" iyy="5e-5" iyz="0" izz="5e-5"/></inertial>
    <visual><geometry><box size="{x} {y} {z}"/></geometry>
      <material name="c"><color rgba="0.8 0.2 0.2 1"/></material></visual>
    <collision><geometry><box size="{x} {y} {z}"/></geometry></collision>
  </link>
</robot>
"""


@pytest.fixture(scope="module")
def box_spec(tmp_path_factory):
    """A 3 x 6 x 4 cm box, independent of the built-in object set."""
    d = tmp_path_factory.mktemp("box")
    path = d / "box.urdf"
    path.write_text(BOX_URDF.format(x=0.03, y=0.06, z=0.04))
    return ObjectSpec(name="box", urdf=path, mass=0.1, friction=0.8, size=(0.03, 0.06, 0.04))


@pytest.fixture(scope="module")
def rod_spec(tmp_path_factory):
    """A square rod 6 x 6 mm, 20 cm long along y, 8 g, with its true (very anisotropic) inertia."""
    m, t, length = 0.008, 0.006, 0.2
    d = tmp_path_factory.mktemp("rod")
    path = d / "rod.urdf"
    text = BOX_URDF.format(x=t, y=length, z=t)
    text = text.replace('<mass value="0.1"/>', f'<mass value="{m}"/>')
    roll, tumble = m * t**2 / 6, m * (length**2 + t**2) / 12
    text = text.replace('ixx="5e-5"', f'ixx="{tumble:.6g}"').replace(
        'iyy="5e-5"', f'iyy="{roll:.6g}"').replace('izz="5e-5"', f'izz="{tumble:.6g}"')
    path.write_text(text)
    return ObjectSpec(name="rod", urdf=path, mass=m, friction=0.8, size=(t, length, t))


@pytest.fixture(scope="module")
def sim():
    s = Simulation()
    yield s
    s.close()


def box_scene(spec):
    return Scene([PlacedObject(spec, (0.0, 0.0, 0.02), (0.0, 0.0, 0.0, 1.0))])


def frame_of(sim, scene, seed=0):
    bodies = build_scene(sim, scene)
    return bodies, capture(sim, scene, bodies, np.random.default_rng(seed),
                           noise=DepthNoise.off())


def project(frame, p_world):
    T_cw = np.linalg.inv(frame.T_world_cam)
    p = T_cw @ np.append(p_world, 1.0)
    uv = (frame.intrinsics.K @ p[:3])[:2] / p[2]
    return uv


def box_rect(frame, along_world, w_m, offset=(0.0, 0.0)):
    """A rectangle centred on the box (plus a world offset) closing along a world direction."""
    c = np.array([offset[0], offset[1], 0.04])
    uv = project(frame, c)
    uv2 = project(frame, c + 0.01 * np.asarray(along_world, float))
    d = uv2 - uv
    theta = np.arctan2(-d[1], d[0])
    z = (np.linalg.inv(frame.T_world_cam) @ np.append(c, 1.0))[2]
    w = w_m * frame.intrinsics.fx / z
    return GraspRectangle(uv[0], uv[1], theta, w, 15.0)


def test_grasp_across_the_narrow_side_lifts_the_box(sim, box_spec):
    scene = box_scene(box_spec)
    _, frame = frame_of(sim, scene)
    rect = box_rect(frame, (1, 0, 0), 0.05)  # across the 3 cm side
    g = rectangle_to_grasp(rect, frame.depth, frame.depth_valid, frame.intrinsics,
                           frame.T_world_cam)
    res = run_grasp(sim, scene, g)
    assert res.success, res.reason
    assert res.lift_height >= 0.10


def test_centred_grasps_lift_a_thin_rod_lying_on_the_table(sim, rod_spec):
    # Before condition_inertia and the 1 mm tip clearance, pybullet rolled such a rod between
    # the pads and squeezed it out under the fingertips (1 of these 4 grasps held).
    t = rod_spec.size[0]
    for yaw in np.radians([0.0, 20.0, 45.0, 70.0]):
        q = (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
        bodies = build_scene(sim, Scene([PlacedObject(rod_spec, (0.0, 0.0, t / 2 + 0.001), q)]))
        sim.step(120)  # at rest on the table
        scene = Scene([PlacedObject(
            rod_spec, *sim.client.getBasePositionAndOrientation(bodies.objects[0]))])
        _, frame = frame_of(sim, scene)
        c = np.array([0.0, 0.0, t / 2])
        across = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        uv, uv2 = project(frame, c), project(frame, c + 0.01 * across)
        z = (np.linalg.inv(frame.T_world_cam) @ np.append(c, 1.0))[2]
        rect = GraspRectangle(uv[0], uv[1], np.arctan2(-(uv2 - uv)[1], (uv2 - uv)[0]),
                              0.015 * frame.intrinsics.fx / z, 15.0)
        g = rectangle_to_grasp(rect, frame.depth, frame.depth_valid, frame.intrinsics,
                               frame.T_world_cam)
        res = run_grasp(sim, scene, g)
        assert res.success, (np.degrees(yaw), res.reason)


def test_failures_have_their_reasons(sim, box_spec):
    scene = box_scene(box_spec)
    _, frame = frame_of(sim, scene)
    args = (frame.depth, frame.depth_valid, frame.intrinsics, frame.T_world_cam)
    # Beside the box (on the table): the jaws close on nothing.
    beside = rectangle_to_grasp(box_rect(frame, (1, 0, 0), 0.02, offset=(0.08, 0.0)), *args)
    assert run_grasp(sim, scene, beside).reason == NOTHING
    # Across the 6 cm side with a 5 cm opening: the fingers land on the box.
    narrow = rectangle_to_grasp(box_rect(frame, (0, 1, 0), 0.05), *args)
    assert run_grasp(sim, scene, narrow).reason == COLLISION
    # Wider than the gripper: not executed.
    wide = rectangle_to_grasp(box_rect(frame, (1, 0, 0), 0.12), *args)
    res = run_grasp(sim, scene, wide)
    assert res.reason == TOO_WIDE and not res.success and res.steps == 0


def test_precheck_decides_only_the_obvious_outcomes(sim, box_spec):
    scene = box_scene(box_spec)
    _, frame = frame_of(sim, scene)
    args = (frame.depth, frame.depth_valid, frame.intrinsics, frame.T_world_cam)
    grasps = [
        rectangle_to_grasp(box_rect(frame, (1, 0, 0), 0.02, offset=(0.08, 0.0)), *args),
        rectangle_to_grasp(box_rect(frame, (0, 1, 0), 0.05), *args),  # pads land on the box
        rectangle_to_grasp(box_rect(frame, (1, 0, 0), 0.05), *args),  # a good grasp
        rectangle_to_grasp(box_rect(frame, (1, 0, 0), 0.12), *args),  # too wide
    ]
    pre = precheck_grasps(sim, scene, grasps)
    assert [None if r is None else r.reason for r in pre] == [NOTHING, COLLISION, None, TOO_WIDE]
    assert all(r.steps == 0 and not r.success for r in pre if r is not None)
    for g, r in zip(grasps, pre, strict=True):
        if r is not None:  # the full execution agrees
            assert run_grasp(sim, scene, g).reason == r.reason


def test_hold_until_still_ends_a_firm_grasp_early(sim, box_spec):
    scene = box_scene(box_spec)
    _, frame = frame_of(sim, scene)
    g = rectangle_to_grasp(box_rect(frame, (1, 0, 0), 0.05), frame.depth, frame.depth_valid,
                           frame.intrinsics, frame.T_world_cam)
    full = run_grasp(sim, scene, g)
    early = run_grasp(sim, scene, g, ExecutionParams(hold_until_still=True))
    assert full.success and early.success
    assert early.steps < full.steps
    assert early.lift_height >= 0.10


def test_same_seed_and_commands_same_result(box_spec):
    specs = [box_spec]

    def episode(sim, seed):
        rng = np.random.default_rng(seed)
        scene = make_scene(sim, specs, rng)
        _, frame = frame_of(sim, scene, seed)
        rect = box_rect(frame, (1, 0, 0), 0.05, offset=scene.objects[0].position[:2])
        g = rectangle_to_grasp(rect, frame.depth, frame.depth_valid, frame.intrinsics,
                               frame.T_world_cam)
        res = run_grasp(sim, scene, g)
        return scene.to_dict(), frame.rgb, res.to_dict(), sim.client.getBasePositionAndOrientation(
            sim.client.getBodyUniqueId(1))

    a, b = Simulation(), Simulation()
    try:
        first = episode(a, 7)
        # Other work in between, in the same and in another instance, changes nothing.
        episode(a, 8)
        episode(b, 9)
        again = episode(a, 7)
        other = episode(b, 7)
    finally:
        a.close()
        b.close()
    for res in (again, other):
        assert res[0] == first[0]
        assert np.array_equal(res[1], first[1])
        assert res[2] == first[2]
        assert res[3] == first[3]  # bit-for-bit object pose after the lift


def test_instances_are_isolated(box_spec):
    a, b = Simulation(), Simulation()
    try:
        build_scene(a, box_scene(box_spec))
        assert a.client.getNumBodies() == 2
        assert b.client.getNumBodies() == 0
        b.step(10)
        assert a.steps == 0
        a.close()
        a.close()  # idempotent
        b.reset()
        assert b.client.getNumBodies() == 0
    finally:
        b.close()


def test_settled_scene_reloads_at_rest(sim, box_spec):
    scene = make_scene(sim, [box_spec], np.random.default_rng(3))
    bodies = build_scene(sim, scene)
    p0 = np.array(sim.client.getBasePositionAndOrientation(bodies.objects[0])[0])
    sim.step(120)
    p1 = np.array(sim.client.getBasePositionAndOrientation(bodies.objects[0])[0])
    assert np.linalg.norm(p1 - p0) < 2e-3
    assert scene.objects[0].position[2] > 0.0


def _settle_failing(monkeypatch, n_fail):
    """``graspsim.sim.scene.settle`` that reports "still moving" for its first ``n_fail`` calls
    (all of them when None), then the real one; returns the list of calls' results."""
    import graspsim.sim.scene as scene_mod

    real, calls = scene_mod.settle, []

    def fake(sim, bodies, **kw):
        ok = False if n_fail is None or len(calls) < n_fail else real(sim, bodies, **kw)
        calls.append(ok)
        return ok

    monkeypatch.setattr(scene_mod, "settle", fake)
    return calls


def test_a_pile_that_does_not_rest_is_started_again(sim, box_spec, monkeypatch):
    calls = _settle_failing(monkeypatch, 3)
    scene = make_scene(sim, [box_spec], np.random.default_rng(3), n_objects=2,
                       max_redraws=2, restarts=1)
    assert len(scene.objects) == 2
    assert calls[:3] == [False, False, False] and all(calls[3:])
    assert len(scene.redraws) == 4  # three re-draws and the restart
    assert "started again (1 of 1)" in scene.redraws[-1]


def test_a_scene_that_never_rests_names_its_attempts(sim, box_spec, monkeypatch):
    calls = _settle_failing(monkeypatch, None)
    with pytest.raises(ValueError, match=r"3 re-draws in each of 3 attempts.*'box'"):
        make_scene(sim, [box_spec], np.random.default_rng(3), max_redraws=2, restarts=2)
    assert len(calls) == 9


def test_restarts_do_not_change_a_scene_that_rests(sim, box_spec):
    a = make_scene(sim, [box_spec], np.random.default_rng(5), n_objects=2, restarts=0)
    b = make_scene(sim, [box_spec], np.random.default_rng(5), n_objects=2)
    assert a.to_dict() == b.to_dict()


def test_a_scene_that_cannot_be_made_is_named(sim, box_spec, monkeypatch):
    import graspsim.sim.observe as trials_mod

    def fail(*args, **kwargs):
        raise ValueError("could not make a scene: 21 re-draws")

    monkeypatch.setattr(trials_mod, "make_scene_of", fail)
    with pytest.raises(ValueError, match=r"^scene 4 of seed 9: could not make a scene"):
        trials_mod.observe_scene(sim, [box_spec], 9, 4)
