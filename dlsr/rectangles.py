"""Oriented grasp rectangles.

Conventions (shared with the Cornell/Jacquard evaluation code of GG-CNN and GR-ConvNet, so
numbers are comparable):

* image coordinates: ``x`` is the column, ``y`` the row, rows grow downward; pixels.
* ``theta`` is the angle of the *closing direction* (the direction the jaws move along) from the
  image x axis, counter-clockwise **as the image is displayed** (so a positive angle points up
  and to the right), in radians, normalised to ``[-pi/2, pi/2)``.
* ``w`` is the gripper opening (distance between the jaws, along the closing direction) and ``h``
  the jaw size (across it).
* Corners follow the Cornell order: ``p0 -> p1`` is an edge along the closing direction (length
  ``w``), ``p1 -> p2`` an edge across it (length ``h``).

The vectorised form is an ``(n, 5)`` float array with columns ``(x, y, theta, w, h)``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "GraspRectangle",
    "normalize_angle",
    "rects_to_array",
    "array_to_rects",
    "corners_from_array",
    "array_from_corners",
]

_HALF_PI = np.pi / 2


def normalize_angle(theta):
    """Wrap angles (radians) to ``[-pi/2, pi/2)``; a rectangle is symmetric under a half turn.

    Parameters
    ----------
    theta : float or ndarray

    Returns
    -------
    float or ndarray of the same shape.
    """
    wrapped = np.mod(np.asarray(theta, dtype=float) + _HALF_PI, np.pi) - _HALF_PI
    # np.mod can return exactly pi for tiny negative inputs; fold that back.
    wrapped = np.where(wrapped >= _HALF_PI, wrapped - np.pi, wrapped)
    if np.ndim(wrapped) == 0:
        return float(wrapped)
    return wrapped


def _axes(theta):
    """Unit vectors along (u) and across (v) the closing direction, in (x, y) image coordinates."""
    c, s = np.cos(theta), np.sin(theta)
    u = np.stack([c, -s], axis=-1)  # closing direction; y flips because rows grow downward
    v = np.stack([s, c], axis=-1)  # perpendicular, p1 -> p2
    return u, v


@dataclass(frozen=True)
class GraspRectangle:
    """An oriented grasp rectangle in pixels and radians (see the module docstring).

    Parameters
    ----------
    x, y : float
        Centre column and row, pixels.
    theta : float
        Angle of the closing direction, radians; normalised to ``[-pi/2, pi/2)`` on construction.
    w : float
        Gripper opening, pixels (> 0).
    h : float
        Jaw size, pixels (> 0).
    """

    x: float
    y: float
    theta: float
    w: float
    h: float

    def __post_init__(self):
        values = (self.x, self.y, self.theta, self.w, self.h)
        if not all(np.isfinite(v) for v in values):
            raise ValueError(f"GraspRectangle needs finite values, got {values}")
        if self.w <= 0 or self.h <= 0:
            raise ValueError(
                f"GraspRectangle needs a positive opening and jaw size, got w={self.w}, h={self.h}"
            )
        for name in ("x", "y", "w", "h"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "theta", normalize_angle(self.theta))

    @classmethod
    def from_corners(cls, pts) -> GraspRectangle:
        """Build from a ``(4, 2)`` array of ``(x, y)`` corners in Cornell order.

        Raises
        ------
        ValueError
            If the corners are not finite or the rectangle is degenerate.
        """
        pts = np.asarray(pts, dtype=float)
        if pts.shape != (4, 2):
            raise ValueError(f"corners must have shape (4, 2), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError(f"corners must be finite, got {pts.tolist()}")
        return cls(*array_from_corners(pts[None])[0])

    def corners(self) -> np.ndarray:
        """The ``(4, 2)`` corners ``(x, y)`` in Cornell order; inverse of :meth:`from_corners`."""
        return corners_from_array(self.as_array()[None])[0]

    def as_array(self) -> np.ndarray:
        """``(5,)`` array ``(x, y, theta, w, h)``."""
        return np.array([self.x, self.y, self.theta, self.w, self.h])

    @property
    def center(self) -> tuple[float, float]:
        return (self.x, self.y)

    @property
    def area(self) -> float:
        return self.w * self.h

    def scaled(self, factor: float, factor_y: float | None = None) -> GraspRectangle:
        """The same rectangle in an image resized by ``factor``.

        Centres map like the pixel grid of ``cv2.resize`` (pixel centres at integer
        coordinates): ``x' = (x + 0.5) * sx - 0.5``, and likewise for ``y`` with ``factor_y``
        (default ``factor``, for a resize whose rounding makes the two axes differ slightly);
        sizes scale by ``factor``.
        """
        sy = factor if factor_y is None else factor_y
        return GraspRectangle(
            (self.x + 0.5) * factor - 0.5, (self.y + 0.5) * sy - 0.5, self.theta,
            self.w * factor, self.h * factor,
        )


def rects_to_array(rects: Iterable[GraspRectangle]) -> np.ndarray:
    """Stack rectangles into an ``(n, 5)`` float array (``(0, 5)`` when empty)."""
    rows = [r.as_array() for r in rects]
    if not rows:
        return np.zeros((0, 5))
    return np.stack(rows)


def _as_rect_array(arr) -> np.ndarray:
    arr = np.asarray(arr, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == 5:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 5:
        raise ValueError(f"rectangle arrays must have shape (n, 5), got {arr.shape}")
    return arr


def array_to_rects(arr) -> list[GraspRectangle]:
    """Inverse of :func:`rects_to_array`."""
    return [GraspRectangle(*row) for row in _as_rect_array(arr)]


def corners_from_array(arr) -> np.ndarray:
    """Corners of many rectangles.

    Parameters
    ----------
    arr : array-like of shape (n, 5)
        ``(x, y, theta, w, h)`` rows.

    Returns
    -------
    ndarray of shape (n, 4, 2)
        ``(x, y)`` corners in Cornell order.
    """
    arr = _as_rect_array(arr)
    c = arr[:, None, :2]
    u, v = _axes(arr[:, 2])
    hw = (arr[:, 3] / 2)[:, None]
    hh = (arr[:, 4] / 2)[:, None]
    du = (u * hw)[:, None, :]
    dv = (v * hh)[:, None, :]
    signs_u = np.array([-1.0, 1.0, 1.0, -1.0])[None, :, None]
    signs_v = np.array([-1.0, -1.0, 1.0, 1.0])[None, :, None]
    return c + signs_u * du + signs_v * dv


def array_from_corners(pts) -> np.ndarray:
    """Rectangles from corners in Cornell order.

    Parameters
    ----------
    pts : array-like of shape (n, 4, 2)

    Returns
    -------
    ndarray of shape (n, 5)
        ``(x, y, theta, w, h)``; the centre is the mean of the corners, ``w = |p1 - p0|``,
        ``h = |p2 - p1|`` and ``theta = atan2(-(y1 - y0), x1 - x0)`` wrapped.
    """
    pts = np.asarray(pts, dtype=float)
    if pts.ndim != 3 or pts.shape[1:] != (4, 2):
        raise ValueError(f"corner arrays must have shape (n, 4, 2), got {pts.shape}")
    centre = pts.mean(axis=1)
    d01 = pts[:, 1] - pts[:, 0]
    d12 = pts[:, 2] - pts[:, 1]
    theta = normalize_angle(np.arctan2(-d01[:, 1], d01[:, 0]))
    w = np.hypot(d01[:, 0], d01[:, 1])
    h = np.hypot(d12[:, 0], d12[:, 1])
    return np.column_stack([centre, np.atleast_1d(theta), w, h])


def as_rect_array(rects: Sequence[GraspRectangle] | np.ndarray) -> np.ndarray:
    """Accept a list of :class:`GraspRectangle`, one rectangle, or an ``(n, 5)`` array."""
    if isinstance(rects, GraspRectangle):
        return rects.as_array()[None]
    if isinstance(rects, np.ndarray):
        return _as_rect_array(rects)
    rects = list(rects)
    if rects and isinstance(rects[0], GraspRectangle):
        return rects_to_array(rects)
    if not rects:
        return np.zeros((0, 5))
    return _as_rect_array(rects)
