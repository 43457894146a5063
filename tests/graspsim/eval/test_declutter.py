"""Clutter-removal rounds (VGN/GIGA protocol) and the scene update shared with the env."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dlsr.rectangles import GraspRectangle
from graspsim.eval.declutter import (
    CLEARED,
    FAILURES,
    MAX_CONSECUTIVE_FAILURES,
    run_rounds,
)
from graspsim.eval.stats import bootstrap_ratio_interval
from graspsim.eval.trials import NO_PROPOSAL, TrialConfig, run_trials
from graspsim.sim.execution import GraspResult
from graspsim.sim.scene import scene_after_grasp

pytestmark = pytest.mark.sim



def strip(rec):
    """A record without its timings."""
    if isinstance(rec, list):
        return [strip(r) for r in rec]
    if isinstance(rec, dict):
        return {k: strip(v) for k, v in rec.items()
                if k not in ("seconds", "planning_seconds", "end_planning_seconds")}
    return rec


class Nothing:
    def predict(self, obs):
        return []


class Corner:
    """Always the same rectangle on the bare table: nothing between the jaws."""

    def predict(self, obs):
        return [GraspRectangle(20.0, 20.0, 0.0, 40.0, 15.0)]


class Raises:
    def predict(self, obs):
        raise KeyError("depth_image")


def check_round(r):
    """Invariants every round record satisfies."""
    att = r["attempts"]
    assert r["removed"] + r["fell_off"] + r["left"] == r["n_objects"] == len(r["objects"])
    assert r["successes"] == sum(a["success"] for a in att) == r["removed"]
    assert [a["attempt"] for a in att] == list(range(len(att)))
    assert all((a["grasped"] is not None) == a["success"] for a in att)
    for a, b in zip(att, att[1:], strict=False):
        assert b["objects_left"] == a["objects_left"] - int(a["success"]) - len(a["fell_off"])
    # Never two failures in a row before the last attempt.
    fails = [not a["success"] for a in att]
    assert not any(x and y for x, y in zip(fails[:-1], fails[1:-1], strict=False))
    if r["end"] == CLEARED:
        assert r["left"] == 0
    elif r["end"] == FAILURES:
        assert fails[-MAX_CONSECUTIVE_FAILURES:] == [True] * MAX_CONSECUTIVE_FAILURES
        assert r["left"] > 0
    else:
        assert r["end"] == NO_PROPOSAL or r["end"].startswith("detector error: ")


def test_rounds_clear_resume_and_pair_with_trials(tmp_path, easy_objects):
    cfg = TrialConfig(n_candidates=0, n_objects=3)
    full = run_rounds("mask-pca", easy_objects, n=2, seed=0, out=tmp_path / "a", config=cfg)
    for r in full["records"]:
        check_round(r)
    s = full
    assert s["attempts"] == sum(len(r["attempts"]) for r in s["records"])
    assert s["success_rate"] == pytest.approx(s["successes"] / s["attempts"])
    assert s["declutter_rate"] == pytest.approx(s["removed"] / s["objects_placed"])
    assert s["objects_placed"] == 6
    for lo, hi in (s["success_ci95"], s["success_ci95_bootstrap"],
                   s["declutter_ci95_bootstrap"]):
        assert 0.0 <= lo <= hi <= 1.0
    assert s["planning_seconds"]["n"] >= s["attempts"]
    md = (tmp_path / "a" / "summary.md").read_text()
    assert "declutter rate" in md and "grasp success rate" in md
    # The first attempt of round i is trial i with the same objects per scene.
    trials = run_trials("mask-pca", easy_objects, n=2, seed=0, config=cfg)
    for r, t in zip(full["records"], trials["records"], strict=True):
        assert r["objects"] == t["object"]
        a = r["attempts"][0]
        assert (a["rectangle"], a["success"], a["reason"]) == \
            (t["rectangle"], t["success"], t["reason"])
    # Killed during round 1: round 0 kept, the torn line dropped, round 1 rerun identically.
    out = tmp_path / "b"
    out.mkdir()
    lines = (tmp_path / "a" / "rounds.jsonl").read_text().splitlines()
    (out / "rounds.jsonl").write_text(lines[0] + "\n" + lines[1][:40])
    (out / "config.json").write_text((tmp_path / "a" / "config.json").read_text())
    resumed = run_rounds("mask-pca", easy_objects, n=2, seed=0, out=out, config=cfg)
    assert strip(resumed["records"]) == strip(full["records"])
    recs = [json.loads(x) for x in (out / "rounds.jsonl").read_text().splitlines()]
    assert sorted(r["index"] for r in recs) == [0, 1]
    assert json.loads((out / "config.json").read_text())["mode"] == "declutter"
    with pytest.raises(ValueError, match="another configuration"):
        run_rounds("random", easy_objects, n=2, seed=0, out=out, config=cfg)


def test_rounds_end_on_failures_no_proposal_and_detector_errors(easy_objects):
    cfg = TrialConfig(n_candidates=0, n_objects=2)
    fail = run_rounds(Corner(), easy_objects, n=1, seed=1, config=cfg)["records"][0]
    check_round(fail)
    assert fail["end"] == FAILURES and len(fail["attempts"]) == MAX_CONSECUTIVE_FAILURES
    none = run_rounds(Nothing(), easy_objects, n=1, seed=1, config=cfg)
    assert none["records"][0]["end"] == NO_PROPOSAL and none["attempts"] == 0
    assert none["declutter_rate"] == 0.0 and none["success_rate"] is None
    err = run_rounds(Raises(), easy_objects, n=1, seed=1, config=cfg)["records"][0]
    assert err["end"] == "detector error: KeyError: 'depth_image'"
    assert err["attempts"] == [] and err["left"] == 2


def test_scene_after_grasp_removes_lifted_and_fallen_objects(easy_objects):
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.scene import build_scene, make_scene

    sim = Simulation()
    try:
        scene = make_scene(sim, easy_objects, np.random.default_rng(3), n_objects=3,
                           spread=0.12)
        assert scene_after_grasp(sim, scene, None, None) == (scene, [])
        bodies = build_scene(sim, scene)
        # Object 2 pushed off the table; object 0 lifted by a successful grasp.
        sim.client.resetBasePositionAndOrientation(bodies.objects[2], [0.8, 0.0, 0.3],
                                                   [0, 0, 0, 1])
        lifted = GraspResult(True, None, 0.15, object_index=0)
        after, fell = scene_after_grasp(sim, scene, bodies, lifted)
        assert fell == [2]
        assert [o.spec.name for o in after.objects] == [scene.objects[1].spec.name]
        # A failed grasp removes nothing that stays on the table.
        bodies = build_scene(sim, scene)
        after, fell = scene_after_grasp(sim, scene, bodies, GraspResult(False, "x", 0.0, 0))
        assert fell == [] and len(after.objects) == 3
    finally:
        sim.close()


def test_bootstrap_ratio_interval():
    rng = np.random.default_rng(0)
    lo, hi = bootstrap_ratio_interval([5, 5, 5], [5, 5, 5], random_state=rng)
    assert lo == hi == 1.0
    lo, hi = bootstrap_ratio_interval([0, 5, 2, 4], [5, 5, 5, 5], random_state=1)
    assert 0.0 <= lo < 11 / 20 < hi <= 1.0
    assert bootstrap_ratio_interval([], []) == [None, None]
    assert bootstrap_ratio_interval([0], [0]) == [None, None]


def test_cli_declutter(tmp_path, capsys):
    from graspsim.cli import main

    out = tmp_path / "d"
    assert main(["trials", "--detector", "mask-pca", "--declutter", "--objects-per-scene",
                 "2", "--n", "1", "--candidates", "0", "--out", str(out)]) == 0
    assert "declutter rate" in capsys.readouterr().out
    assert len((out / "rounds.jsonl").read_text().splitlines()) == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["config"]["n_objects"] == 2 and s["rounds"] == 1
    assert "execution parameters" not in (out / "summary.md").read_text()
    settle = tmp_path / "settle"
    assert main(["trials", "--detector", "mask-pca", "--declutter", "--objects-per-scene",
                 "2", "--n", "1", "--candidates", "0", "--min-grip", "0.01",
                 "--out", str(settle)]) == 0
    assert json.loads((settle / "config.json").read_text())["execution"]["min_grip"] == 0.01
    assert "min_grip = 0.01" in (settle / "summary.md").read_text()
    assert main(["trials", "--detector", "mask-pca", "--objects-per-scene", "0", "--n", "1",
                 "--out", str(tmp_path / "e")]) == 2
    assert "--objects-per-scene must be >= 1" in capsys.readouterr().err
