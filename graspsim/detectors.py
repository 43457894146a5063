"""The detector protocol, the baseline detectors and the detector loader.

A detector is any object with ``predict(obs)`` (the :class:`GraspDetector` protocol below, which
documents the observation and the accepted return values); :func:`check_detections` validates
what it returns. Built-in detectors:

* ``random``: a uniformly random rectangle anywhere in the image (succeeds rarely).
* ``mask-pca``: segments the object from depth alone (the table plane is fitted in ``1/z``, which
  is linear in the pixel coordinates for any plane, so no intrinsics are needed), then grasps at
  the mask centroid across its minor axis, opening = the mask's extent there plus a margin.
* ``oracle``: the best physics-labelled positive (needs ``obs["positives"]``).

Plug-ins (:func:`load_detector`): ``"package.module:NAME"`` imports ``NAME`` (a class or a
factory, called with the detector options as keyword arguments -- none by default --, or an
object with ``predict``) from a module on ``sys.path`` or in the current folder; installed
packages can register names in the entry-point group ``graspsim.detectors`` (see
:data:`ENTRY_POINT_GROUP`). Options come from ``--detector-option KEY=VALUE``
(:func:`parse_detector_options`) or a run configuration's ``detector_options`` table; a
detector's recorded name says them (:func:`detector_label`).
"""

from __future__ import annotations

import copy
import importlib
import json
import os
import re
import sys
from collections.abc import Mapping
from importlib.metadata import entry_points
from typing import Any, Protocol, runtime_checkable

import numpy as np

from dlsr.rectangles import GraspRectangle

from .labelling import extent_along, mask_axes

__all__ = [
    "GraspDetector",
    "check_detections",
    "PluginDetector",
    "ENTRY_POINT_GROUP",
    "AWARE_SUFFIX",
    "RandomDetector",
    "MaskPCADetector",
    "OracleDetector",
    "GripperAwareDetector",
    "executable",
    "gripper_aware",
    "DETECTORS",
    "load_detector",
    "check_detector",
    "check_detector_options",
    "detector_label",
    "parse_detector_options",
    "plugin_names",
    "object_mask_from_depth",
]


@runtime_checkable
class GraspDetector(Protocol):
    """What the trial harness, ``graspsim trials --detector`` and ``graspsim run`` accept.

    ``predict(obs)`` is called once per grasp attempt, in the process that runs the trial (a
    worker process with ``--jobs`` > 1), and must not modify ``obs``.

    Observation ``obs`` (a dict; every array is the harness's own copy):

    * ``rgb``: ndarray of shape (H, W, 3), uint8, RGB.
    * ``depth``: ndarray of shape (H, W), float32, metres along the optical axis (z, not ray
      length), 0 where the simulated sensor has no reading; never NaN.
    * ``depth_valid``: ndarray of shape (H, W), uint8, 1 where ``depth`` holds a reading.
    * ``K``: ndarray of shape (3, 3), float64, the pinhole camera matrix in pixels
      (``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``; pixel centres at integer coordinates).
    * ``T_world_cam``: ndarray of shape (4, 4), float64, the camera pose: it maps points in the
      camera frame (OpenCV: x right, y down, z forward along the optical axis; metres) to the
      world frame (z up; the table top is the plane z = 0).
    * ``seed``: int, a seed for a stochastic detector
      (``np.random.default_rng(obs["seed"])``), so that results repeat across runs and workers.
    * ``positives``: list of GraspRectangle, best first, only when the scene was labelled by
      physics (the trial's ``n_candidates > 0``): the labelling's successful rectangles, for
      oracles. A detector that needs them sets a class attribute ``requires_labels = True``.

    Return value, best first (the harness executes the first rectangle):

    * a list of :class:`~dlsr.rectangles.GraspRectangle`; or
    * an array of shape (n, 5), rows ``(x, y, theta, w, h)``: centre column and row (pixels),
      closing direction in radians counter-clockwise as displayed, opening ``w`` and jaw size
      ``h`` (pixels, > 0) -- the project's rectangle convention (``CONTRIBUTING.md``); or
    * a tuple ``(rectangles, scores)`` of either form above and an array of shape (n,) of
      finite floats (higher = better, in the detector's own units). The order of
      ``rectangles`` is the ranking; the scores are recorded (the executed grasp's ``score``)
      and not used to reorder.

    An empty list or an array of shape (0, 5) means "no grasp proposed". Anything else (another
    type, a wrong shape, NaN or infinite values, a non-positive ``w`` or ``h``, scores of
    another length) stops the run with a one-line error; an exception raised by ``predict``
    is recorded as that trial's failure (``"detector error: TypeName: message"``).
    """

    def predict(self, obs: Mapping[str, Any]) -> Any:
        """Rectangles for one observation, best first.

        Parameters
        ----------
        obs : dict
            The observation: ``rgb``, ``depth``, ``depth_valid``, ``K``, ``T_world_cam``,
            ``seed`` and, for oracles, ``positives`` (described above).

        Returns
        -------
        list of GraspRectangle, or ndarray of shape (n, 5), or tuple
            The rectangles best first, or ``(rectangles, scores)`` with scores of shape (n,)
            (described above).
        """
        ...


