"""Kinect-like RGB-D camera for pybullet: intrinsics, look-down poses, rendering, depth noise.

Conventions (CONTRIBUTING.md): the camera frame is OpenCV (x right, y down, z forward along the
optical axis); ``T_world_cam`` (4x4) maps camera coordinates to world coordinates; depth is float32
metres along the optical axis (z, not ray length), 0 where missing, with a bool validity mask,
never NaN. Pixel ``(u, v)`` = (column, row); pixel centres are at integer coordinates, so the
image spans ``[-0.5, W - 0.5]`` and a centred principal point is ``((W - 1) / 2, (H - 1) / 2)``.

Rendering uses pybullet's CPU TinyRenderer (no display, no GPU). Metric depth from the OpenGL
z-buffer value ``zbuf`` in [0, 1] with near/far planes ``n``/``f`` is
``depth = f * n / (f - (f - n) * zbuf)``.

The depth-noise model (:class:`DepthNoise`) follows the structured-light Kinect (v1): an IR
projector 7.5 cm beside the IR camera, depth from the disparity of the projected pattern. Sources:

* C. V. Nguyen, S. Izadi, D. Lovell, "Modeling Kinect Sensor Noise for Improved 3D Reconstruction
  and Tracking", 3DIMPVT 2012: axial ``sigma_z(z, theta) = 0.0012 + 0.0019 (z - 0.4)^2
  + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2`` m (the last term only matters beyond ~60 deg)
  and lateral ``sigma_L(theta) = 0.8 + 0.035 * theta / (pi/2 - theta)`` px, ``theta`` the angle
  between the surface normal and the viewing ray (clamped to 80 deg here: the fit covers up to
  about 80 deg, and beyond it the grazing dropout removes the pixel anyway). Normals come from
  one-sided differences towards the neighbour of closer depth, so depth edges do not look like
  grazing surfaces.
* K. Khoshelham, S. O. Elberink, "Accuracy and Resolution of Kinect Depth Data for Indoor Mapping
  Applications", Sensors 12(2), 2012: depth from normalised disparity, ``z = f b / d``, and depth
  resolution growing as ``z^2``; J. Smisek, M. Jancosek, T. Pajdla, "3D with Kinect", ICCV
  Workshops 2011: disparity is reported in 1/8 pixel steps (baseline ~7.5 cm). Hence the
  quantised depth ``z_q = f b / (round(8 f b / z) / 8)``, a step of ``z^2 / (8 f b)`` (about
  1.5 mm at 0.7 m with f = 550 px).
* Missing depth on dark (IR-absorbing), specular and transparent surfaces and at depth
  discontinuities is the well-known failure mode of structured light (e.g. I. Lysenkov,
  V. Eruhimov, G. Bradski, "Recognition and Pose Estimation of Rigid Transparent Objects with a
  Kinect Sensor", RSS 2012, for transparent objects). The dropout probabilities below are this
  module's modelling choices, not measured values.
"""

from __future__ import annotations

import atexit
import hashlib
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.special import ndtri as _ndtri

__all__ = [
    "CameraIntrinsics",
    "DepthNoise",
    "Lights",
    "LightRanges",
    "RGBDFrame",
    "Camera",
    "look_down_pose",
    "random_lights",
    "random_table_rgba",
    "random_table_texture",
    "depth_from_zbuffer",
    "backproject",
    "project",
    "depth_figure",
    "apply_depth_noise",
    "projector_shadow",
    "axial_sigma",
    "lateral_sigma",
    "view_matrix",
    "table_texture_image",
    "MATERIALS",
]

MATERIALS = ("matte", "dark", "specular", "transparent")


# --------------------------------------------------------------------------- intrinsics and pose


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


# --------------------------------------------------------------------------- geometry helpers


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


def _one_sided_grad(z: np.ndarray, axis: int) -> np.ndarray:
    """Derivative of ``z`` along ``axis`` from the neighbour (before or after) of closer depth,
    so that pixels next to a depth discontinuity take the slope of their own surface."""
    d = np.diff(z, axis=axis)
    if axis == 1:
        back = np.concatenate([d[:, :1], d], axis=1)  # z[i] - z[i-1]
        fwd = np.concatenate([d, d[:, -1:]], axis=1)  # z[i+1] - z[i]
    else:
        back = np.concatenate([d[:1], d], axis=0)
        fwd = np.concatenate([d, d[-1:]], axis=0)
    return np.where(np.abs(fwd) < np.abs(back), fwd, back)


