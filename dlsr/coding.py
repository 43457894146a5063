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
The lasso is solved exactly by a homotopy (LARS-lasso) per patch, compiled with numba
(:mod:`dlsr._homotopy`): each step costs ``O(k d)`` (the Gram columns of the ``k`` active
atoms) plus ``O(k^2)`` for the bordered / downdated inverse of the active Gram block, all in
float64, and the path records the solution at every requested penalty as it crosses it
(:func:`lasso_path`: a grid of penalties costs about as much as its smallest member). Each
recorded solution is recomputed as ``a_A = G_AA^{-1} (b_A - lam s_A)`` with one refinement step
and checked against the lasso optimality (KKT) conditions; a row that fails (a degenerate tie)
is solved again by scikit-learn's LARS. An atom that is linearly dependent on the active ones
(e.g. a repeated atom) is kept out for that patch, as LARS does; which of two identical atoms
enters (and so which column of the codes is used) depends on the rounding of the products,
hence on the BLAS kernels (see :func:`omp`); the objective and the reconstruction do not.
Masked problems have one Gram matrix per mask: rows sharing a mask (fully valid patches,
padding patterns; at least ``min_group`` of them) read that mask's Gram matrix; for the other
rows the masked Gram column of an entering atom is computed when it enters, from the unmasked
Gram matrix minus the masked entries' contribution (or the sum over the valid entries when
fewer).

OMP is compiled per patch too (:func:`dlsr._homotopy.omp_path_rows`): each step selects the
atom of largest absolute residual correlation, borders the inverse of the selected atoms' Gram
block, solves the least squares on them and updates the correlations in ``O(k d)``, all in
float64 with the same Gram columns as the lasso (so masked least squares are exact). The greedy
selection does not depend on the final number of atoms, so one run gives every smaller ``L`` of
a grid (:func:`omp_path`). (It replaced a version vectorised over patches with numpy, one step
for all rows at a time: on 23,104 real patches, d = 300, L up to 15, 1.7x faster unmasked and
2.4x masked, the same codes.)

Chunks of rows (``chunk_size``, small enough to stay in cache) run in ``n_jobs`` threads with
single-threaded BLAS (numpy and the compiled kernel release the GIL); the dense encoders split
their chunks over as many threads as BLAS is allowed to use.
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

from . import _threads

__all__ = [
    "lasso",
    "lasso_path",
    "omp",
    "omp_path",
    "soft_threshold",
    "kmeans_triangle",
    "polarity_split",
    "natural_encoder",
    "natural_encode",
    "natural_spec",
    "soft_threshold_path",
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

#: Rows sharing one mask get that mask's Gram matrix when at least this many. Forming it costs
#: ``d^2 p`` operations, about what twenty rows spend on per-row masked Gram columns over a
#: lasso path or an OMP run; on real patches (Jacquard crops, d = 300) 32 made masked OMP 30 %
#: and masked lasso 10 % faster than 256.
MIN_GROUP = 32


# --------------------------------------------------------------------------------------------
# validation helpers


def _check_xd(X, D, mask=None, name="X", check_finite_x=True):
    X = np.asarray(X)
    D = np.asarray(D)
    if X.ndim != 2 or D.ndim != 2:
        raise ValueError(f"{name} and D must be 2-D, got shapes {X.shape} and {D.shape}")
    if X.shape[1] != D.shape[1]:
        raise ValueError(
            f"{name} has {X.shape[1]} features per row but the dictionary atoms have "
            f"{D.shape[1]}"
        )
    from dlsr._dense import check_finite

    check_finite(D, "D")
    if check_finite_x:
        check_finite(X, name)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != X.shape:
            raise ValueError(f"mask must have the shape of {name} {X.shape}, got {mask.shape}")
        mask = mask.astype(bool, copy=False)
    return X, D, mask


def _check_base(base_mask, mask):
    """``base_mask`` as bool, checked to contain ``mask`` (None without either)."""
    if base_mask is None or mask is None:
        return None
    base = np.asarray(base_mask, dtype=bool)
    if base.shape != mask.shape:
        raise ValueError(f"base_mask must have the shape of the mask {mask.shape}, got "
                         f"{base.shape}")
    if np.any(mask & ~base):
        raise ValueError("base_mask must contain the mask: True wherever the mask is")
    return base


def _chunks(n, size):
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))


