"""From an image grasp rectangle to a 6-DoF gripper pose (pure numpy, no pybullet).

Conventions
-----------
* Units: metres and radians; pixels for the rectangle.
* ``T_world_cam`` (4x4) maps camera coordinates (OpenCV: x right, y down, z forward) to world
  coordinates; ``T_world_grasp`` maps grasp-frame coordinates to world coordinates.
* Grasp frame (= the gripper's TCP frame, see :mod:`graspsim.sim.gripper`): origin at the grasp
  centre, ``z`` the approach direction (the camera's optical axis), ``x`` the closing direction
  (the rectangle's ``theta`` mapped into the plane perpendicular to the optical axis),
  ``y = z x x``.

The grasp centre is the rectangle centre back-projected at a robust depth -- the median of the
valid depth in the rectangle's central region (the rectangle shrunk to half its opening and half
its jaw size) -- pushed ``depth_offset`` further along the approach so the pads straddle the
object's top rather than touch it, but never so deep that the palm, ``PALM_OFFSET`` (4 cm)
behind the grasp centre, comes within ``palm_clearance`` of the nearest surface seen anywhere in
the rectangle or under the palm (:func:`nearest_depth`, a low percentile of the valid depth,
robust to a few noisy pixels, over the rectangle and over the palm's footprint, ``PALM_LENGTH``
x ``PALM_WIDTH`` about the centre, measured at the surface depth): over an open mug or an
upright bottle's shoulder the median lies far below the rim or the cap, and a gripper with 5 cm
fingers cannot reach that deep around them; a small rectangle on a mug's wall leaves the rest of
the rim under the 11 cm palm. The opening is
``w z / f`` (the rectangle's opening measured at that depth) plus ``margin``. When the central
region holds no valid depth at all, the fallback is explicit: no pose is computed and the grasp
carries the failure reason ``"depth missing at the centre"``; when ``w z / f`` exceeds the
gripper's largest opening, the pose is computed but the reason is ``"too wide for the gripper"``.
Executors do not run a grasp that carries a failure reason.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dlsr.datasets import check_camera_matrix
from dlsr.rectangles import GraspRectangle

from .hands import BUILTIN

__all__ = [
    "Grasp",
    "rectangle_to_grasp",
    "central_depth",
    "nearest_depth",
    "fingers_collide",
    "settle_fingers",
    "table_plane_depth",
    "DEPTH_MISSING",
    "TOO_WIDE",
]

DEPTH_MISSING = "depth missing at the centre"
TOO_WIDE = "too wide for the gripper"


@dataclass(frozen=True)
class Grasp:
    """A parallel-jaw grasp in the world.

    Attributes
    ----------
    T_world_grasp : ndarray of shape (4, 4) or None
        Grasp (TCP) pose; None when no depth was available (see ``failure``).
    opening : float
        Opening to command before closing, metres (``width + margin``, at most ``max_opening``).
    width : float
        The rectangle's opening measured at the grasp depth, ``w z / f``, metres.
    depth : float
        Camera-frame depth of the surface under the centre, metres (nan when missing).
    rect : GraspRectangle
        The rectangle it came from.
    failure : str or None
        ``"depth missing at the centre"`` or ``"too wide for the gripper"``; None when executable.
    """

    T_world_grasp: np.ndarray | None
    opening: float
    width: float
    depth: float
    rect: GraspRectangle
    failure: str | None = None

    @property
    def approach(self) -> np.ndarray | None:
        """Unit approach direction in the world, (3,)."""
        return None if self.T_world_grasp is None else self.T_world_grasp[:3, 2].copy()

    @property
    def position(self) -> np.ndarray | None:
        return None if self.T_world_grasp is None else self.T_world_grasp[:3, 3].copy()

    def to_dict(self) -> dict:
        """JSON-friendly summary (pose as a nested list)."""
        return {
            "T_world_grasp": None if self.T_world_grasp is None
            else np.round(self.T_world_grasp, 6).tolist(),
            "opening": round(float(self.opening), 6),
            "width": round(float(self.width), 6),
            "depth": None if not np.isfinite(self.depth) else round(float(self.depth), 6),
            "failure": self.failure,
        }


def _region_depths(rect: GraspRectangle, depth, valid, fraction: float) -> np.ndarray:
    """Valid depths (metres, 1-D) inside the rectangle scaled by ``fraction`` about its centre
    (at least the centre pixel is always included)."""
    depth = np.asarray(depth)
    valid = np.asarray(valid, dtype=bool)
    if depth.shape != valid.shape or depth.ndim != 2:
        raise ValueError(f"depth {depth.shape} and valid {valid.shape} must be the same (H, W)")
    H, W = depth.shape
    half_u = max(rect.w * fraction / 2, 0.5)
    half_v = max(rect.h * fraction / 2, 0.5)
    r = int(np.ceil(np.hypot(half_u, half_v))) + 1
    x0, x1 = max(int(np.floor(rect.x)) - r, 0), min(int(np.ceil(rect.x)) + r + 1, W)
    y0, y1 = max(int(np.floor(rect.y)) - r, 0), min(int(np.ceil(rect.y)) + r + 1, H)
    if x0 >= x1 or y0 >= y1:
        return np.empty(0, dtype=float)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    dx, dy = xs - rect.x, ys - rect.y
    c, s = np.cos(rect.theta), np.sin(rect.theta)
    along = dx * c - dy * s  # image closing direction is (cos, -sin) in (x, y)
    across = dx * s + dy * c
    inside = (np.abs(along) <= half_u) & (np.abs(across) <= half_v)
    sel = inside & valid[y0:y1, x0:x1] & (depth[y0:y1, x0:x1] > 0)
    return depth[y0:y1, x0:x1][sel].astype(float)


def central_depth(rect: GraspRectangle, depth, valid, fraction: float = 0.5) -> float:
    """Median valid depth inside the rectangle's central region.

    Parameters
    ----------
    rect : GraspRectangle
    depth : ndarray of shape (H, W), float
        Metres.
    valid : ndarray of shape (H, W), bool
    fraction : float
        The central region is the rectangle scaled by this factor about its centre (at least the
        centre pixel is always included).

    Returns
    -------
    float
        Metres; ``nan`` when the region has no valid pixel.
    """
    d = _region_depths(rect, depth, valid, fraction)
    return float(np.median(d)) if d.size else float("nan")


def nearest_depth(rect: GraspRectangle, depth, valid, percentile: float = 5.0) -> float:
    """The nearest surface seen in the whole rectangle: a low percentile of its valid depth.

    Parameters
    ----------
    rect : GraspRectangle
    depth : ndarray of shape (H, W), float
        Metres.
    valid : ndarray of shape (H, W), bool
    percentile : float
        In [0, 100]; a few percent ignores isolated noisy pixels but keeps a rim or a cap that
        covers a small part of the rectangle.

    Returns
    -------
    float
        Metres; ``nan`` when the rectangle has no valid pixel.
    """
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f"percentile must be in [0, 100], got {percentile}")
    d = _region_depths(rect, depth, valid, 1.0)
    return float(np.percentile(d, percentile)) if d.size else float("nan")


def rectangle_to_grasp(
    rect: GraspRectangle,
    depth,
    valid,
    intrinsics,
    T_world_cam,
    depth_offset: float = 0.015,
    margin: float = 0.01,
    max_opening: float = 0.08,
    palm_clearance: float = 0.005,
    palm_percentile: float = 2.0,
    geometry=None,
) -> Grasp:
    """Turn an image rectangle into a gripper pose.

    Parameters
    ----------
    rect : GraspRectangle
        Pixels and radians (``x`` column, ``y`` row, ``theta`` closing direction CCW as displayed).
    depth : ndarray of shape (H, W), float32
        Metres, 0 where missing.
    valid : ndarray of shape (H, W), bool
    intrinsics : CameraIntrinsics or ndarray of shape (3, 3)
        Anything with a ``K`` attribute, or ``K`` itself.
    T_world_cam : ndarray of shape (4, 4)
    depth_offset : float
        Metres the grasp centre lies beyond the surface, along the approach (less where the palm
        would come within ``palm_clearance`` of the nearest surface in the rectangle).
    margin : float
        Metres added to the measured width for the commanded opening.
    max_opening : float
        Metres; the gripper's largest opening.
    palm_clearance : float
        Metres the palm (``PALM_OFFSET`` behind the grasp centre) stays short of the nearest
        surface in the rectangle and under the palm's footprint (:func:`nearest_depth`).
    palm_percentile : float
        Percentile of the valid depth under the palm's footprint taken as its nearest surface
        (lower than the rectangle's 5: the footprint is larger, a mug's rim a smaller part of
        it).
    geometry : graspsim.sim.hands.HandGeometry or None
        The hand's palm offset and footprint (None: the built-in hand's).

    Returns
    -------
    Grasp
        With ``failure="depth missing at the centre"`` and no pose when the central region of the
        rectangle has no valid depth; with ``failure="too wide for the gripper"`` when
        ``w z / f > max_opening``.
    """
    K = check_camera_matrix(intrinsics, "intrinsics")
    T_world_cam = np.asarray(T_world_cam, dtype=float)
    if T_world_cam.shape != (4, 4):
        raise ValueError(f"T_world_cam must be 4x4, got shape {T_world_cam.shape}")
    z = central_depth(rect, depth, valid)
    if not np.isfinite(z):
        return Grasp(None, 0.0, float("nan"), float("nan"), rect, DEPTH_MISSING)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    # Closing direction in the camera frame: the image direction (cos, -sin) back-projected onto
    # the plane perpendicular to the optical axis at depth z.
    c, s = np.cos(rect.theta), np.sin(rect.theta)
    d_cam = np.array([c / fx, -s / fy, 0.0])
    width = float(rect.w * z * np.linalg.norm(d_cam))  # = w z / f when fx = fy
    x_cam = d_cam / np.linalg.norm(d_cam)
    z_cam = np.array([0.0, 0.0, 1.0])
    y_cam = np.cross(z_cam, x_cam)
    p_cam = z * np.array([(rect.x - cx) / fx, (rect.y - cy) / fy, 1.0])
    T_cam_grasp = np.eye(4)
    T_cam_grasp[:3, 0], T_cam_grasp[:3, 1], T_cam_grasp[:3, 2] = x_cam, y_cam, z_cam
    # As deep as asked, but the palm stays clear of the nearest surface between the jaws and
    # under the palm (its footprint measured at the surface depth z).
    hand = BUILTIN if geometry is None else geometry
    palm = GraspRectangle(rect.x, rect.y, rect.theta, hand.palm_length * fx / z,
                          hand.palm_width * fy / z)
    nearest = min(nearest_depth(rect, depth, valid),
                  nearest_depth(palm, depth, valid, percentile=palm_percentile))
    reach = min(depth_offset, nearest + hand.palm_offset - palm_clearance - z)
    T_cam_grasp[:3, 3] = p_cam + reach * z_cam
    T_world_grasp = T_world_cam @ T_cam_grasp
    opening = float(min(width + margin, max_opening))
    failure = TOO_WIDE if width > max_opening else None
    return Grasp(T_world_grasp, opening, width, float(z), rect, failure)


def fingers_collide(grasp: Grasp, depth, valid, intrinsics, T_world_cam, table_depth=None,
                    tolerance: float = 0.003, tip_clearance: float = 0.001,
                    samples: tuple[int, int] = (9, 21), geometry=None) -> bool:
    """Whether the open fingers, coming down along the approach, would land on a seen surface.

    A depth-only check a detector can run before proposing a grasp (the gripper's geometry and
    the observation, nothing of the simulator's state): each finger is a column of
    ``FINGER_THICKNESS`` x ``PAD_WIDTH`` (closing direction x across) just outside the opening,
    whose tip ends ``TIP_OFFSET`` beyond the grasp centre, or where the executor stops it, a
    ``tip_clearance`` above the table (:func:`graspsim.sim.execution.clamp_to_table`). Points of the
    column's footprint are projected into the image through the grasp's depth; a valid depth
    there more than ``tolerance`` in front of the tip's final depth is a surface the finger
    meets on the way down ("collision on approach" in simulation).

    Parameters
    ----------
    grasp : Grasp
        From :func:`rectangle_to_grasp` (a grasp without a pose collides: True).
    depth : ndarray of shape (H, W), float
        Metres, 0 where missing.
    valid : ndarray of shape (H, W), bool
    intrinsics : CameraIntrinsics or ndarray of shape (3, 3)
    T_world_cam : ndarray of shape (4, 4)
    table_depth : ndarray of shape (H, W) or None
        The table's depth at every pixel, metres (e.g. from
        :func:`dlsr.detection.table_surface`); None: the tip is not clamped (no table seen).
    tolerance, tip_clearance : float
        Metres (``tip_clearance`` as :class:`graspsim.sim.execution.ExecutionParams`).
    samples : (int, int)
        Footprint points per finger along the closing direction and across it. The default
        puts them 1 mm apart over the 8 mm x 20 mm footprint, finer than a pixel at the
        camera's working distance (1.3 mm at 0.7 m with f = 550 px), so a rim or edge inside
        the footprint cannot fall between two samples (the earlier (3, 7), 4 mm and 3.3 mm
        apart, let the gripper-aware detectors choose grasps whose fingers met such edges).
    geometry : graspsim.sim.hands.HandGeometry or None
        The hand's finger thickness, pad width and tip offset (None: the built-in hand's).

    Returns
    -------
    bool
        True also when a footprint point falls outside the image (nothing is known there).
    """
    if grasp.T_world_grasp is None:
        return True
    fp = _finger_footprint(grasp, depth, intrinsics, T_world_cam, samples, geometry)
    if fp is None:
        return True
    d, ok, tip = _footprint_depths(fp, depth, valid, table_depth, tip_clearance)
    return bool(np.any(d[ok] < tip - tolerance))


def _finger_footprint(grasp: Grasp, depth, intrinsics, T_world_cam, samples, geometry=None):
    """Pixels ``(v, u)`` of both fingers' footprints and the fingertips' camera depth before
    any table clamp; None when a point falls outside the image or behind the camera."""
    K = check_camera_matrix(intrinsics, "intrinsics")
    H, W = np.shape(depth)
    T_cam_grasp = np.linalg.inv(np.asarray(T_world_cam, dtype=float)) @ grasp.T_world_grasp
    R, o = T_cam_grasp[:3, :3], T_cam_grasp[:3, 3]
    hand = BUILTIN if geometry is None else geometry
    a = (grasp.opening / 2 + np.linspace(0.0, hand.finger_thickness, samples[0]))[:, None]
    b = np.linspace(-hand.pad_width / 2, hand.pad_width / 2, samples[1])[None, :]
    A = np.concatenate([a, -a]) * np.ones_like(b)
    B = np.ones_like(a.repeat(2, axis=0)) * b
    P = o + A.reshape(-1, 1) * R[:, 0] + B.reshape(-1, 1) * R[:, 1]  # footprint at the TCP
    if P[:, 2].min() <= 0:
        return None
    u = np.rint(K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2]).astype(np.intp)
    v = np.rint(K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]).astype(np.intp)
    if u.min() < 0 or u.max() >= W or v.min() < 0 or v.max() >= H:
        return None
    return v, u, o[2] + hand.tip_offset * R[2, 2], R[2, 2]


def _footprint_depths(fp, depth, valid, table_depth, tip_clearance):
    """The footprint's depths, which of them are valid, and the fingertips' final camera depth
    (clamped ``tip_clearance`` above the table when ``table_depth`` is given)."""
    v, u, tip, _ = fp
    if table_depth is not None:
        tip = min(tip, float(np.min(np.asarray(table_depth)[v, u])) - tip_clearance)
    d = np.asarray(depth)[v, u].astype(float)  # only the footprint's pixels: called per candidate
    ok = np.asarray(valid)[v, u].astype(bool) & np.isfinite(d) & (d > 0)
    return d, ok, tip


def settle_fingers(grasp: Grasp, depth, valid, intrinsics, T_world_cam, table_depth=None,
                   min_grip: float = 0.01, clearance: float = 0.002, tolerance: float = 0.003,
                   tip_clearance: float = 0.001, samples: tuple[int, int] = (9, 21),
                   geometry=None) -> Grasp:
    """Stop the fingers short of a surface they would meet on the way down, if they still grip.

    Where :func:`fingers_collide` finds a surface seen in a finger's footprint more than
    ``tolerance`` in front of where the fingertips end (the bottom of a bowl under the inner
    finger, the plate or the bowl a small object rests on), the grasp is moved back along its
    approach so that the fingertips stop ``clearance`` short of the nearest such surface --
    provided they still reach ``min_grip`` beyond the surface under the rectangle's centre
    (``grasp.depth``). Otherwise, or when nothing is in the way, the grasp is returned unchanged
    (and :func:`fingers_collide` still finds the collision). The opening and the closing
    direction are kept. Like the fingers check, only the depth image is used.

    Parameters
    ----------
    grasp : Grasp
        From :func:`rectangle_to_grasp` (returned as it is when it has no pose or a failure).
    depth : ndarray of shape (H, W), float
        Metres, 0 where missing.
    valid : ndarray of shape (H, W), bool
    intrinsics : CameraIntrinsics or ndarray of shape (3, 3)
    T_world_cam : ndarray of shape (4, 4)
    table_depth : ndarray of shape (H, W) or None
        The table's camera depth at every pixel, metres (:func:`table_plane_depth` from a known
        plane, or :func:`dlsr.detection.table_surface` fitted to the depth); the fingertips stop
        ``tip_clearance`` above it as the executor clamps them. None: no table clamp.
    min_grip, clearance, tolerance, tip_clearance : float
        Metres.
    samples : (int, int)
        As :func:`fingers_collide`.
    geometry : graspsim.sim.hands.HandGeometry or None
        As :func:`fingers_collide`.

    Returns
    -------
    Grasp
    """
    if grasp.T_world_grasp is None or grasp.failure is not None or not np.isfinite(grasp.depth):
        return grasp
    fp = _finger_footprint(grasp, depth, intrinsics, T_world_cam, samples, geometry)
    if fp is None:
        return grasp
    d, ok, tip = _footprint_depths(fp, depth, valid, table_depth, tip_clearance)
    hit = d[ok & (d < tip - tolerance)]
    if not hit.size:
        return grasp
    new_tip = float(hit.min()) - clearance
    if new_tip - grasp.depth < min_grip:
        return grasp
    back = (fp[2] - new_tip) / fp[3]  # along the approach, from the unclamped fingertips
    T = np.array(grasp.T_world_grasp, dtype=float)
    T[:3, 3] -= back * T[:3, 2]
    return replace(grasp, T_world_grasp=T)


def table_plane_depth(intrinsics, T_world_cam, table_z: float, shape) -> np.ndarray:
    """Camera depth (metres) of the horizontal plane ``z = table_z`` at every pixel.

    Parameters
    ----------
    intrinsics : CameraIntrinsics or ndarray of shape (3, 3)
    T_world_cam : ndarray of shape (4, 4)
    table_z : float
        Height of the table's top in the world, metres.
    shape : (int, int)
        ``(H, W)`` of the image.

    Returns
    -------
    ndarray of shape (H, W), float64
        ``inf`` where the pixel's ray does not meet the plane in front of the camera.
    """
    K = check_camera_matrix(intrinsics, "intrinsics")
    T = np.asarray(T_world_cam, dtype=float)
    H, W = shape
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], -1)
    down = rays @ T[2, :3]  # world z change per unit of camera depth
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (table_z - T[2, 3]) / down
    return np.where(np.isfinite(z) & (z > 0), z, np.inf)
