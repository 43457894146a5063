"""Gripper-aware detection: a detector's ranking judged by whether the hand can execute each
rectangle (the fingers clear the scene's depth and the object fits the opening), the first
executable ones proposed (:func:`gripper_aware`, ``--gripper-aware``).
"""

from __future__ import annotations

import copy
import dataclasses
import time

import numpy as np

from dlsr.detection import (
    DenseDetector,
    ExactGridDetector,
    LatticeDetector,
    fill_unseen_surface,
    table_plane_mask,
    table_surface,
)
from dlsr.rectangles import GraspRectangle, array_to_rects

from ..sim.grasp import fingers_collide, rectangle_to_grasp, settle_fingers
from ..sim.hands import hand_geometry
from .base import check_detections
from .ggcnn.detector import GGCNNDetector

__all__ = ["executable", "GripperAwareDetector", "gripper_aware"]


def executable(rects, obs, table_depth=None, tolerance: float = 0.003,
               unseen_surface: bool = True, min_grip: float | None = None,
               hand: str = "builtin") -> np.ndarray:
    """Which rectangles this gripper can execute, judged from the observation alone.

    A rectangle passes when :func:`graspsim.sim.grasp.rectangle_to_grasp` gives it a pose (depth
    under its centre, opening within the gripper's reach) and the open fingers, coming down
    along the approach, meet no surface seen in the depth image
    (:func:`graspsim.sim.grasp.fingers_collide`, with the table surface fitted to the depth as
    :func:`dlsr.detection.table_surface` finds it, where the executor stops the fingertips).

    With ``unseen_surface`` the fingers must also miss the object's surface the sensor did not
    return: inside the object region (:func:`dlsr.detection.table_plane_mask`, completed with
    the missing depth inside its convex hull) a pixel without depth counts as the nearest seen
    pixel of the object (:func:`dlsr.detection.fill_unseen_surface`): the rim of a dark or
    enamelled mug, the wall of a glass. When no rectangle of ``rects`` passes so, the verdicts
    without it are returned (an object the sensor hardly sees still gets a grasp). Not in the
    paper; chosen on validation scenes of train objects (README, "Making DLSR grasp").

    Parameters
    ----------
    rects : sequence of GraspRectangle
    obs : mapping
        The observation (``depth``, ``depth_valid``, ``K``, optionally ``T_world_cam``:
        without it, a real image, the camera frame stands for the world's, the approach
        along the optical axis as in :func:`graspsim.sim.grasp.rectangle_to_grasp`).
    table_depth : ndarray of shape (H, W) or None
        The table's depth; fitted to ``obs["depth"]`` when None.
    tolerance : float
        Metres (see :func:`graspsim.sim.grasp.fingers_collide`).
    unseen_surface : bool
        Fingers must also miss the object's unseen surface (above).
    min_grip : float or None
        Metres. Judge each grasp as a harness with ``ExecutionParams(min_grip=...)`` executes it:
        fingers that would meet a surface stop short of it if they still grip this much
        (:func:`graspsim.sim.grasp.settle_fingers`); None (the harness's default): they do not.
    hand : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        The gripper's hand, whose geometry (opening, fingers, palm) is checked
        (:mod:`graspsim.sim.hands`): the harness's ``ExecutionParams.gripper.hand``.

    Returns
    -------
    ndarray of shape (n,), bool
    """
    judge = _Judge(rects, obs, table_depth, tolerance, unseen_surface, min_grip, hand)
    out = np.array([judge.plain(i) for i in range(len(rects))], dtype=bool)
    if out.any() and judge.strict_applies():
        strict = out.copy()
        for i in np.flatnonzero(out):
            strict[i] = judge.strict(i)
        if strict.any():
            return strict
    return out


def _first_executable(rects, obs, keep: int, tolerance: float = 0.003,
                      unseen_surface: bool = True, min_grip: float | None = None,
                      hand: str = "builtin") -> np.ndarray:
    """``np.flatnonzero(executable(rects, obs, ...))[:keep]``, judging the rectangles in order
    only until ``keep`` of them are known to pass (the gripper-aware detectors keep no more):
    the same indices, without judging the rest of a ranking of 40."""
    judge = _Judge(rects, obs, None, tolerance, unseen_surface, min_grip, hand)
    plain, strict = [], []
    for i in range(len(rects)):
        if not judge.plain(i):
            continue
        plain.append(i)
        if not judge.strict_applies():  # the fingers see no unseen surface: plain verdicts
            if len(plain) >= keep:
                break
            continue
        if judge.strict(i):
            strict.append(i)
            if len(strict) >= keep:  # some pass with the unseen surface: those are the verdicts
                break
    chosen = strict if strict else plain
    return np.asarray(chosen[:keep], dtype=np.intp)


