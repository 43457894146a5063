"""Compiled lasso homotopy (LARS-lasso) per patch, with snapshots along the path.

One call solves ``min_a 0.5 a^T G a - b^T a + lam ||a||_1`` for many rows ``b`` and, per row,
for a decreasing sequence of penalties: the homotopy starts at ``lam_max = max |b|`` with
``a = 0`` and follows the piecewise-linear path of solutions down to the smallest penalty,
recording the exact solution each time it crosses one of the requested penalties. The paper's
grids (lasso ``{0.5, 1, 1.5, 2}``, masked lasso ``{1, 2, 3, 4}``) therefore cost one path, not
four solves.

Per step the work is ``O(k d)`` for the correlation direction (the Gram columns of the ``k``
active atoms, kept per row; this product runs in float32, about 15 % faster for the whole
path, because every recorded solution is recomputed and checked in float64 anyway) and
``O(k^2)`` for the bordered / downdated inverse of the active Gram block, in float64 (the
direction ``u = G_AA^{-1} s`` itself is updated in ``O(k)`` when an atom enters or leaves and
recomputed every 16 steps: 8 % faster on real patches, the same codes). For
rows with their own mask the Gram column of an entering atom,
``D diag(m) d_j``, is computed when it enters (``O(d p)``); rows sharing a Gram matrix read it.

At every snapshot the coefficients are recomputed as ``a_A = G_AA^{-1} (b_A - lam s_A)`` plus one
step of iterative refinement, the correlations are recomputed exactly, and the lasso optimality
(KKT) conditions are checked: ``|c_j| <= lam`` off the support, sign agreement on it. A row that
fails, or exceeds the step limit, is flagged so that the caller solves it another way.
Snapshots are computed aside, from the active set of the segment they fall on, and leave the
path's state alone: the path, and so each recorded solution, is the same bit for bit whichever
other penalties are requested (OMP likewise records refined copies), so encoding a test fold at
one chosen parameter gives exactly the codes the whole grid gives.

Also here, the other compiled per-row solve of :mod:`dlsr.coding`: orthogonal matching pursuit
with snapshots at several numbers of atoms (:func:`omp_path_rows`), on the same Gram columns.

Compiled with numba (``nogil``, cached on disk): callers run chunks of rows in threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["lasso_path_rows", "omp_path_rows"]


_FAST = {"reassoc", "contract", "nsz"}  # vectorised sums and FMA; infinities stay exact


@njit(nogil=True, cache=True)
def _mask_entries(m, G, d, idx):
    """The entries a row's masked Gram columns sum over: ``(count, subtract)``, indices in ``idx``.

    With fewer masked entries than valid ones (and ``G``, the unmasked Gram matrix, given) a
    column is ``G[:, j]`` minus the masked entries' terms (``subtract``), else the sum of the
    valid entries' terms.
    """
    p = m.shape[0]
    n_valid = 0
    for q in range(p):
        if m[q] != 0.0:
            n_valid += 1
    subtract = n_valid * 2 >= p and G.shape[0] == d
    nq = 0
    for q in range(p):
        if (m[q] == 0.0) == subtract:
            idx[nq] = q
            nq += 1
    return nq, subtract


@njit(nogil=True, cache=True)
def _argmin(x, n):
    """Smallest of ``x[:n]`` and its first index (``inf, -1`` when all are ``inf``): four
    independent running minima, so that the comparisons do not wait on each other."""
    m0 = np.inf
    m1 = np.inf
    m2 = np.inf
    m3 = np.inf
    i0 = -1
    i1 = -1
    i2 = -1
    i3 = -1
    j = 0
    while j + 4 <= n:
        x0 = x[j]
        x1 = x[j + 1]
        x2 = x[j + 2]
        x3 = x[j + 3]
        if x0 < m0:
            m0 = x0
            i0 = j
        if x1 < m1:
            m1 = x1
            i1 = j + 1
        if x2 < m2:
            m2 = x2
            i2 = j + 2
        if x3 < m3:
            m3 = x3
            i3 = j + 3
        j += 4
    while j < n:
        if x[j] < m0:
            m0 = x[j]
            i0 = j
        j += 1
    best = m0
    ib = i0
    if m1 < best or (m1 == best and m1 < np.inf and i1 < ib):
        best = m1
        ib = i1
    if m2 < best or (m2 == best and m2 < np.inf and i2 < ib):
        best = m2
        ib = i2
    if m3 < best or (m3 == best and m3 < np.inf and i3 < ib):
        best = m3
        ib = i3
    return best, ib


@njit(nogil=True, cache=True, fastmath=_FAST)
def _column(j, G, Dt, use_mask, idx, nq, subtract, out):
    """Gram column ``G[:, j]`` (shared) or ``D diag(m) d_j`` (per-row mask) into ``out``.

    For a mask, ``idx[:nq]`` and ``subtract`` come from :func:`_mask_entries`: the column is
    ``G[:, j] - sum_{q masked} D[j, q] D[:, q]`` or ``sum_{q valid} D[j, q] D[:, q]``, four
    entries per pass over ``out`` (a quarter of its loads and stores).
    """
    d = out.shape[0]
    if not use_mask or (subtract and nq == 0):
        for i in range(d):
            out[i] = G[j, i]
        return
    if subtract:
        for i in range(d):
            out[i] = G[j, i]
    else:
        for i in range(d):
            out[i] = 0.0
    sign = -1.0 if subtract else 1.0
    r = 0
    while r + 4 <= nq:
        q0 = idx[r]
        q1 = idx[r + 1]
        q2 = idx[r + 2]
        q3 = idx[r + 3]
        w0 = sign * Dt[q0, j]
        w1 = sign * Dt[q1, j]
        w2 = sign * Dt[q2, j]
        w3 = sign * Dt[q3, j]
        for i in range(d):
            out[i] += (w0 * Dt[q0, i] + w1 * Dt[q1, i]) + (w2 * Dt[q2, i] + w3 * Dt[q3, i])
        r += 4
    while r < nq:
        q0 = idx[r]
        w0 = sign * Dt[q0, j]
        for i in range(d):
            out[i] += w0 * Dt[q0, i]
        r += 1


@njit(nogil=True, cache=True, fastmath=_FAST)
def lasso_path_rows(B, lams, G, Dt, M, use_mask, out, rows, slots, ok, max_steps, rtol):
    """Lasso homotopy for every row of ``B`` with snapshots at ``lams[i, :]``.

    Parameters
    ----------
    B : ndarray of shape (n, d), float64
        Correlations ``D diag(m) x`` per row.
    lams : ndarray of shape (n, t), float64
        Penalties per row, strictly decreasing along axis 1, all >= 0.
    G : ndarray of shape (d, d), float64
        Shared Gram matrix; with ``use_mask``, the unmasked Gram matrix ``D D^T`` (or a
        1x1 placeholder, then masked columns are summed over the valid entries).
    Dt : ndarray of shape (p, d), float64
        Transposed dictionary (used when ``use_mask``).
    M : ndarray of shape (n, p), float64
        Per-row masks as 0/1 (used when ``use_mask``).
    use_mask : bool
    out : ndarray of shape (T, N, d), float32 or float64
        Zero-initialised output, written in place (the caller's result, so that no per-chunk
        copy is made): row ``i``'s solution at ``lams[i, s]`` goes to
        ``out[slots[s], rows[i]]``.
    rows : ndarray of shape (n,), int64
    slots : ndarray of shape (t,), int64
    ok : ndarray of shape (n,), bool
        Set to False for rows that failed the optimality check or the step limit.
    max_steps : int
    rtol : float
        Relative tolerance of the optimality check.
    """
    n, d = B.shape
    t_count = lams.shape[1]
    kmax = d
    Gc32 = np.empty((kmax, d), dtype=np.float32)
    e32 = np.empty(d, dtype=np.float32)
    Gc = np.empty((kmax, d))  # Gram columns of the active atoms, one per slot
    Ginv = np.empty((kmax, kmax))  # inverse of the active Gram block
    act = np.empty(kmax, dtype=np.int64)  # atom in each slot
    sgn = np.empty(kmax)
    coef = np.empty(kmax)
    u = np.empty(kmax)
    v = np.empty(kmax)
    ga = np.empty(kmax)
    gout = np.empty(kmax)  # step at which each active coefficient reaches 0
    cs = np.empty(kmax)  # a recorded solution on the active atoms
    cc = np.empty(d)  # its exact correlations
    c = np.empty(d)
    e = np.empty(d)
    col = np.empty(d)
    gbuf = np.empty(d)
    pen = np.zeros(d)  # +inf on atoms that cannot enter (active, or excluded for this row)
    excluded = np.empty(d, dtype=np.int64)
    midx = np.empty(Dt.shape[0], dtype=np.int64)
    for i in range(n):
        b = B[i]
        nq, subtract = 0, False
        if use_mask:
            nq, subtract = _mask_entries(M[i], G, d, midx)
        n_excl = 0
        # start of the path: a = 0, lam = max |b|
        j0 = 0
        lam = 0.0
        for j in range(d):
            c[j] = b[j]
            if abs(b[j]) > lam:
                lam = abs(b[j])
                j0 = j
        t = 0
        while t < t_count and lams[i, t] >= lam:
            t += 1  # the solution is 0 down to lam_max
        if t == t_count:
            continue
        _column(j0, G, Dt, use_mask, midx, nq, subtract, col)
        if col[j0] <= 0.0:  # an atom with no valid entries cannot carry the maximum
            ok[i] = False
            continue
        k = 1
        act[0] = j0
        sgn[0] = 1.0 if c[j0] > 0 else -1.0
        coef[0] = 0.0
        Ginv[0, 0] = 1.0 / col[j0]
        for q in range(d):
            Gc[0, q] = col[q]
            Gc32[0, q] = col[q]
        pen[j0] = np.inf
        last_drop = -1
        finished = False
        for step in range(max_steps):
            # direction of the active coefficients per unit decrease of lam, u = Ginv s,
            # updated in O(k) when an atom enters or leaves, recomputed every 16 steps
            if step % 16 == 0:
                for a in range(k):
                    s = 0.0
                    for bb in range(k):
                        s += Ginv[a, bb] * sgn[bb]
                    u[a] = s
            # e = G[:, A] u in float32 (16 lanes), four active atoms per pass over e: the
            # O(k d) part of a step; the path's snapshots and KKT check stay in float64
            for q in range(d):
                e32[q] = 0.0
            a = 0
            while a + 4 <= k:
                u0 = np.float32(u[a])
                u1 = np.float32(u[a + 1])
                u2 = np.float32(u[a + 2])
                u3 = np.float32(u[a + 3])
                for q in range(d):
                    e32[q] += ((u0 * Gc32[a, q] + u1 * Gc32[a + 1, q])
                               + (u2 * Gc32[a + 2, q] + u3 * Gc32[a + 3, q]))
                a += 4
            while a < k:
                ua = np.float32(u[a])
                for q in range(d):
                    e32[q] += ua * Gc32[a, q]
                a += 1
            for q in range(d):
                e[q] = e32[q]
            # entering: c_j - g e_j = +-(lam - g); branch-free so that it vectorises
            if last_drop >= 0:
                pen[last_drop] = np.inf
            for j in range(d):
                cj = c[j]
                ej = e[j]
                n1 = max(lam - cj, 0.0)
                n2 = max(lam + cj, 0.0)
                d1 = 1.0 - ej
                d2 = 1.0 + ej
                g1 = n1 / d1 if d1 > 1e-30 else np.inf
                g2 = n2 / d2 if d2 > 1e-30 else np.inf
                gbuf[j] = min(g1, g2) + pen[j]
            if last_drop >= 0:
                pen[last_drop] = 0.0
            gam_in, j_in = _argmin(gbuf, d)
            # leaving: a coefficient crosses zero
            # (branch-free, so that the divisions vectorise; then the first smallest)
            for a in range(k):
                ua = u[a]
                g = -coef[a] / ua if ua != 0.0 else np.inf
                gout[a] = g if g > 0.0 else np.inf
            gam_out, q_out = _argmin(gout, k)
            # every requested penalty reached on this segment [lam - gam, lam] is recorded
            # from the segment's active set without touching the path's state, so that the
            # path (and each recorded solution) does not depend on which penalties are asked for
            gam = min(gam_in, gam_out)
            while t < t_count and lams[i, t] >= lam - gam:
                if not _snapshot(k, act, sgn, b, lams[i, t], Ginv, Gc, rtol, cs, cc, v, ga):
                    ok[i] = False
                    finished = True
                    break
                for a in range(k):
                    out[slots[t], rows[i], act[a]] = cs[a]
                t += 1
            if finished:
                break
            if t == t_count:
                finished = True
                break
            for a in range(k):
                coef[a] += gam * u[a]
            for q in range(d):
                c[q] -= gam * e[q]
            lam -= gam
            if gam_out < gam_in:
                # drop slot q_out: Schur downdate, then move the last slot into its place
                q = q_out
                ipiv = 1.0 / Ginv[q, q]
                uq = u[q] * ipiv
                for a in range(k):
                    u[a] -= Ginv[a, q] * uq
                for a in range(k):
                    for bb in range(k):
                        if a != q and bb != q:
                            Ginv[a, bb] -= Ginv[a, q] * ipiv * Ginv[q, bb]
                jd = act[q]
                pen[jd] = 0.0
                last_drop = jd
                last = k - 1
                if q != last:
                    act[q] = act[last]
                    sgn[q] = sgn[last]
                    coef[q] = coef[last]
                    u[q] = u[last]
                    for x in range(d):
                        Gc[q, x] = Gc[last, x]
                        Gc32[q, x] = Gc32[last, x]
                    for a in range(k):
                        Ginv[q, a] = Ginv[last, a]
                    for a in range(k):
                        Ginv[a, q] = Ginv[a, last]
                    Ginv[q, q] = Ginv[last, last]
                k -= 1
                continue
            if j_in < 0:  # nothing can enter and nothing leaves: degenerate
                ok[i] = False
                finished = True
                break
            # add j_in: bordered inverse
            jn = j_in
            last_drop = -1
            _column(jn, G, Dt, use_mask, midx, nq, subtract, col)
            sigma = _schur(k, act, col, jn, Ginv, ga, v)
            if sigma <= 1e-10 * max(col[jn], 1e-300) or k == kmax:
                # in the span of the active atoms (e.g. a repeated atom): it stays at 0
                pen[jn] = np.inf
                excluded[n_excl] = jn
                n_excl += 1
                continue
            _border(k, Ginv, v, sigma)
            act[k] = jn
            sgn[k] = 1.0 if c[jn] > 0 else -1.0
            alpha = -sgn[k]
            for a in range(k):
                alpha += v[a] * sgn[a]
            alpha /= sigma
            for a in range(k):
                u[a] += alpha * v[a]
            u[k] = -alpha
            coef[k] = 0.0
            for q in range(d):
                Gc[k, q] = col[q]
                Gc32[k, q] = col[q]
            pen[jn] = np.inf
            k += 1
            if step % 16 == 15:  # re-synchronise the correlations
                _correlations(k, b, coef, Gc, c)
        if not finished:
            ok[i] = False
        for a in range(k):
            pen[act[a]] = 0.0
        for x in range(n_excl):
            pen[excluded[x]] = 0.0


@njit(nogil=True, cache=True, fastmath=_FAST)
def _correlations(k, b, coef, Gc, c):
    """``c = b - G_A coef``: the correlations of the residual of the ``k`` atoms' coefficients
    (their Gram columns ``Gc[:k]``), in float64."""
    for q in range(c.shape[0]):
        c[q] = b[q]
    for a in range(k):
        ca = coef[a]
        for q in range(c.shape[0]):
            c[q] -= ca * Gc[a, q]


@njit(nogil=True, cache=True, fastmath=_FAST)
def _snapshot(k, act, sgn, b, lam, Ginv, Gc, rtol, coef, c, v, res):
    """The lasso solution at ``lam`` on the active set (signs ``sgn``): ``coef = G_AA^{-1}
    (b_A - lam s)`` plus one refinement step, its exact correlations ``c = b - G_A coef`` and
    the optimality (KKT) check, ``|c_j| <= lam`` off the support and sign agreement on it
    (relative tolerance ``rtol``). Returns whether the check passed."""
    d = c.shape[0]
    for a in range(k):
        v[a] = b[act[a]] - lam * sgn[a]
    for a in range(k):
        s = 0.0
        for bb in range(k):
            s += Ginv[a, bb] * v[bb]
        coef[a] = s
    _refine(k, act, v, Gc, Ginv, coef, res)
    _correlations(k, b, coef, Gc, c)
    tol = rtol * max(lam, 1.0)
    for a in range(k):
        if coef[a] * sgn[a] < -tol or abs(c[act[a]] - lam * sgn[a]) > tol:
            return False
    for j in range(d):
        if abs(c[j]) > lam + tol:
            active = False
            for a in range(k):
                if act[a] == j:
                    active = True
            if not active:
                return False
    return True


@njit(nogil=True, cache=True, fastmath=_FAST)
def _schur(k, act, col, j, Ginv, g, v):
    """Schur complement ``sigma = G_jj - g^T G_AA^{-1} g`` of atom ``j`` against the ``k``
    active atoms ``act`` (``col``: its Gram column); fills ``g = G_Aj`` and ``v = G_AA^{-1} g``."""
    for a in range(k):
        g[a] = col[act[a]]
    for a in range(k):
        s = 0.0
        for bb in range(k):
            s += Ginv[a, bb] * g[bb]
        v[a] = s
    sigma = col[j]
    for a in range(k):
        sigma -= g[a] * v[a]
    return sigma


@njit(nogil=True, cache=True, fastmath=_FAST)
def _border(k, Ginv, v, sigma):
    """Grow ``Ginv`` (``k x k``, the inverse of ``G_AA``) to ``k + 1`` for the atom whose
    :func:`_schur` gave ``v`` and ``sigma`` (the bordered inverse)."""
    inv = 1.0 / sigma  # one division: a division per entry took 14 % of a long path
    for a in range(k):
        w = v[a] * inv
        for bb in range(k):
            Ginv[a, bb] += w * v[bb]
    for a in range(k):
        Ginv[k, a] = -v[a] * inv
        Ginv[a, k] = -v[a] * inv
    Ginv[k, k] = inv


@njit(nogil=True, cache=True, fastmath=_FAST)
def _refine(k, act, rhs, Gc, Ginv, coef, res):
    """One step of iterative refinement of ``coef``, the solution of ``G_AA coef = rhs`` on the
    ``k`` active atoms ``act`` (``Gc``: their exact Gram columns, ``Ginv``: the inverse of
    ``G_AA``; ``res``: scratch)."""
    for s in range(k):
        acc = rhs[s]
        for q in range(k):
            acc -= Gc[q, act[s]] * coef[q]
        res[s] = acc
    for s in range(k):
        acc = 0.0
        for q in range(k):
            acc += Ginv[s, q] * res[q]
        coef[s] += acc


@njit(nogil=True, cache=True, fastmath=_FAST)
def _refined_copy(k, act, b, Gc, Ginv, coef, rhs, res, out):
    """``out`` = the least-squares coefficients ``coef`` on the ``k`` selected atoms after one
    refinement step (``coef`` itself unchanged)."""
    for s in range(k):
        rhs[s] = b[act[s]]
        out[s] = coef[s]
    _refine(k, act, rhs, Gc, Ginv, out, res)


@njit(nogil=True, cache=True, fastmath=_FAST)
def omp_path_rows(B, G, Dt, M, use_mask, stops, out, rows, slots, tiny):
    """Orthogonal matching pursuit for every row of ``B``, with snapshots at ``stops`` atoms.

    Per row: select the atom of largest absolute residual correlation, border the inverse of
    the selected atoms' Gram block (a row stops when the new atom is numerically dependent on
    the selected ones, ``sigma <= 1e-10 diag``, or when the residual correlation vanishes,
    ``c_j^2 <= tiny``), solve the least squares on the selected atoms, and update the residual
    correlations ``c = b - G_S a_S`` (``O(k d)``). All in float64; Gram columns as in the
    lasso (:func:`_column`: shared, or the row's masked column computed when the atom enters),
    so masked least squares are exact.

    Parameters
    ----------
    B : ndarray of shape (n, d), float64
        Correlations ``D diag(m) x`` per row.
    G : ndarray of shape (d, d), float64
        Shared Gram matrix (with ``use_mask``: the unmasked one, or a 1x1 placeholder).
    Dt : ndarray of shape (p, d), float64
        Transposed dictionary (used when ``use_mask``).
    M : ndarray of shape (n, p), float64
        Per-row masks as 0/1 (used when ``use_mask``).
    use_mask : bool
    stops : ndarray of shape (t,), int64
        Increasing numbers of atoms, each in ``[1, d]``.
    out : ndarray of shape (T, N, d), float32 or float64
        Zero-initialised, written in place; row ``i``'s solution with ``stops[s]`` atoms goes
        to ``out[slots[s], rows[i]]`` (the last solution when the row stopped earlier).
    rows : ndarray of shape (n,), int64
    slots : ndarray of shape (t,), int64
    tiny : float
    """
    n, d = B.shape
    n_stops = stops.shape[0]
    L = stops[n_stops - 1]
    Gc = np.empty((L, d))
    Ginv = np.empty((L, L))
    act = np.empty(L, dtype=np.int64)
    coef = np.empty(L)
    g = np.empty(L)
    v = np.empty(L)
    res = np.empty(L)
    rhs = np.empty(L)
    cs = np.empty(L)  # a recorded (refined) solution
    c = np.empty(d)
    col = np.empty(d)
    midx = np.empty(Dt.shape[0], dtype=np.int64)
    for i in range(n):
        b = B[i]
        nq, subtract = 0, False
        if use_mask:
            nq, subtract = _mask_entries(M[i], G, d, midx)
        for a in range(d):
            c[a] = b[a]
        k = 0
        si = 0
        for _t in range(L):
            for s in range(k):  # selected atoms cannot be chosen again
                c[act[s]] = 0.0
            bv = 0.0
            for a in range(d):  # two passes: the maximum vectorises, then its first index
                bv = max(bv, abs(c[a]))
            if not bv * bv > tiny:
                break
            best = 0
            while abs(c[best]) != bv:
                best += 1
            _column(best, G, Dt, use_mask, midx, nq, subtract, col)
            diag = col[best]
            sigma = _schur(k, act, col, best, Ginv, g, v)
            if not (sigma > 1e-10 * max(diag, tiny) and sigma > tiny):
                break
            _border(k, Ginv, v, sigma)
            act[k] = best
            for a in range(d):
                Gc[k, a] = col[a]
            k += 1
            for s in range(k):
                acc = 0.0
                for q in range(k):
                    acc += Ginv[s, q] * b[act[q]]
                coef[s] = acc
            if si < n_stops and stops[si] == k:  # recorded refined, the path continues as is
                _refined_copy(k, act, b, Gc, Ginv, coef, rhs, res, cs)
                while si < n_stops and stops[si] == k:
                    for s in range(k):
                        out[slots[si], rows[i], act[s]] = cs[s]
                    si += 1
            if k < L:
                _correlations(k, b, coef, Gc, c)
        # stopped early: later stops keep its last solution (refined once)
        if si < n_stops and k > 0 and not (si > 0 and stops[si - 1] == k):
            _refined_copy(k, act, b, Gc, Ginv, coef, rhs, res, cs)
        while si < n_stops:
            for s in range(k):
                out[slots[si], rows[i], act[s]] = cs[s]
            si += 1
