"""The paper's classifier: an L2-regularised squared-hinge linear SVM on standardised features.

Following the authors' implementation (see ``shared/reference/dlsr-reference-facts.md``):

* features are standardised per dimension with the training mean and ``sqrt(var + 1e-5)``
  (:class:`FeatureStandardizer`);
* the SVM minimises ``F(w, b) = 0.5 ||w||^2 + C * mean_i max(0, 1 - y_i (w.x_i + b))^2`` with an
  unregularised bias (:class:`SquaredHingeSVC`). This is LIBLINEAR's / scikit-learn's
  ``LinearSVC(loss="squared_hinge")`` with ``C / n_train`` except that LIBLINEAR regularises the
  intercept.

Solver. ``F`` is convex, once differentiable and piecewise quadratic: on a fixed set ``SV`` of
margin violators (``y_i f_i < 1``) it is the quadratic ``0.5 ||w||^2 + C/n sum_SV (y_i - f_i)^2``,
whose minimiser is a regularised least-squares solution with an unpenalised intercept. The
default solver (``solver="newton"``, :func:`squared_hinge_fit`) is Newton's method on this
structure (Chapelle 2007, "Training a support vector machine in the primal"; the finite Newton
method of Keerthi & DeCoste 2005): solve that least-squares problem on the current ``SV``, move
towards its solution with an exact line search on the piecewise-quadratic ``F`` along the step
(so the objective decreases at every step and cannot cycle, as full steps can), recompute
``SV``, and stop when ``SV`` no longer changes and the gradient is at rounding level. It ends
in a handful of exact steps at the minimiser itself, where L-BFGS took 50 to 150 iterations
(two passes over ``X`` each) on the benchmark's features and stopped at a gradient tolerance.

When ``n <= 2 d`` the systems are solved in kernel form (``w = X^T beta``, a Cholesky
factorisation of size ``|SV|``); the entries of ``K = X X^T`` (float64) are computed when a row
first violates the margin, once, and shared by all the C values of a call, each C starting from
the previous one's solution. A cold start first solves the problem on a quarter of the rows
(kernel entries among those only), which starts the full problem with far fewer violators than
from zero: rows that violate the margin at no step (a third of the rows on the benchmark's
features) cost no kernel entries. Otherwise the systems are solved in primal form (size
``d + 1``, the Gram matrix of the violators updated as they change); a system whose violators
differ from the last factorised one's by a few rows (at most ``(d + 1) / 8``) is solved with
that factor by the Woodbury identity and refined against its own matrix, and the first step
of a warm-started C (the previous C's violators, a new penalty) aims at a few
conjugate-gradient steps preconditioned by the previous penalty's factor, so that each C
factorises about once, not once per Newton step: on a real 885-image fold 25 factorisations
instead of 93 per parameter. Only the path changes, not the minimiser: every step after the
first of a C is exact.

Speed (``scripts/bench_svm.py``, one thread): on the benchmark's 2,400-column features, both C
values of an inner fold take a third to two fifths of L-BFGS's time (C = 10 warm-started: a
sixth to a tenth; C = 1 alone: about the same). With 1,200 columns or fewer, where ``X`` stays
in the processor's cache and L-BFGS's passes are cheap, it takes about as long, or up to twice
as long (a few tens of milliseconds).

It is the same problem as before: same objective, same minimiser (strictly convex in ``w``, and
in ``b`` too at the minimiser). The former L-BFGS solver is kept as ``solver="lbfgs"``, the
reference the Newton solver is tested against.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.linalg import blas, lapack, lstsq
from scipy.optimize import minimize
from sklearn.base import BaseEstimator, ClassifierMixin, TransformerMixin
from sklearn.exceptions import ConvergenceWarning
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_is_fitted, validate_data

from . import _threads

__all__ = [
    "FeatureStandardizer",
    "SquaredHingeSVC",
    "squared_hinge_fit",
    "squared_hinge_objective",
]


class FeatureStandardizer(TransformerMixin, BaseEstimator):
    """Standardise each feature with the training mean and ``sqrt(var + eps)``.

    Parameters
    ----------
    eps : float, default=1e-5
        Added to the variance; keeps constant features finite.

    Attributes
    ----------
    mean_ : ndarray of shape (n_features,)
    scale_ : ndarray of shape (n_features,)
    """

    def __init__(self, eps: float = 1e-5):
        self.eps = eps

    def fit(self, X, y=None):
        X = validate_data(self, X, dtype=[np.float64, np.float32])
        if self.eps <= 0:
            raise ValueError(f"eps must be positive, got {self.eps}")
        self.mean_ = X.mean(axis=0)
        self.scale_ = np.sqrt(X.var(axis=0) + self.eps)
        return self

    def transform(self, X):
        check_is_fitted(self)
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        return ((X - self.mean_) / self.scale_).astype(X.dtype, copy=False)


def squared_hinge_objective(params, X, y_pm, C):
    """Objective and gradient of the squared-hinge SVM.

    Parameters
    ----------
    params : ndarray of shape (n_features + 1,)
        Weights followed by the bias.
    X : ndarray of shape (n_samples, n_features)
    y_pm : ndarray of shape (n_samples,)
        Labels in {-1, +1}.
    C : float

    Returns
    -------
    value : float
    grad : ndarray of shape (n_features + 1,)
    """
    w, b = params[:-1], params[-1]
    margin = 1.0 - y_pm * (X @ w + b)
    active = margin > 0
    m = np.where(active, margin, 0.0)
    n = X.shape[0]
    value = 0.5 * w @ w + C * (m @ m) / n
    coef = -2.0 * C / n * (y_pm * m)
    grad_w = w + X.T @ coef
    grad_b = coef.sum()
    return value, np.concatenate([grad_w, [grad_b]])


# --- Newton solver -------------------------------------------------------------------------------
#
# Notation: n rows, d features, f = X w + b, margins m_i = 1 - y_i f_i, c = C / n,
# lam = n / (2 C) = 1 / (2 c). On a fixed set S of violators (m_i > 0), using y_i^2 = 1,
#     F_S(w, b) = 0.5 ||w||^2 + c sum_S (y_i - x_i.w - b)^2,
# and grad F_S = 0 reads, after dividing by 2c,
#     (X_S^T X_S + lam I) w + X_S^T 1 b = X_S^T y_S,      1^T X_S w + |S| b = 1^T y_S   (primal),
# a system of size d + 1 whose bias row is not regularised. Its solution has w = X_S^T beta_S with
# beta_S = (y_S - f_S) / lam; substituting gives, with K_SS = X_S X_S^T,
#     (K_SS + lam I) beta_S + b 1 = y_S,                  1^T beta_S = 0                  (kernel),
# a bordered system of size |S| + 1: with u = (K_SS + lam I)^-1 y_S and v = (K_SS + lam I)^-1 1
# (one Cholesky factorisation), b = 1^T u / 1^T v and beta_S = u - b v. Both systems are
# positive definite as soon as S is not empty. For S empty, F_S = 0.5 ||w||^2 is minimised by
# w = 0 with any b; the current b is kept.

# Rows at which a cold start first solves the problem on a quarter of the rows (see _start).
_SUBSET_MIN_ROWS = 400
# Rows per block when the primal form sums outer products (the size of its one scratch array).
_BLOCK_ROWS = 4096
# The primal form solves a system whose violators differ from the last factorised one's by at
# most (d + 1) / _LOW_RANK_FRACTION rows with that factor (Woodbury, then refined): the
# columns L^-1 u_i cost r d^2 against the factorisation's d^3 / 3.
_LOW_RANK_FRACTION = 8
# ... with at least this many features: below, a factorisation costs less than the reuse's
# Python and BLAS-2 overhead (measured equal at 200 features, 0.75 times at 400, 0.68 at 800).
_LOW_RANK_MIN_FEATURES = 256
# Refinement steps of such a solve at most, and the correction (relative to the solution, in
# the largest entry) it must end below, else the system is factorised.
_REFINE_STEPS = 6
_REFINE_TOL = 1e-9
_EPS = np.finfo(np.float64).eps
# Conjugate-gradient steps of the approximate first step of a warm-started C (primal form).
_PCG_STEPS = 6


def _solve_spd(matrix, rhs, full=None):
    """Solve ``A x = rhs`` for the symmetric positive definite ``A = matrix()``.

    Cholesky (LAPACK ``dposv``, overwriting ``A``, reading its lower triangle). ``matrix()``
    returns an array it may overwrite: a C-ordered symmetric one is passed as ``A.T`` (the
    Fortran-ordered array LAPACK wants, no copy), a Fortran-ordered one as it is (only its lower
    triangle need be filled). When ``A`` is not positive definite in floating point (the
    regularisation below the rounding of its entries), least squares on ``full()`` (a fresh
    symmetric ``A``; a second ``matrix()`` when not given).
    """
    A = matrix()
    _, x, info = lapack.dposv(A if A.flags.f_contiguous else A.T, rhs, lower=1, overwrite_a=1,
                              overwrite_b=0)
    if info != 0:
        x = lstsq((full or matrix)(), rhs, check_finite=False)[0]
    return x


class _KernelSystem:
    """Newton systems in kernel form; entries of ``K = X X^T`` computed once, when first needed.

    The rows met so far are kept, in the order they were first met, in ``_rows`` and their
    kernel block in ``_K[:m, :m]``; ``_pos[i]`` is row ``i``'s place there (-1: not yet) and
    ``_order`` the inverse map.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features), float64, C-contiguous
    y : ndarray of shape (n_samples,)
        Labels in {-1, +1}.
    """

    def __init__(self, X, y):
        self.X, self.y = X, y
        self._pos = np.full(len(X), -1, dtype=np.intp)
        self._order = np.empty(len(X), dtype=np.intp)  # the row at each cache position
        self._rows = None
        self._K = None
        self._m = 0

    def _add(self, idx):
        """Cache the rows of ``idx`` not cached yet, with their kernel entries with all cached."""
        new = idx[self._pos[idx] < 0]
        if not new.size:
            return
        if self._K is None:  # allocated on first use; pages never written are never committed
            self._rows = np.empty_like(self.X)
            self._K = np.empty((len(self.X), len(self.X)))
        m, k = self._m, new.size
        R = self._rows
        R[m:m + k] = self.X[new]
        Rn = R[m:m + k]
        self._K[m:m + k, m:m + k] = Rn @ Rn.T  # symmetric product (BLAS syrk), half the work
        if m:
            block = Rn @ R[:m].T
            self._K[m:m + k, :m] = block
            self._K[:m, m:m + k] = block.T
        self._pos[new] = np.arange(m, m + k)
        self._order[m:m + k] = new
        self._m = m + k

    def approximate(self, idx, lam, w, b):  # noqa: ARG002 - the primal form's signature
        """None: in kernel form every Newton step is solved exactly."""
        return None

    def solve(self, idx, lam, refresh=False):
        """Minimiser ``(w, b)`` of the quadratic on rows ``idx`` (not empty).

        ``refresh`` is ignored: kernel entries are computed once, exactly.
        """
        self._add(idx)
        m = self._m
        pos = self._pos[idx]
        inside = np.zeros(m, dtype=bool)
        inside[pos] = True
        rows = np.flatnonzero(inside)  # positions in cache order: a boolean gather is fastest
        idx = self._order[rows]
        K = self._K[:m, :m]

        def matrix():
            A = K[inside][:, inside]
            A.flat[:: len(idx) + 1] += lam
            return A

        rhs = np.empty((len(idx), 2))
        rhs[:, 0] = self.y[idx]
        rhs[:, 1] = 1.0
        uv = _solve_spd(matrix, rhs)
        u, v = uv[:, 0], uv[:, 1]
        b = u.sum() / v.sum()
        beta = np.zeros(m)  # in cache order: w = X^T beta reads the cached rows only
        beta[rows] = u - b * v
        return self._rows[:m].T @ beta, float(b)


class _PrimalSystem:
    """Newton systems in primal form (size ``d + 1``), updating ``[X_S 1]^T [X_S 1]`` as S changes.

    The Gram matrix is updated in place: the rows that enter or leave are gathered, a block of
    ``_BLOCK_ROWS`` at a time, into one scratch array ``[x_i 1]`` made once, and BLAS ``dsyrk``
    adds (or subtracts) their outer products to the lower triangle of ``H`` (Fortran order)
    directly: no copy of ``X``, no product matrix, no scaled temporary. A solve that needs a
    factorisation copies ``H`` into one work array made once, which LAPACK factorises in place
    (Cholesky, ``L L^T = H_f + lam I`` on the violators ``S_f`` of that solve).

    The later systems of the same C differ from the factorised one by the ``r`` rows that
    entered or left the violators since: ``H + lam I = L L^T + U^T diag(s) U`` with ``U`` those
    rows ``[x_i 1]`` and ``s_i = +1`` (entered) or -1 (left). While ``r`` is at most
    ``(d + 1) / _LOW_RANK_FRACTION`` they are solved with the factor already made, by the
    Woodbury identity (``Z = L^-1 U^T``, computed once per row while the factor lasts, and the
    ``r x r`` capacitance ``diag(s) + Z^T Z``; with at least ``_LOW_RANK_MIN_FEATURES``
    features), then refined against ``H + lam I`` itself
    (``x += (H + lam I)^-1_Woodbury (g - (H + lam I) x)``, the residual from the updated ``H``,
    until the correction stops shrinking): the system solved is the one the factorisation
    would solve, to its rounding, for ``O(r d^2)`` instead of ``O(d^3)``. A correction that
    does not converge falls back to the factorisation. The first system of a new C (a new
    penalty) is only approximated, from the last factor (:meth:`approximate`).

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features), float64, C-contiguous
    y : ndarray of shape (n_samples,)
        Labels in {-1, +1}.
    """

    def __init__(self, X, y):
        n, d = X.shape
        self.X, self.y = X, y
        # [X_S 1]^T [X_S 1] for the rows in _in: lower triangle, Fortran order
        self._H = np.zeros((d + 1, d + 1), order="F")
        self._A = None  # H + lam I, factorised in place (made on first solve)
        self._buf = None  # gathered rows [x_i 1] (made on first use)
        self._in = np.zeros(n, dtype=bool)
        # the factor in _A: valid, for the violators _f_in and the penalty _f_lam
        self._f_ok = False
        self._f_in = None
        self._f_lam = None
        # columns L^-1 [x_i 1]^T of rows differing from _f_in, while the factor lasts
        self._zpos = np.full(n, -1, dtype=np.intp)  # row -> column of _Z (-1: none)
        self._Z = None
        self._zrows = np.empty(0, dtype=np.intp)
        self.n_factorisations = 0  # counters, for the benchmarks and tests
        self.n_low_rank = 0
        self.n_approximate = 0

    def _gather(self, block):
        """``[x_i 1]`` for the rows of ``block`` (at most ``_BLOCK_ROWS``) in the scratch array."""
        d = self.X.shape[1]
        if self._buf is None:
            self._buf = np.empty((min(_BLOCK_ROWS, len(self.X)), d + 1))
            self._buf[:, d] = 1.0
        Z = self._buf[:len(block)]
        np.take(self.X, block, axis=0, out=Z[:, :d], mode="clip")
        return Z

    def _accumulate(self, rows, sign):
        """Add (``sign`` +1) or subtract (-1) ``[x_i 1]^T [x_i 1]`` over ``rows``."""
        for sg in (1.0, -1.0):
            part = rows[sign > 0] if sg > 0 else rows[sign < 0]
            for start in range(0, len(part), _BLOCK_ROWS):
                Z = self._gather(part[start:start + _BLOCK_ROWS])
                # H += sg Z^T Z on the lower triangle, in place (Z.T: Fortran, no copy)
                blas.dsyrk(sg, Z.T, beta=1.0, c=self._H, trans=0, lower=1, overwrite_c=1)

    def _full(self, lam):
        """``H + lam I`` (bias entry unregularised) as a fresh symmetric array."""
        d = self.X.shape[1]
        L = np.tril(self._H)
        A = L + np.tril(L, -1).T
        A.flat[: d * (d + 2): d + 2] += lam
        return A

    def _factorise_and_solve(self, S, lam, rhs):
        """Solve by a Cholesky factorisation of ``H + lam I``, kept for the next solves."""
        d = self.X.shape[1]
        if self._A is None:
            self._A = np.empty_like(self._H)  # Fortran order, like H
        A = self._A
        np.copyto(A, self._H)
        A.flat[: d * (d + 2): d + 2] += lam  # not the bias entry A[d, d]
        _, x, info = lapack.dposv(A, rhs, lower=1, overwrite_a=1, overwrite_b=0)
        self.n_factorisations += 1
        self._f_ok = info == 0
        self._f_in, self._f_lam = S.copy(), lam
        self._zpos[self._zrows] = -1
        self._zrows = self._zrows[:0]
        if info != 0:  # not positive definite in floating point: least squares
            x = lstsq(self._full(lam), rhs, check_finite=False)[0]
        return x

    def _z_columns(self, diff):
        """``L^-1 [x_i 1]^T`` for the rows ``diff``, computing those not yet known."""
        d = self.X.shape[1]
        new = diff[self._zpos[diff] < 0]
        cap = max((d + 1) // _LOW_RANK_FRACTION, 1)
        if self._Z is None:
            self._Z = np.empty((d + 1, cap), order="F")
        m = self._zrows.size
        if m + new.size > cap:  # forget the columns of rows no longer needed
            keep = self._zrows[np.isin(self._zrows, diff)]
            self._Z[:, :keep.size] = self._Z[:, self._zpos[keep]]
            self._zpos[self._zrows] = -1
            self._zpos[keep] = np.arange(keep.size)
            self._zrows, m = keep, keep.size
        for start in range(0, new.size, _BLOCK_ROWS):
            block = new[start:start + _BLOCK_ROWS]
            U = self._gather(block)
            self._Z[:, m:m + block.size] = blas.dtrsm(1.0, self._A, U.T, lower=1)
            self._zpos[block] = np.arange(m, m + block.size)
            m += block.size
        self._zrows = np.r_[self._zrows, new]
        return self._Z[:, self._zpos[diff]]

    def _factor_operator(self, S):
        """``v -> (L L^T + U^T diag(s) U)^-1 v``: the inverse of the last factorised matrix
        with the rows of ``S`` that differ from its violators entered or left (Woodbury);
        None when the capacitance is singular."""
        diff = np.flatnonzero(S != self._f_in)
        L = self._A
        if diff.size:
            Z = self._z_columns(diff)
            cap = Z.T @ Z
            cap.flat[:: diff.size + 1] += np.where(S[diff], 1.0, -1.0)
            lu, piv, info = lapack.dgetrf(cap, overwrite_a=1)
            if info != 0:
                return None

        def apply(v):
            t = blas.dtrsv(L, v, lower=1)
            if diff.size:
                t -= Z @ lapack.dgetrs(lu, piv, Z.T @ t)[0]
            return blas.dtrsv(L, t, lower=1, trans=1)

        return apply

    def _matvec(self, x, lam):
        """``(H + lam I) x``, the bias entry unregularised."""
        d = self.X.shape[1]
        out = blas.dsymv(1.0, self._H, x, lower=1)
        out[:d] += lam * x[:d]
        return out

    def _factor_reaches(self, S) -> bool:
        """Whether the last factorisation can serve the violators ``S`` (a boolean mask):
        enough features for the reuse to pay, a valid factor, and at most
        ``(d + 1) / _LOW_RANK_FRACTION`` rows entered or left since it was made."""
        d = self.X.shape[1]
        return (d >= _LOW_RANK_MIN_FEATURES and self._f_ok
                and np.count_nonzero(S != self._f_in) <= (d + 1) // _LOW_RANK_FRACTION)

    def _low_rank_solve(self, S, lam, rhs):
        """Solve with the factor of the last factorisation (Woodbury, then refined against
        ``H + lam I``); None when the refinement does not converge."""
        apply = self._factor_operator(S)
        if apply is None:
            return None
        x = apply(rhs)
        last = size = np.inf
        for _ in range(_REFINE_STEPS):
            delta = apply(rhs - self._matvec(x, lam))
            x += delta
            size = float(np.abs(delta).max())
            scale = float(np.abs(x).max())
            if size <= _EPS * scale or size > 0.5 * last:
                break  # at the rounding floor: the correction no longer shrinks
            last = size
        if not (size <= _REFINE_TOL * scale and np.all(np.isfinite(x))):
            return None
        self.n_low_rank += 1
        return x

    def _update(self, idx, refresh):
        """Bring ``H`` to the violators ``idx``: their mask and the right-hand side."""
        S = np.zeros(len(self._in), dtype=bool)
        S[idx] = True
        changed = np.flatnonzero(S != self._in)
        if refresh or changed.size >= idx.size:  # cheaper to sum S afresh
            self._H[:] = 0.0
            self._accumulate(idx, np.ones(idx.size))
        elif changed.size:  # add the rows that entered, subtract those that left
            self._accumulate(changed, np.where(S[changed], 1.0, -1.0))
        self._in = S
        y_S = np.where(S, self.y, 0.0)
        return S, np.r_[self.X.T @ y_S, y_S.sum()]

    def approximate(self, idx, lam, w, b):
        """A point near the minimiser of the quadratic on rows ``idx`` under a new penalty, or
        None: ``_PCG_STEPS`` conjugate-gradient steps from ``(w, b)`` preconditioned by the
        last factorisation.

        The first system of a new C has the previous C's violators and a new penalty: no
        factor fits it. Preconditioned by the last one (the previous penalty; the violators
        within ``(d + 1) / _LOW_RANK_FRACTION`` rows, by Woodbury), its spectrum lies in
        ``[lam / lam_f, 1]`` (``[1/10, 1]`` for a tenfold C) and a few steps from the previous
        C's solution go most of the way. It is only the first Newton step's target (a descent
        direction whose length the exact line search finds); the later steps are exact, and
        so is the minimiser.
        """
        d = self.X.shape[1]
        if lam == self._f_lam or idx.size == 0:
            return None
        S = np.zeros(len(self._in), dtype=bool)
        S[idx] = True
        if not self._factor_reaches(S):
            return None
        S, rhs = self._update(idx, refresh=False)
        apply = self._factor_operator(S)
        if apply is None:
            return None
        x = np.r_[w, b]
        r = rhs - self._matvec(x, lam)
        z = apply(r)
        p = z.copy()
        rz = float(r @ z)
        for _ in range(_PCG_STEPS):
            Ap = self._matvec(p, lam)
            pAp = float(p @ Ap)
            if not (pAp > 0 and rz > 0 and np.isfinite(pAp)):
                break
            alpha = rz / pAp
            x += alpha * p
            r -= alpha * Ap
            z = apply(r)
            rz_new = float(r @ z)
            p = z + (rz_new / rz) * p
            rz = rz_new
        if not np.all(np.isfinite(x)):
            return None
        self.n_approximate += 1
        return x[:d].copy(), float(x[d])

    def solve(self, idx, lam, refresh=False):
        """Minimiser ``(w, b)`` of the quadratic on rows ``idx`` (sorted, not empty).

        With ``refresh``, the Gram matrix is summed afresh rather than updated (no rounding
        carried over from the updates) and factorised.
        """
        d = self.X.shape[1]
        S, rhs = self._update(idx, refresh)
        x = None
        if not refresh and lam == self._f_lam and self._factor_reaches(S):
            x = self._low_rank_solve(S, lam, rhs)
        if x is None:
            x = self._factorise_and_solve(S, lam, rhs)
        return x[:d].copy(), float(x[d])


def _exact_step(m, s, wp, pp, c):
    """Exact line search along a Newton direction: the minimiser ``t >= 0`` of ``phi``.

    ``phi(t) = F(w + t p_w, b + t p_b)`` is convex and piecewise quadratic:
    ``phi(t) = const + t w.p_w + t^2 / 2 p_w.p_w + c sum_i max(0, m_i - t s_i)^2`` with
    ``s_i = y_i (x_i.p_w + p_b)``, so ``phi'`` is continuous, non-decreasing and linear between
    breakpoints ``t_i = m_i / s_i`` (row ``i`` leaves the violators there if ``s_i > 0``, enters
    if ``s_i < 0``). The breakpoints are scanned in order until ``phi'`` turns non-negative.

    Parameters
    ----------
    m : ndarray of shape (n_samples,)
        Margins ``1 - y_i f_i`` at ``t = 0``.
    s : ndarray of shape (n_samples,)
        Their rates of decrease along the direction.
    wp, pp : float
        ``w.p_w`` and ``p_w.p_w``.
    c : float
        ``C / n_samples``.

    Returns
    -------
    t : float
        Exactly 1 when no breakpoint lies in ``(0, 1)`` (then ``phi`` is the Newton model on
        ``[0, 1]`` and the full step is its minimiser).
    """
    act = m > 0
    enter = ~act & (s < 0)
    leave = act & (s > 0)
    events = np.flatnonzero(enter | leave)
    t_ev = m[events] / s[events]
    if not events.size or t_ev.min() >= 1.0:
        return 1.0
    # phi'(t) = alpha + beta t with, per violator, -2c s_i m_i + 2c s_i^2 t
    a = -2.0 * c * s * m
    q = 2.0 * c * s * s
    alpha = wp + a[act].sum()
    beta = pp + q[act].sum()
    order = np.argsort(t_ev, kind="stable")
    t_ev, events = t_ev[order], events[order]
    sign = np.where(enter[events], 1.0, -1.0)
    alphas = alpha + np.r_[0.0, np.cumsum(sign * a[events])]  # alphas[k]: after k events
    betas = beta + np.r_[0.0, np.cumsum(sign * q[events])]
    past = np.flatnonzero(alphas[:-1] + betas[:-1] * t_ev >= 0)  # phi'(t_k) >= 0
    k = past[0] if past.size else len(t_ev)
    lo = t_ev[k - 1] if k > 0 else 0.0
    hi = t_ev[k] if k < len(t_ev) else np.inf
    if betas[k] <= 0:  # phi' constant on the piece (degenerate direction): its left end
        return float(lo) if np.isfinite(hi) else max(float(lo), 1.0)
    return float(np.clip(-alphas[k] / betas[k], lo, hi))


def _newton(X, y, C, system, rows, w, b, g_ref, tol, max_iter, approximate_first=False):
    """Newton iterations for one C from ``(w, b)``.

    With ``approximate_first`` (a C warm-started from the previous C's solution), the first
    step's target may be the system's approximation (``system.approximate``) rather than its
    exact minimiser: the exact line search along it still decreases ``F``, and the
    convergence test waits for an exact step.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features)
    y : ndarray of shape (n_samples,)
    C : float
    system : _KernelSystem or _PrimalSystem
        Built on the full data; ``rows`` maps the rows of ``X`` to its rows.
    rows : ndarray of shape (n_samples,) or None
    w : ndarray of shape (n_features,)
    b : float
    g_ref : float
        The gradient criterion's reference (:func:`_gradient_reference`).
    tol : float
    max_iter : int

    Returns
    -------
    w : ndarray of shape (n_features,)
    b : float
    n_iter : int
    converged : bool
    """
    n = len(y)
    c = C / n
    lam = n / (2.0 * C)
    f = X @ w + b
    it = 0
    last_norm = None  # gradient norm after the last step that left the violators unchanged
    for it in range(1, max_iter + 1):  # noqa: B007 - it is returned
        m = 1.0 - y * f
        act = m > 0
        idx = np.flatnonzero(act)
        approx = None
        if it == 1 and approximate_first and rows is None:
            approx = system.approximate(idx, lam, w, b)
        if approx is not None:
            w_new, b_new = approx
        elif idx.size:
            w_new, b_new = system.solve(idx if rows is None else rows[idx], lam,
                                        refresh=last_norm is not None)
        else:
            w_new, b_new = np.zeros_like(w), b
        f_new = X @ w_new + b_new
        g = f_new - f
        p_w = w_new - w
        t = _exact_step(m, y * g, float(w @ p_w), float(p_w @ p_w), c)
        if t == 1.0:
            w, b, f = w_new, b_new, f_new
        else:
            w, b, f = w + t * p_w, b + t * (b_new - b), f + t * g
        m_new = 1.0 - y * f
        if approx is not None:
            continue  # not an exact step: neither a convergence test nor a stop
        if np.array_equal(m_new > 0, act):
            # (w, b) is the Newton target of its own violators: optimal up to rounding
            r = y * np.maximum(m_new, 0.0)
            grad_w = w - 2.0 * c * (X.T @ r)
            grad_b = -2.0 * c * r.sum()
            norm = float(np.sqrt(grad_w @ grad_w + grad_b**2))
            if norm <= tol * g_ref:
                return w, b, it, True
            if last_norm is not None and norm > 0.5 * last_norm:
                break  # solving again (afresh) did not help: the rounding floor is above tol
            last_norm = norm
        else:
            last_norm = None
        if t == 0.0:  # no descent left in floating point
            break
    return w, b, it, False


def _subset(y, size):
    """About ``size`` rows, evenly spread within each class (both classes kept)."""
    out = []
    for cls in (-1.0, 1.0):
        rows = np.flatnonzero(y == cls)
        k = min(len(rows), max(1, round(size * len(rows) / len(y))))
        out.append(rows[np.round(np.linspace(0, len(rows) - 1, k)).astype(np.intp)])
    return np.sort(np.concatenate(out))


def _sum_of_squares(X):
    """``sum X**2`` in one pass without a temporary (``X`` C-contiguous)."""
    flat = X.reshape(-1)
    return float(flat @ flat)


def _gradient_reference(X, y, C, sum_sq=None):
    """Scale of the gradient criterion: the gradient norm at ``w = 0, b = 0``, or more.

    That gradient is ``-2 C / n sum_i y_i (x_i, 1)``; when its terms cancel (at worst, to 0 when
    the origin is the minimiser, as with each row present once with each label) the scale is
    ``2 C / n ||[X 1]||_F``, the size of the sum for terms of random signs. ``sum_sq`` is
    ``sum X**2`` if already known.
    """
    at_zero = float(np.sqrt(np.sum((X.T @ y) ** 2) + y.sum() ** 2))
    if sum_sq is None:
        sum_sq = _sum_of_squares(X)
    spread = float(np.sqrt(sum_sq + len(y)))
    return 2.0 * C / len(y) * max(at_zero, spread)


def _start(X, y, C, system, tol, max_iter):
    """Cold start: in kernel form, the solution on a quarter of the rows if there are enough.

    From ``w = 0, b = 0`` every row violates the margin, so the first Newton system involves all
    rows (in kernel form, all of ``K``). The solution on an evenly spread quarter of the rows (a
    problem 16 times smaller in kernel form) is much closer to the full one, with far fewer
    violators, so fewer kernel entries are ever computed. It only changes the starting point.
    In primal form the systems have the same size whatever the rows: start from zero.
    """
    d = X.shape[1]
    if len(y) < _SUBSET_MIN_ROWS or not isinstance(system, _KernelSystem):
        return np.zeros(d), 0.0
    rows = _subset(y, len(y) // 4)
    Xs, ys = X[rows], y[rows]
    w, b, _, _ = _newton(Xs, ys, C, system, rows, np.zeros(d), 0.0,
                         _gradient_reference(Xs, ys, C), tol, max_iter)
    return w, b


def squared_hinge_fit(X, y_pm, Cs, *, tol=1e-6, max_iter=100, form="auto", warm_start=True,
                      check_input=True, start=None):
    """Minimise ``0.5 ||w||^2 + C * mean_i max(0, 1 - y_i (w.x_i + b))^2`` for several C.

    Newton's method on the violators' regularised least squares with an exact line search
    (module docstring). The C values share one kernel (or Gram matrix) and, with
    ``warm_start``, each starts from the previous one's solution.

    Parameters
    ----------
    X : array-like of shape (n_samples, n_features)
        Converted to float64.
    y_pm : array-like of shape (n_samples,)
        Labels in {-1, +1}, both present.
    Cs : float or sequence of float
        Positive weights of the mean squared hinge, solved in the order given.
    tol : float, default=1e-6
        Stop when the violators no longer change and the gradient norm is at most ``tol`` times
        its norm at ``w = 0, b = 0`` (or times ``2 C / n ||[X 1]||_F`` if that is larger: the
        gradient at the origin vanishes when the origin is the minimiser).
    max_iter : int, default=100
        Newton steps per C; a :class:`~sklearn.exceptions.ConvergenceWarning` when exceeded.
    form : {"auto", "kernel", "primal"}, default="auto"
        Linear systems of size ``|SV| + 1`` from ``K = X X^T`` (kernel) or ``d + 1`` (primal).
        "auto" takes the kernel form when ``n_samples <= 2 * n_features``: at ``n`` close to
        ``d`` it is still the cheaper one, since the violators are a fraction of the rows.
    warm_start : bool, default=True
        Start each C from the previous C's solution; otherwise each C starts cold (the first
        from ``start`` when given).
    check_input : bool, default=True
        Check shapes, finiteness and labels (callers that validated already may skip it).
    start : tuple (w, b) or None, default=None
        Where the first C starts (``w`` of shape (n_features,)), e.g. the solution of a
        neighbouring problem; None starts cold. Only the path changes: the minimiser is the
        same, up to rounding.

    Returns
    -------
    list of tuple
        One ``(w, b, n_iter)`` per C, in the order of ``Cs``: ``w`` ndarray of shape
        (n_features,), ``b`` float, ``n_iter`` the Newton steps taken on the full problem.

    Raises
    ------
    ValueError
        On bad shapes, NaN or infinite values, labels other than -1 and +1, a single class, a
        C that is not positive, or an unknown ``form``.
    """
    # One BLAS thread: with more, the Gram and kernel products sum in another order and the
    # solution moved in its last bits, so a model depended on where it was trained (the main
    # process, a worker, the machine's core count).
    with _threads.one_blas_thread():
        return _squared_hinge_fit(X, y_pm, Cs, tol=tol, max_iter=max_iter, form=form,
                                  warm_start=warm_start, check_input=check_input, start=start)


def _squared_hinge_fit(X, y_pm, Cs, *, tol, max_iter, form, warm_start, check_input, start):
    Cs = np.atleast_1d(np.asarray(Cs, dtype=np.float64))
    if Cs.ndim != 1 or not np.all(Cs > 0) or not np.all(np.isfinite(Cs)):
        raise ValueError(f"C must be positive and finite, got {Cs.tolist()}")
    if form not in ("auto", "kernel", "primal"):
        raise ValueError(f"form must be 'auto', 'kernel' or 'primal', got {form!r}")
    X = np.ascontiguousarray(X, dtype=np.float64)
    y = np.asarray(y_pm, dtype=np.float64)
    if check_input:
        if X.ndim != 2 or y.ndim != 1 or len(y) != len(X) or X.shape[1] == 0:
            raise ValueError(
                f"X must be 2-D with at least one column and y_pm 1-D of the same length, got "
                f"shapes {X.shape} and {y.shape}"
            )
    sum_sq = _sum_of_squares(X)
    if check_input:
        # a NaN or infinity makes the sum of squares non-finite (so can an overflow: look)
        if not np.isfinite(sum_sq) and not np.all(np.isfinite(X)):
            raise ValueError("X contains NaN or infinity")
        if not np.all((y == 1.0) | (y == -1.0)):
            raise ValueError("y_pm must hold only -1 and +1")
        if not (np.any(y > 0) and np.any(y < 0)):
            raise ValueError(
                f"the squared-hinge SVM needs both classes; y_pm holds "
                f"{np.unique(y).tolist() or 'no label'}"
            )
    n, d = X.shape
    w = b = None
    if start is not None:
        w = np.array(start[0], dtype=np.float64)  # a copy: Newton replaces, never mutates it
        b = float(start[1])
        if w.shape != (d,) or not (np.all(np.isfinite(w)) and np.isfinite(b)):
            raise ValueError(f"start must be a finite (w, b) with w of shape {(d,)}, got "
                             f"shape {w.shape}")
    if form == "auto":
        form = "kernel" if n <= 2 * d else "primal"
    system = _KernelSystem(X, y) if form == "kernel" else _PrimalSystem(X, y)
    g1 = _gradient_reference(X, y, 1.0, sum_sq)  # proportional to C
    out = []
    for k, C in enumerate(Cs):
        C = float(C)
        if w is None or (k > 0 and not warm_start):
            w, b = _start(X, y, C, system, tol, max_iter)
        w, b, n_iter, converged = _newton(X, y, C, system, None, w, b, g1 * C, tol, max_iter,
                                          approximate_first=k > 0 and warm_start)
        if not converged:
            warnings.warn(
                f"the Newton solver of the squared-hinge SVM did not converge for C={C:g} in "
                f"{n_iter} steps (max_iter={max_iter}); the result may be inexact",
                ConvergenceWarning,
                stacklevel=2,
            )
        out.append((w.copy(), float(b), int(n_iter)))
    return out


class SquaredHingeSVC(ClassifierMixin, BaseEstimator):
    """Binary linear SVM with the squared hinge loss.

    Minimises ``0.5 ||w||^2 + C * mean(max(0, 1 - y (X w + b))^2)``; the bias is not regularised.

    Parameters
    ----------
    C : float, default=1.0
        Weight of the mean squared hinge loss.
    tol : float, default=1e-6
        Newton: gradient norm relative to its norm at ``w = 0, b = 0``, checked once the margin
        violators stop changing (see :func:`squared_hinge_fit`). L-BFGS: its gradient
        tolerance (``gtol``).
    max_iter : int, default=1000
        Newton steps or L-BFGS iterations.
    solver : {"newton", "lbfgs"}, default="newton"
        "newton": :func:`squared_hinge_fit` (exact, a few steps). "lbfgs": scipy's L-BFGS-B on
        :func:`squared_hinge_objective`, the former solver, kept as the reference.

    Attributes
    ----------
    classes_ : ndarray of shape (2,)
    coef_ : ndarray of shape (1, n_features)
    intercept_ : ndarray of shape (1,)
    n_iter_ : int
        Newton steps or L-BFGS iterations.
    """

    def __init__(self, C: float = 1.0, tol: float = 1e-6, max_iter: int = 1000,
                 solver: str = "newton"):
        self.C = C
        self.tol = tol
        self.max_iter = max_iter
        self.solver = solver

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.classifier_tags.multi_class = False
        return tags

    def fit(self, X, y):
        X, y = validate_data(self, X, y, dtype=[np.float64, np.float32])
        check_classification_targets(y)
        if not self.C > 0:
            raise ValueError(f"C must be positive, got {self.C}")
        if self.solver not in ("newton", "lbfgs"):
            raise ValueError(f"solver must be 'newton' or 'lbfgs', got {self.solver!r}")
        self.classes_ = np.unique(y)
        if len(self.classes_) != 2:
            kind = "Only binary classification is supported. " if len(self.classes_) > 2 else ""
            raise ValueError(
                f"{kind}SquaredHingeSVC is a binary classifier: the training labels have "
                f"{len(self.classes_)} class(es) {self.classes_.tolist()}; a fold needs both "
                f"positive and negative rectangles"
            )
        y_pm = np.where(y == self.classes_[1], 1.0, -1.0)
        X64 = np.asarray(X, dtype=np.float64)
        if self.solver == "newton":
            ((w, b, n_iter),) = squared_hinge_fit(
                X64, y_pm, [float(self.C)], tol=self.tol, max_iter=self.max_iter,
                check_input=False,
            )
            self.coef_ = w[None, :]
            self.intercept_ = np.array([b])
            self.n_iter_ = n_iter
            return self
        res = minimize(
            squared_hinge_objective,
            np.zeros(X.shape[1] + 1),
            args=(X64, y_pm, float(self.C)),
            jac=True,
            method="L-BFGS-B",
            options={"gtol": self.tol, "maxiter": self.max_iter, "maxcor": 20},
        )
        self.coef_ = res.x[None, :-1]
        self.intercept_ = res.x[-1:]
        self.n_iter_ = int(res.nit)
        return self

    def decision_function(self, X):
        check_is_fitted(self)
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        return X @ self.coef_[0] + self.intercept_[0]

    def predict(self, X):
        scores = self.decision_function(X)  # checks the fit first
        return self.classes_[(scores > 0).astype(int)]


# Instances collected by tests/dlsr/test_estimator_checks.py (parametrize_with_checks).
ESTIMATORS = [FeatureStandardizer(), SquaredHingeSVC()]
