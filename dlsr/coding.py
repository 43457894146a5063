"""Sparse and dense encoders of patches on a dictionary (batched, exact, fast).

Conventions follow scikit-learn: patches ``X`` are rows ``(n, p)``, a dictionary ``D`` has its
atoms as rows ``(d, p)``, codes are ``(n, d)``. Objectives follow the authors' reference
implementation (see ``../shared/reference/dlsr-reference-facts.md``):

- lasso: ``0.5 ||x - D^T a||^2 + lam ||a||_1`` (the same problem as scikit-learn's
  ``sparse_encode(algorithm="lasso_lars", alpha=lam)``); masked:
  ``0.5 ||m * (x - D^T a)||^2 + lam (||m||_0 / p) ||a||_1``;
- OMP with ``L`` non-zeros (the selection rule and least squares of scikit-learn's
  ``orthogonal_mp_gram``); masked OMP works on the masked residual;
- soft threshold ``sign(D x) max(|D x| - lam, 0)``;
- k-means triangle ``max(mean(z) - z_k, 0)`` with ``z_k = ||x - c_k||``;
- polarity split ``[max(a, 0), max(-a, 0)]``.

Algorithms
----------
The lasso is solved exactly by a homotopy (LARS-lasso) run on all patches of a chunk at once:
every step is one dense matrix product over the chunk (the correlation direction), the inverse
of each patch's active Gram block is updated by bordering (add) or Schur downdating (drop), and
finished patches leave the batch. Large matrix products run in float32 (the correlations are
re-synchronised exactly every 16 steps); the active-set inverses and the final coefficients,
``a_A = G_AA^{-1} (b_A - lam s_A)`` (refined once with exact products for per-row masks), are
float64, and every patch is checked against the lasso optimality (KKT) conditions with exact
products; the rare patch that fails (a float32 near-tie) is solved again entirely in float64,
and a degenerate one after that by scikit-learn's LARS. An atom that is linearly dependent on
the active ones (e.g. a repeated atom) is kept out for that patch, as LARS does. Masked
problems have one Gram matrix per mask: rows sharing a mask (fully valid patches, padding
patterns; at least ``min_group`` of them) are solved as a group with that Gram matrix; the
other rows use per-row masked products ``((W D) * m) D^T``.

OMP is batched the same way (one atom per step for every patch, bordered inverses, the Gram
columns of the selected atoms kept per patch in float32 for the residual correlations; the
coefficients are float64 least squares, refined with exact products for per-row masks).

Chunks of rows (``chunk_size``, small enough to stay in cache) run in ``n_jobs`` threads with
single-threaded BLAS (numpy releases the GIL); the dense encoders use threaded BLAS directly.
Results do not depend on the number of threads.

Masked OMP: exact masked least squares
    The reference library's masked OMP assumes that masked atoms keep unit norm. Here the
    coefficients are the exact least-squares fit of the valid entries,
    ``a_S = (D_S diag(m) D_S^T)^{-1} D_S diag(m) x``, and the atom chosen at each step is the
    one with the largest masked residual correlation ``|d_j^T diag(m) r|`` (scikit-learn's rule
    applied to the masked problem). This was chosen deliberately: it is the principled
    solution of the masked problem and equals the unmasked OMP for an all-ones mask.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_array, check_is_fitted, validate_data
from threadpoolctl import threadpool_limits

__all__ = [
    "lasso",
    "omp",
    "soft_threshold",
    "kmeans_triangle",
    "polarity_split",
    "natural_encoder",
    "natural_encode",
    "encode",
    "lasso_objective",
    "lasso_rowwise",
    "omp_rowwise",
    "SparseEncoder",
    "ENCODER_METHODS",
    "ESTIMATORS",
]

ENCODER_METHODS = ("lasso", "omp", "threshold", "triangle")

_TINY = np.finfo(np.float64).tiny


# --------------------------------------------------------------------------------------------
# validation helpers


def _check_xd(X, D, mask=None, name="X"):
    X = np.asarray(X)
    D = np.asarray(D)
    if X.ndim != 2 or D.ndim != 2:
        raise ValueError(f"{name} and D must be 2-D, got shapes {X.shape} and {D.shape}")
    if X.shape[1] != D.shape[1]:
        raise ValueError(
            f"{name} has {X.shape[1]} features per row but the dictionary atoms have "
            f"{D.shape[1]}"
        )
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(D))):
        raise ValueError(f"{name} and D must be finite (no NaN or inf)")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != X.shape:
            raise ValueError(f"mask must have the shape of {name} {X.shape}, got {mask.shape}")
        mask = mask.astype(bool, copy=False)
    return X, D, mask


def _chunks(n, size):
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))


# --------------------------------------------------------------------------------------------
# Gram operators: how a batch of rows sees its (possibly masked) Gram matrix


class _SharedGram:
    """All rows share ``G = D_m D_m^T`` (unmasked, or one mask for the whole group)."""

    def __init__(self, G):
        self.G64 = np.ascontiguousarray(G, dtype=np.float64)
        self.G32 = self.G64.astype(np.float32)
        self.diag = np.diag(self.G64).copy()

    def subset(self, rows):  # noqa: ARG002 - same operator for every row
        return self

    def columns(self, j):
        """Gram columns ``G[:, j_r]`` for each row r, shape (r, d), float64."""
        return self.G64[j]

    def columns32(self, j):
        return self.G32[j]

    def entries(self, j, slots, col32):  # noqa: ARG002
        """Exact Gram entries ``G[j_r, s]`` for the atoms in ``slots`` (r, t), float64."""
        return self.G64[j[:, None], slots]

    def apply(self, W, exact=False):
        """``G w_r`` for each row, shape (r, d); float64 when exact, else float32."""
        if exact:
            return np.asarray(W, dtype=np.float64) @ self.G64
        return np.asarray(W, dtype=np.float32) @ self.G32

    def gram_diag(self, j):
        return self.diag[j]


class _MaskedGram:
    """Each row r has its own ``G_r = D diag(m_r) D^T``; never formed."""

    def __init__(self, D, M):
        self.D64 = np.ascontiguousarray(D, dtype=np.float64)
        self.D32 = self.D64.astype(np.float32)
        self.M = M

    def subset(self, rows):
        out = _MaskedGram.__new__(_MaskedGram)
        out.D64, out.D32, out.M = self.D64, self.D32, self.M[rows]
        return out

    def columns(self, j):
        return self.columns32(j).astype(np.float64)

    def columns32(self, j):
        Dj = self.D32[j] * self.M
        return Dj @ self.D32.T

    def entries(self, j, slots, col32):  # noqa: ARG002
        """Gram entries from the float32 columns (refined by the callers)."""
        return np.take_along_axis(col32, slots, axis=1).astype(np.float64)

    def apply(self, W, exact=False):
        if exact:
            return ((np.asarray(W, dtype=np.float64) @ self.D64) * self.M) @ self.D64.T
        W = np.asarray(W, dtype=np.float32)
        return ((W @ self.D32) * self.M) @ self.D32.T

    def gram_diag(self, j):
        Dj = self.D64[j]
        return np.einsum("rp,rp->r", Dj * self.M, Dj)


def _scatter(slots_atoms, values, d, dtype=np.float64):
    """Dense C-contiguous (r, d) from per-slot atoms (``-1`` = empty slot) and values."""
    r = slots_atoms.shape[0]
    W = np.zeros((r, d), dtype=dtype)
    ri, si = np.nonzero(slots_atoms >= 0)
    W[ri, slots_atoms[ri, si]] = values[ri, si]
    return W


def _border_add(Ginv, slot, g, sigma):
    """Bordered inverse after adding an atom at ``slot`` (per row).

    ``g`` (r, k) holds the Gram entries between the new atom and the current slots (0 for
    empty slots), ``sigma`` the Schur complement ``G_jj - g^T Ginv g``.
    """
    v = np.matmul(Ginv, g[:, :, None])[:, :, 0]
    Ginv += v[:, :, None] * v[:, None, :] / sigma[:, None, None]
    r = np.arange(Ginv.shape[0])
    Ginv[r, slot, :] = -v / sigma[:, None]
    Ginv[r, :, slot] = -v / sigma[:, None]
    Ginv[r, slot, slot] = 1.0 / sigma


def _border_drop(Ginv, slot):
    """Inverse of the active Gram block after removing ``slot`` (per row)."""
    r = np.arange(Ginv.shape[0])
    col = Ginv[r, :, slot].copy()
    piv = col[r, slot].copy()
    Ginv -= col[:, :, None] * col[:, None, :] / piv[:, None, None]
    Ginv[r, slot, :] = 0.0
    Ginv[r, :, slot] = 0.0


def _grow(arrays3, arrays2, k_new):
    out3 = []
    for A in arrays3:
        B = np.zeros((A.shape[0], k_new, k_new), dtype=A.dtype)
        B[:, : A.shape[1], : A.shape[2]] = A
        out3.append(B)
    out2 = []
    for A, fill in arrays2:
        B = np.full((A.shape[0], k_new), fill, dtype=A.dtype)
        B[:, : A.shape[1]] = A
        out2.append(B)
    return out3, out2


# --------------------------------------------------------------------------------------------
# lasso: batched homotopy


def _lasso_homotopy(B, lam, op, exact=False, max_steps=None, resync=16):
    """Solve ``min 0.5 a^T G_r a - b_r^T a + lam_r ||a||_1`` for every row r (homotopy).

    Parameters
    ----------
    B : ndarray of shape (n, d), float64
        Correlations ``D_m x`` (masked data).
    lam : ndarray of shape (n,)
        Per-row penalty.
    op : _SharedGram or _MaskedGram
    exact : bool
        Keep the correlations and run the large products in float64 too.
    max_steps : int, optional
        Step limit per row (default ``8 d``).
    resync : int
        Recompute the correlations exactly every ``resync`` steps (float32 mode).

    Returns
    -------
    A : ndarray of shape (n, d), float64
    ok : ndarray of shape (n,), bool
        False where the path did not finish within the step limit.
    """
    n, d = B.shape
    out = np.zeros((n, d))
    ok = np.ones(n, dtype=bool)
    if n == 0:
        return out, ok
    if max_steps is None:
        max_steps = 8 * d
    fdt = np.float64 if exact else np.float32
    absB = np.abs(B)
    j0 = np.argmax(absB, axis=1)
    lam0 = absB[np.arange(n), j0]
    rows = np.flatnonzero(lam0 > lam)
    if rows.size == 0:
        return out, ok

    k = 8
    r = rows.size
    rr = np.arange(r)
    c = B[rows].astype(fdt)
    lamc = lam0[rows].copy()
    lamt = np.asarray(lam, dtype=np.float64)[rows]
    slots = np.full((r, k), -1, dtype=np.int64)
    sgn = np.zeros((r, k))
    coef = np.zeros((r, k))
    Ginv = np.zeros((r, k, k))
    sub = op.subset(rows)
    j = j0[rows]
    slots[:, 0] = j
    sgn[:, 0] = np.sign(B[rows, j])
    Ginv[:, 0, 0] = 1.0 / sub.gram_diag(j)
    nact = np.ones(r, dtype=np.int64)
    isact = np.zeros((r, d), dtype=fdt)  # +inf on active atoms, 0 elsewhere
    isact[rr, j] = np.inf
    last_drop = np.full(r, -1, dtype=np.int64)
    live = np.ones(r, dtype=bool)

    def dense(values, dtype):
        return _scatter(slots, values, d, dtype)

    shared = isinstance(op, _SharedGram)

    def finish(sel):
        """Exact coefficients of finished rows on their active sets, stored in ``out``.

        On the active set ``a_A = G_AA^{-1} (b_A - lam s_A)``; the bordered inverse is exact
        for a shared Gram matrix, and refined once with exact products for per-row masks.
        """
        idx = np.flatnonzero(sel)
        sl = slots[idx]
        Bi = B[rows[idx]]
        on = sl >= 0
        rhs = np.where(on, np.take_along_axis(Bi, np.maximum(sl, 0), axis=1), 0.0)
        rhs -= lamt[idx, None] * sgn[idx]
        Gi = Ginv[idx]
        cf = np.matmul(Gi, rhs[:, :, None])[:, :, 0]
        if not shared:
            W = _scatter(sl, cf, d)
            cc = Bi - sub.subset(idx).apply(W, exact=True)
            cs = np.take_along_axis(cc, np.maximum(sl, 0), axis=1)
            res = np.where(on, cs - lamt[idx, None] * sgn[idx], 0.0)
            cf += np.matmul(Gi, res[:, :, None])[:, :, 0]
        coef[idx] = cf
        out[rows[idx]] = _scatter(sl, cf, d)

    tiny = np.asarray(1e-30, dtype=fdt)
    for step in range(max_steps):
        if not live.all():
            if not live.any():
                break
            if (~live).sum() > 0.1 * r:  # compact
                keep = np.flatnonzero(live)
                rows, c, lamc, lamt = rows[keep], c[keep], lamc[keep], lamt[keep]
                slots, sgn, coef, Ginv = slots[keep], sgn[keep], coef[keep], Ginv[keep]
                nact, isact, last_drop = nact[keep], isact[keep], last_drop[keep]
                sub = sub.subset(keep)
                r = rows.size
                rr = np.arange(r)
                live = np.ones(r, dtype=bool)
        if not exact and step % resync == resync - 1:
            c = (B[rows] - sub.apply(dense(coef, np.float64), exact=True)).astype(fdt)
        u = np.matmul(Ginv, sgn[:, :, None])[:, :, 0]
        u[~live] = 0.0
        e = sub.apply(dense(u, fdt), exact=exact).astype(fdt, copy=False)
        lam_col = lamc.astype(fdt)[:, None]
        # entering step: (lam -+ c) / (1 -+ e), numerators clamped at 0, only positive dens
        num = lam_col - c
        np.maximum(num, 0, out=num)
        den = 1 - e
        np.maximum(den, tiny, out=den)
        g_in = num / den
        np.add(lam_col, c, out=num)
        np.maximum(num, 0, out=num)
        np.add(1, e, out=den)
        np.maximum(den, tiny, out=den)
        np.divide(num, den, out=num)
        np.minimum(g_in, num, out=g_in)
        g_in += isact
        has_ld = last_drop >= 0
        g_in[rr[has_ld], last_drop[has_ld]] = np.inf
        j_in = np.argmin(g_in, axis=1)
        gam_in = g_in[rr, j_in].astype(np.float64)
        # leaving step
        with np.errstate(divide="ignore", invalid="ignore"):
            gd = -coef / u
        gd[~((slots >= 0) & (gd > 0))] = np.inf
        q_out = np.argmin(gd, axis=1)
        gam_out = gd[rr, q_out]
        gam_end = lamc - lamt
        gam = np.minimum(np.minimum(gam_in, gam_out), gam_end)
        gam[~live] = 0.0
        coef += gam[:, None] * u
        c -= gam.astype(fdt)[:, None] * e
        lamc -= gam
        ends = live & (gam_end <= np.minimum(gam_in, gam_out))
        drops = live & ~ends & (gam_out < gam_in)
        adds = live & ~ends & ~drops
        last_drop[:] = -1
        if ends.any():
            lamc[ends] = lamt[ends]
            finish(ends)
            live &= ~ends
        if drops.any():
            di = np.flatnonzero(drops)
            q = q_out[di]
            jd = slots[di, q]
            isact[di, jd] = 0.0
            last_drop[di] = jd
            coef[di, q] = 0.0
            sgn[di, q] = 0.0
            slots[di, q] = -1
            nact[di] -= 1
            G_sub = Ginv[di]
            _border_drop(G_sub, q)
            Ginv[di] = G_sub
        if adds.any():
            ai = np.flatnonzero(adds)
            if nact[ai].max() >= k:
                k_new = k + 8
                (Ginv,), (slots, sgn, coef) = _grow(
                    [Ginv], [(slots, -1), (sgn, 0.0), (coef, 0.0)], k_new
                )
                k = k_new
            slot = np.argmax(slots[ai] < 0, axis=1)
            jn = j_in[ai]
            col = sub.subset(ai).columns(jn)  # (na, d) float64
            g = np.zeros((r, k))
            ga = np.take_along_axis(col, np.maximum(slots[ai], 0), axis=1)
            ga[slots[ai] < 0] = 0.0
            g[ai] = ga
            v = np.matmul(Ginv, g[:, :, None])[:, :, 0]
            diag = col[np.arange(ai.size), jn]
            sigma = np.ones(r)
            sigma[ai] = diag - np.einsum("rk,rk->r", ga, v[ai])
            bad = np.zeros(r, dtype=bool)
            bad[ai] = sigma[ai] <= 1e-10 * np.maximum(diag, _TINY)
            sigma[bad] = 1.0
            v[bad] = 0.0
            Ginv += v[:, :, None] * (v / sigma[:, None])[:, None, :]
            # an atom in the span of the active ones (e.g. a repeated atom) cannot join: it
            # stays at 0 on the boundary, excluded for this row (as LARS drops it for good)
            isact[ai, jn] = np.inf
            good = ~bad[ai]
            ai, slot, jn = ai[good], slot[good], jn[good]
            vs = -v[ai] / sigma[ai, None]
            Ginv[ai, slot, :] = vs
            Ginv[ai, :, slot] = vs
            Ginv[ai, slot, slot] = 1.0 / sigma[ai]
            slots[ai, slot] = jn
            sgn[ai, slot] = np.sign(c[ai, jn])
            coef[ai, slot] = 0.0
            nact[ai] += 1
    else:
        ok[rows[live]] = False
    return out, ok


def lasso_objective(X, D, A, lam, mask=None):
    """Per-row lasso objective ``0.5 ||m (x - D^T a)||^2 + lam (||m||_0 / p) ||a||_1``.

    Parameters
    ----------
    X : ndarray of shape (n, p)
    D : ndarray of shape (d, p)
    A : ndarray of shape (n, d)
    lam : float
    mask : ndarray of shape (n, p), bool, optional

    Returns
    -------
    ndarray of shape (n,), float64
    """
    X = np.asarray(X, dtype=np.float64)
    R = X - np.asarray(A, dtype=np.float64) @ np.asarray(D, dtype=np.float64)
    scale = 1.0
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        R = R * mask
        scale = mask.sum(axis=1) / X.shape[1]
    return 0.5 * np.einsum("ij,ij->i", R, R) + lam * scale * np.abs(A).sum(axis=1)


def _kkt_ok(B, A, op, lam, rtol=1e-9):
    """Lasso optimality on rows: |c_j| <= lam off the support, c_j = lam sign(a_j) on it."""
    C = B - op.apply(A, exact=True)
    lam_col = lam[:, None]
    on = A != 0
    atol = rtol * np.maximum(lam_col, 1.0)
    off_ok = np.where(on, True, np.abs(C) <= lam_col + atol)
    on_ok = np.where(on, np.abs(C - lam_col * np.sign(A)) <= atol, True)
    return off_ok.all(axis=1) & on_ok.all(axis=1)


def _group_by_mask(M, min_group):
    """Split rows into groups sharing one mask (size >= min_group) and the rest."""
    packed = np.packbits(M, axis=1)
    _, inverse, counts = np.unique(packed, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    groups = []
    rest = np.zeros(M.shape[0], dtype=bool)
    order = np.argsort(inverse, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    for g, cnt in enumerate(counts):
        rows = order[bounds[g] : bounds[g + 1]]
        if cnt >= min_group:
            groups.append(rows)
        else:
            rest[rows] = True
    return groups, np.flatnonzero(rest)


def _n_workers(n_jobs):
    if n_jobs is None:
        return 1
    n_jobs = int(n_jobs)
    if n_jobs < 0:
        return max(1, (os.cpu_count() or 1) + 1 + n_jobs)
    if n_jobs == 0:
        raise ValueError("n_jobs == 0 is not meaningful; use None, a positive number or -1")
    return n_jobs


def _solve_groups(X, D, mask, chunk_size, min_group, solver, n_jobs=None):
    """Run ``solver(rows, op)`` over chunks of rows sharing a Gram operator.

    Rows sharing one mask (at least ``min_group`` of them) get that mask's Gram matrix; the rest
    get per-row masked products. With ``n_jobs > 1`` chunks run in threads (numpy releases the
    GIL) with single-threaded BLAS in each.
    """
    n, _ = X.shape
    d = D.shape[0]
    out = np.zeros((n, d), dtype=np.float64)
    D64 = np.asarray(D, dtype=np.float64)
    if mask is None:
        groups, rest = [np.arange(n)], np.zeros(0, dtype=np.int64)
        ops = [_SharedGram(D64 @ D64.T)]
    else:
        groups, rest = _group_by_mask(mask, min_group)
        ops = []
        for rows in groups:
            m = mask[rows[0]].astype(np.float64)
            ops.append(_SharedGram((D64 * m) @ D64.T))
    tasks = []
    for rows, op in zip(groups, ops, strict=True):
        for sl in _chunks(rows.size, chunk_size):
            tasks.append((rows[sl], op))
    if rest.size:
        mop = _MaskedGram(D64, mask)
        for sl in _chunks(rest.size, chunk_size):
            tasks.append((rest[sl], mop.subset(rest[sl])))

    def run(task):
        idx, op = task
        out[idx] = solver(idx, op)

    workers = min(_n_workers(n_jobs), max(len(tasks), 1))
    with threadpool_limits(limits=1):  # small products: threaded BLAS only adds overhead
        if workers == 1:
            for task in tasks:
                run(task)
        else:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(run, tasks))
    return out


def lasso(
    X, D, lam, mask=None, *, n_jobs=None, chunk_size=1024, min_group=256, dtype=np.float32
):
    """Lasso codes of every row of ``X`` on the atoms (rows) of ``D``.

    Solves ``min_a 0.5 ||x - D^T a||^2 + lam ||a||_1`` per row, or with a mask
    ``min_a 0.5 ||m * (x - D^T a)||^2 + lam (||m||_0 / p) ||a||_1`` (the reference
    implementation's masked lasso). Exact up to floating point (homotopy; see the module
    docstring); the same problem as ``sklearn.decomposition.sparse_encode(X, D,
    algorithm="lasso_lars", alpha=lam)``.

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
        Atoms as rows (need not be unit norm).
    lam : float
        Penalty, >= 0.
    mask : array-like of shape (n, p), bool, optional
        True where an entry of ``X`` is valid.
    n_jobs : int, optional
        Worker threads over chunks (None: one, with the BLAS threads as configured; -1: all
        cores).
    chunk_size : int
        Rows solved together (bounds memory; small chunks stay in cache).
    min_group : int
        Rows sharing one mask are solved with that mask's Gram matrix when at least this many.
    dtype : numpy dtype
        Output dtype (the solve itself runs in float64 / float32 as described above).

    Returns
    -------
    A : ndarray of shape (n, d)
    """
    X, D, mask = _check_xd(X, D, mask)
    if not np.isfinite(lam) or lam < 0:
        raise ValueError(f"lam must be a finite number >= 0, got {lam}")
    p = X.shape[1]
    X64 = np.asarray(X, dtype=np.float64)
    D64 = np.asarray(D, dtype=np.float64)
    if mask is not None:
        Xm = X64 * mask
        lam_rows = lam * mask.sum(axis=1) / p
    else:
        Xm = X64
        lam_rows = np.full(X.shape[0], float(lam))

    def solver(idx, op):
        B = Xm[idx] @ D64.T
        A, ok = _lasso_homotopy(B, lam_rows[idx], op)
        ok &= _kkt_ok(B, A, op, lam_rows[idx])
        if not np.all(ok):  # rare: float32 path decisions near a tie; redo in float64
            bad = np.flatnonzero(~ok)
            A2, ok2 = _lasso_homotopy(B[bad], lam_rows[idx][bad], op.subset(bad), exact=True)
            ok2 &= _kkt_ok(B[bad], A2, op.subset(bad), lam_rows[idx][bad])
            A[bad] = A2
            if not np.all(ok2):  # degenerate (e.g. repeated atoms): scikit-learn per row
                worst = idx[bad[~ok2]]
                A[bad[~ok2]] = lasso_rowwise(
                    X64[worst], D64, lam, None if mask is None else mask[worst])
        return A

    return _solve_groups(X64, D64, mask, chunk_size, min_group, solver, n_jobs).astype(dtype)


def lasso_rowwise(X, D, lam, mask=None):
    """Reference per-row solver: scikit-learn's LARS on each (masked) sub-problem.

    Slow; used as the fallback for degenerate rows and as the benchmark's per-sample loop.

    Parameters
    ----------
    X : ndarray of shape (n, p)
    D : ndarray of shape (d, p)
    lam : float
    mask : ndarray of shape (n, p), bool, optional

    Returns
    -------
    ndarray of shape (n, d), float64
    """
    import warnings

    from sklearn.decomposition import sparse_encode
    from sklearn.exceptions import ConvergenceWarning

    X = np.asarray(X, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    out = np.zeros((X.shape[0], D.shape[0]))
    p = X.shape[1]
    for i in range(X.shape[0]):
        m = np.ones(p, dtype=bool) if mask is None else np.asarray(mask[i], dtype=bool)
        if not m.any():
            continue
        alpha = lam * m.sum() / p
        with warnings.catch_warnings():  # LARS warns about the degenerate rows sent here
            warnings.simplefilter("ignore", ConvergenceWarning)
            out[i] = sparse_encode(X[i : i + 1, m], D[:, m], algorithm="lasso_lars",
                                   alpha=alpha)[0]
    return out


def omp_rowwise(X, D, n_nonzero, mask=None):
    """Reference per-row OMP: scikit-learn's ``orthogonal_mp_gram`` on each masked sub-problem.

    Parameters
    ----------
    X : ndarray of shape (n, p)
    D : ndarray of shape (d, p)
    n_nonzero : int
    mask : ndarray of shape (n, p), bool, optional

    Returns
    -------
    ndarray of shape (n, d), float64
    """
    import warnings

    from sklearn.linear_model import orthogonal_mp_gram

    X = np.asarray(X, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    out = np.zeros((X.shape[0], D.shape[0]))
    p = X.shape[1]
    for i in range(X.shape[0]):
        m = np.ones(p, dtype=bool) if mask is None else np.asarray(mask[i], dtype=bool)
        Dm = D[:, m]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # "ended prematurely"
            out[i] = orthogonal_mp_gram(Dm @ Dm.T, Dm @ X[i, m], n_nonzero_coefs=n_nonzero)
    return out


# --------------------------------------------------------------------------------------------
# OMP: batched, one atom per step for every row


def _omp_batch(B, n_nonzero, op, refine):
    """OMP on Gram operators: ``B`` (r, d) correlations, returns (r, d) float64 codes."""
    r, d = B.shape
    out = np.zeros((r, d))
    if r == 0 or n_nonzero == 0:
        return out
    rr = np.arange(r)
    if n_nonzero == 1:
        j = np.argmax(np.abs(B), axis=1)
        diag = op.gram_diag(j)
        good = (B[rr, j] ** 2 > _TINY) & (diag > _TINY)
        out[rr[good], j[good]] = B[rr[good], j[good]] / diag[good]
        return out
    L = min(int(n_nonzero), d)
    slots = np.full((r, L), -1, dtype=np.int64)
    Ginv = np.zeros((r, L, L))
    cols = np.zeros((r, L, d), dtype=np.float32)
    coef = np.zeros((r, L))
    live = np.ones(r, dtype=bool)
    B32 = B.astype(np.float32)
    c = B32.copy()
    rc = rr[:, None]
    for t in range(L):
        cabs = np.abs(c)
        if t:
            cabs[rc, slots[:, :t]] = 0.0
        j = np.argmax(cabs, axis=1)
        live &= cabs[rr, j].astype(np.float64) ** 2 > _TINY
        if not live.any():
            break
        col = op.columns32(j)  # (r, d) float32
        diag = op.gram_diag(j)
        if t:
            g = op.entries(j, np.maximum(slots[:, :t], 0), col)
            Gi = Ginv[:, :t, :t]
            v = np.matmul(Gi, g[:, :, None])[:, :, 0]
            sigma = diag - np.einsum("rk,rk->r", g, v)
        else:
            sigma = diag
        ok = live & (sigma > 1e-10 * np.maximum(diag, _TINY)) & (sigma > _TINY)
        live = ok  # a dependent atom stops the row (as scikit-learn)
        sg = np.where(ok, sigma, 1.0)
        if t:
            v[~ok] = 0.0
            vs = v / sg[:, None]
            Gi += v[:, :, None] * vs[:, None, :]
            Ginv[:, t, :t] = -vs
            Ginv[:, :t, t] = -vs
        Ginv[:, t, t] = np.where(ok, 1.0 / sg, 0.0)
        slots[:, t] = np.where(ok, j, -1)
        cols[:, t] = col
        BA = np.where(slots[:, : t + 1] >= 0, B[rc, np.maximum(slots[:, : t + 1], 0)], 0.0)
        coef[:, : t + 1] = np.matmul(Ginv[:, : t + 1, : t + 1], BA[:, :, None])[:, :, 0]
        if t + 1 < L:
            fit = np.einsum("rk,rkd->rd", coef[:, : t + 1].astype(np.float32), cols[:, : t + 1])
            np.subtract(B32, fit, out=c)
    if refine:
        for _ in range(2):
            W = _scatter(slots, coef, d)
            res = B - op.apply(W, exact=True)
            resA = np.where(slots >= 0, res[rc, np.maximum(slots, 0)], 0.0)
            coef += np.matmul(Ginv, resA[:, :, None])[:, :, 0]
    return _scatter(slots, coef, d)


def omp(X, D, n_nonzero, mask=None, *, n_jobs=None, chunk_size=1024, min_group=256,
        dtype=np.float32):
    """Orthogonal matching pursuit codes with ``n_nonzero`` atoms per row.

    The selection rule and the least-squares coefficients are those of scikit-learn's
    ``sparse_encode(algorithm="omp", n_nonzero_coefs=n_nonzero)``: at each step the atom with
    the largest absolute correlation with the residual joins, and the coefficients are the
    least-squares fit on the selected atoms. A row stops early when its residual correlation
    vanishes or the next atom is linearly dependent on the selected ones.

    With a mask, the residual and the least squares are on the valid entries only (exact
    masked least squares; see the module docstring for why this and not the reference
    library's unit-norm assumption).

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
    n_nonzero : int
        Number of atoms per row, >= 1.
    mask : array-like of shape (n, p), bool, optional
    n_jobs, chunk_size, min_group, dtype
        As in :func:`lasso`.

    Returns
    -------
    A : ndarray of shape (n, d)
    """
    X, D, mask = _check_xd(X, D, mask)
    if int(n_nonzero) != n_nonzero or n_nonzero < 1:
        raise ValueError(f"n_nonzero must be a positive integer, got {n_nonzero}")
    X64 = np.asarray(X, dtype=np.float64)
    D64 = np.asarray(D, dtype=np.float64)
    D64t = np.ascontiguousarray(D64.T)
    Xm = X64 * mask if mask is not None else X64

    def solver(idx, op):
        B = Xm[idx] @ D64t
        return _omp_batch(B, int(n_nonzero), op, refine=isinstance(op, _MaskedGram))

    return _solve_groups(X64, D64, mask, chunk_size, min_group, solver, n_jobs).astype(dtype)


# --------------------------------------------------------------------------------------------
# dense encoders


def _dense_chunks(X, n_out, fn, chunk_size, dtype):
    out = np.empty((X.shape[0], n_out), dtype=dtype)
    for sl in _chunks(X.shape[0], chunk_size):
        out[sl] = fn(X[sl])
    return out


def soft_threshold(X, D, lam, *, chunk_size=4096, dtype=np.float32):
    """Soft-threshold codes ``sign(D x) max(|D x| - lam, 0)``.

    Same as ``sparse_encode(X, D, algorithm="threshold", alpha=lam)``; ``lam = 0`` gives the
    plain projections ``D x``.

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
    lam : float, >= 0
    chunk_size : int
    dtype : numpy dtype
        Computation and output dtype (float32 by default).

    Returns
    -------
    A : ndarray of shape (n, d)
    """
    X, D, _ = _check_xd(X, D)
    if not np.isfinite(lam) or lam < 0:
        raise ValueError(f"lam must be a finite number >= 0, got {lam}")
    Dt = np.ascontiguousarray(D.T, dtype=dtype)
    lam = dtype(lam) if isinstance(dtype, type) else np.dtype(dtype).type(lam)

    def fn(x):
        b = np.asarray(x, dtype=Dt.dtype) @ Dt
        if lam == 0:
            return b
        t = np.abs(b)
        t -= lam
        np.maximum(t, 0, out=t)
        return np.copysign(t, b, out=t)

    return _dense_chunks(X, D.shape[0], fn, chunk_size, Dt.dtype)


def kmeans_triangle(X, centroids, *, chunk_size=4096, dtype=np.float32):
    """k-means "triangle" codes ``max(mean_k(z) - z_k, 0)``, ``z_k = ||x - c_k||``.

    Coates, Lee and Ng (2011); the natural encoder of NKM, on the un-normalised centroids.

    Parameters
    ----------
    X : array-like of shape (n, p)
    centroids : array-like of shape (k, p)
    chunk_size : int
    dtype : numpy dtype

    Returns
    -------
    A : ndarray of shape (n, k)
    """
    X, C, _ = _check_xd(X, centroids)
    Ct = np.ascontiguousarray(C.T, dtype=dtype)
    cn = np.einsum("kp,kp->k", C, C).astype(Ct.dtype)

    def fn(x):
        x = np.asarray(x, dtype=Ct.dtype)
        z = x @ Ct
        z *= -2
        z += cn
        z += np.einsum("np,np->n", x, x)[:, None]
        np.maximum(z, 0, out=z)
        np.sqrt(z, out=z)
        mu = z.mean(axis=1, keepdims=True)
        np.subtract(mu, z, out=z)
        return np.maximum(z, 0, out=z)

    return _dense_chunks(X, C.shape[0], fn, chunk_size, Ct.dtype)


def polarity_split(A):
    """Polarity splitting ``[max(A, 0), max(-A, 0)]``.

    Parameters
    ----------
    A : array-like of shape (n, d)

    Returns
    -------
    ndarray of shape (n, 2 d), same dtype
    """
    A = np.asarray(A)
    if A.ndim != 2:
        raise ValueError(f"codes must be 2-D, got shape {A.shape}")
    out = np.empty((A.shape[0], 2 * A.shape[1]), dtype=A.dtype)
    np.maximum(A, 0, out=out[:, : A.shape[1]])
    np.negative(A, out=out[:, A.shape[1] :])
    np.maximum(out[:, A.shape[1] :], 0, out=out[:, A.shape[1] :])
    return out


def encode(X, D, method, *, lam=1.0, n_nonzero=5, mask=None, polarity=True, n_jobs=None,
           dtype=np.float32):
    """Encode with one of :data:`ENCODER_METHODS`, then optionally polarity-split.

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
        Atoms (for ``"triangle"``: the centroids).
    method : {"lasso", "omp", "threshold", "triangle"}
    lam : float
        Lasso penalty or threshold.
    n_nonzero : int
        OMP atoms per row.
    mask : array-like of shape (n, p), bool, optional
        Masked lasso / OMP only.
    polarity : bool
        Return ``[max(A, 0), max(-A, 0)]`` (2 d columns).
    n_jobs : int, optional
    dtype : numpy dtype
        Output dtype (float32 by default).

    Returns
    -------
    ndarray of shape (n, d) or (n, 2 d)
    """
    if method == "lasso":
        A = lasso(X, D, lam, mask=mask, n_jobs=n_jobs, dtype=dtype)
    elif method == "omp":
        A = omp(X, D, n_nonzero, mask=mask, n_jobs=n_jobs, dtype=dtype)
    elif method in ("threshold", "triangle"):
        if mask is not None:
            raise ValueError(f"method {method!r} takes no mask (masked entries are already 0)")
        if method == "threshold":
            A = soft_threshold(X, D, lam, dtype=dtype)
        else:
            A = kmeans_triangle(X, D, dtype=dtype)
    else:
        raise ValueError(f"unknown encoder {method!r}; expected one of {ENCODER_METHODS}")
    return polarity_split(A) if polarity else A


_NATURAL = {
    "SC": dict(method="lasso", masked=False, polarity=True),
    "OMP": dict(method="omp", masked=False, polarity=True),
    "GSVQ": dict(method="omp", masked=True, polarity=True, n_nonzero=1),
    "RP": dict(method="threshold", masked=False, polarity=True, lam=0.0),
    "R": dict(method="threshold", masked=False, polarity=True, lam=0.0),
    "NKM": dict(method="triangle", masked=False, polarity=False),
}


def natural_encoder(learner, dictionary=None, *, lam=None, n_nonzero=None, centroids=None,
                    n_jobs=None):
    """The encoder each dictionary was learned with (the reference implementation's choice).

    SC: lasso with the dictionary's lambda; OMP: OMP with its ``L``; GSVQ: masked OMP with
    ``L = 1``; RP and R: soft threshold with ``lambda = 0``; NKM: the triangle encoder on the
    un-normalised centroids, without polarity splitting. All others split polarity.

    Parameters
    ----------
    learner : str or fitted DictionaryLearner
        A method name in ``{"SC", "OMP", "GSVQ", "NKM", "RP", "R"}``, or a fitted learner
        (its ``method``, ``components_``, ``centroids_``, ``lam`` and ``n_nonzero`` are used).
    dictionary : ndarray of shape (d, p), optional
        Needed with a method name (NKM: give ``centroids`` instead).
    lam, n_nonzero : optional
        The dictionary's lambda (SC) or ``L`` (OMP).
    centroids : ndarray of shape (d, p), optional
        NKM's un-normalised centroids.
    n_jobs : int, optional

    Returns
    -------
    SparseEncoder
        Fitted (holds the dictionary); GSVQ's encoder has ``masked=True`` and wants a mask at
        ``transform``.
    """
    if not isinstance(learner, str):
        check_is_fitted(learner, "components_")
        method = learner.method
        dictionary = learner.components_
        centroids = getattr(learner, "centroids_", None)
        lam = learner.lam if lam is None else lam
        n_nonzero = learner.n_nonzero if n_nonzero is None else n_nonzero
    else:
        method = learner
    if method not in _NATURAL:
        raise ValueError(f"unknown dictionary method {method!r}; expected one of "
                         f"{tuple(_NATURAL)}")
    spec = dict(_NATURAL[method])
    if method == "NKM":
        atoms = centroids if centroids is not None else dictionary
    else:
        atoms = dictionary
    if atoms is None:
        raise ValueError(f"natural_encoder({method!r}) needs the dictionary"
                         + (" (the un-normalised centroids)" if method == "NKM" else ""))
    if method == "SC":
        if lam is None:
            raise ValueError("natural_encoder('SC') needs the dictionary's lam")
        spec["lam"] = lam
    if method == "OMP":
        if n_nonzero is None:
            raise ValueError("natural_encoder('OMP') needs the dictionary's n_nonzero")
        spec["n_nonzero"] = n_nonzero
    enc = SparseEncoder(dictionary=np.asarray(atoms), n_jobs=n_jobs, **spec)
    return enc.fit(np.zeros((1, np.asarray(atoms).shape[1])))


def natural_encode(X, M, learner, D, *, centroids=None, param=None, polarity=True,
                   n_jobs=None):
    """Codes of the natural encoder of ``learner`` (function form of :func:`natural_encoder`).

    Parameters
    ----------
    X : array-like of shape (n, p)
    M : array-like of shape (n, p), bool, or None
        Validity; used by GSVQ's masked OMP only (None: all valid).
    learner : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}
    D : array-like of shape (d, p)
        The dictionary.
    centroids : array-like of shape (d, p), optional
        NKM's un-normalised centroids (the normalised ``D`` is used when absent).
    param : float or int, optional
        SC's lambda (default 1.0) or OMP's L (default 10): the dictionary's own parameter.
    polarity : bool
        Split the signed codes (SC, OMP, GSVQ, RP, R). NKM's triangle codes are non-negative
        and never split, as in the reference (d features instead of 2 d).
    n_jobs : int, optional

    Returns
    -------
    ndarray of shape (n, 2 d) or (n, d), float32
    """
    if learner not in _NATURAL:
        raise ValueError(f"unknown dictionary method {learner!r}; expected one of "
                         f"{tuple(_NATURAL)}")
    spec = dict(_NATURAL[learner])
    if learner == "SC":
        spec["lam"] = 1.0 if param is None else param
    elif learner == "OMP":
        spec["n_nonzero"] = 10 if param is None else int(param)
    atoms = centroids if (learner == "NKM" and centroids is not None) else D
    if spec.pop("masked"):
        mask = np.ones(np.shape(X), dtype=bool) if M is None else M
    else:
        mask = None
    spec["polarity"] = bool(polarity) and spec["polarity"]
    return encode(X, np.asarray(atoms), spec.pop("method"), mask=mask, n_jobs=n_jobs, **spec)


class SparseEncoder(TransformerMixin, BaseEstimator):
    """Encode patches on a dictionary (lasso, OMP, soft threshold or triangle).

    Parameters
    ----------
    method : {"lasso", "omp", "threshold", "triangle"}
    dictionary : ndarray of shape (d, p), optional
        Atoms as rows (for ``"triangle"``: centroids). When None, ``fit`` draws ``n_atoms``
        random training rows and normalises them (the RP dictionary), so the estimator is
        usable on its own.
    lam : float
        Lasso penalty / threshold.
    n_nonzero : int
        OMP atoms per row.
    masked : bool
        Masked lasso / OMP: ``transform(X, mask=...)`` uses the mask (all valid when omitted).
    polarity : bool
        Output ``[max(A, 0), max(-A, 0)]``.
    n_atoms : int
        Dictionary size when ``dictionary`` is None.
    random_state : int, Generator, RandomState or None
        For the random dictionary only.
    n_jobs : int, optional

    Attributes
    ----------
    dictionary_ : ndarray of shape (d, p)
    n_features_in_ : int
    """

    def __init__(self, method="lasso", dictionary=None, *, lam=1.0, n_nonzero=5, masked=False,
                 polarity=True, n_atoms=300, random_state=None, n_jobs=None):
        self.method = method
        self.dictionary = dictionary
        self.lam = lam
        self.n_nonzero = n_nonzero
        self.masked = masked
        self.polarity = polarity
        self.n_atoms = n_atoms
        self.random_state = random_state
        self.n_jobs = n_jobs

    def fit(self, X, y=None):
        """Validate the parameters and store the dictionary.

        Parameters
        ----------
        X : array-like of shape (n, p)
        y : ignored

        Returns
        -------
        self
        """
        X = validate_data(self, X, dtype=[np.float64, np.float32])
        if self.method not in ENCODER_METHODS:
            raise ValueError(f"unknown encoder {self.method!r}; expected one of "
                             f"{ENCODER_METHODS}")
        if self.dictionary is None:
            from sklearn.utils import check_random_state

            rng = check_random_state(self.random_state)
            replace = X.shape[0] < self.n_atoms
            idx = rng.choice(X.shape[0], size=self.n_atoms, replace=replace)
            D = np.asarray(X[idx], dtype=np.float64)
            norms = np.linalg.norm(D, axis=1)
            if replace or np.any(norms == 0):  # repeated / zero rows: keep the atoms distinct
                D = D + 1e-6 * max(np.abs(D).max(), 1.0) * rng.standard_normal(D.shape)
            D /= np.linalg.norm(D, axis=1, keepdims=True)
        else:
            D = check_array(self.dictionary, dtype=np.float64)
            if D.shape[1] != X.shape[1]:
                raise ValueError(f"the dictionary atoms have {D.shape[1]} features but X has "
                                 f"{X.shape[1]}")
        self.dictionary_ = D
        return self

    def transform(self, X, mask=None):
        """Codes of ``X``.

        Parameters
        ----------
        X : array-like of shape (n, p)
        mask : array-like of shape (n, p), bool, optional
            Only with ``masked=True``.

        Returns
        -------
        ndarray of shape (n, d) or (n, 2 d), the dtype of ``X`` (float32 or float64)
        """
        check_is_fitted(self, "dictionary_")
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        if mask is not None and not self.masked:
            raise ValueError("a mask was given but this encoder has masked=False")
        if self.masked and mask is None:
            mask = np.ones(X.shape, dtype=bool)
        return encode(X, self.dictionary_, self.method, lam=self.lam, n_nonzero=self.n_nonzero,
                      mask=mask if self.masked else None, polarity=self.polarity,
                      n_jobs=self.n_jobs, dtype=X.dtype)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = False
        return tags


ESTIMATORS = [
    SparseEncoder(method="lasso", lam=0.1, n_atoms=6, random_state=0),
    SparseEncoder(method="lasso", lam=0.1, n_atoms=6, masked=True, random_state=0),
    SparseEncoder(method="omp", n_nonzero=2, n_atoms=6, random_state=0),
    SparseEncoder(method="omp", n_nonzero=1, n_atoms=6, masked=True, random_state=0),
    SparseEncoder(method="threshold", lam=0.1, n_atoms=6, random_state=0),
    SparseEncoder(method="triangle", n_atoms=6, polarity=False, random_state=0),
]
"""Small instances of every encoder configuration, for ``parametrize_with_checks``."""
