"""GG-CNN's pixel maps (numpy only, no torch): labels from rectangles checked by hand, the
angle convention, the read-out and the round trip, the depth preprocessing and the crop."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.rectangles import GraspRectangle
from graspsim.detectors.ggcnn.maps import (
    WIDTH_SCALE,
    crop_box,
    decode_maps,
    gg_angle,
    grasp_maps,
    our_angle,
    prepare_depth,
)


def test_label_maps_by_hand_horizontal_and_vertical():
    # theta = 0: the jaws close along the image x axis; the centre third of a 30 px opening is
    # |dx| <= 5 around x = 20, the whole 6 px jaw size is |dy| <= 3 around y = 12.
    m = grasp_maps([GraspRectangle(20, 12, 0.0, 30, 6)], (30, 40))
    q, cos2, sin2, width = m
    rows, cols = np.nonzero(q)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (9, 15, 15, 25)
    assert np.all(cos2[q > 0] == 1) and np.all(sin2[q > 0] == 0)
    assert np.allclose(width[q > 0], 30 / WIDTH_SCALE)
    assert np.all(m[:, q == 0] == 0)  # everything else is "not a grasp"
    # theta = pi/2 (closing along the rows): the same box turned a quarter
    q2, cos2b, sin2b, _ = grasp_maps([GraspRectangle(20, 12, np.pi / 2, 30, 6)], (30, 40))
    rows, cols = np.nonzero(q2)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (7, 17, 17, 23)
    assert np.allclose(cos2b[q2 > 0], -1) and np.allclose(sin2b[q2 > 0], 0, atol=1e-6)


def test_angle_convention_counter_clockwise_as_displayed():
    # theta = +45 deg closes up and to the right on screen: the labelled strip runs from the
    # lower left to the upper right (row decreases as column increases).
    q, cos2, sin2, _ = grasp_maps([GraspRectangle(20, 20, np.pi / 4, 30, 1)], (40, 40))
    assert q[17, 23] == 1 and q[23, 17] == 1  # (row, col): up-right and down-left of centre
    assert q[17, 17] == 0 and q[23, 23] == 0
    assert np.allclose(cos2[q > 0], 0, atol=1e-6) and np.allclose(sin2[q > 0], 1)
    # the mapping onto GG-CNN's angle is the identity, modulo pi
    assert gg_angle(np.pi / 4) == pytest.approx(np.pi / 4)
    assert gg_angle(3 * np.pi / 4) == pytest.approx(-np.pi / 4)
    assert our_angle(gg_angle(1.0)) == pytest.approx(1.0)


def test_decode_reads_hand_made_maps():
    maps = np.zeros((4, 50, 60), dtype=np.float32)
    maps[0, 30, 10] = 1.0  # a single peak at column 10, row 30
    maps[1], maps[2] = np.cos(2 * -0.3), np.sin(2 * -0.3)  # angle -0.3 rad everywhere
    maps[3] = 0.4  # width 0.4 * 150 = 60 px
    rects, scores = decode_maps(maps, n=3, sigma=2.0)
    assert len(rects) == 1 and scores[0] > 0
    x, y, theta, w, h = rects[0]
    assert (x, y) == (10, 30)
    assert theta == pytest.approx(-0.3) and w == pytest.approx(60) and h == pytest.approx(30)


def test_angle_from_filtered_cos_sin_not_from_angle_image():
    # Half the neighbourhood at +89 deg, half at -89 deg: the same grasp. Averaging the angle
    # image would give ~0 deg; the filtered cos/sin give +-90 deg.
    maps = np.zeros((4, 40, 40))
    maps[0, 20, 20] = 1
    a = np.deg2rad(np.where(np.arange(40)[None, :] < 20, 89.0, -89.0)) * np.ones((40, 1))
    maps[1], maps[2], maps[3] = np.cos(2 * a), np.sin(2 * a), 0.2
    (rect,), _ = decode_maps(maps, n=1)
    assert abs(abs(rect[2]) - np.pi / 2) < np.deg2rad(2)


@pytest.mark.parametrize("theta", [-1.2, -0.4, 0.0, 0.7, 1.5])
def test_round_trip_rectangle_to_maps_and_back(theta):
    r = GraspRectangle(47, 38, theta, 60, 24)
    maps = grasp_maps([r], (80, 96))
    (got,), scores = decode_maps(maps, n=1, sigma=5.0)  # a smooth peak at the centre
    assert np.hypot(got[0] - r.x, got[1] - r.y) <= 1.5
    d = (got[2] - r.theta + np.pi / 2) % np.pi - np.pi / 2
    assert abs(d) < 1e-6
    assert got[3] == pytest.approx(60, abs=1e-4) and got[4] == pytest.approx(30, abs=1e-4)


def test_decode_peaks_are_apart_and_best_first():
    maps = np.zeros((4, 60, 60))
    maps[0, 10, 10], maps[0, 12, 12], maps[0, 45, 40] = 0.5, 0.4, 0.9
    maps[3] = 0.2
    rects, scores = decode_maps(maps, n=5, sigma=0, min_distance=5)
    assert [tuple(r[:2]) for r in rects] == [(40, 45), (10, 10)]
    assert scores[0] > scores[1]


def test_decode_rejects_bad_maps():
    with pytest.raises(ValueError, match=r"shape \(4, H, W\)"):
        decode_maps(np.zeros((3, 10, 10)))
    bad = np.zeros((4, 10, 10))
    bad[0, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        decode_maps(bad)


def test_prepare_depth_inpaints_centres_and_clips():
    depth = np.full((40, 50), 0.7, dtype=np.float32)
    depth[10:20, 10:20] = 0.6
    depth[15, 30] = 0  # a hole on the table
    depth[0, :] = 0  # a missing border row
    x = prepare_depth(depth, depth > 0)
    assert x.dtype == np.float32 and np.isfinite(x).all()
    assert abs(x.mean()) < 1e-5
    # the holes are filled with what surrounds them (the table)
    assert x[15, 30] == pytest.approx(x[15, 40], abs=1e-3)
    assert x[0, 40] == pytest.approx(x[5, 40], abs=1e-3)
    assert x[15, 15] < x[15, 40]  # the object is nearer than the table
    far = prepare_depth(np.where(depth > 0, depth * 30, 0), depth > 0)  # 3 m relief
    assert far.min() >= -1 and far.max() <= 1 and far.min() == -1  # clipped


def test_prepare_depth_bad_input():
    with pytest.raises(ValueError, match="no valid pixel"):
        prepare_depth(np.zeros((20, 20), np.float32))
    with pytest.raises(ValueError, match="no valid pixel"):
        prepare_depth(np.ones((20, 20), np.float32), np.zeros((20, 20), bool))
    with pytest.raises(ValueError, match="2-D"):
        prepare_depth(np.ones((20, 20, 3), np.float32))


def test_crop_from_observation_not_labels(box_samples):
    s = box_samples(1)[0]
    row0, col0, side = crop_box(s.depth, s.depth_valid, 300, "object")
    assert side == 300 and 0 <= row0 <= 480 - 300 and 0 <= col0 <= 640 - 300
    # the box (centred at 320, 240) lies inside the crop, near its centre
    assert abs(col0 + 149.5 - 320) < 30 and abs(row0 + 149.5 - 240) < 30
    assert crop_box(s.depth, s.depth_valid, 300, "centre") == (90, 170, 300)
    assert crop_box(s.depth, s.depth_valid, 1000, "centre") == (0, 80, 480)
    with pytest.raises(ValueError, match="'object' or 'centre'"):
        crop_box(s.depth, s.depth_valid, 300, "labels")
