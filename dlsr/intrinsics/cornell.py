"""The Cornell camera: read from the point cloud's PCD file, fitted and cached, or estimated;
and the range of the preprocessed TIFFs as depth along the optical axis.

Part of :mod:`dlsr.intrinsics`.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..records import CorruptFileError, file_errors
from .fit import MAX_FIT_RMS_PX, fit_camera, fit_camera_matrix
from .matrix import check_camera_matrix, read_camera_file, write_camera_file

__all__ = ["CORNELL_FALLBACK_K", "CornellCamera", "cornell_camera", "cornell_camera_matrix",
           "pcd_camera_matrix", "pcd_points_and_pixels", "range_to_depth", "read_pcd_points"]

logger = logging.getLogger(__name__)

CORNELL_FALLBACK_K = np.array([[585.0, 0.0, 319.5], [0.0, 585.0, 239.5], [0.0, 0.0, 1.0]])
"""A Kinect v1 depth camera at 640 x 480 (see :mod:`dlsr.intrinsics`): Cornell images without their
point cloud."""


def read_pcd_points(path) -> tuple[list[str], np.ndarray]:
    """The fields and rows of a PCD v0.7 ASCII point cloud (Cornell's ``pcdXXXX.txt``).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    fields : list of str
        The header's ``FIELDS`` (Cornell: ``x y z rgb index``).
    data : ndarray of shape (n, len(fields)), float64

    Raises
    ------
    FileNotFoundError, ValueError
        Naming the file: no ``DATA`` line, binary data, a row count other than ``POINTS``, or
        rows with another number of columns than ``FIELDS``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"point cloud not found: {path}")
    header: dict[str, list[str]] = {}
    with file_errors(path, "point cloud"), open(path, encoding="utf-8") as fh:
        n_header = 0
        for line in fh:
            n_header += 1
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            key, *vals = s.split()
            header[key.upper()] = vals
            if key.upper() == "DATA":
                break
        else:
            raise CorruptFileError(f"point cloud {path}: no DATA line in the PCD header")
    if header["DATA"] != ["ascii"]:
        raise ValueError(
            f"point cloud {path}: only 'DATA ascii' is supported, got {header['DATA']}"
        )
    fields = header.get("FIELDS")
    if not fields:
        raise ValueError(f"point cloud {path}: no FIELDS line in the PCD header")
    with file_errors(path, "malformed point cloud data in"), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*input contained no data")  # POINTS checks
        data = np.loadtxt(path, skiprows=n_header, ndmin=2, dtype=np.float64, encoding="utf-8")
    if data.size and data.shape[1] != len(fields):
        raise ValueError(f"point cloud {path}: {data.shape[1]} columns, FIELDS has {len(fields)}")
    points = header.get("POINTS") or [str(len(data))]
    if not points[0].isdigit():
        raise ValueError(f"point cloud {path}: POINTS must be a count, got {points}")
    if len(data) != int(points[0]):
        raise ValueError(f"point cloud {path}: header says {points[0]} points, found "
                         f"{len(data)}")
    return list(fields), data.reshape(-1, len(fields))


