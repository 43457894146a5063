"""The table under the objects, from depth alone: its fitted surface (:func:`table_surface`:
RANSAC in inverse depth, then robust polynomial refits), the object standing on it
(:func:`table_plane_mask`), and the memo that lets a plan's object region, physical term and
gripper-aware check share one fit.

Part of :mod:`dlsr.detection` (:mod:`dlsr.detection.grid` builds the object region and the
search on it).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import cv2
import numpy as np
from numba import njit

from .. import _threads


def _largest_blob(mask: np.ndarray, min_area: int = 20) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8),
                                                           connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, dtype=bool)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[best, cv2.CC_STAT_AREA] < min_area:
        return np.zeros(mask.shape, dtype=bool)
    return labels == best


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` with its holes filled (background components not touching the image border)."""
    H, W = mask.shape
    n, labels, stats, _ = cv2.connectedComponentsWithStats((~mask).astype(np.uint8),
                                                           connectivity=4)
    x, y = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
    inner = ((x > 0) & (y > 0) & (x + stats[:, cv2.CC_STAT_WIDTH] < W)
             & (y + stats[:, cv2.CC_STAT_HEIGHT] < H))
    inner[0] = False  # label 0: the mask itself
    return mask | inner[labels]


def valid_depth(depth, depth_valid=None) -> np.ndarray:
    """Pixels with a usable depth: finite, > 0 and (when given) marked valid, ``(H, W)`` bool."""
    depth = np.asarray(depth)
    valid = np.isfinite(depth) & (depth > 0)
    if depth_valid is not None:
        valid &= np.asarray(depth_valid, dtype=bool)
    return valid


def _table_surface(depth, valid, degree: int = 3, stride: int = 4, n_iter: int = 100,
                   tol: float = 0.003, band: float = 0.025, random_state=0):
    """The depth of the table's surface at every pixel, or None when none is found.

    RANSAC finds the dominant plane in inverse depth (``1/z`` of a plane is linear in the pixel
    coordinates for a pinhole camera's z-depth) with a loose band (``band`` times the depth, at
    least ``tol``), so that a range image (Euclidean distance to the camera, as Cornell's
    ``pcdXXXXd.tiff``) or a slightly curved or warped table is still caught whole. The inliers'
    largest 4-connected set (on the subsampled grid) is refitted by least squares in inverse depth
    with polynomials of degree 1, 2, ..., ``degree`` in the pixel coordinates, two rounds each;
    every round keeps the points within 3 robust standard deviations (1.4826 x the median absolute
    residual, along the ray, metres) of the fit, at least ``tol / 2``, never more than the band
    before, and again only their largest connected set.

    Parameters
    ----------
    depth : ndarray of shape (H, W), float64, metres
    valid : ndarray of shape (H, W), bool
    degree, stride, n_iter, tol, band, random_state :
        See :func:`table_plane_mask`.

    Returns
    -------
    surface : ndarray of shape (H, W), float64
        The fitted table depth, metres.
    table : ndarray of shape (H, W), bool
        Valid pixels within the final band of the surface, largest 8-connected set.
    sigma : float
        Robust standard deviation of the table's depth about the surface, metres.
    C : ndarray of shape (degree + 1, degree + 1)
        The polynomial in inverse depth: ``C[j, i]`` multiplies ``x**i * y**j``.
    """
    H, W = depth.shape
    sv = valid[::stride, ::stride]
    gv, gu = np.mgrid[0:H:stride, 0:W:stride]
    x, y = (2.0 * gu[sv] + 1) / W - 1, (2.0 * gv[sv] + 1) / H - 1  # in [-1, 1]
    z = depth[::stride, ::stride][sv]
    if len(z) < 50:
        return None
    inv = 1.0 / z
    A = np.column_stack([x, y, np.ones_like(x)])
    rng = np.random.default_rng(random_state)
    loose = np.maximum(band * z, tol)
    best, best_n = _ransac_plane(A, inv, z, loose, rng, n_iter)
    flat = np.flatnonzero(sv.ravel())

    def connected(keep):
        grid = np.zeros(sv.shape, dtype=bool)
        grid.ravel()[flat[keep]] = True
        n, labels, stats, _ = cv2.connectedComponentsWithStats(grid.astype(np.uint8),
                                                               connectivity=4)
        if n <= 1:
            return np.zeros(len(z), dtype=bool)
        return (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).ravel()[flat]

    if best is None or best_n < 20:
        return None
    keep, thr = connected(best), loose
    terms = {}  # x**i * y**j, computed once for every degree
    for deg in [d for d in range(1, degree + 1) for _ in range(2)]:
        if keep.sum() < 20:
            return None
        P = np.column_stack([terms.setdefault((i, j), x ** i * y ** j)
                             for i in range(deg + 1) for j in range(deg + 1 - i)])
        coef, *_ = np.linalg.lstsq(P[keep], inv[keep], rcond=None)
        resid = np.abs(1.0 / np.maximum(P @ coef, 1e-9) - z)
        sigma = 1.4826 * float(np.median(resid[keep]))
        thr = np.minimum(thr, max(3.0 * sigma, 0.5 * tol))
        keep = connected(resid < thr)
    powers = [(i, j) for i in range(deg + 1) for j in range(deg + 1 - i)]
    C = np.zeros((deg + 1, deg + 1))
    for (i, j), c in zip(powers, coef, strict=True):
        C[j, i] = c
    return _table_from(depth, valid, C, sigma, tol)


