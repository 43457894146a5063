"""Compiled kernels of the rectangle images (:mod:`dlsr.preprocess`), one crop at a time.

Each kernel does what the numpy code of :mod:`dlsr.preprocess` did, with the same
floating-point operations in the same order, so the images are the same bit for bit (tested
against the numpy expressions kept in ``tests/dlsr/test_crop_kernels.py``):

* :func:`bilinear_grid`: the bilinear samples of the padded source on a crop's rotated grid
  (float64 coordinates, float32 blending);
* :func:`sample_crop`: those samples, the inside and depth-validity masks, the
  depth outliers masked pass after pass (mean and ``ddof=1`` standard deviation summed as
  numpy sums, pairwise in blocks of eight: :func:`pairwise_sum`), the colour, gray and D
  channels;
* :func:`normals`: MATLAB ``surfnorm`` normals of a height map
  (:func:`dlsr.preprocess.surface_normals`);
* :func:`hole_band`: the valid pixels within ``band`` pixels (chessboard distance) of a hole,
  which the band fill triangulates;
* :func:`interpolate_in_triangles`: the piecewise-linear interpolation of the holes on a
  triangulation of integer pixel positions, each hole located by exact integer orientation
  tests and weighted by Cramer's rule: the values of scipy's ``find_simplex`` and barycentric
  transforms (a 2 x 2 LU factorisation per triangle) up to float rounding, without computing
  a transform for every triangle;
* :func:`nearest_sites`: each pixel's nearest valid pixel, as scipy's exact Euclidean
  distance transform chooses it (the same algorithm and tie-breaking), for the holes left
  outside the triangulation and the object region's filled depth;
* :func:`pad_masked`: the resized crop thresholded into its masks, masked and centred in the
  padded image.

Compiled with numba (``nogil``, cached on disk): the detectors make crops in threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pairwise_sum", "bilinear_grid", "sample_crop", "normals", "hole_band",
           "interpolate_in_triangles", "nearest_sites", "pad_masked"]


@njit(nogil=True, cache=True)
def _block_sum(a, lo, n):
    """:func:`pairwise_sum` of at most 128 values."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0 = a[lo]
    r1 = a[lo + 1]
    r2 = a[lo + 2]
    r3 = a[lo + 3]
    r4 = a[lo + 4]
    r5 = a[lo + 5]
    r6 = a[lo + 6]
    r7 = a[lo + 7]
    i = 8
    stop = n - (n % 8)
    while i < stop:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(nogil=True, cache=True)
def pairwise_sum(a, lo, n):
    """``a[lo:lo + n].sum()`` of a float64 vector, summed as numpy sums a contiguous one.

    Below 8 values one after the other; up to 128 in eight interleaved partial sums combined
    as ``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then the rest; above that the
    sum of the two halves' sums (the first half a multiple of 8 long), each summed so in turn
    (an explicit stack: numba's cache does not keep recursive functions safely).
    """
    if n <= 128:
        return _block_sum(a, lo, n)
    depth = 64
    s_lo = np.empty(depth, np.int64)
    s_n = np.empty(depth, np.int64)
    s_stage = np.empty(depth, np.int64)
    s_left = np.empty(depth)
    top = 0
    s_lo[0], s_n[0], s_stage[0] = lo, n, 0
    result = 0.0
    while top >= 0:
        m = s_n[top]
        if m <= 128:
            value = _block_sum(a, s_lo[top], m)
            top -= 1
        elif s_stage[top] == 0:
            half = m // 2
            half -= half % 8
            s_stage[top] = 1
            top += 1
            s_lo[top], s_n[top], s_stage[top] = s_lo[top - 1], half, 0
            continue
        else:
            value = s_left[top]  # stage 2: both halves known (combined below)
            top -= 1
        # hand the value to the parent
        while top >= 0:
            if s_stage[top] == 1:
                half = s_n[top] // 2
                half -= half % 8
                s_left[top] = value
                s_stage[top] = 2
                top += 1
                s_lo[top], s_n[top], s_stage[top] = s_lo[top - 1] + half, s_n[top - 1] - half, 0
                break
            value = s_left[top] + value  # stage 2: left + right
            top -= 1
        else:
            result = value
    return result


