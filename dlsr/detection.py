"""Grasp detection: find the best rectangle in a whole image (the paper's Table 2).

The search is Lenz et al.'s, as the authors' configuration mirrors
(``shared/reference/dlsr-reference-facts.md``): the object region is found, dilated by 20 px,
and candidates are laid out in its bounding box, centres every 10 px, closing angles
0, 15, ..., 165 degrees, openings and jaw sizes 10, 20, ..., 90 px with opening >= jaw size
(45 pairs x 12 angles per centre). A candidate is kept when at least 50 % of its area lies on
the (dilated) object region and all four corners lie inside the image. Each candidate is scored
by the SVM decision function of the recognition model; the best score is the detection.

Two detectors share the candidates and the trained model (:class:`DLSRDetector`):

* :class:`ExactGridDetector` featurises every candidate exactly as recognition does
  (:func:`dlsr.preprocess.rectangle_images` then :func:`dlsr.features.rectangle_features`,
  batched) and scores it. Several minutes per image, like the paper.
* :class:`DenseDetector` computes the same scores densely. The SVM is linear and pooling is a
  sum, so with the feature standardisation folded in, a candidate's score is
  ``const + sum_q sum_{patches p in quadrant q} v_q . code(p)``: four per-pixel score maps
  (``v_q . code``) and four box sums. Per angle the whole 8-channel image is rotated once (the
  normals recomputed on the rotated full-resolution canvas), per opening ``w`` the canvas is
  rescaled once by ``24 / w`` (so the opening maps to 24 px, as the crop's longer side does), every
  6x6 patch some candidate needs is standardised, whitened and encoded once, the four score maps
  get summed-area tables, and every candidate is scored with a handful of table look-ups. The
  top ``rescore`` candidates are then rescored exactly (recognition's rectangle images, encoded
  by the same kernels: :meth:`DenseDetector.exact_scores`) and re-ranked.

  The encoding is compute-bound and organised for it (:class:`_PatchScorer`,
  :mod:`dlsr._dense`): per-patch group statistics from running window sums, standardised patches
  gathered by a compiled kernel, whitening and the k-means centroid products of NKM-Natural
  folded into one float32 matrix (``P C^T``), the whitened norm from the triangular Cholesky
  factor of ``P P^T`` (about 2 x 288 x 480 operations per patch instead of 2 x 288 x 588), the
  triangle codes and their quadrant weights fused in one compiled pass. The (angle, opening)
  canvases run in ``n_threads`` threads, longest first, each with single-threaded BLAS.

Where dense and exact differ
----------------------------
For a candidate whose crop lines up with the canvas grid (angle a multiple of 90 degrees, crop
origin on the resized canvas's grid) with ``h == w`` (no padding), no depth outlier in the crop
and a depth map whose normals do not depend on the crop border (e.g. a plane), the two scores are
equal up to float rounding (tested). Otherwise the dense score is an approximation:

* **padding** (``h < w``): the exact crop is padded above and below the ``h`` rows; patches
  entirely in the padding get the code of an all-masked patch (exact), but patches straddling
  the padding edge are taken from the canvas, which has image content there;
* **sub-pixel position**: the candidate's window rarely falls on the canvas grid; its score is
  the bilinear interpolation of the window scores at the four neighbouring grid positions;
* **per-crop depth processing**: the exact crop masks depth outliers (4 sigma of the crop,
  twice), fills holes within the crop and extrapolates normals at the crop border; the canvas
  does none of the first, fills holes once over the image (before rotation) and has real
  neighbours at the border. (The crop's mean depth is subtracted in the exact path and not in
  the canvas; per-patch standardisation removes it either way.)

``scripts/bench_detection.py`` measures the differences (score error for ``h == w`` and
``h < w``, top-1 agreement by the rectangle metric).

Object region
-------------
:func:`object_region`, in this order: background subtraction when a background image is given
(the sum over R, G, B of ``|image - background|`` above 100, largest 8-connected blob; Cornell);
the observation's ``mask`` when it has one (Jacquard, simulation); otherwise the pixels standing
more than ``min_height`` (6 mm) in front of the table plane, which is fitted to the valid depth
by RANSAC in inverse depth (for a pinhole camera ``1/z`` of a plane is linear in the pixel
coordinates), within the convex hull of the table pixels, largest 8-connected blob
(:func:`table_plane_mask`).

Departures and choices (named options)
--------------------------------------
* ``SearchGrid.coverage_on="dilated"``: the 50 % is measured on the dilated region (Lenz's
  search); ``"object"`` uses the undilated region.
* Candidate centres are the multiples of ``step`` inside the dilated region's bounding box.
* Coverage is counted on pixel centres in the rotated frame (summed-area table per angle).
* The dense path fills depth holes once over the image before rotating (the exact path fills
  each rotated crop), by default with the nearest valid depth (``DenseDetector(fill=...)``).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .features import Representation, encode_patches, rectangle_features
from .preprocess import _one_blas_thread
from .rectangles import GraspRectangle, array_to_rects, corners_from_array, normalize_angle

__all__ = [
    "SearchGrid",
    "PAPER_GRID",
    "COARSE_GRID",
    "Detection",
    "DLSRDetector",
    "ExactGridDetector",
    "DenseDetector",
    "train_detector",
    "detection_training_data",
    "sample_grid_negatives",
    "fit_search_grid",
    "sample_observation",
    "mine_hard_negatives",
    "check_training_options",
    "object_region",
    "table_plane_mask",
    "background_mask",
    "enumerate_candidates",
    "PATCHES_PER_RECTANGLE",
]

log = logging.getLogger(__name__)

SIZE = 24
PATCH = 6
GRID = SIZE - PATCH + 1  # 19 patch positions per side
SPLIT = 10  # quadrant split of the 19 x 19 code map (10 | 9)
PATCHES_PER_RECTANGLE = GRID * GRID
_ONE = 1.0 - 1e-6  # as dlsr.preprocess: bilinear weights summing to one
_GRAY = np.asarray((0.2989, 0.5870, 0.1140), dtype=np.float32)
_STD_EPS = 1e-4  # the per-patch standardisation's (dlsr.whitening.standardize_patches)
FORMAT_VERSION = 1


# ---------------------------------------------------------------------------------------------
# Search grid and candidates
# ---------------------------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------------------------
# The trained model
# ---------------------------------------------------------------------------------------------


def _default_preprocess() -> dict:
    """The keyword defaults of :func:`dlsr.preprocess.rectangle_images` (recognition's)."""
    import inspect

    from .preprocess import rectangle_images

    out = {"size": SIZE}
    for name, par in inspect.signature(rectangle_images).parameters.items():
        if par.kind is inspect.Parameter.KEYWORD_ONLY and par.default is not inspect._empty:
            out[name] = par.default
    return out


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    return x


@dataclass
class DLSRDetector:
    """A trained DLSR grasp model: representation, feature standardisation and linear SVM.

    ``predict(obs)`` runs the dense detector (``detector="dense"``) or the exact grid search
    (``"exact"``) with ``grid``; build either explicitly with :meth:`detector`.

    Attributes
    ----------
    representation : Representation
    encoder : str
    encoder_param : float or int or None
    polarity : bool
    scaler_mean, scaler_scale : ndarray of shape (n_features,)
    coef : ndarray of shape (n_features,)
    intercept : float
    preprocess : dict
        Keyword options of :func:`dlsr.preprocess.rectangle_images`.
    config : dict
        Training information and detector options (``detector``, ``grid``, ``top_k``,
        ``rescore``, ``region``) saved with the model.
    """

    representation: Representation
    encoder: str
    encoder_param: object
    polarity: bool
    scaler_mean: np.ndarray
    scaler_scale: np.ndarray
    coef: np.ndarray
    intercept: float
    preprocess: dict = field(default_factory=_default_preprocess)
    config: dict = field(default_factory=dict)

    # -- scores ------------------------------------------------------------------------------
    @property
    def n_codes(self) -> int:
        return len(self.coef) // 4

    def quadrant_weights(self):
        """The SVM folded with the feature standardisation.

        Returns
        -------
        V : ndarray of shape (k, 4), float64
            Per-quadrant weights on the codes (TL, TR, BL, BR).
        const : float
            ``score = const + sum_q V[:, q] . pooled_q``.
        """
        k = self.n_codes
        w = np.asarray(self.coef, dtype=np.float64) / np.asarray(self.scaler_scale, np.float64)
        const = float(self.intercept - w @ np.asarray(self.scaler_mean, np.float64))
        return w.reshape(4, k).T.copy(), const

    def features(self, images, masks, chunk_size: int = 64) -> np.ndarray:
        return rectangle_features(images, masks, self.representation, self.encoder,
                                  self.encoder_param, polarity=self.polarity,
                                  chunk_size=chunk_size)

    def image_scores(self, images, masks, chunk_size: int = 64) -> np.ndarray:
        """SVM decision values of rectangle images (the recognition model's scores)."""
        F = self.features(images, masks, chunk_size)
        Z = ((F - self.scaler_mean) / self.scaler_scale).astype(F.dtype, copy=False)
        return Z @ np.asarray(self.coef, np.float64) + float(self.intercept)

    def rectangle_scores(self, obs, rects, batch_size: int = 256) -> np.ndarray:
        """Exact scores of rectangles of an observation (rectangle images, features, SVM)."""
        from .preprocess import rectangle_images

        rects = np.asarray(rects, dtype=float).reshape(-1, 5)
        out = np.empty(len(rects))
        for s in range(0, len(rects), batch_size):
            im, mk = rectangle_images(obs["rgb"], obs["depth"], obs.get("depth_valid"),
                                      rects[s:s + batch_size], **self.preprocess)
            out[s:s + batch_size] = self.image_scores(im, mk)
        return out

    # -- detectors ---------------------------------------------------------------------------
    def detector(self, kind: str | None = None, **options):
        """An :class:`ExactGridDetector` or :class:`DenseDetector` on this model.

        Options default to the saved ``config`` (``grid``, ``top_k``, ``rescore``, ``region``).
        """
        kind = kind or self.config.get("detector", "dense")
        opts = {}
        if "grid" in self.config:
            opts["grid"] = SearchGrid.from_dict(self.config["grid"])
        for key in ("top_k", "region"):
            if key in self.config:
                opts[key] = self.config[key]
        if kind == "dense" and "rescore" in self.config:
            opts["rescore"] = self.config["rescore"]
        opts.update(options)
        if kind == "exact":
            return ExactGridDetector(self, **opts)
        if kind == "dense":
            return DenseDetector(self, **opts)
        raise ValueError(f"unknown detector {kind!r}; choose 'dense' or 'exact'")

    def predict(self, obs) -> list[GraspRectangle]:
        """Rectangles best first (see :meth:`detector`)."""
        if not hasattr(self, "_detector"):
            self._detector = self.detector()
        return self._detector.predict(obs)

    # -- persistence -------------------------------------------------------------------------
    @staticmethod
    def _paths(path):
        p = Path(path)
        if p.suffix in (".npz", ".json"):
            p = p.with_suffix("")
        return p.with_name(p.name + ".npz"), p.with_name(p.name + ".json")

    def save(self, path) -> tuple[Path, Path]:
        """Write ``<path>.npz`` (arrays) and ``<path>.json`` (everything else); never pickle.

        ``path`` may end in ``.npz`` or ``.json`` (the suffix is replaced).
        """
        npz, js = self._paths(path)
        npz.parent.mkdir(parents=True, exist_ok=True)
        arrays = self.representation.to_arrays(prefix="rep_")
        arrays.update(scaler_mean=np.asarray(self.scaler_mean),
                      scaler_scale=np.asarray(self.scaler_scale),
                      coef=np.asarray(self.coef), intercept=np.asarray([self.intercept]))
        np.savez(npz, **{k: np.asarray(v) for k, v in arrays.items()})
        meta = {
            "format": "dlsr-detector",
            "version": FORMAT_VERSION,
            "arrays": npz.name,
            "learner": self.representation.learner,
            "natural_param": _jsonable(self.representation.natural_param),
            "encoder": self.encoder,
            "encoder_param": _jsonable(self.encoder_param),
            "polarity": bool(self.polarity),
            "preprocess": self.preprocess,
            "config": self.config,
        }
        js.write_text(json.dumps(meta, indent=2))
        return npz, js

    @classmethod
    def load(cls, path) -> DLSRDetector:
        """Read a model written by :meth:`save` (``path`` with or without suffix)."""
        npz, js = cls._paths(path)
        for p in (js, npz):
            if not p.is_file():
                raise FileNotFoundError(f"detector model file not found: {p}")
        try:
            meta = json.loads(js.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{js}: not a JSON detector description: {exc}") from exc
        if meta.get("format") != "dlsr-detector":
            raise ValueError(f"{js}: not a DLSR detector model (format {meta.get('format')!r})")
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        for key in ("scaler_mean", "scaler_scale", "coef", "intercept", "rep_dictionary"):
            if key not in arrays:
                raise ValueError(f"{npz}: missing array {key!r}")
        rep = Representation.from_arrays(arrays, meta["learner"], meta.get("natural_param"),
                                         prefix="rep_")
        return cls(representation=rep, encoder=meta["encoder"],
                   encoder_param=meta.get("encoder_param"), polarity=bool(meta["polarity"]),
                   scaler_mean=arrays["scaler_mean"], scaler_scale=arrays["scaler_scale"],
                   coef=arrays["coef"], intercept=float(arrays["intercept"][0]),
                   preprocess=dict(meta.get("preprocess") or _default_preprocess()),
                   config=dict(meta.get("config") or {}))


def sample_grid_negatives(sample, n: int, rng, grid: SearchGrid = PAPER_GRID,
                          region: str = "auto", background=None,
                          min_height: float = 0.006) -> np.ndarray:
    """Negatives drawn from the detector's own search space.

    The object region is found as the detectors find it (:func:`object_region` with
    ``method=region``), the candidates are those the detectors score
    (:func:`enumerate_candidates` with ``grid``: inside the image, enough of them on the dilated
    region), and ``n`` of the candidates that **fail** the rectangle metric against every
    positive (:func:`dlsr.metrics.rectangle_metric_many`) are drawn uniformly without
    replacement. These include the background, object-edge and small rectangles a detector
    proposes and a recognition training set (labelled rectangles around the grasps) never shows.

    Parameters
    ----------
    sample : GraspSample
    n : int
        Negatives wanted (>= 0).
    rng : numpy.random.Generator or int or None
        Resolved with ``numpy.random.default_rng``.
    grid : SearchGrid
    region : {"auto", "background", "mask", "depth"}
        See :func:`object_region`.
    background : ndarray of shape (H, W, 3) or None
    min_height : float

    Returns
    -------
    ndarray of shape (k, 5)
        ``k = min(n, failing candidates)``; empty when the image has no positive (nothing to
        fail against) or no candidate (empty region). A shortfall is logged.
    """
    from .metrics import rectangle_metric_many
    from .rectangles import rects_to_array

    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n}")
    n = int(n)
    if n == 0 or not sample.positives:
        return np.zeros((0, 5))
    rng = np.random.default_rng(rng)
    obs = sample_observation(sample)
    reg, how = object_region(obs, background, region, min_height)
    cand = enumerate_candidates(reg, grid)
    pos = rects_to_array(sample.positives)
    order = rng.permutation(len(cand))
    batch = max(4 * n, 256)
    found, count = [], 0
    for s in range(0, len(order), batch):  # the first n failures of a random order
        c = cand[order[s:s + batch]]
        c = c[~rectangle_metric_many(c, pos)]
        found.append(c)
        count += len(c)
        if count >= n:
            break
    out = np.concatenate(found)[:n] if found else np.zeros((0, 5))
    if len(out) < n:
        log.info("image %s: %d of %d grid negatives (%d candidates, region %s)",
                 sample.image_id, len(out), n, len(cand), how)
    return out


def sample_observation(sample) -> dict:
    """The observation dict a detector reads (``rgb``, ``depth``, ``depth_valid``, ``mask``
    when the sample has one) of a :class:`dlsr.datasets.GraspSample`."""
    obs = {"rgb": sample.rgb, "depth": sample.depth, "depth_valid": sample.depth_valid}
    if sample.mask is not None:
        obs["mask"] = sample.mask
    return obs


def mine_hard_negatives(detector, samples, n: int, pool: int = 200) -> list[np.ndarray]:
    """The best-scoring candidates that fail the rectangle metric, per image.

    Hard-negative mining (Dalal and Triggs 2005; Felzenszwalb et al. 2010): the detector runs
    on its own training images and the ``n`` best of its ``pool`` top candidates that fail the
    rectangle metric against every positive become negatives.

    Parameters
    ----------
    detector : ExactGridDetector or DenseDetector
        Its ``top_k`` is raised to ``pool`` for the run (on a copy).
    samples : sequence of GraspSample
        Training images.
    n : int
        Hard negatives per image (>= 1).
    pool : int
        Top candidates looked at per image.

    Returns
    -------
    list of ndarray of shape (k_i, 5)
        One per sample, ``k_i <= n`` (0 for images without positives or candidates).
    """
    import copy

    from .metrics import rectangle_metric_many
    from .rectangles import rects_to_array

    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n}")
    det = copy.copy(detector)
    det.top_k = max(int(pool), int(n))
    out = []
    for s in samples:
        if not s.positives:
            out.append(np.zeros((0, 5)))
            continue
        d = det.detect(sample_observation(s))
        c = d.rects[~rectangle_metric_many(d.rects, rects_to_array(s.positives))] \
            if len(d.rects) else np.zeros((0, 5))
        out.append(np.asarray(c[: int(n)], dtype=float).reshape(-1, 5))
    return out