def _hypothesis_inliers(A, z, loose, coef):
    """RANSAC's inliers of one plane ``coef`` in inverse depth (the reference expression)."""
    return np.abs(1.0 / np.maximum(A @ coef, 1e-9) - z) < loose


def _ransac_plane(A, inv, z, loose, rng, n_iter):
    """``(inliers of the plane with most, their count)`` of ``n_iter`` RANSAC hypotheses
    (``(None, -1)`` when every draw is degenerate); the first with the largest count wins.

    Each hypothesis is the plane through 3 points drawn by ``rng`` (``choice(n, 3,
    replace=False)``, draw after draw as a loop of single fits draws them) and solved by
    LAPACK (one stacked call, the same factorisation of each 3 x 3 system). The inliers are
    counted in a compiled pass (:func:`_count_inliers`) that also flags every point whose
    verdict the rounding of the reference expression (:func:`_hypothesis_inliers`, a BLAS
    product) could turn: a hypothesis with such a point is counted again by the reference,
    and the winner's inliers are always the reference's, so the result is the loop's exactly.
    """
    idx = np.array([rng.choice(len(z), 3, replace=False) for _ in range(n_iter)],
                   dtype=np.intp).reshape(n_iter, 3)
    try:
        coefs = np.linalg.solve(A[idx], inv[idx][..., None])[..., 0]
        ok = np.ones(n_iter, dtype=bool)
    except np.linalg.LinAlgError:  # a singular draw: solved one at a time, it is skipped
        coefs = np.zeros((n_iter, 3))
        ok = np.zeros(n_iter, dtype=bool)
        for h in range(n_iter):
            try:
                coefs[h] = np.linalg.solve(A[idx[h]], inv[idx[h]])
                ok[h] = True
            except np.linalg.LinAlgError:
                continue
    counts = np.zeros(n_iter, np.int64)
    unsure = np.zeros(n_iter, np.int64)
    if ok.any():
        _count_inliers(np.ascontiguousarray(A[:, 0]), np.ascontiguousarray(A[:, 1]), z, loose,
                       np.ascontiguousarray(coefs), ok, counts, unsure)
    best_h, best_n = -1, -1
    for h in np.flatnonzero(ok).tolist():
        n = int(counts[h]) if not unsure[h] else int(_hypothesis_inliers(A, z, loose,
                                                                         coefs[h]).sum())
        if n > best_n:
            best_h, best_n = h, n
    if best_h < 0:
        return None, -1
    return _hypothesis_inliers(A, z, loose, coefs[best_h]), best_n


@njit(nogil=True, cache=True)
def _count_inliers(x, y, z, loose, coefs, ok, counts, unsure):
    """Per hypothesis ``h`` (``ok[h]``): ``counts[h]``, the points with ``|1 / max(x c0 + y c1
    + c2, 1e-9) - z| < loose``, and ``unsure[h]``, those whose verdict lies within a bound of
    the rounding of any order of that sum (8 units in the last place of its terms' absolute
    sum, carried through the reciprocal, plus the reciprocal's and difference's own rounding):
    only there can another evaluation of the expression decide otherwise. Branch-free, so
    that the loop is vectorised."""
    eps = 2.0 ** -52
    for h in range(coefs.shape[0]):
        if not ok[h]:
            continue
        c0 = coefs[h, 0]
        c1 = coefs[h, 1]
        c2 = coefs[h, 2]
        n = 0
        m = 0
        for i in range(x.shape[0]):
            a = x[i] * c0
            b = y[i] * c1
            v = a + b + c2
            r = abs(1.0 / max(v, 1e-9) - z[i])
            n += r < loose[i]
            # another evaluation gives v' within dv of v: 1 / max(v', 1e-9) moves by at most
            # dv / lo^2 with lo = max(v - dv, 1e-9)
            dv = 8.0 * eps * (abs(a) + abs(b) + abs(c2)) + 1e-300
            ql = 1.0 / max(v - dv, 1e-9)
            err = dv * ql * ql * 1.0000001 + 4.0 * eps * (ql + abs(z[i]) + r) + 1e-15
            m += abs(r - loose[i]) <= err
        counts[h] = n
        unsure[h] = m


