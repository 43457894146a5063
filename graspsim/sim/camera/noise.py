"""A Kinect-like depth sensor's noise (numpy and OpenCV only).

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

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import ndtri as _ndtri

from .geometry import CameraIntrinsics

__all__ = ["MATERIALS", "DepthNoise", "apply_depth_noise", "axial_sigma", "lateral_sigma",
           "projector_shadow", "incidence_angle"]


MATERIALS = ("matte", "dark", "specular", "transparent")


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