# --------------------------------------------------------------------------------------------
# Gram operators: how a batch of rows sees its (possibly masked) Gram matrix


class _SharedGram:
    """All rows share ``G = D_m D_m^T`` (unmasked, or one mask for the whole group)."""

    def __init__(self, G):
        self.G64 = np.ascontiguousarray(G, dtype=np.float64)

    def subset(self, rows):  # noqa: ARG002 - same operator for every row
        return self


class _MaskedGram:
    """Each row r has its own ``G_r = D diag(m_r) D^T``; never formed (the compiled solvers
    compute the masked Gram column of each atom they select).

    With ``G`` given (the Gram matrix of a base mask ``q`` the rows' masks lie in), ``M`` holds
    ``m_r | ~q``: a column is then ``G[:, j]`` minus the terms of the entries masked within
    ``q`` only; otherwise (``G`` None) ``M`` holds the masks and the solvers start from the
    unmasked Gram matrix.
    """

    def __init__(self, M, G=None):
        self.M = M
        self.G64 = G

    def subset(self, rows):
        return _MaskedGram(self.M[rows], self.G64)


# --------------------------------------------------------------------------------------------
# lasso: compiled homotopy (dlsr._homotopy) with snapshots at every requested penalty


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


def _group_by_mask(M, min_group):
    """Split rows into groups sharing one mask (size >= min_group) and the rest.

    Masks are packed to 64-bit words and sorted with one stable ``lexsort`` (about 10x
    ``np.unique(axis=0)``, which sorts a structured view); groups keep their rows in
    increasing order.
    """
    n = M.shape[0]
    if n == 0:
        return [], np.zeros(0, dtype=np.int64)
    packed = np.packbits(M, axis=1)
    width = -(-packed.shape[1] // 8) * 8
    if width != packed.shape[1]:
        packed = np.pad(packed, ((0, 0), (0, width - packed.shape[1])))
    words = np.ascontiguousarray(packed).view(np.uint64)  # (n, width / 8)
    order = np.lexsort(words.T[::-1])
    sw = words[order]
    starts = np.r_[0, np.flatnonzero(np.any(sw[1:] != sw[:-1], axis=1)) + 1, n]
    groups = []
    rest = np.zeros(n, dtype=bool)
    for a, b in zip(starts[:-1], starts[1:], strict=True):
        rows = order[a:b]
        if b - a >= min_group:
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


def _check_gram_cache(cache, D64):
    """``cache`` (a dict or None) ready for masked Gram matrices of ``D64``."""
    if cache is None:
        return None
    if not isinstance(cache, dict):
        raise TypeError(f"gram_cache must be a dict or None, got {type(cache).__name__}")
    D0 = cache.setdefault("dictionary", D64)
    if D0 is not D64 and (D0.shape != D64.shape or not np.array_equal(D0, D64)):
        raise ValueError("gram_cache holds Gram matrices of another dictionary")
    return cache


def _group_gram(D64, m, cache):
    """``D diag(m) D^T`` for one mask ``m`` (bool), from ``cache`` when it holds it."""
    key = None
    if cache is not None:
        key = np.packbits(m).tobytes()
        G = cache.get(key)
        if G is not None:
            return G
    G = (D64 * m.astype(np.float64)) @ D64.T
    if key is not None:
        cache[key] = G
    return G


def _base_groups(mask, base, rest, min_group):
    """Rows of ``rest`` grouped by their base mask (``base[r]``, containing ``mask[r]``):
    ``(groups, left)``, each group at least ``min_group`` rows whose masks leave at most half
    the entries of the row masked within the base (the compiled solvers then subtract those
    entries' terms from the base's Gram column; with more, they sum the valid ones, which only
    the plain masked rows, ``left``, can)."""
    if base is None or not rest.size:
        return [], rest
    holes = np.count_nonzero(base[rest] & ~mask[rest], axis=1)
    fit = holes * 2 <= mask.shape[1]
    groups, small = _group_by_mask(base[rest[fit]], min_group)
    left = np.sort(np.r_[rest[~fit], rest[fit][small]])
    return [rest[fit][g] for g in groups], left


def _solve_groups(X, D, mask, chunk_size, min_group, solver, n_jobs, n_paths, dtype,
                  gram_cache=None, base=None):
    """Run ``solver(rows, op, out)`` over chunks of rows sharing a Gram operator.

    Rows sharing one mask (at least ``min_group`` of them) get that mask's Gram matrix (kept in
    ``gram_cache`` when given, for the next masked solve on the same dictionary); the rest
    get per-row masked products. With ``base`` (a base mask per row containing its mask, e.g.
    its padding pattern), the rest sharing a base (``min_group`` of them) start their columns
    from the base's Gram matrix and subtract only the entries masked within it
    (:func:`_base_groups`). With ``n_jobs > 1`` chunks run in threads (numpy and the
    compiled kernels release the GIL) with single-threaded BLAS in each. ``solver`` writes the
    codes of its rows into ``out``, of shape ``(n_paths, n, d)``, zero-initialised and returned
    (the compiled kernels write there directly: per-chunk result arrays, their reordering and
    their scatter into ``out`` cost as much as OMP itself).
    """
    n, _ = X.shape
    d = D.shape[0]
    out = np.zeros((n_paths, n, d), dtype=dtype)
    D64 = np.asarray(D, dtype=np.float64)
    if mask is None:
        groups, rest = [np.arange(n)], np.zeros(0, dtype=np.int64)
        ops = [_SharedGram(D64 @ D64.T)]
    else:
        groups, rest = _group_by_mask(mask, min_group)
        cache = _check_gram_cache(gram_cache, D64)
        ops = [_SharedGram(_group_gram(D64, mask[rows[0]], cache)) for rows in groups]
    tasks = []
    for rows, op in zip(groups, ops, strict=True):
        for sl in _chunks(rows.size, chunk_size):
            tasks.append((rows[sl], op))
    if mask is not None:
        based, rest = _base_groups(mask, base, rest, min_group)
        for rows in based:
            G_base = _group_gram(D64, base[rows[0]], cache)
            bop = _MaskedGram((mask[rows] | ~base[rows]), G_base)
            for sl in _chunks(rows.size, chunk_size):
                tasks.append((rows[sl], bop.subset(sl)))
    if rest.size:
        mop = _MaskedGram(mask)
        for sl in _chunks(rest.size, chunk_size):
            tasks.append((rest[sl], mop.subset(rest[sl])))

    def run(task):
        idx, op = task
        solver(idx, op, out)

    workers = min(_n_workers(n_jobs), max(len(tasks), 1))
    with _threads.limit(1):  # small products: threaded BLAS only adds overhead
        if workers == 1:
            for task in tasks:
                run(task)
        else:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(run, tasks))
    return out


