"""The search grid and the candidates: :class:`SearchGrid` (the paper's and a coarse one), the
object region (:func:`object_region`: background subtraction, the observation's mask, or the
pixels standing in front of the table plane, :func:`table_plane_mask`) and
:func:`enumerate_candidates`.

Part of :mod:`dlsr.detection` (the package docstring describes the search).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .. import _crops
from ..rectangles import corners_from_array, normalize_angle
from .table import (  # noqa: F401 (the table fit's names stay importable from here)
    _REGIONS,
    _TABLE_ARRAYS,
    _TABLE_FITS,
    _content_key,
    _disk,
    _fill_holes,
    _fit_key,
    _fit_table,
    _largest_blob,
    _Memo,
    _row_ends,
    _table_from,
    _table_surface,
    table_plane_mask,
    table_surface,
    valid_depth,
)


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
    if not holes.any() or not source.any():
        return depth
    # the nearest source pixel, as scipy's distance_transform_edt(~source) finds it
    iy = np.empty(holes.shape, np.int64)
    ix = np.empty(holes.shape, np.int64)
    _crops.nearest_sites(np.ascontiguousarray(source, dtype=bool), holes.any(axis=1), iy, ix)
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
