"""Lattice candidates: rectangles fitted to the object, everywhere on it, every 15 degrees.

The paper's search (:func:`dlsr.detection.enumerate_candidates`) lays a fixed grid of openings
and jaw sizes over the object region, so most candidates are too narrow to span the object or
far wider than it. :func:`lattice_candidates` instead fits each candidate to the object, as the
Jacquard dataset's annotation does (Depierre, Dellandrea and Chen, 2018: simulated grasps tried
all over each object): at points of a lattice over the region and every closing direction, the
opening is the object's chord through the point (and the chord of the surface no deeper than
the point, for rims and handles) plus a margin, within the gripper's reach. The physics labeller
(:func:`graspsim.labelling.dense_candidates`) draws its candidates from the same lattice, on the
simulator's object mask; :class:`LatticeDetector` draws them from the observation's object
region and ranks them with a trained model (its DLSR score, plus its physical term when the
model has one, :mod:`dlsr.detection.physical`).

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from ..datasets import check_camera_matrix
from ..rectangles import GraspRectangle, normalize_angle
from .exact import Detection, _check_obs, _empty, _observed_region
from .grid import _nearest_fill, complete_region, table_surface
from .model import PATCHES_PER_RECTANGLE
from .registry import register_detector

__all__ = ["LatticeDetector", "chord", "chords", "lattice_candidates", "lattice_step",
           "max_width_px"]


def chord(inside, centre, theta, max_px: float = 120.0) -> tuple[float, float]:
    """Contiguous run of ``inside`` pixels through ``centre`` along ``theta``.

    Returns
    -------
    (lo, hi) : offsets in pixels along the direction (``lo <= 0 <= hi``); ``(0, 0)`` when the
    centre itself is outside.
    """
    lo, hi = chords(inside, centre, np.array([theta]), max_px)
    return float(lo[0]), float(hi[0])


def chords(inside, centre, thetas, max_px: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`chord` for several directions at once.

    Parameters
    ----------
    inside : ndarray of shape (H, W), bool
    centre : ndarray of shape (2,)
        ``(x, y)`` pixels.
    thetas : ndarray of shape (k,)
        Radians.
    max_px : float
        Longest run followed in each direction, pixels.

    Returns
    -------
    lo, hi : ndarray of shape (k,)
        Offsets in pixels along each direction.
    """
    H, W = inside.shape
    thetas = np.asarray(thetas, dtype=float)
    u = np.column_stack([np.cos(thetas), -np.sin(thetas)])
    t = np.arange(0.0, max_px + 1.0)
    ends = []
    for sgn in (1.0, -1.0):
        pts = np.rint(np.asarray(centre, float)[None, None, :]
                      + sgn * t[None, :, None] * u[:, None, :]).astype(int)
        ok = (pts[..., 0] >= 0) & (pts[..., 0] < W) & (pts[..., 1] >= 0) & (pts[..., 1] < H)
        run = np.zeros(ok.shape, dtype=bool)
        run[ok] = inside[pts[..., 1][ok], pts[..., 0][ok]]
        stop = np.where(run.all(axis=1), len(t), np.argmin(run, axis=1))
        ends.append(np.maximum(stop - 1, 0) * sgn)
    return ends[1].astype(float), ends[0].astype(float)


def max_width_px(z, theta, intrinsics, max_opening: float):
    """Widest rectangle opening (pixels) the gripper can reach, from depth and intrinsics.

    The inverse of :func:`graspsim.grasp.rectangle_to_grasp`'s width ``w z |(cos/fx, sin/fy)|``
    (``w z / f`` when ``fx = fy``).

    Parameters
    ----------
    z : float or ndarray
        Depth of the surface under the centre, metres (> 0).
    theta : float or ndarray
        Closing direction, radians; broadcast with ``z``.
    intrinsics : CameraIntrinsics or ndarray of shape (3, 3)
    max_opening : float
        Metres.

    Returns
    -------
    float or ndarray
        Pixels.

    Raises
    ------
    ValueError
        When ``intrinsics`` is not a 3x3 camera matrix of finite values with positive focal
        lengths (:func:`dlsr.datasets.check_camera_matrix`).
    """
    return _max_width_px(z, theta, check_camera_matrix(intrinsics, "intrinsics"), max_opening)


