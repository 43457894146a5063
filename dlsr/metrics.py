"""The rectangle metric of Jiang et al. (2011), as used by Lenz et al. (2015) and the paper.

A predicted rectangle is correct when some ground-truth rectangle is within ``max_angle`` of it
(30 degrees; rectangles are pi-periodic) **and** their Jaccard index (intersection over union of
the two polygons) is strictly above ``min_jaccard`` (0.25).

Jaccard indices are exact polygon computations (shapely/GEOS, vectorised), never rasterised.
"""

from __future__ import annotations

import numpy as np
import shapely

from .rectangles import as_rect_array, corners_from_array

__all__ = [
    "angle_difference",
    "jaccard",
    "jaccard_matrix",
    "rectangle_metric",
    "rectangle_metric_many",
]

MAX_ANGLE = np.pi / 6
MIN_JACCARD = 0.25


def angle_difference(a, b):
    """Smallest difference between rectangle angles, pi-periodic, in ``[0, pi/2]`` (radians).

    Accepts scalars, arrays (broadcast) or :class:`~dlsr.rectangles.GraspRectangle` objects.
    """
    a = getattr(a, "theta", a)
    b = getattr(b, "theta", b)
    d = np.mod(np.asarray(a, dtype=float) - np.asarray(b, dtype=float), np.pi)
    d = np.minimum(d, np.pi - d)
    return float(d) if d.ndim == 0 else d


def _polygons(arr: np.ndarray):
    return shapely.polygons(corners_from_array(arr))


def jaccard(a, b) -> float:
    """Exact Jaccard index (intersection over union) of two rectangles."""
    return float(jaccard_matrix(a, b)[0, 0])


def _pairwise_jaccard(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Jaccard index of row i of ``A`` with row i of ``B`` (both ``(n, 5)``)."""
    if len(A) == 0:
        return np.zeros(0)
    pa, pb = _polygons(A), _polygons(B)
    inter = shapely.area(shapely.intersection(pa, pb))
    union = A[:, 3] * A[:, 4] + B[:, 3] * B[:, 4] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def _may_overlap(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(n, m) mask of pairs whose circumscribed circles intersect (a cheap exact pre-filter)."""
    ra = 0.5 * np.hypot(A[:, 3], A[:, 4])
    rb = 0.5 * np.hypot(B[:, 3], B[:, 4])
    d = np.hypot(A[:, None, 0] - B[None, :, 0], A[:, None, 1] - B[None, :, 1])
    return d < ra[:, None] + rb[None, :]


def jaccard_matrix(preds, truths) -> np.ndarray:
    """Exact Jaccard index of every prediction against every truth.

    Parameters
    ----------
    preds, truths : list of GraspRectangle, GraspRectangle or array of shape (n, 5) / (m, 5)

    Returns
    -------
    ndarray of shape (n, m), float64 in [0, 1].
    """
    A, B = as_rect_array(preds), as_rect_array(truths)
    out = np.zeros((len(A), len(B)))
    ii, jj = np.nonzero(_may_overlap(A, B))
    out[ii, jj] = _pairwise_jaccard(A[ii], B[jj])
    return out


def rectangle_metric_many(
    preds, truths, max_angle: float = MAX_ANGLE, min_jaccard: float = MIN_JACCARD
) -> np.ndarray:
    """The rectangle metric for many predictions against the same truths.

    Parameters
    ----------
    preds : list of GraspRectangle or array of shape (n, 5)
    truths : list of GraspRectangle or array of shape (m, 5)
    max_angle : float
        Largest accepted angle difference, radians (inclusive).
    min_jaccard : float
        Jaccard index that must be strictly exceeded.

    Returns
    -------
    ndarray of shape (n,), bool
        True where some truth is within ``max_angle`` and overlaps by more than ``min_jaccard``.
        With no truths every prediction is wrong.
    """
    A, B = as_rect_array(preds), as_rect_array(truths)
    ok = np.zeros(len(A), dtype=bool)
    if len(A) == 0 or len(B) == 0:
        return ok
    close = angle_difference(A[:, None, 2], B[None, :, 2]) <= max_angle + 1e-12
    close &= _may_overlap(A, B)
    ii, jj = np.nonzero(close)
    if len(ii):
        hit = _pairwise_jaccard(A[ii], B[jj]) > min_jaccard
        ok[ii[hit]] = True
    return ok


def rectangle_metric(
    pred, truths, max_angle: float = MAX_ANGLE, min_jaccard: float = MIN_JACCARD
) -> bool:
    """True when ``pred`` is within ``max_angle`` of some truth with Jaccard > ``min_jaccard``."""
    return bool(rectangle_metric_many(pred, truths, max_angle, min_jaccard)[0])