@njit(nogil=True, cache=True)
def bilinear_grid(src, x, y, c, s, nrows, ncols, out):
    """Bilinear samples of a padded source on a rotated ``nrows x ncols`` grid.

    Parameters
    ----------
    src : ndarray of shape (H + 2, W + 2, C), float32
        A one-pixel zero border around the image.
    x, y : float
        The grid's centre, pixels of the image.
    c, s : float
        ``cos(theta)``, ``sin(theta)``: the grid's columns run along ``(c, -s)``, its rows
        along ``(s, c)``.
    nrows, ncols : int
    out : ndarray of shape (nrows, ncols, C), float32, written
        Coordinates in float64 (clipped to the border), weights and blending in float32.
    """
    H = src.shape[0] - 2
    W = src.shape[1] - 2
    nch = src.shape[2]
    f1 = np.float32(1.0)
    for i in range(nrows):
        row = i - (nrows - 1) / 2.0
        for j in range(ncols):
            col = j - (ncols - 1) / 2.0
            xs = min(max(x + 1 + row * s + col * c, 0.0), W + 1.0)
            ys = min(max(y + 1 + row * c + col * -s, 0.0), H + 1.0)
            x0 = min(np.intp(np.floor(xs)), W)
            y0 = min(np.intp(np.floor(ys)), H)
            fx = np.float32(xs - x0)
            fy = np.float32(ys - y0)
            gx = f1 - fx
            gy = f1 - fy
            for k in range(nch):
                top = src[y0, x0, k] * gx + src[y0, x0 + 1, k] * fx
                bot = src[y0 + 1, x0, k] * gx + src[y0 + 1, x0 + 1, k] * fx
                out[i, j, k] = top * gy + bot * fy


@njit(nogil=True, cache=True)
def _masked_values(dep, ok, buf):
    """The values of ``dep`` where ``ok``, row-major, into ``buf``; their number."""
    m = 0
    for i in range(dep.shape[0]):
        for j in range(dep.shape[1]):
            if ok[i, j]:
                buf[m] = dep[i, j]
                m += 1
    return m


@njit(nogil=True, cache=True)
def sample_crop(src, x, y, c, s, nrows, ncols, one, gray, depth_scale, outlier_sigma,
                outlier_passes, full, inside, dvalid, dep):
    """One crop's samples, masks and its K, R, G, B, D channels.

    Parameters
    ----------
    src : ndarray of shape (H + 2, W + 2, 6), float32
        The padded source of :func:`dlsr.preprocess._check_image` (R, G, B, depth, validity,
        inside).
    x, y : float
        The crop's centre, pixels.
    c, s : float
        ``cos(theta)``, ``sin(theta)`` (numpy's, computed by the caller).
    nrows, ncols : int
    one : float32
        Bilinear weights at least this large count as 1 (``1 - 1e-6`` in float32, as numpy
        compares a float32 array with a Python float).
    gray : ndarray of shape (3,), float32
        Gray weights.
    depth_scale, outlier_sigma : float
    outlier_passes : int
    full : ndarray of shape (nrows, ncols, 8), float32, zeros, written
        K, R, G, B (0 outside the source) and, with valid depth, D
        (``(depth - mean) * depth_scale``, 0 where invalid); the normals' channels are left
        as they are.
    inside, dvalid : ndarray of shape (nrows, ncols), bool, written
    dep : ndarray of shape (nrows, ncols), float64, written
        D in float64 (the sampled depth when no pixel has valid depth).

    Returns
    -------
    bool
        Whether any pixel has valid depth.
    """
    smp = np.empty((nrows, ncols, src.shape[2]), np.float32)
    bilinear_grid(src, x, y, c, s, nrows, ncols, smp)
    for i in range(nrows):
        for j in range(ncols):
            ins = smp[i, j, 5] >= one
            inside[i, j] = ins
            dvalid[i, j] = (smp[i, j, 4] >= one) and ins
            dep[i, j] = np.float64(smp[i, j, 3])
            r = smp[i, j, 0] if ins else np.float32(0.0)
            g = smp[i, j, 1] if ins else np.float32(0.0)
            b = smp[i, j, 2] if ins else np.float32(0.0)
            full[i, j, 1] = r
            full[i, j, 2] = g
            full[i, j, 3] = b
            full[i, j, 0] = gray[0] * r + gray[1] * g + gray[2] * b
    buf = np.empty(nrows * ncols)
    for _ in range(outlier_passes):
        m = _masked_values(dep, dvalid, buf)
        if m < 2:
            break
        mu = pairwise_sum(buf, 0, m) / m
        for t in range(m):
            d = buf[t] - mu
            buf[t] = d * d
        sd = np.sqrt(pairwise_sum(buf, 0, m) / (m - 1))
        lim = outlier_sigma * sd
        for i in range(nrows):
            for j in range(ncols):
                if abs(dep[i, j] - mu) > lim:
                    dvalid[i, j] = False
    m = _masked_values(dep, dvalid, buf)
    if m == 0:
        return False
    mu = pairwise_sum(buf, 0, m) / m
    for i in range(nrows):
        for j in range(ncols):
            d = (dep[i, j] - mu) * depth_scale if dvalid[i, j] else 0.0
            dep[i, j] = d
            full[i, j, 4] = np.float32(d)
    return True