def _slots(where, n_levels):
    """First requested index of each distinct level, and a function copying it to the others.

    ``where[w]`` is the level of requested value ``w``; kernels write level ``t`` to output
    ``slots[t]`` and ``fill(out)`` copies it to the other outputs asking for the same level.
    """
    slots = np.full(n_levels, -1, dtype=np.int64)
    for w, t in enumerate(where):
        if slots[t] < 0:
            slots[t] = w
    dups = [(w, int(slots[t])) for w, t in enumerate(where) if slots[t] != w]

    def fill(out):
        for w, src in dups:
            out[w] = out[src]
        return out

    return slots, fill


def _correlations(X, D64, mask, given):
    """``(X * mask) @ D.T`` in float64 (``X @ D.T`` without a mask), or the caller's copy."""
    n, d = X.shape[0], D64.shape[0]
    if given is not None:
        B = np.ascontiguousarray(given, dtype=np.float64)
        if B.shape != (n, d):
            raise ValueError(f"correlations must have shape {(n, d)}, got {B.shape}")
        return B
    X64 = np.asarray(X, dtype=np.float64)
    return (X64 * mask if mask is not None else X64) @ D64.T


def _check_lams(lam, name="lam"):
    lams = np.atleast_1d(np.asarray(lam, dtype=np.float64))
    if lams.ndim != 1 or lams.size == 0:
        raise ValueError(f"{name} must be a number or a non-empty 1-D sequence, got {lam!r}")
    if not np.all(np.isfinite(lams)) or np.any(lams < 0):
        raise ValueError(f"{name} must be finite numbers >= 0, got {lam!r}")
    return lams


