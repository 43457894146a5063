"""Encoding whitened patches against a representation: one computation per (method, masked)
for every encoder and parameter that reads it (:func:`encode_patches_multi`, and
:func:`iter_codes` for callers that pool each computation's codes as soon as it is done)."""

from __future__ import annotations

import time

import numpy as np

from .. import coding
from .base import ENCODERS, N_CHANNELS, PATCH_SIZE
from .representation import Representation

__all__ = ["encode_patches", "encode_patches_grid", "encode_patches_multi", "encoder_plan",
           "code_plans", "iter_codes"]


# The computation behind each encoder's grid: (method, masked); Natural depends on the learner.
_ENCODER_METHOD = {
    "SC": ("lasso", False),
    "mSC": ("lasso", True),
    "OMP": ("omp", False),
    "mOMP": ("omp", True),
    "ST": ("threshold", False),
}


def encoder_plan(rep: Representation, encoder: str, params):
    """``(method, masked, values, polarity)`` of an encoder's grid on ``rep``.

    Natural becomes its learner's computation (:func:`dlsr.coding.natural_spec`), so that, for
    example, SC-Natural reads the SC lasso path at the dictionary's lambda and RP-Natural the
    soft threshold's projection.
    """
    params = list(params)
    if encoder == "Natural":
        spec = coding.natural_spec(rep.learner, rep.natural_param)
        return spec["method"], spec["masked"], [spec["value"]] * len(params), spec["polarity"]
    if encoder not in _ENCODER_METHOD:
        raise ValueError(f"unknown encoder {encoder!r}; choose from {ENCODERS}")
    method, masked = _ENCODER_METHOD[encoder]
    values = [int(v) for v in params] if method == "omp" else [float(v) for v in params]
    return method, masked, values, True


def _padding_masks(M):
    """Each flattened patch's padding pattern: its K channel's mask (the image mask, padding
    only; the depth and normal channels add the depth holes to it) on every channel, joined
    with the patch's own mask so that it contains it. Patches of a rectangle's padded border
    share it; the masked lasso and OMP start their Gram columns from its Gram matrix
    (:func:`dlsr.coding.lasso_path`, ``base_mask``)."""
    M = np.asarray(M, dtype=bool)
    if M.shape[1] != PATCH_SIZE * PATCH_SIZE * N_CHANNELS:
        return None  # not the paper's patches: no known padding channel
    image = M[:, 0::N_CHANNELS]  # channels last: (row, column, channel) flattened
    return np.repeat(image, N_CHANNELS, axis=1) | M


def _method_codes(X, M, rep: Representation, method: str, masked: bool, values,
                  correlations=None, gram_cache=None) -> list:
    """Codes of one computation for each of ``values`` (in that order), unsplit.

    ``correlations``, optional, is ``X @ D.T`` in float64, shared by the lasso and OMP
    computations (masked or not: masked entries of ``X`` are 0); ``gram_cache``, optional, the
    masked Gram matrices shared by the masked lasso and OMP.
    """
    D = rep.dictionary
    mask = M if masked else None
    base = _padding_masks(M) if masked and method in ("lasso", "omp") else None
    if method == "lasso":
        return list(coding.lasso_path(X, D, values, mask=mask, correlations=correlations,
                                      gram_cache=gram_cache, base_mask=base))
    if method == "omp":
        return list(coding.omp_path(X, D, values, mask=mask, correlations=correlations,
                                    gram_cache=gram_cache, base_mask=base))
    if method == "threshold":
        return list(coding.soft_threshold_path(X, D, values))
    atoms = rep.centroids if rep.centroids is not None else D
    return [coding.kmeans_triangle(X, atoms)] * len(values)


