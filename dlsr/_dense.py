"""Compiled kernels of the dense detector (:class:`dlsr.detection.DenseDetector`).

A canvas is an ``(H, W, 8)`` float32 image with an ``(H, W, 8)`` validity mask (masked values
0); its 6x6 patches at top-left positions ``(r, c)`` are flattened row-major over
(row, column, channel), as :func:`dlsr.patches.extract_patches` does. The kernels compute

* :func:`window_stats`: the masked per-group mean and ``1 / sqrt(var + eps)`` of every patch
  from running window sums (float64), with the conventions of
  :func:`dlsr.whitening.standardize_patches` (groups K; R, G, B; D; normals; ``ddof=1``; a
  group with fewer than two valid entries has variance 0);
* :func:`gather_patches`: the standardised patches at chosen positions, one row each (masked
  entries 0), ready for one matrix product;
* :func:`valid_row_spans`: the rows of each patch that hold valid entries (the rectangle
  images' padding masks whole rows), from its gathered mask or (:func:`patch_row_spans`) from
  the canvas; :func:`gather_patch_rows`: only those rows of the patches and their masks;
* :func:`colour_only`: which patches have all their colour entries valid and no valid depth
  entry (a canvas masks the depth channels of the pixels without depth);
  :func:`gather_colour`: only the colour entries of those patches;
* :func:`triangle_scores`: from ``Y1 = whitened patch + mP`` and ``Y2 = whitened patch . c_k +
  b_k`` (one product of the standardised patches with ``[P | P C^T]``), the k-means triangle
  codes ``max(mean_k z - z_k, 0)``, ``z_k = ||x - c_k||`` (:func:`dlsr.coding.kmeans_triangle`),
  dotted with per-quadrant weights, without storing the codes;
* :func:`standardize_rows`: :func:`dlsr.whitening.standardize_patches` on flattened patches
  (two passes per row instead of numpy's eight over the array);
* :func:`soft_threshold_inplace` (:func:`soft_threshold_into` for a separate output) and
  :func:`triangle_inplace`: the element-wise parts of
  :func:`dlsr.coding.soft_threshold` and :func:`dlsr.coding.kmeans_triangle` in one pass over
  a chunk of projections (numpy's separate passes cost a third of the matrix product);
* :func:`first_non_finite_row` (and :func:`check_finite`, which raises on it): the inputs of
  the encoders, the whitening and the learners are checked before any matrix product, because
  what a product does with a NaN or an infinity depends on the BLAS kernels (OpenBLAS's
  AVX-512 kernels raise the floating-point "invalid" flag on an infinity, which numpy turns
  into a ``RuntimeWarning``; its SSE3 and AVX2 kernels do not).

Compiled with numba (``nogil``, cached on disk): the caller runs chunks in threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "PATCH",
    "GROUP_OF_CHANNEL",
    "window_stats",
    "gather_patches",
    "gather_masks",
    "valid_row_spans",
    "patch_row_spans",
    "gather_patch_rows",
    "colour_only",
    "gather_colour",
    "triangle_scores",
    "soft_threshold_inplace",
    "soft_threshold_into",
    "triangle_inplace",
    "standardize_rows",
    "first_non_finite_row",
    "check_finite",
]

PATCH = 6
#: Channel group of each of the 8 channels (K; R, G, B; D; Nx, Ny, Nz).
GROUP_OF_CHANNEL = np.array([0, 1, 1, 1, 2, 3, 3, 3], dtype=np.int64)
_GROUP_SIZE = np.array([1, 3, 1, 3], dtype=np.int64)


@njit(nogil=True, cache=True)
def _add_row(img, msk, r, col, sign, group):
    """``col[j] += sign * (s1[4], s2[4], count[4])`` of pixel ``(r, j)`` for every column."""
    W = img.shape[1]
    for j in range(W):
        for ch in range(8):
            if msk[r, j, ch]:
                v = np.float64(img[r, j, ch])
                g = group[ch]
                col[j, g] += sign * v
                col[j, 4 + g] += sign * v * v
                col[j, 8 + g] += sign


@njit(nogil=True, cache=True)
def window_stats(img, msk, eps, mean, inv, full):
    """Masked per-group statistics of every 6x6 window.

    Parameters
    ----------
    img : ndarray of shape (H, W, 8), float32
    msk : ndarray of shape (H, W, 8), bool
    eps : float
        Added to the variance (1e-4 in :func:`dlsr.whitening.standardize_patches`).
    mean, inv : ndarray of shape (H - 5, W - 5, 4), float32, written
        Mean and ``1 / sqrt(var + eps)`` per channel group over the valid entries.
    full : ndarray of shape (H - 5, W - 5), bool, written
        True where every entry of the window is valid.
    """
    H, W = img.shape[0], img.shape[1]
    Hp, Wp = H - PATCH + 1, W - PATCH + 1
    group = GROUP_OF_CHANNEL
    size = _GROUP_SIZE
    col = np.zeros((W, 12))
    acc = np.zeros(12)
    for r in range(PATCH - 1):
        _add_row(img, msk, r, col, 1.0, group)
    for i in range(Hp):
        _add_row(img, msk, i + PATCH - 1, col, 1.0, group)
        if i > 0:
            _add_row(img, msk, i - 1, col, -1.0, group)
        for q in range(12):
            acc[q] = 0.0
        for j in range(PATCH - 1):
            for q in range(12):
                acc[q] += col[j, q]
        for j in range(Wp):
            for q in range(12):
                acc[q] += col[j + PATCH - 1, q]
                if j > 0:
                    acc[q] -= col[j - 1, q]
            ok = True
            for g in range(4):
                cnt = np.floor(acc[8 + g] + 0.5)
                s1 = acc[g]
                mu = s1 / max(cnt, 1.0)
                var = 0.0
                if cnt >= 2.0:
                    var = max(acc[4 + g] - s1 * mu, 0.0) / (cnt - 1.0)
                mean[i, j, g] = mu
                inv[i, j, g] = 1.0 / np.sqrt(var + eps)
                if cnt != PATCH * PATCH * size[g]:
                    ok = False
            full[i, j] = ok


@njit(nogil=True, cache=True)
def gather_patches(img, msk, rows, cols, mean, inv, full, X):
    """Standardised patches at ``(rows[t], cols[t])`` into ``X[t]`` (masked entries 0).

    Parameters
    ----------
    img, msk : ndarray of shape (H, W, 8)
    rows, cols : ndarray of shape (n,), int
        Top-left corners.
    mean, inv, full :
        From :func:`window_stats`.
    X : ndarray of shape (n, 288), float32, written
    """
    group = GROUP_OF_CHANNEL
    mu = np.empty(8, np.float32)
    iv = np.empty(8, np.float32)
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        for ch in range(8):
            mu[ch] = mean[r, c, group[ch]]
            iv[ch] = inv[r, c, group[ch]]
        if full[r, c]:
            for dy in range(PATCH):
                for dx in range(PATCH):
                    o = (dy * PATCH + dx) * 8
                    for ch in range(8):
                        X[t, o + ch] = (img[r + dy, c + dx, ch] - mu[ch]) * iv[ch]
        else:
            for dy in range(PATCH):
                for dx in range(PATCH):
                    o = (dy * PATCH + dx) * 8
                    for ch in range(8):
                        if msk[r + dy, c + dx, ch]:
                            X[t, o + ch] = (img[r + dy, c + dx, ch] - mu[ch]) * iv[ch]
                        else:
                            X[t, o + ch] = 0.0


@njit(nogil=True, cache=True)
def gather_masks(msk, rows, cols, M):
    """Patch validity at ``(rows[t], cols[t])`` into ``M[t]`` (n, 288), as float32 0/1."""
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        for dy in range(PATCH):
            for dx in range(PATCH):
                o = (dy * PATCH + dx) * 8
                for ch in range(8):
                    M[t, o + ch] = 1.0 if msk[r + dy, c + dx, ch] else 0.0


@njit(nogil=True, cache=True)
def patch_row_spans(msk, rows, cols, lo, hi):
    """:func:`valid_row_spans` of the patches at ``(rows[t], cols[t])``, read from the canvas
    mask without gathering the patches' masks."""
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        first = -1
        last = -1
        for dy in range(PATCH):
            any_valid = False
            for dx in range(PATCH):
                for ch in range(8):
                    if msk[r + dy, c + dx, ch]:
                        any_valid = True
                        break
                if any_valid:
                    break
            if any_valid:
                if first < 0:
                    first = dy
                last = dy
        if first < 0:
            lo[t] = 0
            hi[t] = 0
        else:
            lo[t] = first
            hi[t] = last + 1