class _Judge:
    """:func:`executable`'s verdicts on one observation, one rectangle at a time: the table
    fitted (or found in the memo) and the unseen surface filled once, when first needed."""

    def __init__(self, rects, obs, table_depth, tolerance, unseen_surface, min_grip, hand):
        self.geo = hand_geometry(hand)
        for key in ("depth", "K"):
            if obs.get(key) is None:
                raise ValueError(f"judging rectangles executable needs the observation's "
                                 f"{key!r}")
        if obs.get("T_world_cam") is None:  # a real image: the check is in the camera's frame
            obs = dict(obs, T_world_cam=np.eye(4))
        self.rects, self.obs = rects, obs
        self.tolerance, self.unseen_surface, self.min_grip = tolerance, unseen_surface, min_grip
        depth = np.asarray(obs["depth"], dtype=np.float32)
        self.depth = depth
        self.valid = np.asarray(obs.get("depth_valid", depth > 0), dtype=bool) & (depth > 0)
        self.region = None
        if table_depth is None and len(rects):
            if unseen_surface:  # the table fitted once for both
                self.region, table_depth = table_plane_mask(depth, self.valid,
                                                            return_surface=True)
            else:
                table_depth = table_surface(depth, self.valid)
        self.table_depth = table_depth
        self.grasps = {}
        self._filled = None

    def plain(self, i) -> bool:
        """Whether rectangle ``i`` has a pose and its fingers meet no surface seen."""
        o, geo = self.obs, self.geo
        g = rectangle_to_grasp(self.rects[i], self.depth, self.valid, o["K"], o["T_world_cam"],
                               max_opening=geo.max_opening, geometry=geo)
        if self.min_grip is not None:
            g = settle_fingers(g, self.depth, self.valid, o["K"], o["T_world_cam"],
                               self.table_depth, min_grip=self.min_grip, geometry=geo)
        self.grasps[i] = g
        return g.failure is None and not fingers_collide(
            g, self.depth, self.valid, o["K"], o["T_world_cam"], self.table_depth,
            tolerance=self.tolerance, geometry=geo)

    def strict_applies(self) -> bool:
        """Whether the unseen surface is checked and fills any pixel (computed on first call)."""
        if not self.unseen_surface:
            return False
        if self._filled is None:
            region = self.region
            if region is None:
                region = table_plane_mask(self.depth, self.valid)
            filled, seen = fill_unseen_surface(self.depth, self.valid, region)
            self._filled = (filled, seen, bool((seen != self.valid).any()))
        return self._filled[2]

    def strict(self, i) -> bool:
        """Whether rectangle ``i``'s fingers (judged by :meth:`plain` first) also miss the
        unseen surface."""
        filled, seen, _ = self._filled
        o = self.obs
        return not fingers_collide(self.grasps[i], filled, seen, o["K"], o["T_world_cam"],
                                   self.table_depth, tolerance=self.tolerance,
                                   geometry=self.geo)


