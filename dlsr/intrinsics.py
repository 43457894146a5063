"""Camera matrices of real datasets: fitted where the data has them, estimated where it has not.

* **Cornell** records a PCD point cloud per image (``pcdXXXX.txt``): each point's ``x y z``
  (millimetres) and the pixel it belongs to (``index = row * 640 + col``). The points need not
  be in the camera's optical frame: real Cornell clouds are forward-left-up and tilted with
  the camera (a row of ``pcd0100.txt`` reads ``1924.064 -647.111 -119.4176 0 25547``: x the
  distance forward, y to the left, z up). :func:`fit_camera` fits the whole pinhole camera,
  intrinsics and pose, to the point/pixel pairs (a rotation about the cloud's origin, else a
  general 3 x 4 projection; exact up to the pixel quantisation of the index, about 0.3 px).
  The matrix, the cloud's pose ``T_cam_cloud`` and the residual are cached beside the images
  as ``pcdXXXXcamera.json`` (the file :func:`dlsr.datasets.load_cornell` and ``graspsim
  detect`` read). A cloud that fits no pinhole camera gets a warning naming it and the
  estimate below; the image still loads. A Cornell image without its point cloud (only the
  preprocessed ``pcdXXXXd.tiff``) gets :data:`CORNELL_FALLBACK_K`, an estimate (below).
* **Depth.** The pipeline's depth is the depth along the optical axis, ``z``, as the
  simulator renders it and as ``K`` back-projects it (``X = z K^-1 [u v 1]``). The common
  Cornell preprocessing writes the *range*, the norm of each point, into ``pcdXXXXd.tiff``:
  up to 21 % more than ``z`` at the corners of a 640 x 480 image at 585 px. So a Cornell
  cloud's depth is its points' ``z`` in the fitted camera frame, and a TIFF beside a cloud or
  its fitted camera is converted
  (:func:`range_to_depth`). A TIFF alone, without a camera, is used as read (``K`` unknown):
  give the point cloud or a camera file when the metric features matter. graspsim's own
  datasets write ``z`` (their camera files carry ``T_world_cam``).
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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .records import CorruptFileError, file_errors, write_text_atomic

__all__ = [
    "CORNELL_FALLBACK_K",
    "JACQUARD_FOCAL_PX",
    "JACQUARD_JAW_SIZES_M",
    "MAX_FIT_RMS_PX",
    "CameraFit",
    "CornellCamera",
    "camera_matrix",
    "check_camera_matrix",
    "read_camera_matrix",
    "fit_camera",
    "fit_camera_matrix",
    "focal_from_jaw_sizes",
    "jacquard_camera_matrix",
    "read_pcd_points",
    "pcd_points_and_pixels",
    "cornell_camera",
    "cornell_camera_matrix",
    "range_to_depth",
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
    """The 3x3 ``K`` of a camera file (``pcdXXXXcamera.json``, :mod:`graspsim.datagen`, or
    the cache of :func:`cornell_camera`).

    Raises
    ------
    ValueError
        Not JSON, no ``K``, or not a 3x3 matrix with positive focal lengths (naming the file).
    """
    return _camera_record(Path(path))["K"]


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


MAX_FIT_RMS_PX = 2.0
"""A point cloud whose best pinhole camera leaves a larger root-mean-square reprojection error
(pixels) fits no camera: :func:`cornell_camera` warns and uses :data:`CORNELL_FALLBACK_K`. An
exact cloud leaves about 0.3 px (the pixel index is quantised to whole pixels)."""

_FIT_POINTS = 20000  # points the fit uses (evenly spaced through the cloud); the rms uses all


@dataclass(frozen=True)
class CameraFit:
    """A pinhole camera fitted to 3-D points and the pixels they project to.

    Attributes
    ----------
    K : ndarray of shape (3, 3)
        The camera matrix (zero skew), pixels.
    T_cam_cloud : ndarray of shape (4, 4)
        Maps the cloud's coordinates to the camera's (OpenCV: x right, y down, z along the
        optical axis), in the cloud's unit. Its rotation is proper unless the cloud's frame is
        left-handed.
    rms_px : float
        Root-mean-square reprojection error over all points, pixels.
    model : {"centred", "projection"}
        ``"centred"``: the cloud's origin is the optical centre (a rotation only, as a depth
        camera's own cloud in any axis convention); ``"projection"``: a general 3 x 4
        projection (rotation and translation), tried when the centred camera does not fit.
    """

    K: np.ndarray
    T_cam_cloud: np.ndarray
    rms_px: float
    model: str

    def depth(self, points) -> np.ndarray:
        """Depth of ``points`` (cloud frame, shape (n, 3)) along the optical axis, in the
        cloud's unit."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        return P @ self.T_cam_cloud[2, :3] + self.T_cam_cloud[2, 3]


