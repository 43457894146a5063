"""The six dictionaries of the paper: SC, OMP, GSVQ, NKM, RP and R.

Atoms are rows, as in scikit-learn: ``learn_dictionary(X, method) -> (n_atoms, n_features)``.
Defaults follow the authors' reference implementation (``../shared/reference/
dlsr-reference-facts.md``):

- SC and OMP: online dictionary learning (Mairal, Bach, Ponce and Sapiro, "Online Learning for
  Matrix Factorization and Sparse Coding", JMLR 2010): 1,000 mini-batches of 1,000 patches
  (about ten passes over 100,000 patches), atoms constrained to ``||d|| <= 1``, initialised
  from random patches; lasso coding (:func:`dlsr.coding.lasso`) for SC, OMP coding
  (:func:`dlsr.coding.omp`) for OMP. The sufficient statistics use the mini-batch weighting of
  Mairal et al. section 3.4.3 (``beta = (theta + 1 - eta) / (theta + 1)``); the dictionary update is
  one pass of block coordinate descent per mini-batch, warm-started; an atom that no code uses
  yet is re-drawn from the batch.
- GSVQ (gain-shape vector quantisation): random unit atoms; each patch goes to
  ``argmax |d . x|``; each atom becomes the sum of ``(d . x) x`` over its patches, normalised;
  atoms with a tiny norm are re-drawn; 100 iterations.
- NKM: k-means with 100 full Lloyd iterations, random initialisation (Gaussian, scale 0.1, as
  Coates and Ng), empty clusters reset to random patches (a patch nearest to several identical
  centroids joins the first, whatever the rounding); the dictionary is the normalised
  centroids, and the un-normalised ones are kept for the natural (triangle) encoder.
- RP: random patches, normalised. R: random Gaussian atoms, normalised.

Choices the reference leaves open, as named parameters: ``lam=1.0`` for SC (the middle of the
lasso grid {0.5, 1, 1.5, 2}) and ``n_nonzero=10`` for OMP (in the grid {1, 5, 10, 15}).
Everything is deterministic for a given ``random_state``.
"""

from __future__ import annotations

import os

import numpy as np
from scipy import sparse
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils import check_random_state
from sklearn.utils.validation import check_is_fitted, validate_data

from ._dense import check_finite
from .coding import lasso, natural_encoder, omp

__all__ = [
    "METHODS",
    "learn_dictionary",
    "online_dictionary_learning",
    "kmeans",
    "gsvq",
    "random_patches",
    "random_atoms",
    "LearnedDictionary",
    "DictionaryLearner",
    "ESTIMATORS",
]

METHODS = ("SC", "OMP", "GSVQ", "NKM", "RP", "R")


def _check_X(X):
    X = np.asarray(X)
    if X.ndim != 2 or X.shape[0] == 0 or X.shape[1] == 0:
        raise ValueError(f"X must be a non-empty 2-D array (n_patches, n_features), got {X.shape}")
    check_finite(X, "X")  # before any product
    return X


def _normalise_rows(D, rng=None):
    """Unit rows; rows with a tiny norm are re-drawn as random Gaussian unit vectors."""
    D = np.array(D, dtype=np.float64)
    norms = np.linalg.norm(D, axis=1)
    tiny = norms <= 1e-10 * max(norms.max(initial=0.0), 1e-300)
    if np.any(tiny):
        rng = check_random_state(rng)
        D[tiny] = rng.standard_normal((int(tiny.sum()), D.shape[1]))
        norms[tiny] = np.linalg.norm(D[tiny], axis=1)
    return D / norms[:, None]


def random_atoms(n_atoms, n_features, random_state=None):
    """R: random Gaussian atoms, normalised, shape (n_atoms, n_features)."""
    rng = check_random_state(random_state)
    return _normalise_rows(rng.standard_normal((n_atoms, n_features)), rng)


def random_patches(X, n_atoms, random_state=None):
    """RP: random patches (rows of ``X``), normalised; without replacement when possible.

    Zero patches are skipped while enough non-zero ones remain.
    """
    X = _check_X(X)
    rng = check_random_state(random_state)
    nz = np.flatnonzero(np.linalg.norm(X, axis=1) > 0)
    pool = nz if nz.size >= n_atoms else np.arange(X.shape[0])
    replace = pool.size < n_atoms
    idx = rng.choice(pool, size=n_atoms, replace=replace)
    D = np.asarray(X[idx], dtype=np.float64)
    if replace:  # repeated rows: break exact ties so the atoms stay distinct
        D = D + 1e-6 * rng.standard_normal(D.shape) * max(np.abs(D).max(), 1.0)
    return _normalise_rows(D, rng)


