"""From rectangle images to the paper's feature vectors.

rectangle image (24x24x8 + masks) -> all 19x19 stride-1 6x6x8 patches -> per-patch group
standardisation -> ZCA whitening -> encoding against a learned dictionary -> polarity splitting
-> quadrant sum pooling (rows and columns split 10 | 9) -> one vector per rectangle
(4 * 2 * n_atoms = 2,400 for 300 atoms; 4 * n_atoms = 1,200 for NKM-Natural, which has no
polarity split).

Rectangle images travel through scikit-learn as one 2-D array (see :func:`pack_images`):
``(n, 24 * 24 * 8 * 2)`` float32, the values followed by the masks (1.0 valid, 0.0 masked),
so that ``Pipeline``, ``GridSearchCV``, ``cross_val_score`` and group splitters work unchanged.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils import check_random_state
from sklearn.utils.validation import check_is_fitted, validate_data

from . import coding, dictionaries, patches, whitening
from .memory import reused_heap, small_pages

__all__ = [
    "LEARNERS",
    "ENCODERS",
    "ENCODER_GRIDS",
    "pack_images",
    "unpack_images",
    "quadrant_pool",
    "Representation",
    "fit_representation",
    "encode_patches",
    "encode_patches_grid",
    "encode_patches_multi",
    "rectangle_features",
    "rectangle_features_grid",
    "rectangle_features_multi",
    "DLSRFeatures",
]

LEARNERS = ("SC", "OMP", "GSVQ", "NKM", "RP", "R")
# Encoders in the column order of the paper's Table 1.
ENCODERS = ("SC", "mSC", "OMP", "mOMP", "ST", "Natural")
# Inner-CV grids of the encoder's parameter (reference facts); natural encoders have none.
ENCODER_GRIDS = {
    "SC": (0.5, 1.0, 1.5, 2.0),
    "mSC": (1.0, 2.0, 3.0, 4.0),
    "OMP": (1, 5, 10, 15),
    "mOMP": (1, 5, 10, 15),
    "ST": (0.5, 1.0, 1.5, 2.0),
    "Natural": (None,),
}

IMAGE_SIZE = 24
N_CHANNELS = 8
PATCH_SIZE = 6
POOL_SPLIT = 10


def pack_images(images, masks) -> np.ndarray:
    """Pack rectangle images and masks into one 2-D array for scikit-learn.

    Parameters
    ----------
    images : ndarray of shape (n, 24, 24, 8)
    masks : ndarray of shape (n, 24, 24, 8), bool

    Returns
    -------
    ndarray of shape (n, 9216), float32
    """
    images = np.asarray(images, dtype=np.float32)
    masks = np.asarray(masks, dtype=bool)
    if images.shape != masks.shape or images.ndim != 4:
        raise ValueError(
            f"images and masks must both be (n, H, W, C), got {images.shape} and {masks.shape}"
        )
    n = images.shape[0]
    return np.concatenate([images.reshape(n, -1), masks.reshape(n, -1).astype(np.float32)], 1)


def unpack_images(X, size: int = IMAGE_SIZE, channels: int = N_CHANNELS):
    """Inverse of :func:`pack_images`: ``(images float32, masks bool)``, each (n, size, size, C)."""
    X = np.asarray(X)
    per = size * size * channels
    if X.ndim != 2 or X.shape[1] != 2 * per:
        raise ValueError(
            f"packed rectangle images must have shape (n, {2 * per}) "
            f"(values then masks of {size}x{size}x{channels}), got {X.shape}"
        )
    n = X.shape[0]
    images = X[:, :per].reshape(n, size, size, channels).astype(np.float32, copy=False)
    masks = X[:, per:].reshape(n, size, size, channels) > 0.5
    return images, masks


def quadrant_pool(codes, split: int = POOL_SPLIT) -> np.ndarray:
    """Sum-pool a code map over four quadrants.

    Parameters
    ----------
    codes : ndarray of shape (n, R, C, k)
        Codes of the R x C patch grid (19 x 19 for 24 x 24 images and 6 x 6 patches).
    split : int
        Rows ``[:split]`` / ``[split:]`` and the same for columns (10 | 9, as the authors).

    Returns
    -------
    ndarray of shape (n, 4 * k)
        Quadrants in the order top-left, top-right, bottom-left, bottom-right.
    """
    codes = np.asarray(codes)
    if codes.ndim != 4:
        raise ValueError(f"codes must be (n, rows, cols, k), got {codes.shape}")
    top, bottom = codes[:, :split], codes[:, split:]
    quads = [
        top[:, :, :split].sum(axis=(1, 2)),
        top[:, :, split:].sum(axis=(1, 2)),
        bottom[:, :, :split].sum(axis=(1, 2)),
        bottom[:, :, split:].sum(axis=(1, 2)),
    ]
    return np.concatenate(quads, axis=1)


def _split_pool(codes, polarity: bool, split: int = POOL_SPLIT) -> np.ndarray:
    """``quadrant_pool(polarity_split(codes))`` (or of the codes) in one compiled pass."""
    from ._dense import split_pool

    n, _, _, k = codes.shape
    out = np.empty((n, 4 * k * (2 if polarity else 1)), dtype=np.float32)
    split_pool(np.ascontiguousarray(codes), split, polarity, out)
    return out


@dataclass
class Representation:
    """What unsupervised learning produces: whitening and a dictionary.

    Attributes
    ----------
    learner : str
    dictionary : ndarray of shape (n_atoms, 288)
        Atoms as rows (unit norm except for SC/OMP, whose atoms have norm <= 1).
    centroids : ndarray of shape (n_atoms, 288) or None
        Un-normalised k-means centroids (NKM only; used by its natural triangle encoder).
    zca_mean : ndarray of shape (288,) or None
        None when whitening is off.
    zca_matrix : ndarray of shape (288, 288) or None
    natural_param : float or int or None
        The dictionary's own coding parameter (SC's lambda, OMP's L), used by "Natural".
    """

    learner: str
    dictionary: np.ndarray
    centroids: np.ndarray | None
    zca_mean: np.ndarray | None
    zca_matrix: np.ndarray | None
    natural_param: float | None = None

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        out = {f"{prefix}dictionary": self.dictionary}
        if self.centroids is not None:
            out[f"{prefix}centroids"] = self.centroids
        if self.zca_mean is not None:
            out[f"{prefix}zca_mean"] = self.zca_mean
            out[f"{prefix}zca_matrix"] = self.zca_matrix
        return out

    @classmethod
    def from_arrays(cls, arrays, learner: str, natural_param=None, prefix: str = ""):
        def get(name):
            key = f"{prefix}{name}"
            return np.asarray(arrays[key]) if key in arrays else None

        return cls(
            learner=learner,
            dictionary=get("dictionary"),
            centroids=get("centroids"),
            zca_mean=get("zca_mean"),
            zca_matrix=get("zca_matrix"),
            natural_param=natural_param,
        )


def _preprocess_patches(X, M, rep_or_zca):
    """Standardise and (optionally) whiten flattened patches; masked entries end at 0."""
    X = whitening.standardize_patches(X, M)
    mean, P = rep_or_zca
    if mean is not None:
        X = whitening.apply_zca(X, M, mean, P)
    return X


class _StageClock:
    """Adds the wall seconds since the previous lap to ``seconds[stage]`` (nothing when
    ``seconds`` is None)."""

    def __init__(self, seconds: dict | None):
        self.seconds = seconds
        self.t = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        if self.seconds is not None:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self.t
        self.t = now


def fit_representation(
    images,
    masks,
    learner: str,
    n_atoms: int = 300,
    whiten: bool = True,
    n_patches: int = 100_000,
    min_valid: float = 0.2,
    extra=None,
    random_state=None,
    dictionary_params: dict | None = None,
    rows=None,
    seconds: dict | None = None,
) -> Representation:
    """Learn whitening and a dictionary from random patches of the training rectangles.

    Parameters
    ----------
    images, masks : ndarray of shape (n, 24, 24, 8)
        Training rectangle images only (fold hygiene is the caller's business).
    learner : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}
    n_atoms : int
    whiten : bool
        ZCA whitening (epsilon 0.1) after per-patch standardisation.
    n_patches : int
        Random patches drawn across the rectangles (100,000 in the paper).
    min_valid : float
        A patch is accepted when at least this fraction of its entries is valid.
    extra : tuple (patches, masks) or None
        Extra unlabelled patches (self-taught learning), each ``(m, 6, 6, 8)``.
    random_state : int, Generator, RandomState or None
    dictionary_params : dict or None
        Further keyword arguments of :func:`dlsr.dictionaries.learn_dictionary`.
    rows : array-like of int or None
        Learn from these rectangles only (positions in ``images``): the same representation as
        from ``images[rows]`` and ``masks[rows]``, without copying them. None uses all.
    seconds : dict or None
        When given, the wall seconds of each stage are added under ``"patches"`` (sampling),
        ``"whitening"`` (standardisation and ZCA) and ``"dictionary"`` (learning).

    Returns
    -------
    Representation
    """
    if learner not in LEARNERS:
        raise ValueError(f"unknown learner {learner!r}; choose from {LEARNERS}")
    rs = check_random_state(random_state)
    seeds = rs.randint(0, 2**31 - 1, size=2)
    clock = _StageClock(seconds)
    X, M = patches.sample_patches(
        images, masks, n_patches=n_patches, min_valid=min_valid,
        random_state=int(seeds[0]), extra=extra, rows=rows,
    )
    clock.lap("patches")
    Xs = whitening.standardize_patches(X, M)
    if whiten:
        mean, P = whitening.fit_zca(Xs, M)
        Xw = whitening.apply_zca(Xs, M, mean, P)
    else:
        mean, P = None, None
        Xw = Xs
    clock.lap("whitening")
    learned = dictionaries.learn_dictionary(
        Xw, learner, n_atoms=n_atoms, random_state=int(seeds[1]), **(dictionary_params or {})
    )
    clock.lap("dictionary")
    centroids = None
    natural_param = None
    if isinstance(learned, dictionaries.LearnedDictionary):
        D = learned.components
        centroids = learned.centroids
        natural_param = learned.natural_param
    else:
        D = learned
    return Representation(learner, np.asarray(D, np.float32), centroids, mean, P, natural_param)


# The computation behind each encoder's grid: (method, masked); Natural depends on the learner.
_ENCODER_METHOD = {
    "SC": ("lasso", False),
    "mSC": ("lasso", True),
    "OMP": ("omp", False),
    "mOMP": ("omp", True),
    "ST": ("threshold", False),
}


def _encoder_plan(rep: Representation, encoder: str, params):
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
    plans, needed = _code_plans(rep, grids)
    codes: dict = {}
    for done in _iter_codes(X, M, rep, needed, cpu_seconds):
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


def _code_plans(rep, grids):
    """What the encoders of ``grids`` read: ``plans`` (per encoder, one key ``(method, masked,
    value, split)`` per parameter) and ``needed`` (``(method, masked)`` -> the values its
    computation must give, each once)."""
    plans = {}
    needed: dict = {}
    for enc, params in grids.items():
        method, masked, values, pol = _encoder_plan(rep, enc, params)
        plans[enc] = [(method, masked, v, pol) for v in values]
        bucket = needed.setdefault((method, masked), [])
        bucket.extend(v for v in values if v not in bucket)
    return plans, needed


def _iter_codes(X, M, rep, needed, cpu_seconds):
    """Unsplit codes of each computation in ``needed`` (:func:`_code_plans`), each computed once
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
    from ._dense import check_finite

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