@njit(nogil=True, cache=True)
def _slopes(z, transpose, g):
    """Central differences along the columns of ``z`` (of ``z.T`` with ``transpose``), cubic
    extrapolation at the ends (linear with two values, zero with one), into ``g``."""
    m = z.shape[0]
    n = z.shape[1]
    lines = n if transpose else m
    length = m if transpose else n
    for a in range(lines):
        for b in range(length):
            if length == 1:
                g[a, b] = 0.0
                continue
            if transpose:
                cur_m = z[b - 1, a] if b > 0 else 0.0
                cur_p = z[b + 1, a] if b < length - 1 else 0.0
            else:
                cur_m = z[a, b - 1] if b > 0 else 0.0
                cur_p = z[a, b + 1] if b < length - 1 else 0.0
            if b == 0:
                if transpose:
                    a0, a1 = z[0, a], z[1, a]
                    lo = 2 * a0 - a1 if length == 2 else 3 * a0 - 3 * a1 + z[2, a]
                else:
                    a0, a1 = z[a, 0], z[a, 1]
                    lo = 2 * a0 - a1 if length == 2 else 3 * a0 - 3 * a1 + z[a, 2]
                cur_m = lo
            if b == length - 1:
                if transpose:
                    e1, e2 = z[length - 1, a], z[length - 2, a]
                    hi = 2 * e1 - e2 if length == 2 else 3 * e1 - 3 * e2 + z[length - 3, a]
                else:
                    e1, e2 = z[a, length - 1], z[a, length - 2]
                    hi = 2 * e1 - e2 if length == 2 else 3 * e1 - 3 * e2 + z[a, length - 3]
                cur_p = hi
            g[a, b] = (cur_p - cur_m) / 2.0


@njit(nogil=True, cache=True)
def normals(z, out):
    """:func:`dlsr.preprocess.surface_normals` of ``z`` (m, n) float64 into ``out`` (m, n, 3),
    float32 (any strides)."""
    m = z.shape[0]
    n = z.shape[1]
    gx = np.empty((m, n))
    gyt = np.empty((n, m))
    _slopes(z, False, gx)
    _slopes(z, True, gyt)
    for i in range(m):
        for j in range(n):
            a = gx[i, j]
            b = gyt[j, i]
            inv = 1.0 / np.sqrt(a * a + b * b + 1.0)
            out[i, j, 0] = np.float32(-a * inv)
            out[i, j, 1] = np.float32(-b * inv)
            out[i, j, 2] = np.float32(inv)