def gsvq(X, n_atoms, n_iter=100, random_state=None):
    """Gain-shape vector quantisation (reference semantics, see the module docstring).

    Parameters
    ----------
    X : array-like of shape (n, p)
    n_atoms : int
    n_iter : int
    random_state : int, RandomState, Generator or None

    Returns
    -------
    D : ndarray of shape (n_atoms, p), unit rows
    """
    X = _check_X(X)
    rng = check_random_state(random_state)
    n, p = X.shape
    X32 = np.asarray(X, dtype=np.float32)
    D = random_atoms(n_atoms, p, rng).astype(np.float32)
    rows = np.arange(n)
    for _ in range(n_iter):
        P = X32 @ D.T
        j = np.argmax(np.abs(P), axis=1)
        s = P[rows, j]
        S = sparse.csr_matrix((s, (j, rows)), shape=(n_atoms, n))
        D = np.asarray(S @ X32, dtype=np.float64)
        D = _normalise_rows(D, rng).astype(np.float32)
    return D.astype(np.float64)


def kmeans(X, n_clusters, n_iter=100, random_state=None, init_scale=0.1):
    """k-means with full Lloyd iterations (reference semantics, see the module docstring).

    Parameters
    ----------
    X : array-like of shape (n, p)
    n_clusters : int
    n_iter : int
        Lloyd iterations, all run (no tolerance).
    random_state : int, RandomState, Generator or None
    init_scale : float
        Initial centroids are ``init_scale * N(0, 1)`` (Coates and Ng).

    Returns
    -------
    centroids : ndarray of shape (n_clusters, p), float64
        Un-normalised.
    labels : ndarray of shape (n,), int
    inertia : float
        Sum of squared distances to the assigned centroids (after the last update).
    """
    X = _check_X(X)
    rng = check_random_state(random_state)
    n, p = X.shape
    X32 = np.asarray(X, dtype=np.float32)
    x2 = np.einsum("np,np->n", X32, X32, dtype=np.float64)
    C = (init_scale * rng.standard_normal((n_clusters, p))).astype(np.float32)
    rows = np.arange(n)
    labels = np.zeros(n, dtype=np.int64)
    for _ in range(n_iter):
        labels = _assign(X32, C)
        counts = np.bincount(labels, minlength=n_clusters)
        S = sparse.csr_matrix((np.ones(n, np.float32), (labels, rows)), shape=(n_clusters, n))
        sums = np.asarray(S @ X32, dtype=np.float64)
        C = np.empty((n_clusters, p), dtype=np.float64)
        full = counts > 0
        C[full] = sums[full] / counts[full, None]
        if not np.all(full):  # empty clusters: reset to random patches
            C[~full] = X32[rng.randint(0, n, size=int((~full).sum()))]
        C = C.astype(np.float32)
    labels = _assign(X32, C)
    C64 = C.astype(np.float64)
    d2 = x2 - 2 * np.einsum("np,np->n", X32, C[labels], dtype=np.float64)
    d2 += np.einsum("kp,kp->k", C64, C64)[labels]
    return C64, labels, float(np.maximum(d2, 0).sum())


def _assign(X32, C, chunk=16384):
    """Nearest centroid of each row; a tie between identical centroids goes to the first.

    The distances of identical centroids differ by rounding only, and that rounding depends
    on the BLAS kernels and on each centroid's place in the product, so ``argmin`` alone would
    give the rows to either copy depending on the machine (two empty clusters can be reset to
    the same patch). The rows go to the first copy; the others end empty and are reset.
    """
    c2 = 0.5 * np.einsum("kp,kp->k", C, C)
    out = np.empty(X32.shape[0], dtype=np.int64)
    Ct = np.ascontiguousarray(C.T)
    for s in range(0, X32.shape[0], chunk):
        z = X32[s : s + chunk] @ Ct
        np.subtract(c2, z, out=z)
        out[s : s + chunk] = np.argmin(z, axis=1)
    _, first, copy_of = np.unique(C, axis=0, return_index=True, return_inverse=True)
    if first.size < C.shape[0]:  # identical centroids: O(k p log k), nothing when all differ
        out = first[copy_of.ravel()][out]
    return out