@njit(nogil=True, cache=True)
def gather_patch_rows(img, msk, rows, cols, mean, inv, a, b, X, M):
    """Rows ``[a, b)`` of the standardised patches at ``(rows[t], cols[t])`` and of their
    masks: ``X[t]`` and ``M[t]`` are entries ``a * 48`` to ``b * 48`` of what
    :func:`gather_patches` and :func:`gather_masks` write (the same values), for patches whose
    other rows hold no valid entry.

    Parameters
    ----------
    img, msk : ndarray of shape (H, W, 8)
    rows, cols : ndarray of shape (n,), int
    mean, inv :
        From :func:`window_stats`.
    a, b : int
        Patch rows, ``0 <= a < b <= 6``.
    X, M : ndarray of shape (n, (b - a) * 48), float32, written
    """
    group = GROUP_OF_CHANNEL
    mu = np.empty(8, np.float32)
    iv = np.empty(8, np.float32)
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        for ch in range(8):
            mu[ch] = mean[r, c, group[ch]]
            iv[ch] = inv[r, c, group[ch]]
        for dy in range(a, b):
            for dx in range(PATCH):
                o = ((dy - a) * PATCH + dx) * 8
                for ch in range(8):
                    if msk[r + dy, c + dx, ch]:
                        X[t, o + ch] = (img[r + dy, c + dx, ch] - mu[ch]) * iv[ch]
                        M[t, o + ch] = 1.0
                    else:
                        X[t, o + ch] = 0.0
                        M[t, o + ch] = 0.0


