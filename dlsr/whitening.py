"""Per-patch group standardisation and ZCA whitening with validity masks.

As in the authors' reference implementation (Trottier, Giguère and Chaib-draa 2016;
``shared/reference/dlsr-reference-facts.md``):

* **Standardisation** is per patch over four channel groups - K; R, G, B together; D; the three
  normals together: masked mean and masked variance (``ddof=1``) over the valid entries of the
  group, ``(x - mean) / sqrt(var + 1e-4)``, masked entries set to 0. A group with fewer than two
  valid entries has no variance estimate: its variance is taken as 0 (so a single valid entry
  becomes 0) and an empty group stays 0; no NaN is produced.
* **ZCA**: mean per dimension over the valid entries; covariance (``ddof=1``, about the
  complete patches' own mean, like MATLAB's ``cov``) from the fully valid patches only;
  ``P = V diag(1 / sqrt(eig + epsilon)) V^T`` with ``epsilon = 0.1`` (Coates and Ng); output
  ``(x - mean) P``, then re-masked (masked entries set to 0). The masked entries of ``x`` enter
  the product as they are (0 after standardisation), as in the reference.

Flattened patches follow :mod:`dlsr.patches`: the channel of feature ``j`` is ``j % 8``.
A number of features that is not a multiple of 8 is accepted (the last pixel is then partial)
so that the transformers work on generic data and pass scikit-learn's common checks.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, OneToOneFeatureMixin, TransformerMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from . import _threads
from ._dense import check_finite, standardize_rows

__all__ = [
    "CHANNEL_GROUPS",
    "standardize_patches",
    "fit_zca",
    "apply_zca",
    "PatchStandardizer",
    "ZCAWhitening",
    "ESTIMATORS",
]

#: Channel groups standardised together: K; RGB; D; normals.
CHANNEL_GROUPS = ((0,), (1, 2, 3), (4,), (5, 6, 7))
_N_CHANNELS = 8
_GROUP_OF_CHANNEL = np.array([g for g, chans in enumerate(CHANNEL_GROUPS) for _ in chans])
_CHUNK = 65536


def _check_xm(X, M, name="X"):
    X = np.asarray(X)
    if not np.issubdtype(X.dtype, np.floating):
        X = X.astype(np.float64)
    # before any product: what BLAS does with NaN or inf depends on its kernels (a warning on
    # some, none on others); masked entries too (they enter the ZCA product as they are)
    check_finite(X, name)
    if M is None:
        M = np.ones(X.shape, dtype=bool)
    else:
        M = np.asarray(M)
        if M.shape != X.shape:
            raise ValueError(f"mask shape {M.shape} does not match {name} shape {X.shape}")
        M = M.astype(bool, copy=False)
    return X, M


def _feature_groups(n_features):
    """Channel group (index into :data:`CHANNEL_GROUPS`) of each feature, int64."""
    return _GROUP_OF_CHANNEL[np.arange(n_features) % _N_CHANNELS].astype(np.int64)


def standardize_patches(X, M=None, eps: float = 1e-4):
    """Per-patch, per-channel-group masked standardisation.

    Parameters
    ----------
    X : array-like of shape (..., n_features)
        Flattened patches (288 = 6 x 6 x 8 values), any leading shape.
    M : array-like of the same shape, bool, or None
        Validity; None means all valid.
    eps : float, default=1e-4
        Added to the variance.

    Returns
    -------
    ndarray of the same shape and floating dtype as ``X`` (float64 for integer input)
        Within each patch and group, valid entries have mean 0 and (``ddof=1``) variance
        ``var / (var + eps)``; masked entries are 0.

    Raises
    ------
    ValueError
        If ``X`` holds a NaN or an infinity (masked entries included: masked values are 0 by
        the project's conventions), naming the first bad row.
    """
    X, M = _check_xm(X, M)
    shape = X.shape
    p = shape[-1]
    dtype = X.dtype
    X2 = np.ascontiguousarray(X.reshape(-1, p))
    M2 = np.ascontiguousarray(M.reshape(-1, p), dtype=bool)
    g = _feature_groups(p)
    out = np.empty(X2.shape, dtype=dtype)
    standardize_rows(X2, M2, g, len(CHANNEL_GROUPS), float(eps), out)
    return out.reshape(shape)


def fit_zca(X, M=None, epsilon: float = 0.1):
    """Fit ZCA whitening on masked patches.

    Parameters
    ----------
    X : array-like of shape (n_samples, n_features)
    M : array-like of the same shape, bool, or None
    epsilon : float, default=0.1
        Added to the eigenvalues of the covariance.

    Returns
    -------
    mean : ndarray of shape (n_features,), float64
        Mean over the valid entries of each dimension (0 where none is valid).
    P : ndarray of shape (n_features, n_features), float64
        Symmetric whitening matrix ``V diag(1 / sqrt(eig + epsilon)) V^T`` of the covariance of
        the fully valid patches.

    Raises
    ------
    ValueError
        If fewer than ``n_features + 1`` patches are fully valid, or ``X`` holds a NaN or an
        infinity (masked entries included).
    """
    X, M = _check_xm(X, M)
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (n_samples, n_features), got shape {X.shape}")
    if not epsilon >= 0:
        raise ValueError(f"epsilon must be >= 0, got {epsilon}")
    n, p = X.shape
    cnt = M.sum(axis=0)
    mean = np.where(M, X, 0.0).sum(axis=0, dtype=np.float64) / np.maximum(cnt, 1)
    full = M.all(axis=1)
    nf = int(full.sum())
    if nf < p + 1:
        raise ValueError(
            f"ZCA needs at least n_features + 1 = {p + 1} fully valid patches to estimate the "
            f"covariance; got {nf} fully valid among {n} sample(s)"
        )
    Xf = X[full].astype(np.float64)
    Xf -= Xf.mean(axis=0)
    # One BLAS thread: the covariance's product and the eigendecomposition sum in another
    # order with two threads (P differed by 1e-13), so a model would depend on where it was
    # trained (the main process, a worker, a machine with more cores). 0.1-0.3 s.
    with _threads.one_blas_thread():
        cov = (Xf.T @ Xf) / (nf - 1)
        eig, V = np.linalg.eigh(cov)
        eig = np.clip(eig, 0.0, None)
        P = (V / np.sqrt(eig + epsilon)) @ V.T
    P = (P + P.T) / 2
    return mean, P


def apply_zca(X, M, mean, P):
    """Whiten patches: ``(x - mean) P``, re-masked.

    Parameters
    ----------
    X : array-like of shape (..., n_features)
    M : array-like of the same shape, bool, or None
    mean : array-like of shape (n_features,)
    P : array-like of shape (n_features, n_features)

    Returns
    -------
    ndarray of the same shape and floating dtype as ``X``; masked entries are 0.

    Raises
    ------
    ValueError
        If ``X`` (masked entries included: they enter the product), ``mean`` or ``P`` holds a
        NaN or an infinity; checked before the product.
    """
    X, M = _check_xm(X, M)
    mean = np.asarray(mean)
    P = np.asarray(P)
    p = X.shape[-1]
    if mean.shape != (p,) or P.shape != (p, p):
        raise ValueError(
            f"mean {mean.shape} and P {P.shape} do not fit {p} features"
        )
    check_finite(mean, "the ZCA mean")
    check_finite(P, "the ZCA matrix P")
    dtype = X.dtype
    X2 = X.reshape(-1, p)
    M2 = M.reshape(-1, p)
    mean_t = mean.astype(dtype)
    P_t = P.astype(dtype)
    out = np.empty(X2.shape, dtype=dtype)
    for s in range(0, len(X2), _CHUNK):
        y = (X2[s:s + _CHUNK] - mean_t) @ P_t
        y[~M2[s:s + _CHUNK]] = 0
        out[s:s + _CHUNK] = y
    return out.reshape(X.shape)


def _validate_mask(mask, X, est):
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.shape != X.shape:
        raise ValueError(
            f"{type(est).__name__}: mask shape {mask.shape} does not match X shape {X.shape}"
        )
    return mask.astype(bool, copy=False)


class _MaskedPatchTransformer(OneToOneFeatureMixin, TransformerMixin, BaseEstimator):
    """What both patch transformers share: the mask reaches ``transform`` from ``fit_transform``
    (scikit-learn's default would drop it), and float32 stays float32."""

    def fit_transform(self, X, y=None, mask=None):
        """``fit(X, mask=mask).transform(X, mask=mask)``."""
        return self.fit(X, y, mask=mask).transform(X, mask=mask)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.transformer_tags.preserves_dtype = ["float64", "float32"]
        return tags


class PatchStandardizer(_MaskedPatchTransformer):
    """Per-patch group standardisation (:func:`standardize_patches`) as a transformer.

    Stateless: ``fit`` only records the number of features.

    Parameters
    ----------
    eps : float, default=1e-4
        Added to each group's variance.

    Attributes
    ----------
    n_features_in_ : int
    """

    def __init__(self, eps=1e-4):
        self.eps = eps

    def fit(self, X, y=None, mask=None):
        """Validate ``X`` (and ``mask``, None meaning all valid)."""
        X = validate_data(self, X, dtype=[np.float64, np.float32])
        _validate_mask(mask, X, self)
        if not self.eps > 0:
            raise ValueError(f"eps must be > 0, got {self.eps}")
        return self

    def transform(self, X, mask=None):
        """Standardise ``X`` of shape (n_samples, n_features) with its validity ``mask``."""
        check_is_fitted(self)
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        mask = _validate_mask(mask, X, self)
        return standardize_patches(X, mask, eps=self.eps)



class ZCAWhitening(_MaskedPatchTransformer):
    """Masked ZCA whitening (:func:`fit_zca`, :func:`apply_zca`) as a transformer.

    Parameters
    ----------
    epsilon : float, default=0.1
        Added to the covariance eigenvalues.

    Attributes
    ----------
    mean_ : ndarray of shape (n_features,)
        Mean over the valid entries of each dimension.
    whitening_ : ndarray of shape (n_features, n_features)
        The symmetric matrix ``P``; ``transform`` returns ``(x - mean_) P``, re-masked.
    n_features_in_ : int
    """

    def __init__(self, epsilon=0.1):
        self.epsilon = epsilon

    def fit(self, X, y=None, mask=None):
        """Fit on ``X`` (n_samples, n_features) with validity ``mask`` (None: all valid)."""
        X = validate_data(self, X, dtype=[np.float64, np.float32])
        mask = _validate_mask(mask, X, self)
        self.mean_, self.whitening_ = fit_zca(X, mask, epsilon=self.epsilon)
        return self

    def transform(self, X, mask=None):
        """Whiten ``X`` (n_samples, n_features) and zero its masked entries."""
        check_is_fitted(self)
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        mask = _validate_mask(mask, X, self)
        return apply_zca(X, mask, self.mean_, self.whitening_)



#: Default instances for the shared ``parametrize_with_checks`` test.
ESTIMATORS = [PatchStandardizer(), ZCAWhitening()]
