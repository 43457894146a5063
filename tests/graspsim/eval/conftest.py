"""Fixtures of the evaluation tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def small_labelled_dataset(tmp_path_factory):
    """``(root, stats, samples)``: a 3-scene physics-labelled dataset of four graspable built-in
    objects (``graspsim dataset``'s Cornell layout, 6 candidates executed per scene), read-only
    for the tests that share it."""
    from dlsr.datasets import load_cornell
    from graspsim.data.datagen import make_dataset
    from graspsim.sim.objects import builtin_objects

    names = {"can_tall", "box_matches", "toothbrush", "bottle_shampoo"}
    specs = [s for s in builtin_objects("all") if s.name in names]
    root = tmp_path_factory.mktemp("data") / "ds"
    stats = make_dataset(n_scenes=3, objects=specs, out=root, seed=1, n_candidates=6)
    samples = load_cornell(root)
    assert any(s.positives for s in samples) and any(s.negatives for s in samples)
    return root, stats, samples
