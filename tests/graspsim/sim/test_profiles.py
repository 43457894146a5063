"""Simulation profiles: named camera, table, lighting and noise settings."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from graspsim.sim.camera import DepthNoise, LightRanges, random_lights
from graspsim.sim.profiles import PROFILES, SimProfile, get_profile, profile_changes
from graspsim.sim.scene import table_colour


def test_get_profile_resolves_names_and_refuses_unknown_ones():
    assert get_profile(None) == get_profile("default") == SimProfile()
    p = replace(SimProfile(), name="mine", camera_height=(0.5, 0.5))
    assert get_profile(p) is p
    with pytest.raises(ValueError, match="unknown simulation profile 'nope'.*jacquard"):
        get_profile("nope")


SOFT = LightRanges(elevation=(60.0, 90.0), ambient=(0.6, 0.75), diffuse=(0.2, 0.35), shadow=0.0)
LOOK = replace(SimProfile(), name="look", table="grey", lighting=SOFT)


def test_jacquard_profile_changes_exactly_the_settings_it_names():
    assert profile_changes("default") == []
    assert profile_changes("jacquard") == ["depth_noise"]
    j = PROFILES["jacquard"]
    assert j.depth_noise == DepthNoise.off() and not j.depth_noise.any
    assert profile_changes(LOOK) == ["table", "lighting"]


def test_profile_settings_are_checked_and_serialisable():
    with pytest.raises(ValueError, match="camera_height"):
        SimProfile(camera_height=(0.8, 0.6))
    with pytest.raises(ValueError, match="unknown table 'wood'"):
        SimProfile(table="wood")
    with pytest.raises(ValueError, match="LightRanges.ambient"):
        LightRanges(ambient=(0.7, 0.4))
    with pytest.raises(ValueError, match="probability"):
        LightRanges(shadow=1.5)
    d = json.loads(json.dumps(LOOK.to_dict()))
    assert d["table"] == "grey" and d["lighting"]["elevation"] == [60.0, 90.0]
    assert d["depth_noise"]["shadow"] is True and d["intrinsics"]["fx"] == 550.0
    assert json.loads(json.dumps(PROFILES["jacquard"].to_dict()))["depth_noise"]["shadow"] is False


def test_light_ranges_bound_the_draws_and_keep_the_stream():
    """Other ranges give lights inside them, from the same number of draws."""
    soft = SOFT
    for seed in range(20):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        la, lb = random_lights(a), random_lights(b, soft)
        assert a.random() == b.random()  # the next draw (the depth noise's) is the same
        assert la == random_lights(np.random.default_rng(seed), LightRanges())
        assert 0.6 <= lb.ambient <= 0.75 and 0.2 <= lb.diffuse <= 0.35 and not lb.shadow
        assert lb.direction[2] >= np.sin(np.deg2rad(60.0)) - 1e-12
        assert 0.45 <= la.ambient <= 0.7


def test_table_colour_grey_from_the_same_draws():
    rng = np.random.default_rng(0)
    for d in rng.uniform(0.25, 0.75, size=(50, 3)):
        r = table_colour(d)
        assert r == (*(float(v) for v in d), 1.0)
        g = table_colour(d, "grey")
        assert g[0] == g[1] == g[2] and 0.6 <= g[0] <= 0.8 and g[3] == 1.0
    assert table_colour([0.25] * 3, "grey")[0] == pytest.approx(0.6)
    assert table_colour([0.75] * 3, "grey")[0] == pytest.approx(0.8)
    with pytest.raises(ValueError, match="unknown table colour"):
        table_colour([0.5] * 3, "wood")


@pytest.mark.sim
def test_profile_changes_the_look_not_the_scene_or_the_depth(easy_objects):
    """Under a grey table and soft light the same scene is seen from the same pose with the
    same depth; only the table colour and the light differ. Under "jacquard" only the depth
    does (it is the clean depth). A closer camera sees the object larger."""
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.observe import observe_scene

    sim = Simulation()
    try:
        s0, b0, f0, _ = observe_scene(sim, easy_objects, 3, 0)
        objects0 = [(o.spec.name, o.position, o.orientation) for o in s0.objects]
        area0 = np.isin(f0.segmentation, b0.objects).sum()
        s1, _, f1, _ = observe_scene(sim, easy_objects, 3, 0, profile=LOOK)
        assert [(o.spec.name, o.position, o.orientation) for o in s1.objects] == objects0
        np.testing.assert_array_equal(f1.T_world_cam, f0.T_world_cam)
        np.testing.assert_array_equal(f1.depth, f0.depth)
        np.testing.assert_array_equal(f1.depth_valid, f0.depth_valid)
        assert s1.table_rgba[0] == s1.table_rgba[1] == s1.table_rgba[2]
        assert s0.table_rgba != s1.table_rgba and not f1.lights.shadow
        assert not np.array_equal(f1.rgb, f0.rgb)
        s3, _, f3, _ = observe_scene(sim, easy_objects, 3, 0, profile="jacquard")
        assert s3.table_rgba == s0.table_rgba
        np.testing.assert_array_equal(f3.rgb, f0.rgb)
        np.testing.assert_array_equal(f3.T_world_cam, f0.T_world_cam)
        np.testing.assert_array_equal(f3.depth, np.where(f3.depth_clean > 0, f3.depth_clean, 0))
        assert f3.depth_valid.sum() > f0.depth_valid.sum()
        close = replace(SimProfile(), name="close", camera_height=(0.4, 0.4),
                        depth_noise=DepthNoise.off())
        s2, b2, f2, _ = observe_scene(sim, easy_objects, 3, 0, profile=close)
        assert [(o.spec.name, o.position, o.orientation) for o in s2.objects] == objects0
        assert s2.table_rgba == s0.table_rgba
        assert np.isin(f2.segmentation, b2.objects).sum() > 1.5 * area0
        np.testing.assert_array_equal(f2.depth, np.where(f2.depth_clean > 0, f2.depth_clean, 0))
    finally:
        sim.close()


@pytest.mark.sim
def test_dataset_records_its_profile_and_refuses_another(tmp_path, easy_objects):
    from graspsim.data.datagen import MANIFEST, make_dataset

    make_dataset(n_scenes=1, objects=easy_objects, out=tmp_path, seed=2, n_candidates=2,
                 profile=LOOK)
    m = json.loads((tmp_path / MANIFEST).read_text())
    assert m["generator"]["profile"]["name"] == "look"
    assert m["generator"]["profile"]["table"] == "grey"
    rgba = m["images"][0]["table"]["rgba"]
    assert rgba[0] == rgba[1] == rgba[2]
    with pytest.raises(ValueError, match="another configuration"):
        make_dataset(n_scenes=1, objects=easy_objects, out=tmp_path, seed=2, n_candidates=2)


@pytest.mark.sim
def test_env_takes_a_profile():
    from graspsim.env import GraspEnv

    with pytest.raises(ValueError, match="unknown simulation profile"):
        GraspEnv(profile="nope")
    env = GraspEnv(objects="train", profile=LOOK)
    try:
        obs, info = env.reset(seed=1)
        assert obs["rgb"].shape == (480, 640, 3)
        assert env._scene.table_rgba[0] == env._scene.table_rgba[1]
    finally:
        env.close()
    env = GraspEnv(objects="train", profile="jacquard")
    try:
        obs, info = env.reset(seed=1)
        f = env._frame
        np.testing.assert_array_equal(obs["depth"], np.where(f.depth_clean > 0, f.depth_clean, 0))
    finally:
        env.close()


def test_cli_dataset_refuses_an_unknown_profile(capsys):
    from graspsim.cli import main

    with pytest.raises(SystemExit) as e:
        main(["dataset", "--scenes", "1", "--out", "x", "--profile", "nope"])
    assert e.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err


@pytest.mark.sim
def test_trials_run_under_a_profile_on_the_same_scenes(tmp_path, easy_objects):
    from graspsim.eval.trials import TrialConfig, run_trials

    runs = {}
    for name in ("default", "jacquard"):
        s = run_trials(detector="mask-pca", objects=easy_objects, n=2, seed=5,
                       out=tmp_path / name, config=TrialConfig(n_candidates=0, profile=name))
        lines = (tmp_path / name / "trials.jsonl").read_text().splitlines()
        runs[name] = [json.loads(line) for line in lines]
        assert s["n"] == 2
    cfg = json.loads((tmp_path / "jacquard" / "config.json").read_text())
    assert cfg["config"]["profile"] == "jacquard"
    assert [r["object"] for r in runs["jacquard"]] == [r["object"] for r in runs["default"]]
    with pytest.raises(ValueError, match="another configuration"):
        run_trials(detector="mask-pca", objects=easy_objects, n=2, seed=5,
                   out=tmp_path / "jacquard", config=TrialConfig(n_candidates=0))


def test_cli_trials_refuses_an_unknown_profile(capsys):
    from graspsim.cli import main

    with pytest.raises(SystemExit) as e:
        main(["trials", "--detector", "random", "--n", "1", "--out", "x", "--profile", "nope"])
    assert e.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err
