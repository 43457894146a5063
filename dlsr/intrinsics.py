"""Camera matrices of real datasets: fitted where the data has them, estimated where it has not.

* **Cornell** records a PCD point cloud per image (``pcdXXXX.txt``): each point's ``x y z``
  (millimetres, camera frame) and the pixel it belongs to (``index = row * 640 + col``). A
  pinhole camera maps it to ``u = fx x / z + cx``, ``v = fy y / z + cy``, two linear
  least-squares problems in ``(fx, cx)`` and ``(fy, cy)`` (:func:`fit_camera_matrix`): the
  fit is exact up to the pixel quantisation of the index (a residual of about 0.3 px). The
  matrix is cached beside the images as ``pcdXXXXcamera.json`` (the file
  :func:`dlsr.datasets.load_cornell` and ``graspsim detect`` read). A Cornell image without its
  point cloud (only the preprocessed ``pcdXXXXd.tiff``) gets :data:`CORNELL_FALLBACK_K`, an
  estimate (below).
* **Jacquard** ships no intrinsics. Its grasp files measure the jaw size in pixels, and the
  Jacquard paper's simulated gripper has jaws of 1, 2, 3, 4 and 6 cm (Depierre, Dellandrea and
  Chen, "Jacquard: A Large Scale Dataset for Robotic Grasp Detection", IROS 2018): a jaw of
  ``h`` px at depth ``z`` m is ``h z / f`` m, so ``h z`` clusters at ``f`` times those sizes.
  On the 28 sample views the clusters sit at 1 : 2 : 3 : 4 : 6 (the paper's sizes, up to the
  unit) and give ``f`` = :data:`JACQUARD_FOCAL_PX` px for the 1024 x 1024 renders
  (:func:`focal_from_jaw_sizes`), with the principal point assumed at the image centre.

How far off the estimates can be
--------------------------------
* Jacquard: the views' own estimates lie within 1.2 % of the pooled one (1879 to 1911 px;
  tested within 2 %), the spread inside a cluster (the jaw measured at the grasp centre's
  depth, not at the jaws) is about 2 %; a principal point a few pixels off the centre moves
  an off-centre grasp's metric opening by well under 1 %. So openings in metres are within
  about 3 % (if the paper's sizes are right: they are what makes the clusters 1:2:3:4:6).
* Cornell without a point cloud: the Kinect v1 depth camera's focal length is about 585 px at
  640 x 480 (the value PCL's KinectFusion maintainers measured against the 525 px of the
  colour camera, PointCloudLibrary/pcl pull request 389); devices differ by a few per cent and
  a registered cloud may use the colour camera's 525 px, so openings from it can be off by up
  to about 10 %. Give the point cloud (or ``--intrinsics``) when it matters.
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path

import numpy as np

from .records import CorruptFileError, file_errors, write_text_atomic

__all__ = [
    "CORNELL_FALLBACK_K",
    "JACQUARD_FOCAL_PX",
    "JACQUARD_JAW_SIZES_M",
    "camera_matrix",
    "check_camera_matrix",
    "read_camera_matrix",
    "fit_camera_matrix",
    "focal_from_jaw_sizes",
    "jacquard_camera_matrix",
    "read_pcd_points",
    "cornell_camera_matrix",
    "write_camera_file",
]

logger = logging.getLogger(__name__)

JACQUARD_JAW_SIZES_M = (0.01, 0.02, 0.03, 0.04, 0.06)
"""The jaw sizes of the Jacquard paper's simulated gripper, metres."""

JACQUARD_FOCAL_PX = 1900.0
"""Focal length of the Jacquard renders (1024 x 1024), pixels: :func:`focal_from_jaw_sizes`
pooled over the 28 sample views (perfect depth): 1900.2 px; the views' own estimates range
from 1879 to 1911 px."""