def online_dictionary_learning(X, n_atoms, coding="lasso", *, lam=1.0, n_nonzero=10,
                               batch_size=1000, n_batches=1000, random_state=None, n_jobs=None):
    """Online dictionary learning (Mairal et al. 2010) with lasso or OMP coding.

    Parameters
    ----------
    X : array-like of shape (n, p)
    n_atoms : int
    coding : {"lasso", "omp"}
    lam : float
        Lasso penalty (``coding="lasso"``).
    n_nonzero : int
        OMP atoms per patch (``coding="omp"``).
    batch_size, n_batches : int
        Mini-batches are drawn by passing over random permutations of the patches.
    random_state : int, RandomState, Generator or None
    n_jobs : int, optional
        Threads for the coding step.

    Returns
    -------
    D : ndarray of shape (n_atoms, p), rows with ``||d|| <= 1``
    """
    X = _check_X(X)
    if coding not in ("lasso", "omp"):
        raise ValueError(f"coding must be 'lasso' or 'omp', got {coding!r}")
    rng = check_random_state(random_state)
    n, p = X.shape
    X32 = np.asarray(X, dtype=np.float32)
    D = random_patches(X32, n_atoms, rng)
    A = np.zeros((n_atoms, n_atoms))
    Bm = np.zeros((p, n_atoms))
    eta = min(batch_size, n)
    workers = 1 if n_jobs is None else (os.cpu_count() or 1) if n_jobs < 0 else int(n_jobs)
    chunk = -(-eta // max(workers, 1))  # one chunk per worker thread
    order = rng.permutation(n)
    pos = 0
    for t in range(1, n_batches + 1):
        if pos + eta > n:
            order = rng.permutation(n)
            pos = 0
        Xb = X32[order[pos : pos + eta]]
        pos += eta
        if coding == "lasso":
            C = lasso(Xb, D, lam, n_jobs=n_jobs, chunk_size=chunk, dtype=np.float64)
        else:
            C = omp(Xb, D, n_nonzero, n_jobs=n_jobs, chunk_size=chunk, dtype=np.float64)
        theta = t * eta if t < eta else eta * eta + t - eta
        beta = (theta + 1.0 - eta) / (theta + 1.0)
        A *= beta
        A += C.T @ C / eta
        Bm *= beta
        Bm += Xb.T.astype(np.float64) @ C / eta
        D = _update_dictionary(D, A, Bm, Xb, rng)
    return D


def _update_dictionary(D, A, Bm, Xb, rng):
    """One pass of block coordinate descent on ``0.5 tr(D^T D A) - tr(D^T B)``, ``||d|| <= 1``."""
    D = D.copy()
    diag = np.diag(A)
    scale = diag.max(initial=0.0)
    for j in range(D.shape[0]):
        if diag[j] <= 1e-10 * max(scale, 1e-300):  # unused atom: re-draw from the batch
            dj = Xb[rng.randint(0, Xb.shape[0])].astype(np.float64)
            nrm = np.linalg.norm(dj)
            dj = dj / nrm if nrm > 0 else rng.standard_normal(D.shape[1])
            D[j] = dj / max(np.linalg.norm(dj), 1.0)
        else:
            u = (Bm[:, j] - A[j] @ D) / diag[j] + D[j]
            D[j] = u / max(np.linalg.norm(u), 1.0)
    return D


class LearnedDictionary(np.ndarray):
    """A learned dictionary: an ``(n_atoms, n_features)`` array that also carries what its
    natural encoder needs.

    Returned by :func:`learn_dictionary`; use it as a plain array. Arrays derived from it
    (slices, arithmetic) drop the extra attributes (None).

    Attributes
    ----------
    components : ndarray of shape (n_atoms, n_features)
        The atoms as a plain array.
    centroids : ndarray of shape (n_atoms, n_features) or None
        NKM: the un-normalised centroids (its triangle encoder's).
    natural_param : float, int or None
        The natural encoder's parameter: SC's lambda, OMP's L, GSVQ's L = 1, RP/R's threshold 0.
    method : str or None
    """

    def __new__(cls, components, centroids=None, natural_param=None, method=None):
        obj = np.asarray(components, dtype=np.float64).view(cls)
        obj.centroids = centroids
        obj.natural_param = natural_param
        obj.method = method
        return obj

    def __array_finalize__(self, obj):
        self.centroids = None
        self.natural_param = None
        self.method = None

    @property
    def components(self):
        return self.view(np.ndarray)


_NATURAL_PARAM = {"GSVQ": 1, "RP": 0.0, "R": 0.0, "NKM": None}


def learn_dictionary(X, method, n_atoms=300, random_state=None, *, lam=1.0, n_nonzero=10,
                     n_iter=None, batch_size=1000, n_jobs=None, return_centroids=False):
    """Learn one of the six dictionaries.

    Parameters
    ----------
    X : array-like of shape (n, p)
        Whitened (re-masked) patches, masked entries 0.
    method : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}
    n_atoms : int, default=300
    random_state : int, RandomState, Generator or None
    lam : float, default=1.0
        SC's lasso penalty.
    n_nonzero : int, default=10
        OMP's atoms per patch.
    n_iter : int, optional
        Mini-batches (SC, OMP; default 1000) or iterations (GSVQ, NKM; default 100).
    batch_size : int, default=1000
    n_jobs : int, optional
        Threads for the SC / OMP coding step.
    return_centroids : bool
        NKM only: also return the un-normalised centroids.

    Returns
    -------
    D : LearnedDictionary of shape (n_atoms, p), float64
        An ndarray subclass that also carries ``centroids`` (NKM) and ``natural_param``.
    centroids : ndarray of shape (n_atoms, p)
        Only with ``return_centroids=True``.
    """
    X = _check_X(X)
    if method not in METHODS:
        raise ValueError(f"unknown dictionary method {method!r}; expected one of {METHODS}")
    if int(n_atoms) != n_atoms or n_atoms < 1:
        raise ValueError(f"n_atoms must be a positive integer, got {n_atoms}")
    if return_centroids and method != "NKM":
        raise ValueError("return_centroids is only meaningful for method='NKM'")
    rng = check_random_state(random_state)
    n_atoms = int(n_atoms)
    if method in ("SC", "OMP"):
        D = online_dictionary_learning(
            X, n_atoms, "lasso" if method == "SC" else "omp", lam=lam, n_nonzero=n_nonzero,
            batch_size=batch_size, n_batches=1000 if n_iter is None else n_iter,
            random_state=rng, n_jobs=n_jobs)
    elif method == "GSVQ":
        D = gsvq(X, n_atoms, 100 if n_iter is None else n_iter, rng)
    elif method == "NKM":
        C, _, _ = kmeans(X, n_atoms, 100 if n_iter is None else n_iter, rng)
        D = LearnedDictionary(_normalise_rows(C, rng), centroids=C, method=method)
        if return_centroids:
            return D, C
        return D
    elif method == "RP":
        D = random_patches(X, n_atoms, rng)
    else:
        D = random_atoms(n_atoms, X.shape[1], rng)
    param = {"SC": lam, "OMP": n_nonzero}.get(method, _NATURAL_PARAM.get(method))
    return LearnedDictionary(D, natural_param=param, method=method)


class DictionaryLearner(TransformerMixin, BaseEstimator):
    """Learn one of the six dictionaries; ``transform`` applies its natural encoder.

    Parameters
    ----------
    method : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}
    n_atoms : int, default=300
    lam : float, default=1.0
        SC's penalty (also its natural encoder's).
    n_nonzero : int, default=10
        OMP's atoms per patch (also its natural encoder's).
    n_iter : int, optional
        See :func:`learn_dictionary`.
    batch_size : int, default=1000
    random_state : int, RandomState, Generator or None
    n_jobs : int, optional

    Attributes
    ----------
    components_ : ndarray of shape (n_atoms, n_features)
        The dictionary, atoms as rows.
    centroids_ : ndarray of shape (n_atoms, n_features)
        NKM only: the un-normalised centroids (the natural encoder's).
    n_features_in_ : int
    """

    def __init__(self, method="SC", n_atoms=300, *, lam=1.0, n_nonzero=10, n_iter=None,
                 batch_size=1000, random_state=None, n_jobs=None):
        self.method = method
        self.n_atoms = n_atoms
        self.lam = lam
        self.n_nonzero = n_nonzero
        self.n_iter = n_iter
        self.batch_size = batch_size
        self.random_state = random_state
        self.n_jobs = n_jobs

    def fit(self, X, y=None):
        """Learn the dictionary.

        Parameters
        ----------
        X : array-like of shape (n, p)
        y : ignored

        Returns
        -------
        self
        """
        X = validate_data(self, X, dtype=[np.float64, np.float32])
        out = learn_dictionary(X, self.method, self.n_atoms, self.random_state, lam=self.lam,
                               n_nonzero=self.n_nonzero, n_iter=self.n_iter,
                               batch_size=self.batch_size, n_jobs=self.n_jobs,
                               return_centroids=self.method == "NKM")
        if self.method == "NKM":
            D, self.centroids_ = out
        else:
            D = out
        self.components_ = np.asarray(D).view(np.ndarray)
        self.n_components_ = self.components_.shape[0]
        return self

    def transform(self, X, mask=None):
        """Codes of the natural encoder (see :func:`dlsr.coding.natural_encoder`).

        Parameters
        ----------
        X : array-like of shape (n, p)
        mask : array-like of shape (n, p), bool, optional
            GSVQ's masked OMP only (all valid when omitted).

        Returns
        -------
        ndarray of shape (n, 2 n_atoms), or (n, n_atoms) for NKM, float32
        """
        check_is_fitted(self, "components_")
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        enc = natural_encoder(self, n_jobs=self.n_jobs)
        if mask is not None and not enc.masked:
            raise ValueError(f"the natural encoder of {self.method} takes no mask")
        return enc.transform(X, mask=mask) if enc.masked else enc.transform(X)


ESTIMATORS = [
    DictionaryLearner(method=m, n_atoms=6, n_iter=5, batch_size=20, random_state=0)
    for m in METHODS
]
"""Small instances of every estimator here, for ``parametrize_with_checks``."""