def _table_from(depth, valid, C, sigma, tol):
    """``(surface, table, sigma, C)`` of :func:`_table_surface` from the fitted polynomial's
    coefficients ``C`` (``surface = 1 / (Y^T C X)``, the polynomial evaluated separably on the
    full grid)."""
    H, W = depth.shape
    deg = C.shape[0] - 1
    X = ((2.0 * np.arange(W) + 1) / W - 1)[None, :] ** np.arange(deg + 1)[:, None]
    Y = ((2.0 * np.arange(H) + 1) / H - 1)[None, :] ** np.arange(deg + 1)[:, None]
    surface = 1.0 / np.maximum(Y.T @ C @ X, 1e-9)
    table = _largest_blob(valid & (np.abs(depth - surface) < max(3.0 * sigma, tol)))
    return surface, table, sigma, C


def table_surface(depth, depth_valid=None, stride: int = 4, n_iter: int = 100,
                  tol: float = 0.003, random_state=0, degree: int = 3,
                  band: float = 0.025) -> np.ndarray | None:
    """The table's depth at every pixel, as :func:`table_plane_mask` fits it.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Metres; values <= 0 or non-finite are missing.
    depth_valid : ndarray of shape (H, W), bool, or None
    stride, n_iter, tol, random_state, degree, band :
        See :func:`table_plane_mask`.

    Returns
    -------
    ndarray of shape (H, W), float64, or None
        Metres (the fitted surface extrapolated over the whole image); None when fewer than 50
        pixels are valid or no table is found.
    """
    key = _fit_key(depth, depth_valid, stride, n_iter, tol, random_state, degree, band)
    _, _, fit = _fit_table(depth, depth_valid, stride, n_iter, tol, random_state, degree, band,
                           key)
    return None if fit is None else fit[0]


class _Memo:
    """A small thread-safe LRU of results keyed by the content of images (per process)."""

    def __init__(self, size: int):
        self.size = size
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            if key not in self._items:
                return None
            self._items.move_to_end(key)
            return self._items[key]

    def put(self, key, value) -> None:
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


#: The table fits and object regions of the images seen lately, by their content: a detector's
#: training, cross-validation folds, the physical features and the search each fit the table of
#: the same image again (15 times per image in ``graspsim run``'s detection benchmark and
#: models; 38 ms a fit, 37 ms more for the region). What is kept is small (the polynomial's
#: coefficients and the noise; the region as bits) and the result is recomputed from it the
#: same, bit for bit: the memo changes no result.
_TABLE_FITS = _Memo(4096)
_REGIONS = _Memo(1024)
#: The surface and table pixels of the last few fits (a plan asks for them three times: its
#: object region, its physical term and the gripper-aware check), consulted only where
#: :data:`_TABLE_FITS` knows the fit: what :func:`_table_from` would recompute from it,
#: handed out as copies.
_TABLE_ARRAYS = _Memo(4)


def _content_key(depth, depth_valid) -> bytes:
    """A digest of what a table fit reads of a depth image: its valid pixels
    (:func:`valid_depth`) and their depth in float64.

    Two ways of passing the same image (float32 or float64 depth, a validity mask of uint8 or
    bool, or none where the missing depth is already 0) get the same key, so that the detector,
    its physical term and the gripper-aware check (which passes a bool mask) share one fit; the
    fit reads nothing else (:func:`_fit_table`), so the memo still changes no result. The
    depth is digested as float32 when float32 holds its values exactly (a camera's float32
    depth, or the same values in float64: half the bytes, no float64 copy), else as float64.
    """
    depth = np.asarray(depth)
    valid = valid_depth(depth, depth_valid)
    kept = np.where(valid, depth, 0).reshape(-1)
    if kept.dtype != np.float32:
        wide = kept.astype(np.float64, copy=False)
        narrow = wide.astype(np.float32)
        kept = narrow if np.array_equal(narrow, wide) else wide
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{depth.shape} {kept.dtype.str}".encode())
    h.update(np.packbits(valid.reshape(-1)).tobytes())
    h.update(kept.view(np.uint8))
    return h.digest()


