"""graspsim.eval.hand_choice: DLSR's training data chosen per hand on validation scenes of the train
objects, resumable, never on the test objects."""

from __future__ import annotations

import json

import pytest

from graspsim.eval.hand_choice import choose_per_hand, chosen_detector, hand_candidates

pytestmark = pytest.mark.sim

SMALL = {"n_train": 4, "n_val": 3, "candidates": 8, "n_atoms": 16, "n_patches": 10_000}


def test_candidates_per_hand():
    assert hand_candidates("builtin") == ["curve", "train-builtin"]
    assert hand_candidates("franka") == ["curve", "train-builtin", "train-franka"]


@pytest.fixture(scope="module")
def curve_model(tmp_path_factory):
    from dlsr.datasets import load_cornell
    from dlsr.detection import train_detector
    from graspsim.data.datagen import make_dataset

    root = tmp_path_factory.mktemp("curve")
    make_dataset(n_scenes=4, objects="train", out=root / "data", seed=11, n_candidates=8,
                 sampler="dense")
    model = train_detector(load_cornell(root / "data"), n_atoms=16, n_patches=10_000,
                           detector="lattice", physical=True, grid_negatives=0.0)
    model.save(root / "dlsr")
    return root / "dlsr"


def test_choice_per_hand_resumes_and_loads(tmp_path, curve_model):
    out = tmp_path / "choice"
    res = choose_per_hand(out, ["builtin", "franka"], curve_model, objects="train", **SMALL)
    for hand in ("builtin", "franka"):
        e = res[hand]
        assert list(e["candidates"]) == hand_candidates(hand)
        best = max(c["successes"] for c in e["candidates"].values())
        # the chosen one has the most validation successes, ties to the earlier candidate
        assert e["chosen"] == next(n for n in hand_candidates(hand)
                                   if e["candidates"][n]["successes"] == best)
        for name, c in e["candidates"].items():
            recs = [json.loads(x) for x in
                    (out / "validation" / hand / name / "trials.jsonl").read_text().splitlines()]
            assert c["successes"] == sum(r["success"] for r in recs) and c["n"] == 3
            # validation scenes are of the train objects, the same scenes for every candidate
            ref = [json.loads(x) for x in (out / "validation" / hand / "mask-pca" /
                                           "trials.jsonl").read_text().splitlines()]
            assert [r["object"] for r in recs] == [r["object"] for r in ref]
    # the two labelling hands label the same scenes
    a = json.loads((out / "datasets" / "builtin" / "scenes.json").read_text())
    b = json.loads((out / "datasets" / "franka" / "scenes.json").read_text())
    assert len(a["images"]) == 4
    assert [i["objects"] for i in a["images"]] == [i["objects"] for i in b["images"]]
    md = (out / "choice.md").read_text()
    assert "| franka | train-franka |" in md
    # a rerun finds everything done and gives the same result
    mtime = (out / "models" / "dlsr-train-franka.npz").stat().st_mtime_ns
    assert choose_per_hand(out, ["builtin", "franka"], curve_model, objects="train",
                           **SMALL) == res
    assert (out / "models" / "dlsr-train-franka.npz").stat().st_mtime_ns == mtime
    det = chosen_detector(out, "franka")
    assert det.hand == "franka"
    with pytest.raises(ValueError, match="no choice for the hand 'wsg50'"):
        chosen_detector(out, "wsg50")
    # the hands are a selection: one hand alone reruns nothing and keeps the other's choice
    again = choose_per_hand(out, ["builtin"], curve_model, objects="train", **SMALL)
    assert again["builtin"] == res["builtin"] and again["franka"] == res["franka"]
    with pytest.raises(ValueError, match="other settings"):
        choose_per_hand(out, ["builtin"], curve_model, objects="train",
                        **{**SMALL, "n_val": SMALL["n_val"] + 1})
