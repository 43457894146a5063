"""Graspable by physics: the measurement, its cache keyed by fingerprint and gripper, the flags
the trials use, and ``graspsim objects``."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from graspsim.cli import main
from graspsim.labels import graspability as g
from graspsim.labels.graspability import resolve_objects
from graspsim.sim.execution import ExecutionParams
from graspsim.sim.objects import builtin_objects


@pytest.fixture
def user_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GRASPSIM_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _spec(name):
    return next(s for s in builtin_objects("all") if s.name == name)


def test_cache_dir_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("GRASPSIM_CACHE_DIR", str(tmp_path / "a"))
    assert g.cache_dir() == tmp_path / "a"
    monkeypatch.delenv("GRASPSIM_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert g.cache_dir() == tmp_path / "xdg" / "graspsim"


def test_keys_follow_the_gripper_and_the_object():
    key = g.gripper_key()
    assert key["gripper"]["max_opening"] == 0.08 and key["budget"] == g.BUDGET
    assert g.gripper_key(ExecutionParams(lift_height=0.2)) != key
    s = _spec("can_soda")
    assert g.object_key(s) == g.object_key(replace(s))
    assert g.object_key(replace(s, mass=0.5)) != g.object_key(s)
    assert g.object_key(_spec("plate")) != g.object_key(s)


def test_flags_come_from_the_cache_only_when_it_decides_them(user_cache):
    specs = [_spec("can_soda"), _spec("plate")]
    assert g.graspability_flags(specs, n_poses=2, params=ExecutionParams(lift_height=0.2)) \
        is None
    key = g.gripper_key()
    entries = {g.object_key(specs[0]): {"name": "can_soda", "first_success": 0,
                                        "poses_tried": 1},
               g.object_key(specs[1]): {"name": "plate", "first_success": None,
                                        "poses_tried": 2}}
    g._write_entries(user_cache / "m.json", key, entries)
    path = g._manifest_paths(key)[-1]
    path.parent.mkdir(parents=True, exist_ok=True)
    (user_cache / "m.json").rename(path)
    assert g.graspability_flags(specs, n_poses=2) == {"can_soda": True, "plate": False}
    # 4 poses: the plate was tried in 2 only, so its flag is not decided.
    assert g.graspability_flags(specs, n_poses=4) is None
    flipped = g.apply_graspability([replace(specs[1], graspable=True)], n_poses=2)
    assert flipped[0].graspable is False


@pytest.mark.sim
def test_measure_caches_and_does_not_measure_again(user_cache, monkeypatch):
    # Another mass: an object the committed manifest does not have.
    spec = replace(_spec("can_soda"), mass=0.123)
    out = g.measure_graspability([spec], n_poses=1)
    assert out["can_soda"] == {"first_success": 0, "poses_tried": 1}
    data = json.loads(next(user_cache.glob("graspability-*.json")).read_text())
    assert data["grippers"][0]["key"] == g.gripper_key()

    def boom(*a, **k):
        raise AssertionError("measured again")

    monkeypatch.setattr(g, "object_outcome", boom)
    assert g.measure_graspability([spec], n_poses=1) == out
    assert g.graspability_flags([spec], n_poses=1) == {"can_soda": True}


@pytest.mark.sim
def test_a_plate_wider_than_the_opening_is_not_graspable(user_cache):
    out = g.object_outcome(_spec("plate"), n_poses=1)
    assert out == {"name": "plate", "first_success": None, "poses_tried": 1}


def test_n_poses_must_be_a_positive_integer(user_cache):
    with pytest.raises(ValueError, match="n_poses"):
        g.measure_graspability("can_soda", n_poses=0)
    with pytest.raises(ValueError, match="n_poses"):
        g.object_table("can_soda", n_poses=1.5)


def test_the_builtin_set_has_committed_physics_flags():
    rows = g.object_table("all")
    assert len(rows) == 57 and all(r["graspable_by"] == "physics" for r in rows)
    flags = {r["name"]: r["graspable"] for r in rows}
    assert {s.name: s.graspable for s in resolve_objects("all")} == flags


def test_objects_command_prints_a_table_and_json(capsys):
    assert main(["objects", "can_soda,plate"]) == 0
    text = capsys.readouterr().out
    assert text.splitlines()[0].split() == ["name", "size", "(cm)", "graspable", "split"]
    assert "can_soda" in text and "of 2 graspable" in text
    assert main(["objects", "can_soda", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["name"] == "can_soda" and rows[0]["split"] == "train"
    assert rows[0]["size"] == pytest.approx(list(_spec("can_soda").size))


def test_objects_command_refuses_a_bad_set(tmp_path, capsys):
    assert main(["objects", f"folder:{tmp_path / 'nope'}"]) != 0
    assert "object folder not found" in capsys.readouterr().err


def test_a_runs_flags_are_those_of_its_hand(user_cache, capsys):
    from graspsim.sim.gripper import hand_params

    franka = ExecutionParams(gripper=hand_params("franka"))
    spec = _spec("can_soda")
    assert resolve_objects("can_soda")[0].graspable  # by the committed built-in hand's flags
    key = g.gripper_key(franka)
    assert key != g.gripper_key()
    path = g._manifest_paths(key)[-1]
    path.parent.mkdir(parents=True, exist_ok=True)
    g._write_entries(path, key, {g.object_key(spec): {
        "name": "can_soda", "first_success": None, "poses_tried": g.DEFAULT_POSES}})
    assert resolve_objects("can_soda", franka)[0].graspable is False
    assert resolve_objects("can_soda")[0].graspable
    # and graspsim objects lists the flags of the hand it is given
    capsys.readouterr()
    assert main(["objects", "can_soda", "--json", "--gripper", "franka"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["graspable"] is False and row["graspable_by"] == "physics"
    assert main(["objects", "can_soda", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["graspable"] is True