@njit(nogil=True, cache=True)
def colour_only(msk, rows, cols, out):
    """Whether each patch at ``(rows[t], cols[t])`` has every colour entry (channels 0-3)
    valid and no valid depth entry (channels 4-7), as a pile's patches without depth have.

    Parameters
    ----------
    msk : ndarray of shape (H, W, 8), bool
    rows, cols : ndarray of shape (n,), int
    out : ndarray of shape (n,), bool, written
    """
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        ok = True
        for dy in range(PATCH):
            for dx in range(PATCH):
                for ch in range(8):
                    if msk[r + dy, c + dx, ch] != (ch < 4):
                        ok = False
                        break
                if not ok:
                    break
            if not ok:
                break
        out[t] = ok


@njit(nogil=True, cache=True)
def gather_colour(img, rows, cols, mean, inv, X):
    """The colour entries (channels 0-3 of the 36 pixels, in patch order) of the standardised
    patches at ``(rows[t], cols[t])``: the entries ``(dy * 6 + dx) * 8 + ch``, ``ch < 4``, of
    what :func:`gather_patches` writes (the same values), for patches whose colour entries are
    all valid.

    Parameters
    ----------
    img : ndarray of shape (H, W, 8)
    rows, cols : ndarray of shape (n,), int
    mean, inv :
        From :func:`window_stats`.
    X : ndarray of shape (n, 144), float32, written
    """
    group = GROUP_OF_CHANNEL
    mu = np.empty(4, np.float32)
    iv = np.empty(4, np.float32)
    for t in range(len(rows)):
        r = rows[t]
        c = cols[t]
        for ch in range(4):
            mu[ch] = mean[r, c, group[ch]]
            iv[ch] = inv[r, c, group[ch]]
        for dy in range(PATCH):
            for dx in range(PATCH):
                o = (dy * PATCH + dx) * 4
                for ch in range(4):
                    X[t, o + ch] = (img[r + dy, c + dx, ch] - mu[ch]) * iv[ch]


@njit(nogil=True, cache=True)
def valid_row_spans(M, lo, hi):
    """The rows of each flattened patch that hold valid entries: ``[lo[t], hi[t])``.

    Parameters
    ----------
    M : ndarray of shape (n, 288), float32
        Patch validity (0/1), as :func:`gather_masks` writes it.
    lo, hi : ndarray of shape (n,), int64, written
        The first patch row with a valid entry and one past the last (``lo == hi == 0`` for
        a patch with none): entries outside those rows are all masked.
    """
    width = PATCH * 8
    for t in range(M.shape[0]):
        first = -1
        last = -1
        for r in range(PATCH):
            for q in range(r * width, (r + 1) * width):
                if M[t, q] != 0.0:
                    if first < 0:
                        first = r
                    last = r
                    break
        if first < 0:
            lo[t] = 0
            hi[t] = 0
        else:
            lo[t] = first
            hi[t] = last + 1


