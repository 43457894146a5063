"""Patches of rectangle images: dense extraction, random sampling, patch files.

A patch of a ``(S, S, C)`` rectangle image is a ``p x p x C`` window (6 x 6 x 8 by default).
Flattened patches are **row-major over (row, column, channel)**: feature
``j = (r * p + c) * C + k`` holds row ``r``, column ``c``, channel ``k`` of the window, so the
channel of feature ``j`` is ``j % C`` (:data:`dlsr.preprocess.CHANNELS` order, K R G B D Nx Ny
Nz). Patches are listed row-major over their top-left corner: patch ``i`` of the
``G x G`` grid (``G = S - p + 1``, 19 for 24 x 24 images) starts at row ``i // G``, column
``i % G``.

Sampling follows the authors' reference implementation: random patches drawn across the
training rectangles, a patch accepted when at least ``min_valid`` (20 %) of its entries are valid.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from sklearn.utils import check_random_state

from .records import atomic_write, load_npz

__all__ = [
    "extract_patches",
    "sample_patches",
    "load_patch_file",
    "save_patch_file",
    "check_rows",
]


_ROW_CHUNK = 4096  # images per step when counting the valid entries of selected rows


def _check_images(images, masks):
    images = np.asarray(images)
    if images.ndim != 4:
        raise ValueError(f"images must have shape (n, S, S, C), got {images.shape}")
    images = images.astype(np.float32, copy=False)
    if masks is None:
        masks = np.ones(images.shape, dtype=bool)
    else:
        masks = np.asarray(masks)
        if masks.shape != images.shape:
            raise ValueError(f"masks shape {masks.shape} does not match images {images.shape}")
        masks = masks.astype(bool, copy=False)
    return images, masks


def check_rows(rows, n: int) -> np.ndarray | None:
    """Validate ``rows``, positions of images among ``n`` (None: all of them, in order).

    Returns
    -------
    ndarray of shape (k,), intp, or None
    """
    if rows is None:
        return None
    r = np.asarray(rows)
    if r.ndim != 1 or (r.size and not np.issubdtype(r.dtype, np.integer)):
        raise ValueError(f"rows must be a 1-d array of image positions, got {r.dtype} of shape "
                         f"{r.shape}")
    r = r.astype(np.intp, copy=False)
    if r.size and (r.min() < 0 or r.max() >= n):
        raise ValueError(f"rows must be in [0, {n}), got values from {r.min()} to {r.max()}")
    return r


def _windows(a, p):
    """``(n, G, G, p, p, C)`` strided view of all windows (no copy)."""
    return sliding_window_view(a, (p, p), axis=(1, 2)).transpose(0, 1, 2, 4, 5, 3)


def extract_patches(images, masks=None, patch_size: int = 6):
    """All stride-1 patches of each image, flattened.

    Parameters
    ----------
    images : array-like of shape (n, S, S, C)
    masks : array-like of shape (n, S, S, C), bool, or None
        None means all valid.
    patch_size : int, default=6

    Returns
    -------
    X : ndarray of shape (n, G * G, patch_size * patch_size * C), float32
        ``G = S - patch_size + 1`` (19 x 19 = 361 patches of 288 values for the defaults);
        patches row-major over their top-left corner, values row-major over (row, col, channel).
    M : ndarray of the same shape, bool
    """
    images, masks = _check_images(images, masks)
    n, S, S2, C = images.shape
    p = int(patch_size)
    if p < 1 or p > min(S, S2):
        raise ValueError(f"patch_size must be in [1, {min(S, S2)}], got {patch_size}")
    G1, G2 = S - p + 1, S2 - p + 1
    # One copy each: the strided view is materialised by the reshape.
    X = _windows(images, p).reshape(n, G1 * G2, p * p * C)
    M = _windows(masks, p).reshape(n, G1 * G2, p * p * C)
    return X, M


def _resolve_rng(random_state) -> np.random.Generator:
    if isinstance(random_state, np.random.Generator):
        return random_state
    rs = check_random_state(random_state)
    return np.random.default_rng(rs.randint(0, 2**31 - 1))


def _as_extra(extra, n_features, patch_size, n_channels):
    if isinstance(extra, (str, os.PathLike)):
        P, Q = load_patch_file(extra, patch_size=patch_size, n_channels=n_channels)
    else:
        try:
            P, Q = extra
        except (TypeError, ValueError):
            raise ValueError(
                "extra must be a patch file path or a (patches, masks) tuple"
            ) from None
    P = np.asarray(P)
    Q = np.asarray(Q)
    if P.shape != Q.shape:
        raise ValueError(f"extra patches {P.shape} and masks {Q.shape} differ in shape")
    P = P.reshape(len(P), -1).astype(np.float32, copy=False)
    Q = Q.reshape(len(Q), -1).astype(bool, copy=False)
    if P.shape[1] != n_features:
        raise ValueError(
            f"extra patches have {P.shape[1]} values each, the images give {n_features}"
        )
    if not np.all(np.isfinite(P)):
        raise ValueError("extra patches contain non-finite values")
    return P, Q


def sample_patches(
    images,
    masks=None,
    n_patches: int = 100_000,
    min_valid: float = 0.2,
    random_state=None,
    extra=None,
    *,
    patch_size: int = 6,
    extra_fraction: float | None = None,
    return_index: bool = False,
    rows=None,
):
    """Random patches across rectangle images, optionally mixed with extra unlabelled patches.

    Each draw picks uniformly among the accepted candidates (image, row, column) - patches with
    at least ``min_valid`` of their entries valid - with replacement, which is the reference's
    draw-and-reject scheme. Extra patches (self-taught learning) are filtered the same way.

    Parameters
    ----------
    images : array-like of shape (n, S, S, C)
    masks : array-like of shape (n, S, S, C), bool, or None
    n_patches : int, default=100_000
    min_valid : float, default=0.2
        Minimum fraction of valid entries for a patch to be accepted.
    random_state : int, RandomState, Generator or None
    extra : path, (patches, masks) or None
        Extra unlabelled patches: a file for :func:`load_patch_file`, or arrays of shape
        ``(m, p, p, C)`` or ``(m, p * p * C)``.
    patch_size : int, default=6
    extra_fraction : float or None
        None draws uniformly from the union of image and extra candidates; a number in
        ``[0, 1]`` draws ``round(extra_fraction * n_patches)`` patches from the extra ones.
    return_index : bool, default=False
        Also return where each patch comes from.
    rows : array-like of int or None
        Draw from these images only, in this order: the same patches as from ``images[rows]``
        and ``masks[rows]`` (and the returned index counts images within ``rows``), without
        copying the selected images (a training fold of a large, memory-mapped set). None
        draws from all.

    Returns
    -------
    X : ndarray of shape (n_patches, p * p * C), float32
        Masked entries are 0.
    M : ndarray of shape (n_patches, p * p * C), bool
    index : ndarray of shape (n_patches, 3), int
        Only with ``return_index``: ``(image, row, col)`` of the patch's top-left corner, or
        ``(-1, k, -1)`` for the ``k``-th extra patch.

    Raises
    ------
    ValueError
        When no patch (or no extra patch, with ``extra_fraction > 0``) is valid enough.
    """
    images, masks = _check_images(images, masks)
    n, S, S2, C = images.shape
    rows = check_rows(rows, n)
    p = int(patch_size)
    if p < 1 or p > min(S, S2):
        raise ValueError(f"patch_size must be in [1, {min(S, S2)}], got {patch_size}")
    n_patches = int(n_patches)
    if n_patches < 0:
        raise ValueError(f"n_patches must be >= 0, got {n_patches}")
    if not 0.0 <= min_valid <= 1.0:
        raise ValueError(f"min_valid must be in [0, 1], got {min_valid}")
    if extra_fraction is not None and not 0.0 <= extra_fraction <= 1.0:
        raise ValueError(f"extra_fraction must be in [0, 1] or None, got {extra_fraction}")
    rng = _resolve_rng(random_state)
    d = p * p * C
    need = min_valid * d - 1e-9

    m = n if rows is None else len(rows)
    counts = np.empty((m, S, S2), dtype=np.int32)
    for start in range(0, m, _ROW_CHUNK):  # in chunks: masks[rows] would copy what rows avoids
        stop = min(start + _ROW_CHUNK, m)
        sel = slice(start, stop) if rows is None else rows[start:stop]
        counts[start:stop] = masks[sel].sum(axis=3, dtype=np.int32)
    win = sliding_window_view(counts, (p, p), axis=(1, 2)).sum(axis=(3, 4))  # (n, G1, G2)
    cand = np.flatnonzero(win.ravel() >= need)
    if extra is not None:
        EX, EM = _as_extra(extra, d, p, C)
        ecand = np.flatnonzero(EM.sum(axis=1) >= need)
    else:
        EX = EM = None
        ecand = np.zeros(0, dtype=np.intp)

    if extra_fraction is None or extra is None:
        pool = len(cand) + len(ecand)
        if pool == 0 and n_patches > 0:
            raise ValueError(f"no patch has at least {min_valid:.0%} valid entries")
        draw = rng.integers(0, pool, size=n_patches) if n_patches else np.zeros(0, np.intp)
        from_img = draw[draw < len(cand)]
        from_ext = draw[draw >= len(cand)] - len(cand)
        order = np.argsort(draw >= len(cand), kind="stable")  # images first, then extra
        inverse = np.empty_like(order)
        inverse[order] = np.arange(len(order))
    else:
        k_ext = int(round(extra_fraction * n_patches))
        k_img = n_patches - k_ext
        if k_img and not len(cand):
            raise ValueError(f"no image patch has at least {min_valid:.0%} valid entries")
        if k_ext and not len(ecand):
            raise ValueError(f"no extra patch has at least {min_valid:.0%} valid entries")
        from_img = rng.integers(0, len(cand), size=k_img) if k_img else np.zeros(0, np.intp)
        from_ext = rng.integers(0, len(ecand), size=k_ext) if k_ext else np.zeros(0, np.intp)
        inverse = rng.permutation(n_patches)

    flat = cand[from_img]
    G1, G2 = win.shape[1], win.shape[2]
    img_i, rem = np.divmod(flat, G1 * G2)
    row_i, col_i = np.divmod(rem, G2)
    src = img_i if rows is None else rows[img_i]
    Xi = _windows(images, p)[src, row_i, col_i].reshape(len(flat), d)
    Mi = _windows(masks, p)[src, row_i, col_i].reshape(len(flat), d)
    idx_i = np.column_stack([img_i, row_i, col_i])
    if len(from_ext):
        ek = ecand[from_ext]
        X = np.concatenate([Xi, EX[ek]])
        M = np.concatenate([Mi, EM[ek]])
        idx = np.concatenate([idx_i, np.column_stack([np.full_like(ek, -1), ek,
                                                      np.full_like(ek, -1)])])
    else:
        X, M, idx = Xi, Mi, idx_i
    X = X[inverse]
    M = M[inverse]
    X[~M] = 0.0
    if return_index:
        return X, M, idx[inverse].astype(np.intp)
    return X, M


def save_patch_file(path, patches, masks, *, patch_size: int = 6, n_channels: int = 8):
    """Write patches to an ``.npz`` file (``patches`` float32, ``masks`` bool, ``(m, p, p, C)``).

    Parameters
    ----------
    path : str or Path
        Written as given (no suffix is added); parent folders are created.
    patches : array-like of shape (m, p, p, C) or (m, p * p * C)
    masks : array-like of the same shape, bool
    patch_size, n_channels : int
        Used to reshape flattened patches.
    """
    shape = (patch_size, patch_size, n_channels)
    P = np.asarray(patches, dtype=np.float32)
    Q = np.asarray(masks)
    if P.shape != Q.shape:
        raise ValueError(f"patches {P.shape} and masks {Q.shape} differ in shape")
    if P.ndim == 2 and P.shape[1] == int(np.prod(shape)):
        P = P.reshape((-1, *shape))
        Q = Q.reshape((-1, *shape))
    if P.ndim != 4 or P.shape[1:] != shape:
        raise ValueError(f"patches must have shape (m, {shape}) or flattened, got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("patches contain non-finite values")
    with atomic_write(path, "wb") as f:  # a kill leaves the old file or none, never half
        np.savez_compressed(f, patches=P, masks=Q.astype(bool))


def load_patch_file(path, *, patch_size: int = 6, n_channels: int = 8):
    """Read a patch file written by :func:`save_patch_file`.

    Parameters
    ----------
    path : str or Path
        ``.npz`` with ``patches`` (m, p, p, C) float and ``masks`` (m, p, p, C) bool.
    patch_size, n_channels : int
        Expected patch shape.

    Returns
    -------
    patches : ndarray of shape (m, p, p, C), float32
    masks : ndarray of shape (m, p, p, C), bool

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not a readable ``.npz``, lacks a key, or has wrong shapes, dtypes or values;
        the message names the file.
    """
    path = Path(path)
    shape = (patch_size, patch_size, n_channels)
    arrays = load_npz(path, ("patches", "masks"), what="patch file")
    P, Q = arrays["patches"], arrays["masks"]
    if P.ndim != 4 or P.shape[1:] != shape:
        raise ValueError(f"patch file {path}: patches must have shape (m, {shape}), got {P.shape}")
    if Q.shape != P.shape:
        raise ValueError(f"patch file {path}: masks {Q.shape} do not match patches {P.shape}")
    if not np.issubdtype(P.dtype, np.floating):
        raise ValueError(f"patch file {path}: patches must be floating point, got {P.dtype}")
    if Q.dtype != bool:
        if np.issubdtype(Q.dtype, np.integer) and np.isin(Q, (0, 1)).all():
            Q = Q.astype(bool)
        else:
            raise ValueError(f"patch file {path}: masks must be bool, got {Q.dtype}")
    P = P.astype(np.float32, copy=False)
    if not np.all(np.isfinite(P)):
        raise ValueError(f"patch file {path}: patches contain non-finite values")
    return P, Q
