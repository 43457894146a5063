"""``graspsim run``'s DLSR (the lattice, the physical term, the gripper-aware check) proposes
what the reference path gives on seeded simulated test scenes: the candidates scored by the
recognition model (:meth:`dlsr.detection.DLSRDetector.rectangle_scores`: scipy's hole filling,
the recognition encoder) plus the physical term, ranked, the best 40 judged in order by
:func:`graspsim.detectors.executable`, the first 5 that pass kept. The detector's own path
(compiled crops, the exact scores' masked patches whitened on their valid rows, the lattice's
chords) must give the same rectangles in the same order, with the same scores up to float
rounding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dlsr.rectangles import array_to_rects

MODEL = Path(__file__).resolve().parents[3] / "results/ggcnn-curve/models/dlsr_300"


@pytest.fixture(scope="module")
def scenes(observed_test_scenes):
    return observed_test_scenes(3, 6)


@pytest.fixture(scope="module")
def run_detector():
    from dlsr.detection import DLSRDetector
    from graspsim.detectors.dlsr_options import DetectorOptions, build_real_detector

    if not MODEL.with_suffix(".npz").exists():
        pytest.skip(f"the committed model {MODEL} is absent")
    return build_real_detector(DLSRDetector.load(MODEL), DetectorOptions(), hand="builtin")


def _reference(det, obs):
    """The first ``keep`` executable of the 40 best by the recognition model's scores."""
    from dlsr.detection import table_surface
    from graspsim.detectors import executable

    lattice = det.detector
    model = lattice.model
    cand, reason, region = lattice.candidates(obs)
    assert reason is None
    table = table_surface(obs["depth"], obs.get("depth_valid"))
    scores = (model.rectangle_scores(obs, cand)
              + model.physical_scores(obs, cand, region, table))
    order = np.argsort(-scores, kind="stable")[: lattice.top_k]
    rects = array_to_rects(cand[order])
    ok = executable(rects, obs)
    kept = np.flatnonzero(ok)[: det.keep]
    return [rects[i] for i in kept], scores[order][kept]


def test_run_detector_proposes_what_the_reference_path_gives(scenes, run_detector):
    n = 0
    for obs in scenes:
        expected, ref_scores = _reference(run_detector, obs)
        assert run_detector.predict(obs) == expected
        d = run_detector.detect(obs)
        assert array_to_rects(d.rects) == expected
        np.testing.assert_allclose(d.scores, ref_scores, rtol=0, atol=1e-5)
        n += len(expected)
    assert n >= 20  # proposals compared (a scene may have none: an ungraspable plate)