def lasso_path(
    X, D, lams, mask=None, *, n_jobs=None, chunk_size=1024, min_group=MIN_GROUP, dtype=np.float32,
    max_steps=None, correlations=None, gram_cache=None, base_mask=None,
):
    """Lasso codes of every row of ``X`` for several penalties, from one homotopy path.

    The homotopy (LARS-lasso) starts from ``a = 0`` at ``lam_max = max_j |d_j^T x|`` and follows
    the exact piecewise-linear path of solutions down to the smallest requested penalty; each
    requested penalty is recorded as the path crosses it. A grid of penalties therefore costs
    about as much as its smallest member. Every recorded solution is checked against the lasso
    optimality conditions; a row that fails (degenerate ties) is solved again per penalty by
    scikit-learn's LARS (:func:`lasso_rowwise`).

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
        Atoms as rows (need not be unit norm).
    lams : float or sequence of float
        Penalties, >= 0, in any order (duplicates allowed).
    mask : array-like of shape (n, p), bool, optional
        True where an entry of ``X`` is valid; the penalty of a row is scaled by
        ``||m||_0 / p`` (the reference implementation's masked lasso).
    n_jobs : int, optional
        Worker threads over chunks (None: one; -1: all cores).
    chunk_size : int
        Rows per task.
    min_group : int
        Rows sharing one mask are solved with that mask's Gram matrix when at least this many;
        the others compute the masked Gram column of each entering atom.
    dtype : numpy dtype
        Output dtype (the path is computed in float64).
    max_steps : int, optional
        Homotopy steps per row before it is handed to the fallback (default ``8 d``).
    correlations : ndarray of shape (n, d), float64, optional
        ``(X * mask) @ D.T`` (``X @ D.T`` without a mask), when the caller already has it:
        encoders sharing patches share this product (with masked entries of ``X`` already 0,
        the masked and unmasked products are the same array).
    gram_cache : dict, optional
        The Gram matrices of groups of rows sharing a mask, by mask, kept for the next masked
        call on the same dictionary: the masked lasso and the masked OMP of the same patches
        form the same ones (about 4 % of the two on a chunk of real patches). It refuses
        another dictionary; without a mask it is not used.
    base_mask : array-like of shape (n, p), bool, optional
        Per row, a mask containing ``mask`` (True wherever ``mask`` is), shared by many rows:
        a rectangle's padding pattern, of which the depth holes are a few more masked entries.
        Rows whose masks share no Gram matrix but share a base (``min_group`` of them) start
        each masked Gram column from the base's and subtract only the entries masked within
        it, instead of every masked entry from ``D D^T``: the same columns, summed in another
        order (last bits). Ignored without ``mask``.

    Returns
    -------
    A : ndarray of shape (len(lams), n, d)
        ``A[t]`` solves the problem with penalty ``lams[t]``.
    """
    from dlsr._homotopy import lasso_path_rows

    X, D, mask = _check_xd(X, D, mask)
    base = _check_base(base_mask, mask)
    lams = _check_lams(lams, "lams")
    n, p = X.shape
    d = D.shape[0]
    levels, where = np.unique(lams, return_inverse=True)
    levels = levels[::-1].copy()  # the path runs from large to small penalties
    where = levels.size - 1 - where.ravel()
    if max_steps is None:
        max_steps = 8 * d
    D64 = np.ascontiguousarray(D, dtype=np.float64)
    scale = mask.sum(axis=1) / p if mask is not None else np.ones(n)
    B_all = _correlations(X, D64, mask, correlations)
    Dt = np.ascontiguousarray(D64.T)
    G_full = D64 @ D64.T if mask is not None else None
    no_M = np.zeros((1, 1))

    slots, fill = _slots(where, levels.size)

    def solver(idx, op, out):
        B = B_all[idx]
        L = np.ascontiguousarray(scale[idx, None] * levels[None, :])
        ok = np.ones(idx.size, dtype=bool)
        if isinstance(op, _SharedGram):
            lasso_path_rows(B, L, op.G64, Dt, no_M, False, out, idx, slots, ok, max_steps, 1e-9)
        else:
            M = np.ascontiguousarray(op.M, dtype=np.float64)
            G = G_full if op.G64 is None else op.G64
            lasso_path_rows(B, L, G, Dt, M, True, out, idx, slots, ok, max_steps, 1e-9)
        if not ok.all():  # rare degenerate rows: scikit-learn's LARS per row and penalty
            rows = idx[~ok]
            for t, lam_t in enumerate(levels):
                out[slots[t], rows] = lasso_rowwise(
                    np.asarray(X[rows], dtype=np.float64), D64, lam_t,
                    None if mask is None else mask[rows])

    return fill(_solve_groups(X, D64, mask, chunk_size, min_group, solver, n_jobs,
                              where.size, dtype, gram_cache, base))