def _max_width_px(z, theta, K, max_opening):
    """:func:`max_width_px` with ``K`` already checked (called once per chord)."""
    scale = np.hypot(np.cos(theta) / K[0, 0], np.sin(theta) / K[1, 1])
    return max_opening / (np.asarray(z, dtype=float) * scale)


def lattice_step(jaw_px=(10.0, 28.0), spacing: float | None = None) -> tuple[list, float]:
    """The two jaw sizes (a quarter of the way into ``jaw_px`` from either end) and the
    lattice step (``spacing``, default half the smaller jaw), pixels."""
    lo_h, hi_h = float(jaw_px[0]), float(jaw_px[1])
    jaws = sorted({round(lo_h + 0.25 * (hi_h - lo_h), 2), round(hi_h - 0.25 * (hi_h - lo_h), 2)})
    step = 0.5 * jaws[0] if spacing is None else float(spacing)
    if not step > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    return jaws, step


def lattice_candidates(mask, depth, intrinsics, offset, max_opening: float | None,
                       jaw_px=(10.0, 28.0), spacing: float | None = None, n_angles: int = 12,
                       margin_px: float = 4.0, depth_band: float = 0.02, reach: float = 0.95,
                       seen: set | None = None,
                       widest_in_reach: bool = False) -> list[GraspRectangle]:
    """Rectangles fitted to one object mask (see the module docstring).

    Parameters
    ----------
    mask : ndarray of shape (H, W), bool
        The object's pixels (fewer than 5: no candidate).
    depth : ndarray of shape (H, W), float
        Metres, 0 where missing; lattice points without depth are skipped.
    intrinsics : CameraIntrinsics, ndarray of shape (3, 3) or None
        Only read with ``max_opening``.
    offset : ndarray of shape (2,)
        Lattice offset, pixels in ``[0, spacing)``.
    max_opening : float or None
        The gripper's largest opening, metres; openings wider than ``reach`` x
        :func:`max_width_px` at the depth under the centre are not generated (None: no limit).
    jaw_px, spacing, n_angles, margin_px, depth_band, reach :
        As :func:`graspsim.labelling.dense_candidates` documents them.
    seen : set or None
        Keys of candidates already generated (shared across the objects of a scene);
        updated in place.
    widest_in_reach : bool
        Where a chord's wide opening (``1.3 * length + 2 * margin_px``) is beyond the reach but
        its tight one (``length + margin_px``) is not, add the widest opening within the reach
        in its place (``max_opening`` only): an object nearly as wide as the gripper's reach
        then also gets the candidate with all the clearance the gripper has, not only the
        tight one. Not the default (README): ahead on a first 600 validation scenes of objects
        the model had not seen, not on 900 new ones (702 against 697).

    Returns
    -------
    list of GraspRectangle

    Raises
    ------
    ValueError
        With ``max_opening``, when ``intrinsics`` is not a valid camera matrix (as
        :func:`max_width_px`), even for an empty mask.
    """
    arr, keys = _lattice_array(mask, depth, intrinsics, offset, max_opening, jaw_px, spacing,
                               n_angles, margin_px, depth_band, reach, seen, widest_in_reach,
                               normalized=False)
    return [GraspRectangle(*row) for row in arr.tolist()]


