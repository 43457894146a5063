"""graspsim.detectors.ggcnn.plateau: budgets doubled until validation stops improving, resumable,
the same
weights as one uninterrupted run."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.datasets import GraspSample
from dlsr.rectangles import GraspRectangle
from graspsim.detectors.ggcnn.model import budget_path, snapshot_path, timed_path
from graspsim.detectors.ggcnn.plateau import (
    budgets_to,
    plateau_model,
    plateau_reached,
    prune_snapshots,
    train_to_plateau,
)

torch = pytest.importorskip("torch")

from graspsim.detectors.ggcnn.model import model_paths  # noqa: E402
from graspsim.detectors.ggcnn.train import train_ggcnn  # noqa: E402

TINY = {"input_size": 48, "crop": 72, "filters": (4, 4, 4, 4, 4, 4), "crop_method": "centre",
        "threads": 1, "progress": False, "checkpoint_every": 8, "seed": 3}


def test_budgets_double_up_to_the_recipe():
    assert budgets_to(2500, 400_000) == [2500, 5000, 10_000, 20_000, 40_000, 80_000, 160_000,
                                         320_000, 400_000]
    assert budgets_to(8, 8) == [8]
    with pytest.raises(ValueError, match="between 1 and the recipe's 100"):
        budgets_to(200, 100)


def test_snapshot_names_take_the_model_path_with_or_without_suffix(tmp_path):
    base = tmp_path / "ggcnn_10"
    for given in (base, base.with_suffix(".pt"), base.with_suffix(".json")):
        assert snapshot_path(given, 2500) == tmp_path / "ggcnn_10_step2500"
    assert budget_path(base, 5000, final=5000) == base
    assert budget_path(base, 2500, final=5000) == tmp_path / "ggcnn_10_step2500"
    assert model_paths(snapshot_path(base, 20))[0].name == "ggcnn_10_step20.pt"
    assert timed_path(base.with_suffix(".pt"), 7.6) == tmp_path / "ggcnn_10_time8s"


def test_the_curves_budget_is_the_most_successes_ties_to_the_smaller():
    from graspsim.eval.data_efficiency import chosen_budget

    val = {"2000": {"successes": 5}, "5000": {"successes": 7}, "10000": {"successes": 7},
           "20000": {"successes": 9}}
    assert chosen_budget(val, [2000, 5000, 10000]) == 5000
    assert chosen_budget(val, [10000, 2000, 20000]) == 20000


@pytest.mark.parametrize("seq,reached", [
    ([1, 3, 3, 2], True), ([1, 3, 4, 2], False), ([1, 3], False), ([5, 5, 5], True),
    ([1, 2, 3, 4], False), ([4, 1, 5], False)])
def test_plateau_is_two_budgets_without_improvement(seq, reached):
    assert plateau_reached(seq) is reached


def _weights(path):
    """The saved tensors (the file's bytes also hold its own name)."""
    return torch.load(model_paths(path)[0], weights_only=True)


def _bars(n=3):
    """72 x 72 depth images of a bar on a table, grasped across it."""
    rows, cols = np.mgrid[0:72, 0:72]
    out = []
    for i in range(n):
        a = (0.0, 0.8, -0.6)[i % 3]
        c, s = np.cos(a), np.sin(a)
        bar = (np.abs((cols - 36.0) * c - (rows - 36.0) * s) < 20) & \
            (np.abs((cols - 36.0) * s + (rows - 36.0) * c) < 6)
        depth = np.where(bar, 0.62, 0.70).astype(np.float32)
        pos = [GraspRectangle(36.0, 36.0, a + np.pi / 2, 24, 8)]
        out.append(GraspSample(f"{i:04d}", f"bar{i}", None, depth, np.ones(depth.shape, bool),
                               pos, []))
    return out


def test_training_stops_at_the_plateau_and_resumes(tmp_path):
    samples = _bars()
    trained, validated = [], []
    scripted = {8: 1, 16: 3, 32: 3, 64: 2, 128: 9, 256: 9}

    def train(out, steps, snapshots):
        trained.append(steps)
        return train_ggcnn(samples, out, steps=steps, snapshots=snapshots, **TINY)

    def validate(path, budget):
        validated.append(budget)
        assert path.name == f"model_step{budget}"
        return scripted[budget], 10

    out = tmp_path / "model"
    res = train_to_plateau(train, validate, out, start=8, recipe=256)
    # 16 gave 3; 32 and 64 did not beat it: the doubling stops at 64, before 128's 9
    assert [b["budget"] for b in res["budgets"]] == [8, 16, 32, 64] == trained
    assert res["stopped"] == "plateau" and res["chosen"] == 16  # ties to the smaller budget
    assert plateau_model(out) == tmp_path / "model_step16"
    secs = [b["seconds"] for b in res["budgets"]]
    assert secs == sorted(secs) and all(b["loss"] is not None for b in res["budgets"])
    # trained in doublings, resumed from checkpoints: the weights of one uninterrupted run
    straight = tmp_path / "straight"
    train_ggcnn(samples, straight, steps=64, **TINY)
    a, b = _weights(tmp_path / "model_step64"), _weights(straight)
    assert list(a) == list(b) and all(torch.equal(a[k], b[k]) for k in a)
    # a rerun trains and validates nothing again
    again = train_to_plateau(train, validate, out, start=8, recipe=256)
    assert again == res and trained == [8, 16, 32, 64] and validated == [8, 16, 32, 64]
    # pruned: the unchosen budgets' weights and the checkpoint go, their records stay
    gone = prune_snapshots(out)
    assert {p.name for p in gone} == {"model_step8.pt", "model_step32.pt", "model_step64.pt",
                                      "model.ckpt.pt", "model.ckpt.json"}
    assert (tmp_path / "model_step16.pt").is_file() and (tmp_path / "model.pt").is_file()
    assert all((tmp_path / f"model_step{b}.json").is_file() for b in (8, 16, 32, 64))
    assert train_to_plateau(train, validate, out, start=8, recipe=256) == res
    assert trained == [8, 16, 32, 64] and prune_snapshots(out) == []


def test_training_time_caps_the_doubling(tmp_path):
    samples = _bars(2)

    def train(out, steps, snapshots):
        return train_ggcnn(samples, out, steps=steps, snapshots=snapshots, **TINY)

    res = train_to_plateau(train, lambda p, b: (b, 10), tmp_path / "m", start=8, recipe=64,
                           max_seconds=0.0)
    assert res["stopped"] == "capped" and [b["budget"] for b in res["budgets"]] == [8]
    with pytest.raises(FileNotFoundError, match="train to the plateau first"):
        plateau_model(tmp_path / "other")
    with pytest.raises(FileNotFoundError, match="train to the plateau first"):
        prune_snapshots(tmp_path / "other")