def detection_training_data(samples, grid_negatives: float = 1.0,
                            grid: SearchGrid = PAPER_GRID, region: str = "auto",
                            negatives_per_image: int | None = None, random_state=0):
    """The training rectangles of a detector: recognition's, plus negatives from the grid.

    Parameters
    ----------
    samples : sequence of GraspSample
    grid_negatives : float
        Per image, ``round(grid_negatives * m)`` negatives from the detector's candidate grid
        (:func:`sample_grid_negatives`), ``m`` the image's labelled rectangles (positives and
        negatives, sampled ones included); 0 gives recognition's training set.
    grid, region :
        The search space the negatives come from (the detector's).
    negatives_per_image : int or None
        See :func:`dlsr.recognition.recognition_data`.
    random_state : int, numpy.random.Generator or None
        The labelled part is drawn exactly as :func:`~dlsr.recognition.recognition_data`
        draws it with this seed; the grid negatives come from an independent stream spawned
        from it.

    Returns
    -------
    RecognitionData
    """
    from .recognition import recognition_data

    if not (np.isfinite(grid_negatives) and grid_negatives >= 0):
        raise ValueError(f"grid_negatives must be a finite number >= 0, got {grid_negatives}")
    rng = np.random.default_rng(random_state)
    extra = None
    if grid_negatives > 0:
        grid_rng = rng.spawn(1)[0]  # does not advance rng

        def extra(sample, rects):
            k = int(round(grid_negatives * len(rects)))
            return sample_grid_negatives(sample, k, grid_rng, grid, region)

    return recognition_data(samples, negatives_per_image=negatives_per_image, random_state=rng,
                            extra_negatives=extra)