def _fit_key(depth, depth_valid, stride, n_iter, tol, random_state, degree, band):
    """The memo key of a table fit; None when RANSAC's randomness is not a plain seed."""
    if isinstance(random_state, bool) or not isinstance(random_state, int | np.integer):
        return None
    return (_content_key(depth, depth_valid), int(stride), int(n_iter), float(tol),
            int(random_state), int(degree), float(band))


def _fit_table(depth, depth_valid, stride, n_iter, tol, random_state, degree, band, key):
    """``(depth as float64, valid, (surface, table, sigma, C) or None)``: the table fit shared
    by :func:`table_surface` and :func:`table_plane_mask` (None when fewer than 50 pixels are
    valid or no table is found). Memoised in :data:`_TABLE_FITS` under ``key``
    (:func:`_fit_key`, which its callers compute once; None: not memoised)."""
    depth = np.asarray(depth, dtype=np.float64)
    valid = valid_depth(depth, depth_valid)
    if valid.sum() < 50:
        return depth, valid, None
    known = None if key is None else _TABLE_FITS.get(key)
    if known is not None:
        C, sigma = known
        if C is None:
            return depth, valid, None
        arrays = _TABLE_ARRAYS.get(key)
        if arrays is not None:
            return depth, valid, (arrays[0].copy(), arrays[1].copy(), sigma, C)
    filled = np.where(valid, depth, 1.0)
    # BLAS on one thread: the fit's products and least squares are small (under 20,000 x 10),
    # and a threaded BLAS waits for its pool on a busy machine (a fit took 0.3 s instead of
    # 0.03 s with 2 cores shared)
    with _threads.one_blas_thread():
        if known is not None:
            fit = _table_from(filled, valid, C, sigma, tol)
        else:
            fit = _table_surface(filled, valid, degree, stride, n_iter, tol, band,
                                 random_state)
    if key is not None:
        if known is None:
            _TABLE_FITS.put(key, (None, None) if fit is None else (fit[3].copy(), fit[2]))
        if fit is not None:
            _TABLE_ARRAYS.put(key, (fit[0].copy(), fit[1].copy()))
    return depth, valid, fit


def table_plane_mask(depth, depth_valid=None, min_height: float = 0.006, stride: int = 4,
                     n_iter: int = 100, tol: float = 0.003, random_state=0, degree: int = 3,
                     band: float = 0.025, min_area: int = 20, return_surface: bool = False):
    """The object standing on the table, from depth alone.

    The table's surface is fitted to the valid depth (subsampled by ``stride``): RANSAC on the
    dominant plane in inverse depth, ``1/z = a u + b v + c`` (exact for any plane seen by a
    pinhole camera, no intrinsics needed), then robust least-squares refits in inverse depth with
    polynomials up to ``degree`` in the pixel coordinates, so that a range image (Cornell's
    depth is the distance to the camera, not ``z``) or a warped board is followed too, with an
    inlier band of 3 robust standard deviations of the table's own depth noise. The table is the
    largest connected set of pixels on that surface.

    Object pixels stand in front of the surface (3 x 3 median of the height) by more than
    ``min_height`` or 3 standard deviations of the table's depth noise, whichever is larger,
    inside the convex hull of the table (the floor, walls and clutter beyond the table's edge
    are not on it). Pixels of missing depth in the hull join them into candidates, so the
    pieces of one object that dropout or shadows separate stay together. Of the candidates
    with at least ``min_area`` standing pixels, the one chosen is the largest the table
    encloses (at least half of its standing pixels inside the table with its holes filled: an
    object lies in a hole of the table), else the largest whose border is mostly table (at
    least half of the valid pixels of a 3 px ring), else the largest; walls and boards
    standing at the table's edge are neither. The region is its standing pixels, closed by a
    7 px disk within the candidate, holes filled.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Metres; values <= 0 or non-finite are missing.
    depth_valid : ndarray of shape (H, W), bool, or None
    min_height : float
        Metres.
    stride : int
        Subsampling of the pixels for the fit.
    n_iter : int
        RANSAC hypotheses.
    tol : float
        Smallest inlier band, metres (the final band is at least ``tol / 2`` around the fit,
        the table's pixels are those within ``max(tol, 3 sigma)``).
    random_state : int, numpy.random.Generator or None
        For RANSAC.
    degree : int
        Degree of the surface polynomial (1: a plane).
    band : float
        RANSAC's inlier band as a fraction of the depth (0.025: 25 mm at 1 m).
    min_area : int
        Smallest object blob, pixels.
    return_surface : bool
        Also return the fitted table surface (what :func:`table_surface` returns for the same
        arguments), so that a caller needing both fits the table once.

    Returns
    -------
    region : ndarray of shape (H, W), bool
        Empty when nothing stands out or the depth is unusable.
    surface : ndarray of shape (H, W), float64, or None
        Only with ``return_surface``: as :func:`table_surface`.
    """
    if int(degree) != degree or degree < 1:
        raise ValueError(f"degree must be an integer >= 1, got {degree!r}")
    key = _fit_key(depth, depth_valid, stride, n_iter, tol, random_state, degree, band)
    rkey = None if key is None else (key, float(min_height), int(min_area))
    bits = None if rkey is None else _REGIONS.get(rkey)
    if bits is not None and not return_surface:  # the region alone: no fit needed
        shape = np.shape(depth)
        return np.unpackbits(bits, count=int(np.prod(shape))).reshape(shape).astype(bool)
    depth, valid, fit = _fit_table(depth, depth_valid, stride, n_iter, tol, random_state,
                                   degree, band, key)
    if bits is not None:
        region = np.unpackbits(bits, count=depth.size).reshape(depth.shape).astype(bool)
    else:
        region = (np.zeros(depth.shape, dtype=bool) if fit is None or not fit[1].any()
                  else _standing_object(depth, valid, *fit[:3], min_height, min_area))
        if rkey is not None:
            _REGIONS.put(rkey, np.packbits(region.reshape(-1)))
    if return_surface:
        return region, None if fit is None else fit[0]
    return region


