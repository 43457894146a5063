"""The planning path's fast parts give what the straightforward code gave, bit for bit: the
lattice made all at once against one point and one rectangle at a time (the code it replaced,
kept here as the reference), the convex hull of the rows' end points against that of every
pixel, the table fit's RANSAC against its loop of single fits, and the table fit's memo shared
by every way of passing the same image."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dlsr.datasets import check_camera_matrix
from dlsr.detection import complete_region, lattice_candidates, table_plane_mask, table_surface
from dlsr.detection.lattice import _lattice_array, _max_width_px, chords, lattice_step
from dlsr.detection.table import (
    _REGIONS,
    _TABLE_ARRAYS,
    _TABLE_FITS,
    _ransac_plane,
    _row_ends,
    _table_surface,
)
from dlsr.rectangles import GraspRectangle

K = np.array([[550.0, 0, 64], [0, 540.0, 48], [0, 0, 1]])


def _reference_lattice(mask, depth, intrinsics, offset, max_opening, jaw_px=(10.0, 28.0),
                       spacing=None, n_angles=12, margin_px=4.0, depth_band=0.02, reach=0.95,
                       seen=None, widest_in_reach=False):
    """One lattice point, one direction, one rectangle at a time (the code before the arrays)."""
    jaws, step = lattice_step(jaw_px, spacing)
    Km = None if max_opening is None else check_camera_matrix(intrinsics, "intrinsics")
    seen = set() if seen is None else seen
    full = np.asarray(mask, dtype=bool)
    depth = np.asarray(depth, dtype=float)
    out = []
    if full.sum() < 5:
        return out
    H, W = full.shape
    thetas = -np.pi / 2 + np.pi * np.arange(n_angles) / n_angles
    ys, xs = np.nonzero(full)
    x0, y0 = max(xs.min() - 1, 0), max(ys.min() - 1, 0)
    x1, y1 = min(xs.max() + 2, W), min(ys.max() + 2, H)
    mask, dep = full[y0:y1, x0:x1], depth[y0:y1, x0:x1]
    h_, w_ = mask.shape
    gx = np.arange(xs.min() - x0 + offset[0] - step, xs.max() - x0 + 1.0, step)
    gy = np.arange(ys.min() - y0 + offset[1] - step, ys.max() - y0 + 1.0, step)
    px, py = np.meshgrid(gx, gy)
    px, py = px.ravel(), py.ravel()
    ix, iy = np.rint(px).astype(int), np.rint(py).astype(int)
    ok = (ix >= 0) & (ix < w_) & (iy >= 0) & (iy < h_)
    ok[ok] = mask[iy[ok], ix[ok]] & (dep[iy[ok], ix[ok]] > 0)
    for x, y, i, j in zip(px[ok], py[ok], ix[ok], iy[ok], strict=True):
        pt = np.array([x, y])
        zc = dep[j, i]
        near = mask & (dep > 0) & (dep < zc + depth_band)
        runs_mask = np.column_stack(chords(mask, pt, thetas))
        runs_near = np.column_stack(chords(near, pt, thetas))
        for k, th in enumerate(thetas):
            u = np.array([np.cos(th), -np.sin(th)])
            for lo, hi in sorted({tuple(runs_mask[k]), tuple(runs_near[k])}):
                length = hi - lo
                c = pt + 0.5 * (lo + hi) * u
                ci = int(np.clip(np.rint(c[0]), 0, w_ - 1))
                cj = int(np.clip(np.rint(c[1]), 0, h_ - 1))
                z = dep[cj, ci] if dep[cj, ci] > 0 else zc
                c = c + (x0, y0)
                w_max = (np.inf if max_opening is None else
                         reach * float(_max_width_px(z, th, Km, max_opening)))
                widths = [length + margin_px, 1.3 * length + 2 * margin_px]
                if widest_in_reach and widths[0] <= w_max < widths[1]:
                    widths[1] = w_max
                for w in widths:
                    if w > w_max:
                        continue
                    for h in jaws:
                        key = (round(c[0]), round(c[1]), k, round(w / 2), h)
                        if key in seen:
                            continue
                        seen.add(key)
                        out.append(GraspRectangle(float(c[0]), float(c[1]), float(th),
                                                  float(w), float(h)))
    return out


def _objects(seed):
    """Masks and depths of a box, a mug seen from above (a rim standing over its inside and
    holes in it), a thin diagonal bar and a few pixels, on a 96 x 128 table."""
    rng = np.random.default_rng(seed)
    H, W = 96, 128
    yy, xx = np.mgrid[0:H, 0:W]
    table = 0.7 + 0.0002 * xx + 0.0001 * yy
    out = []
    box = (np.abs(xx - 60 - rng.integers(-5, 5)) < 25) & (np.abs(yy - 45) < 12)
    out.append((box, np.where(box, table - 0.05, table)))
    r = np.hypot(xx - 64, yy - 48 + rng.integers(-4, 4))
    mug = r < 22
    d = np.where(r < 17, table - 0.03, table - 0.09)
    d = np.where(mug & (rng.random((H, W)) < 0.05), 0.0, d)  # dropout on the object
    out.append((mug, np.where(mug, d, table)))
    bar = np.abs((xx - 64) * 0.6 - (yy - 48)) < 3 + rng.random() * 2
    bar &= np.abs(xx - 64) < 40
    out.append((bar, np.where(bar, table - 0.02, table)))
    tiny = np.zeros((H, W), bool)
    tiny[10:12, 10:13] = True
    out.append((tiny, table))
    return out


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("max_opening", [None, 0.085, 0.04])
@pytest.mark.parametrize("widest", [False, True])
def test_lattice_made_at_once_is_the_lattice_made_one_rectangle_at_a_time(seed, max_opening,
                                                                           widest):
    rng = np.random.default_rng(seed)
    seen_ref, seen_new = set(), set()
    n_total = 0
    for mask, depth in _objects(seed):  # one scene's objects share the keys already made
        offset = rng.uniform(0, 3.6, size=2)
        ref = _reference_lattice(mask, depth, K, offset, max_opening, (10.0, 28.0),
                                 seen=seen_ref, widest_in_reach=widest)
        new = lattice_candidates(mask, depth, K, offset, max_opening, (10.0, 28.0),
                                 seen=seen_new, widest_in_reach=widest)
        assert new == ref  # the same rectangles, in the same order
        arr, keys = _lattice_array(mask, depth, K, offset, max_opening, (10.0, 28.0),
                                   seen=set(), widest_in_reach=widest)
        fresh = _reference_lattice(mask, depth, K, offset, max_opening, (10.0, 28.0),
                                   widest_in_reach=widest)
        # the detector's array: the rows GraspRectangle.as_array gives, bit for bit
        expected = np.array([r.as_array() for r in fresh]).reshape(-1, 5)
        assert arr.shape == expected.shape and np.array_equal(arr, expected)
        assert len(keys) == len(fresh)
        # the detector's call, without keys: the same array
        quick, none = _lattice_array(mask, depth, K, offset, max_opening, (10.0, 28.0),
                                     widest_in_reach=widest, with_keys=False)
        assert np.array_equal(quick, arr) and none == []
        n_total += len(ref)
    assert seen_new == seen_ref
    assert n_total > 100


def _blobs(seed):
    rng = np.random.default_rng(seed)
    H, W = 120, 160
    yy, xx = np.mgrid[0:H, 0:W]
    yield rng.random((H, W)) < 0.02  # scattered pixels
    yield (np.hypot(xx - 80, yy - 60) < 40) & ~(np.hypot(xx - 90, yy - 60) < 20)  # crescent
    m = np.zeros((H, W), bool)
    m[5:115, 3:157] = True
    m[40:80, 60:100] = False  # a table with a hole
    yield m
    yield np.abs((xx - 80) - 2 * (yy - 60)) < 1.5  # a thin line with collinear pixels
    m = np.zeros((H, W), bool)
    m[0, :] = True
    yield m  # one row
    m = np.zeros((H, W), bool)
    m[50, 70] = True
    yield m  # one pixel


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_convex_hull_of_the_rows_end_points_is_the_masks(seed):
    for mask in _blobs(seed):
        every = cv2.convexHull(np.argwhere(mask)[:, ::-1].astype(np.int32))
        ends = cv2.convexHull(_row_ends(mask))
        assert np.array_equal(every, ends)
        a = np.zeros(mask.shape, np.uint8)
        b = np.zeros(mask.shape, np.uint8)
        cv2.fillConvexPoly(a, every, 1)
        cv2.fillConvexPoly(b, ends, 1)
        assert np.array_equal(a, b)


def test_complete_region_fills_the_missing_depth_inside_the_hull():
    H, W = 60, 80
    yy, xx = np.mgrid[0:H, 0:W]
    region = (np.hypot(xx - 40, yy - 30) < 15) & (np.abs(xx - 40) > 4)  # two halves
    valid = ~((np.abs(xx - 40) <= 4) & (np.abs(yy - 30) < 10))  # missing between them
    out = complete_region(region, valid)
    assert out[30, 40] and not region[30, 40]  # the gap inside the hull is added
    assert not out[5, 5]  # the table outside stays out
    assert not complete_region(np.zeros((H, W), bool), valid).any()


def _depth_scene():
    H, W = 120, 160
    yy, xx = np.mgrid[0:H, 0:W]
    depth = (0.7 + 0.0002 * xx + 0.0001 * yy).astype(np.float32)
    box = (np.abs(xx - 80) < 20) & (np.abs(yy - 60) < 15)
    depth[box] -= 0.04
    valid = np.ones((H, W), np.uint8)
    valid[::17, ::13] = 0
    depth[valid == 0] = 0.0
    return depth, valid, box


def test_table_fit_is_shared_by_every_way_of_passing_the_same_image():
    depth, valid, box = _depth_scene()
    _TABLE_FITS.clear()
    _REGIONS.clear()
    region, surface = table_plane_mask(depth, valid, return_surface=True)
    assert len(_TABLE_FITS._items) == 1
    assert (region & box).sum() > 0.8 * box.sum()
    # float64 depth, a bool mask, or no mask (missing depth is 0): the same fit, not another
    for d, v in ((depth.astype(np.float64), valid.astype(bool)), (depth, None),
                 (np.where(valid > 0, depth, 0.0), valid.astype(bool))):
        assert np.array_equal(table_surface(d, v), surface)
        assert np.array_equal(table_plane_mask(d, v), region)
    assert len(_TABLE_FITS._items) == 1
    # another image is another fit, and a fresh fit gives what the memo gave
    other = depth.copy()
    other[0, 0] += 0.001  # a pixel without depth: what the fit reads is the same
    table_surface(other, valid)
    assert len(_TABLE_FITS._items) == 1
    other[1, 1] += 0.001
    table_surface(other, valid)
    assert len(_TABLE_FITS._items) == 2
    _TABLE_FITS.clear()
    _REGIONS.clear()
    assert np.array_equal(table_surface(depth.astype(np.float64), valid.astype(bool)), surface)
    assert np.array_equal(table_plane_mask(depth, None), region)


def test_content_key_digests_float32_depth_once_and_tells_finer_float64_apart():
    """The memo key digests depth as float32 when float32 holds it exactly: float32 depth and
    the same values in float64 share a key; float64 depth that float32 would round does not
    share the key of its rounding (the fit reads the float64 values)."""
    from dlsr.detection.table import _content_key

    depth, valid, _ = _depth_scene()
    d32 = np.asarray(depth, dtype=np.float32)
    d64 = d32.astype(np.float64)
    assert _content_key(d32, valid) == _content_key(d64, np.asarray(valid, dtype=bool))
    finer = d64.copy()
    finer[np.asarray(valid, dtype=bool)] += 1e-12
    assert _content_key(finer, valid) != _content_key(d32, valid)
    assert _content_key(finer, valid) == _content_key(finer.copy(), valid)


def _reference_ransac(A, inv, z, loose, rng, n_iter):
    """RANSAC as a loop of single fits (the code before the stacked solve and the compiled
    counts)."""
    best, best_n = None, -1
    for _ in range(n_iter):
        idx = rng.choice(len(z), 3, replace=False)
        try:
            coef = np.linalg.solve(A[idx], inv[idx])
        except np.linalg.LinAlgError:
            continue
        inl = np.abs(1.0 / np.maximum(A @ coef, 1e-9) - z) < loose
        n = int(inl.sum())
        if n > best_n:
            best, best_n = inl, n
    return best, best_n


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ransac_is_the_loop_of_single_fits(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    x, y = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    z = 1.0 / (0.9 + 0.05 * x - 0.03 * y) + rng.normal(0, 0.002, n)
    z[: n // 4] -= rng.uniform(0.01, 0.1, n // 4)  # an object in front
    cases = [(x, y, z, None)]
    # a grid of pixels: repeated coordinates, singular draws (three points on a line), and
    # points lying exactly on the inlier band's edge
    gx, gy = np.meshgrid(np.linspace(-1, 1, 7), np.linspace(-1, 1, 5))
    zg = np.round(1.0 / (1.0 + 0.25 * gx.ravel()), 3)
    cases.append((gx.ravel(), gy.ravel(), zg, None))
    # points at 3 mm from the plane 1/z = 1, on the edge of a 3 mm band: verdicts decided by
    # the last bit, counted again by the reference expression
    xe, ye = rng.integers(-4, 5, 60) / 4, rng.integers(-4, 5, 60) / 4
    cases.append((xe, ye, np.where(rng.random(60) < 0.5, 1.0, 1.003), 0.003))
    # every draw singular (all points on a line): no plane
    cases.append((np.linspace(-1, 1, 40), np.zeros(40), np.ones(40), None))
    for x, y, z, edge in cases:
        A = np.column_stack([x, y, np.ones_like(x)])
        loose = np.maximum(0.025 * z, 0.003) if edge is None else np.full(len(z), edge)
        for state in (0, seed + 7):
            ref = _reference_ransac(A, 1.0 / z, z, loose, np.random.default_rng(state), 100)
            new = _ransac_plane(A, 1.0 / z, z, loose, np.random.default_rng(state), 100)
            assert new[1] == ref[1]
            assert (new[0] is None) == (ref[0] is None)
            assert ref[0] is None or np.array_equal(new[0], ref[0])


def test_table_arrays_memo_hands_out_copies_of_what_a_fit_gives():
    depth, valid, _ = _depth_scene()
    _TABLE_FITS.clear()
    _TABLE_ARRAYS.clear()
    d = np.where(valid > 0, depth, 1.0).astype(np.float64)
    fresh = _table_surface(d, valid > 0)
    first = table_surface(depth, valid)
    assert np.array_equal(first, fresh[0])
    first[:] = 0.0  # a caller changing its surface changes no later answer
    again = table_surface(depth, valid)
    assert np.array_equal(again, fresh[0])
    region, surface = table_plane_mask(depth, valid, return_surface=True)
    assert np.array_equal(surface, fresh[0])
    _TABLE_ARRAYS.clear()  # the fit known, its arrays recomputed: the same
    assert np.array_equal(table_surface(depth, valid), fresh[0])
    assert np.array_equal(table_plane_mask(depth, valid), region)
    _TABLE_FITS.clear()
    _TABLE_ARRAYS.clear()
    _REGIONS.clear()