def check_detections(result, name: str = "detector"):
    """Validate what a detector's ``predict`` returned (see :class:`GraspDetector`).

    Parameters
    ----------
    result : list of GraspRectangle, array-like of shape (n, 5), or (rectangles, scores)
    name : str
        The detector's name, for error messages.

    Returns
    -------
    rects : list of GraspRectangle
        In the detector's order (best first); empty when nothing was proposed.
    scores : ndarray of shape (n,), float64, or None
        None when the detector gave no scores.

    Raises
    ------
    ValueError
        One line naming the detector and what is wrong with its return value.
    """
    scores = None
    if isinstance(result, tuple):
        if len(result) != 2:
            raise ValueError(f"detector {name!r} returned a tuple of {len(result)} items; "
                             "expected (rectangles, scores)")
        result, scores = result
    if isinstance(result, list | tuple):
        bad = [i for i, r in enumerate(result) if not isinstance(r, GraspRectangle)]
        if bad:
            raise ValueError(
                f"detector {name!r} returned a list whose item {bad[0]} is a "
                f"{type(result[bad[0]]).__name__}, not a GraspRectangle (return a list of "
                "GraspRectangle or an (n, 5) array)"
            )
        rects = list(result)
    elif isinstance(result, np.ndarray) or hasattr(result, "__array__"):
        arr = np.asarray(result)
        if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number) \
                or np.issubdtype(arr.dtype, np.complexfloating):
            raise ValueError(f"detector {name!r} returned an array of dtype {arr.dtype}; "
                             "expected real numbers (x, y, theta, w, h)")
        if arr.ndim != 2 or arr.shape[1] != 5:
            raise ValueError(f"detector {name!r} returned an array of shape {arr.shape}; "
                             "expected (n, 5) rows (x, y, theta, w, h)")
        arr = arr.astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        if bad.size:
            raise ValueError(f"detector {name!r} returned non-finite values in row {bad[0]}: "
                             f"{arr[bad[0]].tolist()}")
        bad = np.flatnonzero((arr[:, 3] <= 0) | (arr[:, 4] <= 0))
        if bad.size:
            raise ValueError(f"detector {name!r} returned a non-positive opening or jaw size "
                             f"in row {bad[0]}: {arr[bad[0]].tolist()}")
        rects = [GraspRectangle(*row) for row in arr]
    else:
        raise ValueError(
            f"detector {name!r} returned a {type(result).__name__}; expected a list of "
            "GraspRectangle, an (n, 5) array, or a (rectangles, scores) tuple"
        )
    if scores is not None:
        s = np.asarray(scores)
        if s.dtype == bool or not np.issubdtype(s.dtype, np.number) \
                or np.issubdtype(s.dtype, np.complexfloating):
            raise ValueError(f"detector {name!r} returned scores of dtype {s.dtype}; "
                             "expected real numbers")
        if s.shape != (len(rects),):
            raise ValueError(f"detector {name!r} returned scores of shape {s.shape} for "
                             f"{len(rects)} rectangles; expected ({len(rects)},)")
        s = s.astype(np.float64)
        if not np.all(np.isfinite(s)):
            raise ValueError(f"detector {name!r} returned non-finite scores: {s.tolist()}")
        scores = s
    return rects, scores


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


