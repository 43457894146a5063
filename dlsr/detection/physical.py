"""Physical features of grasp rectangles, measured in the observation's depth.

The paper's representation sees a rectangle only through its 24 x 24 crop: the crop is rescaled
so the opening spans it, and every 6 x 6 patch is standardised, so the rectangle's size in metres
and how high the surfaces under its jaws stand are gone from the features. A parallel-jaw
gripper cares about both: an opening the gripper cannot reach, or a finger that lands on the
object, is a failed grasp whatever the crop looks like. :func:`physical_features` measures them
(and the rectangle's place on the object's principal axes, the prior of the ``mask-pca``
heuristic) from the depth, the camera matrix, the table surface fitted to the depth
(:func:`dlsr.detection.table_surface`) and the object region, for any number of rectangles at
once. :class:`PhysicalEncoder` turns them into the indicator columns a linear SVM can weigh
(quantile bins fitted on the training rectangles), so that they join the DLSR features in one
SVM (:func:`dlsr.detection.train_detector` with ``physical=True``): a named departure from the
paper, off by default.

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import numpy as np

from .grid import complete_region, opening_widths, valid_depth

__all__ = ["PHYSICAL_FEATURES", "PhysicalEncoder", "mask_axes", "physical_features"]

#: Columns of :func:`physical_features`, in order (units in its docstring).
PHYSICAL_FEATURES = (
    "opening_m",
    "jaw_m",
    "centre_height_m",
    "jaw_height_m",
    "jaw_above_centre_m",
    "jaw_on_object",
    "centre_on_object",
    "offset_major",
    "angle_to_minor",
)

#: Finger thickness along the closing direction, metres (graspsim's gripper, 8 mm).
FINGER_THICKNESS = 0.008


def mask_axes(mask) -> tuple[np.ndarray, float, np.ndarray]:
    """Centroid, minor-axis angle and pixel coordinates of a mask.

    Parameters
    ----------
    mask : ndarray of shape (H, W), bool

    Returns
    -------
    centroid : ndarray of shape (2,)
        ``(x, y)`` pixels.
    theta_minor : float
        Angle of the minor axis (counter-clockwise as displayed, the rectangle convention).
    xy : ndarray of shape (n, 2)
        ``(x, y)`` of the mask pixels.

    Raises
    ------
    ValueError
        If the mask is empty.
    """
    ys, xs = np.nonzero(np.asarray(mask, dtype=bool))
    if len(xs) == 0:
        raise ValueError("the object mask is empty")
    xy = np.column_stack([xs, ys]).astype(float)
    c = xy.mean(axis=0)
    d = xy - c
    cov = d.T @ d / max(len(xy), 1)
    _, vecs = np.linalg.eigh(cov)
    minor = vecs[:, 0]
    return c, float(np.arctan2(-minor[1], minor[0])), xy


def _sample(values, r, a, b, fill):
    """``values`` at points ``a`` along each rectangle's closing direction and ``b`` across it
    (pixels from the centre; arrays broadcasting to ``(n, k)``); ``fill`` outside the image."""
    H, W = values.shape
    c, s = np.cos(r[:, 2:3]), np.sin(r[:, 2:3])  # u = (c, -s), v = (s, c): dlsr.preprocess
    col = np.rint(r[:, 0:1] + a * c + b * s).astype(np.intp)
    row = np.rint(r[:, 1:2] - a * s + b * c).astype(np.intp)
    ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    out = np.full(col.shape, fill, dtype=values.dtype)
    out[ok] = values[row[ok], col[ok]]
    return out


def physical_features(obs: dict, rects, region, table=None,
                      finger: float = FINGER_THICKNESS, n_across: int = 7,
                      n_along: int = 3) -> np.ndarray:
    """What a parallel-jaw gripper would meet at each rectangle, from depth.

    Parameters
    ----------
    obs : dict
        ``depth`` (H, W) metres (values <= 0 or non-finite are missing), optional
        ``depth_valid`` (H, W) bool, and ``K`` (3, 3).
    rects : ndarray of shape (n, 5)
        ``(x, y, theta, w, h)``, pixels and radians (:class:`dlsr.rectangles.GraspRectangle`).
    region : ndarray of shape (H, W), bool
        The object region (:func:`dlsr.detection.object_region`); the features measure it
        with its unseen surface added (:func:`dlsr.detection.complete_region`: the missing
        depth inside its convex hull), as the lattice detector lays its candidates.
    table : ndarray of shape (H, W) or None
        The table's depth at every pixel (:func:`dlsr.detection.table_surface`), metres; None
        (no table found) measures heights from the deepest valid pixel of the region's
        surroundings instead (the image's 95th depth percentile).
    finger : float
        Finger thickness along the closing direction, metres.
    n_across, n_along : int
        Sample points of each finger's footprint across and along the closing direction.

    Returns
    -------
    ndarray of shape (n, 9), float64
        Columns :data:`PHYSICAL_FEATURES`:

        * ``opening_m``, ``jaw_m``: the opening ``w`` and jaw size ``h`` in metres at the depth
          under the centre (:func:`dlsr.detection.opening_widths`);
        * ``centre_height_m``: height of the surface under the centre above the table, metres
          (that of the region's median when the centre's depth is missing);
        * ``jaw_height_m``: the highest surface in the two finger footprints (``finger`` wide,
          just outside the opening, ``h`` long), metres above the table (0 where nothing valid
          was seen);
        * ``jaw_above_centre_m``: ``jaw_height_m - centre_height_m``;
        * ``jaw_on_object``: the larger fraction of a footprint's points on the region;
        * ``centre_on_object``: 1 when the centre pixel is on the region, else 0;
        * ``offset_major``: distance of the centre from the region's centroid along its major
          axis, over the region's half-length (0: centred, 1: at an end);
        * ``angle_to_minor``: ``|sin|`` of the angle between the closing direction and the
          region's minor axis (0: across the object, 1: along it).

        With an empty region the last two are 1 and ``centre_on_object`` is 0.

    Raises
    ------
    ValueError
        When shapes disagree or ``K`` is missing (as :func:`dlsr.detection.opening_widths`).
    """
    depth = np.asarray(obs["depth"], dtype=np.float64)
    region = np.asarray(region, dtype=bool)
    if region.shape != depth.shape:
        raise ValueError(f"region {region.shape} and depth {depth.shape} must be the same "
                         "(H, W)")
    if table is not None and np.shape(table) != depth.shape:
        raise ValueError(f"table surface {np.shape(table)} and depth {depth.shape} must be "
                         "the same (H, W)")
    if n_across < 1 or n_along < 1:
        raise ValueError(f"n_across and n_along must be >= 1, got {n_across}, {n_along}")
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 5)
    n = len(rects)
    out = np.zeros((n, len(PHYSICAL_FEATURES)))
    if n == 0:
        return out
    valid = valid_depth(depth, obs.get("depth_valid"))
    region = complete_region(region, valid)
    opening = opening_widths(obs, rects, region)
    out[:, 0] = opening
    out[:, 1] = opening * rects[:, 4] / np.maximum(rects[:, 3], 1e-9)
    if table is None:
        base = float(np.percentile(depth[valid], 95)) if valid.any() else 0.0
        height = np.where(valid, base - depth, np.nan)
    else:
        height = np.where(valid, np.asarray(table, dtype=np.float64) - depth, np.nan)
    on_valid = valid & region
    fallback = float(np.median(height[on_valid])) if on_valid.any() else 0.0
    zero = np.zeros((n, 1))
    hc = _sample(height, rects, zero, zero, np.nan)[:, 0]
    out[:, 2] = np.where(np.isfinite(hc), hc, fallback)
    # finger footprints: `finger` metres beyond each end of the opening, h pixels across
    px_per_m = rects[:, 3] / np.maximum(opening, 1e-9)
    px_per_m = np.where(np.isfinite(px_per_m), px_per_m, 0.0)
    t_along = np.linspace(0.0, 1.0, n_along)
    t_across = np.linspace(-0.5, 0.5, n_across)
    a = (0.5 * rects[:, 3:4] + (finger * px_per_m)[:, None] * t_along[None, :])
    a = np.repeat(a, n_across, axis=1)
    b = np.tile(rects[:, 4:5] * t_across[None, :], (1, n_along))
    jaw_h = np.zeros(n)
    jaw_on = np.zeros(n)
    for side in (1.0, -1.0):
        h = _sample(height, rects, side * a, b, np.nan)
        seen = np.isfinite(h)
        top = np.where(seen.any(axis=1), np.max(np.where(seen, h, -np.inf), axis=1), 0.0)
        jaw_h = np.maximum(jaw_h, top)
        jaw_on = np.maximum(jaw_on, _sample(region, rects, side * a, b, False).mean(axis=1))
    col = {name: j for j, name in enumerate(PHYSICAL_FEATURES)}
    out[:, col["jaw_height_m"]] = jaw_h
    out[:, col["jaw_above_centre_m"]] = jaw_h - out[:, 2]
    out[:, col["jaw_on_object"]] = jaw_on
    out[:, col["centre_on_object"]] = _sample(region, rects, zero, zero, False)[:, 0]
    if region.any():
        c, th_minor, xy = mask_axes(region)
        major = np.array([np.sin(th_minor), np.cos(th_minor)])  # (x, y), across the minor axis
        half = max(float(np.abs((xy - c) @ major).max()), 1.0)
        out[:, col["offset_major"]] = np.abs((rects[:, :2] - c) @ major) / half
        out[:, col["angle_to_minor"]] = np.abs(np.sin(rects[:, 2] - th_minor))
    else:
        out[:, col["offset_major"]] = 1.0
        out[:, col["angle_to_minor"]] = 1.0
    return out


class PhysicalEncoder:
    """Quantile-bin indicators of :func:`physical_features`, for a linear SVM.

    Each column is cut at its training quantiles into at most ``n_bins`` bins (fewer where
    quantiles coincide: two for a 0/1 column, one for a constant) and encoded one-hot, so a
    linear model can weigh a U-shaped effect (an opening too narrow or too wide). Plain arrays
    in and out; the edges are the whole state (saved with the model).

    Parameters
    ----------
    n_bins : int
        Bins per column, at least 2.

    Attributes
    ----------
    edges_ : list of ndarray
        Inner bin edges per column (``len(edges_[j]) + 1`` indicators for column ``j``).
    """

    def __init__(self, n_bins: int = 6):
        self.n_bins = n_bins

    def fit(self, F):
        """Fit the bin edges on the training rectangles' features ``F`` (n, k)."""
        F = np.asarray(F, dtype=np.float64)
        if F.ndim != 2 or len(F) == 0:
            raise ValueError(f"physical features must be a non-empty (n, k) array, got shape "
                             f"{F.shape}")
        if not np.isfinite(F).all():
            raise ValueError("physical features contain non-finite values")
        if int(self.n_bins) < 2:
            raise ValueError(f"n_bins must be >= 2, got {self.n_bins}")
        q = np.linspace(0.0, 1.0, int(self.n_bins) + 1)[1:-1]
        self.edges_ = []
        for j in range(F.shape[1]):  # an edge at the minimum would leave its lower bin empty
            e = np.unique(np.quantile(F[:, j], q))
            self.edges_.append(e[e > F[:, j].min()])
        return self

    @property
    def n_output(self) -> int:
        return int(sum(len(e) + 1 for e in self.edges_))

    def transform(self, F) -> np.ndarray:
        """One-hot bin indicators, shape ``(n, n_output)``, float32."""
        F = np.asarray(F, dtype=np.float64)
        if F.ndim != 2 or F.shape[1] != len(self.edges_):
            raise ValueError(f"expected physical features of shape (n, {len(self.edges_)}), "
                             f"got {F.shape}")
        out = np.zeros((len(F), self.n_output), dtype=np.float32)
        start = 0
        rows = np.arange(len(F))
        for j, e in enumerate(self.edges_):
            out[rows, start + np.searchsorted(e, F[:, j], side="right")] = 1.0
            start += len(e) + 1
        return out
