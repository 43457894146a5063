"""Ground truth by physics: propose rectangles on the object mask and execute every one.

:func:`sample_candidates` proposes rectangles so that both classes are well represented: about
half are "informed" (centre near the object's centroid, closing direction near the mask's minor
axis, opening just wider than the mask's extent along it -- mostly successes) and the rest vary
centre (any mask pixel), angle (uniform), opening (narrower or much wider than the extent) and jaw
size (mostly failures). ``sample_candidates(..., mode="dense")`` (:func:`dense_candidates`)
instead covers the space of grasps on the object -- positions over the mask, every 15 degrees,
two openings and two jaw sizes, within the gripper's reach -- for dense, Jacquard-like labels.
:func:`label_rectangles` executes each candidate from the same rebuilt scene state
(``resetSimulation`` + reload, deterministic) and returns the physical outcomes; obvious
collisions and empty closes are decided geometrically first
(:func:`graspsim.sim.execution.precheck_grasps`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dlsr.detection.lattice import chord, chords, lattice_candidates, lattice_step
from dlsr.detection.lattice import max_width_px as _max_width_px
from dlsr.detection.physical import mask_axes
from dlsr.rectangles import GraspRectangle

from ..sim.execution import ExecutionParams, GraspResult, harness_grasps, precheck_grasps, run_grasp
from ..sim.gripper import MAX_OPENING

__all__ = [
    "Labelled",
    "sample_candidates",
    "SAMPLERS",
    "check_sampler",
    "dense_candidates",
    "max_width_px",
    "chord",
    "chords",
    "extent_along",
    "label_rectangles",
    "mask_axes",
    "rank_order",
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


SAMPLERS = ("mixed", "dense")


def check_sampler(mode: str, name: str = "sampler") -> str:
    """``mode`` if it names a candidate sampler of :func:`sample_candidates`, else a ValueError
    naming the setting (``name``)."""
    if mode not in SAMPLERS:
        raise ValueError(f"{name} must be one of {', '.join(SAMPLERS)}, got {mode!r}")
    return mode


def sample_candidates(segmentation, object_ids, rng: np.random.Generator, n: int = 32,
                      jaw_px=(10.0, 28.0), depth=None,
                      mix=(0.35, 0.35, 0.30), mode: str = "mixed", intrinsics=None,
                      max_opening: float = MAX_OPENING,
                      spacing: float | None = None) -> list[GraspRectangle]:
    """Propose ``n`` rectangles on the objects' masks.

    ``mode="dense"`` covers the space of grasps on the objects instead (see
    :func:`dense_candidates`, which receives ``n`` as its budget, ``jaw_px``, ``depth``,
    ``intrinsics``, ``max_opening`` and ``spacing``). The default ``mode="mixed"`` draws three
    kinds, with probabilities ``mix``:

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
    mode : {"mixed", "dense"}
    intrinsics, max_opening, spacing
        Dense mode only (see :func:`dense_candidates`).

    Returns
    -------
    list of GraspRectangle
        Empty when no object is visible.
    """
    if check_sampler(mode, "mode") == "dense":
        return dense_candidates(segmentation, object_ids, rng, depth, intrinsics, n=n,
                                jaw_px=jaw_px, max_opening=max_opening, spacing=spacing)
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


def max_width_px(z, theta, intrinsics, max_opening: float = MAX_OPENING):
    """:func:`dlsr.detection.lattice.max_width_px` for this gripper (``MAX_OPENING`` metres)."""
    return _max_width_px(z, theta, intrinsics, max_opening)


def dense_candidates(segmentation, object_ids, rng: np.random.Generator, depth, intrinsics,
                     n: int | None = None, jaw_px=(10.0, 28.0),
                     max_opening: float = MAX_OPENING, spacing: float | None = None,
                     n_angles: int = 12, margin_px: float = 4.0, depth_band: float = 0.02,
                     reach: float = 0.95) -> list[GraspRectangle]:
    """Rectangles covering the space of grasps on the objects (Jacquard-like dense labels).

    Like the Jacquard dataset (Depierre, Dellandrea and Chen, 2018), whose labels are the
    simulated grasps that succeed among many tried all over each object, the candidates span
    positions, angles, openings and jaw sizes: a lattice of points over each object mask
    (``spacing`` pixels apart, at a random offset), and at each point every closing direction
    ``pi / n_angles`` apart (15 degrees by default) with

    * the contiguous run of mask pixels through the point along that direction (centred on
      it) and, when it differs, the run of pixels no more than ``depth_band`` deeper than the
      point (rims, handles, arms), each with two openings: the run plus ``margin_px``, and
      1.3 x the run plus ``2 margin_px``;
    * two jaw sizes, a quarter of the way into ``jaw_px`` from either end.

    Openings the gripper cannot reach are not generated: wider than ``reach`` x
    :func:`max_width_px` at the depth under the centre. Duplicates (same rounded centre, angle,
    opening and jaw size) are dropped.

    Parameters
    ----------
    segmentation : ndarray of shape (H, W), int
        Body id per pixel.
    object_ids : sequence of int
    rng : numpy.random.Generator
        Draws the lattice offset and, with a budget, the subset kept.
    depth : ndarray of shape (H, W), float
        Clean depth, metres (0 where nothing was rendered).
    intrinsics : CameraIntrinsics or ndarray of shape (3, 3)
    n : int or None
        Budget: at most ``n`` candidates, a uniformly random subset (in generation order) when
        the lattice gives more; None keeps all.
    jaw_px : (float, float)
        Range of jaw sizes ``h``, pixels.
    max_opening : float
        The gripper's largest opening, metres.
    spacing : float or None
        Lattice step, pixels; default half the smaller jaw size, so that a grasp anywhere on
        the object lies within a quarter jaw of a lattice line (Jaccard index well above 0.25
        with the nearest candidate of the same size).
    n_angles : int
        Closing directions over pi.
    margin_px, depth_band, reach : float
        Pixels, metres, fraction.

    Returns
    -------
    list of GraspRectangle
        Empty when no object is visible.

    Raises
    ------
    ValueError
        Without depth or intrinsics, or when their shapes do not match the segmentation.
    """
    if depth is None or intrinsics is None:
        raise ValueError("dense candidates need the depth and the camera intrinsics "
                         "(to keep openings within the gripper's reach)")
    seg = np.asarray(segmentation)
    depth = np.asarray(depth, dtype=float)
    if depth.shape != seg.shape or seg.ndim != 2:
        raise ValueError(f"depth {depth.shape} and segmentation {seg.shape} must be the same "
                         "(H, W)")
    if n is not None and n < 1:
        raise ValueError(f"the candidate budget n must be >= 1 or None, got {n}")
    if n_angles < 1:
        raise ValueError(f"n_angles must be >= 1, got {n_angles}")
    _, step = lattice_step(jaw_px, spacing)
    offset = rng.uniform(0.0, step, size=2)
    out: list[GraspRectangle] = []
    seen: set = set()
    for b in object_ids:
        out += lattice_candidates(seg == b, depth, intrinsics, offset, max_opening, jaw_px,
                                  spacing, n_angles, margin_px, depth_band, reach, seen)
    if n is not None and len(out) > n:
        keep = np.sort(rng.choice(len(out), size=n, replace=False))
        out = [out[i] for i in keep]
    return out


def label_rectangles(sim, scene, frame, candidates, params: ExecutionParams | None = None,
                     depth=None, depth_valid=None, fast: bool = True) -> Labelled:
    """Execute every candidate from the same rebuilt scene state and label it by physics.

    With ``fast`` (the default), :func:`graspsim.sim.execution.precheck_grasps` first decides the
    obvious collisions and empty closes geometrically in one built scene, and the other grasps
    are executed with ``hold_until_still=True`` (the hold ends once the object is at rest in the
    hand). ``fast=False`` executes every grasp with ``params`` as given (the reference). The two
    gave the same verdict (success and failure reason) for every one of 896 grasps compared
    by ``scripts/bench_labelling.py`` (512 dense and 384 mixed candidates, 8 scenes of the
    train objects, seed 5).

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    scene : graspsim.sim.scene.Scene
    frame : RGBDFrame
        The view the rectangles live in (intrinsics, ``T_world_cam`` and, unless ``depth`` is
        given, the observed depth and validity).
    candidates : list of GraspRectangle
    params : ExecutionParams or None
    depth, depth_valid : ndarray of shape (H, W) or None
        Depth to turn rectangles into poses with (e.g. ``frame.depth_clean`` for ground truth
        independent of sensor dropout); defaults to the observed depth.
    fast : bool
        Geometric precheck and the early-ending hold (see above).

    Returns
    -------
    Labelled
        Results decided without stepping have ``steps == 0``.
    """
    grasps = harness_grasps(candidates, frame, scene.table_z, params, depth, depth_valid)
    if not fast:
        return Labelled(list(candidates), [run_grasp(sim, scene, g, params) for g in grasps])
    p = replace(ExecutionParams() if params is None else params, hold_until_still=True)
    decided = precheck_grasps(sim, scene, grasps, p)
    results = [r if r is not None else run_grasp(sim, scene, g, p)
               for g, r in zip(grasps, decided, strict=True)]
    return Labelled(list(candidates), results)


def rank_order(labelled: Labelled, radius_px: float = 12.0,
               max_angle: float = np.radians(20)) -> list[int]:
    """The indices into ``labelled.rects`` of the positives, ranked as :func:`rank_positives`
    ranks them (what :mod:`graspsim.labels.store` keeps of a labelled scene)."""
    idx = [i for i, r in enumerate(labelled.results) if r.success]
    if not idx:
        return []
    arr = np.array([[labelled.rects[i].x, labelled.rects[i].y, labelled.rects[i].theta]
                    for i in idx])
    d = np.hypot(arr[:, None, 0] - arr[None, :, 0], arr[:, None, 1] - arr[None, :, 1])
    da = np.mod(arr[:, None, 2] - arr[None, :, 2], np.pi)
    da = np.minimum(da, np.pi - da)
    score = ((d <= radius_px) & (da <= max_angle)).sum(axis=1)
    order = np.argsort(-score, kind="stable")
    return [idx[i] for i in order]


def rank_positives(labelled: Labelled, radius_px: float = 12.0,
                   max_angle: float = np.radians(20)) -> list[GraspRectangle]:
    """Positives ranked by robustness: how many other positives lie close in centre and angle.

    Ties keep the sampling order. Used by the oracle ("best physics-labelled positive").
    """
    return [labelled.rects[i] for i in rank_order(labelled, radius_px, max_angle)]