def _standing_object(depth, valid, surface, table, sigma, min_height, min_area) -> np.ndarray:
    """:func:`table_plane_mask`'s object region, given the fitted table."""
    H, W = depth.shape
    empty = np.zeros((H, W), dtype=bool)
    hull = cv2.convexHull(_row_ends(table))
    on_table = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(on_table, hull, 1)
    on_table = on_table.astype(bool)
    # height above the table, 3 x 3 median: a third less noise, thin objects kept
    height = cv2.medianBlur(np.where(valid, surface - depth, 0.0).astype(np.float32), 3)
    above = (height > max(min_height, 3.0 * sigma)) & on_table
    # the pieces of one object that missing depth (dropout, shadows) separates: one candidate
    n, labels, stats, _ = cv2.connectedComponentsWithStats(
        (above | (~valid & on_table)).astype(np.uint8), connectivity=8)
    enclosing = _fill_holes(table)
    ring_kernel = _disk(3)
    best, best_key = 0, None
    for i in range(1, n):
        x, y, w, h = (int(s) for s in stats[i, :4])
        r0, r1, c0, c1 = max(y - 4, 0), min(y + h + 4, H), max(x - 4, 0), min(x + w + 4, W)
        comp = labels[r0:r1, c0:c1] == i
        blob = comp & above[r0:r1, c0:c1]
        area = int(blob.sum())
        if area < min_area:
            continue
        ring = cv2.dilate(comp.astype(np.uint8), ring_kernel).astype(bool) & ~comp
        n_ring = max(int((ring & valid[r0:r1, c0:c1]).sum()), 1)
        support = (ring & table[r0:r1, c0:c1]).sum() / n_ring
        enclosed = (blob & enclosing[r0:r1, c0:c1]).sum() / area
        key = (enclosed >= 0.5, support >= 0.5, area)
        if best_key is None or key > best_key:
            best, best_key = i, key
    if best_key is None:
        return empty
    comp = labels == best
    region = cv2.morphologyEx((above & comp).astype(np.uint8), cv2.MORPH_CLOSE, _disk(3))
    return _fill_holes(region.astype(bool) & comp)


def _row_ends(mask) -> np.ndarray:
    """The first and last pixel of each row of ``mask``, ``(n, 2)`` int32 ``(x, y)`` points.

    The convex hull of a mask's pixels is that of its rows' end points (every other pixel lies
    between the two ends of its row), a few hundred points instead of up to the whole image's;
    ``cv2.convexHull`` of either returns the same polygon (tests check it).
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if not len(rows):
        return np.zeros((0, 2), np.int32)
    sub = mask[rows]
    first = np.argmax(sub, axis=1)
    last = sub.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    return np.concatenate([np.column_stack([first, rows]),
                           np.column_stack([last, rows])]).astype(np.int32)


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
