"""The gripper-aware DLSR detector of ``graspsim run`` plans as before, faster: on simulated
test scenes, with the built-in and the Franka hand, it proposes the rectangles the whole
ranking judged by :func:`graspsim.detectors.executable` gives (the same rectangles in the same
order), and its exact scores are the recognition model's up to float rounding."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.rectangles import array_to_rects


@pytest.fixture(scope="module")
def scenes(observed_test_scenes):
    return observed_test_scenes(0, 4)


@pytest.fixture(scope="module")
def model(saved_model):
    from dlsr.detection import DLSRDetector

    path, _ = saved_model
    return DLSRDetector.load(path)


@pytest.mark.parametrize("hand", ["builtin", "franka"])
def test_gripper_aware_lattice_proposes_what_judging_the_whole_ranking_gives(scenes, model,
                                                                             hand):
    from graspsim.detectors.dlsr_options import DetectorOptions, build_real_detector
    from graspsim.detectors.gripper_aware import _first_executable, executable

    det = build_real_detector(model, DetectorOptions(physical=False), hand=hand)
    n_kept = 0
    for obs in scenes:
        ranked = det.detector.detect(obs)  # the 40 best, best first
        rects = ranked.rectangles()
        ok = executable(rects, obs, hand=hand)
        expected = [r for r, k in zip(rects, ok, strict=True) if k][: det.keep]
        assert det.predict(obs) == expected
        d = det.detect(obs)
        assert array_to_rects(d.rects) == expected if len(d.rects) else expected == []
        n_kept += len(expected)
        for keep in (1, 3, 40):  # and any number kept, with or without the unseen surface
            for unseen in (True, False):
                ok = executable(rects, obs, hand=hand, unseen_surface=unseen)
                got = _first_executable(rects, obs, keep, unseen_surface=unseen, hand=hand)
                assert got.tolist() == np.flatnonzero(ok)[:keep].tolist()
    assert n_kept > 0


def test_lattice_exact_scores_are_the_recognition_models(scenes, model):
    from dlsr.detection import DenseDetector

    det = model.detector("lattice", budget=48)
    for obs in scenes[:2]:
        cand, reason, _ = det.candidates(obs)
        assert reason is None and len(cand) == 48
        fast = DenseDetector(model).exact_scores(obs, cand)
        ref = model.rectangle_scores(obs, cand)
        np.testing.assert_allclose(fast, ref, rtol=1e-4, atol=1e-4 * np.abs(ref).max())


def test_dense_search_proposes_the_same_with_patches_without_depth_whitened_on_colour(
        observed_test_scenes, model):
    """The paper's dense search (``dlsr-paper``) proposes the same rectangles in the same
    order whether patches without depth are whitened on their colour entries or on all 288,
    on a seeded pile of five objects and on single objects, with scores equal up to float
    rounding; the pile's encodings need fewer products."""
    from graspsim.labels.graspability import resolve_objects
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.observe import observation, observe_scene

    sim = Simulation()
    try:
        pile = observation(observe_scene(sim, resolve_objects("test"), 0, 0, 5, None,
                                         "pile")[2], 0)
    finally:
        sim.close()
    for obs in [pile, *observed_test_scenes(0, 2)]:
        old = model.detector("dense", colour_whitening=False, top_k=10).detect(obs)
        new = model.detector("dense", top_k=10).detect(obs)
        assert len(old.rects) > 0
        np.testing.assert_array_equal(new.rects, old.rects)
        np.testing.assert_allclose(new.scores, old.scores, rtol=0, atol=1e-6)
        if obs is pile:
            assert new.timings["encode_flops"] < old.timings["encode_flops"]
