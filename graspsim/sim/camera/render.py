"""The Kinect-like RGB-D camera for pybullet: a frame rendered with the TinyRenderer from a
look-down pose, the depth noise applied (:mod:`graspsim.sim.camera.noise`), and a figure of it.

Conventions and the depth from the z-buffer: :mod:`graspsim.sim.camera.geometry`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .appearance import LightRanges, Lights, random_lights
from .geometry import CameraIntrinsics, depth_from_zbuffer, view_matrix
from .noise import DepthNoise, apply_depth_noise

__all__ = ["RGBDFrame", "Camera", "depth_figure"]

# --------------------------------------------------------------------------- intrinsics and pose


# --------------------------------------------------------------------------- geometry helpers


# --------------------------------------------------------------------------- noise model


# --------------------------------------------------------------------------- lights, table


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
    # deferred, heavy and rarely used: matplotlib, for figures only
    import matplotlib

    matplotlib.use("Agg", force=False)
    # deferred, heavy and rarely used: matplotlib, for figures only
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
