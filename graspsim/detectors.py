"""Baseline grasp detectors and the detector loader.

A detector is anything with ``predict(obs) -> list[GraspRectangle]``, best first. ``obs`` is the
environment's observation dict (``rgb`` uint8 (H, W, 3), ``depth`` float32 (H, W) metres,
``depth_valid`` (H, W)); the trial harness adds ``seed`` (an int for stochastic detectors) and,
when the scene was labelled, ``positives`` (physics-labelled positives ranked best first).

* ``random``: a uniformly random rectangle anywhere in the image (succeeds rarely).
* ``mask-pca``: segments the object from depth alone (the table plane is fitted in ``1/z``, which
  is linear in the pixel coordinates for any plane, so no intrinsics are needed), then grasps at
  the mask centroid across its minor axis, opening = the mask's extent there plus a margin.
* ``oracle``: the best physics-labelled positive (needs ``obs["positives"]``).
"""

from __future__ import annotations

import numpy as np

from dlsr.rectangles import GraspRectangle

from .labelling import extent_along, mask_axes

__all__ = [
    "RandomDetector",
    "MaskPCADetector",
    "OracleDetector",
    "DETECTORS",
    "load_detector",
    "object_mask_from_depth",
]


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

    The observation-side name for :func:`dlsr.detection.table_plane_mask` (RANSAC plane in
    inverse depth, restricted to the table's convex hull), so the baselines and the DLSR
    detectors find the object the same way.

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
    from dlsr.detection import table_plane_mask

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
                "(run it through graspsim.trials, which labels every scene)"
            )
        return list(obs["positives"])


DETECTORS = {
    "random": RandomDetector,
    "mask-pca": MaskPCADetector,
    "oracle": OracleDetector,
}


def load_detector(name_or_path):
    """A detector from a built-in name or a saved DLSR model.

    Parameters
    ----------
    name_or_path : str or Path
        ``"random"``, ``"mask-pca"``, ``"oracle"``, or the path of a model saved by
        :meth:`dlsr.detection.DLSRDetector.save` (``.npz`` + ``.json``, with or without the
        suffix); it detects with the options saved in the model.

    Raises
    ------
    FileNotFoundError
        If it is neither a built-in name nor an existing model.
    """
    key = str(name_or_path)
    if key in DETECTORS:
        return DETECTORS[key]()
    from dlsr.detection import DLSRDetector

    npz, js = DLSRDetector._paths(key)
    if npz.exists() or js.exists():
        return DLSRDetector.load(key).detector()  # names the missing or broken file
    raise FileNotFoundError(
        f"unknown detector {key!r}: not one of {', '.join(DETECTORS)} and no saved model "
        f"({npz} + {js})"
    )