@njit(nogil=True, cache=True, fastmath=True)
def triangle_scores(Y1, o1, Y2, o2, mP, cc2, VT, S):
    """Triangle codes dotted with quadrant weights, per row.

    With ``x = Y1[t, o1:o1 + p] - mP`` (the whitened patch) and
    ``x . c_k = Y2[t, o2 + k] - b_k``:
    ``z_k = sqrt(max(||x||^2 + ||c_k||^2 + 2 b_k - 2 Y2[t, o2 + k], 0))``, codes
    ``a_k = max(mean(z) - z_k, 0)``, ``S[t, q] = sum_k a_k VT[q, k]``.

    Parameters
    ----------
    Y1 : ndarray of shape (n, m1), float32, C-contiguous
    o1 : int
        First column of the whitened patch in ``Y1``.
    Y2 : ndarray of shape (n, m2), float32, C-contiguous (may be ``Y1``)
    o2 : int
        First column of the centroid products in ``Y2``.
    mP : ndarray of shape (p,), float32
    cc2 : ndarray of shape (k,), float32
        ``||c_k||^2 + 2 b_k``.
    VT : ndarray of shape (q, k), float32
    S : ndarray of shape (n, q), float32, written
    """
    n = Y1.shape[0]
    p = mP.shape[0]
    k = cc2.shape[0]
    nq = VT.shape[0]
    zero = np.float32(0.0)
    z = np.empty(k, np.float32)
    for t in range(n):
        y1 = Y1[t, o1 : o1 + p]
        y2 = Y2[t, o2 : o2 + k]
        nrm = zero
        for j in range(p):
            d = y1[j] - mP[j]
            nrm += d * d
        s = zero
        for i in range(k):
            v = nrm + cc2[i] - np.float32(2.0) * y2[i]
            v = np.sqrt(v if v > zero else zero)
            z[i] = v
            s += v
        mu = s / np.float32(k)
        for i in range(k):
            v = mu - z[i]
            z[i] = v if v > zero else zero
        for q in range(nq):
            vq = VT[q]
            a = zero
            for i in range(k):
                a += z[i] * vq[i]
            S[t, q] = a


# no "nnan"/"ninf": the non-finite checks below must survive compilation
_FAST = {"reassoc", "contract", "nsz", "arcp"}


@njit(nogil=True, cache=True, fastmath=_FAST)
def soft_threshold_inplace(A, lam):
    """``A <- sign(A) max(|A| - lam, 0)`` in place; returns ``sum(A)`` before (float64).

    The returned sum is finite exactly when every input value is (overflow aside), which is
    how the caller checks its inputs without another pass.

    Parameters
    ----------
    A : ndarray of shape (n, d), float32 or float64, written
    lam : float, >= 0
    """
    n, d = A.shape
    total = 0.0
    for i in range(n):
        row = A[i]
        for j in range(d):
            v = row[j]
            total += v
            a = abs(v) - lam
            row[j] = (a if v > 0 else -a) if a > 0 else 0.0
    return total


@njit(nogil=True, cache=True, fastmath=_FAST)
def soft_threshold_into(Z, lam, out):
    """``out <- sign(Z) max(|Z| - lam, 0)``, one pass (``Z``: ``(n, d)``, read only)."""
    n, d = Z.shape
    for i in range(n):
        row = Z[i]
        dst = out[i]
        for j in range(d):
            v = row[j]
            a = abs(v) - lam
            dst[j] = (a if v > 0 else -a) if a > 0 else 0.0


@njit(nogil=True, cache=True, fastmath=_FAST)
def triangle_inplace(Z, cn, xx):
    """k-means triangle codes in place from ``Z = -2 X C^T``; returns a float64 checksum.

    ``z_k = sqrt(max(Z[t, k] + cn[k] + xx[t], 0))``, ``Z[t, k] <- max(mean_k z - z_k, 0)``.

    Parameters
    ----------
    Z : ndarray of shape (n, k), float32 or float64, written
    cn : ndarray of shape (k,)
        ``||c_k||^2``.
    xx : ndarray of shape (n,)
        ``||x_t||^2``.

    Returns
    -------
    float
        Sum of the squared distances (non-finite when an input row was).
    """
    n, k = Z.shape
    total = 0.0
    for t in range(n):
        row = Z[t]
        s = 0.0
        for i in range(k):
            v = row[i] + cn[i] + xx[t]
            total += v  # the checksum sees NaN and inf before they are clamped
            v = np.sqrt(v) if v > 0 else 0.0  # negatives: rounding when x is a centroid
            row[i] = v
            s += v
        mu = s / k
        for i in range(k):
            v = mu - row[i]
            row[i] = v if v > 0 else 0.0
    return total


