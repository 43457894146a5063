"""Scene protocols: drop (today's), isolated, packed, pile; recorded in campaigns, refused on
resume, flagged by compare, in the environment."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import graspsim  # noqa: F401 - registers the environment
from graspsim.eval.trials import TrialConfig, run_trials
from graspsim.sim.bullet import Simulation
from graspsim.sim.layouts import (
    check_scene,
    make_packed_scene,
    make_pile_scene,
    make_scene_of,
    tilt,
)
from graspsim.sim.scene import build_scene, make_scene, settle

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def sim():
    s = Simulation()
    yield s
    s.close()


def _poses(scene):
    return [(o.spec.name, o.position, o.orientation) for o in scene.objects]


def test_drop_is_todays_scene_and_isolated_the_same_with_one_object(sim, easy_objects):
    for n in (1, 3):
        today = make_scene(sim, easy_objects, np.random.default_rng(4), n_objects=n)
        drop = make_scene_of("drop", sim, easy_objects, np.random.default_rng(4), n_objects=n)
        assert _poses(drop) == _poses(today)
    iso = make_scene_of("isolated", sim, easy_objects, np.random.default_rng(4))
    assert _poses(iso) == _poses(make_scene(sim, easy_objects, np.random.default_rng(4)))


def test_packed_objects_upright_without_overlap(sim, easy_objects):
    scene = make_packed_scene(sim, easy_objects, np.random.default_rng(1), n_objects=4)
    assert len(scene.objects) == 4
    assert all(tilt(o.orientation) < 15.0 for o in scene.objects)
    bodies = build_scene(sim, scene)
    c = sim.client
    for i, a in enumerate(bodies.objects):
        for b in bodies.objects[i + 1:]:
            # touching is allowed (side by side), interpenetration is not
            assert all(cp[8] > -0.002 for cp in c.getClosestPoints(a, b, 0.01))
    # the same generator gives the same scene
    again = make_packed_scene(sim, easy_objects, np.random.default_rng(1), n_objects=4)
    assert _poses(again) == _poses(scene)


def test_pile_on_the_table_after_the_box_is_removed(sim, easy_objects):
    scene = make_pile_scene(sim, easy_objects, np.random.default_rng(2), n_objects=4)
    assert len(scene.objects) == 4
    bodies = build_scene(sim, scene)
    c = sim.client
    assert c.getNumBodies() == 1 + 4  # the table and the objects: the box is gone
    for b in bodies.objects:
        # on the table top, not in it, and near its centre
        assert all(cp[8] > -0.003 for cp in c.getClosestPoints(b, bodies.table, 0.05))
        pos = c.getBasePositionAndOrientation(b)[0]
        assert max(abs(pos[0]), abs(pos[1])) < 0.3 and scene.table_z < pos[2] < 0.3
    start = [np.array(c.getBasePositionAndOrientation(b)[0]) for b in bodies.objects]
    assert settle(sim, bodies.objects, max_time=1.0)  # at rest as described
    moved = [np.linalg.norm(np.array(c.getBasePositionAndOrientation(b)[0]) - p)
             for b, p in zip(bodies.objects, start, strict=True)]
    assert max(moved) < 0.01
    # a heap: dropped at random orientations, not all standing as modelled
    assert max(tilt(o.orientation) for o in scene.objects) > 15.0


def test_bad_scene_input_is_one_line(sim, easy_objects):
    with pytest.raises(ValueError, match="unknown scene 'heap'; use one of drop, isolated"):
        check_scene("heap")
    with pytest.raises(ValueError, match="isolated scene has one object"):
        check_scene("isolated", 3)
    with pytest.raises(ValueError, match=r"object 2 of 6 could not be placed .* 4 cm square"):
        make_packed_scene(sim, easy_objects, np.random.default_rng(0), n_objects=6,
                          half_side=0.02, max_attempts=5)
    with pytest.raises(ValueError, match="n_objects must be an integer >= 1"):
        make_pile_scene(sim, easy_objects, np.random.default_rng(0), n_objects=0)
    with pytest.raises(ValueError, match="unknown scene"):
        run_trials("random", easy_objects, n=1, config=TrialConfig(scene="heap"))


def test_scene_recorded_resume_refused_compare_flags(tmp_path, easy_objects):
    from graspsim.eval.compare import compare_pair

    cfg = TrialConfig(n_candidates=0, n_objects=2, scene="packed")
    out = tmp_path / "packed"
    s = run_trials("mask-pca", easy_objects, n=1, seed=2, out=out, config=cfg)
    assert json.loads((out / "config.json").read_text())["config"]["scene"] == "packed"
    assert "scene packed" in (out / "summary.md").read_text()
    assert len(s["records"][0]["object"]) == 2
    with pytest.raises(ValueError, match="another configuration"):
        run_trials("mask-pca", easy_objects, n=1, seed=2, out=out,
                   config=TrialConfig(n_candidates=0, n_objects=2, scene="pile"))
    drop = tmp_path / "drop"
    run_trials("random", easy_objects, n=1, seed=2, out=drop,
               config=TrialConfig(n_candidates=0, n_objects=2))
    assert json.loads((drop / "config.json").read_text())["config"]["scene"] == "drop"
    with pytest.raises(ValueError, match="scene packed vs drop"):
        compare_pair(out, drop)


def test_rounds_run_on_a_pile(tmp_path, easy_objects):
    from graspsim.eval.declutter import run_rounds

    cfg = TrialConfig(n_candidates=0, n_objects=2, scene="pile")
    s = run_rounds("mask-pca", easy_objects, n=1, seed=1, out=tmp_path / "r", config=cfg)
    assert s["objects_placed"] == 2 and s["rounds"] == 1
    assert json.loads((tmp_path / "r" / "config.json").read_text())["config"]["scene"] == "pile"


def test_scene_cli(tmp_path, capsys):
    from graspsim.cli import main

    assert main(["trials", "--detector", "random", "--scene", "isolated",
                 "--objects-per-scene", "2", "--n", "1", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "isolated scene has one object" in err and err.count("\n") == 1
    with pytest.raises(SystemExit):
        main(["trials", "--detector", "random", "--scene", "heap", "--out", str(tmp_path / "y")])
    assert "invalid choice" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space:UserWarning")
@pytest.mark.parametrize("scene", ["packed", "pile"])
def test_env_with_each_scene(scene, easy_objects):
    boxes = [s for s in easy_objects if s.name == "box_matches"]  # quick to settle
    env = gym.make("graspsim/Grasp-v0", objects=boxes, scene=scene, n_objects=2)
    try:
        check_env(env.unwrapped)
        _, info = env.reset(seed=3)
        assert len(info["objects"]) == 2
        assert env.unwrapped.scene == scene
    finally:
        env.close()
    with pytest.raises(ValueError, match="unknown scene"):
        gym.make("graspsim/Grasp-v0", scene="heap")
