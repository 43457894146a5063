"""GG-CNN's pixel maps (numpy only): label maps drawn from rectangles, rectangles read back from
predicted maps, the depth preprocessing and the crop taken from the observation alone.

Facts from Morrison, Corke and Leitner, "Closing the Loop for Robotic Grasping" (RSS 2018)
and its authors' description; the code is this project's.

Angle convention
----------------
GG-CNN's grasp angle is the direction in which the jaws close, measured counter-clockwise as
the image is displayed, modulo pi; it is encoded as ``(cos 2 phi, sin 2 phi)`` so that ``phi``
and ``phi + pi`` are the same grasp. This project's ``theta`` (:mod:`dlsr.rectangles`) is the
same direction measured the same way, so ``phi = theta`` exactly; :func:`gg_angle` and
:func:`our_angle` make the mapping explicit (and are where a change of convention would go).
The opening ``w`` is GG-CNN's grasp width (pixels, encoded ``w / width_scale``); GG-CNN has no
jaw size, so a read-out rectangle gets ``h = w / 2``.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter, maximum_filter, minimum_filter

from dlsr.datasets import inpaint_depth
from dlsr.detection import table_plane_mask
from dlsr.rectangles import normalize_angle, rects_to_array

__all__ = [
    "WIDTH_SCALE",
    "gg_angle",
    "our_angle",
    "grasp_maps",
    "decode_maps",
    "prepare_depth",
    "prepare_rgb",
    "crop_box",
]

#: Width maps hold the opening divided by this many pixels (GG-CNN's 150).
WIDTH_SCALE = 150.0


def gg_angle(theta):
    """GG-CNN's grasp angle of this project's ``theta`` (both radians, CCW as displayed).

    Parameters
    ----------
    theta : float or ndarray
        Closing direction (:mod:`dlsr.rectangles`).

    Returns
    -------
    float or ndarray
        GG-CNN's angle in ``[-pi/2, pi/2)``: the same direction (see the module docstring).
    """
    return normalize_angle(theta)


def our_angle(phi):
    """This project's ``theta`` of GG-CNN's grasp angle ``phi`` (the inverse of
    :func:`gg_angle`), in ``[-pi/2, pi/2)``."""
    return normalize_angle(phi)


def _as_rects(rects) -> np.ndarray:
    if isinstance(rects, np.ndarray):
        arr = np.asarray(rects, dtype=np.float64).reshape(-1, 5)
    else:
        arr = rects_to_array(list(rects)) if len(rects) else np.zeros((0, 5))
    return arr


def grasp_maps(rects, shape, width_scale: float = WIDTH_SCALE, fraction: float = 1 / 3,
               clip_width: bool = False):
    """GG-CNN's training targets: quality, cos 2 phi, sin 2 phi and width maps.

    Every pixel inside the centre ``fraction`` of a rectangle along its opening axis (and
    across its whole jaw size) gets ``Q = 1``, the rectangle's ``cos 2 phi``, ``sin 2 phi`` and
    ``w / width_scale``; every other pixel is 0 ("not a grasp"). Where rectangles overlap the
    later one wins.

    Parameters
    ----------
    rects : list of GraspRectangle or ndarray of shape (n, 5)
        Positive rectangles ``(x, y, theta, w, h)`` in pixels and radians.
    shape : (int, int)
        ``(H, W)`` of the maps.
    width_scale : float
        Pixels that map to a width value of 1.
    fraction : float
        Part of the opening that is labelled (GG-CNN's one third).
    clip_width : bool
        Width values above 1 are set to 1 (GR-ConvNet's labels; GG-CNN's are not clipped).

    Returns
    -------
    ndarray of shape (4, H, W), float32
        ``Q``, ``cos 2 phi``, ``sin 2 phi``, ``width``.
    """
    H, W = (int(v) for v in shape)
    out = np.zeros((4, H, W), dtype=np.float32)
    arr = _as_rects(rects)
    for x, y, theta, w, h in arr:
        phi = gg_angle(theta)
        c, s = np.cos(phi), np.sin(phi)
        half_u, half_v = fraction * w / 2, h / 2
        reach = np.hypot(half_u, half_v)
        r0, r1 = max(int(np.floor(y - reach)), 0), min(int(np.ceil(y + reach)) + 1, H)
        c0, c1 = max(int(np.floor(x - reach)), 0), min(int(np.ceil(x + reach)) + 1, W)
        if r0 >= r1 or c0 >= c1:
            continue
        rr, cc = np.mgrid[r0:r1, c0:c1]
        dx, dy = cc - x, rr - y
        u = dx * c - dy * s  # along the closing direction (rows grow downward)
        v = dx * s + dy * c  # across it
        inside = (np.abs(u) <= half_u + 1e-9) & (np.abs(v) <= half_v + 1e-9)
        width = min(w / width_scale, 1.0) if clip_width else w / width_scale
        for k, value in enumerate((1.0, np.cos(2 * phi), np.sin(2 * phi), width)):
            out[k, r0:r1, c0:c1][inside] = value
    return out


def decode_maps(maps, n: int = 1, sigma: float = 2.0, width_scale: float = WIDTH_SCALE,
                min_distance: int = 10, threshold: float | None = None):
    """Rectangles read from GG-CNN's maps: the highest peaks of the filtered quality map.

    ``Q`` and the ``cos``/``sin`` maps are Gaussian-filtered (the angle comes from the filtered
    cos and sin maps, not from a filtered angle image, which would average across the wrap at
    +-90 deg); the peaks are local maxima at least ``min_distance`` pixels apart, best first.

    Parameters
    ----------
    maps : ndarray of shape (4, H, W)
        ``Q``, ``cos 2 phi``, ``sin 2 phi``, ``width`` (as :func:`grasp_maps`).
    n : int
        Rectangles returned at most.
    sigma : float
        Gaussian filter width, pixels (0: none).
    width_scale : float
        As :func:`grasp_maps`.
    min_distance : int
        Peaks closer than this many pixels to a higher one are dropped.
    threshold : float or None
        Peaks of filtered ``Q`` at or below this are dropped (None: none is; GG-CNN takes the
        best peak whatever its value).

    Returns
    -------
    rects : ndarray of shape (m, 5), m <= n
        ``(x, y, theta, w, h)``, pixels and radians (``h = w / 2``), best first.
    scores : ndarray of shape (m,)
        Filtered ``Q`` at the peaks.
    """
    maps = np.asarray(maps, dtype=np.float64)
    if maps.ndim != 3 or maps.shape[0] != 4:
        raise ValueError(f"GG-CNN maps must have shape (4, H, W), got {maps.shape}")
    if not np.isfinite(maps).all():
        raise ValueError("GG-CNN maps hold NaN or infinite values")
    q, cos2, sin2, width = maps
    if sigma > 0:
        q = gaussian_filter(q, sigma)
        cos2 = gaussian_filter(cos2, sigma)
        sin2 = gaussian_filter(sin2, sigma)
    size = 2 * int(min_distance) + 1
    # local maxima that stand above their neighbourhood (not flat ground), else the best pixel
    peaks = (q == maximum_filter(q, size=size, mode="nearest")) \
        & (q > minimum_filter(q, size=size, mode="nearest"))
    if not peaks.any():
        peaks = np.zeros(q.shape, bool)
        peaks[np.unravel_index(np.argmax(q), q.shape)] = True
    if threshold is not None:
        peaks &= q > threshold
    rows, cols = np.nonzero(peaks)
    order = np.argsort(-q[rows, cols], kind="stable")
    kept: list[tuple[int, int]] = []
    for i in order:  # plateaus give several equal maxima: keep them min_distance apart
        r, c = rows[i], cols[i]
        if all(max(abs(r - a), abs(c - b)) > min_distance for a, b in kept):
            kept.append((r, c))
        if len(kept) == n:
            break
    rects = np.zeros((len(kept), 5))
    scores = np.zeros(len(kept))
    for j, (r, c) in enumerate(kept):
        phi = 0.5 * np.arctan2(sin2[r, c], cos2[r, c])
        w = max(float(width[r, c]) * width_scale, 1.0)
        rects[j] = (c, r, our_angle(phi), w, w / 2)
        scores[j] = q[r, c]
    return rects, scores


def prepare_depth(depth, valid=None) -> np.ndarray:
    """GG-CNN's depth input: missing depth inpainted, mean subtracted, clipped to [-1, 1].

    Missing pixels (``valid`` false, or depth <= 0) are filled by OpenCV's Navier-Stokes
    inpainting after a 1-pixel border pad and scaling the depth into [-1, 1]
    (:func:`dlsr.datasets.inpaint_depth`); the filled depth (metres) has its mean subtracted
    and is clipped to [-1, 1].

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Metres, 0 where missing.
    valid : ndarray of shape (H, W), bool, or None
        Readings; default ``depth > 0``.

    Returns
    -------
    ndarray of shape (H, W), float32

    Raises
    ------
    ValueError
        A depth image that is not 2-D, or has no valid pixel.
    """
    d = inpaint_depth(depth, valid)
    d = d - d[np.isfinite(d)].mean()
    return np.clip(np.nan_to_num(d, nan=0.0), -1.0, 1.0).astype(np.float32)


def prepare_rgb(rgb) -> np.ndarray:
    """GR-ConvNet's colour input: values over 255, minus their mean over the whole image.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3), uint8

    Returns
    -------
    ndarray of shape (3, H, W), float32
        Channels first (R, G, B).

    Raises
    ------
    ValueError
        An image that is not ``(H, W, 3)`` or holds NaN.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be an (H, W, 3) image, got shape {rgb.shape}")
    x = rgb.astype(np.float32) / 255.0
    if not np.isfinite(x).all():
        raise ValueError("the RGB image holds NaN or infinite values")
    x -= x.mean()
    return np.ascontiguousarray(x.transpose(2, 0, 1))


def crop_box(depth, valid=None, size: int = 300, method: str = "object"):
    """The square crop GG-CNN sees, chosen from the observation alone.

    Never from the labels: the published Cornell loaders centre the evaluation crop on the
    ground-truth rectangles, which leaks the answer.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Metres, 0 where missing.
    valid : ndarray of shape (H, W), bool, or None
    size : int
        Side of the crop, pixels (clipped to the image).
    method : {"object", "centre"}
        ``"object"``: centred on the bounding box of the object region found from depth
        (:func:`dlsr.detection.table_plane_mask`; the image centre when none is found);
        ``"centre"``: the image centre.

    Returns
    -------
    (row0, col0, side) : tuple of int
        Top-left corner and side of the crop, inside the image.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D image, got shape {depth.shape}")
    H, W = depth.shape
    side = int(min(size, H, W))
    cy, cx = (H - 1) / 2, (W - 1) / 2
    if method == "object":
        v = (depth > 0) if valid is None else (np.asarray(valid, dtype=bool) & (depth > 0))
        region = table_plane_mask(depth, v) if v.sum() > 100 else np.zeros_like(v)
        if region.any():
            rows, cols = np.nonzero(region)
            cy, cx = (rows.min() + rows.max()) / 2, (cols.min() + cols.max()) / 2
    elif method != "centre":
        raise ValueError(f"crop must be 'object' or 'centre', got {method!r}")
    row0 = int(np.clip(round(cy - (side - 1) / 2), 0, H - side))
    col0 = int(np.clip(round(cx - (side - 1) / 2), 0, W - side))
    return row0, col0, side