def _lattice_array(mask, depth, intrinsics, offset, max_opening, jaw_px=(10.0, 28.0),
                   spacing=None, n_angles=12, margin_px=4.0, depth_band=0.02, reach=0.95,
                   seen=None, widest_in_reach=False, normalized=True, with_keys=True):
    """:func:`lattice_candidates` as an ``(n, 5)`` array, and the candidates' keys.

    Every lattice point's chords in every direction are followed at once, and the candidates
    (point, direction, run, opening, jaw, in that order) are made as arrays with the same
    floating-point operations, in the same order, as one rectangle at a time; the first of
    those sharing a key (centre rounded to the pixel, direction, half opening rounded, jaw) is
    kept. ``normalized``: the angle column as :class:`~dlsr.rectangles.GraspRectangle` stores
    it (wrapped once more into ``[-pi/2, pi/2)``), else the lattice's own angles.
    ``with_keys=False`` with no ``seen``: the same candidates, the keys not made (an empty
    list).
    """
    jaws, step = lattice_step(jaw_px, spacing)
    if n_angles < 1:
        raise ValueError(f"n_angles must be >= 1, got {n_angles}")
    K = None if max_opening is None else check_camera_matrix(intrinsics, "intrinsics")
    fresh = seen is None
    seen = set() if seen is None else seen
    full = np.asarray(mask, dtype=bool)
    depth = np.asarray(depth, dtype=float)
    empty = np.zeros((0, 5))
    if full.sum() < 5:
        return empty, []
    H, W = full.shape
    thetas = -np.pi / 2 + np.pi * np.arange(n_angles) / n_angles
    ys, xs = np.nonzero(full)
    # Work in the mask's bounding box (plus a pixel): chords never leave the mask.
    x0, y0 = max(xs.min() - 1, 0), max(ys.min() - 1, 0)
    x1, y1 = min(xs.max() + 2, W), min(ys.max() + 2, H)
    mask, dep = full[y0:y1, x0:x1], depth[y0:y1, x0:x1]
    h_, w_ = mask.shape
    gx = np.arange(xs.min() - x0 + offset[0] - step, xs.max() - x0 + 1.0, step)
    gy = np.arange(ys.min() - y0 + offset[1] - step, ys.max() - y0 + 1.0, step)
    px, py = np.meshgrid(gx, gy)
    px, py = px.ravel(), py.ravel()
    ix, iy = np.rint(px).astype(int), np.rint(py).astype(int)
    ok = (ix >= 0) & (ix < w_) & (iy >= 0) & (iy < h_)
    ok[ok] = mask[iy[ok], ix[ok]] & (dep[iy[ok], ix[ok]] > 0)
    px, py, ix, iy = px[ok], py[ok], ix[ok], iy[ok]
    if not len(px):
        return empty, []
    zc = dep[iy, ix]
    # the directions as the one-point code computes them: scalar cos/sin per angle
    u_pt = np.array([[np.cos(th), -np.sin(th)] for th in thetas])
    scale = (None if K is None else
             np.array([np.hypot(np.cos(th) / K[0, 0], np.sin(th) / K[1, 1]) for th in thetas]))
    lo_m, hi_m, lo_n, hi_n = _runs(mask, dep, np.column_stack([px, py]), zc, thetas,
                                   depth_band)
    # (point, angle, run): the runs of the mask and of the surface near the point's depth,
    # in sorted order, the second dropped when both are the same
    same = (lo_m == lo_n) & (hi_m == hi_n)
    first_m = (lo_m < lo_n) | ((lo_m == lo_n) & (hi_m <= hi_n))
    lo = np.stack([np.where(first_m, lo_m, lo_n), np.where(first_m, lo_n, lo_m)], axis=2)
    hi = np.stack([np.where(first_m, hi_m, hi_n), np.where(first_m, hi_n, hi_m)], axis=2)
    run_ok = np.stack([np.ones_like(same), ~same], axis=2)
    P, A = len(px), len(thetas)
    k = np.broadcast_to(np.arange(A)[None, :, None], lo.shape)
    length = hi - lo
    mid = 0.5 * (lo + hi)
    cx = px[:, None, None] + mid * u_pt[k, 0]
    cy = py[:, None, None] + mid * u_pt[k, 1]
    ci = np.clip(np.rint(cx), 0, w_ - 1).astype(int)
    cj = np.clip(np.rint(cy), 0, h_ - 1).astype(int)
    zd = dep[cj, ci]
    z = np.where(zd > 0, zd, np.broadcast_to(zc[:, None, None], zd.shape))
    cx = cx + x0
    cy = cy + y0
    if max_opening is None:
        w_max = np.full(lo.shape, np.inf)
    else:
        w_max = reach * (max_opening / (z * scale[k]))
    w_tight = length + margin_px
    w_wide = 1.3 * length + 2 * margin_px
    if widest_in_reach:
        w_wide = np.where((w_tight <= w_max) & (w_max < w_wide), w_max, w_wide)
    widths = np.stack([w_tight, w_wide], axis=3)  # (P, A, 2 runs, 2 widths)
    keep = run_ok[..., None] & ~(widths > w_max[..., None])
    n_j = len(jaws)
    shape = (P, A, 2, 2, n_j)
    keep = np.broadcast_to(keep[..., None], shape).ravel()
    W_ = np.broadcast_to(widths[..., None], shape).ravel()[keep]
    X = np.broadcast_to(cx[..., None, None], shape).ravel()[keep]
    Y = np.broadcast_to(cy[..., None, None], shape).ravel()[keep]
    Kk = np.broadcast_to(k[..., None, None], shape).ravel()[keep]
    J = np.broadcast_to(np.arange(n_j), shape).ravel()[keep]
    jaw = np.asarray(jaws, dtype=float)
    # the first candidate of each key, in the order made
    ikey = np.column_stack([np.rint(X), np.rint(Y), Kk, np.rint(W_ / 2), J]).astype(np.int64)
    _, first = np.unique(ikey, axis=0, return_index=True)
    first = np.sort(first)
    out_keys = []
    if fresh and not with_keys:  # no key seen before, none asked for: every first one is new
        chosen = first.astype(np.intp)
    else:
        chosen = []
        for i in first.tolist():
            key = (int(ikey[i, 0]), int(ikey[i, 1]), int(ikey[i, 2]), int(ikey[i, 3]),
                   jaws[int(ikey[i, 4])])
            if key in seen:
                continue
            seen.add(key)
            out_keys.append(key)
            chosen.append(i)
        chosen = np.asarray(chosen, dtype=np.intp)
    th = normalize_angle(thetas) if normalized else thetas
    arr = np.column_stack([X[chosen], Y[chosen], th[Kk[chosen]], W_[chosen],
                           jaw[J[chosen]]]).reshape(-1, 5)
    return arr, out_keys


