"""Ground truth by physics: propose rectangles on the object mask and execute every one.

:func:`sample_candidates` proposes rectangles so that both classes are well represented: about
half are "informed" (centre near the object's centroid, closing direction near the mask's minor
axis, opening just wider than the mask's extent along it -- mostly successes) and the rest vary
centre (any mask pixel), angle (uniform), opening (narrower or much wider than the extent) and jaw
size (mostly failures). :func:`label_rectangles` executes each candidate from the same rebuilt
scene state (``resetSimulation`` + reload, deterministic) and returns the physical outcomes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dlsr.rectangles import GraspRectangle

from .execution import ExecutionParams, GraspResult, run_grasp
from .grasp import rectangle_to_grasp

__all__ = [
    "Labelled",
    "sample_candidates",
    "chord",
    "extent_along",
    "label_rectangles",
    "mask_axes",
    "rank_positives",
]


@dataclass
class Labelled:
    """Candidates with their physical outcomes.

    Attributes
    ----------
    rects : list of GraspRectangle
    results : list of GraspResult
    """

    rects: list[GraspRectangle]
    results: list[GraspResult]

    @property
    def success(self) -> np.ndarray:
        """``(n,)`` bool."""
        return np.array([r.success for r in self.results], dtype=bool)

    @property
    def positives(self) -> list[GraspRectangle]:
        return [g for g, r in zip(self.rects, self.results, strict=True) if r.success]

    @property
    def negatives(self) -> list[GraspRectangle]:
        return [g for g, r in zip(self.rects, self.results, strict=True) if not r.success]


def mask_axes(mask) -> tuple[np.ndarray, float, np.ndarray]:
    """Centroid, minor-axis angle and pixel coordinates of a mask.

    Parameters
    ----------
    mask : ndarray of shape (H, W), bool

    Returns
    -------
    centroid : ndarray of shape (2,)
        ``(x, y)`` pixels.
    theta_minor : float
        Angle of the minor axis (counter-clockwise as displayed, the rectangle convention).
    xy : ndarray of shape (n, 2)
        ``(x, y)`` of the mask pixels.

    Raises
    ------
    ValueError
        If the mask is empty.
    """
    ys, xs = np.nonzero(np.asarray(mask, dtype=bool))
    if len(xs) == 0:
        raise ValueError("the object mask is empty")
    xy = np.column_stack([xs, ys]).astype(float)
    c = xy.mean(axis=0)
    d = xy - c
    cov = d.T @ d / max(len(xy), 1)
    _, vecs = np.linalg.eigh(cov)
    minor = vecs[:, 0]
    return c, float(np.arctan2(-minor[1], minor[0])), xy


def extent_along(xy, centre, theta, half_band) -> float:
    """Extent (pixels) of mask pixels ``xy`` along ``theta`` in a band through ``centre``."""
    u = np.array([np.cos(theta), -np.sin(theta)])
    v = np.array([np.sin(theta), np.cos(theta)])
    d = xy - centre
    along, across = d @ u, d @ v
    band = np.abs(across) <= half_band
    if not band.any():
        return 0.0
    a = along[band]
    return float(2 * max(a.max(), -a.min()))


def chord(inside, centre, theta, max_px: float = 120.0) -> tuple[float, float]:
    """Contiguous run of ``inside`` pixels through ``centre`` along ``theta``.

    Returns
    -------
    (lo, hi) : offsets in pixels along the direction (``lo <= 0 <= hi``); ``(0, 0)`` when the
    centre itself is outside.
    """
    H, W = inside.shape
    u = np.array([np.cos(theta), -np.sin(theta)])
    t = np.arange(0.0, max_px + 1.0)
    ends = []
    for sgn in (1.0, -1.0):
        pts = np.rint(centre[None, :] + sgn * t[:, None] * u[None, :]).astype(int)
        ok = (pts[:, 0] >= 0) & (pts[:, 0] < W) & (pts[:, 1] >= 0) & (pts[:, 1] < H)
        run = np.zeros(len(t), dtype=bool)
        run[ok] = inside[pts[ok, 1], pts[ok, 0]]
        stop = np.argmin(run) if not run.all() else len(t)
        ends.append(max(stop - 1, 0) * sgn)
    return float(ends[1]), float(ends[0])


def sample_candidates(segmentation, object_ids, rng: np.random.Generator, n: int = 32,
                      jaw_px=(10.0, 28.0), depth=None,
                      mix=(0.35, 0.35, 0.30)) -> list[GraspRectangle]:
    """Propose ``n`` rectangles on the objects' masks.

    Three kinds, drawn with probabilities ``mix``:

    * global: centre near the mask centroid, closing direction near the minor axis, opening the
      mask's extent there plus 2-9 px (mostly successes on compact objects);
    * local: a random mask pixel and a random angle; the rectangle spans the contiguous run
      (chord) of the mask -- or, when ``depth`` is given, half of the time of pixels no more than
      2 cm deeper than the centre pixel (rims, handles, arms) -- plus 2-9 px, centred on it;
    * random: a random mask pixel, angle, opening (0.3-1.5 x the extent) and jaw size (mostly
      failures).

    Parameters
    ----------
    segmentation : ndarray of shape (H, W), int
        Body id per pixel (the camera's segmentation).
    object_ids : sequence of int
        Body ids of the graspable objects.
    rng : numpy.random.Generator
    n : int
    jaw_px : (float, float)
        Range of jaw sizes ``h``, pixels.
    depth : ndarray of shape (H, W) or None
        Clean depth, metres, for the depth chords.
    mix : (float, float, float)
        Probabilities of the global, local and random kinds.

    Returns
    -------
    list of GraspRectangle
        Empty when no object is visible.
    """
    seg = np.asarray(segmentation)
    masks = [(seg == b) for b in object_ids]
    masks = [m for m in masks if m.sum() >= 5]
    if not masks:
        return []
    axes = [mask_axes(m) for m in masks]
    p = np.asarray(mix, dtype=float) / np.sum(mix)
    out = []
    for _ in range(n):
        k = int(rng.integers(len(axes)))
        c, th_minor, xy = axes[k]
        h = float(rng.uniform(*jaw_px))
        kind = rng.choice(3, p=p)
        if kind == 0:
            centre = c + rng.normal(0.0, 3.0, size=2)
            theta = th_minor + rng.normal(0.0, np.radians(8))
            w = extent_along(xy, centre, theta, h / 2) + rng.uniform(2.0, 9.0)
        elif kind == 1:
            centre = xy[int(rng.integers(len(xy)))].copy()
            theta = rng.uniform(-np.pi / 2, np.pi / 2)
            inside = masks[k]
            if depth is not None and rng.random() < 0.5:
                zc = depth[int(centre[1]), int(centre[0])]
                inside = inside & (depth > 0) & (depth < zc + 0.02)
            lo, hi = chord(inside, centre, theta)
            mid = 0.5 * (lo + hi)
            centre = centre + mid * np.array([np.cos(theta), -np.sin(theta)])
            w = (hi - lo) + rng.uniform(2.0, 9.0)
        else:
            centre = xy[int(rng.integers(len(xy)))] + rng.uniform(-0.5, 0.5, size=2)
            theta = rng.uniform(-np.pi / 2, np.pi / 2)
            ext = extent_along(xy, centre, theta, h / 2)
            w = max(ext, 8.0) * rng.uniform(0.3, 1.5) + rng.uniform(0.0, 10.0)
        out.append(GraspRectangle(float(centre[0]), float(centre[1]), float(theta),
                                  float(max(w, 4.0)), h))
    return out


def label_rectangles(sim, scene, frame, candidates, params: ExecutionParams | None = None,
                     depth=None, depth_valid=None) -> Labelled:
    """Execute every candidate from the same rebuilt scene state and label it by physics.

    Parameters
    ----------
    sim : graspsim.sim.Simulation
    scene : graspsim.scene.Scene
    frame : RGBDFrame
        The view the rectangles live in (intrinsics, ``T_world_cam`` and, unless ``depth`` is
        given, the observed depth and validity).
    candidates : list of GraspRectangle
    params : ExecutionParams or None
    depth, depth_valid : ndarray of shape (H, W) or None
        Depth to turn rectangles into poses with (e.g. ``frame.depth_clean`` for ground truth
        independent of sensor dropout); defaults to the observed depth.

    Returns
    -------
    Labelled
    """
    depth = frame.depth if depth is None else depth
    valid = frame.depth_valid if depth_valid is None else depth_valid
    results = []
    for rect in candidates:
        g = rectangle_to_grasp(rect, depth, valid, frame.intrinsics, frame.T_world_cam)
        results.append(run_grasp(sim, scene, g, params))
    return Labelled(list(candidates), results)


def rank_positives(labelled: Labelled, radius_px: float = 12.0,
                   max_angle: float = np.radians(20)) -> list[GraspRectangle]:
    """Positives ranked by robustness: how many other positives lie close in centre and angle.

    Ties keep the sampling order. Used by the oracle ("best physics-labelled positive").
    """
    pos = labelled.positives
    if not pos:
        return []
    arr = np.array([[r.x, r.y, r.theta] for r in pos])
    d = np.hypot(arr[:, None, 0] - arr[None, :, 0], arr[:, None, 1] - arr[None, :, 1])
    da = np.mod(arr[:, None, 2] - arr[None, :, 2], np.pi)
    da = np.minimum(da, np.pi - da)
    score = ((d <= radius_px) & (da <= max_angle)).sum(axis=1)
    order = np.argsort(-score, kind="stable")
    return [pos[i] for i in order]
