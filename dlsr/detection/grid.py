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
    """

    angles_deg: tuple = tuple(range(0, 180, 15))
    openings: tuple = tuple(range(10, 100, 10))
    jaws: tuple = tuple(range(10, 100, 10))
    step: float = 10.0
    dilate: int = 20
    min_coverage: float = 0.5
    coverage_on: str = "dilated"

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


def table_plane_mask(depth, depth_valid=None, min_height: float = 0.006, stride: int = 4,
                     n_iter: int = 100, tol: float = 0.003, random_state=0) -> np.ndarray:
    """Pixels standing more than ``min_height`` in front of the table, largest blob.

    The table plane is fitted by RANSAC to the valid depth (subsampled by ``stride``) in inverse
    depth, ``1/z = a u + b v + c`` (exact for any plane seen by a pinhole camera, no intrinsics
    needed), inliers within ``tol`` metres along the ray, then refitted by least squares with an
    adaptive inlier band (3 x the median inlier residual). Only pixels inside the convex hull
    of the largest connected set of table pixels count, so walls and clutter beyond the
    table's edge are not taken for the object.

    Returns
    -------
    ndarray of shape (H, W), bool (empty when nothing stands out or the depth is unusable).
    """
    depth = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    if depth_valid is not None:
        valid &= np.asarray(depth_valid, dtype=bool)
    H, W = depth.shape
    if valid.sum() < 50:
        return np.zeros((H, W), dtype=bool)
    vs, us = np.mgrid[0:H:stride, 0:W:stride]
    sv = valid[::stride, ::stride]
    u, v = us[sv].astype(float) / W, vs[sv].astype(float) / H
    z = depth[::stride, ::stride][sv]
    A = np.column_stack([u, v, np.ones_like(u)])
    inv = 1.0 / z
    rng = np.random.default_rng(random_state)
    best_inl, best_n = None, -1
    for _ in range(n_iter):  # RANSAC: a robust start
        idx = rng.choice(len(z), 3, replace=False)
        try:
            coef = np.linalg.solve(A[idx], inv[idx])
        except np.linalg.LinAlgError:
            continue
        inl = np.abs(1.0 / np.maximum(A @ coef, 1e-9) - z) < tol
        n = int(inl.sum())
        if n > best_n:
            best_inl, best_n = inl, n
    if best_inl is None or best_n < 6:
        return np.zeros((H, W), dtype=bool)
    keep, thr = best_inl, tol
    for _ in range(4):  # least-squares refits with an adaptive inlier band
        coef, *_ = np.linalg.lstsq(A[keep], inv[keep], rcond=None)
        resid = np.abs(1.0 / np.maximum(A @ coef, 1e-9) - z)
        thr = max(3.0 * float(np.median(resid[keep])), 0.5 * tol)
        keep = resid < thr
    vv, uu = np.mgrid[0:H, 0:W]
    zp = 1.0 / np.maximum(coef[0] * uu / W + coef[1] * vv / H + coef[2], 1e-9)
    table = _largest_blob(valid & (np.abs(zp - depth) < max(thr, tol)))
    if not table.any():
        return np.zeros((H, W), dtype=bool)
    hull = cv2.convexHull(np.argwhere(table)[:, ::-1].astype(np.int32))
    on_table = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(on_table, hull, 1)
    return _largest_blob(valid & (zp - depth > min_height) & on_table.astype(bool))


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
    return cand[inside]