def incidence_angle(depth: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """(H, W) angle (rad) between the surface normal and the viewing ray, from z-depth.

    For ``P = z r`` with ``r = ((u - cx) / fx, (v - cy) / fy, 1)``, the normal is proportional to
    ``n = (-fx z_u, -fy z_v, fx z_u r_x + fy z_v r_y + z)`` and ``n . r = z``, so
    ``cos(theta) = z / (|n| |r|)`` (derivatives by one-sided differences, see above). 0 where the
    depth is missing.
    """
    z = np.asarray(depth, dtype=np.float32)
    H, W = z.shape
    rx = ((np.arange(W, dtype=np.float32) - intrinsics.cx) / intrinsics.fx)[None, :]
    ry = ((np.arange(H, dtype=np.float32) - intrinsics.cy) / intrinsics.fy)[:, None]
    zu = _one_sided_grad(z, 1)
    zv = _one_sided_grad(z, 0)
    a = intrinsics.fx * zu
    b = intrinsics.fy * zv
    c = a * rx + b * ry + z
    n_norm = np.sqrt(a * a + b * b + c * c)
    r_norm = np.sqrt(rx * rx + ry * ry + 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.where(z > 0, z / (n_norm * r_norm), 1.0)
    return np.arccos(np.clip(cos, 0.0, 1.0))


def _blob_dropout(rng: np.random.Generator, p: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W) bool: drop each pixel with probability ``p`` (array), in spatially correlated blobs.

    White Gaussian noise is blurred by a Gaussian of ``sigma`` px and divided by its exact
    standard deviation (the root sum of squared kernel weights), so each pixel is still standard
    normal; a pixel is dropped where this field is below ``Phi^-1(p)``. Marginally each pixel is
    dropped with probability exactly ``p``, in blobs about ``sigma`` px across.
    """
    g = rng.standard_normal(p.shape, dtype=np.float32)
    if sigma > 0:
        k = int(2 * np.ceil(3 * sigma) + 1)
        w = cv2.getGaussianKernel(k, sigma)
        g = cv2.GaussianBlur(g, (k, k), sigma, borderType=cv2.BORDER_REFLECT)
        g /= np.float32(np.sum(w**2))  # 2-D std of the blurred field = sum(w^2) (separable)
    out = np.zeros(p.shape, bool)
    m = p > 0
    out[m] = g[m] < _ndtri(np.minimum(p[m], 1.0))
    return out


# --------------------------------------------------------------------------- noise model


@dataclass(frozen=True)
class DepthNoise:
    """Kinect-like missing and noisy depth; each effect is a switch (see the module docstring).

    All randomness comes from the generator passed to :meth:`Camera.render`; each effect draws
    from its own child generator, so switching one effect off leaves the others' draws unchanged.

    Attributes
    ----------
    shadow : bool
        Projector shadow: a pixel is missing when its surface point is not visible from the IR
        projector at ``projector_offset`` (camera frame, default 7.5 cm along +x). The clean depth
        is back-projected, the points reprojected into the projector (same intrinsics and
        orientation) and z-buffered there (each point splatted to the two nearest projector
        columns); a point farther than the projector z-buffer by more than
        ``0.002 + 0.01 z`` m is shadowed. The shadow falls on the side of an object *away from* the
        projector (for +x: the left side in the image).
    grazing : bool
        Grazing-angle dropout: probability ``clip((theta - grazing_start) / (grazing_end -
        grazing_start), 0, 1)``, theta the angle between the surface normal and the viewing ray.
    materials : bool
        Dropout on bodies whose material (``materials`` argument of ``render``) is ``dark``
        (probability ``p_dark``), ``specular`` (``p_specular``, raised to ``p_specular_highlight``
        where theta < ``highlight_angle``: the mirror reflection saturates the sensor) or
        ``transparent`` (``p_transparent``). Dropout is drawn in blobs of ``blob_sigma`` px.
    edges : bool
        Depth-edge dropout: pixels within ``edge_width`` px of a jump larger than
        ``max(edge_jump, edge_jump_rel * z)`` between 4-neighbours are missing with probability
        ``p_edge``.
    axial : bool
        Additive Gaussian depth noise with the Nguyen et al. (2012) sigma_z(z, theta) above.
    lateral : bool
        Each pixel takes the depth of a pixel displaced by N(0, sigma_L(theta)^2) px in u and v
        (Nguyen et al. 2012), rounded to the nearest pixel: ragged object boundaries.
    quantisation : bool
        Disparity ``d = f b / z`` rounded to 1/``subpixel`` px (Smisek et al. 2011; Khoshelham &
        Elberink 2012) with ``f = fx`` and ``b = baseline``.
    """

    shadow: bool = True
    grazing: bool = True
    materials: bool = True
    edges: bool = True
    axial: bool = True
    lateral: bool = True
    quantisation: bool = True
    projector_offset: tuple[float, float, float] = (0.075, 0.0, 0.0)
    baseline: float = 0.075
    subpixel: int = 8
    grazing_start: float = np.deg2rad(70.0)
    grazing_end: float = np.deg2rad(85.0)
    p_dark: float = 0.6
    p_specular: float = 0.3
    p_specular_highlight: float = 0.9
    highlight_angle: float = np.deg2rad(15.0)
    p_transparent: float = 0.9
    edge_jump: float = 0.01
    edge_jump_rel: float = 0.02
    edge_width: int = 1
    p_edge: float = 0.5
    blob_sigma: float = 2.0

    @classmethod
    def off(cls) -> DepthNoise:
        """No noise: observed depth equals the clean depth."""
        return cls(shadow=False, grazing=False, materials=False, edges=False, axial=False,
                   lateral=False, quantisation=False)

    @property
    def any(self) -> bool:
        return any((self.shadow, self.grazing, self.materials, self.edges, self.axial,
                    self.lateral, self.quantisation))


def axial_sigma(z, theta=0.0):
    """Nguyen et al. (2012) axial noise std (m) at z-depth ``z`` (m) and incidence ``theta``."""
    z = np.asarray(z)
    theta = np.minimum(np.asarray(theta), np.float32(np.deg2rad(80.0)))
    return (0.0012 + 0.0019 * (z - 0.4) ** 2
            + 0.0001 / np.sqrt(np.maximum(z, 1e-6)) * theta**2 / (np.pi / 2 - theta) ** 2)


def lateral_sigma(theta=0.0):
    """Nguyen et al. (2012) lateral noise std in pixels at incidence ``theta``."""
    theta = np.minimum(np.asarray(theta), np.float32(np.deg2rad(80.0)))
    return 0.8 + 0.035 * theta / (np.pi / 2 - theta)


def projector_shadow(depth: np.ndarray, intrinsics: CameraIntrinsics,
                     offset=(0.075, 0.0, 0.0)) -> np.ndarray:
    """(H, W) bool: pixels whose surface point is not lit by a projector at ``offset``.

    The projector has the camera's intrinsics and orientation and sits at ``offset`` (camera
    frame, metres). Pixels with depth 0 are never shadowed (and cast no shadow).
    """
    H, W = depth.shape
    valid = depth > 0
    vs, us = np.nonzero(valid)
    zc = depth[vs, us].astype(np.float32)
    ox, oy, oz = (float(o) for o in offset)
    x = (us - intrinsics.cx) / intrinsics.fx * zc - ox
    y = (vs - intrinsics.cy) / intrinsics.fy * zc - oy
    z = zc - oz
    ok = z > 1e-6
    zs = np.where(ok, z, 1.0)
    up = np.where(ok, intrinsics.fx * x / zs + intrinsics.cx, -10.0)
    vp = np.where(ok, intrinsics.fy * y / zs + intrinsics.cy, -10.0)
    vi = np.rint(vp).astype(np.int64)
    u0 = np.floor(up).astype(np.int64)
    zbuf = np.full(H * (W + 2), np.inf, dtype=np.float32)
    inside = ok & (vi >= 0) & (vi < H) & (u0 >= -1) & (u0 < W)
    base = vi[inside] * (W + 2) + (u0[inside] + 1)  # padded by one column on each side
    np.minimum.at(zbuf, base, z[inside])
    np.minimum.at(zbuf, base + 1, z[inside])
    frac = up[inside] - u0[inside]
    # compare with the z-buffer at the nearer of the two splatted columns
    near_col = base + (frac >= 0.5)
    out = np.zeros((H, W), bool)
    out[vs[inside], us[inside]] = z[inside] > zbuf[near_col] + 0.002 + 0.01 * z[inside]
    return out


def _edge_band(depth: np.ndarray, noise: DepthNoise) -> np.ndarray:
    z = depth.astype(np.float32)
    thr = np.maximum(noise.edge_jump, noise.edge_jump_rel * z)
    jump = np.zeros(z.shape, bool)
    dx = np.abs(np.diff(z, axis=1))
    dy = np.abs(np.diff(z, axis=0))
    jx = dx > np.minimum(thr[:, 1:], thr[:, :-1])
    jy = dy > np.minimum(thr[1:, :], thr[:-1, :])
    jump[:, 1:] |= jx
    jump[:, :-1] |= jx
    jump[1:, :] |= jy
    jump[:-1, :] |= jy
    if noise.edge_width > 1:
        k = 2 * (noise.edge_width - 1) + 1
        jump = cv2.dilate(jump.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    return jump


def apply_depth_noise(depth_clean: np.ndarray, intrinsics: CameraIntrinsics,
                      rng: np.random.Generator, noise: DepthNoise,
                      segmentation: np.ndarray | None = None,
                      materials: dict[int, str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Observed depth and validity from clean depth.

    Parameters
    ----------
    depth_clean : (H, W) float32, metres, 0 where nothing was rendered.
    intrinsics : CameraIntrinsics
    rng : numpy.random.Generator
        Seven child seeds are always drawn, whatever the switches.
    noise : DepthNoise
    segmentation : (H, W) int, body ids (-1 background); needed for material dropout.
    materials : dict body id -> material (bodies not listed are matte).

    Returns
    -------
    depth : (H, W) float32, 0 where missing (never NaN)
    valid : (H, W) bool
    """
    clean = np.asarray(depth_clean, dtype=np.float32)
    H, W = clean.shape
    seeds = rng.integers(0, 2**63 - 1, size=7)
    gen = {k: np.random.default_rng(s) for k, s in zip(
        ("lateral", "axial", "grazing", "materials", "edges", "shadow", "spare"), seeds,
        strict=True)}
    valid = clean > 0
    if not noise.any:
        return np.where(valid, clean, 0).astype(np.float32), valid

    need_theta = noise.lateral or noise.axial or noise.grazing or noise.materials
    theta = incidence_angle(clean, intrinsics) if need_theta else None

    z = clean.copy()
    if noise.lateral:
        g = gen["lateral"]
        s = lateral_sigma(theta)
        du = g.standard_normal((H, W), dtype=np.float32) * s
        dv = g.standard_normal((H, W), dtype=np.float32) * s
        uu = np.clip(np.rint(np.arange(W)[None, :] + du), 0, W - 1).astype(np.int64)
        vv = np.clip(np.rint(np.arange(H)[:, None] + dv), 0, H - 1).astype(np.int64)
        z = z[vv, uu]
        valid = valid & (z > 0)
        theta = theta[vv, uu]
    if noise.axial:
        z = z + gen["axial"].standard_normal((H, W), dtype=np.float32) * axial_sigma(z, theta)
    if noise.quantisation:
        fb = intrinsics.fx * noise.baseline
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.round(noise.subpixel * fb / np.where(z > 0, z, np.inf)) / noise.subpixel
            z = np.where(d > 0, fb / np.where(d > 0, d, 1.0), 0.0)
    drop = np.zeros((H, W), bool)
    if noise.shadow:
        drop |= projector_shadow(clean, intrinsics, noise.projector_offset)
    if noise.grazing:
        p = np.clip((theta - noise.grazing_start) / (noise.grazing_end - noise.grazing_start),
                    0.0, 1.0)
        drop |= gen["grazing"].random((H, W)) < p
    if noise.materials and segmentation is not None and materials:
        p = np.zeros((H, W))
        for body, mat in materials.items():
            if mat not in MATERIALS:
                raise ValueError(f"unknown material {mat!r} for body {body}; use {MATERIALS}")
            m = segmentation == body
            if mat == "dark":
                p[m] = noise.p_dark
            elif mat == "transparent":
                p[m] = noise.p_transparent
            elif mat == "specular":
                p[m] = np.where(theta[m] < noise.highlight_angle, noise.p_specular_highlight,
                                noise.p_specular)
        drop |= _blob_dropout(gen["materials"], p, noise.blob_sigma)
    if noise.edges:
        band = _edge_band(clean, noise)
        drop |= _blob_dropout(gen["edges"], np.where(band, noise.p_edge, 0.0), 1.0)
    valid = valid & ~drop & np.isfinite(z) & (z > 0)
    depth = np.where(valid, z, 0.0).astype(np.float32)
    return depth, valid


# --------------------------------------------------------------------------- lights, table


@dataclass(frozen=True)
class Lights:
    """TinyRenderer lighting: one directional light plus ambient (pybullet's model)."""

    direction: tuple[float, float, float] = (0.3, 0.2, 1.0)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    distance: float = 2.0
    ambient: float = 0.6
    diffuse: float = 0.35
    specular: float = 0.05
    shadow: bool = False

    def kwargs(self) -> dict:
        return dict(lightDirection=list(self.direction), lightColor=list(self.color),
                    lightDistance=self.distance, shadow=int(self.shadow),
                    lightAmbientCoeff=self.ambient, lightDiffuseCoeff=self.diffuse,
                    lightSpecularCoeff=self.specular)


@dataclass(frozen=True)
class LightRanges:
    """Ranges :func:`random_lights` draws a light from (uniformly within each).

    The defaults are the simulator's usual lighting. Every field is a ``(low, high)`` range,
    except ``shadow``, the probability of cast shadows. Changing a range never changes how many
    values are drawn, so the draws after the lights (the depth noise) stay the same.

    Attributes
    ----------
    elevation : (float, float)
        Elevation of the light direction above the table plane, degrees.
    tint : (float, float)
        Per-channel reduction of the white light colour (0 = white).
    distance : (float, float)
        Light distance, metres (TinyRenderer's shading parameter).
    ambient, diffuse, specular : (float, float)
        TinyRenderer's lighting coefficients.
    shadow : float
        Probability that the light casts shadows.
    """

    elevation: tuple[float, float] = (30.0, 90.0)
    tint: tuple[float, float] = (0.0, 0.15)
    distance: tuple[float, float] = (1.5, 3.0)
    ambient: tuple[float, float] = (0.45, 0.7)
    diffuse: tuple[float, float] = (0.25, 0.5)
    specular: tuple[float, float] = (0.0, 0.2)
    shadow: float = 0.5

    def __post_init__(self):
        for name in ("elevation", "tint", "distance", "ambient", "diffuse", "specular"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"LightRanges.{name} must be a finite (low, high) with "
                                 f"low <= high, got {(lo, hi)}")
        if not 0.0 <= self.shadow <= 1.0:
            raise ValueError(f"LightRanges.shadow is a probability, got {self.shadow}")


def random_lights(rng: np.random.Generator, ranges: LightRanges | None = None) -> Lights:
    """Light from a random direction of the upper hemisphere, slightly tinted, with random
    ambient/diffuse/specular coefficients and cast shadows at random.

    Parameters
    ----------
    rng : numpy.random.Generator
        Eleven values are drawn, whatever the ranges.
    ranges : LightRanges or None
        None: ``LightRanges()`` (elevation 30-90 deg, shadows half the time).

    Returns
    -------
    Lights
    """
    r = LightRanges() if ranges is None else ranges
    az = rng.uniform(0, 2 * np.pi)
    el = rng.uniform(np.deg2rad(r.elevation[0]), np.deg2rad(r.elevation[1]))
    d = (np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el))
    tint = 1.0 - rng.uniform(r.tint[0], r.tint[1], size=3)
    return Lights(direction=tuple(float(x) for x in d), color=tuple(float(x) for x in tint),
                  distance=float(rng.uniform(*r.distance)),
                  ambient=float(rng.uniform(*r.ambient)),
                  diffuse=float(rng.uniform(*r.diffuse)),
                  specular=float(rng.uniform(*r.specular)),
                  shadow=bool(rng.random() < r.shadow))


