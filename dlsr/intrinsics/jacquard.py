"""The Jacquard renders' camera, estimated from the jaw sizes of their grasp files.

Part of :mod:`dlsr.intrinsics`.
"""

from __future__ import annotations

import numpy as np

from .matrix import camera_matrix

__all__ = ["JACQUARD_FOCAL_PX", "JACQUARD_JAW_SIZES_M", "focal_from_jaw_sizes",
           "jacquard_camera_matrix"]

JACQUARD_JAW_SIZES_M = (0.01, 0.02, 0.03, 0.04, 0.06)
"""The jaw sizes of the Jacquard paper's simulated gripper, metres."""

JACQUARD_FOCAL_PX = 1900.0
"""Focal length of the Jacquard renders (1024 x 1024), pixels: :func:`focal_from_jaw_sizes`
pooled over the 28 sample views (perfect depth): 1900.2 px; the views' own estimates range
from 1879 to 1911 px."""


def jacquard_camera_matrix(shape=(1024, 1024)) -> np.ndarray:
    """The estimated camera matrix of a Jacquard render of ``shape`` (H, W): the focal length
    :data:`JACQUARD_FOCAL_PX` scaled from 1024 px wide, the principal point at the centre."""
    H, W = int(shape[0]), int(shape[1])
    s = W / 1024.0
    return camera_matrix(JACQUARD_FOCAL_PX * s, JACQUARD_FOCAL_PX * s, (W - 1) / 2, (H - 1) / 2)


def focal_from_jaw_sizes(jaw_px, depth_m, sizes_m=JACQUARD_JAW_SIZES_M) -> float:
    """Focal length (pixels) from jaw sizes in pixels at known depths, the metric sizes being
    from a known set.

    ``jaw_px * depth_m`` is ``f`` times a size of ``sizes_m``; each product is assigned the
    size whose multiple of a first guess (the 2nd percentile of the products over the smallest
    size) is nearest, and ``f`` is the median of ``product / size``, refined three times.

    Parameters
    ----------
    jaw_px : array-like of shape (n,)
        Jaw sizes, pixels (Jacquard's ``jaw_size``).
    depth_m : array-like of shape (n,)
        Depth at each grasp centre, metres (missing: <= 0 or non-finite, ignored).
    sizes_m : sequence of float
        The metric jaw sizes.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        With no grasp at a valid depth.
    """
    h = np.asarray(jaw_px, dtype=float).ravel()
    z = np.asarray(depth_m, dtype=float).ravel()
    sizes = np.asarray(sizes_m, dtype=float)
    ok = np.isfinite(h) & np.isfinite(z) & (z > 0) & (h > 0)
    if not ok.any():
        raise ValueError("no grasp at a valid depth to estimate a focal length from")
    v = h[ok] * z[ok]
    f = float(np.percentile(v, 2) / sizes.min())  # the smallest jaws are the commonest
    for _ in range(3):
        size = sizes[np.argmin(np.abs(v[:, None] - f * sizes[None, :]), axis=1)]
        f = float(np.median(v / size))
    return f