ENTRY_POINT_GROUP = "graspsim.detectors"
"""Entry-point group in which installed packages register detector names: in a package's
``pyproject.toml``, ``[project.entry-points."graspsim.detectors"]`` then
``mynet = "mypkg.detect:MyDetector"``; ``--detector mynet`` then loads it."""

# ``package.module:NAME`` (NAME may be dotted: ``module:Class.factory``), as entry points write it.
_SPEC = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


def executable(rects, obs, table_depth=None, tolerance: float = 0.003,
               unseen_surface: bool = True, min_grip: float | None = None,
               hand: str = "builtin") -> np.ndarray:
    """Which rectangles this gripper can execute, judged from the observation alone.

    A rectangle passes when :func:`graspsim.grasp.rectangle_to_grasp` gives it a pose (depth
    under its centre, opening within the gripper's reach) and the open fingers, coming down
    along the approach, meet no surface seen in the depth image
    (:func:`graspsim.grasp.fingers_collide`, with the table surface fitted to the depth as
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
        along the optical axis as in :func:`graspsim.grasp.rectangle_to_grasp`).
    table_depth : ndarray of shape (H, W) or None
        The table's depth; fitted to ``obs["depth"]`` when None.
    tolerance : float
        Metres (see :func:`graspsim.grasp.fingers_collide`).
    unseen_surface : bool
        Fingers must also miss the object's unseen surface (above).
    min_grip : float or None
        Metres. Judge each grasp as a harness with ``ExecutionParams(min_grip=...)`` executes it:
        fingers that would meet a surface stop short of it if they still grip this much
        (:func:`graspsim.grasp.settle_fingers`); None (the harness's default): they do not.
    hand : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        The gripper's hand, whose geometry (opening, fingers, palm) is checked
        (:mod:`graspsim.hands`): the harness's ``ExecutionParams.gripper.hand``.

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
        from dlsr.detection import table_plane_mask, table_surface

        from .hands import hand_geometry

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
        from .grasp import fingers_collide, rectangle_to_grasp, settle_fingers

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
            from dlsr.detection import fill_unseen_surface, table_plane_mask

            region = self.region
            if region is None:
                region = table_plane_mask(self.depth, self.valid)
            filled, seen = fill_unseen_surface(self.depth, self.valid, region)
            self._filled = (filled, seen, bool((seen != self.valid).any()))
        return self._filled[2]

    def strict(self, i) -> bool:
        """Whether rectangle ``i``'s fingers (judged by :meth:`plain` first) also miss the
        unseen surface."""
        from .grasp import fingers_collide

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
        Metres (see :func:`graspsim.grasp.fingers_collide`).
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
        import dataclasses
        import time

        t0 = time.perf_counter()
        det = self.detector.detect(obs)
        if not len(det.rects):
            return det
        from dlsr.rectangles import array_to_rects

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
    gripper reaches (``SearchGrid.max_width``, :data:`graspsim.gripper.MAX_OPENING`), and to
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
    import dataclasses

    from dlsr.detection import DenseDetector, ExactGridDetector, LatticeDetector

    from .ggcnn.detector import GGCNNDetector
    from .hands import hand_geometry

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


class PluginDetector:
    """A detector loaded from a plug-in (``module:NAME`` or an entry-point name).

    It predicts with the loaded object and pickles as its name and the folder its module came
    from, so a worker process (loky, Ray) imports the plug-in again, once per process, even
    when that folder is not on the worker's ``sys.path``.

    Parameters
    ----------
    spec : str
        What was asked for (``"mydet:Detector"`` or an entry-point name).
    detector : object with ``predict(obs)``
    path : str or None
        Folder to put on ``sys.path`` before importing in another process.
    options : dict or None
        The keyword arguments NAME was called with (JSON values), passed again in another
        process.
    """

    def __init__(self, spec, detector, path=None, options=None):
        self.spec = spec
        self.detector = detector
        self.path = path
        self.options = options

    @property
    def label(self) -> str:
        """The name runs record: the spec with its options (:func:`detector_label`)."""
        return detector_label(self.spec, self.options)

    @property
    def requires_labels(self) -> bool:
        return bool(getattr(self.detector, "requires_labels", False))

    def predict(self, obs):
        return self.detector.predict(obs)

    def __repr__(self):
        return f"PluginDetector({self.label!r})"

    def __reduce__(self):
        return (_plugin_in_worker, (self.spec, self.path, self.options))


_WORKER_PLUGINS: dict = {}


def _plugin_in_worker(spec, path, options=None):
    """Unpickling a :class:`PluginDetector`: import it (once per process) from ``path`` too."""
    key = (spec, path, json.dumps(options, sort_keys=True), os.getpid())
    det = _WORKER_PLUGINS.get(key)
    if det is None:
        if path is not None and path not in sys.path:
            sys.path.append(path)
            importlib.invalidate_caches()
        det = load_detector(spec, options)
        _WORKER_PLUGINS[key] = det
    return det


def parse_detector_options(items) -> dict:
    """``["KEY=VALUE", ...]`` (``--detector-option``, repeatable) as a dict of options.

    A value is read as JSON where it parses (``5`` an int, ``0.5`` a float, ``true``, ``null``,
    ``[1, 2]``, ``{"a": 1}``, ``"quoted"`` a string), else kept as the text given
    (``model=runs/net/model.pt``).

    Parameters
    ----------
    items : sequence of str

    Returns
    -------
    dict
        Keys in the order given.

    Raises
    ------
    ValueError
        An item without ``=``, a key that is not an identifier, or a key given twice.
    """
    out = {}
    for item in items or ():
        key, eq, text = str(item).partition("=")
        key = key.strip()
        if not eq or not key.isidentifier():
            raise ValueError(f"--detector-option {item!r}: expected KEY=VALUE with KEY a "
                             "Python identifier (the keyword the detector takes)")
        if key in out:
            raise ValueError(f"--detector-option {key!r} is given twice")
        try:
            out[key] = json.loads(text)
        except ValueError:
            out[key] = text
    return out


def check_detector_options(options, where: str = "detector options") -> dict:
    """``options`` as a plain dict of JSON values with identifier keys (a copy), or an error.

    Parameters
    ----------
    options : dict or None
    where : str
        What the options are, for the message.

    Returns
    -------
    dict
        Empty for None.
    """
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ValueError(f"{where} must be a table of KEY = VALUE, got {options!r}")
    for key in options:
        if not isinstance(key, str) or not key.isidentifier():
            raise ValueError(f"{where}: option name {key!r} is not a Python identifier")
    try:
        return json.loads(json.dumps(dict(options), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: values must be JSON (numbers, strings, booleans, lists, "
                         f"tables): {exc}") from None


#: Longest option value a :func:`detector_label` shows in full.
LABEL_VALUE_WIDTH = 24


def _label_value(value) -> str:
    if isinstance(value, str):
        text = value.rstrip("/\\")
        if "/" in text or os.sep in text:  # a path: its last part says which file or folder
            text = text.replace(os.sep, "/").rsplit("/", 1)[-1] or text
    else:
        text = json.dumps(value, separators=(",", ":"))
    return text if len(text) <= LABEL_VALUE_WIDTH else text[: LABEL_VALUE_WIDTH - 3] + "..."


def detector_label(name, options=None) -> str:
    """A detector's name with its options, as runs record and print it.

    ``name`` alone without options; else ``name(key=value,...)`` with the keys sorted, a path
    shortened to its last part (``model=runs/net/ggcnn.pt`` gives ``model=ggcnn.pt``) and a
    value longer than :data:`LABEL_VALUE_WIDTH` characters cut. The full options are recorded
    beside it (``detector_options`` in ``config.json``).

    Parameters
    ----------
    name : str
    options : dict or None

    Returns
    -------
    str
    """
    if not options:
        return str(name)
    return f"{name}(" + ",".join(f"{k}={_label_value(options[k])}"
                                 for k in sorted(options)) + ")"


def one_line(exc: BaseException) -> str:
    """``"TypeName: message"`` of an exception on one line (whitespace runs become a space)."""
    msg = " ".join(str(exc).split())
    return type(exc).__name__ + (f": {msg}" if msg else "")


def _module_folder(module) -> str | None:
    """The ``sys.path`` entry a top-level module or package was imported from."""
    top = sys.modules.get(module.__name__.split(".")[0], module)
    origin = getattr(top, "__file__", None)
    if origin is None:
        return None
    folder = os.path.dirname(os.path.abspath(origin))
    return os.path.dirname(folder) if hasattr(top, "__path__") else folder


def _import_module(spec: str, module_name: str):
    """Import ``module_name``, retrying with the current folder on ``sys.path``."""
    def missing(exc):  # the plug-in's own module is absent (not one of its imports)
        return exc.name is not None and (module_name == exc.name
                                         or module_name.startswith(exc.name + "."))

    for attempt in (0, 1):
        try:
            return importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if not missing(exc):  # a package the plug-in imports is missing
                raise ValueError(f"plug-in {spec!r}: importing {module_name} failed: "
                                 f"{_missing_text(exc)}") from exc
            cwd = os.getcwd()
            if attempt or cwd in sys.path:
                raise ValueError(
                    f"detector {spec!r}: no module named {exc.name!r} (looked in the current "
                    f"folder {cwd} and on sys.path)"
                ) from exc
            sys.path.append(cwd)  # like `python -m`, but installed modules keep precedence
            importlib.invalidate_caches()
        except Exception as exc:
            raise ValueError(f"plug-in {spec!r}: importing {module_name} failed: "
                             f"{one_line(exc)}") from exc
    raise AssertionError("unreachable")  # pragma: no cover


def _missing_text(exc: ImportError) -> str:
    """``No module named 'x'`` and what to do about it, on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        return f"{text} (install it in the environment graspsim runs in)"
    return text


