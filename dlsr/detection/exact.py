"""Detection results (:class:`Detection`), the detectors' shared base and the exact path
(:class:`ExactGridDetector`: every candidate featurised as recognition does).

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from ..rectangles import GraspRectangle, array_to_rects
from .grid import (
    PAPER_GRID,
    SearchGrid,
    complete_region,
    enumerate_candidates,
    object_region,
    valid_depth,
    within_reach,
)
from .model import PATCHES_PER_RECTANGLE, DLSRDetector
from .registry import register_detector

log = logging.getLogger(__name__)


@dataclass
class Detection:
    """What a detector found in one image.

    Attributes
    ----------
    rects : ndarray of shape (k, 5)
        Best first.
    scores : ndarray of shape (k,)
    n_candidates : int
        Candidates scored.
    n_encodings : int
        Patch encodings performed.
    seconds : float
    reason : str or None
        Why nothing was found (empty result).
    timings : dict
    """

    rects: np.ndarray
    scores: np.ndarray
    n_candidates: int = 0
    n_encodings: int = 0
    seconds: float = 0.0
    reason: str | None = None
    timings: dict = field(default_factory=dict)

    def rectangles(self) -> list[GraspRectangle]:
        return array_to_rects(self.rects) if len(self.rects) else []


def _empty(reason: str, t0: float, **kw) -> Detection:
    log.warning("no detection: %s", reason)
    return Detection(np.zeros((0, 5)), np.zeros(0), reason=reason,
                     seconds=time.perf_counter() - t0, **kw)


def _check_obs(obs):
    for key in ("rgb", "depth"):
        if key not in obs:
            raise ValueError(f"the observation has no {key!r}")
    rgb = np.asarray(obs["rgb"])
    depth = np.asarray(obs["depth"])
    if rgb.ndim != 3 or rgb.shape[2] != 3 or depth.shape != rgb.shape[:2]:
        raise ValueError(f"observation rgb {rgb.shape} and depth {depth.shape} do not match")


def _observed_region(obs, background, method: str, min_height: float):
    """``(valid depth, object region, how it was found, reason or None)`` of an observation;
    the reason says why no candidate can be laid (no valid depth, empty region)."""
    valid = valid_depth(obs["depth"], obs.get("depth_valid"))
    if not valid.any():
        return valid, None, None, "the depth image has no valid pixel (all masked)"
    region, how = object_region(obs, background, method, min_height)
    if not region.any():
        return valid, region, how, f"empty object region (method {how})"
    return valid, region, how, None


class _Base:
    def __init__(self, model: DLSRDetector, grid: SearchGrid = PAPER_GRID, top_k: int = 5,
                 region: str = "auto", background=None, min_height: float = 0.006):
        self.model = model
        self.grid = grid
        self.top_k = top_k
        self.region = region
        self.background = background
        self.min_height = min_height

    def candidates(self, obs, grid: SearchGrid | None = None):
        """``(candidates (n, 5), reason or None)`` for an observation."""
        cand, reason, _ = self._candidates(obs, grid)
        return cand, reason

    def _candidates(self, obs, grid: SearchGrid | None = None):
        """``(candidates, reason or None, object region or None)``."""
        _check_obs(obs)
        valid, region, how, reason = _observed_region(obs, self.background, self.region,
                                                      self.min_height)
        if reason:
            return np.zeros((0, 5)), reason, region
        grid = grid or self.grid
        if self.grid.complete_region:
            region = complete_region(region, valid)
        cand = enumerate_candidates(region, grid)
        cand = within_reach(obs, cand, region, grid)
        if len(cand) == 0:
            what = " with both jaws clear of it" if grid.clear_jaws else ""
            if grid.max_width is not None:
                what += f" and an opening of at most {grid.max_width:g} m"
            return cand, (f"no candidate covers the object region enough{what} "
                          f"(method {how})"), region
        return cand, None, region

    def predict(self, obs) -> list[GraspRectangle]:
        """The top-k rectangles, best first (empty, with a logged reason, when none)."""
        return self.detect(obs).rectangles()


class ExactGridDetector(_Base):
    """Lenz et al.'s grid search, every candidate featurised exactly as in recognition.

    Parameters
    ----------
    model : DLSRDetector
    grid : SearchGrid
    top_k : int
        Rectangles returned.
    region : {"auto", "background", "mask", "depth"}
        See :func:`~dlsr.detection.object_region`.
    background : ndarray or None
        Background image (Cornell).
    min_height : float
    batch_size : int
        Candidates preprocessed and encoded at once.
    """

    def __init__(self, model, grid=PAPER_GRID, top_k=5, region="auto", background=None,
                 min_height=0.006, batch_size: int = 512):
        super().__init__(model, grid, top_k, region, background, min_height)
        self.batch_size = batch_size

    def detect(self, obs, candidates=None) -> Detection:
        t0 = time.perf_counter()
        region = None
        if candidates is None:
            cand, reason, region = self._candidates(obs)
            if reason:
                return _empty(reason, t0)
        else:
            cand = np.asarray(candidates, dtype=float).reshape(-1, 5)
        t1 = time.perf_counter()
        scores = self.model.rectangle_scores(obs, cand, self.batch_size)
        if self.model.physical:
            if region is None:
                region, _ = object_region(obs, self.background, self.region, self.min_height)
            scores = scores + self.model.physical_scores(obs, cand, region)
        order = np.argsort(-scores, kind="stable")[: self.top_k]
        t2 = time.perf_counter()
        return Detection(cand[order], scores[order], n_candidates=len(cand),
                         n_encodings=len(cand) * PATCHES_PER_RECTANGLE, seconds=t2 - t0,
                         timings={"candidates": t1 - t0, "score": t2 - t1})


register_detector("exact", ExactGridDetector)
