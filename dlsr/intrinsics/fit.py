"""The pinhole camera, intrinsics and pose, that maps 3-D points to their pixels.

Part of :mod:`dlsr.intrinsics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .matrix import camera_matrix

__all__ = ["MAX_FIT_RMS_PX", "CameraFit", "fit_camera", "fit_camera_matrix"]

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
