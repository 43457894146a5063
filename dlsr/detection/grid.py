"""The search grid and the candidates: :class:`SearchGrid` (the paper's and a coarse one), the
object region (:func:`object_region`: background subtraction, the observation's mask, or the
pixels standing in front of the table plane, :func:`table_plane_mask`) and
:func:`enumerate_candidates`.

Part of :mod:`dlsr.detection` (the package docstring describes the search).
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from .. import _threads
from ..rectangles import corners_from_array, normalize_angle


@dataclass(frozen=True)
class SearchGrid:
    """The candidate grid (Lenz et al.'s search by default).

    Parameters
    ----------
    angles_deg : tuple of float
        Closing-direction angles, degrees, counter-clockwise as displayed.
    openings, jaws : tuple of float
        Opening ``w`` and jaw size ``h`` values, pixels; pairs with ``w >= h`` are searched.
    step : float
        Spacing of the candidate centres, pixels.
    dilate : int
        Dilation of the object region, pixels (a disk).
    min_coverage : float
        Fraction of a candidate's area that must lie on the region.
    coverage_on : {"dilated", "object"}
        Which region the coverage is measured on.
    clear_jaws : bool
        Keep only the candidates a parallel-jaw gripper can close on: both jaws (the two
        sides of length ``h`` at ``+-w/2`` along the closing direction) lie off the
        (undilated) object region for at least 75 % of their length, and some of the object
        lies between them (:func:`jaws_clear`). Not in the paper (off by default): without it
        the search also scores rectangles narrower than the object, which a model can rank
        first (e.g. 10 x 10 px on a real remote control's edge).
    max_width : float or None
        Metres: keep only the candidates whose opening, measured at the depth under their
        centre (``w z / f`` with the observation's camera matrix ``K``, :func:`opening_widths`),
        is at most this (a gripper's largest opening). Needs ``obs["K"]``; None (default, the
        paper) keeps every size.
    complete_region : bool
        Lay the candidates on the object region with its unseen surface added (the missing
        depth inside its convex hull, :func:`complete_region`), as the lattice detector does
        (``LatticeDetector(complete=True)``). Not in the paper (off by default).
    """

    angles_deg: tuple = tuple(range(0, 180, 15))
    openings: tuple = tuple(range(10, 100, 10))
    jaws: tuple = tuple(range(10, 100, 10))
    step: float = 10.0
    dilate: int = 20
    min_coverage: float = 0.5
    coverage_on: str = "dilated"
    clear_jaws: bool = False
    max_width: float | None = None
    complete_region: bool = False

    def pairs(self) -> list[tuple[float, float]]:
        """``(w, h)`` pairs with ``w >= h``."""
        return [(float(w), float(h)) for w in self.openings for h in self.jaws if w >= h]

    def to_dict(self) -> dict:
        return {
            "angles_deg": [float(a) for a in self.angles_deg],
            "openings": [float(w) for w in self.openings],
            "jaws": [float(h) for h in self.jaws],
            "step": float(self.step),
            "dilate": int(self.dilate),
            "min_coverage": float(self.min_coverage),
            "coverage_on": self.coverage_on,
            "clear_jaws": bool(self.clear_jaws),
            "max_width": None if self.max_width is None else float(self.max_width),
            # added later: only when used, so earlier models' saved grids stay the same
            **({"complete_region": True} if self.complete_region else {}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> SearchGrid:
        d = dict(d)
        for k in ("angles_deg", "openings", "jaws"):
            if k in d:
                d[k] = tuple(d[k])
        return cls(**d)


#: The paper's grid (Lenz et al.): 12 angles x 45 (w, h) pairs, centres every 10 px.
PAPER_GRID = SearchGrid()
#: First stage of the coarse-to-fine mode: 6 angles, openings and jaws 20..80 every 20 px,
#: centres every 10 px (the paper's centres: a 10 px shift is half of a small rectangle).
COARSE_GRID = SearchGrid(angles_deg=tuple(range(0, 180, 30)), openings=(20, 40, 60, 80),
                         jaws=(20, 40, 60, 80), step=10.0)


def _largest_blob(mask: np.ndarray, min_area: int = 20) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8),
                                                           connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, dtype=bool)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[best, cv2.CC_STAT_AREA] < min_area:
        return np.zeros(mask.shape, dtype=bool)
    return labels == best


def background_mask(rgb, background, threshold: float = 100.0) -> np.ndarray:
    """Background subtraction (Lenz et al.): sum over RGB of ``|image - background|`` above
    ``threshold`` (0-255 units), largest 8-connected blob.

    Returns
    -------
    ndarray of shape (H, W), bool (empty when nothing differs).
    """
    rgb = np.asarray(rgb)
    background = np.asarray(background)
    if background.shape != rgb.shape:
        raise ValueError(f"background image shape {background.shape} differs from the image "
                         f"{rgb.shape}")
    diff = np.abs(rgb.astype(np.int32) - background.astype(np.int32)).sum(axis=-1)
    return _largest_blob(diff > threshold)


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


def _poly_terms(x, y, degree: int) -> np.ndarray:
    """Monomials ``x**i * y**j`` with ``i + j <= degree``, shape ``(len(x), n_terms)``."""
    return np.column_stack([x ** i * y ** j for i in range(degree + 1)
                            for j in range(degree + 1 - i)])


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
    best, best_n = None, -1
    for _ in range(n_iter):  # RANSAC: the dominant plane
        idx = rng.choice(len(z), 3, replace=False)
        try:
            coef = np.linalg.solve(A[idx], inv[idx])
        except np.linalg.LinAlgError:
            continue
        inl = np.abs(1.0 / np.maximum(A @ coef, 1e-9) - z) < loose
        n = int(inl.sum())
        if n > best_n:
            best, best_n = inl, n
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
    for deg in [d for d in range(1, degree + 1) for _ in range(2)]:
        if keep.sum() < 20:
            return None
        P = _poly_terms(x, y, deg)
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
    filled = np.where(valid, depth, 1.0)
    known = None if key is None else _TABLE_FITS.get(key)
    # BLAS on one thread: the fit's products and least squares are small (under 20,000 x 10),
    # and a threaded BLAS waits for its pool on a busy machine (a fit took 0.3 s instead of
    # 0.03 s with 2 cores shared)
    with _threads.limit(1, user_api="blas"):
        if known is not None:
            C, sigma = known
            return depth, valid, None if C is None else _table_from(filled, valid, C, sigma,
                                                                    tol)
        fit = _table_surface(filled, valid, degree, stride, n_iter, tol, band, random_state)
    if key is not None:
        _TABLE_FITS.put(key, (None, None) if fit is None else (fit[3].copy(), fit[2]))
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


def complete_region(region, valid) -> np.ndarray:
    """The object region with the missing depth inside its convex hull added.

    A structured-light sensor returns little or no depth on the top of a dark, specular or
    transparent object seen from above, so the region found from depth
    (:func:`table_plane_mask`) is a scatter of small islands where the object is one disc;
    the missing pixels between them are the object's unseen surface. The table around the
    object (valid depth) stays outside, and so does missing depth outside the hull (most of a
    projector shadow, which falls beside the object).

    Parameters
    ----------
    region : ndarray of shape (H, W), bool
    valid : ndarray of shape (H, W), bool
        Pixels with depth (:func:`valid_depth`).

    Returns
    -------
    ndarray of shape (H, W), bool
        A new array; ``region`` itself when it is empty.
    """
    region = np.asarray(region, dtype=bool)
    valid = np.asarray(valid, dtype=bool)
    if region.shape != valid.shape or region.ndim != 2:
        raise ValueError(f"region {region.shape} and valid {valid.shape} must be the same "
                         "(H, W)")
    if not region.any():
        return region
    hull = np.zeros(region.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(_row_ends(region)), 1)
    return region | (hull.astype(bool) & ~valid)


def fill_unseen_surface(depth, valid, region):
    """The depth image with the object's unseen surface filled in from its seen surface.

    The pixels without depth inside the completed object region (:func:`complete_region`:
    the missing depth inside the convex hull of ``region``) get the depth of the nearest pixel
    of ``region`` that has depth (exact Euclidean distance). A check that only trusts the
    depth it sees (a finger coming down where the sensor returned nothing) then meets the rim
    of a dark mug or the wall of a glass where the object is, not empty space.

    Parameters
    ----------
    depth : ndarray of shape (H, W), float
        Metres, 0 where missing.
    valid : ndarray of shape (H, W), bool
    region : ndarray of shape (H, W), bool
        The object region found from the observation (e.g. :func:`table_plane_mask`).

    Returns
    -------
    depth : ndarray of shape (H, W), float
        A new array (the input is not changed).
    valid : ndarray of shape (H, W), bool
        ``valid`` with the filled pixels added.
    """
    depth = np.asarray(depth)
    valid = np.asarray(valid, dtype=bool)
    region = np.asarray(region, dtype=bool)
    if not (depth.shape == valid.shape == region.shape) or depth.ndim != 2:
        raise ValueError(f"depth {depth.shape}, valid {valid.shape} and region {region.shape} "
                         "must be the same (H, W)")
    seen = region & valid & (depth > 0)
    out_valid = valid.copy()
    if not seen.any():
        return depth.copy(), out_valid
    unseen = complete_region(region, valid) & ~valid
    out_valid[unseen] = True
    out = _nearest_fill(depth, unseen, seen)
    return (depth.copy() if out is depth else out), out_valid


def _nearest_fill(depth, holes, source):
    """``depth`` with each pixel of ``holes`` set to the depth of the nearest ``source`` pixel
    (exact Euclidean distance); ``depth`` itself when there is nothing to fill or nothing to
    fill from.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
    holes, source : ndarray of shape (H, W), bool

    Returns
    -------
    ndarray of shape (H, W)
        A new array when a hole was filled.
    """
    from scipy.ndimage import distance_transform_edt

    if not holes.any() or not source.any():
        return depth
    _, (iy, ix) = distance_transform_edt(~source, return_indices=True)
    out = depth.copy()
    out[holes] = depth[iy[holes], ix[holes]]
    return out


def object_region(obs: dict, background=None, method: str = "auto", min_height: float = 0.006):
    """The object region of an observation and how it was found.

    Parameters
    ----------
    obs : dict
        ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) metres, ``depth_valid`` (H, W), optional
        ``mask`` (H, W) bool.
    background : ndarray of shape (H, W, 3) or None
        Background image for background subtraction (Cornell).
    method : {"auto", "background", "mask", "depth"}
        ``"auto"``: background subtraction when ``background`` is given, else ``obs["mask"]``
        when present, else the depth above the table plane (:func:`table_plane_mask`).
    min_height : float
        For the table-plane method, metres.

    Returns
    -------
    region : ndarray of shape (H, W), bool
    how : str
    """
    if method not in ("auto", "background", "mask", "depth"):
        raise ValueError(f"unknown region method {method!r}; choose auto, background, mask "
                         "or depth")
    if method == "background" or (method == "auto" and background is not None):
        if background is None:
            raise ValueError("region method 'background' needs a background image")
        return background_mask(obs["rgb"], background), "background"
    mask = obs.get("mask")
    if method == "mask" or (method == "auto" and mask is not None):
        if mask is None:
            raise ValueError("region method 'mask' needs obs['mask']")
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != np.asarray(obs["depth"]).shape:
            raise ValueError(f"obs['mask'] has shape {mask.shape}, the depth "
                             f"{np.asarray(obs['depth']).shape}")
        return mask, "mask"
    return table_plane_mask(obs["depth"], obs.get("depth_valid"), min_height=min_height), "depth"


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _axes(theta: float):
    c, s = math.cos(theta), math.sin(theta)
    return np.array([c, -s]), np.array([s, c])  # u: closing direction, v: across (as preprocess)


def _box_sums(T, r0, r1, c0, c1):
    """Sums over ``[r0, r1) x [c0, c1)`` from a summed-area table with a zero first row/col."""
    return T[r1, c1] - T[r0, c1] - T[r1, c0] + T[r0, c0]


def _sat(a) -> np.ndarray:
    T = np.zeros((a.shape[0] + 1, a.shape[1] + 1), dtype=np.float64)
    np.cumsum(np.cumsum(a, axis=0, dtype=np.float64), axis=1, out=T[1:, 1:])
    return T


def enumerate_candidates(region: np.ndarray, grid: SearchGrid = PAPER_GRID):
    """All candidates of the search grid on an object region.

    Parameters
    ----------
    region : ndarray of shape (H, W), bool
        The (undilated) object region.
    grid : SearchGrid

    Returns
    -------
    ndarray of shape (n, 5)
        ``(x, y, theta, w, h)`` rows, grouped by angle then ``(w, h)``; empty when the region is.
    """
    region = np.asarray(region, dtype=bool)
    H, W = region.shape
    if not region.any():
        return np.zeros((0, 5))
    dil = cv2.dilate(region.astype(np.uint8), _disk(int(grid.dilate))).astype(bool)
    cover = dil if grid.coverage_on == "dilated" else region
    if grid.coverage_on not in ("dilated", "object"):
        raise ValueError(f"coverage_on must be 'dilated' or 'object', got {grid.coverage_on!r}")
    rows, cols = np.nonzero(dil)
    step = float(grid.step)
    xs = np.arange(math.ceil(cols.min() / step) * step, cols.max() + 1e-9, step)
    ys = np.arange(math.ceil(rows.min() / step) * step, rows.max() + 1e-9, step)
    cx, cy = np.meshgrid(xs, ys)
    cx, cy = cx.ravel(), cy.ravel()
    pairs = grid.pairs()
    out = []
    cover_u8 = cover.astype(np.uint8)
    for deg in grid.angles_deg:
        theta = normalize_angle(math.radians(deg))
        u, v = _axes(theta)
        a = cx * u[0] + cy * u[1]
        b = cx * v[0] + cy * v[1]
        half = max(max(w, h) for w, h in pairs) / 2 + 2
        A0 = math.floor(a.min() - half)
        B0 = math.floor(b.min() - half)
        Wc = int(math.ceil(a.max() + half)) - A0 + 1
        Hc = int(math.ceil(b.max() + half)) - B0 + 1
        # canvas pixel (i, j) <-> image point (A0 + j) u + (B0 + i) v
        M = np.array([[u[0], v[0], A0 * u[0] + B0 * v[0]],
                      [u[1], v[1], A0 * u[1] + B0 * v[1]]])
        rot = cv2.warpAffine(cover_u8, M, (Wc, Hc), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        T = _sat(rot)
        for w, h in pairs:
            nw, nh = max(1, int(round(w))), max(1, int(round(h)))
            j0 = np.rint(a - A0 - (nw - 1) / 2).astype(np.intp)
            i0 = np.rint(b - B0 - (nh - 1) / 2).astype(np.intp)
            frac = _box_sums(T, i0, i0 + nh, j0, j0 + nw) / (nw * nh)
            keep = frac >= grid.min_coverage
            if not keep.any():
                continue
            k = int(keep.sum())
            out.append(np.column_stack([cx[keep], cy[keep], np.full(k, theta),
                                        np.full(k, w), np.full(k, h)]))
    if not out:
        return np.zeros((0, 5))
    cand = np.concatenate(out)
    corners = corners_from_array(cand)
    inside = ((corners[..., 0] >= 0) & (corners[..., 0] <= W - 1)
              & (corners[..., 1] >= 0) & (corners[..., 1] <= H - 1)).all(axis=1)
    cand = cand[inside]
    if grid.clear_jaws:
        cand = cand[jaws_clear(region, cand)]
    return cand


def opening_widths(obs: dict, rects, region=None) -> np.ndarray:
    """The openings of rectangles in metres, measured at the depth under their centres.

    ``w z |(cos(theta) / fx, sin(theta) / fy)|`` (``w z / f`` for square pixels), with ``z`` the
    valid depth at the centre pixel, or where it is missing the median valid depth of
    ``region`` (of the whole image when None or empty).

    Parameters
    ----------
    obs : dict
        ``depth`` (H, W) metres, optional ``depth_valid``, and ``K`` (3, 3).
    rects : ndarray of shape (n, 5)
    region : ndarray of shape (H, W), bool, or None

    Returns
    -------
    ndarray of shape (n,), metres
    """
    if obs.get("K") is None:
        raise ValueError("measuring openings in metres needs the observation's camera matrix "
                         "'K' (SearchGrid.max_width)")
    from ..datasets import check_camera_matrix

    K = check_camera_matrix(obs["K"], "observation 'K'")
    depth = np.asarray(obs["depth"], dtype=float)
    valid = valid_depth(depth, obs.get("depth_valid"))
    rects = np.asarray(rects, dtype=float).reshape(-1, 5)
    if not valid.any():
        return np.full(len(rects), np.inf)
    pool = valid & region if region is not None and (valid & region).any() else valid
    fallback = float(np.median(depth[pool]))
    H, W = depth.shape
    col = np.clip(np.rint(rects[:, 0]).astype(np.intp), 0, W - 1)
    row = np.clip(np.rint(rects[:, 1]).astype(np.intp), 0, H - 1)
    z = np.where(valid[row, col], depth[row, col], fallback)
    scale = np.hypot(np.cos(rects[:, 2]) / K[0, 0], np.sin(rects[:, 2]) / K[1, 1])
    return rects[:, 3] * z * scale


def within_reach(obs: dict, rects, region, grid: SearchGrid) -> np.ndarray:
    """``rects`` whose opening is at most ``grid.max_width`` metres (:func:`opening_widths`);
    all of them when ``grid.max_width`` is None."""
    if grid.max_width is None or not len(rects):
        return rects
    return rects[opening_widths(obs, rects, region) <= grid.max_width]


def jaws_clear(region, rects, max_on: float = 0.0, n_samples: int = 17,
               clearance: int = 1) -> np.ndarray:
    """Whether a parallel-jaw gripper can close on the object along each rectangle.

    A rectangle ``(x, y, theta, w, h)`` passes when its centre is on the object region and
    each of its two jaws (the segments of length ``h`` across the closing direction at
    ``+-w/2`` from the centre, ``n_samples`` points each) has at most ``max_on`` of its points
    within ``clearance`` pixels of the region: the fingers come down beside the object, not on
    it (in simulation, "collision on approach"), so the opening spans the object there, with
    room for the fingers and for a region found from depth, whose edge falls a few pixels
    inside the object's where its sides are rounded.

    Parameters
    ----------
    region : ndarray of shape (H, W), bool
        The (undilated) object region.
    rects : ndarray of shape (n, 5)
        Pixels and radians, as :class:`dlsr.rectangles.GraspRectangle`.
    max_on : float
        Largest fraction of a jaw's points within ``clearance`` of the region.
    n_samples : int
        Points per jaw (at least 3).
    clearance : int
        Dilation of the region for the jaw test, pixels (a square of side
        ``2 clearance + 1``).

    Returns
    -------
    ndarray of shape (n,), bool

    Notes
    -----
    A stricter test than the training labels: of the labelled positives of the 28 real
    Jacquard sample views (half size, object masks) 63 % pass (85 % have their centre on the
    mask; the others mostly have a jaw over another part of a 3-D object, a chair's legs, a
    frame's bars), of 96 physics-labelled positives of 16 synthetic scenes (regions from
    depth) 83 %.
    """
    region = np.asarray(region, dtype=bool)
    rects = np.asarray(rects, dtype=float).reshape(-1, 5)
    if n_samples < 3:
        raise ValueError(f"n_samples must be >= 3, got {n_samples}")
    if region.ndim != 2:
        raise ValueError(f"region must be a 2-D mask, got shape {region.shape}")
    if clearance < 0:
        raise ValueError(f"clearance must be >= 0, got {clearance}")
    H, W = region.shape
    near = region
    if clearance:
        side = 2 * int(clearance) + 1
        near = cv2.dilate(region.astype(np.uint8), np.ones((side, side), np.uint8)).astype(bool)

    def on(mask, r, a, b):  # points a along the closing direction, b across, (n, k) each
        c, s = np.cos(r[:, 2:3]), np.sin(r[:, 2:3])  # u = (c, -s), v = (s, c), as _axes
        col = np.rint(r[:, 0:1] + a * c + b * s).astype(np.intp)
        row = np.rint(r[:, 1:2] - a * s + b * c).astype(np.intp)
        ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        hit = np.zeros(col.shape, dtype=bool)
        hit[ok] = mask[row[ok], col[ok]]
        return hit

    keep = on(region, rects, np.zeros((len(rects), 1)), np.zeros((len(rects), 1)))[:, 0]
    t = np.linspace(-0.5, 0.5, n_samples)[None, :]
    for side in (0.5, -0.5):  # each jaw, on the candidates still in
        idx = np.flatnonzero(keep)
        r = rects[idx]
        hits = on(near, r, side * r[:, 3:4] * np.ones_like(t), r[:, 4:5] * t)
        keep[idx] = hits.mean(axis=1) <= max_on
    return keep