def pcd_points_and_pixels(fields, data, width: int = 640, what: str = "point cloud"):
    """The ``x y z`` of a parsed PCD cloud (:func:`read_pcd_points`) and each point's pixel
    ``(col, row)`` from its ``index`` field (``row * width + col``): ``(xyz, pixels)``."""
    if not {"x", "y", "z", "index"} <= set(fields):
        raise ValueError(f"{what}: FIELDS must include x y z index, got {fields}")
    xyz = data[:, [fields.index("x"), fields.index("y"), fields.index("z")]]
    index = data[:, fields.index("index")]
    return xyz, np.column_stack([index % width, index // width])


def pcd_camera_matrix(fields, data, width: int = 640, what: str = "point cloud"):
    """:func:`fit_camera_matrix` of a parsed PCD cloud (:func:`read_pcd_points`) whose
    ``index`` field is ``row * width + col``: ``(K, rms_px)``."""
    return fit_camera_matrix(*pcd_points_and_pixels(fields, data, width, what), what)


@dataclass(frozen=True)
class CornellCamera:
    """The camera of a Cornell image (:func:`cornell_camera`).

    Attributes
    ----------
    K : ndarray of shape (3, 3)
    source : {"camera file", "point cloud", "estimate"}
    T_cam_cloud : ndarray of shape (4, 4) or None
        Cloud (millimetres) to camera coordinates, when fitted to the point cloud.
    rms_px : float or None
        The fit's reprojection error, pixels.
    tiff_depth : {"range", "z"}
        What the image's ``pcdXXXXd.tiff`` holds: ``"range"``, the distance to the camera (the
        common preprocessing's norm of each point: real Cornell), or ``"z"``, the depth along
        the optical axis (graspsim's datasets, whose camera files carry ``T_world_cam``, or a
        camera file saying ``"depth": "z"``).
    """

    K: np.ndarray
    source: str
    T_cam_cloud: np.ndarray | None = None
    rms_px: float | None = None
    tiff_depth: str = "range"


def cornell_camera(image, cache: bool = True, cloud=None, warn: bool = True) -> CornellCamera:
    """The camera of a Cornell image: its matrix, where it came from and, when fitted to the
    point cloud, the cloud's pose in the camera frame.

    In order: the cached ``pcdXXXXcamera.json`` beside the image (one written by an earlier
    fit that assumed the optical frame, without ``T_cam_cloud``, is fitted again); the camera
    fitted to ``pcdXXXX.txt`` in whatever frame its points are (:func:`fit_camera`, written to
    the cache when ``cache`` and the folder is writable, else a logged note); a cloud that
    fits no pinhole camera (fewer than 10 points, or over :data:`MAX_FIT_RMS_PX` px
    reprojection error) gets a logged warning naming it and :data:`CORNELL_FALLBACK_K`, not
    cached; no cloud: :data:`CORNELL_FALLBACK_K`, with a logged warning when ``warn``.

    Parameters
    ----------
    image : path-like
        Any of the image's files (``pcdXXXXr.png``, ``pcdXXXXd.tiff``, ``pcdXXXX.txt``).
    cache : bool
    cloud : (fields, data) or None
        The image's point cloud already read (:func:`read_pcd_points`), to read it once.
    warn : bool
        Log the estimate's warning for an image with neither camera file nor cloud.

    Returns
    -------
    CornellCamera

    Raises
    ------
    ValueError
        The name is not a Cornell one (``pcdXXXX...``), or a camera file or point cloud is
        unreadable (naming it).
    """
    p = Path(image)
    name = p.name
    if not (name.startswith("pcd") and name[3:7].isdigit()):
        raise ValueError(f"{p}: not a Cornell file name (pcdXXXXr.png, pcdXXXXd.tiff)")
    stem = p.parent / name[:7]
    cam, pcd = Path(f"{stem}camera.json"), Path(f"{stem}.txt")
    if cam.is_file():
        rec = read_camera_file(cam)
        stale = (str(rec.get("source", "")).startswith("fitted to")
                 and rec.get("T_cam_cloud") is None and (cloud is not None or pcd.is_file()))
        if not stale:
            return CornellCamera(rec["K"], "camera file", rec.get("T_cam_cloud"),
                                 rec.get("rms_px"), rec["depth"])
    if cloud is None and pcd.is_file():
        cloud = read_pcd_points(pcd)
    if cloud is not None:
        what = f"point cloud {pcd}"
        fit = None
        try:
            fit = fit_camera(*pcd_points_and_pixels(*cloud, what=what), what)
            problem = (None if fit.rms_px <= MAX_FIT_RMS_PX else
                       f"its best pinhole camera leaves {fit.rms_px:.3g} px of reprojection "
                       f"error, over {MAX_FIT_RMS_PX:g} px")
        except ValueError as exc:
            if "FIELDS" in str(exc):
                raise
            problem = str(exc).removeprefix(f"{what}: ")
        if problem is None:
            if cache:
                try:
                    write_camera_file(cam, fit.K, f"fitted to {pcd.name}", fit.rms_px,
                                      fit.T_cam_cloud, fit.model)
                except OSError as exc:
                    logger.info("could not cache the camera of %s in %s: %s", pcd, cam, exc)
            return CornellCamera(fit.K, "point cloud", fit.T_cam_cloud, fit.rms_px)
        logger.warning("%s fits no pinhole camera (%s); using the Kinect v1 estimate f = %.0f "
                       "px (dlsr.intrinsics.CORNELL_FALLBACK_K)", pcd, problem,
                       CORNELL_FALLBACK_K[0, 0])
        return CornellCamera(CORNELL_FALLBACK_K.copy(), "estimate",
                             rms_px=None if fit is None else fit.rms_px)
    if warn:
        logger.warning("%s: no %s or %s; using the Kinect v1 estimate f = %.0f px "
                       "(dlsr.intrinsics.CORNELL_FALLBACK_K; openings in metres may be off by "
                       "about 10 %%)", p, pcd.name, cam.name, CORNELL_FALLBACK_K[0, 0])
    return CornellCamera(CORNELL_FALLBACK_K.copy(), "estimate")


def cornell_camera_matrix(image, cache: bool = True) -> tuple[np.ndarray, str]:
    """:func:`cornell_camera`'s matrix and source, ``(K, source)`` with ``source`` one of
    ``"camera file"``, ``"point cloud"``, ``"estimate"``."""
    c = cornell_camera(image, cache=cache)
    return c.K, c.source


def range_to_depth(range_m, K) -> np.ndarray:
    """Depth along the optical axis from the distance to the optical centre.

    A pixel ``(u, v)``'s ray is ``K^-1 [u v 1]``; a point at distance ``r`` along it has depth
    ``r / |K^-1 [u v 1]|``. Real Cornell's preprocessed ``pcdXXXXd.tiff`` hold ``r`` (the norm
    of each point); ``K`` back-projects depth ``z`` (``X = z K^-1 [u v 1]``): ``r`` is 21 %
    more than ``z`` at the corners of a 640 x 480 image at 585 px.

    Parameters
    ----------
    range_m : ndarray of shape (H, W)
        Distances (0 where missing stays 0).
    K : array-like of shape (3, 3)

    Returns
    -------
    ndarray of shape (H, W), float32
    """
    r = np.asarray(range_m)
    K = check_camera_matrix(K)
    h, w = r.shape
    x = (np.arange(w) - K[0, 2] - K[0, 1] / K[1, 1] * (np.arange(h)[:, None] - K[1, 2])) / K[0, 0]
    y = (np.arange(h)[:, None] - K[1, 2]) / K[1, 1]
    return (r / np.sqrt(x * x + y * y + 1.0)).astype(np.float32)