def rectangle_features_multi(
    images,
    masks,
    rep: Representation,
    grids: dict,
    polarity: bool = True,
    chunk_size: int = 64,
    cpu_seconds: dict | None = None,
    rows=None,
) -> dict:
    """Features of many rectangles for several encoders and parameters, streamed in chunks.

    Patches are extracted, standardised and whitened once per chunk for all encoders, and
    shared computations run once (:func:`encode_patches_multi`).

    Parameters
    ----------
    images, masks : ndarray of shape (n, 24, 24, 8)
    rep : Representation
    grids : dict
        ``{encoder: params}`` (see :func:`encode_patches_multi`).
    polarity : bool
    chunk_size : int
        Rectangles encoded at once (each is 361 patches).
    cpu_seconds : dict or None
        When given, process CPU seconds are added per computation ``(method, masked)`` and
        under ``"patches"`` (extraction, standardisation, whitening) and ``"pooling"``.
    rows : array-like of int or None
        Featurise these rectangles only, in this order (positions in ``images``): the features
        of ``images[rows]`` without copying them, a chunk at a time. None featurises all.

    Returns
    -------
    dict
        ``{encoder: list of ndarray of shape (n, 4 * k), float32}``, one per parameter.
        Encoders that read the same codes (SC-Natural and SC at the dictionary's penalty, for
        example) share the same array object, written once.
    """
    images = np.asarray(images, dtype=np.float32)
    masks = np.asarray(masks, dtype=bool)
    if masks.shape != images.shape:
        raise ValueError(f"masks shape {masks.shape} does not match images {images.shape}")
    rows = patches.check_rows(rows, len(images))
    n = len(images) if rows is None else len(rows)
    if n == 0:
        raise ValueError("no rectangles to featurise")
    for enc, params in grids.items():
        if not list(params):
            raise ValueError(f"params of {enc!r} must hold at least one encoder parameter")
    acc = cpu_seconds if cpu_seconds is not None else {}
    plans, needed = _code_plans(rep, grids)
    # see dlsr.memory: freshly faulted pages (huge or not) cost more than they save
    with small_pages(), reused_heap():
        out = None
        for start in range(0, n, chunk_size):
            c0 = time.process_time()
            stop = start + chunk_size
            sel = slice(start, stop) if rows is None else rows[start:stop]
            P, PM = patches.extract_patches(images[sel], masks[sel], PATCH_SIZE)
            b, g, p = P.shape
            Xp = _preprocess_patches(P.reshape(b * g, p), PM.reshape(b * g, p),
                                     (rep.zca_mean, rep.zca_matrix))
            acc["patches"] = acc.get("patches", 0.0) + time.process_time() - c0
            side = int(round(np.sqrt(g)))
            pooled: dict = {}
            # each computation's codes pooled as soon as they are done, then dropped: a chunk
            # never holds every computation's codes at once
            for done in _iter_codes(Xp, PM.reshape(b * g, p), rep, needed, acc):
                c0 = time.process_time()
                for keys in plans.values():
                    for key in keys:
                        if key not in pooled and key[:3] in done:
                            pooled[key] = _split_pool(done[key[:3]].reshape(b, side, side, -1),
                                                      bool(polarity and key[3]))
                del done
                acc["pooling"] = acc.get("pooling", 0.0) + time.process_time() - c0
            c0 = time.process_time()
            if out is None:  # encoders reading the same codes share one array
                arrays = {key: np.empty((n, pooled[key].shape[1]), dtype=np.float32)
                          for key in pooled}
                out = {enc: [arrays[key] for key in keys] for enc, keys in plans.items()}
            for key, pooled_key in pooled.items():
                arrays[key][start:start + b] = pooled_key
            acc["pooling"] = acc.get("pooling", 0.0) + time.process_time() - c0
    return out


