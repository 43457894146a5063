"""From rectangle images to pooled feature vectors: polarity splitting and quadrant sum pooling
(:func:`quadrant_pool`, :func:`split_pool`), and the whole pipeline streamed over many
rectangles in chunks (:func:`rectangle_features_multi`)."""

from __future__ import annotations

import time

import numpy as np

from .. import patches
from ..memory import reused_heap, small_pages
from .base import PATCH_SIZE, POOL_SPLIT
from .encoding import code_plans, iter_codes
from .representation import Representation, preprocess_patches, whitening_groups

__all__ = ["quadrant_pool", "split_pool", "rectangle_features", "rectangle_features_grid",
           "rectangle_features_multi"]


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


def split_pool(codes, polarity: bool, split: int = POOL_SPLIT) -> np.ndarray:
    """``quadrant_pool(polarity_split(codes))`` (or of the codes) in one compiled pass."""
    from .._dense import split_pool as fused

    n, _, _, k = codes.shape
    out = np.empty((n, 4 * k * (2 if polarity else 1)), dtype=np.float32)
    fused(np.ascontiguousarray(codes), split, polarity, out)
    return out


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
    return _features_of(images, masks, [(rep, grids, polarity)], chunk_size, cpu_seconds,
                        rows)[0]


def rectangle_features_many(images, masks, models, chunk_size: int = 64) -> list[np.ndarray]:
    """:func:`rectangle_features` of the same rectangles under several models, the patches
    extracted once and standardised and whitened once for the models that whiten alike.

    The representations of one training set drawn from one seed whiten alike whatever their
    learner (they sample the same patches): a detector's models (NKM, OMP and RP in the paper's
    Table 2) then read the same whitened patches, and each model's features are the ones
    :func:`rectangle_features` gives it alone, bit for bit.

    Parameters
    ----------
    images, masks : ndarray of shape (n, 24, 24, 8)
    models : sequence of tuple
        ``(rep, encoder, param, polarity)`` per model (see :func:`rectangle_features`).
    chunk_size : int

    Returns
    -------
    list of ndarray of shape (n, 4 * k), float32
        One per model, in their order.
    """
    jobs = [(rep, {encoder: [param]}, polarity) for rep, encoder, param, polarity in models]
    out = _features_of(images, masks, jobs, chunk_size, None, None)
    return [o[next(iter(grids))][0] for o, (_, grids, _) in zip(out, jobs, strict=True)]


def _features_of(images, masks, jobs, chunk_size, cpu_seconds, rows) -> list[dict]:
    """Per job ``(rep, grids, polarity)``, :func:`rectangle_features_multi`'s dict; the
    patches extracted once per chunk and preprocessed once per whitening."""
    images = np.asarray(images, dtype=np.float32)
    masks = np.asarray(masks, dtype=bool)
    if masks.shape != images.shape:
        raise ValueError(f"masks shape {masks.shape} does not match images {images.shape}")
    rows = patches.check_rows(rows, len(images))
    n = len(images) if rows is None else len(rows)
    if n == 0:
        raise ValueError("no rectangles to featurise")
    for _, grids, _ in jobs:
        for enc, params in grids.items():
            if not list(params):
                raise ValueError(f"params of {enc!r} must hold at least one encoder parameter")
    acc = cpu_seconds if cpu_seconds is not None else {}
    planned = [code_plans(rep, grids) for rep, grids, _ in jobs]
    groups = whitening_groups([rep for rep, _, _ in jobs])
    outs: list = [None] * len(jobs)
    arrays: list = [None] * len(jobs)
    # see dlsr.memory: freshly faulted pages (huge or not) cost more than they save
    with small_pages(), reused_heap():
        for start in range(0, n, chunk_size):
            c0 = time.process_time()
            stop = start + chunk_size
            sel = slice(start, stop) if rows is None else rows[start:stop]
            P, PM = patches.extract_patches(images[sel], masks[sel], PATCH_SIZE)
            b, g, p = P.shape
            M = PM.reshape(b * g, p)
            acc["patches"] = acc.get("patches", 0.0) + time.process_time() - c0
            side = int(round(np.sqrt(g)))
            for group in groups:
                c0 = time.process_time()
                first = jobs[group[0]][0]
                Xp = preprocess_patches(P.reshape(b * g, p), M,
                                        (first.zca_mean, first.zca_matrix))
                acc["patches"] = acc.get("patches", 0.0) + time.process_time() - c0
                for j in group:
                    rep, _, polarity = jobs[j]
                    plans, needed = planned[j]
                    pooled: dict = {}
                    # each computation's codes pooled as soon as they are done, then dropped:
                    # a chunk never holds every computation's codes at once
                    for done in iter_codes(Xp, M, rep, needed, acc):
                        c0 = time.process_time()
                        for keys in plans.values():
                            for key in keys:
                                if key not in pooled and key[:3] in done:
                                    pooled[key] = split_pool(
                                        done[key[:3]].reshape(b, side, side, -1),
                                        bool(polarity and key[3]))
                        del done
                        acc["pooling"] = acc.get("pooling", 0.0) + time.process_time() - c0
                    c0 = time.process_time()
                    if outs[j] is None:  # encoders reading the same codes share one array
                        arrays[j] = {key: np.empty((n, pooled[key].shape[1]), dtype=np.float32)
                                     for key in pooled}
                        outs[j] = {enc: [arrays[j][key] for key in keys]
                                   for enc, keys in plans.items()}
                    for key, pooled_key in pooled.items():
                        arrays[j][key][start:start + b] = pooled_key
                    acc["pooling"] = acc.get("pooling", 0.0) + time.process_time() - c0
    return outs


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
