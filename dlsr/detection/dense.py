"""The dense path (:class:`DenseDetector`): per (angle, opening) canvas score maps and box sums,
the top candidates rescored exactly. The package docstring (:mod:`dlsr.detection`) describes the
method and where it differs from :class:`~dlsr.detection.exact.ExactGridDetector`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from .._threads import one_blas_thread, thread_budget
from ..features import encode_patches
from ..features.representation import whitening_groups
from ..memory import reused_heap
from ..rectangles import corners_from_array, normalize_angle
from .exact import Detection, _Base, _check_obs, _empty
from .grid import (
    COARSE_GRID,
    PAPER_GRID,
    SearchGrid,
    _axes,
    _box_sums,
    jaws_clear,
    table_surface,
    within_reach,
)
from .model import GRID, PATCH, PATCHES_PER_RECTANGLE, SIZE, SPLIT
from .registry import register_detector

_ONE = 1.0 - 1e-6  # as dlsr.preprocess: bilinear weights summing to one
_GRAY = np.asarray((0.2989, 0.5870, 0.1140), dtype=np.float32)
_STD_EPS = 1e-4  # the per-patch standardisation's (dlsr.whitening.standardize_patches)


class _Source:
    """One observation prepared for canvas sampling: ``(H + 2, W + 2, 7)`` float32.

    Channels R, G, B (0..1), depth (metres, 0 invalid), validity, inside, hole-filled depth
    (metres); a one-pixel zero border like :mod:`dlsr.preprocess`.
    """

    def __init__(self, obs, preprocess: dict, roi=None, fill: str | None = None):
        from ..preprocess import _check_image, fill_depth_holes

        src6 = _check_image(obs["rgb"], obs["depth"], obs.get("depth_valid"))
        H, W = src6.shape[0] - 2, src6.shape[1] - 2
        self.src = np.zeros((H + 2, W + 2, 7), dtype=np.float32)
        self.src[..., :6] = src6
        depth = src6[1:-1, 1:-1, 3].astype(np.float64)
        valid = src6[1:-1, 1:-1, 4] > 0.5
        r0, r1, c0, c1 = roi if roi is not None else (0, H, 0, W)
        sub = fill_depth_holes(depth[r0:r1, c0:c1], valid[r0:r1, c0:c1],
                               fill or preprocess.get("fill", "band"), preprocess.get("band", 3))
        if not valid[r0:r1, c0:c1].any():
            ref = float(depth[valid].mean())
            sub = np.full((r1 - r0, c1 - c0), ref)
        filled = np.full((H, W), float(np.mean(sub)))
        filled[r0:r1, c0:c1] = sub
        self.src[1:-1, 1:-1, 6] = filled
        roi_valid = valid[r0:r1, c0:c1]
        self.ref = float(depth[r0:r1, c0:c1][roi_valid].mean()) if roi_valid.any() \
            else float(depth[valid].mean())
        self.shape = (H, W)


class _PatchScorer:
    """``V[:, q] . code(patch)`` of standardised 6x6 patches under a model (the dense encoding).

    For NKM-Natural (k-means triangle codes ``max(mean_k z - z_k, 0)``, ``z_k = ||w - c_k||``
    on the un-normalised centroids ``C``) with ZCA whitening ``w = (x - m) P``, a patch ``x``
    without masked entries needs ``w . c_k = x (P C^T) - m P C^T`` and
    ``||w||^2 = ||(x - m) L||^2`` with ``L`` the lower Cholesky factor of ``P P^T``; ``L`` is
    triangular, so its columns are computed in ``n_blocks`` column blocks from the rows they
    use, the first block in the same product as ``P C^T``: 2 x 288 x (300 + 180) operations
    per patch instead of 2 x 288 x (300 + 288) for ``[P | P C^T]``.
    :func:`dlsr._dense.triangle_scores` turns the products into codes and quadrant scores
    without storing the codes. A patch with masked entries is whitened (``P``), re-masked as
    :func:`dlsr.whitening.apply_zca` does, then multiplied by ``C^T``. Other encoders whiten
    and call :func:`dlsr.features.encode_patches`.

    Parameters
    ----------
    model : DLSRDetector
    V : ndarray of shape (k, q)
        Per-quadrant weights on the codes.
    n_blocks : int
        Column blocks of ``L`` (4 was fastest here; 1 computes all of ``L`` in one product).
    by_rows : bool
        Whiten a patch with masked entries on the rows that hold valid ones only (the
        rectangle images' padding masks whole patch rows): the patches sharing those rows
        ``T`` are multiplied by the block ``P[T, T]`` and by ``C[:, T]^T``, which is what the
        whole products give, since the other rows are 0 before whitening and masked after,
        with fewer operations (2 |T| (|T| + k) per patch); the scores are the same up to
        float rounding (the products sum in another order). The exact scores use it.
    colour_only : bool
        :meth:`masked_scores` whitens a patch whose colour entries (channels 0-3) are all valid
        and whose depth entries all masked (a canvas masks the depth channels of the pixels
        without depth; in a pile about an eighth of all patches) on its 144 colour entries
        ``T``: ``P[T, T]`` and ``C[:, T]^T`` give what the whole products give, since the
        depth entries are 0 before whitening and masked after, with 2 x 144 x (144 + k)
        operations per patch instead of 2 x 288 x (288 + k); the scores are the same up to
        float rounding (the products sum in another order). The dense scores use it.
    """

    def __init__(self, model, V, n_blocks: int = 4, by_rows: bool = False,
                 colour_only: bool = False):
        rep = model.representation
        self.model = model
        self.by_rows = by_rows
        self.colour_only = colour_only
        self._rows = {}
        self.V = np.asarray(V, np.float32)
        self.VT = np.ascontiguousarray(self.V.T)
        p = PATCH * PATCH * 8
        self.p = p
        self.whiten = rep.zca_mean is not None
        P = np.asarray(rep.zca_matrix, np.float64) if self.whiten else None
        mP = np.asarray(rep.zca_mean, np.float64) @ P if self.whiten else np.zeros(p)
        self.P = None if P is None else np.ascontiguousarray(P, dtype=np.float32)
        self.mP = mP.astype(np.float32)
        self.zero = np.zeros(p, np.float32)
        self.triangle = (rep.learner == "NKM" and model.encoder == "Natural"
                         and rep.centroids is not None)
        flops = 2.0 * p * p if self.whiten else 0.0
        if self.triangle:
            Cn = np.asarray(rep.centroids, np.float64)
            k = Cn.shape[0]
            self.CT = np.ascontiguousarray(Cn.T, dtype=np.float32)
            cc = (Cn * Cn).sum(1)
            self.cc = cc.astype(np.float32)
            self.cc2 = (cc + 2.0 * (mP @ Cn.T)).astype(np.float32)
            flops = 2.0 * p * k
            if self.whiten:
                try:
                    L = np.linalg.cholesky(P @ P.T)
                except np.linalg.LinAlgError:  # singular P: any L with L L^T = P P^T will do
                    L, n_blocks = P, 1
                self.mL = (np.asarray(rep.zca_mean, np.float64) @ L).astype(np.float32)
                edges = np.linspace(0, p, max(1, int(n_blocks)) + 1).round().astype(int)
                self.blocks = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]
                a0, b0 = self.blocks[0]
                self.B = [np.ascontiguousarray(np.hstack([P @ Cn.T, L[:, a0:b0]]),
                                               dtype=np.float32)]
                self.B += [np.ascontiguousarray(L[a:, a:b], dtype=np.float32)
                           for a, b in self.blocks[1:]]
                flops = sum(2.0 * B.shape[0] * B.shape[1] for B in self.B)
        # useful products per patch: whitening and centroids (or the dictionary), quadrant
        # weights; a patch with masked entries is whitened in full, then multiplied by C^T
        self.flops = flops + 2.0 * self.V.size
        self.flops_masked = self.flops
        if self.triangle and self.whiten:
            self.flops_masked = 2.0 * p * (p + k) + 2.0 * self.V.size

    def scores(self, img, msk, rows, cols, mean, inv, full) -> np.ndarray:
        """``(n, q)`` float32 scores of the patches with top-left corners ``(rows, cols)``.

        ``mean, inv, full`` come from :func:`dlsr._dense.window_stats` on ``img, msk``.
        """
        n = len(rows)
        S = np.empty((n, self.V.shape[1]), np.float32)
        if not self.triangle:
            S[:] = self._generic(img, msk, rows, cols, mean, inv, full)
            return S
        ok = full[rows, cols]
        if ok.all():
            S[:] = self._triangle_full(img, msk, rows, cols, mean, inv, full)
            return S
        good = np.flatnonzero(ok)
        bad = np.flatnonzero(~ok)
        if len(good):
            S[good] = self._triangle_full(img, msk, rows[good], cols[good], mean, inv, full)
        S[bad] = self._triangle_masked(img, msk, rows[bad], cols[bad], mean, inv, full)
        return S

    def _gather(self, img, msk, rows, cols, mean, inv, full):
        from .. import _dense

        X = np.empty((len(rows), self.p), np.float32)
        _dense.gather_patches(img, msk, rows, cols, mean, inv, full, X)
        return X

    def _masks(self, msk, rows, cols):
        from .. import _dense

        M = np.empty((len(rows), self.p), np.float32)
        _dense.gather_masks(msk, rows, cols, M)
        return M

    def _triangle_full(self, img, msk, rows, cols, mean, inv, full):
        from .. import _dense

        X = self._gather(img, msk, rows, cols, mean, inv, full)
        S = np.empty((len(rows), self.V.shape[1]), np.float32)
        if self.whiten:
            k = self.CT.shape[1]
            Y = np.empty((len(rows), k + self.p), np.float32)
            a0, b0 = self.blocks[0]
            np.matmul(X, self.B[0], out=Y[:, :k + b0])
            for (a, b), B in zip(self.blocks[1:], self.B[1:], strict=True):
                np.matmul(X[:, a:], B, out=Y[:, k + a:k + b])
            _dense.triangle_scores(Y, k, Y, 0, self.mL, self.cc2, self.VT, S)
        else:
            _dense.triangle_scores(X, 0, X @ self.CT, 0, self.zero, self.cc, self.VT, S)
        return S

    def _triangle_masked(self, img, msk, rows, cols, mean, inv, full):
        if self.whiten and self.by_rows and self.triangle:
            return self._triangle_by_rows(img, msk, rows, cols, mean, inv)
        X = self._gather(img, msk, rows, cols, mean, inv, full)
        if not self.whiten:
            return self._triangle_whitened(X)
        M = self._masks(msk, rows, cols)
        blank = ~M.any(axis=1)
        if not blank.any():
            return self._triangle_whitened(X, M)
        # a patch with every entry masked (the padding of a crop narrower than it is wide, a
        # quarter of a lattice's patches) is 0 after masking, whatever the product: its code
        # is the all-masked patch's, computed once
        S = np.empty((len(rows), self.V.shape[1]), np.float32)
        S[blank] = self._blank_scores()
        live = ~blank
        if live.any():
            S[live] = self._triangle_whitened(X[live], M[live])
        return S

    def _triangle_whitened(self, X, M=None):
        """Scores of gathered patches ``X`` with masked entries: whitened, re-masked by ``M``
        (with whitening), multiplied by the centroids."""
        from .. import _dense

        if self.whiten:
            X = X @ self.P
            X -= self.mP
            X *= M
        S = np.empty((len(X), self.V.shape[1]), np.float32)
        _dense.triangle_scores(X, 0, X @ self.CT, 0, self.zero, self.cc, self.VT, S)
        return S

    def _triangle_by_rows(self, img, msk, rows, cols, mean, inv):
        """:meth:`_triangle_whitened` of masked patches, each on its rows with valid entries
        (``by_rows``); a patch without any has the all-masked patch's scores. Only those rows
        of the patches and their masks are gathered, group by group
        (:func:`dlsr._dense.gather_patch_rows`)."""
        from .. import _dense

        n = len(rows)
        lo = np.empty(n, np.int64)
        hi = np.empty(n, np.int64)
        _dense.patch_row_spans(msk, rows, cols, lo, hi)
        S = np.empty((n, self.V.shape[1]), np.float32)
        blank = hi == 0
        if blank.any():
            S[blank] = self._blank_scores()
        live = np.flatnonzero(~blank)
        key = lo[live] * (PATCH + 1) + hi[live]
        order = live[np.argsort(key, kind="stable")]
        cuts = np.flatnonzero(np.diff(np.sort(key, kind="stable"))) + 1
        for group in np.split(order, cuts):
            a, b = int(lo[group[0]]), int(hi[group[0]])
            PT, mPT, CT, zero = self._row_blocks(a, b)
            Xg = np.empty((len(group), (b - a) * PATCH * 8), np.float32)
            Mg = np.empty_like(Xg)
            _dense.gather_patch_rows(img, msk, rows[group], cols[group], mean, inv, a, b, Xg,
                                     Mg)
            W = Xg @ PT
            W -= mPT
            W *= Mg
            Sg = np.empty((len(group), self.V.shape[1]), np.float32)
            _dense.triangle_scores(W, 0, W @ CT, 0, zero, self.cc, self.VT, Sg)
            S[group] = Sg
        return S

    def masked_scores(self, img, msk, rows, cols, mean, inv, full, chunk):
        """``(n, q)`` float32 scores of patches with masked entries, in chunks of ``chunk``,
        those with no valid depth whitened on their colour entries (``colour_only``); and the
        useful products done (flops).

        Only for the k-means triangle codes with whitening (``self.triangle and
        self.whiten``).
        """
        from .. import _dense

        n = len(rows)
        S = np.empty((n, self.V.shape[1]), np.float32)
        if n == 0:
            return S, 0.0
        colour = np.empty(n, bool)
        _dense.colour_only(msk, rows, cols, colour)
        PT, mPT, CT = self._colour_blocks()
        m = len(mPT)
        per = 2.0 * self.V.size
        flops = (np.count_nonzero(colour) * (2.0 * m * (m + CT.shape[1]) + per)
                 + np.count_nonzero(~colour) * self.flops_masked)
        for sel, colour_only in ((np.flatnonzero(colour), True),
                                 (np.flatnonzero(~colour), False)):
            for st in range(0, len(sel), chunk):
                g = sel[st:st + chunk]
                if not colour_only:
                    S[g] = self._triangle_masked(img, msk, rows[g], cols[g], mean, inv, full)
                    continue
                W = np.empty((len(g), m), np.float32)
                _dense.gather_colour(img, rows[g], cols[g], mean, inv, W)
                W = W @ PT
                W -= mPT
                Sg = np.empty((len(g), self.V.shape[1]), np.float32)
                _dense.triangle_scores(W, 0, W @ CT, 0, np.zeros(m, np.float32), self.cc,
                                       self.VT, Sg)
                S[g] = Sg
        return S, flops

    def _colour_blocks(self):
        """``P[T, T]``, ``(m P)[T]`` and ``C[:, T]^T`` for the colour entries ``T`` (channels
        0-3 of every pixel)."""
        if not hasattr(self, "_colour"):
            T = (np.arange(PATCH * PATCH)[:, None] * 8 + np.arange(4)).ravel()
            self._colour = (np.ascontiguousarray(self.P[np.ix_(T, T)]),
                            np.ascontiguousarray(self.mP[T]),
                            np.ascontiguousarray(self.CT[T]))
        return self._colour

    def _row_blocks(self, a, b):
        """``P[T, T]``, ``(m P)[T]``, ``C[:, T]^T`` and zeros for the patch rows ``[a, b)``."""
        key = (a, b)
        if key not in self._rows:
            e0, e1 = a * PATCH * 8, b * PATCH * 8
            self._rows[key] = (np.ascontiguousarray(self.P[e0:e1, e0:e1]),
                               np.ascontiguousarray(self.mP[e0:e1]),
                               np.ascontiguousarray(self.CT[e0:e1]),
                               np.zeros(e1 - e0, np.float32))
        return self._rows[key]

    def _blank_scores(self):
        """The scores of a patch whose every entry is masked (as :meth:`_triangle_masked`
        computes them: the whitened patch re-masked is 0)."""
        if not hasattr(self, "_blank"):
            p = self.p
            self._blank = self._triangle_whitened(np.zeros((1, p), np.float32),
                                                  np.zeros((1, p), np.float32))[0]
        return self._blank

    def _generic(self, img, msk, rows, cols, mean, inv, full):
        return self.encoded_scores(*self.whitened(img, msk, rows, cols, mean, inv, full))

    def whitened(self, img, msk, rows, cols, mean, inv, full):
        """The patches at ``(rows, cols)`` standardised, whitened and re-masked (masked entries
        0), ``(n, 288)`` float32, and their masks as 0/1 float32: what the encoder reads."""
        X = self._gather(img, msk, rows, cols, mean, inv, full)
        M = self._masks(msk, rows, cols)
        if self.whiten:
            X = X @ self.P
            X -= self.mP
            X *= M
        return X, M

    def encoded_scores(self, X, M) -> np.ndarray:
        """``(n, q)`` scores of whitened patches ``X`` with masks ``M`` (:meth:`whitened`),
        through the model's encoder; ``X`` and ``M`` are only read."""
        m = self.model
        codes = encode_patches(X, M > 0.5, m.representation, m.encoder, m.encoder_param,
                               m.polarity)
        return np.asarray(codes, np.float32) @ self.V


def _new_stats() -> dict:
    """Counters of the dense encoding (summed over threads)."""
    return {"n_encodings": 0, "encode_seconds": 0.0, "encode_flops": 0.0}


def _merge_stats(into: dict, other: dict) -> None:
    """Add the counters of ``other`` to ``into``."""
    for key, val in other.items():
        into[key] = into.get(key, 0) + val


def window_statistics(img, msk, eps: float = _STD_EPS):
    """The per-patch standardisation's statistics at every patch position of a canvas
    (:func:`dlsr._dense.window_stats`).

    Parameters
    ----------
    img : ndarray of shape (H, W, 8), float32
    msk : ndarray of shape (H, W, 8), bool
    eps : float
        As :func:`dlsr.whitening.standardize_patches`.

    Returns
    -------
    mean, inv : ndarray of shape (H - 5, W - 5, 4), float32
        Per channel group, the mean and the inverse deviation of the patch's valid entries.
    full : ndarray of shape (H - 5, W - 5), bool
        Whether every entry of the patch is valid.
    """
    from .. import _dense

    Hp, Wp = img.shape[0] - PATCH + 1, img.shape[1] - PATCH + 1
    mean = np.empty((Hp, Wp, 4), np.float32)
    inv = np.empty((Hp, Wp, 4), np.float32)
    full = np.empty((Hp, Wp), bool)
    _dense.window_stats(img, msk, eps, mean, inv, full)
    return mean, inv, full


@contextlib.contextmanager
def _scoring(detector):
    """Where a detector scores: BLAS on one thread, the detector's thread pool, and freed
    large blocks kept in the heap for the next chunk (:func:`dlsr.memory.reused_heap`).

    Without the heap, every array above glibc's mmap threshold is mapped afresh and faulted in
    4 kB at a time; and once training has called ``mallopt`` (as the recognition benchmark's
    feature pass does), the threshold no longer adapts and stays at 128 kB for the process.
    """
    with one_blas_thread(), reused_heap(), detector._pool() as pool:
        yield pool


def _map(pool, fn, items) -> list:
    """``[fn(x) for x in items]``, in the pool's threads when there is one."""
    if pool is None or len(items) < 2:
        return [fn(x) for x in items]
    return list(pool.map(fn, items))


def score_images_many(detectors, images) -> tuple[list[np.ndarray], list[float]]:
    """Each detector's :meth:`DenseDetector.score_images` of the same rectangle images, the
    patches whitened once for the models that whiten alike.

    The models of one fold whiten alike whatever their learner (their representations draw
    the same patches from the same seed): the patches of the encoders other than NKM's
    triangle codes (SC, OMP, RP...) are then gathered, standardised and whitened once for all
    of them, in the same chunks, so each detector's scores are the ones it gives alone, bit
    for bit.

    Parameters
    ----------
    detectors : sequence of DenseDetector
        Of one preprocessing and one ``chunk_size``; the first one's ``n_threads`` is used.
    images : tuple or None
        From :meth:`DenseDetector.exact_images`.

    Returns
    -------
    scores : list of ndarray of shape (n,), float64
    seconds : list of float
        Per detector, the wall seconds it would have taken alone: the whole scoring's wall
        seconds times its share of the CPU seconds, a shared whitening counted in full for
        each detector that reads it.
    """
    detectors = list(detectors)
    if images is None:
        return [np.zeros(0) for _ in detectors], [0.0] * len(detectors)
    if len({d.chunk_size for d in detectors}) > 1:
        raise ValueError("score_images_many needs detectors of one chunk_size")
    t0 = time.perf_counter()
    with _scoring(detectors[0]) as pool:
        scores, alone, spent = _scores_of_images(detectors, images, pool)
    wall = time.perf_counter() - t0
    return scores, [wall * a / spent if spent > 0 else wall for a in alone]


def _scores_of_images(detectors, images, pool):
    """Scores of every detector; with the thread CPU seconds each would take alone and those
    spent (a shared whitening once)."""
    n, img, msk, rows, cols, mean, inv, full = images
    weights = [d.model.quadrant_weights() for d in detectors]
    scorers = [_PatchScorer(d.model, V, by_rows=True)
               for d, (V, _) in zip(detectors, weights, strict=True)]
    # the generic scorers grouped by their whitening: one whitening per group and chunk (the
    # triangle codes have their own fused products)
    generic = [i for i, sc in enumerate(scorers) if not sc.triangle]
    groups = [[i] for i, sc in enumerate(scorers) if sc.triangle]
    groups += [[generic[j] for j in g] for g in
               whitening_groups([detectors[i].model.representation for i in generic])]
    per = max(1, detectors[0].chunk_size // PATCHES_PER_RECTANGLE) * PATCHES_PER_RECTANGLE
    spans = [(s, min(s + per, len(rows))) for s in range(0, len(rows), per)]

    def chunk(se):
        r, c = rows[se[0]:se[1]], cols[se[0]:se[1]]
        out = [None] * len(scorers)
        alone = np.zeros(len(scorers))
        start = time.thread_time()
        for g in groups:
            t = time.thread_time()
            first = scorers[g[0]]
            if len(g) == 1:
                out[g[0]] = first.scores(img, msk, r, c, mean, inv, full)
                alone[g[0]] = time.thread_time() - t
                continue
            X, M = first.whitened(img, msk, r, c, mean, inv, full)
            shared = time.thread_time() - t
            for i in g:
                t = time.thread_time()
                out[i] = scorers[i].encoded_scores(X, M)
                alone[i] = shared + time.thread_time() - t
        return out, alone, time.thread_time() - start

    done = _map(pool, chunk, spans)
    alone = sum(a for _, a, _ in done)
    spent = sum(t for _, _, t in done)
    result = []
    for i, (_, const) in enumerate(weights):
        S = np.concatenate([d[0][i] for d in done])
        S = S.reshape(n, GRID, GRID, -1).astype(np.float64)
        pooled = (S[:, :SPLIT, :SPLIT, 0].sum((1, 2)) + S[:, :SPLIT, SPLIT:, 1].sum((1, 2))
                  + S[:, SPLIT:, :SPLIT, 2].sum((1, 2)) + S[:, SPLIT:, SPLIT:, 3].sum((1, 2)))
        result.append(pooled + const)
    return result, list(alone), spent


class _CanvasCache:
    """Rotated canvases made on first use (one lock per angle), dropped after their last use."""

    def __init__(self, make, uses):
        self._make = make
        self._uses = dict(uses)
        self._locks = {k: threading.Lock() for k in self._uses}
        self._count_lock = threading.Lock()
        self._canvas = {}

    def get(self, key):
        with self._locks[key]:
            if key not in self._canvas:
                self._canvas[key] = self._make(key)
            return self._canvas[key]

    def release(self, key):
        with self._count_lock:
            self._uses[key] -= 1
            if self._uses[key] == 0:
                self._canvas.pop(key, None)


class DenseDetector(_Base):
    """The grid search with dense, shared computation (see the :mod:`dlsr.detection` docstring).

    Parameters
    ----------
    model : DLSRDetector
    grid : SearchGrid
    top_k : int
    region, background, min_height :
        See :class:`~dlsr.detection.ExactGridDetector`.
    rescore : int or None
        The best dense candidates rescored exactly and re-ranked (0: none); see
        :meth:`exact_scores`. None: 100 for the full grid (on four synthetic 640x480 images
        and one Jacquard view the exact best of the full grid was at dense rank 2 to 38), 60 in
        coarse-to-fine mode.
    coarse_to_fine : bool
        Coarse-to-fine mode: first the coarse grid (``coarse_grid``: 6 angles, openings and
        jaws every 20 px, centres every 10 px) is scored with patches encoded every
        ``coarse_stride`` positions; then the paper's grid is scored densely (every position)
        around the ``refine_top`` best coarse candidates: the neighbouring angles, openings and
        jaws of ``grid`` (one step each way) at centres within ``refine_radius`` steps; the
        best ``rescore`` of those are rescored exactly. Chosen among 27 variants on 123
        labelled images with object-wise models (95 synthetic 640x480 Cornell-layout images,
        28 Jacquard views at half size): the same accuracy as the full grid on the synthetic
        images (40/95), one image more on Jacquard (25/28 against 24/28), top-1 agreeing with
        the full grid by the rectangle metric on 90 % / 75 % of them, at about a fifth of the
        full grid's CPU time on the synthetic images (0.66 s against 3.1 s) and an eighth on
        Jacquard (0.92 s against 7.1 s); ``scripts/bench_detection.py`` times it.
    coarse_grid : SearchGrid
    refine_top : int
    refine_radius : int
        Centre offsets of the refinement, in steps of ``grid`` (0: the coarse centre only;
        the coarse grid already has the paper's centres).
    chunk_size : int
        Patches encoded at once (per thread).
    straddle : float
        Weight of the canvas patches in the rows that straddle the edge of a padded crop
        (``h < w``); the rest of their weight goes to the all-masked (padding) code. The exact
        crop masks their padding part; 0.5 tracked the exact scores best on the Jacquard
        samples (1: canvas only, 0: padding only).
    coarse_stride : int
        Coarse stage of the coarse-to-fine mode: patches are encoded every ``coarse_stride``
        positions in each direction and their scores replicated (2: a quarter of the
        encodings).
    fill : {"nearest", "band", "griddata"} or None
        Hole filling of the depth before the canvas normals are computed (once per image).
        Filled values only reach the normals of valid pixels next to a hole (normals at
        invalid pixels are masked), so the cheap ``"nearest"`` is the default; None uses the
        model's preprocessing choice (the exact path's, ``"band"``).
    n_threads : int or None
        Threads for the (angle, opening) canvases and the rescoring; None: the process's
        share of the cores (:func:`dlsr._threads.thread_budget`: the CPUs available to it,
        one in each of two loky workers on two cores). BLAS runs single-threaded inside (each
        thread does whole products).
    colour_whitening : bool
        Whiten a canvas patch without any valid depth on its colour entries only
        (:class:`_PatchScorer`'s ``colour_only``; in a pile about 45 % of the patches have
        masked entries, and a quarter of those no depth at all); False: on all 288 entries.
        The scores are the same up to float rounding (the products sum in another order);
        the proposals were the same on the pile and single-object scenes compared
        (``docs/experiments/2026-12-06-dense-clutter.md``).
    """

    def __init__(self, model, grid=PAPER_GRID, top_k=5, region="auto", background=None,
                 min_height=0.006, rescore: int | None = None, coarse_to_fine: bool = False,
                 coarse_grid: SearchGrid = COARSE_GRID, refine_top: int = 40,
                 refine_radius: int = 0,
                 chunk_size: int = 2048, fill: str | None = "nearest",
                 straddle: float = 0.5, coarse_stride: int = 2, n_threads: int | None = None,
                 colour_whitening: bool = True):
        super().__init__(model, grid, top_k, region, background, min_height)
        self.rescore = rescore
        self.coarse_to_fine = coarse_to_fine
        self.coarse_grid = coarse_grid
        self.refine_top = refine_top
        self.refine_radius = refine_radius
        self.chunk_size = chunk_size
        self.fill = fill
        self.straddle = straddle
        self.coarse_stride = coarse_stride
        self.n_threads = n_threads
        self.colour_whitening = colour_whitening

    # -- public ------------------------------------------------------------------------------
    def detect(self, obs) -> Detection:
        """Detect grasps in one observation.

        ``timings`` holds wall seconds per stage (``candidates``, ``dense``, ``rescore``), the
        process CPU seconds of the last two (``dense_cpu``, ``rescore_cpu``, all threads), the
        encoding's summed thread seconds and useful products (``encode``, ``encode_flops``)
        and ``threads``.
        """
        t0 = time.perf_counter()
        _check_obs(obs)
        stats = _new_stats()
        if self.coarse_to_fine:  # the coarse stage keeps the grid's jaw clearance
            coarse = dataclasses.replace(self.coarse_grid, clear_jaws=self.grid.clear_jaws,
                                         max_width=self.grid.max_width)
            cand, reason, region = self._candidates(obs, coarse)
        else:
            cand, reason, region = self._candidates(obs)
        if reason:
            return _empty(reason, t0)
        t1, c1 = time.perf_counter(), time.process_time()
        physical = self._physical_term(obs, region)
        with _scoring(self) as pool:
            src = self._source(obs, cand)
            stride = self.coarse_stride if self.coarse_to_fine else 1
            scores = self._dense_scores(src, cand, stats, pool, stride) + physical(cand)
            n_scored = len(cand)
            if self.coarse_to_fine:
                seeds = cand[np.argsort(-scores, kind="stable")[: self.refine_top]]
                fine = self._neighbourhood(obs, seeds, region)
                if len(fine):  # the seeds are in it: rank the fine (stride-1) scores only
                    scores = self._dense_scores(src, fine, stats, pool, 1) + physical(fine)
                    cand = fine
                    n_scored += len(fine)
            t2, c2 = time.perf_counter(), time.process_time()
            n_exact = 0
            n_rescore = self.rescore
            if n_rescore is None:
                n_rescore = 60 if self.coarse_to_fine else 100
            if n_rescore:
                top = np.argsort(-scores, kind="stable")[:n_rescore]
                cand = cand[top]
                scores = self._exact_scores(obs, cand, pool) + physical(cand)
                n_exact = len(cand)
        order = np.argsort(-scores, kind="stable")[: self.top_k]
        t3, c3 = time.perf_counter(), time.process_time()
        timings = {"candidates": t1 - t0, "dense": t2 - t1, "rescore": t3 - t2,
                   "dense_cpu": c2 - c1, "rescore_cpu": c3 - c2,
                   "encode": stats["encode_seconds"], "encode_flops": stats["encode_flops"],
                   "threads": self._threads()}
        return Detection(cand[order], scores[order], n_candidates=n_scored,
                         n_encodings=stats["n_encodings"] + n_exact * PATCHES_PER_RECTANGLE,
                         seconds=t3 - t0, timings=timings)

    def score(self, obs, candidates, source=None, stats=None) -> np.ndarray:
        """Dense scores of arbitrary candidates ``(n, 5)`` (no exact rescoring).

        ``stats`` (a dict), when given, accumulates ``n_encodings``, ``encode_flops`` and
        ``encode_seconds`` (summed over threads).
        """
        cand = np.asarray(candidates, dtype=float).reshape(-1, 5)
        if len(cand) == 0:
            return np.full(0, -np.inf)
        with _scoring(self) as pool:
            if source is None:
                source = self._source(obs, cand)
            own = _new_stats()
            out = self._dense_scores(source, cand, own, pool, 1)
        if stats is not None:
            _merge_stats(stats, own)
        return out

    def exact_scores(self, obs, rects) -> np.ndarray:
        """Exact scores of rectangles (the rescoring).

        The rectangle images are recognition's (:func:`dlsr.preprocess.rectangle_images`);
        their 19 x 19 patches are encoded by the dense kernels and pooled over the quadrants,
        which gives :meth:`~dlsr.detection.DLSRDetector.rectangle_scores` up to float rounding.

        Returns
        -------
        ndarray of shape (n,), float64
        """
        with _scoring(self) as pool:
            return self._exact_scores(obs, rects, pool)

    def exact_images(self, obs, rects):
        """The rectangle images of :meth:`exact_scores` and their patches' statistics, which
        depend on the model's preprocessing only: computed once, they are scored by every
        model of the same preprocessing (:meth:`score_images`).

        Returns
        -------
        tuple or None
            Opaque inputs of :meth:`score_images` (None for no rectangle).
        """
        with _scoring(self) as pool:
            return self._exact_images(obs, rects, pool)

    def score_images(self, images) -> np.ndarray:
        """:meth:`exact_scores` of the rectangles of ``images`` (from :meth:`exact_images` of
        a detector whose model has this model's preprocessing), bit for bit.

        Returns
        -------
        ndarray of shape (n,), float64
        """
        if images is None:
            return np.zeros(0)
        with _scoring(self) as pool:
            return self._score_images(images, pool)

    # -- internals ---------------------------------------------------------------------------
    def _physical_term(self, obs, region):
        """``rects -> the model's physical scores`` (zeros without one; the table is fitted
        once per observation)."""
        if not self.model.physical:
            return lambda rects: np.zeros(len(rects))
        table = table_surface(obs["depth"], obs.get("depth_valid"))
        return lambda rects: self.model.physical_scores(obs, rects, region, table)

    def _threads(self) -> int:
        if self.n_threads is not None:
            return max(1, int(self.n_threads))
        return thread_budget()

    def _pool(self):
        n = self._threads()
        return ThreadPoolExecutor(n) if n > 1 else contextlib.nullcontext()

    def _source(self, obs, cand):
        H, W = np.asarray(obs["depth"]).shape
        m = int(np.max(cand[:, 3:5]) * 0.75) + 8 if len(cand) else 0
        roi = (max(0, int(cand[:, 1].min()) - m), min(H, int(cand[:, 1].max()) + m + 1),
               max(0, int(cand[:, 0].min()) - m), min(W, int(cand[:, 0].max()) + m + 1))
        return _Source(obs, self.model.preprocess, roi, self.fill)

    def _exact_scores(self, obs, rects, pool) -> np.ndarray:
        images = self._exact_images(obs, rects, pool)
        return np.zeros(0) if images is None else self._score_images(images, pool)

    def _exact_images(self, obs, rects, pool):
        from ..preprocess import rectangle_images

        rects = np.asarray(rects, dtype=float).reshape(-1, 5)
        if len(rects) == 0:
            return None
        pre = dict(self.model.preprocess)
        pre["size"] = SIZE
        pre["locate"] = "compiled"  # the holes' values up to float rounding, 5 times sooner
        parts = [r for r in np.array_split(rects, self._threads()) if len(r)]
        made = _map(pool, lambda r: rectangle_images(obs["rgb"], obs["depth"],
                                                     obs.get("depth_valid"), r, **pre), parts)
        n = len(rects)
        img = np.concatenate([m[0] for m in made]).reshape(n * SIZE, SIZE, 8)
        msk = np.concatenate([m[1] for m in made]).reshape(n * SIZE, SIZE, 8)
        mean, inv, full = window_statistics(img, msk)
        g = np.arange(GRID)
        rows = (np.arange(n)[:, None, None] * SIZE + g[None, :, None]
                + np.zeros(GRID, np.intp)[None, None, :]).ravel()
        cols = np.broadcast_to(g[None, None, :], (n, GRID, GRID)).ravel()
        return n, img, msk, rows, cols, mean, inv, full

    def _score_images(self, images, pool) -> np.ndarray:
        return _scores_of_images([self], images, pool)[0][0]

    def _neighbourhood(self, obs, seeds, region=None):
        g = self.grid
        angles = np.radians(np.asarray(g.angles_deg, float))
        da = np.radians(np.min(np.diff(np.sort(np.asarray(g.angles_deg, float))))) \
            if len(angles) > 1 else 0.0
        ow = np.asarray(g.openings, float)
        jh = np.asarray(g.jaws, float)
        dw = np.min(np.diff(np.sort(ow))) if len(ow) > 1 else 0.0
        dh = np.min(np.diff(np.sort(jh))) if len(jh) > 1 else 0.0
        angles = normalize_angle(angles)
        r = int(self.refine_radius)
        offsets = np.arange(-r, r + 1, dtype=float) * g.step
        rows = []
        H, W = np.asarray(obs["depth"]).shape
        for x, y, t, w, h in seeds:
            ths = angles[np.abs(normalize_angle(angles - t)) <= da * 1.01]
            ws = ow[np.abs(ow - w) <= dw * 1.01]
            hs = jh[np.abs(jh - h) <= dh * 1.01]
            A, Wm, Hm, Y, X = np.meshgrid(ths, ws, hs, y + offsets, x + offsets, indexing="ij")
            keep = Wm >= Hm
            rows.append(np.column_stack([X[keep], Y[keep], A[keep], Wm[keep], Hm[keep]]))
        rows = np.concatenate(rows) if rows else np.zeros((0, 5))
        if not len(rows):
            return np.zeros((0, 5))
        fine = np.unique(np.round(rows, 6), axis=0)
        corners = corners_from_array(fine)
        inside = ((corners[..., 0] >= 0) & (corners[..., 0] <= W - 1)
                  & (corners[..., 1] >= 0) & (corners[..., 1] <= H - 1)).all(axis=1)
        fine = fine[inside]
        if g.clear_jaws and region is not None:
            fine = fine[jaws_clear(region, fine)]
        return within_reach(obs, fine, region, g)

    def _padding_code_scores(self, V):
        """``V[:, q] . code(all-masked patch)`` per quadrant (the exact path's padding)."""
        rep = self.model.representation
        p = rep.dictionary.shape[1]
        code = encode_patches(np.zeros((1, p), np.float32), np.zeros((1, p), bool), rep,
                              self.model.encoder, self.model.encoder_param,
                              self.model.polarity)
        return np.asarray(code, np.float64)[0] @ V  # (4,)

    def _canvas(self, source: _Source, theta, A0, B0, Wf, Hf):
        """Full-resolution rotated canvas: values (Hf, Wf, 8), image mask, depth mask."""
        from ..preprocess import _sample, surface_normals

        u, v = _axes(theta)
        centre = (A0 + (Wf - 1) / 2) * u + (B0 + (Hf - 1) / 2) * v
        smp = _sample(source.src, (centre[0], centre[1], theta, 0, 0), Wf, Hf)
        inside = smp[..., 5] >= _ONE
        dvalid = (smp[..., 4] >= _ONE) & inside
        pre = self.model.preprocess
        scale = float(pre.get("depth_scale", 1000.0))
        full = np.zeros((Hf, Wf, 8), dtype=np.float32)
        rgb = smp[..., :3] * inside[..., None]
        full[..., 1:4] = rgb
        full[..., 0] = rgb @ _GRAY
        full[..., 4] = np.where(dvalid, (smp[..., 3].astype(np.float64) - source.ref) * scale,
                                0.0)
        filled = (smp[..., 6].astype(np.float64) - source.ref) * scale
        full[..., 5:8] = surface_normals(filled)
        return full, inside, dvalid

    def _dense_scores(self, source, cand, stats, pool, stride) -> np.ndarray:
        """Dense scores of ``cand``: one task per (angle, opening), run in the pool."""
        out = np.full(len(cand), -np.inf)
        V, const = self.model.quadrant_weights()
        scorer = _PatchScorer(self.model, V, colour_only=self.colour_whitening)
        c0 = self._padding_code_scores(V)
        theta = normalize_angle(cand[:, 2])
        geoms, tasks = [], []
        for t in np.unique(np.round(theta, 9)):
            sel = np.flatnonzero(np.abs(theta - t) < 1e-8)
            u, v = _axes(float(t))
            c = cand[sel]
            a = c[:, 0] * u[0] + c[:, 1] * u[1]
            b = c[:, 0] * v[0] + c[:, 1] * v[1]
            margin = int(round(c[:, 3:5].max())) / 2 + 4
            A0 = math.floor(a.min() - margin)
            B0 = math.floor(b.min() - margin)
            Wf = int(math.ceil(a.max() + margin)) - A0 + 1
            Hf = int(math.ceil(b.max() + margin)) - B0 + 1
            key = len(geoms)
            geoms.append((float(t), A0, B0, Wf, Hf))
            ns = np.rint(c[:, 3]).astype(int)
            for n in np.unique(ns):
                gsel = np.flatnonzero(ns == n)
                s = SIZE / n
                cost = min(len(gsel) * (GRID + 1) ** 2,
                           (np.ptp(a[gsel]) * s + 2 * SIZE) * (np.ptp(b[gsel]) * s + 2 * SIZE))
                tasks.append((cost, key, int(n), a[gsel] - A0, b[gsel] - B0, c[gsel, 4],
                              sel[gsel]))
        tasks.sort(key=lambda x: -x[0])  # longest first: balanced threads
        uses = {}
        for task in tasks:
            uses[task[1]] = uses.get(task[1], 0) + 1
        canvases = _CanvasCache(lambda k: self._canvas(source, *geoms[k]), uses)

        def run(task):
            _, key, n, a, b, hs, idx = task
            full, imask, dmask = canvases.get(key)
            st = _new_stats()
            self._score_opening(full, imask, dmask, n, a, b, hs, idx, out, scorer, const, c0,
                                st, stride)
            canvases.release(key)
            return st

        for st in _map(pool, run, tasks):
            _merge_stats(stats, st)
        return out

    def _score_opening(self, full, imask, dmask, n, a, b, hs, idx, out, scorer, const, c0,
                       stats, stride=1):
        """Score candidates of one (angle, opening); ``a, b`` centres in canvas coordinates."""
        interp = {"area": cv2.INTER_AREA, "linear": cv2.INTER_LINEAR,
                  "cubic": cv2.INTER_CUBIC}[self.model.preprocess.get("interpolation", "area")]
        s = SIZE / n
        nrows = np.maximum(1, np.rint(hs).astype(int))
        nh = np.minimum(SIZE, np.maximum(1, np.rint(nrows * s).astype(int)))
        r0 = (SIZE - nh) // 2
        j0 = a - (n - 1) / 2  # full-res column of the crop's first column
        i0 = b - (nrows - 1) / 2 - r0 / s  # full-res row of the 24-frame's top
        q = n // math.gcd(n, SIZE)
        Jst = math.floor(j0.min()) - 2
        Ist = math.floor(i0.min()) - 2
        Ws = math.ceil(j0.max()) + n + 3 - Jst
        Hs = math.ceil(i0.max()) + n + 3 - Ist
        Ws = -(-Ws // q) * q
        Hs = -(-Hs // q) * q
        stack = np.zeros((Hs, Ws, 10), dtype=np.float32)
        Hf, Wf = imask.shape
        ra, rb = max(Ist, 0), min(Ist + Hs, Hf)
        ca, cb = max(Jst, 0), min(Jst + Ws, Wf)
        if ra < rb and ca < cb:
            tgt = stack[ra - Ist:rb - Ist, ca - Jst:cb - Jst]
            tgt[..., :8] = full[ra:rb, ca:cb]
            tgt[..., 8] = imask[ra:rb, ca:cb]
            tgt[..., 9] = dmask[ra:rb, ca:cb]
        oh, ow = Hs * SIZE // n, Ws * SIZE // n
        if (oh, ow) == (Hs, Ws):
            small = stack
        elif interp == cv2.INTER_LINEAR:
            small = cv2.resize(stack, (ow, oh), interpolation=interp)
        else:
            small = np.concatenate(
                [cv2.resize(stack[..., i:i + 4], (ow, oh), interpolation=interp)
                 .reshape(oh, ow, -1) for i in range(0, 10, 4)], axis=2)
        img = np.ascontiguousarray(small[..., :8])
        im = small[..., 8] > 0.75
        dm = small[..., 9] > 0.75
        msk = np.empty(img.shape, dtype=bool)
        msk[..., :4] = im[..., None]
        msk[..., 4:] = dm[..., None]
        img *= msk
        # window top-left in the resized canvas
        J0 = (j0 - Jst) * s
        I0 = (i0 - Ist) * s
        Ji = np.floor(J0).astype(np.intp)
        Ii = np.floor(I0).astype(np.intp)
        fj = J0 - Ji
        fi = I0 - Ii
        Hp, Wp = oh - PATCH + 1, ow - PATCH + 1
        Ji = np.clip(Ji, 0, Wp - GRID - 1)
        Ii = np.clip(Ii, 0, Hp - GRID - 1)
        # content patch rows (overlapping the crop's content rows); the others are padding
        lo = np.maximum(r0 - PATCH + 1, 0)
        hi = np.minimum(r0 + nh, GRID)
        # patch rows entirely inside the content; the rows between straddle its edge
        lo_f = np.minimum(r0, GRID)
        hi_f = np.maximum(lo_f, np.minimum(r0 + nh - PATCH + 1, GRID))
        alpha = float(self.straddle)
        # only the patch positions some window needs (+1 for the bilinear neighbours)
        diff = np.zeros((Hp + 1, Wp + 1), dtype=np.int32)
        np.add.at(diff, (Ii + lo, Ji), 1)
        np.add.at(diff, (Ii + lo, Ji + GRID + 1), -1)
        np.add.at(diff, (Ii + hi + 1, Ji), -1)
        np.add.at(diff, (Ii + hi + 1, Ji + GRID + 1), 1)
        needed = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:Hp, :Wp] > 0
        if stride > 1:  # coarse stage: encode every stride-th position, replicate the scores
            keep = np.zeros_like(needed)
            keep[::stride, ::stride] = True
            needed &= keep
        S = self._score_maps(img, msk, scorer, stats, needed)  # (Hp, Wp, 4)
        if stride > 1:
            S = np.repeat(np.repeat(S[::stride, ::stride], stride, axis=0), stride,
                          axis=1)[:Hp, :Wp]
            if S.shape[:2] != (Hp, Wp):
                S = np.pad(S, ((0, Hp - S.shape[0]), (0, Wp - S.shape[1]), (0, 0)))
        T = np.zeros((Hp + 1, Wp + 1, S.shape[2]))  # the summed-area tables of the 4 maps
        np.cumsum(np.cumsum(S, axis=0, dtype=np.float64), axis=1, out=T[1:, 1:])
        quads = ((0, SPLIT, 0, SPLIT), (0, SPLIT, SPLIT, GRID),
                 (SPLIT, GRID, 0, SPLIT), (SPLIT, GRID, SPLIT, GRID))
        # per quadrant: content rows [ra, rb), rows entirely in the content [fa, fb) and
        # the padding's share (the all-masked code) of the sum, independent of the position
        rows = []
        res = np.full(len(a), float(const))
        for k, (qa, qb, qc, qd) in enumerate(quads):
            ra_ = np.clip(lo, qa, qb)
            rb_ = np.clip(hi, qa, qb)
            npad = ((qb - qa) - (rb_ - ra_)) * (qd - qc)
            if alpha != 1.0:  # straddling rows: alpha * canvas + (1 - alpha) * padding
                fa = np.clip(lo_f, qa, qb)
                fb = np.maximum(np.clip(hi_f, qa, qb), fa)
                nst = ((rb_ - ra_) - (fb - fa)) * (qd - qc)
                res += (npad + (1 - alpha) * nst) * c0[k]
            else:
                fa = fb = None
                res += npad * c0[k]
            rows.append((k, ra_, rb_, fa, fb, qc, qd))
        for di, dj, wgt in ((0, 0, (1 - fi) * (1 - fj)), (0, 1, (1 - fi) * fj),
                            (1, 0, fi * (1 - fj)), (1, 1, fi * fj)):
            rr = Ii + di
            c_lo = Ji + dj
            tot = np.zeros(len(a))
            for k, ra_, rb_, fa, fb, qc, qd in rows:
                Tk = T[..., k]
                box = _box_sums(Tk, rr + ra_, rr + rb_, c_lo + qc, c_lo + qd)
                if fa is not None:
                    inner = _box_sums(Tk, rr + fa, rr + fb, c_lo + qc, c_lo + qd)
                    box = inner + alpha * (box - inner)
                tot += box
            res += wgt * tot
        out[idx] = res

    def _score_maps(self, img, msk, scorer, stats, needed=None):
        """Per-pixel ``V[:, q] . code(patch)`` for the 6x6 patches of a canvas.

        Patches are standardised (masked per-group statistics from running window sums,
        float64, :func:`dlsr._dense.window_stats`), whitened and encoded by ``scorer``
        (a :class:`_PatchScorer`) exactly as :func:`dlsr.whitening.standardize_patches`,
        :func:`~dlsr.whitening.apply_zca` and :func:`dlsr.features.encode_patches` do, in
        chunks of ``chunk_size`` patches, only at the positions where ``needed`` is True (all
        when None; the others stay 0).

        Returns
        -------
        ndarray of shape (H - 5, W - 5, q), float32
        """
        Hc, Wc, _ = img.shape
        Hp, Wp = Hc - PATCH + 1, Wc - PATCH + 1
        nq = scorer.V.shape[1]
        S = np.zeros((max(Hp, 0) * max(Wp, 0), nq), dtype=np.float32)
        if Hp <= 0 or Wp <= 0:
            return S.reshape(max(Hp, 0), max(Wp, 0), nq)
        pos = np.flatnonzero(needed.ravel()) if needed is not None else np.arange(Hp * Wp)
        if len(pos) == 0:
            return S.reshape(Hp, Wp, nq)
        img = np.ascontiguousarray(img, dtype=np.float32)
        msk = np.ascontiguousarray(msk, dtype=bool)
        mean, inv, full = window_statistics(img, msk)
        t0 = time.perf_counter()
        apart = scorer.colour_only and scorer.triangle and scorer.whiten
        if apart:  # the masked patches apart, those without depth on their colour entries
            ok = full.ravel()[pos]
            masked, pos = pos[~ok], pos[ok]
            S[masked], flops = scorer.masked_scores(img, msk, masked // Wp, masked % Wp,
                                                    mean, inv, full, self.chunk_size)
            stats["encode_flops"] += flops
        for st in range(0, len(pos), self.chunk_size):
            pc = pos[st:st + self.chunk_size]
            S[pc] = scorer.scores(img, msk, pc // Wp, pc % Wp, mean, inv, full)
        n_masked = int(np.count_nonzero(~full.ravel()[pos]))
        stats["n_encodings"] += len(pos) + (len(masked) if apart else 0)
        stats["encode_flops"] += (scorer.flops * (len(pos) - n_masked)
                                  + scorer.flops_masked * n_masked)
        stats["encode_seconds"] += time.perf_counter() - t0
        return S.reshape(Hp, Wp, nq)


register_detector("dense", DenseDetector)