@njit(nogil=True, cache=True)
def hole_band(valid, band):
    """The valid pixels within ``band`` pixels (chessboard distance) of an invalid one: what
    ``valid & binary_dilation(~valid, 3x3, iterations=band)`` gives (outside counts as
    valid)."""
    m, n = valid.shape
    near = np.zeros((m, n), np.bool_)
    for i in range(m):
        for j in range(n):
            if not valid[i, j]:
                for a in range(max(i - band, 0), min(i + band + 1, m)):
                    for b in range(max(j - band, 0), min(j + band + 1, n)):
                        near[a, b] = True
    for i in range(m):
        for j in range(n):
            near[i, j] = near[i, j] and valid[i, j]
    return near


@njit(nogil=True, cache=True)
def interpolate_in_triangles(pts, values, simplices, holes, out):
    """Linear interpolation of the holes in the triangles of integer pixel positions.

    Parameters
    ----------
    pts : ndarray of shape (k, 2), int64
        ``(row, col)`` of the triangulated pixels.
    values : ndarray of shape (k,), float64
    simplices : ndarray of shape (t, 3), int
        Triangles (indices into ``pts``), e.g. a Delaunay triangulation's.
    holes : ndarray of shape (m, n), bool, written
        Pixels to fill; those inside a triangle (on its edges included) are set to False.
    out : ndarray of shape (m, n), float64, written
        Each filled hole's value: with ``r`` the triangle's third vertex and ``(b0, b1)``
        the barycentric coordinates of the first two from Cramer's rule on the integer
        offsets, ``v0 b0 + v1 b1 + v2 (1 - (b0 + b1))``. A hole on an edge shared by two
        triangles takes the first triangle's value (the same up to float rounding). Triangles
        of zero area are skipped.
    """
    m, n = holes.shape
    for t in range(simplices.shape[0]):
        i0, i1, i2 = simplices[t, 0], simplices[t, 1], simplices[t, 2]
        r0y, r0x = pts[i0, 0], pts[i0, 1]
        r1y, r1x = pts[i1, 0], pts[i1, 1]
        ry, rx = pts[i2, 0], pts[i2, 1]
        ay, ax = r0y - ry, r0x - rx
        by, bx = r1y - ry, r1x - rx
        det = ay * bx - ax * by
        if det == 0:
            continue
        lo_y = max(min(r0y, r1y, ry), 0)
        hi_y = min(max(r0y, r1y, ry), m - 1)
        lo_x = max(min(r0x, r1x, rx), 0)
        hi_x = min(max(r0x, r1x, rx), n - 1)
        for qy in range(lo_y, hi_y + 1):
            for qx in range(lo_x, hi_x + 1):
                if not holes[qy, qx]:
                    continue
                dy, dx = qy - ry, qx - rx
                n0 = dy * bx - dx * by  # det[q - r, p1 - r]
                n1 = ay * dx - ax * dy  # det[p0 - r, q - r]
                n2 = det - n0 - n1
                if det > 0:
                    if n0 < 0 or n1 < 0 or n2 < 0:
                        continue
                elif n0 > 0 or n1 > 0 or n2 > 0:
                    continue
                b0 = n0 / det
                b1 = n1 / det
                w2 = 1.0 - (b0 + b1)
                out[qy, qx] = values[i0] * b0 + values[i1] * b1 + values[i2] * w2
                holes[qy, qx] = False


@njit(nogil=True, cache=True)
def _envelope_row(fr, fc, n, row, g, out_r, out_c):
    """One row of the exact Euclidean feature transform (Maurer, Qi and Raghavan 2003): of the
    sites ``(fr[j], fc[j])`` its columns found (``fr[j] < 0``: none), those whose Voronoi
    cells cross the row are kept in order, then each pixel takes the nearest, the earlier on a
    tie."""
    top = -1
    for j in range(n):
        if fr[j] < 0:
            continue
        fd = float(fc[j])
        tw = float(fr[j]) - row
        w2 = tw * tw
        while top >= 1:
            k1 = g[top]
            k2 = g[top - 1]
            f1 = float(fc[k1])
            a = f1 - float(fc[k2])
            b = fd - f1
            c = a + b
            tu = float(fr[k2]) - row
            tv = float(fr[k1]) - row
            if c * (tv * tv) - b * (tu * tu) - a * w2 - a * b * c <= 0.0:
                break
            top -= 1
        top += 1
        g[top] = j
    if top < 0:
        for j in range(n):
            out_r[j] = -1
            out_c[j] = -1
        return
    k = 0
    for j in range(n):
        s = g[k]
        t0 = float(fr[s]) - row
        t1 = float(fc[s]) - j
        d1 = t0 * t0 + t1 * t1
        while k < top:
            s2 = g[k + 1]
            t0 = float(fr[s2]) - row
            t1 = float(fc[s2]) - j
            d2 = t0 * t0 + t1 * t1
            if d1 <= d2:
                break
            d1 = d2
            k += 1
        out_r[j] = fr[g[k]]
        out_c[j] = fc[g[k]]