def _normaliser(x: np.ndarray) -> np.ndarray:
    """Hartley's similarity taking the rows of ``x`` (n, d) to their centroid at the origin
    and a mean distance of sqrt(d): ``(d + 1, d + 1)``."""
    c = x.mean(axis=0)
    s = np.sqrt(x.shape[1]) / max(float(np.mean(np.linalg.norm(x - c, axis=1))), 1e-12)
    T = np.eye(x.shape[1] + 1)
    T[:-1, :-1] *= s
    T[:-1, -1] = -s * c
    return T


def _dlt(X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The (3, m) matrix ``P`` minimising the algebraic error of ``[u v 1] ~ P X`` for
    homogeneous ``X`` of shape (n, m) (the direct linear transform), pixels normalised."""
    Tp = _normaliser(uv)
    u = uv @ Tp[:2, :2].T + Tp[:2, 2]
    n, m = X.shape
    A = np.zeros((2 * n, 3 * m))
    A[0::2, 0:m] = X
    A[0::2, 2 * m:] = -u[:, :1] * X
    A[1::2, m:2 * m] = X
    A[1::2, 2 * m:] = -u[:, 1:] * X
    P = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, m)
    return np.linalg.solve(Tp, P)


def _intrinsics_and_rotation(M: np.ndarray):
    """``M = s K R`` (RQ decomposition) with ``K`` upper triangular, positive diagonal and
    ``K[2, 2] = 1``, ``R`` orthogonal; returns ``(K, R, s)``."""
    from scipy.linalg import rq

    K, R = rq(M)
    D = np.diag(np.sign(np.diag(K)) + (np.diag(K) == 0))
    K, R = K @ D, D @ R
    return K / K[2, 2], R, K[2, 2]


def _project(params, X, reflect, with_t):
    from scipy.spatial.transform import Rotation

    fx, fy, cx, cy = params[:4]
    R = Rotation.from_rotvec(params[4:7]).as_matrix() @ reflect
    C = X @ R.T + (params[7:10] if with_t else 0.0)
    z = np.where(np.abs(C[:, 2]) > 1e-12, C[:, 2], 1e-12)
    return np.column_stack([fx * C[:, 0] / z + cx, fy * C[:, 1] / z + cy])


def _refine(K, R, t, X, uv, with_t):
    """Least-squares reprojection refinement of a zero-skew camera from a linear estimate."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    reflect = np.diag([1.0, 1.0, np.sign(np.linalg.det(R))])
    x0 = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
                         Rotation.from_matrix(R @ reflect).as_rotvec(),
                         t if with_t else []])
    res = least_squares(lambda p: (_project(p, X, reflect, with_t) - uv).ravel(), x0,
                        x_scale="jac", method="lm")
    p = res.x
    K = camera_matrix(*p[:4])
    R = Rotation.from_rotvec(p[4:7]).as_matrix() @ reflect
    return K, R, (p[7:10] if with_t else np.zeros(3))


def _rms(K, T, X, uv) -> float:
    C = X @ T[:3, :3].T + T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = (C @ K.T)[:, :2] / C[:, 2:3]
    err = np.sum((proj - uv) ** 2, axis=1)
    return float(np.sqrt(np.mean(np.where(np.isfinite(err), err, 1e12))))