def _runs(mask, dep, centres, zc, thetas, depth_band, max_px: float = 120.0):
    """:func:`chords` of every lattice point at once, on the mask and on the surface no deeper
    than ``depth_band`` beyond the point's depth ``zc``: ``lo_m, hi_m, lo_n, hi_n`` of shape
    ``(n_points, n_angles)``; the same pixels and arithmetic as :func:`chords` point by point
    (:func:`_runs_kernel`, each walk stopping where both runs have ended)."""
    thetas = np.asarray(thetas, dtype=float)
    u = np.column_stack([np.cos(thetas), -np.sin(thetas)])
    n = len(centres)
    out = np.empty((4, n, len(thetas)))
    if n:
        _runs_kernel(np.ascontiguousarray(mask, dtype=bool), np.ascontiguousarray(dep, float),
                     np.ascontiguousarray(centres, float), np.asarray(zc, float), u,
                     float(depth_band), int(max_px) + 1, out)
    return out[0], out[1], out[2], out[3]


@njit(nogil=True, cache=True)
def _runs_kernel(mask, dep, centres, zc, u, depth_band, n_steps, out):
    """Walk from each centre along ``+u`` and ``-u`` (pixel ``rint(c + (s t) u)``, ``t = 0,
    1, ...``) until the mask and the near surface (valid depth below ``zc + depth_band``) have
    both ended; ``out[0..3]``: ``lo_m, hi_m, lo_n, hi_n`` (the last step inside, signed)."""
    H, W = mask.shape
    for p in range(centres.shape[0]):
        cx = centres[p, 0]
        cy = centres[p, 1]
        lim = zc[p] + depth_band
        for a in range(u.shape[0]):
            for side in range(2):
                sgn = 1.0 if side == 0 else -1.0
                stop_m = -1
                stop_n = -1
                for t in range(n_steps):
                    st = sgn * t
                    x = np.rint(cx + st * u[a, 0])
                    y = np.rint(cy + st * u[a, 1])
                    on = False
                    near = False
                    if x >= 0 and x < W and y >= 0 and y < H:
                        xi = int(x)
                        yi = int(y)
                        on = mask[yi, xi]
                        d = dep[yi, xi]
                        near = on and d > 0 and d < lim
                    if stop_m < 0 and not on:
                        stop_m = t
                    if stop_n < 0 and not near:
                        stop_n = t
                    if stop_m >= 0 and stop_n >= 0:
                        break
                if stop_m < 0:
                    stop_m = n_steps
                if stop_n < 0:
                    stop_n = n_steps
                i_m, i_n = (1, 3) if side == 0 else (0, 2)
                out[i_m, p, a] = max(stop_m - 1, 0) * sgn
                out[i_n, p, a] = max(stop_n - 1, 0) * sgn


