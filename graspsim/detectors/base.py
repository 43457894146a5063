"""The protocol every grasp detector follows, and the check of what ``predict`` returns.

A detector is any object with ``predict(obs)`` (the :class:`GraspDetector` protocol, which
documents the observation and the accepted return values); :func:`check_detections` validates
what it returns.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

from dlsr.rectangles import GraspRectangle

__all__ = ["GraspDetector", "check_detections", "one_line"]


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


def one_line(exc: BaseException) -> str:
    """``"TypeName: message"`` of an exception on one line (whitespace runs become a space)."""
    msg = " ".join(str(exc).split())
    return type(exc).__name__ + (f": {msg}" if msg else "")