def _transform(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def fit_camera(points, pixels, what: str = "the points") -> CameraFit:
    """The pinhole camera (intrinsics and pose) that best maps 3-D points to their pixels.

    The points may be in any frame: the camera's optical frame, a depth camera's
    forward-left-up frame, or either tilted. First the camera is assumed centred on the
    cloud's origin (a depth camera's own cloud): the rays ``x / |x|`` map to the pixels by a
    homography ``K R``, fitted by the direct linear transform and split by an RQ
    decomposition, which is well posed even when all points lie on a table's plane. When that
    leaves more than :data:`MAX_FIT_RMS_PX` and the points are not coplanar, a general 3 x 4
    projection ``K [R | t]`` is fitted the same way and kept if it reprojects better. Either
    is refined by least squares on the reprojection error with zero skew (Hartley and
    Zisserman, *Multiple View Geometry*, 2nd ed., sections 4.4, 6.1 and 6.2).

    Parameters
    ----------
    points : array-like of shape (n, 3)
        ``x y z`` in any unit and frame.
    pixels : array-like of shape (n, 2)
        ``(col, row)`` of each point.
    what : str
        Names the data in errors.

    Returns
    -------
    CameraFit
        Check ``rms_px``: a large error means no pinhole camera explains the points.

    Raises
    ------
    ValueError
        Fewer than 10 usable points, or points that do not spread across the image (all on
        one row, column or line), naming ``what``.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if len(P) != len(uv):
        raise ValueError(f"{what}: {len(P)} points but {len(uv)} pixels")
    norm = np.linalg.norm(P, axis=1)
    ok = np.isfinite(P).all(axis=1) & np.isfinite(uv).all(axis=1) & (norm > 0)
    if ok.sum() < 10:
        raise ValueError(f"{what}: {int(ok.sum())} usable points, need at least 10 to fit a "
                         "camera matrix")
    P, uv, norm = P[ok], uv[ok], norm[ok]
    centred_uv = uv - uv.mean(axis=0)
    sv = np.linalg.svd(centred_uv, compute_uv=False)
    if sv[-1] < 1e-6 * max(sv[0], 1e-12) or np.ptp(uv[:, 0]) < 1 or np.ptp(uv[:, 1]) < 1:
        raise ValueError(f"{what}: the points do not spread across the image; no focal "
                         "length can be fitted")
    sub = np.unique(np.linspace(0, len(P) - 1, min(len(P), _FIT_POINTS)).astype(int))
    Xs, uvs = P[sub], uv[sub]

    # centred: [u v 1] ~ K R x, a homography of the rays
    rays = Xs / norm[sub, None]
    H = _dlt(rays, uvs)
    H *= np.sign(np.median(rays @ H[2]))  # points in front of the camera
    K, R, _ = _intrinsics_and_rotation(H)
    K, R, t = _refine(K, R, np.zeros(3), Xs, uvs, with_t=False)
    best = CameraFit(K, _transform(R, t), _rms(K, _transform(R, t), P, uv), "centred")
    if best.rms_px <= MAX_FIT_RMS_PX:
        return best

    # projection: [u v 1] ~ K (R x + t), when the points span three dimensions
    spread = np.linalg.svd(Xs - Xs.mean(axis=0), compute_uv=False)
    if spread[-1] < 1e-3 * spread[0]:
        return best
    Tx = _normaliser(Xs)
    Pm = _dlt(np.column_stack([Xs, np.ones(len(Xs))]) @ Tx.T, uvs) @ Tx
    Pm *= np.sign(np.median(np.column_stack([Xs, np.ones(len(Xs))]) @ Pm[2]))
    K, R, s = _intrinsics_and_rotation(Pm[:, :3])
    t = np.linalg.solve(s * K, Pm[:, 3])
    K, R, t = _refine(K, R, t, Xs, uvs, with_t=True)
    general = CameraFit(K, _transform(R, t), _rms(K, _transform(R, t), P, uv), "projection")
    return general if general.rms_px < best.rms_px else best


def fit_camera_matrix(points, pixels, what: str = "the points"):
    """:func:`fit_camera`'s camera matrix and reprojection error, ``(K, rms_px)``."""
    fit = fit_camera(points, pixels, what)
    return fit.K, fit.rms_px


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


def write_camera_file(path, K, source: str, rms_px: float | None = None,
                      T_cam_cloud=None, model: str | None = None) -> Path:
    """Write a camera file (``{"K": ..., "source": ...}``, with the fit's ``rms_px``,
    ``model`` and ``T_cam_cloud`` when given) atomically; the format
    :func:`read_camera_matrix` and :func:`cornell_camera` read."""
    body = {"K": np.asarray(K, dtype=float).tolist(), "source": source}
    if rms_px is not None:
        body["rms_px"] = round(float(rms_px), 4)
    if model is not None:
        body["model"] = model
    if T_cam_cloud is not None:
        body["T_cam_cloud"] = np.asarray(T_cam_cloud, dtype=float).tolist()
    write_text_atomic(Path(path), json.dumps(body, indent=2) + "\n")
    return Path(path)


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


def _camera_record(path: Path) -> dict:
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
        rec = _camera_record(cam)
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