def _fill_region_holes(depth, valid, region):
    """``depth`` with the region's missing pixels set to the nearest valid depth."""
    return _nearest_fill(depth, region & ~valid, valid)


class LatticeDetector:
    """Rank rectangles fitted to the object (:func:`lattice_candidates`) with a trained model.

    The candidates are the physics labeller's, drawn from the observation instead of the
    simulator: the object region (:func:`dlsr.detection.object_region`, with its unseen
    surface added, ``complete``), the observed depth (holes in the region filled,
    ``fill_holes``) and the camera matrix. At most ``budget`` of
    them (a random subset, ``seed``) are scored exactly (recognition's rectangle images and the
    model's SVM, :meth:`dlsr.detection.DenseDetector.exact_scores`) plus the model's physical
    term when it has one (:meth:`dlsr.detection.DLSRDetector.physical_scores`). A departure
    from the paper's grid search (:class:`dlsr.detection.DenseDetector`), chosen on validation
    scenes of the training objects (README).

    Parameters
    ----------
    model : DLSRDetector
    top_k : int
        Rectangles returned.
    region, background, min_height :
        See :class:`~dlsr.detection.ExactGridDetector`.
    budget : int or None
        Candidates scored at most (None: all).
    max_width : float or None
        The gripper's largest opening, metres; wider openings are not generated (None: any;
        then the observation needs no camera matrix unless the model is physical).
    jaw_px, spacing, n_angles, margin_px, depth_band, reach :
        See :func:`lattice_candidates`.
    seed : int
        Lattice offset and budget subset.
    fill_holes : bool
        Give the region's pixels without depth the nearest valid depth before the lattice is
        laid (otherwise lattice points on holes are skipped and the depth band of rims and
        handles breaks at them); scoring still sees the observed depth. On validation scenes
        of the training objects: 72 against 68 successes of 100 (5 against 1 scenes won alone,
        not separated).
    complete : bool
        Lay the lattice on the region with its unseen surface added (the missing depth inside
        its convex hull, :func:`dlsr.detection.complete_region`, on which the physical
        features always measure): the tops of dark, specular and transparent objects, which
        the sensor hardly returns, otherwise leave islands too narrow for any opening that
        spans the object. Chosen on validation scenes of the training objects (README).
    widest_in_reach : bool
        Also the widest opening within the reach where a chord's wide opening is beyond it
        (:func:`lattice_candidates`; not the default, README).
    n_threads : int or None
        Threads of the exact scoring (None: the process's share of the cores, as
        :class:`~dlsr.detection.dense.DenseDetector`).
    """

    def __init__(self, model, top_k: int = 5, region: str = "auto", background=None,
                 min_height: float = 0.006, budget: int | None = 192,
                 max_width: float | None = None, jaw_px=(10.0, 28.0),
                 spacing: float | None = None, n_angles: int = 12, margin_px: float = 4.0,
                 depth_band: float = 0.02, reach: float = 0.95, seed: int = 0,
                 fill_holes: bool = True, complete: bool = True,
                 widest_in_reach: bool = False, n_threads: int | None = None):
        self.model = model
        self.top_k = top_k
        self.region = region
        self.background = background
        self.min_height = min_height
        self.budget = budget
        self.max_width = max_width
        self.jaw_px = jaw_px
        self.spacing = spacing
        self.n_angles = n_angles
        self.margin_px = margin_px
        self.depth_band = depth_band
        self.reach = reach
        self.seed = seed
        self.fill_holes = fill_holes
        self.complete = complete
        self.widest_in_reach = widest_in_reach
        self.n_threads = n_threads

    def candidates(self, obs):
        """``(candidates (n, 5), reason or None, object region or None)``: the lattice of an
        observation within the budget."""
        _check_obs(obs)
        if obs.get("K") is None and (self.max_width is not None or self.model.physical):
            raise ValueError("lattice candidates within the gripper's reach (max_width) and "
                             "a model with physical features need the observation's camera "
                             "matrix 'K'")
        if self.budget is not None and int(self.budget) < 1:
            raise ValueError(f"budget must be >= 1 or None, got {self.budget}")
        valid, region, how, reason = _observed_region(obs, self.background, self.region,
                                                      self.min_height)
        if reason:
            return np.zeros((0, 5)), reason, region
        laid = complete_region(region, valid) if self.complete else region
        depth = np.asarray(obs["depth"], dtype=float)
        rng = np.random.default_rng(self.seed)
        _, step = lattice_step(self.jaw_px, self.spacing)
        offset = rng.uniform(0.0, step, size=2)
        dep = np.where(valid, depth, 0.0)
        if self.fill_holes:
            dep = _fill_region_holes(dep, valid, laid)
        cand, _ = _lattice_array(laid, dep, obs.get("K"), offset, self.max_width, self.jaw_px,
                                 self.spacing, self.n_angles, self.margin_px, self.depth_band,
                                 self.reach, widest_in_reach=self.widest_in_reach,
                                 with_keys=False)
        if self.budget is not None and len(cand) > self.budget:
            cand = cand[np.sort(rng.choice(len(cand), size=int(self.budget), replace=False))]
        if not len(cand):
            return cand, f"no rectangle fits the object region (method {how})", region
        return cand, None, region

    def detect(self, obs) -> Detection:
        """Detect grasps in one observation (``timings``: ``candidates``, ``score``)."""
        from .dense import DenseDetector

        t0 = time.perf_counter()
        cand, reason, region = self.candidates(obs)
        if reason:
            return _empty(reason, t0)
        t1 = time.perf_counter()
        exact = DenseDetector(self.model, n_threads=self.n_threads).exact_scores(obs, cand)
        table = (table_surface(obs["depth"], obs.get("depth_valid"))
                 if self.model.physical else None)
        rects, scores = self._ranked(obs, cand, region, exact, table)
        t2 = time.perf_counter()
        return Detection(rects, scores, n_candidates=len(cand),
                         n_encodings=len(cand) * PATCHES_PER_RECTANGLE, seconds=t2 - t0,
                         timings={"candidates": t1 - t0, "score": t2 - t1})

    def _ranked(self, obs, cand, region, exact, table):
        """The best ``top_k`` candidates and their scores (the exact scores plus the model's
        physical term), best first."""
        scores = exact + self.model.physical_scores(obs, cand, region, table)
        order = np.argsort(-scores, kind="stable")[: self.top_k]
        return cand[order], scores[order]

    def predict(self, obs) -> list[GraspRectangle]:
        """The top-k rectangles, best first (empty, with a logged reason, when none)."""
        return self.detect(obs).rectangles()