@njit(nogil=True, cache=True)
def split_pool(A, split, polarity, out):
    """Quadrant sum pooling of a code map, with polarity splitting, in one pass.

    ``out[b]`` gets, for the quadrants top-left, top-right, bottom-left, bottom-right (rows and
    columns ``[:split]`` / ``[split:]``), the sums of ``max(a, 0)`` then of ``max(-a, 0)``
    (``2 k`` values per quadrant) when ``polarity``, else the sums of ``a`` (``k`` values):
    what :func:`dlsr.features.quadrant_pool` gives on the split codes, without materialising
    them. Sums are accumulated in float64.

    Parameters
    ----------
    A : ndarray of shape (n, R, C, k)
    split : int
    polarity : bool
    out : ndarray of shape (n, 4 * k * (2 if polarity else 1)), written
    """
    n, R, C, k = A.shape
    width = 2 * k if polarity else k
    acc = np.zeros(4 * width)
    for b in range(n):
        for x in range(4 * width):
            acc[x] = 0.0
        for r in range(R):
            for c in range(C):
                q = (2 if r >= split else 0) + (1 if c >= split else 0)
                base = q * width
                row = A[b, r, c]
                if polarity:
                    for j in range(k):
                        v = np.float64(row[j])
                        if v > 0:
                            acc[base + j] += v
                        else:
                            acc[base + k + j] -= v
                else:
                    for j in range(k):
                        acc[base + j] += row[j]
        for x in range(4 * width):
            out[b, x] = acc[x]


@njit(nogil=True, cache=True)
def standardize_rows(X, M, group, n_groups, eps, out):
    """Per-row, per-channel-group masked standardisation, in float64.

    Parameters
    ----------
    X : ndarray of shape (n, p)
    M : ndarray of shape (n, p), bool
    group : ndarray of shape (p,), int64
        Channel group of each feature, in ``[0, n_groups)``.
    n_groups : int
    eps : float
    out : ndarray of shape (n, p), written
        Valid entries ``(x - mean) / sqrt(var + eps)`` (mean and ``ddof=1`` variance over the
        row's valid entries of the group; variance 0 with fewer than two), masked entries 0.
    """
    n, p = X.shape
    s = np.empty(n_groups)
    cnt = np.empty(n_groups)
    mean = np.empty(n_groups)
    sd = np.empty(n_groups)
    for i in range(n):
        for h in range(n_groups):
            s[h] = 0.0
            cnt[h] = 0.0
        for q in range(p):
            if M[i, q]:
                s[group[q]] += X[i, q]
                cnt[group[q]] += 1.0
        for h in range(n_groups):
            mean[h] = s[h] / max(cnt[h], 1.0)
            s[h] = 0.0
        for q in range(p):
            if M[i, q]:
                dev = X[i, q] - mean[group[q]]
                s[group[q]] += dev * dev
        for h in range(n_groups):
            var = s[h] / max(cnt[h] - 1.0, 1.0) if cnt[h] >= 2.0 else 0.0
            sd[h] = np.sqrt(var + eps)
        for q in range(p):
            if M[i, q]:
                out[i, q] = (X[i, q] - mean[group[q]]) / sd[group[q]]
            else:
                out[i, q] = 0.0


# "reassoc" only: the sum vectorises, and ``v - v`` stays NaN for NaN and infinite ``v``
@njit(nogil=True, cache=True, fastmath={"reassoc"})
def _first_non_finite_row(a):
    n, m = a.shape
    if m == 0:
        return -1
    for i in range(n):
        row = a[i]
        acc = row[0] - row[0]  # 0 for a finite value, NaN for NaN and infinities (a's dtype)
        for j in range(1, m):
            acc += row[j] - row[j]
        if acc != 0:  # NaN compares unequal
            return i
    return -1


def first_non_finite_row(a) -> int:
    """Index of the first row of ``a`` holding a NaN or an infinity, or -1.

    One compiled pass without temporaries (float32 and float64; other dtypes go through
    ``np.isfinite``); integer and boolean arrays are finite.

    Parameters
    ----------
    a : array-like of shape (n, ...)
        Rows along the first axis; a 0-d or 1-D array is one row.

    Returns
    -------
    int
    """
    a = np.asarray(a)
    if a.dtype.kind in "biu":
        return -1
    a2 = a.reshape(1, -1) if a.ndim < 2 else a.reshape(a.shape[0], -1)
    if a.dtype in (np.float32, np.float64):
        return int(_first_non_finite_row(a2))
    bad = np.flatnonzero(~np.isfinite(a2).all(axis=1))  # float16, long double, complex
    return int(bad[0]) if bad.size else -1


def check_finite(a, name: str = "X"):
    """Raise ``ValueError`` naming ``name`` (and the first bad row of a 2-D or larger array)
    when ``a`` holds a NaN or an infinity.

    Parameters
    ----------
    a : array-like
    name : str
        What ``a`` is, for the message.
    """
    a = np.asarray(a)
    bad = first_non_finite_row(a)
    if bad >= 0:
        where = f": row {bad} is not" if a.ndim >= 2 else ""
        raise ValueError(f"{name} must be finite (no NaN or inf){where}")