CORNELL_FALLBACK_K = np.array([[585.0, 0.0, 319.5], [0.0, 585.0, 239.5], [0.0, 0.0, 1.0]])
"""A Kinect v1 depth camera at 640 x 480 (see the module notes): Cornell images without their
point cloud."""


def read_camera_matrix(path) -> np.ndarray:
    """The 3x3 ``K`` of a camera file (``pcdXXXXcamera.json``, :mod:`graspsim.datagen`).

    Raises
    ------
    ValueError
        Not JSON, no ``K``, or not a 3x3 matrix with positive focal lengths (naming the file).
    """
    path = Path(path)
    try:
        K = json.loads(path.read_text())["K"]
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"camera file {path}: no readable 'K' ({e})") from e
    return check_camera_matrix(K, f"camera file {path}: 'K'")


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


def fit_camera_matrix(points, pixels, what: str = "the points"):
    """Least-squares pinhole camera matrix of 3-D points and the pixels they project to.

    Parameters
    ----------
    points : array-like of shape (n, 3)
        Camera-frame ``x y z`` (any unit; only ``x / z`` and ``y / z`` matter), ``z > 0``.
    pixels : array-like of shape (n, 2)
        ``(col, row)`` of each point.
    what : str
        Names the data in errors.

    Returns
    -------
    K : ndarray of shape (3, 3)
    rms_px : float
        Root-mean-square reprojection error, pixels.

    Raises
    ------
    ValueError
        Fewer than 10 points in front of the camera, or points that do not constrain a focal
        length (all on one column or row ray), naming ``what``.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if len(P) != len(uv):
        raise ValueError(f"{what}: {len(P)} points but {len(uv)} pixels")
    ok = np.isfinite(P).all(axis=1) & np.isfinite(uv).all(axis=1) & (P[:, 2] > 0)
    if ok.sum() < 10:
        raise ValueError(f"{what}: {int(ok.sum())} points in front of the camera, need at "
                         "least 10 to fit a camera matrix")
    P, uv = P[ok], uv[ok]
    coef, res = [], []
    for axis in (0, 1):
        a = P[:, axis] / P[:, 2]
        if np.ptp(a) < 1e-6:
            raise ValueError(f"{what}: the points do not spread across the image; no focal "
                             "length can be fitted")
        A = np.column_stack([a, np.ones_like(a)])
        c, *_ = np.linalg.lstsq(A, uv[:, axis], rcond=None)
        coef.append(c)
        res.append(A @ c - uv[:, axis])
    (fx, cx), (fy, cy) = coef
    if fx <= 0 or fy <= 0:
        raise ValueError(f"{what}: fitted a negative focal length ({fx:.4g}, {fy:.4g}); are "
                         "x and y in the camera frame (x right, y down)?")
    rms = float(np.sqrt(np.mean(np.square(res[0]) + np.square(res[1]))))
    return camera_matrix(fx, fy, cx, cy), rms


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


def pcd_camera_matrix(fields, data, width: int = 640, what: str = "point cloud"):
    """:func:`fit_camera_matrix` of a parsed PCD cloud (:func:`read_pcd_points`) whose
    ``index`` field is ``row * width + col``: ``(K, rms_px)``."""
    if not {"x", "y", "z", "index"} <= set(fields):
        raise ValueError(f"{what}: FIELDS must include x y z index, got {fields}")
    xyz = data[:, [fields.index("x"), fields.index("y"), fields.index("z")]]
    index = data[:, fields.index("index")]
    pixels = np.column_stack([index % width, index // width])
    return fit_camera_matrix(xyz, pixels, what)


def write_camera_file(path, K, source: str, rms_px: float | None = None) -> Path:
    """Write a camera file (``{"K": ..., "source": ...}``) atomically; the format
    :func:`dlsr.datasets.read_camera_matrix` reads."""
    body = {"K": np.asarray(K, dtype=float).tolist(), "source": source}
    if rms_px is not None:
        body["rms_px"] = round(float(rms_px), 4)
    write_text_atomic(Path(path), json.dumps(body, indent=2) + "\n")
    return Path(path)


def cornell_camera_matrix(image, cache: bool = True) -> tuple[np.ndarray, str]:
    """The camera matrix of a Cornell image, and where it came from.

    In order: the cached ``pcdXXXXcamera.json`` beside the image; the matrix fitted to
    ``pcdXXXX.txt`` (:func:`fit_camera_matrix`, written to the cache when ``cache`` and the
    folder is writable, else a logged note); :data:`CORNELL_FALLBACK_K` with a logged warning.

    Parameters
    ----------
    image : path-like
        Any of the image's files (``pcdXXXXr.png``, ``pcdXXXXd.tiff``, ``pcdXXXX.txt``).
    cache : bool

    Returns
    -------
    K : ndarray of shape (3, 3)
    source : {"camera file", "point cloud", "estimate"}

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
        return read_camera_matrix(cam), "camera file"
    if pcd.is_file():
        fields, data = read_pcd_points(pcd)
        K, rms = pcd_camera_matrix(fields, data, what=f"point cloud {pcd}")
        if cache:
            try:
                write_camera_file(cam, K, f"fitted to {pcd.name}", rms)
            except OSError as exc:
                logger.info("could not cache the camera matrix of %s in %s: %s", pcd, cam, exc)
        return K, "point cloud"
    logger.warning("%s: no %s or %s; using the Kinect v1 estimate f = %.0f px "
                   "(dlsr.intrinsics.CORNELL_FALLBACK_K; openings in metres may be off by "
                   "about 10 %%)", p, pcd.name, cam.name, CORNELL_FALLBACK_K[0, 0])
    return CORNELL_FALLBACK_K.copy(), "estimate"


