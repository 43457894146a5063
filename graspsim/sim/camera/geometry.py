"""Camera geometry: intrinsics, look-down poses, projection and back-projection (numpy only).

Conventions (CONTRIBUTING.md): the camera frame is OpenCV (x right, y down, z forward along the
optical axis); ``T_world_cam`` (4x4) maps camera coordinates to world coordinates; depth is float32
metres along the optical axis (z, not ray length), 0 where missing, with a bool validity mask,
never NaN. Pixel ``(u, v)`` = (column, row); pixel centres are at integer coordinates, so the
image spans ``[-0.5, W - 0.5]`` and a centred principal point is ``((W - 1) / 2, (H - 1) / 2)``.


Rendering uses pybullet's CPU TinyRenderer (no display, no GPU). Metric depth from the OpenGL
z-buffer value ``zbuf`` in [0, 1] with near/far planes ``n``/``f`` is
``depth = f * n / (f - (f - n) * zbuf)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CameraIntrinsics", "view_matrix", "look_down_pose", "depth_from_zbuffer", "backproject",
           "project"]


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics (Kinect v1-like defaults) and clipping planes.

    Attributes
    ----------
    width, height : int
        Pixels.
    fx, fy : float
        Focal lengths in pixels (Kinect IR camera: about 525-580).
    cx, cy : float or None
        Principal point in pixels; None = the image centre ``((W - 1) / 2, (H - 1) / 2)``.
    near, far : float
        Clipping planes of the renderer, metres.
    """

    width: int = 640
    height: int = 480
    fx: float = 550.0
    fy: float = 550.0
    cx: float | None = None
    cy: float | None = None
    near: float = 0.1
    far: float = 2.0

    def __post_init__(self):
        if self.cx is None:
            object.__setattr__(self, "cx", (self.width - 1) / 2.0)
        if self.cy is None:
            object.__setattr__(self, "cy", (self.height - 1) / 2.0)
        if not (0 < self.near < self.far):
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ValueError("width, height, fx and fy must be positive")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def projection_matrix(self) -> np.ndarray:
        """(4, 4) OpenGL projection matrix equivalent to ``K`` (row-major; pybullet wants
        ``P.T.ravel()``, i.e. column-major).

        It maps the OpenGL camera frame (x right, y up, looking along -z) to clip space such that
        pixel ``u = fx x / z + cx`` (OpenCV frame) lands at NDC ``2 (u + 0.5) / W - 1`` and row
        ``v`` at NDC ``1 - 2 (v + 0.5) / H``.
        """
        W, H, n, f = self.width, self.height, self.near, self.far
        return np.array([
            [2 * self.fx / W, 0.0, 1.0 - 2.0 * (self.cx + 0.5) / W, 0.0],
            [0.0, 2 * self.fy / H, 2.0 * (self.cy + 0.5) / H - 1.0, 0.0],
            [0.0, 0.0, -(f + n) / (f - n), -2.0 * f * n / (f - n)],
            [0.0, 0.0, -1.0, 0.0],
        ])


_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def view_matrix(T_world_cam: np.ndarray) -> np.ndarray:
    """(4, 4) OpenGL view matrix (world -> GL camera) for an OpenCV ``T_world_cam``."""
    return np.linalg.inv(np.asarray(T_world_cam, float) @ _CV_TO_GL)


def look_down_pose(rng: np.random.Generator, height=(0.6, 0.8), jitter=(0.03, 0.08, np.pi),
                   table_z: float = 0.0, target=(0.0, 0.0)) -> np.ndarray:
    """A camera looking down at the table, with seeded jitter.

    Parameters
    ----------
    rng : numpy.random.Generator
    height : (float, float)
        Uniform range of the camera height above the table top, metres.
    jitter : (float, float, float)
        ``(xy, tilt, yaw)``: the looked-at point is ``target`` plus a uniform offset in
        ``[-xy, xy]^2`` m; the optical axis is tilted from the vertical by a uniform angle in
        ``[0, tilt]`` rad about a random horizontal axis; the image is rotated about the vertical by
        a uniform yaw in ``[-yaw, yaw]`` rad.
    table_z : float
        Height of the table top (world z), metres.
    target : (float, float)
        World xy the camera looks at, before jitter.

    Returns
    -------
    (4, 4) float array
        ``T_world_cam`` (OpenCV camera frame: z along the optical axis, pointing down).
    """
    xy_j, tilt_j, yaw_j = (float(x) for x in jitter)
    h = rng.uniform(*height)
    look = np.array([target[0] + rng.uniform(-xy_j, xy_j), target[1] + rng.uniform(-xy_j, xy_j),
                     table_z])
    yaw = rng.uniform(-yaw_j, yaw_j)
    tilt = rng.uniform(0.0, tilt_j)
    tilt_axis = rng.uniform(0.0, 2 * np.pi)
    # straight down: x_cam = (cos yaw, sin yaw, 0), z_cam = (0, 0, -1), y_cam = z x x
    x = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    R = np.stack([x, np.cross(z, x), z], axis=1)
    a = np.array([np.cos(tilt_axis), np.sin(tilt_axis), 0.0])
    R = _axis_angle(a, tilt) @ R
    T = np.eye(4)
    T[:3, :3] = R
    # camera on the optical axis through the looked-at point, at height h above the table
    T[:3, 3] = look - R[:, 2] * (h / max(-R[2, 2], 1e-6))
    return T


def _axis_angle(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx


def depth_from_zbuffer(zbuf: np.ndarray, near: float, far: float) -> np.ndarray:
    """Metric z-depth from an OpenGL z-buffer in [0, 1]: ``f n / (f - (f - n) zbuf)``."""
    zbuf = np.asarray(zbuf, dtype=np.float64)
    return (far * near / (far - (far - near) * zbuf)).astype(np.float32)


def backproject(depth: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) points in the camera frame from (H, W) z-depth (zeros stay at the origin)."""
    H, W = depth.shape
    u = np.arange(W, dtype=np.float64)[None, :]
    v = np.arange(H, dtype=np.float64)[:, None]
    z = depth.astype(np.float64)
    x = (u - intrinsics.cx) / intrinsics.fx * z
    y = (v - intrinsics.cy) / intrinsics.fy * z
    return np.stack([x, y, z], axis=-1)


def project(points_world: np.ndarray, intrinsics: CameraIntrinsics,
            T_world_cam: np.ndarray) -> np.ndarray:
    """(N, 2) pixel coordinates (u, v) and (N,) depths of (N, 3) world points.

    Returns
    -------
    uv : (N, 2) float array
    z : (N,) float array
    """
    p = np.atleast_2d(np.asarray(points_world, float))
    T_cam_world = np.linalg.inv(np.asarray(T_world_cam, float))
    pc = p @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = pc[:, 2]
    uv = np.stack([intrinsics.fx * pc[:, 0] / z + intrinsics.cx,
                   intrinsics.fy * pc[:, 1] / z + intrinsics.cy], axis=1)
    return uv, z
