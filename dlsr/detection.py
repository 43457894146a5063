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
  6x6 patch of it is standardised, whitened and encoded once (float32 matrix products, in chunks;
  per-patch group statistics come from box filters), the four score maps get summed-area tables,
  and every candidate is scored with a handful of table look-ups. The top ``rescore`` candidates
  are then rescored exactly and re-ranked.

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

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .features import Representation, encode_patches, rectangle_features
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
#: First stage of the coarse-to-fine mode: 6 angles, openings 20..80, centres every 20 px.
COARSE_GRID = SearchGrid(angles_deg=tuple(range(0, 180, 30)), openings=(20, 40, 60, 80),
                         jaws=(20, 40, 60, 80), step=20.0)


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
    random_state : int
    data : RecognitionData or None
        Precomputed rectangle images of ``samples`` (skips preprocessing).
    **config :
        Detector options stored in the model (``detector``, ``grid`` (dict), ``top_k``,
        ``rescore``, ``region``).

    Returns
    -------
    DLSRDetector
    """
    from .features import ENCODER_GRIDS, ENCODERS, fit_representation
    from .recognition import recognition_data
    from .svm import FeatureStandardizer, SquaredHingeSVC

    if encoder not in ENCODERS:
        raise ValueError(f"unknown encoder {encoder!r}; choose from {ENCODERS}")
    if encoder_param is None and encoder != "Natural":
        grid = ENCODER_GRIDS[encoder]
        encoder_param = grid[len(grid) // 2 - 1]
    t0 = time.perf_counter()
    if data is None:
        data = recognition_data(samples, negatives_per_image=negatives_per_image,
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
    info = {"learner": learner, "encoder": encoder, "encoder_param": _jsonable(encoder_param),
            "C": float(C), "n_atoms": int(n_atoms), "whiten": bool(whiten),
            "n_patches": int(n_patches), "n_train_rectangles": int(len(data)),
            "n_train_positive": int(np.sum(data.labels == 1)),
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


class DenseDetector(_Base):
    """The grid search with dense, shared computation (see the module docstring).

    Parameters
    ----------
    model : DLSRDetector
    grid : SearchGrid
    top_k : int
    region, background, min_height :
        See :class:`ExactGridDetector`.
    rescore : int
        The best dense candidates rescored exactly and re-ranked (0: none).
    coarse_to_fine : bool
        First a coarse search (:data:`COARSE_GRID`), then the full grid in a neighbourhood
        (one grid step in angle, opening, jaw and centre) of the best ``refine_top`` coarse
        candidates.
    refine_top : int
    chunk_size : int
        Patches encoded at once.
    straddle : float
        Weight of the canvas patches in the rows that straddle the edge of a padded crop
        (``h < w``); the rest of their weight goes to the all-masked (padding) code. The exact
        crop masks their padding part; 0.5 tracked the exact scores best on the Jacquard
        samples (1: canvas only, 0: padding only).
    coarse_stride : int
        Coarse stage of the coarse-to-fine mode: patches are encoded every ``coarse_stride``
        positions in each direction and their scores replicated.
    fill : {"nearest", "band", "griddata"} or None
        Hole filling of the depth before the canvas normals are computed (once per image).
        Filled values only reach the normals of valid pixels next to a hole (normals at
        invalid pixels are masked), so the cheap ``"nearest"`` is the default; None uses the
        model's preprocessing choice (the exact path's, ``"band"``).
    """

    def __init__(self, model, grid=PAPER_GRID, top_k=5, region="auto", background=None,
                 min_height=0.006, rescore: int = 300, coarse_to_fine: bool = False,
                 coarse_grid: SearchGrid = COARSE_GRID, refine_top: int = 20,
                 chunk_size: int = 8192, fill: str | None = "nearest",
                 straddle: float = 0.5, coarse_stride: int = 2):
        super().__init__(model, grid, top_k, region, background, min_height)
        self.rescore = rescore
        self.coarse_to_fine = coarse_to_fine
        self.coarse_grid = coarse_grid
        self.refine_top = refine_top
        self.chunk_size = chunk_size
        self.fill = fill
        self.straddle = straddle
        self.coarse_stride = coarse_stride
        self._stride = 1

    # -- public ------------------------------------------------------------------------------
    def detect(self, obs) -> Detection:
        t0 = time.perf_counter()
        _check_obs(obs)
        stats = {"n_encodings": 0, "encode_seconds": 0.0, "encode_flops": 0.0}
        if self.coarse_to_fine:
            cand, reason = self.candidates(obs, self.coarse_grid)
        else:
            cand, reason = self.candidates(obs)
        if reason:
            return _empty(reason, t0)
        t1 = time.perf_counter()
        src = self._source(obs, cand)
        self._stride = self.coarse_stride if self.coarse_to_fine else 1
        try:
            scores = self.score(obs, cand, source=src, stats=stats)
        finally:
            self._stride = 1
        n_scored = len(cand)
        if self.coarse_to_fine:
            seeds = cand[np.argsort(-scores, kind="stable")[: self.refine_top]]
            fine = self._neighbourhood(obs, seeds)
            if len(fine):
                fscores = self.score(obs, fine, source=src, stats=stats)
                cand = np.concatenate([cand, fine])
                scores = np.concatenate([scores, fscores])
                n_scored += len(fine)
        t2 = time.perf_counter()
        n_exact = 0
        if self.rescore:
            top = np.argsort(-scores, kind="stable")[: self.rescore]
            cand = cand[top]
            scores = self.model.rectangle_scores(obs, cand)
            n_exact = len(cand)
        order = np.argsort(-scores, kind="stable")[: self.top_k]
        t3 = time.perf_counter()
        timings = {"candidates": t1 - t0, "dense": t2 - t1, "rescore": t3 - t2,
                   "encode": stats["encode_seconds"], "encode_flops": stats["encode_flops"]}
        return Detection(cand[order], scores[order], n_candidates=n_scored,
                         n_encodings=stats["n_encodings"] + n_exact * PATCHES_PER_RECTANGLE,
                         seconds=t3 - t0, timings=timings)

    def score(self, obs, candidates, source=None, stats=None) -> np.ndarray:
        """Dense scores of arbitrary candidates ``(n, 5)`` (no exact rescoring)."""
        cand = np.asarray(candidates, dtype=float).reshape(-1, 5)
        out = np.full(len(cand), -np.inf)
        if len(cand) == 0:
            return out
        if source is None:
            source = self._source(obs, cand)
        if stats is None:
            stats = {"n_encodings": 0, "encode_seconds": 0.0, "encode_flops": 0.0}
        V, const = self.model.quadrant_weights()
        V32 = V.astype(np.float32)
        c0 = self._padding_code_scores(V)
        theta = normalize_angle(cand[:, 2])
        for t in np.unique(np.round(theta, 9)):
            sel = np.flatnonzero(np.abs(theta - t) < 1e-8)
            self._score_angle(source, float(t), cand, sel, out, V32, const, c0, stats)
        return out

    # -- internals ---------------------------------------------------------------------------
    def _source(self, obs, cand):
        H, W = np.asarray(obs["depth"]).shape
        m = int(np.max(cand[:, 3:5]) * 0.75) + 8 if len(cand) else 0
        roi = (max(0, int(cand[:, 1].min()) - m), min(H, int(cand[:, 1].max()) + m + 1),
               max(0, int(cand[:, 0].min()) - m), min(W, int(cand[:, 0].max()) + m + 1))
        return _Source(obs, self.model.preprocess, roi, self.fill)

    def _neighbourhood(self, obs, seeds):
        g = self.grid
        angles = np.radians(np.asarray(g.angles_deg, float))
        da = np.radians(np.min(np.diff(np.sort(np.asarray(g.angles_deg, float))))) \
            if len(angles) > 1 else 0.0
        ow = np.asarray(g.openings, float)
        jh = np.asarray(g.jaws, float)
        dw = np.min(np.diff(np.sort(ow))) if len(ow) > 1 else 0.0
        dh = np.min(np.diff(np.sort(jh))) if len(jh) > 1 else 0.0
        rows = []
        H, W = np.asarray(obs["depth"]).shape
        for x, y, t, w, h in seeds:
            ths = [a for a in angles
                   if abs(normalize_angle(a - t)) <= da * 1.01]
            ws = ow[np.abs(ow - w) <= dw * 1.01]
            hs = jh[np.abs(jh - h) <= dh * 1.01]
            xs = np.arange(x - g.step, x + g.step + 1e-9, g.step)
            ys = np.arange(y - g.step, y + g.step + 1e-9, g.step)
            for a in ths:
                for ww in ws:
                    for hh in hs:
                        if ww < hh:
                            continue
                        for yy in ys:
                            for xx in xs:
                                rows.append((xx, yy, normalize_angle(a), ww, hh))
        if not rows:
            return np.zeros((0, 5))
        fine = np.unique(np.round(np.asarray(rows), 6), axis=0)
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

    def _score_angle(self, source, theta, cand, sel, out, V32, const, c0, stats):
        u, v = _axes(theta)
        c = cand[sel]
        a = c[:, 0] * u[0] + c[:, 1] * u[1]
        b = c[:, 0] * v[0] + c[:, 1] * v[1]
        nmax = int(round(c[:, 3:5].max()))
        margin = nmax / 2 + 4
        A0 = math.floor(a.min() - margin)
        B0 = math.floor(b.min() - margin)
        Wf = int(math.ceil(a.max() + margin)) - A0 + 1
        Hf = int(math.ceil(b.max() + margin)) - B0 + 1
        full, imask, dmask = self._canvas(source, theta, A0, B0, Wf, Hf)
        for n in np.unique(np.rint(c[:, 3]).astype(int)):
            gsel = np.flatnonzero(np.rint(c[:, 3]).astype(int) == n)
            self._score_opening(full, imask, dmask, int(n), a[gsel] - A0, b[gsel] - B0,
                                c[gsel, 4], sel[gsel], out, V32, const, c0, stats)

    def _score_opening(self, full, imask, dmask, n, a, b, hs, idx, out, V32, const, c0,
                       stats):
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
        stride = int(self._stride)
        if stride > 1:  # coarse stage: encode every stride-th position, replicate the scores
            keep = np.zeros_like(needed)
            keep[::stride, ::stride] = True
            needed &= keep
        S = self._score_maps(img, msk, V32, stats, needed)  # (Hp, Wp, 4)
        if stride > 1:
            S = np.repeat(np.repeat(S[::stride, ::stride], stride, axis=0), stride,
                          axis=1)[:Hp, :Wp]
            if S.shape[:2] != (Hp, Wp):
                S = np.pad(S, ((0, Hp - S.shape[0]), (0, Wp - S.shape[1]), (0, 0)))
        T = [_sat(S[..., k]) for k in range(4)]
        res = np.zeros(len(a))
        quads = ((0, SPLIT, 0, SPLIT), (0, SPLIT, SPLIT, GRID),
                 (SPLIT, GRID, 0, SPLIT), (SPLIT, GRID, SPLIT, GRID))
        for di, dj, wgt in ((0, 0, (1 - fi) * (1 - fj)), (0, 1, (1 - fi) * fj),
                            (1, 0, fi * (1 - fj)), (1, 1, fi * fj)):
            tot = np.zeros(len(a))
            rr = Ii + di
            cc = Ji + dj
            for k, (qa, qb, qc, qd) in enumerate(quads):
                ra_ = np.clip(lo, qa, qb)
                rb_ = np.clip(hi, qa, qb)
                npad = ((qb - qa) - (rb_ - ra_)) * (qd - qc)
                box = _box_sums(T[k], rr + ra_, rr + rb_, cc + qc, cc + qd)
                if alpha != 1.0:  # straddling rows: alpha * canvas + (1 - alpha) * padding
                    fa = np.clip(lo_f, qa, qb)
                    fb = np.maximum(np.clip(hi_f, qa, qb), fa)
                    inner = _box_sums(T[k], rr + fa, rr + fb, cc + qc, cc + qd)
                    nst = ((rb_ - ra_) - (fb - fa)) * (qd - qc)
                    box = inner + alpha * (box - inner) + (1 - alpha) * nst * c0[k]
                tot += box + npad * c0[k]
            res += wgt * tot
        out[idx] = res + const

    def _score_maps(self, img, msk, V32, stats, needed=None):
        """Per-pixel ``V[:, q] . code(patch)`` for the 6x6 patches of a canvas.

        Patches are standardised (masked per-group statistics from box filters, float64),
        whitened (one float32 product, re-masked) and encoded exactly as
        :func:`dlsr.whitening.standardize_patches`, :func:`~dlsr.whitening.apply_zca` and
        :func:`dlsr.features.encode_patches` do, in chunks of ``chunk_size`` patches, only at
        the positions where ``needed`` is True (all when None; the others stay 0).
        """
        rep = self.model.representation
        Hc, Wc, C = img.shape
        Hp, Wp = Hc - PATCH + 1, Wc - PATCH + 1
        S = np.zeros((max(Hp, 0) * max(Wp, 0), 4), dtype=np.float32)
        if Hp <= 0 or Wp <= 0:
            return S.reshape(max(Hp, 0), max(Wp, 0), 4)
        pos = np.flatnonzero(needed.ravel()) if needed is not None else np.arange(Hp * Wp)
        if len(pos) == 0:
            return S.reshape(Hp, Wp, 4)
        # per-position masked group statistics by box filters (float64)
        groups = ((0,), (1, 2, 3), (4,), (5, 6, 7))
        gof = np.array([0, 1, 1, 1, 2, 3, 3, 3])
        x64 = img.astype(np.float64)
        mean = np.empty((Hp * Wp, 4))
        inv = np.empty((Hp * Wp, 4))
        full = np.ones(Hp * Wp, dtype=bool)
        for g, chans in enumerate(groups):
            xs = x64[..., list(chans)]
            s1 = _window_sum(xs.sum(-1)).ravel()
            s2 = _window_sum((xs * xs).sum(-1)).ravel()
            cnt = np.rint(_window_sum(msk[..., list(chans)].sum(-1).astype(np.float64))).ravel()
            full &= cnt == PATCH * PATCH * len(chans)
            mu = s1 / np.maximum(cnt, 1.0)
            var = np.maximum(s2 - s1 * mu, 0.0) / np.maximum(cnt - 1.0, 1.0)
            var[cnt < 2] = 0.0
            mean[:, g] = mu
            inv[:, g] = 1.0 / np.sqrt(var + 1e-4)
        mean_ch = mean[:, gof].astype(np.float32)
        inv_ch = inv[:, gof].astype(np.float32)
        P = None if rep.zca_mean is None else np.asarray(rep.zca_matrix, np.float32)
        mP = None if P is None else np.asarray(rep.zca_mean, np.float32) @ P
        # gather offsets of a patch's 288 values (row, col, channel) in the flat canvas
        dy, dx, ch = np.meshgrid(np.arange(PATCH), np.arange(PATCH), np.arange(C),
                                 indexing="ij")
        off = ((dy * Wc + dx) * C + ch).ravel()
        flat = img.reshape(-1)
        mflat = msk.reshape(-1)
        fast_nkm = rep.learner == "NKM" and self.model.encoder == "Natural" \
            and rep.centroids is not None
        if fast_nkm:
            Cn = np.asarray(rep.centroids, np.float32)
            CT = np.ascontiguousarray(Cn.T)
            cc = np.einsum("kp,kp->k", Cn, Cn)
        k_codes = V32.shape[0]
        p = PATCH * PATCH * C
        t0 = time.perf_counter()
        for st in range(0, len(pos), self.chunk_size):
            pc = pos[st:st + self.chunk_size]
            N = len(pc)
            base = ((pc // Wp) * Wc + pc % Wp) * C
            gidx = base[:, None] + off[None, :]
            X = flat[gidx].reshape(N, PATCH * PATCH, C)
            X -= mean_ch[pc][:, None, :]
            X *= inv_ch[pc][:, None, :]
            Xs = X.reshape(N, p)
            bad = np.flatnonzero(~full[pc])
            Mb = mflat[gidx[bad]] if len(bad) else None
            if len(bad):
                Xs[bad] *= Mb
            if P is not None:
                Xw = Xs @ P
                Xw -= mP
                if len(bad):
                    Xw[bad] *= Mb
            else:
                Xw = Xs
            if fast_nkm:  # dlsr.coding.kmeans_triangle, fused
                z = Xw @ CT
                z *= -2.0
                z += cc[None, :]
                z += np.einsum("ij,ij->i", Xw, Xw)[:, None]
                np.maximum(z, 0.0, out=z)
                np.sqrt(z, out=z)
                mu = z.mean(axis=1, keepdims=True)
                np.subtract(mu, z, out=z)
                codes = np.maximum(z, 0.0, out=z)
            else:
                codes = np.asarray(encode_patches(Xw, mflat[gidx], rep, self.model.encoder,
                                                  self.model.encoder_param,
                                                  self.model.polarity), np.float32)
            S[pc] = codes @ V32
            stats["n_encodings"] += N
            stats["encode_flops"] += 2.0 * N * p * ((p if P is not None else 0) + k_codes)
        stats["encode_seconds"] += time.perf_counter() - t0
        return S.reshape(Hp, Wp, 4)


def _window_sum(a: np.ndarray) -> np.ndarray:
    """Sums over every 6x6 window (valid positions), float64."""
    T = _sat(a)
    return T[PATCH:, PATCH:] - T[:-PATCH, PATCH:] - T[PATCH:, :-PATCH] + T[:-PATCH, :-PATCH]


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