def lasso(
    X, D, lam, mask=None, *, n_jobs=None, chunk_size=1024, min_group=MIN_GROUP, dtype=np.float32
):
    """Lasso codes of every row of ``X`` on the atoms (rows) of ``D``.

    Solves ``min_a 0.5 ||x - D^T a||^2 + lam ||a||_1`` per row, or with a mask
    ``min_a 0.5 ||m * (x - D^T a)||^2 + lam (||m||_0 / p) ||a||_1`` (the reference
    implementation's masked lasso). Exact up to floating point (homotopy, see
    :func:`lasso_path`); the same problem as ``sklearn.decomposition.sparse_encode(X, D,
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
        Worker threads over chunks (None: one; -1: all cores).
    chunk_size : int
        Rows per task.
    min_group : int
        Rows sharing one mask are solved with that mask's Gram matrix when at least this many.
    dtype : numpy dtype
        Output dtype (the solve runs in float64).

    Returns
    -------
    A : ndarray of shape (n, d)
    """
    if np.ndim(lam) != 0:
        raise ValueError(f"lam must be a single number (use lasso_path for several), got {lam!r}")
    _check_lams(lam)
    return lasso_path(X, D, [lam], mask, n_jobs=n_jobs, chunk_size=chunk_size,
                      min_group=min_group, dtype=dtype)[0]


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

    X, D, _ = _check_xd(np.asarray(X, dtype=np.float64), np.asarray(D, dtype=np.float64))
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

    X, D, _ = _check_xd(np.asarray(X, dtype=np.float64), np.asarray(D, dtype=np.float64))
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
# OMP: compiled per row (dlsr._homotopy.omp_path_rows) with snapshots at every requested L


def omp_path(X, D, n_nonzeros, mask=None, *, n_jobs=None, chunk_size=1024, min_group=MIN_GROUP,
             dtype=np.float32, correlations=None, gram_cache=None, base_mask=None):
    """OMP codes for several numbers of atoms from one greedy run.

    OMP's selection does not depend on the final number of atoms, so one run to the largest
    ``L`` gives every smaller one (the least-squares fit on the first ``L`` selected atoms).
    Which of two identical atoms is selected depends on rounding (see :func:`omp`).

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
    n_nonzeros : int or sequence of int
        Numbers of atoms, >= 1, in any order.
    mask : array-like of shape (n, p), bool, optional
    n_jobs, chunk_size, min_group, dtype, correlations, gram_cache, base_mask
        As in :func:`lasso_path`.

    Returns
    -------
    A : ndarray of shape (len(n_nonzeros), n, d)
    """
    X, D, mask = _check_xd(X, D, mask)
    base = _check_base(base_mask, mask)
    Ls = np.atleast_1d(np.asarray(n_nonzeros))
    if (Ls.ndim != 1 or Ls.size == 0 or not np.issubdtype(Ls.dtype, np.number)
            or np.any(Ls != np.round(Ls)) or np.any(Ls < 1)):
        raise ValueError(f"n_nonzero must be positive integers, got {n_nonzeros!r}")
    stops, where = np.unique(Ls.astype(np.int64), return_inverse=True)
    where = where.ravel()
    from dlsr._homotopy import omp_path_rows

    D64 = np.ascontiguousarray(D, dtype=np.float64)
    Dt = np.ascontiguousarray(D64.T)
    B_all = _correlations(X, D64, mask, correlations)
    G_full = D64 @ D64.T if mask is not None else None
    stops_c = np.minimum(stops, D64.shape[0]).astype(np.int64)
    no_M = np.zeros((1, 1))

    slots, fill = _slots(where, stops_c.size)

    def solver(idx, op, out):
        B = B_all[idx]
        if isinstance(op, _SharedGram):
            omp_path_rows(B, op.G64, Dt, no_M, False, stops_c, out, idx, slots, _TINY)
        else:
            M = np.ascontiguousarray(op.M, dtype=np.float64)
            G = G_full if op.G64 is None else op.G64
            omp_path_rows(B, G, Dt, M, True, stops_c, out, idx, slots, _TINY)

    return fill(_solve_groups(X, D64, mask, chunk_size, min_group, solver, n_jobs,
                              where.size, dtype, gram_cache, base))


