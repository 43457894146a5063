"""Grasp datasets: a common sample type, Cornell and Jacquard readers, a Cornell writer, splits."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .rectangles import GraspRectangle

__all__ = ["GraspSample"]


@dataclass
class GraspSample:
    """One RGB-D image with its labelled grasp rectangles.

    Attributes
    ----------
    image_id : str
        Unique within a dataset (Cornell: ``"0100"``; Jacquard: ``"<view>_<hash>"``).
    object_id : str or None
        Object identity for object-wise splits; None when unknown.
    rgb : ndarray of shape (H, W, 3), uint8
    depth : ndarray of shape (H, W), float32
        Metres; 0 where missing (never NaN).
    depth_valid : ndarray of shape (H, W), bool
    positives, negatives : list of GraspRectangle
    source : Path or None
        The file (or folder) the sample came from, for error messages.
    mask : ndarray of shape (H, W), bool, or None
        Object mask when the dataset has one (Jacquard, simulation).
    """

    image_id: str
    object_id: str | None
    rgb: np.ndarray
    depth: np.ndarray
    depth_valid: np.ndarray
    positives: list[GraspRectangle] = field(default_factory=list)
    negatives: list[GraspRectangle] = field(default_factory=list)
    source: Path | None = None
    mask: np.ndarray | None = None
