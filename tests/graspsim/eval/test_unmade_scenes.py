"""A seeded scene that cannot be made is a logged skip in trials, clutter rounds, comparisons
and comparison grids: recorded once, left out of the figures and of the pairing, never the end
of a campaign."""

from __future__ import annotations

import json
import logging

import pytest

import graspsim.sim.observe as trials_mod
from graspsim.detectors import load_detector
from graspsim.eval.compare import load_folder
from graspsim.eval.comparison_grid import Row, grow, results_markdown
from graspsim.eval.declutter import run_rounds
from graspsim.eval.trials import TrialConfig, run_trials
from graspsim.runtime.campaign import is_skipped
from graspsim.sim.observe import trial_streams

pytestmark = pytest.mark.sim

UNMADE = 1  # the index whose scene "cannot be made"


@pytest.fixture
def unmade(monkeypatch):
    """Scene ``UNMADE`` of every seed fails as a pile that never settles; the others are made
    as usual. The scene is told by its generator's state, so it does not depend on the order
    in which scenes are made."""
    real = trials_mod.make_scene_of

    def make(kind, sim, specs, rng, **kwargs):
        for seed in (0, 1):
            if rng.bit_generator.state == trial_streams(seed, UNMADE)["scene"].bit_generator.state:
                raise ValueError("could not make a pile of 2 objects in 4 attempts: the heap "
                                 "did not settle")
        return real(kind, sim, specs, rng, **kwargs)

    monkeypatch.setattr(trials_mod, "make_scene_of", make)


def test_trials_skip_an_unmade_scene_and_go_on(tmp_path, easy_objects, unmade, caplog):
    out = tmp_path / "t"
    with caplog.at_level(logging.WARNING, logger="graspsim.runtime.campaign"):
        s = run_trials("mask-pca", easy_objects, n=3, seed=0, out=out,
                       config=TrialConfig(n_candidates=0))
    assert "scene 1 of seed 0: could not make a pile" in caplog.text
    assert s["n"] == 2 and [r["index"] for r in s["records"]] == [0, 2]
    assert [x["index"] for x in s["skipped"]] == [UNMADE]
    lines = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert sorted(r["index"] for r in lines) == [0, 1, 2]
    skip = next(r for r in lines if r["index"] == UNMADE)
    assert is_skipped(skip) and skip["seed"] == 0 and "did not settle" in skip["skipped"]
    assert "skipped: 1 scene(s) that could not be made (indices 1;" in \
        (out / "summary.md").read_text()
    # the skip is a finished record: a rerun makes nothing again and gives the same figures
    again = run_trials("mask-pca", easy_objects, n=3, seed=0, out=out,
                       config=TrialConfig(n_candidates=0))
    assert again["successes"] == s["successes"] and again["skipped"] == s["skipped"]
    assert len((out / "trials.jsonl").read_text().splitlines()) == 3
    # compare pairs the scenes that were made
    folder = load_folder(out)
    assert sorted(folder["records"]) == [0, 2] and folder["skipped"] == 1


def test_rounds_skip_an_unmade_scene_and_go_on(tmp_path, easy_objects, unmade):
    cfg = TrialConfig(n_candidates=0, n_objects=2)
    s = run_rounds("mask-pca", easy_objects, n=2, seed=0, out=tmp_path / "r", config=cfg)
    assert s["rounds"] == 1 and [r["index"] for r in s["records"]] == [0]
    assert s["objects_placed"] == 2 and [x["index"] for x in s["skipped"]] == [UNMADE]
    assert "could not be made" in (tmp_path / "r" / "summary.md").read_text()
    assert sorted(load_folder(tmp_path / "r")["records"]) == ["0"]  # rounds pair by str


def test_a_grid_pairs_around_an_unmade_scene_and_tops_up(tmp_path, unmade):
    rows = [Row("drop", objects="test", sizes=(3,))]
    dets = ["mask-pca", "random"]
    res = grow(rows, dets, lambda name, row: load_detector(name), tmp_path)
    drop = res["drop"]
    # scene 1 cannot be made, so each cell runs a fourth scene: 3 paired scenes, as asked
    assert drop["n"] == 3 and drop["skipped"] == [UNMADE]
    for d in dets:
        assert sum(drop["cells"][d]["reasons"].values()) == 3
        lines = (tmp_path / "drop" / d / "trials.jsonl").read_text().splitlines()
        assert sorted(json.loads(x)["index"] for x in lines) == [0, 1, 2, 3]
    assert "Left out: 1 scene(s) that could not be made (indices 1)" in results_markdown(res)


def test_a_scene_that_fails_once_is_made_in_a_new_simulation(tmp_path, easy_objects,
                                                              monkeypatch):
    import graspsim.sim.bullet as bullet
    from graspsim.sim.observe import SceneError, made_again_if_unmade

    real, calls = trials_mod.make_scene_of, []

    def fails_once(kind, sim, specs, rng, **kwargs):  # scene 1 fails in its first simulation
        first = rng.bit_generator.state == trial_streams(0, UNMADE)["scene"].bit_generator.state
        calls.append(sim)  # kept, so a new simulation is not mistaken for an old one
        if first and len(calls) == 2:
            raise ValueError("inertia must be 3 finite moments >= 0, got [1e-06, inf, inf]")
        return real(kind, sim, specs, rng, **kwargs)

    cfg = TrialConfig(n_candidates=0)
    clean = run_trials("mask-pca", easy_objects, n=3, seed=0, out=tmp_path / "a", config=cfg)
    monkeypatch.setattr(trials_mod, "make_scene_of", fails_once)
    s = run_trials("mask-pca", easy_objects, n=3, seed=0, out=tmp_path / "b", config=cfg)
    assert s["skipped"] == [] and len(calls) == 4
    assert calls[2] is not calls[1]  # made again in another simulation (a new connection)
    assert [r["success"] for r in s["records"]] == [r["success"] for r in clean["records"]]
    assert [r["rectangle"] for r in s["records"]] == [r["rectangle"] for r in clean["records"]]

    def never():
        raise SceneError("scene 7 of seed 0: the heap did not settle")

    before = bullet.worker_sim()
    with pytest.raises(SceneError, match="did not settle"):
        made_again_if_unmade(never)
    assert bullet.worker_sim() is not before