def encode_patches_multi(X, M, rep: Representation, grids: dict, polarity: bool = True,
                         cpu_seconds: dict | None = None) -> dict:
    """Encode preprocessed patches for several encoders, each computation done once.

    Encoders that share a computation share it: SC and SC-Natural one lasso path, OMP and
    OMP-Natural one OMP run, mOMP and GSVQ-Natural one masked OMP run, ST and RP/R-Natural one
    matrix product. One homotopy path gives every lasso penalty
    (:func:`dlsr.coding.lasso_path`) and one OMP run every number of atoms
    (:func:`dlsr.coding.omp_path`), so a grid costs about as much as its most expensive member.

    Parameters
    ----------
    X : ndarray of shape (m, 288)
        Standardised (and whitened) patches, masked entries 0.
    M : ndarray of shape (m, 288), bool
    rep : Representation
    grids : dict
        ``{encoder: params}``, encoders from :data:`ENCODERS`: lambdas for SC/mSC/ST, numbers
        of non-zeros for OMP/mOMP; Natural ignores its params (its parameter is the
        dictionary's) and gets the same array for each.
    polarity : bool
        Polarity splitting ``[max(a, 0), max(-a, 0)]`` (never for NKM-Natural).
    cpu_seconds : dict or None
        When given, the process CPU seconds of each computation are added under
        ``(method, masked)``.

    Returns
    -------
    dict
        ``{encoder: list of ndarray of shape (m, k)}``, one array per parameter, ``k = 2 *
        n_atoms`` with polarity splitting, else ``n_atoms``. Encoders sharing a code array share
        the same object.
    """
    plans, needed = code_plans(rep, grids)
    codes: dict = {}
    for done in iter_codes(X, M, rep, needed, cpu_seconds):
        codes.update(done)
    split: dict = {}
    out = {}
    for enc, keys in plans.items():
        arrays = []
        for key in keys:
            if key not in split:
                A = codes[key[:3]]
                split[key] = coding.polarity_split(A) if polarity and key[3] else A
            arrays.append(split[key])
        out[enc] = arrays
    return out


def code_plans(rep, grids):
    """What the encoders of ``grids`` read: ``plans`` (per encoder, one key ``(method, masked,
    value, split)`` per parameter) and ``needed`` (``(method, masked)`` -> the values its
    computation must give, each once)."""
    plans = {}
    needed: dict = {}
    for enc, params in grids.items():
        method, masked, values, pol = encoder_plan(rep, enc, params)
        plans[enc] = [(method, masked, v, pol) for v in values]
        bucket = needed.setdefault((method, masked), [])
        bucket.extend(v for v in values if v not in bucket)
    return plans, needed


