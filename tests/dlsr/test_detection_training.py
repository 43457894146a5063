"""Detection training data: negatives from the detector's own candidate grid."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dlsr.detection import (
    PAPER_GRID,
    SearchGrid,
    detection_training_data,
    enumerate_candidates,
    object_region,
    sample_grid_negatives,
)
from dlsr.metrics import rectangle_metric_many
from dlsr.recognition import recognition_data
from dlsr.rectangles import corners_from_array, rects_to_array

GRID = SearchGrid(angles_deg=(0, 30, 60, 90, 120, 150), openings=(20, 40, 60, 80, 100),
                  jaws=(20, 30), step=12.0, dilate=10)


def _region(sample):
    from dlsr.detection import sample_observation

    return object_region(sample_observation(sample))[0]


def _rows(a):
    return {tuple(np.round(r, 6)) for r in np.asarray(a)}


def test_grid_negatives_are_failing_grid_candidates_inside_the_image(box_samples):
    s = box_samples(1)[0]
    neg = sample_grid_negatives(s, 200, np.random.default_rng(0), GRID)
    assert neg.shape == (200, 5)
    assert len(_rows(neg)) == 200  # drawn without replacement
    # from the detector's search space, so inside the image and on the object region
    assert _rows(neg) <= _rows(enumerate_candidates(_region(s), GRID))
    corners = corners_from_array(neg)
    assert corners[..., 0].min() >= 0 and corners[..., 0].max() <= s.rgb.shape[1] - 1
    assert corners[..., 1].min() >= 0 and corners[..., 1].max() <= s.rgb.shape[0] - 1
    # every one fails the rectangle metric against every positive
    assert not rectangle_metric_many(neg, rects_to_array(s.positives)).any()
    # ... while the grid does hold candidates that pass it (they were left out)
    assert rectangle_metric_many(enumerate_candidates(_region(s), GRID),
                                 rects_to_array(s.positives)).any()


def test_grid_negatives_are_reproducible_for_a_seed(box_samples):
    s = box_samples(1)[0]
    a = sample_grid_negatives(s, 50, np.random.default_rng(3), GRID)
    b = sample_grid_negatives(s, 50, np.random.default_rng(3), GRID)
    c = sample_grid_negatives(s, 50, np.random.default_rng(4), GRID)
    np.testing.assert_array_equal(a, b)
    assert _rows(a) != _rows(c)


def test_grid_negatives_counts_and_bad_input(box_samples):
    s = box_samples(1)[0]
    rng = np.random.default_rng(0)
    failing = ~rectangle_metric_many(enumerate_candidates(_region(s), GRID),
                                     rects_to_array(s.positives))
    # more than there are: all failing candidates, no more
    assert len(sample_grid_negatives(s, 10**6, rng, GRID)) == int(failing.sum())
    assert sample_grid_negatives(s, 0, rng, GRID).shape == (0, 5)
    nopos = dataclasses.replace(s, positives=[])
    assert sample_grid_negatives(nopos, 5, rng, GRID).shape == (0, 5)
    with pytest.raises(ValueError, match="non-negative integer"):
        sample_grid_negatives(s, -1, rng, GRID)


def test_grid_negatives_follow_the_region_method(box_samples):
    """With a mask (Jacquard, simulation) the candidates are laid out on the mask."""
    s = box_samples(1)[0]
    mask = np.zeros(s.depth.shape, bool)
    mask[20:60, 20:100] = True  # deliberately not the box
    neg = sample_grid_negatives(dataclasses.replace(s, mask=mask), 30,
                                np.random.default_rng(0), GRID)
    assert _rows(neg) <= _rows(enumerate_candidates(mask, GRID))
    assert neg[:, 1].max() < 120


def test_training_data_adds_grid_negatives_by_the_ratio(box_samples):
    samples = box_samples(3)
    base = recognition_data(samples, random_state=0)
    same = detection_training_data(samples, 0.0, GRID, random_state=0)
    np.testing.assert_array_equal(same.images, base.images)
    np.testing.assert_array_equal(same.labels, base.labels)
    m = 4  # 3 positives + 1 labelled negative per image
    for ratio, k in ((1.0, 4), (0.5, 2), (2.0, 8)):
        d = detection_training_data(samples, ratio, GRID, random_state=0)
        assert len(d) == len(samples) * (m + k)
        assert int(d.labels.sum()) == int(base.labels.sum())  # only negatives are added
        for s in samples:
            rows = np.flatnonzero(d.image_ids == s.image_id)
            assert len(rows) == m + k
            # the labelled rectangles come first, unchanged; then the grid negatives
            keep = np.flatnonzero(base.image_ids == s.image_id)
            np.testing.assert_array_equal(d.images[rows[:m]], base.images[keep])
            assert not d.labels[rows[m:]].any()
    a = detection_training_data(samples, 1.0, GRID, random_state=0)
    b = detection_training_data(samples, 1.0, GRID, random_state=0)
    c = detection_training_data(samples, 1.0, GRID, random_state=1)
    np.testing.assert_array_equal(a.images, b.images)
    assert not np.array_equal(a.images, c.images)


def test_training_data_keeps_the_sampled_negatives_of_positive_only_images(box_samples):
    """Jacquard-like images (mask, positives only): the sampled negatives do not change when
    grid negatives are added (independent random streams)."""
    samples = []
    for s in box_samples(2):
        samples.append(dataclasses.replace(s, negatives=[], mask=_region(s)))
    base = recognition_data(samples, random_state=5)
    d = detection_training_data(samples, 1.0, GRID, random_state=5)
    for s in samples:
        n_lab = 2 * len(s.positives)  # positives + as many sampled negatives
        rows = np.flatnonzero(d.image_ids == s.image_id)
        assert len(rows) == 2 * n_lab
        np.testing.assert_array_equal(d.images[rows[:n_lab]],
                                      base.images[base.image_ids == s.image_id])


def test_training_data_rejects_a_bad_ratio(box_samples):
    for bad in (-0.5, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="grid_negatives"):
            detection_training_data(box_samples(1), bad, PAPER_GRID)


def test_train_detector_records_and_applies_grid_negatives(box_samples):
    from dlsr.detection import train_detector

    samples = box_samples(3)
    with_grid = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID)
    without = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID,
                             grid_negatives=0)
    assert with_grid.config["grid_negatives"] == 1.0  # the default
    assert without.config["n_train_rectangles"] == 3 * 4
    assert with_grid.config["n_train_rectangles"] == 2 * 3 * 4
    assert with_grid.config["n_train_positive"] == without.config["n_train_positive"] == 9
    assert not np.allclose(with_grid.coef, without.coef)


# ------------------------------------------------------------------------------------------
# search grid fitted to the training positives


def test_fit_search_grid_keeps_the_sizes_of_the_positives():
    from dlsr.detection import fit_search_grid

    rng = np.random.default_rng(0)
    n = 400
    pos = np.column_stack([rng.uniform(0, 100, n), rng.uniform(0, 100, n),
                           rng.uniform(-1.5, 1.5, n), rng.uniform(22, 68, n),
                           rng.uniform(11, 27, n)])
    g = fit_search_grid(pos, PAPER_GRID, 0.0)
    assert g.openings == (20.0, 30.0, 40.0, 50.0, 60.0, 70.0)  # 22..68 widened by 5 px
    assert g.jaws == (10.0, 20.0, 30.0)
    # everything but the sizes is the base grid's
    assert (g.angles_deg, g.step, g.dilate, g.min_coverage, g.coverage_on, g.clear_jaws) == (
        PAPER_GRID.angles_deg, PAPER_GRID.step, PAPER_GRID.dilate, PAPER_GRID.min_coverage,
        PAPER_GRID.coverage_on, PAPER_GRID.clear_jaws)
    assert fit_search_grid(pos, SearchGrid(clear_jaws=True), 0.0).clear_jaws
    # a few outliers do not widen the range at the default quantile ...
    out = np.array([[50, 50, 0.0, 8.0, 8.0]] * 4 + [[50, 50, 0.0, 90.0, 60.0]] * 4)
    g2 = fit_search_grid(np.concatenate([pos, out]))
    assert g2.openings == g.openings and g2.jaws == g.jaws
    # ... but do at quantile 0
    g3 = fit_search_grid(np.concatenate([pos, out]), quantile=0.0)
    assert g3.openings[0] == 10.0 and g3.openings[-1] == 90.0 and g3.jaws[-1] == 60.0


def test_fit_search_grid_degenerate_cases():
    from dlsr.detection import fit_search_grid

    one = np.array([[50.0, 50.0, 0.3, 34.0, 14.0]])
    g = fit_search_grid(one)
    assert g.openings == (30.0,) and g.jaws == (10.0,)  # nearest values, one pair
    assert g.pairs() == [(30.0, 10.0)]
    # all positives between grid values far from any: the value nearest the median is kept
    coarse = SearchGrid(openings=(10, 90), jaws=(10,))
    assert fit_search_grid(np.array([[5, 5, 0, 50, 10], [5, 5, 0, 52, 10]]), coarse).openings \
        == (90.0,)
    with pytest.raises(ValueError, match="at least one positive"):
        fit_search_grid(np.zeros((0, 5)))
    with pytest.raises(ValueError, match="quantile"):
        fit_search_grid(one, quantile=0.5)
    with pytest.raises(ValueError, match="opening >= jaw"):
        fit_search_grid(np.array([[5, 5, 0, 10, 80]]), SearchGrid(openings=(10,), jaws=(80,)))


def test_train_detector_fits_the_grid_and_draws_negatives_from_it(box_samples):
    from dlsr.detection import train_detector

    samples = box_samples(3)  # positives 90 x 30 px
    model = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID,
                           fit_grid=0.025)
    assert model.config["fit_grid"] == 0.025
    # 90 px openings lie half way between 80 and 100 (half a step each way), 30 px jaws on 30
    assert model.config["grid"]["openings"] == [80.0, 100.0]
    assert model.config["grid"]["jaws"] == [30.0]
    assert model.config["grid"]["step"] == GRID.step
    # the detector searches the fitted grid
    assert model.detector("dense").grid.pairs() == [(80.0, 30.0), (100.0, 30.0)]
    # the training set's grid negatives come from it too: same count, other rectangles
    unfitted = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID,
                              fit_grid=None)
    assert unfitted.config["grid"]["openings"] == list(GRID.openings)
    assert model.config["n_train_rectangles"] == unfitted.config["n_train_rectangles"]
    assert not np.allclose(model.coef, unfitted.coef)


# ------------------------------------------------------------------------------------------
# hard-negative mining


def test_mined_negatives_are_the_detectors_best_failing_candidates(box_samples):
    from dlsr.detection import mine_hard_negatives, sample_observation, train_detector

    samples = box_samples(2)
    model = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID)
    det = model.detector("dense", grid=GRID, rescore=0, top_k=3)
    mined = mine_hard_negatives(det, samples, 4, pool=50)
    assert det.top_k == 3  # the caller's detector is left alone
    assert len(mined) == 2
    for s, m in zip(samples, mined, strict=True):
        assert m.shape == (4, 5)
        pos = rects_to_array(s.positives)
        assert not rectangle_metric_many(m, pos).any()
        # they are the first failing ones in the detector's own ranking
        full = model.detector("dense", grid=GRID, rescore=0, top_k=50).detect(
            sample_observation(s)).rects
        failing = full[~rectangle_metric_many(full, pos)]
        np.testing.assert_allclose(m, failing[:4])
    with pytest.raises(ValueError, match="positive integer"):
        mine_hard_negatives(det, samples, 0)


def test_train_detector_hard_negatives_refit_the_svm_only(box_samples):
    from dlsr.detection import train_detector

    samples = box_samples(3)
    plain = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID)
    hard = train_detector(samples, n_atoms=8, n_patches=2000, random_state=0, grid=GRID,
                          hard_negatives=3)
    assert hard.config["hard_negatives"] == 3 and hard.config["hard_rounds"] == 1
    assert hard.config["n_hard_negatives"] == 3 * 3
    assert hard.config["n_train_rectangles"] == plain.config["n_train_rectangles"] + 9
    assert hard.config["n_train_positive"] == plain.config["n_train_positive"]
    # same representation (dictionary and whitening), another classifier
    np.testing.assert_array_equal(hard.representation.dictionary, plain.representation.dictionary)
    assert not np.allclose(hard.coef, plain.coef)
    assert plain.config["n_hard_negatives"] == 0
    with pytest.raises(ValueError, match="hard_negatives"):
        train_detector(samples, n_atoms=8, n_patches=2000, grid=GRID, hard_negatives=-1)
