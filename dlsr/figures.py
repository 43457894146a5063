"""A picture in the spirit of the paper's Figure 3: from a grasp rectangle to its 24 x 24 image.

Panels: the rectangle drawn on the view (jaw plates blue, opening edges red, as
:mod:`dlsr.viz`), the full-resolution rotated crop (RGB and depth) with the closing direction
horizontal, and the padded ``size x size`` result of :func:`dlsr.preprocess.rectangle_images`
shown as K, RGB, D and the normals (``(N + 1) / 2`` as RGB); masked entries are drawn in a
checker-free flat magenta so padding and missing depth stand out.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .preprocess import rectangle_images, rotated_crop  # noqa: E402
from .rectangles import GraspRectangle, as_rect_array, corners_from_array  # noqa: E402

__all__ = ["crop_figure"]

_MASKED = np.array([1.0, 0.0, 1.0])  # magenta
_JAW = "#0000ff"
_OPENING = "#ff0000"


def _paint(values, mask):
    """RGB float image with masked pixels magenta; ``values`` (h, w, 3) in [0, 1]."""
    out = np.clip(values, 0.0, 1.0).copy()
    out[~mask] = _MASKED
    return out


def _gray(values, mask, lo=None, hi=None):
    v = values.astype(float)
    if lo is None:
        lo = v[mask].min() if mask.any() else 0.0
        hi = v[mask].max() if mask.any() else 1.0
    span = hi - lo if hi > lo else 1.0
    g = (v - lo) / span
    return _paint(np.repeat(g[..., None], 3, axis=2), mask)


def crop_figure(rgb, depth, depth_valid, rect, path, *, size: int = 24, depth_scale=1000.0,
                margin: float = 1.0, dpi: int = 150, title: str | None = None) -> Path:
    """Draw the rectangle-to-image pipeline for one rectangle and save it as a PNG.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3), uint8
    depth : ndarray of shape (H, W)
        Metres, 0 where missing.
    depth_valid : ndarray of shape (H, W), bool, or None
    rect : GraspRectangle or array-like of shape (5,)
    path : str or Path
        Output PNG; parent folders are created.
    size : int, default=24
    depth_scale : float, default=1000.0
        As in :func:`dlsr.preprocess.rectangle_images`.
    margin : float, default=1.0
        The first panel shows the rectangle's surroundings, ``margin`` times its longer side
        around it.
    dpi : int, default=150
    title : str or None

    Returns
    -------
    Path
        The written file.
    """
    arr = as_rect_array(rect if not isinstance(rect, GraspRectangle) else [rect])
    if len(arr) != 1:
        raise ValueError(f"crop_figure takes one rectangle, got {len(arr)}")
    full, imask, dmask = rotated_crop(rgb, depth, depth_valid, arr, depth_scale=depth_scale)
    ims, mks = rectangle_images(rgb, depth, depth_valid, arr, size=size, depth_scale=depth_scale)
    im, mk = ims[0], mks[0]

    fig, axes = plt.subplots(2, 4, figsize=(12, 7.2))
    # (a) the view around the rectangle
    ax = axes[0, 0]
    H, W = np.asarray(rgb).shape[:2]
    x, y, _, w, h = arr[0]
    half = (1 + margin) * max(w, h) / 2
    ax.imshow(rgb)
    pts = corners_from_array(arr)[0]
    for a, b, colour in ((0, 1, _OPENING), (1, 2, _JAW), (2, 3, _OPENING), (3, 0, _JAW)):
        ax.plot(*np.stack([pts[a], pts[b]]).T, color=colour, lw=2)
    ax.plot([x], [y], "+", color="yellow", ms=8)
    ax.set_xlim(max(0, x - half) - 0.5, min(W, x + half) - 0.5)
    ax.set_ylim(min(H, y + half) - 0.5, max(0, y - half) - 0.5)
    ax.set_title("rectangle on the view\n(blue: jaws, red: opening)", fontsize=9)
    # (b, c) full-resolution rotated crop
    axes[0, 1].imshow(_paint(full[..., 1:4], imask), interpolation="nearest")
    axes[0, 1].set_title(f"rotated crop, RGB\n{full.shape[1]} x {full.shape[0]} px "
                         "(jaws left/right)", fontsize=9)
    axes[0, 2].imshow(_gray(full[..., 4], dmask), interpolation="nearest")
    axes[0, 2].set_title("rotated crop, depth - mean\n(magenta: invalid/outlier)", fontsize=9)
    axes[0, 3].imshow(_paint((full[..., 5:8] + 1) / 2, np.ones_like(dmask)),
                      interpolation="nearest")
    axes[0, 3].set_title("rotated crop, normals\n(from hole-filled depth)", fontsize=9)
    # (d) the size x size result, four panels
    imask24 = mk[..., 0]
    dmask24 = mk[..., 4]
    axes[1, 0].imshow(_gray(im[..., 0], imask24, 0.0, 1.0), interpolation="nearest")
    axes[1, 0].set_title(f"{size}x{size}: K (magenta: masked)", fontsize=9)
    axes[1, 1].imshow(_paint(im[..., 1:4], imask24), interpolation="nearest")
    axes[1, 1].set_title(f"{size}x{size}: RGB", fontsize=9)
    axes[1, 2].imshow(_gray(im[..., 4], dmask24), interpolation="nearest")
    axes[1, 2].set_title(f"{size}x{size}: D", fontsize=9)
    axes[1, 3].imshow(_paint((im[..., 5:8] + 1) / 2, dmask24), interpolation="nearest")
    axes[1, 3].set_title(f"{size}x{size}: normals (N+1)/2", fontsize=9)
    for a in axes.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle(title or (f"rectangle x={x:.1f} y={y:.1f} theta={np.degrees(arr[0, 2]):.1f} deg "
                           f"w={w:.1f} h={h:.1f}"), fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
