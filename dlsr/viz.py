"""Pictures of grasp rectangles in the look of the paper's Figure 1.

Each rectangle is drawn as four anti-aliased edges: the two **jaw plates** (the edges of length
``h``, across the closing direction) in blue and the two **opening edges** (the edges of length
``w``, along the closing direction) in red. Negatives, when given, are drawn underneath in other
colours (yellow jaws, grey opening edges by default) so the positives stay readable.

Colours are RGB triples; images are RGB ``uint8`` arrays (convert to BGR only when writing with
OpenCV; this module writes with Pillow).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from .rectangles import GraspRectangle, as_rect_array, corners_from_array

__all__ = [
    "JAW_COLOR",
    "OPENING_COLOR",
    "NEGATIVE_JAW_COLOR",
    "NEGATIVE_OPENING_COLOR",
    "draw_rectangles",
    "to_rgb8",
    "write_overlays",
    "show_dataset",
]

logger = logging.getLogger(__name__)

JAW_COLOR = (0, 0, 255)  # blue: jaw plates (edges of length h)
OPENING_COLOR = (255, 0, 0)  # red: opening edges (edges of length w)
NEGATIVE_JAW_COLOR = (255, 215, 0)  # yellow
NEGATIVE_OPENING_COLOR = (128, 128, 128)  # grey

_SHIFT = 4  # sub-pixel bits for cv2 drawing (coordinates are multiplied by 2**_SHIFT)


def to_rgb8(image) -> np.ndarray:
    """A copy of ``image`` as an ``(H, W, 3)`` uint8 RGB array.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3) or (H, W)
        uint8 RGB is copied as is; a single channel (e.g. depth) is min-max scaled to grey over
        its finite values, with non-finite pixels black.

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 3:
        if arr.dtype == np.uint8:
            return arr.copy()
        return np.clip(arr, 0, 255).astype(np.uint8)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise ValueError(f"expected an (H, W, 3) or (H, W) image, got shape {arr.shape}")
    arr = arr.astype(float)
    finite = np.isfinite(arr)
    grey = np.zeros(arr.shape, dtype=np.uint8)
    if finite.any():
        lo, hi = arr[finite].min(), arr[finite].max()
        span = hi - lo if hi > lo else 1.0
        grey[finite] = np.round(255 * (arr[finite] - lo) / span).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


def _draw(img, rects, jaw_color, opening_color, thickness):
    arr = as_rect_array(rects)
    if len(arr) == 0:
        return
    pts = np.round(corners_from_array(arr) * (1 << _SHIFT)).astype(np.int64)
    for c in pts:
        # Cornell order: p0->p1 and p2->p3 run along the closing direction (length w, opening
        # edges); p1->p2 and p3->p0 run across it (length h, jaw plates). Jaws go on top.
        for a, b in ((0, 1), (2, 3)):
            cv2.line(img, _pt(c[a]), _pt(c[b]), opening_color, thickness, cv2.LINE_AA, _SHIFT)
        for a, b in ((1, 2), (3, 0)):
            cv2.line(img, _pt(c[a]), _pt(c[b]), jaw_color, thickness, cv2.LINE_AA, _SHIFT)


def _pt(p):
    return (int(p[0]), int(p[1]))


def draw_rectangles(
    rgb,
    rects: Sequence[GraspRectangle] | np.ndarray,
    negatives: Sequence[GraspRectangle] | np.ndarray | None = None,
    *,
    jaw_color=JAW_COLOR,
    opening_color=OPENING_COLOR,
    negative_jaw_color=NEGATIVE_JAW_COLOR,
    negative_opening_color=NEGATIVE_OPENING_COLOR,
    thickness: int | None = None,
) -> np.ndarray:
    """Draw grasp rectangles on a copy of an image (the paper's Figure 1 look).

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3) uint8, or (H, W)
        The image; not modified. Single-channel images are shown in grey (see :func:`to_rgb8`).
    rects : list of GraspRectangle or array of shape (n, 5)
        Rectangles drawn with jaw plates (edges of length ``h``) in ``jaw_color`` and opening
        edges (edges of length ``w``) in ``opening_color``.
    negatives : list of GraspRectangle or array of shape (m, 5), optional
        Drawn first, in ``negative_jaw_color`` / ``negative_opening_color``.
    jaw_color, opening_color, negative_jaw_color, negative_opening_color : tuple of 3 int
        RGB colours.
    thickness : int, optional
        Line width in pixels; defaults to about 1/300 of the image size, at least 1.

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    img = to_rgb8(rgb)
    if thickness is None:
        thickness = max(1, int(round(max(img.shape[:2]) / 300)))
    if thickness < 1:
        raise ValueError(f"thickness must be >= 1, got {thickness}")
    if negatives is not None:
        _draw(img, negatives, tuple(negative_jaw_color), tuple(negative_opening_color), thickness)
    _draw(img, rects, tuple(jaw_color), tuple(opening_color), thickness)
    return img


def _safe_name(image_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(image_id)) or "image"


def write_overlays(samples: Iterable, out_dir, draw_negatives: bool = True) -> list[Path]:
    """Write one PNG per sample with its positives (and negatives) drawn on the RGB image.

    Parameters
    ----------
    samples : iterable of dlsr.datasets.GraspSample
    out_dir : path-like
        Created if missing; files are named ``<image_id>.png``.
    draw_negatives : bool
        Also draw ``sample.negatives`` (in the negative colours).

    Returns
    -------
    list of Path
        The files written, in the order of ``samples``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for s in samples:
        img = draw_rectangles(s.rgb, s.positives, s.negatives if draw_negatives else None)
        path = out_dir / f"{_safe_name(s.image_id)}.png"
        Image.fromarray(img).save(path)
        paths.append(path)
    logger.info("wrote %d overlays to %s", len(paths), out_dir)
    return paths


def show_dataset(
    data, format: str, out_dir, scale: float = 1.0, depth: str = "stereo"
) -> list[Path]:
    """Load a dataset and write its rectangle overlays (the ``graspsim show`` command).

    Parameters
    ----------
    data : path-like
        Dataset root (see :func:`dlsr.datasets.load_cornell` and
        :func:`dlsr.datasets.load_jacquard`).
    format : {"cornell", "jacquard"}
    out_dir : path-like
    scale : float
        Image scale passed to the loader.
    depth : {"stereo", "perfect"}
        Jacquard depth variant (ignored for Cornell).

    Returns
    -------
    list of Path
    """
    from . import datasets

    if format == "cornell":
        samples = datasets.load_cornell(data, scale=scale)
    elif format == "jacquard":
        samples = datasets.load_jacquard(data, depth=depth, scale=scale)
    else:
        raise ValueError(f"unknown dataset format {format!r}; expected 'cornell' or 'jacquard'")
    if not samples:
        raise FileNotFoundError(f"no {format} images found under {data}")
    return write_overlays(samples, out_dir)