def jacquard_camera_matrix(shape=(1024, 1024)) -> np.ndarray:
    """The estimated camera matrix of a Jacquard render of ``shape`` (H, W): the focal length
    :data:`JACQUARD_FOCAL_PX` scaled from 1024 px wide, the principal point at the centre."""
    H, W = int(shape[0]), int(shape[1])
    s = W / 1024.0
    return camera_matrix(JACQUARD_FOCAL_PX * s, JACQUARD_FOCAL_PX * s, (W - 1) / 2, (H - 1) / 2)


def focal_from_jaw_sizes(jaw_px, depth_m, sizes_m=JACQUARD_JAW_SIZES_M) -> float:
    """Focal length (pixels) from jaw sizes in pixels at known depths, the metric sizes being
    from a known set.

    ``jaw_px * depth_m`` is ``f`` times a size of ``sizes_m``; each product is assigned the
    size whose multiple of a first guess (the 2nd percentile of the products over the smallest
    size) is nearest, and ``f`` is the median of ``product / size``, refined three times.

    Parameters
    ----------
    jaw_px : array-like of shape (n,)
        Jaw sizes, pixels (Jacquard's ``jaw_size``).
    depth_m : array-like of shape (n,)
        Depth at each grasp centre, metres (missing: <= 0 or non-finite, ignored).
    sizes_m : sequence of float
        The metric jaw sizes.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        With no grasp at a valid depth.
    """
    h = np.asarray(jaw_px, dtype=float).ravel()
    z = np.asarray(depth_m, dtype=float).ravel()
    sizes = np.asarray(sizes_m, dtype=float)
    ok = np.isfinite(h) & np.isfinite(z) & (z > 0) & (h > 0)
    if not ok.any():
        raise ValueError("no grasp at a valid depth to estimate a focal length from")
    v = h[ok] * z[ok]
    f = float(np.percentile(v, 2) / sizes.min())  # the smallest jaws are the commonest
    for _ in range(3):
        size = sizes[np.argmin(np.abs(v[:, None] - f * sizes[None, :]), axis=1)]
        f = float(np.median(v / size))
    return f
