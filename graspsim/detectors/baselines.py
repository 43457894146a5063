"""The baseline detectors.

* ``random`` (:class:`RandomDetector`): a uniformly random rectangle anywhere in the image
  (succeeds rarely); :class:`ObjectRandomDetector`, the offline benchmark's, on the object.
* ``mask-pca`` (:class:`MaskPCADetector`): segments the object from depth alone (the table
  plane is fitted in ``1/z``, which is linear in the pixel coordinates for any plane, so no
  intrinsics are needed), then grasps at the mask centroid across its minor axis, opening = the
  mask's extent there plus a margin.
* ``oracle`` (:class:`OracleDetector`): the best physics-labelled positive (needs
  ``obs["positives"]``).
"""

from __future__ import annotations

import numpy as np

from dlsr.detection import (
    object_region,
    table_plane_mask,
)
from dlsr.rectangles import GraspRectangle

from ..labels.labelling import extent_along, mask_axes

__all__ = ["RandomDetector", "ObjectRandomDetector", "MaskPCADetector", "OracleDetector",
           "object_mask_from_depth"]


class RandomDetector:
    """Uniformly random rectangles.

    Parameters
    ----------
    n : int
        Rectangles per call.
    w_px, h_px : (float, float)
        Ranges of opening and jaw size, pixels.
    random_state : int, Generator or None
        Used when ``obs`` carries no ``seed``.
    """

    requires_labels = False

    def __init__(self, n=1, w_px=(20.0, 120.0), h_px=(10.0, 30.0), random_state=None):
        self.n = n
        self.w_px = w_px
        self.h_px = h_px
        self.random_state = random_state

    def predict(self, obs) -> list[GraspRectangle]:
        if obs.get("seed") is not None:
            rng = np.random.default_rng(obs["seed"])
        else:
            if not hasattr(self, "rng_"):
                self.rng_ = np.random.default_rng(self.random_state)
            rng = self.rng_
        H, W = np.asarray(obs["depth"]).shape
        return [
            GraspRectangle(rng.uniform(0, W - 1), rng.uniform(0, H - 1),
                           rng.uniform(-np.pi / 2, np.pi / 2), rng.uniform(*self.w_px),
                           rng.uniform(*self.h_px))
            for _ in range(self.n)
        ]


def object_mask_from_depth(depth, valid, min_height: float = 0.006) -> np.ndarray:
    """Pixels standing more than ``min_height`` (m) above the table plane, largest blob.

    The observation-side name for :func:`dlsr.detection.table_plane_mask` (the table's
    surface fitted robustly in inverse depth, the object the blob standing in front of it that
    the table encloses), so the baselines and the DLSR detectors find the object the same way.

    Parameters
    ----------
    depth : ndarray of shape (H, W), float, metres (0 where missing)
    valid : ndarray of shape (H, W)
    min_height : float

    Returns
    -------
    ndarray of shape (H, W), bool
        Empty when nothing stands out.
    """
    return table_plane_mask(depth, valid, min_height=min_height)


class MaskPCADetector:
    """Grasp across the minor axis of the depth-segmented object, at its centroid.

    Parameters
    ----------
    jaw_px : float
        Jaw size ``h``, pixels.
    margin_px : float
        Added to the mask's extent for the opening ``w``.
    min_height : float
        Metres above the table for a pixel to count as object.
    """

    requires_labels = False

    def __init__(self, jaw_px: float = 18.0, margin_px: float = 6.0, min_height: float = 0.006):
        self.jaw_px = jaw_px
        self.margin_px = margin_px
        self.min_height = min_height

    def predict(self, obs) -> list[GraspRectangle]:
        mask = object_mask_from_depth(obs["depth"], obs["depth_valid"], self.min_height)
        if mask.sum() < 20:
            return []
        c, theta, xy = mask_axes(mask)
        w = extent_along(xy, c, theta, self.jaw_px / 2) + self.margin_px
        return [GraspRectangle(float(c[0]), float(c[1]), theta, max(w, 4.0), self.jaw_px)]


class OracleDetector:
    """The best physics-labelled positive of the scene (``obs["positives"]``, ranked)."""

    requires_labels = True

    def predict(self, obs) -> list[GraspRectangle]:
        if "positives" not in obs:
            raise ValueError(
                "the oracle detector needs physics-labelled positives in obs['positives'] "
                "(run it through graspsim.eval.trials, which labels every scene)"
            )
        return list(obs["positives"])


class ObjectRandomDetector:
    """Baseline: a uniformly random rectangle on the object region (the issue's ``random``).

    Centre on a random object pixel, angle uniform, opening and jaw uniform in ``[10, 90]``
    with opening >= jaw. The region is found as the DLSR detectors find it
    (:func:`dlsr.detection.object_region`); with no region, anywhere in the image.
    """

    requires_labels = False

    def __init__(self, region: str = "auto", random_state=None):
        self.region = region
        self.random_state = random_state

    def predict(self, obs):
        rng = np.random.default_rng(obs.get("seed", self.random_state))
        region, _ = object_region(obs, method=self.region)
        if region.any():
            rows, cols = np.nonzero(region)
            i = rng.integers(len(rows))
            x, y = float(cols[i]), float(rows[i])
        else:
            H, W = np.asarray(obs["depth"]).shape
            x, y = rng.uniform(0, W - 1), rng.uniform(0, H - 1)
        w, h = sorted(rng.uniform(10, 90, size=2), reverse=True)
        return [GraspRectangle(x, y, rng.uniform(-np.pi / 2, np.pi / 2), w, h)]
