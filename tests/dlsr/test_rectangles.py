"""Properties of dlsr.rectangles: conventions, corner round trips, vectorised forms."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.rectangles import (
    GraspRectangle,
    array_from_corners,
    array_to_rects,
    as_rect_array,
    corners_from_array,
    normalize_angle,
    rects_to_array,
)


def random_rects(rng, n):
    return np.column_stack(
        [
            rng.uniform(0, 640, n),
            rng.uniform(0, 480, n),
            rng.uniform(-np.pi / 2, np.pi / 2, n),
            rng.uniform(1, 120, n),
            rng.uniform(1, 60, n),
        ]
    )


def test_normalize_angle_range_and_periodicity(rng):
    theta = rng.uniform(-20, 20, 10_000)
    out = normalize_angle(theta)
    assert np.all(out >= -np.pi / 2) and np.all(out < np.pi / 2)
    # Same line direction: differs by a multiple of pi.
    k = (theta - out) / np.pi
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    assert normalize_angle(np.pi / 2) == pytest.approx(-np.pi / 2)
    assert normalize_angle(-np.pi / 2) == pytest.approx(-np.pi / 2)
    assert normalize_angle(np.nextafter(-np.pi / 2, 0) - np.pi) < np.pi / 2
    assert isinstance(normalize_angle(0.3), float)


def test_theta_is_counter_clockwise_as_displayed():
    # Closing direction up and to the right on screen: p1 has a larger column, smaller row.
    r = GraspRectangle(100, 100, np.pi / 4, 20 * np.sqrt(2), 10)
    p0, p1 = r.corners()[:2]
    assert p1[0] - p0[0] == pytest.approx(20)
    assert p1[1] - p0[1] == pytest.approx(-20)


def test_corners_layout_w_along_closing_h_across():
    r = GraspRectangle(50, 40, 0.0, 30, 10)
    c = r.corners()
    np.testing.assert_allclose(c, [[35, 35], [65, 35], [65, 45], [35, 45]])
    assert np.linalg.norm(c[1] - c[0]) == pytest.approx(30)  # w: p0 -> p1
    assert np.linalg.norm(c[2] - c[1]) == pytest.approx(10)  # h: p1 -> p2
    np.testing.assert_allclose(c.mean(axis=0), [50, 40])


def test_from_corners_formula():
    pts = np.array([[10.0, 20.0], [13.0, 16.0], [21.0, 22.0], [18.0, 26.0]])
    r = GraspRectangle.from_corners(pts)
    assert r.w == pytest.approx(5.0)
    assert r.h == pytest.approx(10.0)
    assert r.theta == pytest.approx(normalize_angle(np.arctan2(4.0, 3.0)))
    assert (r.x, r.y) == pytest.approx((15.5, 21.0))


def test_corner_round_trip(rng):
    arr = random_rects(rng, 2000)
    back = array_from_corners(corners_from_array(arr))
    np.testing.assert_allclose(back[:, [0, 1, 3, 4]], arr[:, [0, 1, 3, 4]], atol=1e-9)
    dtheta = np.mod(back[:, 2] - arr[:, 2] + np.pi / 2, np.pi) - np.pi / 2
    np.testing.assert_allclose(dtheta, 0, atol=1e-9)
    for row in arr[:50]:
        r = GraspRectangle(*row)
        r2 = GraspRectangle.from_corners(r.corners())
        np.testing.assert_allclose(r2.as_array(), r.as_array(), atol=1e-9)
        np.testing.assert_allclose(r2.corners(), r.corners(), atol=1e-9)


def test_half_turn_gives_same_rectangle(rng):
    arr = random_rects(rng, 100)
    turned = arr.copy()
    turned[:, 2] += np.pi
    a, b = corners_from_array(arr), corners_from_array(turned)
    # Same corner set, in a different order (rotated by two).
    np.testing.assert_allclose(np.roll(b, 2, axis=1), a, atol=1e-9)
    for row in arr[:10]:
        r, r2 = GraspRectangle(*row), GraspRectangle(row[0], row[1], row[2] + np.pi, *row[3:])
        np.testing.assert_allclose(r2.as_array(), r.as_array(), atol=1e-12)


def test_vectorised_forms_agree(rng):
    arr = random_rects(rng, 30)
    rects = array_to_rects(arr)
    np.testing.assert_allclose(rects_to_array(rects), arr)
    np.testing.assert_allclose(
        corners_from_array(arr), np.stack([r.corners() for r in rects]), atol=1e-12
    )
    assert rects_to_array([]).shape == (0, 5)
    assert as_rect_array([]).shape == (0, 5)
    assert as_rect_array(rects[0]).shape == (1, 5)
    np.testing.assert_allclose(as_rect_array(rects), arr)
    np.testing.assert_allclose(as_rect_array(arr[0]), arr[:1])


def test_scaled():
    r = GraspRectangle(10, 20, 0.3, 30, 8).scaled(0.5)
    # Pixel-grid mapping of cv2.resize: x' = (x + 0.5) s - 0.5.
    np.testing.assert_allclose(r.as_array(), [4.75, 9.75, 0.3, 15, 4])
    assert r.area == pytest.approx(60)
    assert r.center == (4.75, 9.75)
    r2 = GraspRectangle(10, 20, 0.3, 30, 8).scaled(2.0, 3.0)
    np.testing.assert_allclose(r2.center, (20.5, 61.0))


@pytest.mark.parametrize(
    "args",
    [
        (0, 0, 0, 0, 10),
        (0, 0, 0, 10, -1),
        (np.nan, 0, 0, 10, 10),
        (0, 0, np.inf, 10, 10),
    ],
)
def test_invalid_rectangles_raise(args):
    with pytest.raises(ValueError, match="GraspRectangle"):
        GraspRectangle(*args)


def test_invalid_corners_raise():
    with pytest.raises(ValueError, match="finite"):
        GraspRectangle.from_corners([[0, 0], [1, 0], [1, 1], [np.nan, np.nan]])
    with pytest.raises(ValueError, match="shape"):
        GraspRectangle.from_corners([[0, 0], [1, 0], [1, 1]])
    with pytest.raises(ValueError, match="positive"):
        GraspRectangle.from_corners([[0, 0], [0, 0], [1, 1], [1, 1]])
    with pytest.raises(ValueError, match=r"\(n, 4, 2\)"):
        array_from_corners(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"\(n, 5\)"):
        corners_from_array(np.zeros((3, 4)))
