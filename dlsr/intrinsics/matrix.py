"""Pinhole camera matrices: built from four numbers, checked, read from a camera file.

Part of :mod:`dlsr.intrinsics`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..records import write_text_atomic

__all__ = ["camera_matrix", "check_camera_matrix", "read_camera_file", "read_camera_matrix",
           "write_camera_file"]


def check_camera_matrix(K, what: str = "the camera matrix 'K'") -> np.ndarray:
    """``K`` as a float (3, 3) array, or a ValueError naming ``what`` unless it is a 3x3
    camera matrix of finite values with positive focal lengths. An object with a ``K``
    attribute (camera intrinsics) stands for its matrix."""
    K = getattr(K, "K", K)
    try:
        K = np.asarray(K, dtype=float)
    except (ValueError, TypeError) as e:
        raise ValueError(f"{what} must be a 3x3 camera matrix, got {K!r}"[:300]) from e
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{what} must be a 3x3 camera matrix with positive focal lengths, "
                         f"got {K.tolist()}")
    return K


def camera_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3x3 pinhole matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (pixels)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=float)


def read_camera_file(path) -> dict:
    """The record of a camera file (``pcdXXXXcamera.json``: graspsim's datasets, or the
    cache of :func:`dlsr.intrinsics.cornell_camera`), checked.

    Returns
    -------
    dict
        ``K`` as a (3, 3) array, ``T_cam_cloud`` as a (4, 4) array when present, ``depth``
        (``"z"`` or ``"range"``: what the image's depth TIFF holds; ``"z"`` for files with
        ``T_world_cam``, graspsim's, unless they say otherwise) and the file's other keys.

    Raises
    ------
    ValueError
        Not JSON, no ``K``, not a 3x3 matrix with positive focal lengths, a bad
        ``T_cam_cloud`` or ``depth`` (naming the file).
    """
    path = Path(path)
    try:
        rec = json.loads(path.read_text())
        rec["K"] = check_camera_matrix(rec["K"], f"camera file {path}: 'K'")
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"camera file {path}: no readable 'K' ({e})") from e
    T = rec.get("T_cam_cloud")
    if T is not None:
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"camera file {path}: 'T_cam_cloud' must be a finite 4x4 matrix")
        rec["T_cam_cloud"] = T
    depth = rec.get("depth", "z" if "T_world_cam" in rec else "range")
    if depth not in ("range", "z"):
        raise ValueError(f"camera file {path}: 'depth' must be 'range' or 'z', got {depth!r}")
    rec["depth"] = depth
    return rec


def read_camera_matrix(path) -> np.ndarray:
    """The 3x3 ``K`` of a camera file (``pcdXXXXcamera.json``, :mod:`graspsim.datagen`, or
    the cache of :func:`cornell_camera`).

    Raises
    ------
    ValueError
        Not JSON, no ``K``, or not a 3x3 matrix with positive focal lengths (naming the file).
    """
    return read_camera_file(path)["K"]


def write_camera_file(path, K, source: str, rms_px: float | None = None,
                      T_cam_cloud=None, model: str | None = None) -> Path:
    """Write a camera file (``{"K": ..., "source": ...}``, with the fit's ``rms_px``,
    ``model`` and ``T_cam_cloud`` when given) atomically; the format
    :func:`read_camera_file` and :func:`dlsr.intrinsics.cornell_camera` read."""
    body = {"K": np.asarray(K, dtype=float).tolist(), "source": source}
    if rms_px is not None:
        body["rms_px"] = round(float(rms_px), 4)
    if model is not None:
        body["model"] = model
    if T_cam_cloud is not None:
        body["T_cam_cloud"] = np.asarray(T_cam_cloud, dtype=float).tolist()
    write_text_atomic(Path(path), json.dumps(body, indent=2) + "\n")
    return Path(path)