def _instantiate(spec: str, obj, what: str, options=None):
    """A class or factory is called with ``options`` as keyword arguments; an object with
    ``predict`` is used as it is (and takes no options)."""
    options = options or {}
    call = f"{what}({', '.join(f'{k}={v!r}' for k, v in options.items())})"
    if isinstance(obj, type) or (callable(obj) and not hasattr(obj, "predict")):
        try:
            obj = obj(**options)
        except ImportError as exc:  # the constructor imports a missing package
            raise ValueError(f"plug-in {spec!r}: {call} failed importing "
                             f"{exc.name or 'a module'}: {_missing_text(exc)}") from exc
        except TypeError as exc:
            hint = ("" if options else "; give its arguments with --detector-option KEY=VALUE "
                    "(a run configuration: its detector_options table)")
            raise ValueError(f"plug-in {spec!r}: calling {call} failed: {one_line(exc)}"
                             f"{hint}") from exc
        except Exception as exc:
            raise ValueError(f"plug-in {spec!r}: calling {call} failed: "
                             f"{one_line(exc)}") from exc
    elif options:
        raise ValueError(f"plug-in {spec!r}: {what} is a {type(obj).__name__} object, not a "
                         f"class or factory, and takes no options (given: "
                         f"{', '.join(options)})")
    if not callable(getattr(obj, "predict", None)):
        raise ValueError(f"detector {spec!r}: {what} gave a {type(obj).__name__} with no "
                         "predict(obs) method")
    return obj