def omp(X, D, n_nonzero, mask=None, *, n_jobs=None, chunk_size=1024, min_group=MIN_GROUP,
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

    Ties between identical atoms: when the dictionary holds an atom twice (or an atom and its
    negative), both have the same residual correlation up to rounding, and the rounding of the
    products ``X D^T`` and ``D D^T`` depends on the BLAS kernels the CPU runs (OpenBLAS's
    SSE3, AVX2 or AVX-512 kernels) and on where each copy sits in the product. Which copy is
    selected, and so which column carries the coefficient, can therefore differ from one
    machine to another (and from scikit-learn's choice). Nothing else does: the other copy is
    linearly dependent on the selected atoms and never joins, so the number of atoms, the
    coefficients summed over the copies of each atom, the reconstruction ``D^T a`` and the
    residual are the same. Remove duplicate atoms first if the column matters. (Distinct atoms
    whose correlations differ by less than the rounding are likewise picked by rounding.)

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
    if np.ndim(n_nonzero) != 0:
        raise ValueError(f"n_nonzero must be one integer (use omp_path for several), "
                         f"got {n_nonzero!r}")
    return omp_path(X, D, [n_nonzero], mask, n_jobs=n_jobs, chunk_size=chunk_size,
                    min_group=min_group, dtype=dtype)[0]


# --------------------------------------------------------------------------------------------
# dense encoders


def _dense_chunks(X, n_out, fn, chunk_size, dtype):
    """``fn(x, out)`` over row chunks, in as many threads as BLAS may use (1 BLAS thread each).

    ``fn`` receives ``x`` already in ``dtype`` and returns a float that is finite when its
    products did not overflow (or None: the output's sum is used).

    Splitting rows over threads parallelises the element-wise work too, which threaded BLAS
    alone does not. Each chunk's rows are checked finite before its product (in the workers):
    what a product does with a NaN or an infinity depends on the BLAS kernels (OpenBLAS's
    AVX-512 kernels raise numpy's "invalid value encountered in matmul" on an infinity, its
    AVX2 and SSE3 kernels do not), so the error must come first. Finite rows can then only
    overflow ``dtype``; the products run with numpy's overflow and invalid warnings off (again
    kernel-dependent) and an overflow is reported as a ``ValueError``.
    """
    from dlsr._dense import first_non_finite_row

    n = X.shape[0]
    out = np.empty((n, n_out), dtype=dtype)
    slices = list(_chunks(n, chunk_size))

    def run(sl):
        x = X[sl]
        bad = first_non_finite_row(x)
        if bad >= 0:
            raise ValueError(f"X must be finite (no NaN or inf): row {sl.start + bad} is not")
        o = out[sl]
        with np.errstate(over="ignore", invalid="ignore"):  # errstate is per thread
            check = fn(np.asarray(x, dtype=dtype), o)
            if check is None:
                check = o.sum(dtype=np.float64)
        if not np.isfinite(check):
            raise ValueError(f"the products of X (rows {sl.start} to {sl.stop - 1}) with the "
                             f"dictionary overflow {np.dtype(dtype).name}; scale the input down")

    workers = min(_threads.blas_threads(), len(slices)) if len(slices) > 1 else 1
    if workers <= 1:
        for sl in slices:
            run(sl)
        return out
    with _threads.limit(1), ThreadPoolExecutor(workers) as pool:
        list(pool.map(run, slices))
    return out


def _as_finite(a, dtype, name):
    """``a`` cast to ``dtype`` (C-contiguous); ``ValueError`` if a value does not fit in it."""
    from dlsr._dense import check_finite

    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(a, dtype=dtype)
    if out.dtype != np.asarray(a).dtype:
        try:
            check_finite(out, name)
        except ValueError:
            raise ValueError(f"{name} has values beyond the range of "
                             f"{np.dtype(dtype).name}") from None
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
    X, D, _ = _check_xd(X, D, check_finite_x=False)  # X: per chunk, before its product
    if not np.isfinite(lam) or lam < 0:
        raise ValueError(f"lam must be a finite number >= 0, got {lam}")
    from dlsr._dense import soft_threshold_inplace

    Dt = _as_finite(D.T, dtype, "D")
    lam = dtype(lam) if isinstance(dtype, type) else np.dtype(dtype).type(lam)

    def fn(x, out):
        np.matmul(x, Dt, out=out)
        if lam == 0:
            return None
        return soft_threshold_inplace(out, lam)  # one fused pass; sum of the projections

    return _dense_chunks(X, D.shape[0], fn, chunk_size, Dt.dtype)


def soft_threshold_path(X, D, lams, *, chunk_size=4096, dtype=np.float32):
    """Soft-threshold codes for several thresholds from one matrix product.

    Parameters
    ----------
    X : array-like of shape (n, p)
    D : array-like of shape (d, p)
    lams : sequence of float, each >= 0
    chunk_size : int
    dtype : numpy dtype

    Returns
    -------
    A : ndarray of shape (len(lams), n, d)
        ``A[t]`` equals ``soft_threshold(X, D, lams[t])``.
    """
    from dlsr._dense import soft_threshold_into

    lams = _check_lams(lams, "lams")
    Z = soft_threshold(X, D, 0.0, chunk_size=chunk_size, dtype=dtype)  # D x, checked finite
    out = np.empty((lams.size,) + Z.shape, dtype=Z.dtype)
    for t, lam in enumerate(lams):
        if lam > 0:
            soft_threshold_into(Z, Z.dtype.type(lam), out[t])
        else:
            out[t] = Z
    return out


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
    from dlsr._dense import triangle_inplace

    X, C, _ = _check_xd(X, centroids, check_finite_x=False)  # X: per chunk, before products
    Ct = _as_finite(C.T, dtype, "the centroids")
    with np.errstate(over="ignore"):  # an overflow shows in the checksum below
        Ct = Ct * -2  # z = ||x||^2 - 2 x.c + ||c||^2
        cn = np.einsum("kp,kp->k", C, C).astype(Ct.dtype)

    def fn(x, z):
        np.matmul(x, Ct, out=z)
        # one fused pass; its checksum (the sum of the squared distances) sees an overflow
        return triangle_inplace(z, cn, np.einsum("np,np->n", x, x))

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
    spec = natural_spec(learner, param)
    atoms = centroids if (learner == "NKM" and centroids is not None) else D
    mask = None
    if spec["masked"]:
        mask = np.ones(np.shape(X), dtype=bool) if M is None else M
    key = {"lasso": "lam", "threshold": "lam", "omp": "n_nonzero"}.get(spec["method"])
    kw = {key: spec["value"]} if key is not None else {}
    return encode(X, np.asarray(atoms), spec["method"], mask=mask, n_jobs=n_jobs,
                  polarity=bool(polarity) and spec["polarity"], **kw)


def natural_spec(learner, param=None) -> dict:
    """What the natural encoder of ``learner`` computes.

    Parameters
    ----------
    learner : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}
    param : float or int, optional
        SC's lambda (default 1.0) or OMP's L (default 10): the dictionary's own parameter;
        ignored by the others.

    Returns
    -------
    dict
        ``method`` (one of :data:`ENCODER_METHODS`), ``masked`` (bool), ``polarity`` (whether
        the codes are split; never for NKM's triangle codes) and ``value`` (the lambda or
        threshold, the number of atoms, or None for the triangle encoder).
    """
    if learner not in _NATURAL:
        raise ValueError(f"unknown dictionary method {learner!r}; expected one of "
                         f"{tuple(_NATURAL)}")
    spec = dict(_NATURAL[learner])
    fixed = spec.pop("lam", None), spec.pop("n_nonzero", None)  # at most one is set
    if learner == "SC":
        spec["value"] = 1.0 if param is None else float(param)
    elif learner == "OMP":
        spec["value"] = 10 if param is None else int(param)
    else:
        spec["value"] = fixed[0] if fixed[0] is not None else fixed[1]
    return spec


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
