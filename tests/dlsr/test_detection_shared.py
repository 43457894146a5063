"""Several detection models on the same images, the shared work done once:
:func:`dlsr.detection.train_detectors` and :func:`dlsr.detection.detect_many` give each model's
own training and detection bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.detection import (
    DLSRDetector,
    detect_many,
    sample_observation,
    train_detector,
    train_detectors,
)

MODELS = [{"learner": "NKM", "encoder": "Natural"},
          {"learner": "NKM", "encoder": "SC", "C": 10.0},
          {"learner": "RP", "encoder": "Natural"}]
OPTIONS = dict(n_atoms=8, n_patches=1500, grid_negatives=0.5, region="auto")


@pytest.fixture(scope="module")
def trained(box_samples):
    samples = box_samples(3)
    shared = train_detectors(samples[:2], MODELS, random_state=3, **OPTIONS)
    alone = [train_detector(samples[:2], **m, random_state=3, **OPTIONS) for m in MODELS]
    return samples, shared, alone


def _arrays(model: DLSRDetector) -> dict:
    rep = model.representation
    return {"dictionary": rep.dictionary, "zca": rep.zca_matrix, "coef": model.coef,
            "mean": model.scaler_mean, "scale": model.scaler_scale, "intercept": model.intercept}


def test_train_detectors_equal_train_detector_each(trained):
    _, shared, alone = trained
    for s, a in zip(shared, alone, strict=True):
        for name, value in _arrays(a).items():
            np.testing.assert_array_equal(_arrays(s)[name], value, err_msg=name)
        cfg = {k: v for k, v in s.config.items() if "seconds" not in k}
        assert cfg == {k: v for k, v in a.config.items() if "seconds" not in k}
        assert s.config["train_seconds"] >= s.config["shared_train_seconds"] > 0
    # NKM-Natural and NKM-SC read one dictionary
    assert shared[0].representation is shared[1].representation


def test_train_detectors_refuses_per_model_options_as_shared(box_samples):
    with pytest.raises(ValueError, match="per model"):
        train_detectors(box_samples(2), MODELS, C=1.0)
    with pytest.raises(ValueError, match="learner"):
        train_detectors(box_samples(2), [{"encoder": "SC"}])


def test_detect_many_equals_each_detector_alone(trained):
    samples, shared, _ = trained
    obs = sample_observation(samples[2])
    dets = [m.detector("lattice", top_k=5, complete=False) for m in shared]
    together = detect_many(dets, obs)
    for det, d in zip(dets, together, strict=True):
        alone = det.detect(obs)
        np.testing.assert_array_equal(d.rects, alone.rects)
        np.testing.assert_array_equal(d.scores, alone.scores)
        assert (d.n_candidates, d.n_encodings, d.reason) == \
            (alone.n_candidates, alone.n_encodings, alone.reason)
        assert d.seconds >= d.timings["shared"] > 0
    # detectors that search differently do not share: each detects alone, the same result
    other = [dets[0], shared[1].detector("lattice", top_k=3, complete=False)]
    mixed = detect_many(other, obs)
    assert "shared" not in mixed[1].timings
    np.testing.assert_array_equal(mixed[1].rects, other[1].detect(obs).rects)


def test_the_models_of_one_fold_whiten_the_patches_once(trained, monkeypatch):
    from dlsr.detection import dense

    samples, shared, _ = trained
    obs = sample_observation(samples[2])
    det = shared[0].detector("lattice", complete=False)
    cand, _, _ = det.candidates(obs)
    images = dense.DenseDetector(shared[0], n_threads=1).exact_images(obs, cand)
    generic = [shared[1], shared[2]]  # NKM-SC and RP-Natural: two learners, one whitening
    np.testing.assert_array_equal(generic[0].representation.zca_matrix,
                                  generic[1].representation.zca_matrix)
    alone = [dense.DenseDetector(m, n_threads=1, chunk_size=400).score_images(images)
             for m in generic]
    calls = []
    whitened = dense._PatchScorer.whitened
    monkeypatch.setattr(dense._PatchScorer, "whitened",
                        lambda self, *a: calls.append(1) or whitened(self, *a))
    scores, seconds = dense.score_images_many(
        [dense.DenseDetector(m, n_threads=1, chunk_size=400) for m in generic], images)
    for s, a in zip(scores, alone, strict=True):
        np.testing.assert_array_equal(s, a)
    per = 400 // dense.PATCHES_PER_RECTANGLE * dense.PATCHES_PER_RECTANGLE
    assert len(calls) == -(-len(cand) * dense.PATCHES_PER_RECTANGLE // per) > 1
    assert all(t > 0 for t in seconds)
    with pytest.raises(ValueError, match="chunk_size"):
        dense.score_images_many([dense.DenseDetector(generic[0], chunk_size=400),
                                 dense.DenseDetector(generic[1], chunk_size=800)], images)


@pytest.mark.parametrize("n_threads", [1, 2])
def test_scoring_keeps_freed_blocks_in_the_heap_in_every_thread(trained, monkeypatch, n_threads):
    # Every chunk is encoded while dlsr.memory's heap switch is held (the arrays freed by one
    # chunk serve the next instead of being mapped afresh), and the switch is released after.
    from dlsr import memory
    from dlsr.detection import dense

    samples, shared, _ = trained
    obs = sample_observation(samples[2])
    det = dense.DenseDetector(shared[1], n_threads=n_threads, chunk_size=400)
    cand, _, _ = shared[1].detector("lattice", complete=False).candidates(obs)
    held = []
    scores = dense._PatchScorer.scores
    monkeypatch.setattr(dense._PatchScorer, "scores", lambda self, *a: held.append(
        memory._heap_switch._depth) or scores(self, *a))
    encoded = dense._PatchScorer.encoded_scores
    monkeypatch.setattr(dense._PatchScorer, "encoded_scores", lambda self, *a: held.append(
        memory._heap_switch._depth) or encoded(self, *a))
    det.exact_scores(obs, cand)
    det.detect(obs)
    assert len(held) > 2 and min(held) >= 1
    assert memory._heap_switch._depth == 0