def _check_quantile(q, name: str) -> None:
    if not 0 <= q < 0.5:
        raise ValueError(f"{name} must be in [0, 0.5), got {q}")


def check_training_options(fit_grid=None, hard_negatives=0, hard_rounds=1) -> None:
    """Clear errors for the detector training options beyond the paper, before any work.

    ``fit_grid`` is None or a quantile in ``[0, 0.5)`` (:func:`fit_search_grid`);
    ``hard_negatives`` and ``hard_rounds`` are integers >= 0 (:func:`train_detector`).
    """
    if fit_grid is not None:
        _check_quantile(fit_grid, "fit_grid")
    for name, value in (("hard_negatives", hard_negatives), ("hard_rounds", hard_rounds)):
        if int(value) != value or value < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {value}")


def fit_search_grid(positives, grid: SearchGrid = PAPER_GRID,
                    quantile: float = 0.025) -> SearchGrid:
    """The search grid restricted to the sizes of the training positives.

    Openings (jaw sizes) of ``grid`` are kept when they lie in the ``[quantile, 1 - quantile]``
    range of the positives' openings ``w`` (jaw sizes ``h``), widened by half the grid's
    spacing; angles, centres, dilation and coverage are unchanged. The rectangle images are
    scale-normalised (the opening maps to 24 px), so the classifier cannot tell a size it never
    saw labelled; searching only the labelled sizes keeps the search space the training data
    covers (anchor sizes fitted to the training boxes, as object detectors do).

    Parameters
    ----------
    positives : array of shape (n, 5) or list of GraspRectangle
        Training positives (never test ones).
    grid : SearchGrid
    quantile : float
        In ``[0, 0.5)``.

    Returns
    -------
    SearchGrid
        Keeps at least the grid value nearest the median on each axis.

    Raises
    ------
    ValueError
        No positives, a bad quantile, or no (opening, jaw) pair with opening >= jaw left.
    """
    from .rectangles import as_rect_array

    pos = as_rect_array(positives)
    if len(pos) == 0:
        raise ValueError("fit_search_grid needs at least one positive rectangle")
    _check_quantile(quantile, "quantile")

    def keep(values, x):
        v = np.sort(np.asarray(values, dtype=float))
        half = np.min(np.diff(v)) / 2 if len(v) > 1 else 0.0
        lo, hi = np.quantile(x, quantile), np.quantile(x, 1 - quantile)
        kept = v[(v >= lo - half) & (v <= hi + half)]
        if len(kept) == 0:
            kept = v[[np.argmin(np.abs(v - np.median(x)))]]
        return tuple(float(a) for a in kept)

    fitted = SearchGrid(angles_deg=grid.angles_deg, openings=keep(grid.openings, pos[:, 3]),
                        jaws=keep(grid.jaws, pos[:, 4]), step=grid.step, dilate=grid.dilate,
                        min_coverage=grid.min_coverage, coverage_on=grid.coverage_on)
    if not fitted.pairs():
        raise ValueError(f"fitted grid has no opening >= jaw size (openings {fitted.openings}, "
                         f"jaws {fitted.jaws})")
    return fitted