def _resolve_spec(spec: str):
    """Import ``module`` of ``module:NAME`` and return ``(NAME's object, module)``."""
    module_name, _, attr = spec.partition(":")
    module = _import_module(spec, module_name)
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            where = getattr(module, "__file__", None) or module_name
            raise ValueError(f"detector {spec!r}: module {module_name!r} ({where}) has no "
                             f"attribute {attr!r}")
        obj = getattr(obj, part)
    return obj, module


def _load_spec(spec: str, options=None) -> PluginDetector:
    obj, module = _resolve_spec(spec)
    return PluginDetector(spec, _instantiate(spec, obj, spec.partition(":")[2], options),
                          _module_folder(module), options or None)


def plugin_names() -> dict:
    """Installed detector plug-ins: ``{name: "module:NAME"}`` of the entry-point group."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _load_entry_point(name: str, options=None) -> PluginDetector | None:
    eps = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
    if not eps:
        return None
    ep = eps[0]
    try:
        obj = ep.load()
    except ImportError as exc:
        raise ValueError(f"plug-in {name!r}: importing {ep.value.partition(':')[0].strip()} "
                         f"(entry point {ep.value!r} of {ENTRY_POINT_GROUP}) failed: "
                         f"{_missing_text(exc)}") from exc
    except Exception as exc:
        raise ValueError(f"detector {name!r}: loading the entry point {ep.value!r} "
                         f"({ENTRY_POINT_GROUP}) failed: {one_line(exc)}") from exc
    module = sys.modules.get(ep.value.partition(":")[0].strip())
    return PluginDetector(name, _instantiate(name, obj, ep.value, options),
                          None if module is None else _module_folder(module), options or None)


#: Appended to a detector's name: the same detector made gripper-aware (:func:`load_detector`).
AWARE_SUFFIX = "+aware"


def load_detector(name_or_path, options=None):
    """A detector from a built-in name, a plug-in, or a saved DLSR model.

    Parameters
    ----------
    name_or_path : str or Path
        Any of the following with ``"+aware"`` appended is that detector made gripper-aware
        (:func:`gripper_aware`, as ``graspsim trials --gripper-aware``), so that run configs
        can list both. In this order: ``"random"``, ``"mask-pca"``, ``"oracle"``;
        ``"package.module:NAME"``
        (a class or a no-argument factory, or an object with ``predict``; the module is looked
        up on ``sys.path``, then in the current folder); a name registered by an installed
        package in the entry-point group ``graspsim.detectors``; the path of a model saved by
        :meth:`dlsr.detection.DLSRDetector.save` (``.npz`` + ``.json``, with or without the
        suffix), which detects with the options saved in the model; the path of a GG-CNN
        model (``MODEL.pt`` + ``MODEL.json``, :mod:`graspsim.ggcnn`).
    options : dict or None
        Keyword arguments for a plug-in's class or factory, or a built-in detector's class
        (:func:`parse_detector_options` reads them from ``KEY=VALUE`` text). A saved model
        detects with the options saved in it and takes none.

    Returns
    -------
    object with ``predict(obs)``
        Plug-ins come wrapped in a :class:`PluginDetector` (which re-imports them in worker
        processes).

    Raises
    ------
    ValueError
        A plug-in that cannot be imported (the message names the missing module), lacks the
        attribute, has no ``predict`` or does not take the options.
    FileNotFoundError
        If it is none of the above.
    """
    key = str(name_or_path)
    options = check_detector_options(options, f"detector {key!r}: options")
    if key in DETECTORS:
        try:
            return DETECTORS[key](**options)
        except TypeError as exc:
            raise ValueError(f"detector {key!r}: {one_line(exc)}") from exc
    if key.endswith(AWARE_SUFFIX) and key != AWARE_SUFFIX:
        return gripper_aware(load_detector(key[: -len(AWARE_SUFFIX)], options))
    if _SPEC.match(key):
        return _load_spec(key, options)
    det = _load_entry_point(key, options)
    if det is not None:
        return det
    if options:
        raise ValueError(f"detector {key!r}: options ({', '.join(options)}) are for plug-ins "
                         "and the built-in detectors; a saved model detects with the options "
                         "saved in it")
    from .ggcnn.model import is_ggcnn_model

    if is_ggcnn_model(key):
        from .ggcnn.detector import GGCNNDetector

        det = GGCNNDetector(key)
        det._loaded()  # one line naming a broken file, or how to install torch
        return det
    from dlsr.detection import DLSRDetector

    npz, js = DLSRDetector._paths(key)
    if npz.exists() or js.exists():
        return DLSRDetector.load(key).detector()  # names the missing or broken file
    installed = ", ".join(sorted(plugin_names())) or "none installed"
    raise FileNotFoundError(
        f"unknown detector {key!r}: not one of {', '.join(DETECTORS)}, not a plug-in "
        f"(package.module:NAME, or an entry point of {ENTRY_POINT_GROUP}: {installed}) and no "
        f"saved model ({npz} + {js})"
    )


def _check_signature(spec: str, obj, options: dict) -> None:
    """The options bind to the class's or factory's parameters (checked without calling it)."""
    import inspect

    if not (isinstance(obj, type) or (callable(obj) and not hasattr(obj, "predict"))):
        if options:
            raise ValueError(f"plug-in {spec!r}: a {type(obj).__name__} object, not a class or "
                             f"factory, takes no options (given: {', '.join(options)})")
        return
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):  # a builtin without a signature: called as it is
        return
    try:
        signature.bind(**options)
    except TypeError as exc:
        hint = ("" if options else "; give its arguments with --detector-option KEY=VALUE (a "
                "run configuration: its detector_options table)")
        raise ValueError(f"plug-in {spec!r}: {spec.partition(':')[2]}{signature} does not take "
                         f"the options given ({', '.join(options) or 'none'}): {exc}"
                         f"{hint}") from None


def check_detector(name_or_path, options=None) -> None:
    """Raise the error :func:`load_detector` would give for ``name_or_path``, without loading it.

    A plug-in's module is imported and NAME looked up (a class must have ``predict``), but no
    factory or class is called and no model is read, so checking costs no checkpoint load; use
    it to reject a bad name before a long run starts. ``options`` are checked to be JSON
    values with identifier names, and refused for a saved model.
    """
    key = str(name_or_path)
    options = check_detector_options(options, f"detector {key!r}: options")
    if key in DETECTORS:
        return
    if key.endswith(AWARE_SUFFIX) and key != AWARE_SUFFIX:
        check_detector(key[: -len(AWARE_SUFFIX)], options)
        return
    if _SPEC.match(key):
        obj, _ = _resolve_spec(key)
        if isinstance(obj, type) and not callable(getattr(obj, "predict", None)):
            raise ValueError(f"detector {key!r}: class {obj.__name__} has no predict(obs) "
                             "method")
        if not callable(obj) and not callable(getattr(obj, "predict", None)):
            raise ValueError(f"detector {key!r}: {type(obj).__name__} object is neither a "
                             "class, a factory nor a detector with predict(obs)")
        _check_signature(key, obj, options)
        return
    if key in plugin_names():
        return
    if options:
        raise ValueError(f"detector {key!r}: options ({', '.join(options)}) are for plug-ins "
                         "and the built-in detectors; a saved model detects with the options "
                         "saved in it")
    from .ggcnn.model import is_ggcnn_model, require_torch

    if is_ggcnn_model(key):
        require_torch()
        return
    from dlsr.detection import DLSRDetector

    npz, js = DLSRDetector._paths(key)
    if npz.exists() or js.exists():
        return
    load_detector(key)  # raises the full message