@njit(nogil=True, cache=True)
def nearest_sites(site, need, iy, ix):
    """The nearest ``site`` pixel of the pixels of the rows ``need`` (exact Euclidean
    distance), as ``scipy.ndimage.distance_transform_edt(~site, return_indices=True)`` chooses
    it: the same separable algorithm, down the columns (the nearest site of each column, the
    upper of two equally near), then along each row among the columns' nearest sites (the
    earlier of two equally near), so that ties are broken the same way. A row's result needs
    only that row of the first pass: the rows not needed are skipped.

    Parameters
    ----------
    site : ndarray of shape (m, n), bool
        At least one True.
    need : ndarray of shape (m,), bool
        The rows whose pixels are wanted.
    iy, ix : ndarray of shape (m, n), int64, written in the rows ``need``
        Row and column of each pixel's nearest site.
    """
    m, n = site.shape
    size = max(m, n)
    for j in range(n):  # down each column: the nearest site in the column, the upper on a tie
        up = -1
        for i in range(m):
            if site[i, j]:
                up = i
            if need[i]:
                iy[i, j] = up  # the nearest above (or here) for now
        down = -1
        for i in range(m - 1, -1, -1):
            if site[i, j]:
                down = i
            if need[i]:
                above = iy[i, j]
                if above < 0 or (down >= 0 and down - i < i - above):
                    iy[i, j] = down
                ix[i, j] = j
    fr = np.empty(size, np.int64)
    fc = np.empty(size, np.int64)
    g = np.empty(size, np.int64)
    out_r = np.empty(size, np.int64)
    out_c = np.empty(size, np.int64)
    for i in range(m):  # along each row, among the columns' nearest sites
        if not need[i]:
            continue
        for j in range(n):
            fr[j] = iy[i, j]
            fc[j] = ix[i, j]
        _envelope_row(fr, fc, n, float(i), g, out_r, out_c)
        for j in range(n):
            iy[i, j] = out_r[j]
            ix[i, j] = out_c[j]


@njit(nogil=True, cache=True)
def pad_masked(g0, g1, g2, r0, c0, img, msk):
    """The resized crop into the padded image: masks ``> 0.75``, masked values 0.

    Parameters
    ----------
    g0, g1 : ndarray of shape (nh, nw, 4), float32
        The image channels (K, R, G, B) and the depth channels (D, Nx, Ny, Nz), resized.
    g2 : ndarray of shape (nh, nw, 4), float32
        The image mask and the depth mask (channels 0 and 1), resized.
    r0, c0 : int
        Where the crop's first row and column go.
    img : ndarray of shape (size, size, 8), float32, written in the crop's place
    msk : ndarray of shape (size, size, 8), bool, written in the crop's place
    """
    nh, nw = g0.shape[0], g0.shape[1]
    thr = np.float32(0.75)
    for i in range(nh):
        for j in range(nw):
            im = g2[i, j, 0] > thr
            dm = g2[i, j, 1] > thr
            for ch in range(4):
                msk[r0 + i, c0 + j, ch] = im
                msk[r0 + i, c0 + j, 4 + ch] = dm
                img[r0 + i, c0 + j, ch] = g0[i, j, ch] if im else np.float32(0.0)
                img[r0 + i, c0 + j, 4 + ch] = g1[i, j, ch] if dm else np.float32(0.0)