class GripperAwareDetector:
    """Another detector's ranking, keeping the rectangles the gripper can execute.

    The wrapped detector proposes its ranked rectangles; those :func:`executable` rejects
    (no depth at the centre, wider than the gripper opens, a finger landing on a surface seen in
    the depth image, or on the object's unseen surface: ``unseen_surface``) are dropped and
    the first ``keep`` of the others returned in the same order.
    Nothing of the simulator's state is used: a real robot can run the same check on its own
    camera's depth. A departure from the paper (which ranks rectangles by appearance alone).

    Parameters
    ----------
    detector : object with ``predict(obs)``
        Ranks rectangles, best first; it should propose several (e.g. a DLSR detector with
        ``top_k=40``) so that some remain.
    keep : int
        Rectangles returned at most.
    tolerance : float
        Metres (see :func:`graspsim.sim.grasp.fingers_collide`).
    unseen_surface : bool
        See :func:`executable`.
    min_grip : float or None
        See :func:`executable`: set it to the harness's ``ExecutionParams.min_grip``.
    hand : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        See :func:`executable`: set it to the harness's ``ExecutionParams.gripper.hand``.
    """

    def __init__(self, detector, keep: int = 5, tolerance: float = 0.003,
                 unseen_surface: bool = True, min_grip: float | None = None,
                 hand: str = "builtin"):
        self.detector = detector
        self.keep = keep
        self.tolerance = tolerance
        self.unseen_surface = unseen_surface
        self.min_grip = min_grip
        self.hand = hand

    @property
    def requires_labels(self) -> bool:
        """As the wrapped detector (an oracle needs the scene's labels)."""
        return bool(getattr(self.detector, "requires_labels", False))

    def predict(self, obs) -> list[GraspRectangle]:
        rects, _ = check_detections(self.detector.predict(obs), type(self.detector).__name__)
        if not rects:
            return []
        keep = _first_executable(rects, obs, self.keep, tolerance=self.tolerance,
                                 unseen_surface=self.unseen_surface, min_grip=self.min_grip,
                                 hand=getattr(self, "hand", "builtin"))
        return [rects[i] for i in keep]

    def detect(self, obs):
        """The wrapped DLSR detector's :class:`dlsr.detection.Detection`, keeping the
        rectangles :func:`executable` passes (the first ``keep``, with their scores); its
        ``reason`` says so when none passes."""
        t0 = time.perf_counter()
        det = self.detector.detect(obs)
        if not len(det.rects):
            return det

        keep = _first_executable(array_to_rects(det.rects), obs, self.keep,
                                 tolerance=self.tolerance, unseen_surface=self.unseen_surface,
                                 min_grip=self.min_grip, hand=getattr(self, "hand", "builtin"))
        reason = None if len(keep) else (f"none of the {len(det.rects)} best rectangles is "
                                         "executable by this gripper")
        return dataclasses.replace(det, rects=det.rects[keep], scores=det.scores[keep],
                                   seconds=det.seconds + time.perf_counter() - t0,
                                   reason=reason)

    def __repr__(self):
        hand = getattr(self, "hand", "builtin")
        return (f"GripperAwareDetector({self.detector!r}, keep={self.keep}, "
                f"unseen_surface={self.unseen_surface}, min_grip={self.min_grip}"
                + ("" if hand == "builtin" else f", hand={hand!r}") + ")")


def gripper_aware(detector, top_k: int = 40, keep: int = 5, unseen_surface: bool = True,
                  min_grip: float | None = None, hand: str = "builtin") -> GripperAwareDetector:
    """``detector`` made aware of this gripper (:class:`GripperAwareDetector`).

    A DLSR grid detector (:class:`dlsr.detection.DenseDetector` or
    :class:`~dlsr.detection.ExactGridDetector`) is first told to search only rectangles whose
    jaws come down beside the object region (``SearchGrid.clear_jaws``) with an opening the
    gripper reaches (``SearchGrid.max_width``, :data:`graspsim.sim.gripper.MAX_OPENING`), and to
    return its best ``top_k`` (rescoring at least as many exactly); a
    :class:`dlsr.detection.LatticeDetector` (whose candidates already span the object) is told
    the gripper's reach and to return its best ``top_k``; any other detector is wrapped as it
    is.

    Parameters
    ----------
    detector : object with ``predict(obs)``
    top_k : int
        DLSR candidates ranked before the check.
    keep : int
    unseen_surface : bool
        The fingers must also miss the object's unseen surface (:func:`executable`).
    min_grip : float or None
        As the harness's ``ExecutionParams.min_grip`` (:func:`executable`).
    hand : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        As the harness's ``ExecutionParams.gripper.hand``: its largest opening bounds the
        search and its geometry is checked (:func:`executable`).

    Returns
    -------
    GripperAwareDetector
    """
    MAX_OPENING = hand_geometry(hand).max_opening  # noqa: N806

    if isinstance(detector, LatticeDetector):
        detector = copy.copy(detector)
        if detector.max_width is None or detector.max_width > MAX_OPENING:
            detector.max_width = MAX_OPENING
        detector.top_k = max(int(top_k), int(detector.top_k))
    elif isinstance(detector, DenseDetector | ExactGridDetector):
        detector = copy.copy(detector)
        detector.grid = dataclasses.replace(detector.grid, clear_jaws=True,
                                            max_width=MAX_OPENING)
        detector.top_k = max(int(top_k), int(detector.top_k))
        if isinstance(detector, DenseDetector) and detector.rescore:
            detector.rescore = max(int(detector.rescore), detector.top_k)
    elif isinstance(detector, GGCNNDetector):  # more of its quality peaks to choose from
        detector = copy.copy(detector)
        detector.top_k = max(int(top_k), int(detector.top_k))
    return GripperAwareDetector(detector, keep=keep, unseen_surface=unseen_surface,
                                min_grip=min_grip, hand=hand)
