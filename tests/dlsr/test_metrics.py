"""Properties of dlsr.metrics: exact Jaccard, pi-periodic angles, the rectangle metric."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.metrics import (
    angle_difference,
    jaccard,
    jaccard_matrix,
    rectangle_metric,
    rectangle_metric_many,
)
from dlsr.rectangles import GraspRectangle, array_to_rects


def random_rects(rng, n, spread=60.0):
    return np.column_stack(
        [
            rng.uniform(100, 100 + spread, n),
            rng.uniform(100, 100 + spread, n),
            rng.uniform(-np.pi / 2, np.pi / 2, n),
            rng.uniform(5, 80, n),
            rng.uniform(5, 40, n),
        ]
    )


# --- angle_difference -----------------------------------------------------------------------


def test_angle_difference_properties(rng):
    a = rng.uniform(-10, 10, 1000)
    b = rng.uniform(-10, 10, 1000)
    d = angle_difference(a, b)
    assert np.all(d >= 0) and np.all(d <= np.pi / 2 + 1e-12)
    np.testing.assert_allclose(d, angle_difference(b, a), atol=1e-12)
    np.testing.assert_allclose(d, angle_difference(a + np.pi, b), atol=1e-9)
    np.testing.assert_allclose(d, angle_difference(a, b - 3 * np.pi), atol=1e-9)
    assert angle_difference(0.0, np.pi / 2) == pytest.approx(np.pi / 2)
    assert angle_difference(np.deg2rad(85), np.deg2rad(-85)) == pytest.approx(np.deg2rad(10))
    r1, r2 = GraspRectangle(0, 0, 0.1, 5, 5), GraspRectangle(0, 0, -0.2, 5, 5)
    assert angle_difference(r1, r2) == pytest.approx(0.3)


# --- jaccard --------------------------------------------------------------------------------


def test_identity_gives_one_and_disjoint_gives_zero(rng):
    for row in random_rects(rng, 20):
        r = GraspRectangle(*row)
        assert jaccard(r, r) == pytest.approx(1.0, abs=1e-12)
        far = GraspRectangle(r.x + 500, r.y, r.theta, r.w, r.h)
        assert jaccard(r, far) == 0.0
    # Touching squares (shared edge) have zero overlap.
    assert jaccard(GraspRectangle(0, 0, 0, 10, 10), GraspRectangle(10, 0, 0, 10, 10)) == 0.0


@pytest.mark.parametrize("dx,dy", [(0, 0), (3, 0), (0, 4), (5, 2), (9.5, 9.5), (12, 1)])
def test_axis_aligned_shift_analytic(dx, dy):
    w, h = 10.0, 10.0
    a = GraspRectangle(50, 50, 0.0, w, h)
    b = GraspRectangle(50 + dx, 50 + dy, 0.0, w, h)
    inter = max(w - abs(dx), 0) * max(h - abs(dy), 0)
    expected = inter / (2 * w * h - inter)
    assert jaccard(a, b) == pytest.approx(expected, abs=1e-12)


def test_axis_aligned_different_sizes_analytic():
    a = GraspRectangle(0, 0, 0.0, 40, 10)  # [-20, 20] x [-5, 5]
    b = GraspRectangle(10, 2, 0.0, 20, 20)  # [0, 20] x [-8, 12]
    inter = 20 * 10
    assert jaccard(a, b) == pytest.approx(inter / (400 + 400 - inter), abs=1e-12)
    # theta = pi/2 swaps which side lies along x.
    c = GraspRectangle(0, 0, np.pi / 2, 10, 40)
    assert jaccard(a, c) == pytest.approx(1.0, abs=1e-12)


def test_square_rotated_45_degrees_gives_octagon():
    s = 10.0
    a = GraspRectangle(0, 0, 0.0, s, s)
    b = GraspRectangle(0, 0, np.pi / 4, s, s)
    # The intersection is a regular octagon with inradius s/2: area 8 tan(pi/8) (s/2)^2.
    inter = 8 * np.tan(np.pi / 8) * (s / 2) ** 2
    assert jaccard(a, b) == pytest.approx(inter / (2 * s * s - inter), abs=1e-12)
    # Closed form of that ratio: 1 / sqrt(2).
    assert jaccard(a, b) == pytest.approx(1 / np.sqrt(2), abs=1e-12)


def test_jaccard_symmetric_and_invariant(rng):
    A, B = random_rects(rng, 40), random_rects(rng, 30)
    M = jaccard_matrix(A, B)
    np.testing.assert_allclose(M, jaccard_matrix(B, A).T, atol=1e-12)
    assert np.all((M >= 0) & (M <= 1 + 1e-12))
    # Same rectangles expressed with a half turn, and a common translation, change nothing.
    B2 = B.copy()
    B2[:, 2] += np.pi
    np.testing.assert_allclose(M, jaccard_matrix(A, B2), atol=1e-9)
    A3, B3 = A.copy(), B.copy()
    A3[:, :2] += [17.0, -5.0]
    B3[:, :2] += [17.0, -5.0]
    np.testing.assert_allclose(M, jaccard_matrix(A3, B3), atol=1e-9)


def test_jaccard_matrix_equals_scalar_loop(rng):
    A, B = random_rects(rng, 25), random_rects(rng, 15)
    M = jaccard_matrix(A, B)
    assert M.shape == (25, 15)
    assert (M > 0).sum() > 20 and (M == 0).sum() > 0  # the test covers both cases
    loop = np.array([[jaccard(a, b) for b in array_to_rects(B)] for a in array_to_rects(A)])
    np.testing.assert_allclose(M, loop, atol=1e-12)
    assert jaccard_matrix(np.zeros((0, 5)), B).shape == (0, 15)


# --- rectangle metric -----------------------------------------------------------------------


def test_angle_threshold_inclusive_at_30_degrees():
    truth = GraspRectangle(100, 100, 0.0, 40, 20)
    at = GraspRectangle(100, 100, np.pi / 6, 40, 20)
    beyond = GraspRectangle(100, 100, np.pi / 6 + 1e-6, 40, 20)
    assert jaccard(at, truth) > 0.25 and jaccard(beyond, truth) > 0.25
    assert rectangle_metric(at, [truth])
    assert not rectangle_metric(beyond, [truth])
    # pi-periodic: 180 + 30 degrees is still within.
    assert rectangle_metric(GraspRectangle(100, 100, np.pi + np.pi / 6, 40, 20), [truth])
    assert rectangle_metric(GraspRectangle(100, 100, -np.pi / 6, 40, 20), [truth])


def test_jaccard_threshold_strictly_above_quarter():
    truth = GraspRectangle(0, 0, 0.0, 10, 10)
    # Shift dx along x: J = (10 - dx) / (10 + dx); J = 0.25 at dx = 6.
    exactly = GraspRectangle(6, 0, 0.0, 10, 10)
    assert jaccard(exactly, truth) == pytest.approx(0.25, abs=1e-12)
    assert not rectangle_metric(exactly, [truth])
    assert rectangle_metric(GraspRectangle(5.99, 0, 0.0, 10, 10), [truth])
    assert not rectangle_metric(GraspRectangle(6.01, 0, 0.0, 10, 10), [truth])
    # Custom thresholds are honoured.
    assert rectangle_metric(exactly, [truth], min_jaccard=0.2)


def test_metric_needs_one_truth_meeting_both_conditions():
    pred = GraspRectangle(0, 0, 0.0, 20, 10)
    good_angle_far = GraspRectangle(100, 0, 0.0, 20, 10)
    close_bad_angle = GraspRectangle(0, 0, np.pi / 2, 20, 10)
    assert not rectangle_metric(pred, [good_angle_far, close_bad_angle])
    assert rectangle_metric(pred, [good_angle_far, close_bad_angle, pred])
    assert not rectangle_metric(pred, [])


def test_metric_many_equals_scalar_loop(rng):
    A, B = random_rects(rng, 200), random_rects(rng, 10)
    many = rectangle_metric_many(A, B)
    assert many.dtype == bool and many.shape == (200,)
    assert 0 < many.sum() < 200  # both outcomes occur
    loop = []
    for a in array_to_rects(A):
        ok = any(
            angle_difference(a, b) <= np.pi / 6 and jaccard(a, b) > 0.25
            for b in array_to_rects(B)
        )
        loop.append(ok)
    np.testing.assert_array_equal(many, loop)
    np.testing.assert_array_equal(
        many, [rectangle_metric(a, array_to_rects(B)) for a in array_to_rects(A)]
    )
    assert rectangle_metric_many(np.zeros((0, 5)), B).shape == (0,)


def test_invalid_input_raises():
    with pytest.raises(ValueError, match=r"\(n, 5\)"):
        jaccard_matrix(np.zeros((3, 4)), np.zeros((1, 5)))
    with pytest.raises(ValueError, match=r"\(n, 5\)"):
        rectangle_metric_many(np.zeros((2, 3)), np.zeros((1, 5)))