def iter_codes(X, M, rep, needed, cpu_seconds):
    """Unsplit codes of each computation in ``needed`` (:func:`code_plans`), each computed once
    and yielded as soon as it is done: a dict ``(method, masked, value)`` -> codes per
    computation, so that a caller can pool and drop them before the next one (the codes of a
    chunk of every computation together are about 26 MB per computation and value).

    A fully valid patch's masked lasso (penalty scaled by ``||m||_0 / p = 1``) and masked OMP
    are the unmasked problems, so when both the masked and the unmasked computation of a
    method are needed, the unmasked one also records the masked grid's values (snapshots of
    the same lasso path, or the same OMP run) and the masked one solves only the patches with
    a masked entry. The fully valid patches' masked codes are then the unmasked ones: the same
    problem, solved with the Gram matrix ``D D^T`` (BLAS ``syrk``) instead of the masked group's
    ``(D diag(1)) D^T`` (``gemm``), which differ in their last bits. Only those recorded codes
    are kept here until the masked computation has used them.
    """
    from .._dense import check_finite

    check_finite(X, "the patches X")  # before the shared product below (kernel-dependent)
    # masked lasso / OMP whose unmasked partner runs too: the partner codes the fully valid rows
    paired = {meth for meth, masked in needed
              if masked and meth in ("lasso", "omp") and (meth, False) in needed}
    full = np.all(np.asarray(M, dtype=bool), axis=1) if paired else None
    partner: dict = {}  # the unmasked codes of the masked values, until the masked run
    grams: dict = {}  # the masked Gram matrices of mask groups, for the masked lasso and OMP
    B = None  # X @ D.T in float64, computed once for every lasso and OMP computation
    zero_masked = None  # masked ones too, when the masked entries of X are 0 (they should be)
    # a method's unmasked computation just before its masked one, whose fully valid rows it
    # codes: its codes (one block for all values) are dropped once the masked one has run
    for (method, masked), values in sorted(needed.items()):
        c0 = time.process_time()
        shared = None
        if method in ("lasso", "omp"):
            if masked and zero_masked is None:
                zero_masked = not np.any(X[~np.asarray(M, dtype=bool)])
            if not masked or zero_masked:
                if B is None:
                    D64 = np.asarray(rep.dictionary, dtype=np.float64)
                    B = np.asarray(X, dtype=np.float64) @ D64.T
                shared = B
        if method in paired and not masked:
            run = list(dict.fromkeys([*values, *needed[(method, True)]]))
            done = {(method, False, v): A for v, A in
                    zip(run, _method_codes(X, M, rep, method, False, run, shared), strict=True)}
            partner.update({(method, False, v): done[(method, False, v)]
                            for v in needed[(method, True)]})
            done = {(method, False, v): done[(method, False, v)] for v in values}
        elif method in paired:
            done = _masked_with_full_rows(X, M, rep, method, values, shared, grams, full,
                                          partner)
            for v in values:
                partner.pop((method, False, v), None)
        else:
            done = {(method, masked, v): A for v, A in
                    zip(values, _method_codes(X, M, rep, method, masked, values, shared,
                                              grams if masked else None), strict=True)}
        if cpu_seconds is not None:
            key = (method, masked)
            cpu_seconds[key] = cpu_seconds.get(key, 0.0) + time.process_time() - c0
        yield done
        del done  # not held through the next computation


def _masked_with_full_rows(X, M, rep, method, values, shared, grams, full, codes) -> dict:
    """Masked codes for ``values``: the fully valid rows (``full``) from the unmasked
    computation's ``codes`` (which recorded ``values``), the others solved masked."""
    rest = np.flatnonzero(~full)
    out = {}
    for v in values:
        A = codes[(method, False, v)].copy()  # right for the fully valid rows
        out[(method, True, v)] = A
    if rest.size:
        sub = _method_codes(X[rest], M[rest], rep, method, True, values,
                            None if shared is None else shared[rest], grams)
        for v, A in zip(values, sub, strict=True):
            out[(method, True, v)][rest] = A
    return out


def encode_patches_grid(X, M, rep: Representation, encoder: str, params,
                        polarity: bool = True) -> list[np.ndarray]:
    """Encode preprocessed patches for several values of one encoder's parameter.

    See :func:`encode_patches_multi` (this is its one-encoder case).

    Returns
    -------
    list of ndarray of shape (m, k), one per parameter
    """
    return encode_patches_multi(X, M, rep, {encoder: params}, polarity)[encoder]


def encode_patches(X, M, rep: Representation, encoder: str, param=None, polarity: bool = True):
    """Encode preprocessed patches.

    Parameters
    ----------
    X : ndarray of shape (m, 288)
        Standardised (and whitened) patches, masked entries 0.
    M : ndarray of shape (m, 288), bool
    rep : Representation
    encoder : {"SC", "mSC", "OMP", "mOMP", "ST", "Natural"}
    param : float or int or None
        lambda for SC/mSC/ST, the number of non-zeros for OMP/mOMP; ignored by Natural.
    polarity : bool
        Polarity splitting ``[max(a, 0), max(-a, 0)]`` (never for NKM-Natural).

    Returns
    -------
    ndarray of shape (m, k)
        ``k = 2 * n_atoms`` with polarity splitting, else ``n_atoms``.
    """
    return encode_patches_grid(X, M, rep, encoder, [param], polarity)[0]