def random_table_rgba(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A plausible table colour: wood, grey, white or a muted colour."""
    kind = rng.integers(4)
    if kind == 0:  # wood
        base = np.array([0.55, 0.38, 0.22]) * rng.uniform(0.7, 1.2)
    elif kind == 1:  # grey
        base = np.full(3, rng.uniform(0.3, 0.7))
    elif kind == 2:  # white-ish
        base = np.full(3, rng.uniform(0.8, 0.95))
    else:
        base = rng.uniform(0.2, 0.7, size=3)
    return (*(float(c) for c in np.clip(base, 0, 1)), 1.0)


_TEXTURE_DIR: Path | None = None


def _texture_dir() -> Path:
    global _TEXTURE_DIR
    if _TEXTURE_DIR is None:
        _TEXTURE_DIR = Path(tempfile.mkdtemp(prefix="graspsim_textures_"))
        atexit.register(shutil.rmtree, _TEXTURE_DIR, True)
    return _TEXTURE_DIR


def table_texture_image(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """(size, size, 3) uint8 table texture: wood grain, checker, speckle or plain + noise."""
    base = np.array(random_table_rgba(rng)[:3])
    kind = rng.integers(4)
    y, x = np.mgrid[0:size, 0:size] / size
    if kind == 0:  # wood grain
        f = rng.uniform(8, 20)
        wave = 0.3 * np.sin(2 * np.pi * rng.uniform(1, 3) * y)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * (f * x + wave))
        shade = 0.8 + 0.25 * t
    elif kind == 1:  # checker
        n = int(rng.integers(2, 8))
        shade = np.where(((x * n).astype(int) + (y * n).astype(int)) % 2 == 0, 1.0, 0.75)
    elif kind == 2:  # speckle
        shade = 0.85 + 0.3 * rng.random((size, size))
    else:
        shade = np.ones((size, size))
    shade = shade + 0.04 * rng.standard_normal((size, size))
    img = np.clip(shade[..., None] * base[None, None, :], 0, 1)
    return (img * 255).astype(np.uint8)


def random_table_texture(client, rng: np.random.Generator, body: int | None = None,
                         link: int = -1) -> int:
    """Make a random table texture, load it into ``client`` and, if ``body`` is given, apply it.

    Returns
    -------
    int
        The pybullet texture id (apply with ``changeVisualShape(body, -1, textureUniqueId=id,
        rgbaColor=[1, 1, 1, 1])``).
    """
    img = table_texture_image(rng)
    # pybullet caches textures by file name, so every image gets its own name (its content hash);
    # the file is deleted once loaded, so nothing piles up over thousands of scenes. Textures
    # live in the client until resetSimulation.
    digest = hashlib.sha1(img.tobytes()).hexdigest()[:16]
    path = _texture_dir() / f"table_{digest}.png"
    cv2.imwrite(str(path), img[..., ::-1])
    try:
        tex = client.loadTexture(str(path))
    finally:
        path.unlink(missing_ok=True)
    if body is not None:
        client.changeVisualShape(body, link, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1])
    return tex


# --------------------------------------------------------------------------- rendering


@dataclass
class RGBDFrame:
    """One rendered frame.

    Attributes
    ----------
    rgb : (H, W, 3) uint8
    depth : (H, W) float32, observed metres, 0 where missing
    depth_valid : (H, W) bool
    depth_clean : (H, W) float32, z-buffer depth (0 where nothing was rendered)
    segmentation : (H, W) int32, pybullet body ids, -1 background
    intrinsics : CameraIntrinsics
    T_world_cam : (4, 4) float
    lights : Lights
    """

    rgb: np.ndarray
    depth: np.ndarray
    depth_valid: np.ndarray
    depth_clean: np.ndarray
    segmentation: np.ndarray
    intrinsics: CameraIntrinsics
    T_world_cam: np.ndarray
    lights: Lights | None = None
    meta: dict = field(default_factory=dict)


class Camera:
    """A Kinect-like RGB-D camera rendering from a pybullet client with the TinyRenderer.

    Parameters
    ----------
    client : pybullet_utils.bullet_client.BulletClient
    intrinsics : CameraIntrinsics
    """

    def __init__(self, client, intrinsics: CameraIntrinsics | None = None):
        self.client = client
        self.intrinsics = CameraIntrinsics() if intrinsics is None else intrinsics

    def render_clean(self, T_world_cam: np.ndarray, lights: Lights | None = None):
        """RGB, clean depth and segmentation without noise. Returns (rgb, depth, seg)."""
        intr = self.intrinsics
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_world_cam must be a finite 4x4 array, got shape {T.shape}")
        view = view_matrix(T)
        proj = intr.projection_matrix()
        kw = (lights or Lights()).kwargs()
        _, _, rgba, zbuf, seg = self.client.getCameraImage(
            intr.width, intr.height, viewMatrix=view.T.ravel().tolist(),
            projectionMatrix=proj.T.ravel().tolist(), renderer=self.client.ER_TINY_RENDERER,
            **kw,
        )
        H, W = intr.height, intr.width
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(H, W, 4)[..., :3].copy()
        zbuf = np.asarray(zbuf, dtype=np.float64).reshape(H, W)
        seg = np.asarray(seg, dtype=np.int32).reshape(H, W)
        depth = depth_from_zbuffer(zbuf, intr.near, intr.far)
        depth[zbuf >= 1.0 - 1e-7] = 0.0  # nothing rendered: missing, not `far`
        return rgb, depth, seg

    def render(self, T_world_cam: np.ndarray, rng: np.random.Generator,
               noise: DepthNoise | None = None, lights: Lights | None = None,
               materials: dict[int, str] | None = None,
               lighting: LightRanges | None = None) -> RGBDFrame:
        """Render one frame.

        Parameters
        ----------
        T_world_cam : (4, 4) array
        rng : numpy.random.Generator
            Draws the lights (always, even when ``lights`` is given, so the noise draws do not
            depend on it) and then the noise.
        noise : DepthNoise or None
            None: the default Kinect-like noise ``DepthNoise()``; ``DepthNoise.off()`` for none.
        lights : Lights or None
            None: ``random_lights(rng)``.
        materials : dict body id -> material, for the material dropout.
        lighting : LightRanges or None
            The ranges the lights are drawn from (None: ``LightRanges()``).

        Returns
        -------
        RGBDFrame
        """
        noise = DepthNoise() if noise is None else noise
        drawn = random_lights(rng, lighting)
        lights = drawn if lights is None else lights
        rgb, clean, seg = self.render_clean(T_world_cam, lights)
        depth, valid = apply_depth_noise(clean, self.intrinsics, rng, noise, seg, materials)
        return RGBDFrame(rgb=rgb, depth=depth, depth_valid=valid, depth_clean=clean,
                         segmentation=seg, intrinsics=self.intrinsics,
                         T_world_cam=np.asarray(T_world_cam, dtype=np.float64).copy(),
                         lights=lights)


# --------------------------------------------------------------------------- figure


def depth_figure(frame: RGBDFrame, path, title: str | None = None) -> Path:
    """Save a PNG: RGB, clean depth, observed depth (missing in black) and observed - clean (mm).

    Parameters
    ----------
    frame : RGBDFrame
    path : str or Path
        Output PNG (parent folders are created).
    title : str, optional

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    path = Path(path)
    clean = frame.depth_clean
    obs = frame.depth
    ok = clean > 0
    if not ok.any():
        raise ValueError("depth_figure: the clean depth is empty (nothing rendered)")
    lo, hi = np.percentile(clean[ok], [0.5, 99.5])
    hi = hi + 0.01
    cmap = plt.get_cmap("viridis").with_extremes(bad="black")
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.4), constrained_layout=True)
    axes[0].imshow(frame.rgb)
    axes[0].set_title("RGB")
    axes[1].imshow(np.ma.masked_where(~ok, clean), cmap=cmap, vmin=lo, vmax=hi)
    axes[1].set_title("clean depth (z-buffer)")
    im = axes[2].imshow(np.ma.masked_where(~frame.depth_valid, obs), cmap=cmap, vmin=lo, vmax=hi)
    miss = 100.0 * (1 - frame.depth_valid[ok].mean())
    axes[2].set_title(f"observed depth ({miss:.1f} % missing, black)")
    fig.colorbar(im, ax=axes[2], shrink=0.85, label="depth (m)")
    diff = np.ma.masked_where(~frame.depth_valid, (obs - clean) * 1000.0)
    im2 = axes[3].imshow(diff, cmap=plt.get_cmap("RdBu").with_extremes(bad="black"),
                         vmin=-6, vmax=6)
    axes[3].set_title("observed - clean (noise + quantisation)")
    fig.colorbar(im2, ax=axes[3], shrink=0.85, label="mm")
    for a in axes:
        a.set_axis_off()
    if title:
        fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=72)
    plt.close(fig)
    return path