def detect_many(detectors, obs) -> list[Detection]:
    """Every detector's :meth:`~LatticeDetector.detect` on one observation, the shared work
    done once.

    Lattice detectors that differ only in their model, whose models preprocess alike and are
    all physical or all not, lay the same candidates and cut the same rectangle images: both
    are computed once (:meth:`LatticeDetector.candidates`,
    :meth:`dlsr.detection.DenseDetector.exact_images`) and scored by each model, the patches
    whitened once for the models that whiten alike (:func:`dlsr.detection.dense.
    score_images_many`: the models of one fold), which gives each detector's own detection
    bit for bit. Other detectors detect one by one.

    Parameters
    ----------
    detectors : sequence of objects with ``detect(obs)``
    obs : dict
        An observation (``rgb``, ``depth``, ``depth_valid``, ``K`` ...).

    Returns
    -------
    list of Detection
        One per detector, in their order. With shared work, a detection's ``seconds`` counts
        the shared candidates, rectangle images and whitening in full (what the detector alone
        takes) and its ``timings`` add ``shared`` (the candidates' and images' seconds).
    """
    from .dense import DenseDetector, score_images_many

    detectors = list(detectors)
    if not detectors or not _share_search(detectors):
        return [d.detect(obs) for d in detectors]
    first = detectors[0]
    t0 = time.perf_counter()
    cand, reason, region = first.candidates(obs)
    if reason:  # each detector alone would have taken the candidates' seconds
        return [_empty(reason, t0) for _ in detectors]
    t1 = time.perf_counter()
    images = DenseDetector(first.model, n_threads=first.n_threads).exact_images(obs, cand)
    shared = time.perf_counter() - t0
    table = None
    out = []
    scores_of, scoring = score_images_many(
        [DenseDetector(d.model, n_threads=first.n_threads) for d in detectors], images)
    for d, exact, seconds in zip(detectors, scores_of, scoring, strict=True):
        t2 = time.perf_counter()
        if d.model.physical and table is None:
            table = table_surface(obs["depth"], obs.get("depth_valid"))
        rects, scores = d._ranked(obs, cand, region, exact, table)
        own = seconds + time.perf_counter() - t2
        out.append(Detection(rects, scores, n_candidates=len(cand),
                             n_encodings=len(cand) * PATCHES_PER_RECTANGLE,
                             seconds=shared + own,
                             timings={"candidates": t1 - t0, "score": shared - (t1 - t0) + own,
                                      "shared": shared}))
    return out


def _share_search(detectors) -> bool:
    """Whether ``detectors`` are lattice detectors that lay the same candidates and cut the
    same rectangle images (they differ in their model only, whose preprocessing and physical
    flag are the same)."""
    if not all(type(d) is LatticeDetector for d in detectors):
        return False
    first = detectors[0]
    settings = {k: v for k, v in vars(first).items() if k != "model"}
    for d in detectors[1:]:
        other = {k: v for k, v in vars(d).items() if k != "model"}
        if other.keys() != settings.keys() or any(
                not _same(other[k], settings[k]) for k in settings):
            return False
        if (d.model.preprocess != first.model.preprocess
                or bool(d.model.physical) != bool(first.model.physical)):
            return False
    return True


def _same(a, b) -> bool:
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)
                and a.shape == b.shape and bool(np.array_equal(a, b)))
    return a == b


register_detector("lattice", LatticeDetector, grid_search=False)