def train_detector(
    samples,
    learner: str = "NKM",
    encoder: str = "Natural",
    encoder_param=None,
    C: float = 1.0,
    n_atoms: int = 300,
    whiten: bool = True,
    n_patches: int = 100_000,
    negatives_per_image: int | None = None,
    grid_negatives: float = 1.0,
    fit_grid: float | None = None,
    hard_negatives: int = 0,
    hard_rounds: int = 1,
    random_state=0,
    data=None,
    **config,
) -> DLSRDetector:
    """Train the recognition model on the labelled rectangles of ``samples``.

    Parameters
    ----------
    samples : sequence of GraspSample
        Training images only (fold hygiene is the caller's). Images without negatives
        (Jacquard) get sampled negatives (:func:`dlsr.recognition.recognition_data`).
    learner, encoder, encoder_param :
        See :class:`dlsr.features.DLSRFeatures`; ``encoder_param`` None takes the middle of the
        reference grid (ignored by "Natural").
    C : float
        SVM cost.
    n_atoms, whiten, n_patches :
        Representation settings (:func:`dlsr.features.fit_representation`).
    negatives_per_image : int or None
    grid_negatives : float
        Negatives from the detector's own candidate grid (``config["grid"]`` and
        ``config["region"]``, the defaults otherwise) per labelled rectangle of an image
        (:func:`detection_training_data`): 1 (default) doubles the training set, 0 trains on
        the labelled rectangles only (the recognition model).
    fit_grid : float or None
        The search grid (``config["grid"]``, the paper's by default) is restricted to the
        openings and jaw sizes of the training positives (:func:`fit_search_grid` with this
        quantile, e.g. 0.025) and saved in the model, so detection and the grid negatives use
        it; None (default) keeps the grid as given (the paper's). A departure from the
        paper, off by default.
    hard_negatives : int
        After the first fit, ``hard_rounds`` rounds of hard-negative mining
        (:func:`mine_hard_negatives`): the dense detector (the model's grid and region, no
        exact rescoring) runs on every training image, up to ``hard_negatives`` of its best
        candidates that fail the rectangle metric join the negatives, and the SVM (not the
        representation) is refitted. 0 (default): none, as the paper.
    hard_rounds : int
    random_state : int
    data : RecognitionData or None
        Precomputed training rectangles of ``samples`` (skips preprocessing), e.g. from
        :func:`detection_training_data` with the same ``negatives_per_image``,
        ``grid_negatives`` and (fitted) grid, which are then only recorded in the model's
        config.
    **config :
        Detector options stored in the model (``detector``, ``grid`` (dict), ``top_k``,
        ``rescore``, ``region``).

    Returns
    -------
    DLSRDetector
    """
    from .features import ENCODER_GRIDS, ENCODERS, fit_representation
    from .svm import FeatureStandardizer, SquaredHingeSVC

    if encoder not in ENCODERS:
        raise ValueError(f"unknown encoder {encoder!r}; choose from {ENCODERS}")
    if encoder_param is None and encoder != "Natural":
        grid = ENCODER_GRIDS[encoder]
        encoder_param = grid[len(grid) // 2 - 1]
    check_training_options(fit_grid, hard_negatives, hard_rounds)
    t0 = time.perf_counter()
    sgrid = config.get("grid", PAPER_GRID)
    if isinstance(sgrid, dict):
        sgrid = SearchGrid.from_dict(sgrid)
    if fit_grid is not None:
        from .rectangles import rects_to_array

        pos = [rects_to_array(s.positives) for s in samples]
        sgrid = fit_search_grid(np.concatenate(pos) if pos else np.zeros((0, 5)), sgrid,
                                fit_grid)
        config["grid"] = sgrid
    if data is None:
        data = detection_training_data(samples, grid_negatives, sgrid,
                                       config.get("region", "auto"),
                                       negatives_per_image=negatives_per_image,
                                       random_state=random_state)
    if len(np.unique(data.labels)) < 2:
        raise ValueError("training needs positive and negative rectangles")
    rep = fit_representation(data.images, data.masks, learner, n_atoms=n_atoms, whiten=whiten,
                             n_patches=n_patches, random_state=random_state)
    polarity = not (learner == "NKM" and encoder == "Natural")
    F = rectangle_features(data.images, data.masks, rep, encoder, encoder_param,
                           polarity=polarity)
    scaler = FeatureStandardizer().fit(F)
    svm = SquaredHingeSVC(C=C).fit(scaler.transform(F), data.labels)
    labels = np.asarray(data.labels)
    n_hard = 0
    if hard_negatives:
        from .preprocess import rectangle_images

        for _ in range(int(hard_rounds)):
            model = DLSRDetector(rep, encoder, encoder_param, polarity, scaler.mean_,
                                 scaler.scale_, np.asarray(svm.coef_[0]),
                                 float(svm.intercept_[0]), preprocess=_default_preprocess())
            det = model.detector("dense", grid=sgrid, region=config.get("region", "auto"),
                                 rescore=0)
            mined = mine_hard_negatives(det, samples, int(hard_negatives))
            ims, mks = [], []
            for smp, rects in zip(samples, mined, strict=True):
                if len(rects):
                    im, mk = rectangle_images(smp.rgb, smp.depth, smp.depth_valid,
                                              array_to_rects(rects), size=SIZE)
                    ims.append(im)
                    mks.append(mk)
            if not ims:
                log.info("hard-negative mining found no failing candidate")
                break
            Fh = rectangle_features(np.concatenate(ims), np.concatenate(mks), rep, encoder,
                                    encoder_param, polarity=polarity)
            F = np.concatenate([F, Fh])
            labels = np.r_[labels, np.zeros(len(Fh), labels.dtype)]
            n_hard += len(Fh)
            scaler = FeatureStandardizer().fit(F)
            svm = SquaredHingeSVC(C=C).fit(scaler.transform(F), labels)
    info = {"learner": learner, "encoder": encoder, "encoder_param": _jsonable(encoder_param),
            "C": float(C), "n_atoms": int(n_atoms), "whiten": bool(whiten),
            "n_patches": int(n_patches), "grid_negatives": float(grid_negatives),
            "fit_grid": None if fit_grid is None else float(fit_grid),
            "hard_negatives": int(hard_negatives), "hard_rounds": int(hard_rounds),
            "n_hard_negatives": int(n_hard),
            "n_train_rectangles": int(len(labels)),
            "n_train_positive": int(np.sum(labels == 1)),
            "train_seconds": time.perf_counter() - t0}
    info.update(config)
    if isinstance(info.get("grid"), SearchGrid):
        info["grid"] = info["grid"].to_dict()
    return DLSRDetector(rep, encoder, encoder_param, polarity, scaler.mean_, scaler.scale_,
                        np.asarray(svm.coef_[0]), float(svm.intercept_[0]),
                        preprocess=_default_preprocess(), config=info)


# ---------------------------------------------------------------------------------------------
# Detection results and the exact path
# ---------------------------------------------------------------------------------------------


@dataclass
class Detection:
    """What a detector found in one image.

    Attributes
    ----------
    rects : ndarray of shape (k, 5)
        Best first.
    scores : ndarray of shape (k,)
    n_candidates : int
        Candidates scored.
    n_encodings : int
        Patch encodings performed.
    seconds : float
    reason : str or None
        Why nothing was found (empty result).
    timings : dict
    """

    rects: np.ndarray
    scores: np.ndarray
    n_candidates: int = 0
    n_encodings: int = 0
    seconds: float = 0.0
    reason: str | None = None
    timings: dict = field(default_factory=dict)

    def rectangles(self) -> list[GraspRectangle]:
        return array_to_rects(self.rects) if len(self.rects) else []


def _empty(reason: str, t0: float, **kw) -> Detection:
    log.warning("no detection: %s", reason)
    return Detection(np.zeros((0, 5)), np.zeros(0), reason=reason,
                     seconds=time.perf_counter() - t0, **kw)


def _check_obs(obs):
    for key in ("rgb", "depth"):
        if key not in obs:
            raise ValueError(f"the observation has no {key!r}")
    rgb = np.asarray(obs["rgb"])
    depth = np.asarray(obs["depth"])
    if rgb.ndim != 3 or rgb.shape[2] != 3 or depth.shape != rgb.shape[:2]:
        raise ValueError(f"observation rgb {rgb.shape} and depth {depth.shape} do not match")


class _Base:
    def __init__(self, model: DLSRDetector, grid: SearchGrid = PAPER_GRID, top_k: int = 5,
                 region: str = "auto", background=None, min_height: float = 0.006):
        self.model = model
        self.grid = grid
        self.top_k = top_k
        self.region = region
        self.background = background
        self.min_height = min_height

    def candidates(self, obs, grid: SearchGrid | None = None):
        """``(candidates (n, 5), reason or None)`` for an observation."""
        _check_obs(obs)
        depth = np.asarray(obs["depth"])
        valid = np.isfinite(depth) & (depth > 0)
        if obs.get("depth_valid") is not None:
            valid &= np.asarray(obs["depth_valid"], dtype=bool)
        if not valid.any():
            return np.zeros((0, 5)), "the depth image has no valid pixel (all masked)"
        region, how = object_region(obs, self.background, self.region, self.min_height)
        if not region.any():
            return np.zeros((0, 5)), f"empty object region (method {how})"
        cand = enumerate_candidates(region, grid or self.grid)
        if len(cand) == 0:
            return cand, f"no candidate covers the object region enough (method {how})"
        return cand, None

    def predict(self, obs) -> list[GraspRectangle]:
        """The top-k rectangles, best first (empty, with a logged reason, when none)."""
        return self.detect(obs).rectangles()


class ExactGridDetector(_Base):
    """Lenz et al.'s grid search, every candidate featurised exactly as in recognition.

    Parameters
    ----------
    model : DLSRDetector
    grid : SearchGrid
    top_k : int
        Rectangles returned.
    region : {"auto", "background", "mask", "depth"}
        See :func:`object_region`.
    background : ndarray or None
        Background image (Cornell).
    min_height : float
    batch_size : int
        Candidates preprocessed and encoded at once.
    """

    def __init__(self, model, grid=PAPER_GRID, top_k=5, region="auto", background=None,
                 min_height=0.006, batch_size: int = 512):
        super().__init__(model, grid, top_k, region, background, min_height)
        self.batch_size = batch_size

    def detect(self, obs, candidates=None) -> Detection:
        t0 = time.perf_counter()
        if candidates is None:
            cand, reason = self.candidates(obs)
            if reason:
                return _empty(reason, t0)
        else:
            cand = np.asarray(candidates, dtype=float).reshape(-1, 5)
        t1 = time.perf_counter()
        scores = self.model.rectangle_scores(obs, cand, self.batch_size)
        order = np.argsort(-scores, kind="stable")[: self.top_k]
        t2 = time.perf_counter()
        return Detection(cand[order], scores[order], n_candidates=len(cand),
                         n_encodings=len(cand) * PATCHES_PER_RECTANGLE, seconds=t2 - t0,
                         timings={"candidates": t1 - t0, "score": t2 - t1})


# ---------------------------------------------------------------------------------------------
# The dense path
# ---------------------------------------------------------------------------------------------


class _Source:
    """One observation prepared for canvas sampling: ``(H + 2, W + 2, 7)`` float32.

    Channels R, G, B (0..1), depth (metres, 0 invalid), validity, inside, hole-filled depth
    (metres); a one-pixel zero border like :mod:`dlsr.preprocess`.
    """

    def __init__(self, obs, preprocess: dict, roi=None, fill: str | None = None):
        from .preprocess import _check_image, fill_depth_holes

        src6 = _check_image(obs["rgb"], obs["depth"], obs.get("depth_valid"))
        H, W = src6.shape[0] - 2, src6.shape[1] - 2
        self.src = np.zeros((H + 2, W + 2, 7), dtype=np.float32)
        self.src[..., :6] = src6
        depth = src6[1:-1, 1:-1, 3].astype(np.float64)
        valid = src6[1:-1, 1:-1, 4] > 0.5
        r0, r1, c0, c1 = roi if roi is not None else (0, H, 0, W)
        sub = fill_depth_holes(depth[r0:r1, c0:c1], valid[r0:r1, c0:c1],
                               fill or preprocess.get("fill", "band"), preprocess.get("band", 3))
        if not valid[r0:r1, c0:c1].any():
            ref = float(depth[valid].mean())
            sub = np.full((r1 - r0, c1 - c0), ref)
        filled = np.full((H, W), float(np.mean(sub)))
        filled[r0:r1, c0:c1] = sub
        self.src[1:-1, 1:-1, 6] = filled
        roi_valid = valid[r0:r1, c0:c1]
        self.ref = float(depth[r0:r1, c0:c1][roi_valid].mean()) if roi_valid.any() \
            else float(depth[valid].mean())
        self.shape = (H, W)


class _PatchScorer:
    """``V[:, q] . code(patch)`` of standardised 6x6 patches under a model (the dense encoding).

    For NKM-Natural (k-means triangle codes ``max(mean_k z - z_k, 0)``, ``z_k = ||w - c_k||``
    on the un-normalised centroids ``C``) with ZCA whitening ``w = (x - m) P``, a patch ``x``
    without masked entries needs ``w . c_k = x (P C^T) - m P C^T`` and
    ``||w||^2 = ||(x - m) L||^2`` with ``L`` the lower Cholesky factor of ``P P^T``; ``L`` is
    triangular, so its columns are computed in ``n_blocks`` column blocks from the rows they
    use, the first block in the same product as ``P C^T``: 2 x 288 x (300 + 180) operations
    per patch instead of 2 x 288 x (300 + 288) for ``[P | P C^T]``.
    :func:`dlsr._dense.triangle_scores` turns the products into codes and quadrant scores
    without storing the codes. A patch with masked entries is whitened (``P``), re-masked as
    :func:`dlsr.whitening.apply_zca` does, then multiplied by ``C^T``. Other encoders whiten
    and call :func:`dlsr.features.encode_patches`.

    Parameters
    ----------
    model : DLSRDetector
    V : ndarray of shape (k, q)
        Per-quadrant weights on the codes.
    n_blocks : int
        Column blocks of ``L`` (4 was fastest here; 1 computes all of ``L`` in one product).
    """

    def __init__(self, model, V, n_blocks: int = 4):
        rep = model.representation
        self.model = model
        self.V = np.asarray(V, np.float32)
        self.VT = np.ascontiguousarray(self.V.T)
        p = PATCH * PATCH * 8
        self.p = p
        self.whiten = rep.zca_mean is not None
        P = np.asarray(rep.zca_matrix, np.float64) if self.whiten else None
        mP = np.asarray(rep.zca_mean, np.float64) @ P if self.whiten else np.zeros(p)
        self.P = None if P is None else np.ascontiguousarray(P, dtype=np.float32)
        self.mP = mP.astype(np.float32)
        self.zero = np.zeros(p, np.float32)
        self.triangle = (rep.learner == "NKM" and model.encoder == "Natural"
                         and rep.centroids is not None)
        flops = 2.0 * p * p if self.whiten else 0.0
        if self.triangle:
            Cn = np.asarray(rep.centroids, np.float64)
            k = Cn.shape[0]
            self.CT = np.ascontiguousarray(Cn.T, dtype=np.float32)
            cc = (Cn * Cn).sum(1)
            self.cc = cc.astype(np.float32)
            self.cc2 = (cc + 2.0 * (mP @ Cn.T)).astype(np.float32)
            flops = 2.0 * p * k
            if self.whiten:
                try:
                    L = np.linalg.cholesky(P @ P.T)
                except np.linalg.LinAlgError:  # singular P: any L with L L^T = P P^T will do
                    L, n_blocks = P, 1
                self.mL = (np.asarray(rep.zca_mean, np.float64) @ L).astype(np.float32)
                edges = np.linspace(0, p, max(1, int(n_blocks)) + 1).round().astype(int)
                self.blocks = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]
                a0, b0 = self.blocks[0]
                self.B = [np.ascontiguousarray(np.hstack([P @ Cn.T, L[:, a0:b0]]),
                                               dtype=np.float32)]
                self.B += [np.ascontiguousarray(L[a:, a:b], dtype=np.float32)
                           for a, b in self.blocks[1:]]
                flops = sum(2.0 * B.shape[0] * B.shape[1] for B in self.B)
        # useful products per patch: whitening and centroids (or the dictionary), quadrant
        # weights; a patch with masked entries is whitened in full, then multiplied by C^T
        self.flops = flops + 2.0 * self.V.size
        self.flops_masked = self.flops
        if self.triangle and self.whiten:
            self.flops_masked = 2.0 * p * (p + k) + 2.0 * self.V.size

    def scores(self, img, msk, rows, cols, mean, inv, full) -> np.ndarray:
        """``(n, q)`` float32 scores of the patches with top-left corners ``(rows, cols)``.

        ``mean, inv, full`` come from :func:`dlsr._dense.window_stats` on ``img, msk``.
        """
        n = len(rows)
        S = np.empty((n, self.V.shape[1]), np.float32)
        if not self.triangle:
            S[:] = self._generic(img, msk, rows, cols, mean, inv, full)
            return S
        ok = full[rows, cols]
        if ok.all():
            S[:] = self._triangle_full(img, msk, rows, cols, mean, inv, full)
            return S
        good = np.flatnonzero(ok)
        bad = np.flatnonzero(~ok)
        if len(good):
            S[good] = self._triangle_full(img, msk, rows[good], cols[good], mean, inv, full)
        S[bad] = self._triangle_masked(img, msk, rows[bad], cols[bad], mean, inv, full)
        return S

    def _gather(self, img, msk, rows, cols, mean, inv, full):
        from . import _dense

        X = np.empty((len(rows), self.p), np.float32)
        _dense.gather_patches(img, msk, rows, cols, mean, inv, full, X)
        return X

    def _masks(self, msk, rows, cols):
        from . import _dense

        M = np.empty((len(rows), self.p), np.float32)
        _dense.gather_masks(msk, rows, cols, M)
        return M

    def _triangle_full(self, img, msk, rows, cols, mean, inv, full):
        from . import _dense

        X = self._gather(img, msk, rows, cols, mean, inv, full)
        S = np.empty((len(rows), self.V.shape[1]), np.float32)
        if self.whiten:
            k = self.CT.shape[1]
            Y = np.empty((len(rows), k + self.p), np.float32)
            a0, b0 = self.blocks[0]
            np.matmul(X, self.B[0], out=Y[:, :k + b0])
            for (a, b), B in zip(self.blocks[1:], self.B[1:], strict=True):
                np.matmul(X[:, a:], B, out=Y[:, k + a:k + b])
            _dense.triangle_scores(Y, k, Y, 0, self.mL, self.cc2, self.VT, S)
        else:
            _dense.triangle_scores(X, 0, X @ self.CT, 0, self.zero, self.cc, self.VT, S)
        return S

    def _triangle_masked(self, img, msk, rows, cols, mean, inv, full):
        from . import _dense

        X = self._gather(img, msk, rows, cols, mean, inv, full)
        if self.whiten:
            X = X @ self.P
            X -= self.mP
            X *= self._masks(msk, rows, cols)
        S = np.empty((len(rows), self.V.shape[1]), np.float32)
        _dense.triangle_scores(X, 0, X @ self.CT, 0, self.zero, self.cc, self.VT, S)
        return S

    def _generic(self, img, msk, rows, cols, mean, inv, full):
        X = self._gather(img, msk, rows, cols, mean, inv, full)
        M = self._masks(msk, rows, cols)
        if self.whiten:
            X = X @ self.P
            X -= self.mP
            X *= M
        m = self.model
        codes = encode_patches(X, M > 0.5, m.representation, m.encoder, m.encoder_param,
                               m.polarity)
        return np.asarray(codes, np.float32) @ self.V