def rectangle_features_grid(
    images,
    masks,
    rep: Representation,
    encoder: str,
    params,
    polarity: bool = True,
    chunk_size: int = 64,
) -> list[np.ndarray]:
    """Features of many rectangles for several values of one encoder's parameter.

    The one-encoder case of :func:`rectangle_features_multi`.

    Returns
    -------
    list of ndarray of shape (n, 4 * k), float32, one per parameter
    """
    return rectangle_features_multi(images, masks, rep, {encoder: params}, polarity,
                                    chunk_size)[encoder]


def rectangle_features(
    images,
    masks,
    rep: Representation,
    encoder: str,
    param=None,
    polarity: bool = True,
    chunk_size: int = 64,
) -> np.ndarray:
    """Features of many rectangles, streamed in chunks to bound memory.

    Parameters
    ----------
    images, masks : ndarray of shape (n, 24, 24, 8)
    rep : Representation
    encoder, param, polarity : see :func:`encode_patches`
    chunk_size : int
        Rectangles encoded at once (each is 361 patches).

    Returns
    -------
    ndarray of shape (n, 4 * k), float32
    """
    return rectangle_features_grid(images, masks, rep, encoder, [param], polarity,
                                   chunk_size)[0]


class DLSRFeatures(TransformerMixin, BaseEstimator):
    """The DLSR representation as a scikit-learn transformer.

    ``fit`` learns whitening and a dictionary from random patches of the training rectangles;
    ``transform`` encodes every patch and pools. Input is packed rectangle images
    (:func:`pack_images`).

    Parameters
    ----------
    learner : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}, default="NKM"
    encoder : {"SC", "mSC", "OMP", "mOMP", "ST", "Natural"}, default="SC"
    encoder_param : float or int or None
        lambda (SC, mSC, ST) or number of non-zeros (OMP, mOMP); None takes the middle of the
        reference grid.
    n_atoms : int, default=300
    whiten : bool, default=True
    n_patches : int, default=100_000
    min_valid : float, default=0.2
    polarity : bool, default=True
    extra_patches : tuple (patches, masks) or None
        Self-taught learning: unlabelled patches joined to dictionary learning.
    chunk_size : int, default=64
    random_state : int, RandomState instance or None

    Attributes
    ----------
    representation_ : Representation
    n_features_out_ : int
    """

    def __init__(
        self,
        learner="NKM",
        encoder="SC",
        encoder_param=None,
        n_atoms=300,
        whiten=True,
        n_patches=100_000,
        min_valid=0.2,
        polarity=True,
        extra_patches=None,
        chunk_size=64,
        random_state=None,
    ):
        self.learner = learner
        self.encoder = encoder
        self.encoder_param = encoder_param
        self.n_atoms = n_atoms
        self.whiten = whiten
        self.n_patches = n_patches
        self.min_valid = min_valid
        self.polarity = polarity
        self.extra_patches = extra_patches
        self.chunk_size = chunk_size
        self.random_state = random_state

    def _param(self):
        if self.encoder not in ENCODERS:
            raise ValueError(f"unknown encoder {self.encoder!r}; choose from {ENCODERS}")
        if self.encoder_param is not None or self.encoder == "Natural":
            return self.encoder_param
        grid = ENCODER_GRIDS[self.encoder]
        return grid[len(grid) // 2 - 1]

    def fit(self, X, y=None):
        X = validate_data(self, X, dtype=np.float32)
        images, masks = unpack_images(X)
        self._param()
        self.representation_ = fit_representation(
            images, masks, self.learner, n_atoms=self.n_atoms, whiten=self.whiten,
            n_patches=self.n_patches, min_valid=self.min_valid, extra=self.extra_patches,
            random_state=self.random_state,
        )
        self.n_features_out_ = self.transform(X[:1]).shape[1]
        return self

    def transform(self, X):
        check_is_fitted(self, "representation_")
        X = validate_data(self, X, dtype=np.float32, reset=False)
        images, masks = unpack_images(X)
        return rectangle_features(
            images, masks, self.representation_, self.encoder, self._param(),
            polarity=self.polarity, chunk_size=self.chunk_size,
        )