def _new_stats() -> dict:
    """Counters of the dense encoding (summed over threads)."""
    return {"n_encodings": 0, "encode_seconds": 0.0, "encode_flops": 0.0}


def _merge_stats(into: dict, other: dict) -> None:
    """Add the counters of ``other`` to ``into``."""
    for key, val in other.items():
        into[key] = into.get(key, 0) + val


def _map(pool, fn, items) -> list:
    """``[fn(x) for x in items]``, in the pool's threads when there is one."""
    if pool is None or len(items) < 2:
        return [fn(x) for x in items]
    return list(pool.map(fn, items))


class _CanvasCache:
    """Rotated canvases made on first use (one lock per angle), dropped after their last use."""

    def __init__(self, make, uses):
        self._make = make
        self._uses = dict(uses)
        self._locks = {k: threading.Lock() for k in self._uses}
        self._count_lock = threading.Lock()
        self._canvas = {}

    def get(self, key):
        with self._locks[key]:
            if key not in self._canvas:
                self._canvas[key] = self._make(key)
            return self._canvas[key]

    def release(self, key):
        with self._count_lock:
            self._uses[key] -= 1
            if self._uses[key] == 0:
                self._canvas.pop(key, None)


class DenseDetector(_Base):
    """The grid search with dense, shared computation (see the module docstring).

    Parameters
    ----------
    model : DLSRDetector
    grid : SearchGrid
    top_k : int
    region, background, min_height :
        See :class:`ExactGridDetector`.
    rescore : int or None
        The best dense candidates rescored exactly and re-ranked (0: none); see
        :meth:`exact_scores`. None: 100 for the full grid (on four synthetic 640x480 images
        and one Jacquard view the exact best of the full grid was at dense rank 2 to 38), 60 in
        coarse-to-fine mode.
    coarse_to_fine : bool
        Coarse-to-fine mode: first the coarse grid (``coarse_grid``: 6 angles, openings and
        jaws every 20 px, centres every 10 px) is scored with patches encoded every
        ``coarse_stride`` positions; then the paper's grid is scored densely (every position)
        around the ``refine_top`` best coarse candidates: the neighbouring angles, openings and
        jaws of ``grid`` (one step each way) at centres within ``refine_radius`` steps; the
        best ``rescore`` of those are rescored exactly. Chosen among 27 variants on 123
        labelled images with object-wise models (95 synthetic 640x480 Cornell-layout images,
        28 Jacquard views at half size): the same accuracy as the full grid on the synthetic
        images (40/95), one image more on Jacquard (25/28 against 24/28), top-1 agreeing with
        the full grid by the rectangle metric on 90 % / 75 % of them, at about a fifth of the
        full grid's CPU time on the synthetic images (0.66 s against 3.1 s) and an eighth on
        Jacquard (0.92 s against 7.1 s); ``scripts/bench_detection.py`` times it.
    coarse_grid : SearchGrid
    refine_top : int
    refine_radius : int
        Centre offsets of the refinement, in steps of ``grid`` (0: the coarse centre only;
        the coarse grid already has the paper's centres).
    chunk_size : int
        Patches encoded at once (per thread).
    straddle : float
        Weight of the canvas patches in the rows that straddle the edge of a padded crop
        (``h < w``); the rest of their weight goes to the all-masked (padding) code. The exact
        crop masks their padding part; 0.5 tracked the exact scores best on the Jacquard
        samples (1: canvas only, 0: padding only).
    coarse_stride : int
        Coarse stage of the coarse-to-fine mode: patches are encoded every ``coarse_stride``
        positions in each direction and their scores replicated (2: a quarter of the
        encodings).
    fill : {"nearest", "band", "griddata"} or None
        Hole filling of the depth before the canvas normals are computed (once per image).
        Filled values only reach the normals of valid pixels next to a hole (normals at
        invalid pixels are masked), so the cheap ``"nearest"`` is the default; None uses the
        model's preprocessing choice (the exact path's, ``"band"``).
    n_threads : int or None
        Threads for the (angle, opening) canvases and the rescoring; None: the CPUs available
        to the process. BLAS runs single-threaded inside (each thread does whole products).
    """

    def __init__(self, model, grid=PAPER_GRID, top_k=5, region="auto", background=None,
                 min_height=0.006, rescore: int | None = None, coarse_to_fine: bool = False,
                 coarse_grid: SearchGrid = COARSE_GRID, refine_top: int = 40,
                 refine_radius: int = 0,
                 chunk_size: int = 2048, fill: str | None = "nearest",
                 straddle: float = 0.5, coarse_stride: int = 2, n_threads: int | None = None):
        super().__init__(model, grid, top_k, region, background, min_height)
        self.rescore = rescore
        self.coarse_to_fine = coarse_to_fine
        self.coarse_grid = coarse_grid
        self.refine_top = refine_top
        self.refine_radius = refine_radius
        self.chunk_size = chunk_size
        self.fill = fill
        self.straddle = straddle
        self.coarse_stride = coarse_stride
        self.n_threads = n_threads

    # -- public ------------------------------------------------------------------------------
    def detect(self, obs) -> Detection:
        """Detect grasps in one observation.

        ``timings`` holds wall seconds per stage (``candidates``, ``dense``, ``rescore``), the
        process CPU seconds of the last two (``dense_cpu``, ``rescore_cpu``, all threads), the
        encoding's summed thread seconds and useful products (``encode``, ``encode_flops``)
        and ``threads``.
        """
        t0 = time.perf_counter()
        _check_obs(obs)
        stats = _new_stats()
        if self.coarse_to_fine:
            cand, reason = self.candidates(obs, self.coarse_grid)
        else:
            cand, reason = self.candidates(obs)
        if reason:
            return _empty(reason, t0)
        t1, c1 = time.perf_counter(), time.process_time()
        with _one_blas_thread(), self._pool() as pool:
            src = self._source(obs, cand)
            stride = self.coarse_stride if self.coarse_to_fine else 1
            scores = self._dense_scores(src, cand, stats, pool, stride)
            n_scored = len(cand)
            if self.coarse_to_fine:
                seeds = cand[np.argsort(-scores, kind="stable")[: self.refine_top]]
                fine = self._neighbourhood(obs, seeds)
                if len(fine):  # the seeds are in it: rank the fine (stride-1) scores only
                    scores = self._dense_scores(src, fine, stats, pool, 1)
                    cand = fine
                    n_scored += len(fine)
            t2, c2 = time.perf_counter(), time.process_time()
            n_exact = 0
            n_rescore = self.rescore
            if n_rescore is None:
                n_rescore = 60 if self.coarse_to_fine else 100
            if n_rescore:
                top = np.argsort(-scores, kind="stable")[:n_rescore]
                cand = cand[top]
                scores = self._exact_scores(obs, cand, pool)
                n_exact = len(cand)
        order = np.argsort(-scores, kind="stable")[: self.top_k]
        t3, c3 = time.perf_counter(), time.process_time()
        timings = {"candidates": t1 - t0, "dense": t2 - t1, "rescore": t3 - t2,
                   "dense_cpu": c2 - c1, "rescore_cpu": c3 - c2,
                   "encode": stats["encode_seconds"], "encode_flops": stats["encode_flops"],
                   "threads": self._threads()}
        return Detection(cand[order], scores[order], n_candidates=n_scored,
                         n_encodings=stats["n_encodings"] + n_exact * PATCHES_PER_RECTANGLE,
                         seconds=t3 - t0, timings=timings)

    def score(self, obs, candidates, source=None, stats=None) -> np.ndarray:
        """Dense scores of arbitrary candidates ``(n, 5)`` (no exact rescoring).

        ``stats`` (a dict), when given, accumulates ``n_encodings``, ``encode_flops`` and
        ``encode_seconds`` (summed over threads).
        """
        cand = np.asarray(candidates, dtype=float).reshape(-1, 5)
        if len(cand) == 0:
            return np.full(0, -np.inf)
        with _one_blas_thread(), self._pool() as pool:
            if source is None:
                source = self._source(obs, cand)
            own = _new_stats()
            out = self._dense_scores(source, cand, own, pool, 1)
        if stats is not None:
            _merge_stats(stats, own)
        return out

    def exact_scores(self, obs, rects) -> np.ndarray:
        """Exact scores of rectangles (the rescoring).

        The rectangle images are recognition's (:func:`dlsr.preprocess.rectangle_images`);
        their 19 x 19 patches are encoded by the dense kernels and pooled over the quadrants,
        which gives :meth:`DLSRDetector.rectangle_scores` up to float rounding.

        Returns
        -------
        ndarray of shape (n,), float64
        """
        with _one_blas_thread(), self._pool() as pool:
            return self._exact_scores(obs, rects, pool)

    # -- internals ---------------------------------------------------------------------------
    def _threads(self) -> int:
        if self.n_threads is not None:
            return max(1, int(self.n_threads))
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # not on Linux
            return max(1, os.cpu_count() or 1)

    def _pool(self):
        n = self._threads()
        return ThreadPoolExecutor(n) if n > 1 else contextlib.nullcontext()

    def _source(self, obs, cand):
        H, W = np.asarray(obs["depth"]).shape
        m = int(np.max(cand[:, 3:5]) * 0.75) + 8 if len(cand) else 0
        roi = (max(0, int(cand[:, 1].min()) - m), min(H, int(cand[:, 1].max()) + m + 1),
               max(0, int(cand[:, 0].min()) - m), min(W, int(cand[:, 0].max()) + m + 1))
        return _Source(obs, self.model.preprocess, roi, self.fill)

    def _exact_scores(self, obs, rects, pool) -> np.ndarray:
        from . import _dense
        from .preprocess import rectangle_images

        rects = np.asarray(rects, dtype=float).reshape(-1, 5)
        if len(rects) == 0:
            return np.zeros(0)
        pre = dict(self.model.preprocess)
        pre["size"] = SIZE
        parts = [r for r in np.array_split(rects, self._threads()) if len(r)]
        made = _map(pool, lambda r: rectangle_images(obs["rgb"], obs["depth"],
                                                     obs.get("depth_valid"), r, **pre), parts)
        n = len(rects)
        img = np.concatenate([m[0] for m in made]).reshape(n * SIZE, SIZE, 8)
        msk = np.concatenate([m[1] for m in made]).reshape(n * SIZE, SIZE, 8)
        V, const = self.model.quadrant_weights()
        scorer = _PatchScorer(self.model, V)
        Hp = n * SIZE - PATCH + 1
        mean = np.empty((Hp, GRID, 4), np.float32)
        inv = np.empty((Hp, GRID, 4), np.float32)
        full = np.empty((Hp, GRID), bool)
        _dense.window_stats(img, msk, _STD_EPS, mean, inv, full)
        g = np.arange(GRID)
        rows = (np.arange(n)[:, None, None] * SIZE + g[None, :, None]
                + np.zeros(GRID, np.intp)[None, None, :]).ravel()
        cols = np.broadcast_to(g[None, None, :], (n, GRID, GRID)).ravel()
        per = max(1, self.chunk_size // PATCHES_PER_RECTANGLE) * PATCHES_PER_RECTANGLE
        spans = [(s, min(s + per, len(rows))) for s in range(0, len(rows), per)]
        S = np.concatenate(_map(pool, lambda se: scorer.scores(
            img, msk, rows[se[0]:se[1]], cols[se[0]:se[1]], mean, inv, full), spans))
        S = S.reshape(n, GRID, GRID, -1).astype(np.float64)
        pooled = (S[:, :SPLIT, :SPLIT, 0].sum((1, 2)) + S[:, :SPLIT, SPLIT:, 1].sum((1, 2))
                  + S[:, SPLIT:, :SPLIT, 2].sum((1, 2)) + S[:, SPLIT:, SPLIT:, 3].sum((1, 2)))
        return pooled + const

    def _neighbourhood(self, obs, seeds):
        g = self.grid
        angles = np.radians(np.asarray(g.angles_deg, float))
        da = np.radians(np.min(np.diff(np.sort(np.asarray(g.angles_deg, float))))) \
            if len(angles) > 1 else 0.0
        ow = np.asarray(g.openings, float)
        jh = np.asarray(g.jaws, float)
        dw = np.min(np.diff(np.sort(ow))) if len(ow) > 1 else 0.0
        dh = np.min(np.diff(np.sort(jh))) if len(jh) > 1 else 0.0
        angles = normalize_angle(angles)
        r = int(self.refine_radius)
        offsets = np.arange(-r, r + 1, dtype=float) * g.step
        rows = []
        H, W = np.asarray(obs["depth"]).shape
        for x, y, t, w, h in seeds:
            ths = angles[np.abs(normalize_angle(angles - t)) <= da * 1.01]
            ws = ow[np.abs(ow - w) <= dw * 1.01]
            hs = jh[np.abs(jh - h) <= dh * 1.01]
            A, Wm, Hm, Y, X = np.meshgrid(ths, ws, hs, y + offsets, x + offsets, indexing="ij")
            keep = Wm >= Hm
            rows.append(np.column_stack([X[keep], Y[keep], A[keep], Wm[keep], Hm[keep]]))
        rows = np.concatenate(rows) if rows else np.zeros((0, 5))
        if not len(rows):
            return np.zeros((0, 5))
        fine = np.unique(np.round(rows, 6), axis=0)
        corners = corners_from_array(fine)
        inside = ((corners[..., 0] >= 0) & (corners[..., 0] <= W - 1)
                  & (corners[..., 1] >= 0) & (corners[..., 1] <= H - 1)).all(axis=1)
        return fine[inside]

    def _padding_code_scores(self, V):
        """``V[:, q] . code(all-masked patch)`` per quadrant (the exact path's padding)."""
        rep = self.model.representation
        p = rep.dictionary.shape[1]
        code = encode_patches(np.zeros((1, p), np.float32), np.zeros((1, p), bool), rep,
                              self.model.encoder, self.model.encoder_param,
                              self.model.polarity)
        return np.asarray(code, np.float64)[0] @ V  # (4,)

    def _canvas(self, source: _Source, theta, A0, B0, Wf, Hf):
        """Full-resolution rotated canvas: values (Hf, Wf, 8), image mask, depth mask."""
        from .preprocess import _sample, surface_normals

        u, v = _axes(theta)
        centre = (A0 + (Wf - 1) / 2) * u + (B0 + (Hf - 1) / 2) * v
        smp = _sample(source.src, (centre[0], centre[1], theta, 0, 0), Wf, Hf)
        inside = smp[..., 5] >= _ONE
        dvalid = (smp[..., 4] >= _ONE) & inside
        pre = self.model.preprocess
        scale = float(pre.get("depth_scale", 1000.0))
        full = np.zeros((Hf, Wf, 8), dtype=np.float32)
        rgb = smp[..., :3] * inside[..., None]
        full[..., 1:4] = rgb
        full[..., 0] = rgb @ _GRAY
        full[..., 4] = np.where(dvalid, (smp[..., 3].astype(np.float64) - source.ref) * scale,
                                0.0)
        filled = (smp[..., 6].astype(np.float64) - source.ref) * scale
        full[..., 5:8] = surface_normals(filled)
        return full, inside, dvalid

    def _dense_scores(self, source, cand, stats, pool, stride) -> np.ndarray:
        """Dense scores of ``cand``: one task per (angle, opening), run in the pool."""
        out = np.full(len(cand), -np.inf)
        V, const = self.model.quadrant_weights()
        scorer = _PatchScorer(self.model, V)
        c0 = self._padding_code_scores(V)
        theta = normalize_angle(cand[:, 2])
        geoms, tasks = [], []
        for t in np.unique(np.round(theta, 9)):
            sel = np.flatnonzero(np.abs(theta - t) < 1e-8)
            u, v = _axes(float(t))
            c = cand[sel]
            a = c[:, 0] * u[0] + c[:, 1] * u[1]
            b = c[:, 0] * v[0] + c[:, 1] * v[1]
            margin = int(round(c[:, 3:5].max())) / 2 + 4
            A0 = math.floor(a.min() - margin)
            B0 = math.floor(b.min() - margin)
            Wf = int(math.ceil(a.max() + margin)) - A0 + 1
            Hf = int(math.ceil(b.max() + margin)) - B0 + 1
            key = len(geoms)
            geoms.append((float(t), A0, B0, Wf, Hf))
            ns = np.rint(c[:, 3]).astype(int)
            for n in np.unique(ns):
                gsel = np.flatnonzero(ns == n)
                s = SIZE / n
                cost = min(len(gsel) * (GRID + 1) ** 2,
                           (np.ptp(a[gsel]) * s + 2 * SIZE) * (np.ptp(b[gsel]) * s + 2 * SIZE))
                tasks.append((cost, key, int(n), a[gsel] - A0, b[gsel] - B0, c[gsel, 4],
                              sel[gsel]))
        tasks.sort(key=lambda x: -x[0])  # longest first: balanced threads
        uses = {}
        for task in tasks:
            uses[task[1]] = uses.get(task[1], 0) + 1
        canvases = _CanvasCache(lambda k: self._canvas(source, *geoms[k]), uses)

        def run(task):
            _, key, n, a, b, hs, idx = task
            full, imask, dmask = canvases.get(key)
            st = _new_stats()
            self._score_opening(full, imask, dmask, n, a, b, hs, idx, out, scorer, const, c0,
                                st, stride)
            canvases.release(key)
            return st

        for st in _map(pool, run, tasks):
            _merge_stats(stats, st)
        return out

    def _score_opening(self, full, imask, dmask, n, a, b, hs, idx, out, scorer, const, c0,
                       stats, stride=1):
        """Score candidates of one (angle, opening); ``a, b`` centres in canvas coordinates."""
        interp = {"area": cv2.INTER_AREA, "linear": cv2.INTER_LINEAR,
                  "cubic": cv2.INTER_CUBIC}[self.model.preprocess.get("interpolation", "area")]
        s = SIZE / n
        nrows = np.maximum(1, np.rint(hs).astype(int))
        nh = np.minimum(SIZE, np.maximum(1, np.rint(nrows * s).astype(int)))
        r0 = (SIZE - nh) // 2
        j0 = a - (n - 1) / 2  # full-res column of the crop's first column
        i0 = b - (nrows - 1) / 2 - r0 / s  # full-res row of the 24-frame's top
        q = n // math.gcd(n, SIZE)
        Jst = math.floor(j0.min()) - 2
        Ist = math.floor(i0.min()) - 2
        Ws = math.ceil(j0.max()) + n + 3 - Jst
        Hs = math.ceil(i0.max()) + n + 3 - Ist
        Ws = -(-Ws // q) * q
        Hs = -(-Hs // q) * q
        stack = np.zeros((Hs, Ws, 10), dtype=np.float32)
        Hf, Wf = imask.shape
        ra, rb = max(Ist, 0), min(Ist + Hs, Hf)
        ca, cb = max(Jst, 0), min(Jst + Ws, Wf)
        if ra < rb and ca < cb:
            tgt = stack[ra - Ist:rb - Ist, ca - Jst:cb - Jst]
            tgt[..., :8] = full[ra:rb, ca:cb]
            tgt[..., 8] = imask[ra:rb, ca:cb]
            tgt[..., 9] = dmask[ra:rb, ca:cb]
        oh, ow = Hs * SIZE // n, Ws * SIZE // n
        if (oh, ow) == (Hs, Ws):
            small = stack
        elif interp == cv2.INTER_LINEAR:
            small = cv2.resize(stack, (ow, oh), interpolation=interp)
        else:
            small = np.concatenate(
                [cv2.resize(stack[..., i:i + 4], (ow, oh), interpolation=interp)
                 .reshape(oh, ow, -1) for i in range(0, 10, 4)], axis=2)
        img = np.ascontiguousarray(small[..., :8])
        im = small[..., 8] > 0.75
        dm = small[..., 9] > 0.75
        msk = np.empty(img.shape, dtype=bool)
        msk[..., :4] = im[..., None]
        msk[..., 4:] = dm[..., None]
        img *= msk
        # window top-left in the resized canvas
        J0 = (j0 - Jst) * s
        I0 = (i0 - Ist) * s
        Ji = np.floor(J0).astype(np.intp)
        Ii = np.floor(I0).astype(np.intp)
        fj = J0 - Ji
        fi = I0 - Ii
        Hp, Wp = oh - PATCH + 1, ow - PATCH + 1
        Ji = np.clip(Ji, 0, Wp - GRID - 1)
        Ii = np.clip(Ii, 0, Hp - GRID - 1)
        # content patch rows (overlapping the crop's content rows); the others are padding
        lo = np.maximum(r0 - PATCH + 1, 0)
        hi = np.minimum(r0 + nh, GRID)
        # patch rows entirely inside the content; the rows between straddle its edge
        lo_f = np.minimum(r0, GRID)
        hi_f = np.maximum(lo_f, np.minimum(r0 + nh - PATCH + 1, GRID))
        alpha = float(self.straddle)
        # only the patch positions some window needs (+1 for the bilinear neighbours)
        diff = np.zeros((Hp + 1, Wp + 1), dtype=np.int32)
        np.add.at(diff, (Ii + lo, Ji), 1)
        np.add.at(diff, (Ii + lo, Ji + GRID + 1), -1)
        np.add.at(diff, (Ii + hi + 1, Ji), -1)
        np.add.at(diff, (Ii + hi + 1, Ji + GRID + 1), 1)
        needed = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:Hp, :Wp] > 0
        if stride > 1:  # coarse stage: encode every stride-th position, replicate the scores
            keep = np.zeros_like(needed)
            keep[::stride, ::stride] = True
            needed &= keep
        S = self._score_maps(img, msk, scorer, stats, needed)  # (Hp, Wp, 4)
        if stride > 1:
            S = np.repeat(np.repeat(S[::stride, ::stride], stride, axis=0), stride,
                          axis=1)[:Hp, :Wp]
            if S.shape[:2] != (Hp, Wp):
                S = np.pad(S, ((0, Hp - S.shape[0]), (0, Wp - S.shape[1]), (0, 0)))
        T = np.zeros((Hp + 1, Wp + 1, S.shape[2]))  # the summed-area tables of the 4 maps
        np.cumsum(np.cumsum(S, axis=0, dtype=np.float64), axis=1, out=T[1:, 1:])
        quads = ((0, SPLIT, 0, SPLIT), (0, SPLIT, SPLIT, GRID),
                 (SPLIT, GRID, 0, SPLIT), (SPLIT, GRID, SPLIT, GRID))
        # per quadrant: content rows [ra, rb), rows entirely in the content [fa, fb) and
        # the padding's share (the all-masked code) of the sum, independent of the position
        rows = []
        res = np.full(len(a), float(const))
        for k, (qa, qb, qc, qd) in enumerate(quads):
            ra_ = np.clip(lo, qa, qb)
            rb_ = np.clip(hi, qa, qb)
            npad = ((qb - qa) - (rb_ - ra_)) * (qd - qc)
            if alpha != 1.0:  # straddling rows: alpha * canvas + (1 - alpha) * padding
                fa = np.clip(lo_f, qa, qb)
                fb = np.maximum(np.clip(hi_f, qa, qb), fa)
                nst = ((rb_ - ra_) - (fb - fa)) * (qd - qc)
                res += (npad + (1 - alpha) * nst) * c0[k]
            else:
                fa = fb = None
                res += npad * c0[k]
            rows.append((k, ra_, rb_, fa, fb, qc, qd))
        for di, dj, wgt in ((0, 0, (1 - fi) * (1 - fj)), (0, 1, (1 - fi) * fj),
                            (1, 0, fi * (1 - fj)), (1, 1, fi * fj)):
            rr = Ii + di
            c_lo = Ji + dj
            tot = np.zeros(len(a))
            for k, ra_, rb_, fa, fb, qc, qd in rows:
                Tk = T[..., k]
                box = _box_sums(Tk, rr + ra_, rr + rb_, c_lo + qc, c_lo + qd)
                if fa is not None:
                    inner = _box_sums(Tk, rr + fa, rr + fb, c_lo + qc, c_lo + qd)
                    box = inner + alpha * (box - inner)
                tot += box
            res += wgt * tot
        out[idx] = res

    def _score_maps(self, img, msk, scorer, stats, needed=None):
        """Per-pixel ``V[:, q] . code(patch)`` for the 6x6 patches of a canvas.

        Patches are standardised (masked per-group statistics from running window sums,
        float64, :func:`dlsr._dense.window_stats`), whitened and encoded by ``scorer``
        (a :class:`_PatchScorer`) exactly as :func:`dlsr.whitening.standardize_patches`,
        :func:`~dlsr.whitening.apply_zca` and :func:`dlsr.features.encode_patches` do, in
        chunks of ``chunk_size`` patches, only at the positions where ``needed`` is True (all
        when None; the others stay 0).

        Returns
        -------
        ndarray of shape (H - 5, W - 5, q), float32
        """
        from . import _dense

        Hc, Wc, _ = img.shape
        Hp, Wp = Hc - PATCH + 1, Wc - PATCH + 1
        nq = scorer.V.shape[1]
        S = np.zeros((max(Hp, 0) * max(Wp, 0), nq), dtype=np.float32)
        if Hp <= 0 or Wp <= 0:
            return S.reshape(max(Hp, 0), max(Wp, 0), nq)
        pos = np.flatnonzero(needed.ravel()) if needed is not None else np.arange(Hp * Wp)
        if len(pos) == 0:
            return S.reshape(Hp, Wp, nq)
        img = np.ascontiguousarray(img, dtype=np.float32)
        msk = np.ascontiguousarray(msk, dtype=bool)
        mean = np.empty((Hp, Wp, 4), np.float32)
        inv = np.empty((Hp, Wp, 4), np.float32)
        full = np.empty((Hp, Wp), bool)
        _dense.window_stats(img, msk, _STD_EPS, mean, inv, full)
        t0 = time.perf_counter()
        for st in range(0, len(pos), self.chunk_size):
            pc = pos[st:st + self.chunk_size]
            S[pc] = scorer.scores(img, msk, pc // Wp, pc % Wp, mean, inv, full)
        n_masked = int(np.count_nonzero(~full.ravel()[pos]))
        stats["n_encodings"] += len(pos)
        stats["encode_flops"] += (scorer.flops * (len(pos) - n_masked)
                                  + scorer.flops_masked * n_masked)
        stats["encode_seconds"] += time.perf_counter() - t0
        return S.reshape(Hp, Wp, nq)


# ---------------------------------------------------------------------------------------------
# One image from files (``graspsim detect``)
# ---------------------------------------------------------------------------------------------


def detect_files(model, rgb, depth, mask=None, background=None, depth_units: float = 1.0,
                 detector: str | None = None, top_k: int = 5, out=None, **options):
    """Detect grasps in one RGB-D image read from files (the ``graspsim detect`` command).

    Parameters
    ----------
    model : DLSRDetector or path
        A model or the path of a saved one.
    rgb : path
        Colour image (PNG, ...).
    depth : path
        Depth image (float TIFF in metres, or ``.npy``); values <= 0 or non-finite are missing.
    mask, background : path or None
        Object mask (non-zero = object) or background image for the object region.
    depth_units : float
        Multiplies the depth file's values to give metres (e.g. 0.001 for millimetres).
    detector : {"dense", "exact"} or None
        None: the model's saved choice.
    top_k : int
    out : path or None
        Overlay PNG with the detections (best drawn last).
    **options :
        Passed to the detector (``coarse_to_fine``, ``rescore``, ``region``).

    Returns
    -------
    Detection
    """
    if not isinstance(model, DLSRDetector):
        model = DLSRDetector.load(model)
    from .datasets import clean_depth, read_depth_image, read_gray, read_rgb

    rgb_arr = read_rgb(rgb)
    d, valid = clean_depth(read_depth_image(depth))
    if d.shape != rgb_arr.shape[:2]:
        raise ValueError(f"depth {depth} has shape {d.shape}, the image {rgb} "
                         f"{rgb_arr.shape[:2]}")
    obs = {"rgb": rgb_arr, "depth": d * np.float32(depth_units), "depth_valid": valid}
    if mask is not None:
        obs["mask"] = read_gray(mask) > 0
    bg = None if background is None else read_rgb(background)
    det = model.detector(detector, top_k=top_k, background=bg, **options).detect(obs)
    if out is not None:
        from PIL import Image

        from .viz import draw_rectangles

        img = draw_rectangles(rgb_arr, det.rects[:1], negatives=det.rects[1:][::-1])
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(img).save(out)
    return det
