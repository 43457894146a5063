"""Exactness of the encoders in dlsr.coding against scikit-learn, on random and real patches."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from sklearn.decomposition import sparse_encode
from sklearn.linear_model import orthogonal_mp_gram

from dlsr.coding import (
    SparseEncoder,
    kmeans_triangle,
    lasso,
    lasso_objective,
    lasso_path,
    lasso_rowwise,
    natural_encoder,
    omp,
    omp_path,
    polarity_split,
    soft_threshold,
    soft_threshold_path,
)


@pytest.fixture(scope="module")
def real_patches(jacquard_root):
    """Whitened real 6x6x8 patches (288 dims) with masks, and an RP dictionary of 300 atoms.

    Built with the project's pipeline (rectangle images -> patches -> standardisation -> ZCA)
    from a few real Jacquard views; the single place to change how real patches are made.
    """
    from dlsr.datasets import load_jacquard
    from dlsr.patches import sample_patches
    from dlsr.preprocess import rectangle_images
    from dlsr.rectangles import rects_to_array
    from dlsr.whitening import apply_zca, fit_zca, standardize_patches

    samples = load_jacquard(jacquard_root)[:4]
    ims, ms = [], []
    for s in samples:
        im, m = rectangle_images(s, rects_to_array(s.positives)[::6])
        ims.append(im)
        ms.append(m)
    X, M = sample_patches(np.concatenate(ims), np.concatenate(ms), 4000, 0.2, 0)
    Xs = standardize_patches(X, M)
    mean, P = fit_zca(Xs, M)
    Xw = apply_zca(Xs, M, mean, P).astype(np.float64)
    rng = np.random.default_rng(1)
    # patches are drawn with replacement and overlap: keep atoms with |cos| < 0.95 to one another
    cand = Xw[rng.permutation(len(Xw))[:1500]]
    cand = cand / np.linalg.norm(cand, axis=1, keepdims=True)
    keep = []
    for i in range(len(cand)):
        if not keep or np.abs(cand[keep] @ cand[i]).max() < 0.95:
            keep.append(i)
        if len(keep) == 300:
            break
    D = cand[keep]
    return Xw[:400], M[:400], D


@pytest.fixture(scope="module")
def random_problem():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((150, 20))
    D = rng.standard_normal((30, 20))
    D[:5] *= 0.5  # atoms need not be unit norm
    D[5:] /= np.linalg.norm(D[5:], axis=1, keepdims=True)
    M = rng.random(X.shape) > 0.3
    return X, D, M


def _problems(request, names):
    return [request.getfixturevalue(n) for n in names]


def _rel_obj_gap(X, D, A, R, lam, mask=None):
    o1 = lasso_objective(X, D, A, lam, mask)
    o2 = lasso_objective(X, D, R, lam, mask)
    return np.max((o1 - o2) / np.maximum(o2, 1e-12))


def _masked_gradient(X, D, A, M):
    return ((X - A @ D) * M) @ D.T


# ---------------------------------------------------------------------------------------------
# lasso


@pytest.mark.parametrize("lam", [0.05, 0.5])
def test_lasso_matches_lasso_lars_random(random_problem, lam):
    X, D, _ = random_problem
    A = lasso(X, D, lam, dtype=np.float64)
    R = sparse_encode(X, D, algorithm="lasso_lars", alpha=lam)
    assert _rel_obj_gap(X, D, A, R, lam) <= 1e-5
    # and sklearn is not better anywhere by more than rounding
    assert np.max(lasso_objective(X, D, A, lam) - lasso_objective(X, D, R, lam)) < 1e-6


# scikit-learn's LARS warns about (and drops) nearly degenerate regressors at small lambda on
# real patches; its answer is still the reference objective.
@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
@pytest.mark.parametrize("lam", [0.5, 1.0, 2.0])
def test_lasso_matches_lasso_lars_real(real_patches, lam):
    X, _, D = real_patches
    X = X[:150]
    A = lasso(X, D, lam)  # float32 output, as the pipeline uses it
    R = sparse_encode(X, D, algorithm="lasso_lars", alpha=lam)
    assert _rel_obj_gap(X, D, A, R, lam) <= 1e-5
    assert np.mean(np.all((A != 0) == (R != 0), axis=1)) > 0.9


def test_lasso_kkt_unmasked(real_patches):
    X, _, D = real_patches
    lam = 1.0
    A = lasso(X, D, lam, dtype=np.float64)
    C = (X - A @ D) @ D.T
    on = A != 0
    assert np.all(np.abs(C[~on]) <= lam * (1 + 1e-6))
    assert np.allclose(C[on], lam * np.sign(A[on]), atol=1e-6)
    assert on.sum(axis=1).mean() > 5  # a real sparse problem, not all zeros


def test_lasso_zero_when_lambda_large(random_problem):
    X, D, _ = random_problem
    lam = np.abs(X @ D.T).max() * 1.01
    assert not np.any(lasso(X, D, lam))


def test_lasso_masked_all_ones_equals_unmasked(real_patches):
    X, _, D = real_patches
    ones = np.ones(X.shape, dtype=bool)
    A = lasso(X, D, 1.0, dtype=np.float64)
    # shared-mask path and per-row masked path
    A1 = lasso(X, D, 1.0, mask=ones, dtype=np.float64)
    A2 = lasso(X, D, 1.0, mask=ones, min_group=10**9, dtype=np.float64)
    np.testing.assert_allclose(A1, A, atol=1e-8)
    np.testing.assert_allclose(A2, A, atol=1e-6)


@pytest.mark.parametrize("fixture", ["random_problem", "real_patches"])
@pytest.mark.parametrize("min_group", [1, 10**9])
def test_lasso_masked_kkt(request, fixture, min_group):
    X, D, M = (request.getfixturevalue(fixture)[i] for i in ((0, 1, 2) if fixture ==
               "random_problem" else (0, 2, 1)))
    lam = 0.3 if fixture == "random_problem" else 2.0
    A = lasso(X, D, lam, mask=M, min_group=min_group, dtype=np.float64)
    lam_rows = lam * M.sum(axis=1) / X.shape[1]
    C = _masked_gradient(X, D, A, M)
    on = A != 0
    L = np.broadcast_to(lam_rows[:, None], A.shape)
    assert np.all(np.abs(C[~on]) <= L[~on] * (1 + 1e-6) + 1e-9)
    assert np.allclose(C[on], L[on] * np.sign(A[on]), atol=1e-6)
    assert on.any()


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_lasso_masked_matches_rowwise_lars(real_patches):
    X, M, D = real_patches
    X, M = X[:40], M[:40]
    lam = 1.5
    A = lasso(X, D, lam, mask=M, dtype=np.float64)
    p = X.shape[1]
    for i in range(len(X)):
        m = M[i]
        r = sparse_encode(X[i : i + 1, m], D[:, m], algorithm="lasso_lars",
                          alpha=lam * m.sum() / p)
        o_ours = lasso_objective(X[i : i + 1], D, A[i : i + 1], lam, M[i : i + 1])[0]
        o_ref = lasso_objective(X[i : i + 1], D, r, lam, M[i : i + 1])[0]
        assert o_ours <= o_ref * (1 + 1e-5) + 1e-12


def test_lasso_repeated_atoms(random_problem):
    # Exactly repeated atoms make the solution non-unique and scikit-learn's LARS drops
    # regressors (its batch and per-row answers even differ): check optimality (KKT) instead.
    X, D, _ = random_problem
    D2 = np.vstack([D, D[:3], -D[3:4]])
    lam = 0.3
    A = lasso(X, D2, lam, dtype=np.float64)
    C = (X - A @ D2) @ D2.T
    on = A != 0
    assert np.all(np.abs(C[~on]) <= lam * (1 + 1e-6))
    assert np.allclose(C[on], lam * np.sign(A[on]), atol=1e-6)
    ref = lasso(X, D, lam, dtype=np.float64)  # same optimum without the copies
    np.testing.assert_allclose(lasso_objective(X, D2, A, lam), lasso_objective(X, D, ref, lam),
                               rtol=1e-9)


@pytest.mark.parametrize("masked", [False, True])
def test_lasso_path_equals_separate_solves(real_patches, masked):
    X, M, D = real_patches
    X, M = X[:150], (M[:150] if masked else None)
    lams = [2.0, 0.5, 1.0, 1.0, 1.5]  # any order, duplicates allowed
    P = lasso_path(X, D, lams, mask=M, min_group=10**9, dtype=np.float64)
    assert P.shape == (len(lams), len(X), D.shape[0])
    for t, lam in enumerate(lams):
        ref = sparse_encode(X, D, algorithm="lasso_lars", alpha=lam) if not masked else None
        A = lasso(X, D, lam, mask=M, min_group=10**9, dtype=np.float64)
        np.testing.assert_allclose(P[t], A, atol=1e-9)
        if ref is not None:
            assert _rel_obj_gap(X, D, P[t], ref, lam) < 1e-6
    # a smaller penalty keeps more atoms on this path
    nnz = [(P[lams.index(v)] != 0).sum() for v in (2.0, 1.5, 1.0, 0.5)]
    assert nnz == sorted(nnz) and nnz[0] < nnz[-1]


@pytest.mark.parametrize("path", ["lasso", "omp"])
def test_paths_read_given_correlations(real_patches, path):
    """``correlations`` is used as ``(X * mask) D^T``: the caller's product gives the same codes,
    a different one different codes, a wrong shape an error."""
    X, M, D = real_patches
    X, M = X[:60], M[:60]
    fn, grid = (lasso_path, [1.0, 2.0]) if path == "lasso" else (omp_path, [1, 5])
    for mask in (None, M):
        Xm = X * mask if mask is not None else X
        own = fn(X, D, grid, mask=mask)
        given = fn(X, D, grid, mask=mask, correlations=Xm @ D.T)
        np.testing.assert_array_equal(own, given)
        other = fn(X, D, grid, mask=mask, correlations=0.5 * (Xm @ D.T))
        assert not np.allclose(other, own)
    with pytest.raises(ValueError, match="correlations"):
        fn(X, D, grid, correlations=np.zeros((len(X) + 1, D.shape[0])))


@pytest.mark.parametrize("path", ["lasso", "omp"])
def test_gram_cache_keeps_each_mask_groups_gram_matrix(real_patches, path):
    """Rows sharing a mask read ``D diag(m) D^T`` from the cache when it holds it: the same codes
    as without a cache, other codes from other matrices, and no other dictionary."""
    X, M, D = real_patches
    patterns = M[:3]
    M = patterns[np.arange(120) % 3]
    X = np.where(M, X[:120], 0.0)
    fn, grid = (lasso_path, [1.0, 2.0]) if path == "lasso" else (omp_path, [1, 5])
    cache = {}
    codes = fn(X, D, grid, mask=M, min_group=10, gram_cache=cache)
    assert len(cache) == 1 + len(patterns)  # the dictionary, one matrix per mask
    for m in patterns:
        np.testing.assert_allclose(cache[np.packbits(m).tobytes()], (D * m) @ D.T)
    np.testing.assert_array_equal(codes, fn(X, D, grid, mask=M, min_group=10))
    np.testing.assert_array_equal(codes, fn(X, D, grid, mask=M, min_group=10, gram_cache=cache))
    halved = {k: (v if k == "dictionary" else 0.5 * v) for k, v in cache.items()}
    assert not np.allclose(fn(X, D, grid, mask=M, min_group=10, gram_cache=halved), codes)
    with pytest.raises(ValueError, match="another dictionary"):
        fn(X, 2 * D, grid, mask=M, min_group=10, gram_cache=cache)
    with pytest.raises(TypeError, match="gram_cache"):
        fn(X, D, grid, mask=M, gram_cache=[])


@pytest.mark.parametrize("masked", [False, True])
def test_paths_do_not_depend_on_the_other_requested_values(real_patches, masked):
    """A penalty's (a number of atoms') codes are the same bit for bit alone or among others:
    recording a solution does not change the path."""
    X, M, D = real_patches
    X, M = X[:200], (M[:200] if masked else None)
    grid = lasso_path(X, D, [0.5, 1.0, 1.5, 2.0], mask=M, dtype=np.float64)
    for t, lam in enumerate([0.5, 1.0, 1.5, 2.0]):
        np.testing.assert_array_equal(lasso_path(X, D, [lam], mask=M, dtype=np.float64)[0],
                                      grid[t])
    grid = omp_path(X, D, [1, 5, 10, 15], mask=M, dtype=np.float64)
    for t, L in enumerate([1, 5, 10, 15]):
        np.testing.assert_array_equal(omp_path(X, D, [L], mask=M, dtype=np.float64)[0],
                                      grid[t])


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_lasso_path_rows_over_the_step_limit_fall_back_to_lars(real_patches):
    X, M, D = real_patches
    X, M = X[:30], M[:30]
    A = lasso_path(X, D, [1.0, 2.0], mask=M, max_steps=3, dtype=np.float64)
    for t, lam in enumerate([1.0, 2.0]):
        R = lasso_rowwise(X, D, lam, M)
        assert _rel_obj_gap(X, D, A[t], R, lam, M) < 1e-6


def test_lasso_path_validates(random_problem):
    X, D, _ = random_problem
    for bad in ([], [0.5, -1.0], [[0.5]], [np.nan]):
        with pytest.raises(ValueError, match="lams"):
            lasso_path(X, D, bad)
    with pytest.raises(ValueError, match="lasso_path"):
        lasso(X, D, [0.5, 1.0])


def test_lasso_does_not_mutate_and_validates(random_problem):
    X, D, M = random_problem
    Xc, Dc, Mc = X.copy(), D.copy(), M.copy()
    lasso(X, D, 0.2, mask=M)
    assert np.array_equal(X, Xc) and np.array_equal(D, Dc) and np.array_equal(M, Mc)
    with pytest.raises(ValueError, match="features"):
        lasso(X[:, :5], D, 0.1)
    with pytest.raises(ValueError, match="finite"):
        Xn = X.copy()
        Xn[0, 0] = np.nan
        lasso(Xn, D, 0.1)
    with pytest.raises(ValueError, match="lam"):
        lasso(X, D, -1.0)
    with pytest.raises(ValueError, match="mask"):
        lasso(X, D, 0.1, mask=M[:, :3])


# ---------------------------------------------------------------------------------------------
# OMP


def _sk_omp(X, D, L):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return sparse_encode(X, D, algorithm="omp", n_nonzero_coefs=L)


@pytest.mark.parametrize("L", [1, 3, 7])
def test_omp_matches_sklearn_random(random_problem, L):
    X, D, _ = random_problem
    A = omp(X, D, L, dtype=np.float64)
    R = _sk_omp(X, D, L)
    assert np.array_equal(A != 0, R != 0)
    np.testing.assert_allclose(A, R, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("L", [1, 5, 10])
def test_omp_matches_sklearn_real(real_patches, L):
    X, _, D = real_patches
    A = omp(X, D, L, dtype=np.float64)
    R = _sk_omp(X, D, L)
    # once a residual is exhausted the remaining picks are noise-level near-ties: compare the
    # coefficients that matter
    big = np.abs(R) > 1e-4 * np.abs(R).max(axis=1, keepdims=True)
    same = np.all((np.abs(A) > 1e-4 * np.abs(A).max(axis=1, keepdims=True)) == big, axis=1)
    assert same.mean() >= 0.99
    np.testing.assert_allclose(A[same], R[same], atol=1e-4)


@pytest.mark.parametrize("L", [1, 4])
def test_omp_masked_all_ones_and_rowwise(random_problem, L):
    X, D, M = random_problem
    A = omp(X, D, L, dtype=np.float64)
    ones = np.ones(X.shape, dtype=bool)
    np.testing.assert_allclose(omp(X, D, L, mask=ones, min_group=10**9, dtype=np.float64), A,
                               atol=1e-5)
    Am = omp(X, D, L, mask=M, min_group=10**9, dtype=np.float64)
    for i in range(len(X)):
        m = M[i]
        Dm = D[:, m]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            r = orthogonal_mp_gram(Dm @ Dm.T, Dm @ X[i, m], n_nonzero_coefs=L)
        np.testing.assert_allclose(Am[i], r, atol=1e-5, rtol=1e-4)


def test_omp_masked_real_exact_least_squares(real_patches):
    X, M, D = real_patches
    A = omp(X, D, 5, mask=M, dtype=np.float64)
    # exact masked least squares: the masked residual is orthogonal to the selected atoms
    C = _masked_gradient(X, D, A, M)
    on = A != 0
    assert np.all((on.sum(axis=1) >= 1) & (on.sum(axis=1) <= 5))
    assert np.mean(on.sum(axis=1) == 5) > 0.9
    assert np.abs(C[on]).max() < 1e-3 * np.abs(X).max()


@pytest.mark.parametrize("masked", [False, True])
def test_omp_path_equals_separate_runs(real_patches, masked):
    X, M, D = real_patches
    X, M = X[:200], (M[:200] if masked else None)
    Ls = [10, 1, 5, 15, 5]
    P = omp_path(X, D, Ls, mask=M, min_group=10**9, dtype=np.float64)
    assert P.shape == (len(Ls), len(X), D.shape[0])
    for t, L in enumerate(Ls):
        A = omp(X, D, L, mask=M, min_group=10**9, dtype=np.float64)
        np.testing.assert_allclose(P[t], A, atol=1e-9)
        assert np.all((P[t] != 0).sum(axis=1) <= L)
    if not masked:  # and scikit-learn's OMP with that many atoms
        np.testing.assert_allclose(P[2], _sk_omp(X, D, 5), atol=1e-5, rtol=1e-4)


def _merge_copies(A, D):
    """Codes with the coefficients of identical atoms summed onto the first copy, and the
    number of copies of each atom a row uses."""
    first = np.array([np.flatnonzero(np.all(D == D[j], axis=1))[0] for j in range(len(D))])
    S = np.zeros((len(D), len(D)))
    S[np.arange(len(D)), first] = 1.0
    return A @ S, (A != 0) @ S


@pytest.mark.parametrize("masked", [False, True])
def test_omp_stops_early_on_dependent_atoms_and_exhausted_residuals(masked):
    """A rank-4 dictionary with a repeated atom: no row can use more than 4 atoms, a zero row
    gets no atom, a row equal to an atom is coded by that atom, and every longer L repeats the
    last solution; the codes are scikit-learn's up to which copy of the repeated atom carries
    the coefficient (a tie broken by the rounding of the BLAS products, which depends on the
    kernels the CPU runs: see :func:`dlsr.coding.omp`)."""
    rng = np.random.default_rng(3)
    D = rng.standard_normal((5, 4))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    D = np.vstack([D, D[2]])  # repeated atom: 6 atoms spanning 4 dimensions
    X = np.vstack([rng.standard_normal((20, 4)), np.zeros(4), 2.5 * D[1]])
    M = np.ones_like(X, dtype=bool) if masked else None
    Ls = [1, 2, 4, 6]
    P = omp_path(X, D, Ls, mask=M, min_group=10**9, dtype=np.float64)
    nnz = (P != 0).sum(axis=2)
    assert np.all(nnz[3] <= 4) and np.array_equal(nnz[3], nnz[2])
    np.testing.assert_array_equal(P[3], P[2])  # the same run, stopped: no arithmetic between
    assert not P[:, 20].any()
    expected = np.zeros(6)
    expected[1] = 2.5  # further picks are noise-level, as in scikit-learn
    np.testing.assert_allclose(P[:, 21], np.tile(expected, (4, 1)), atol=1e-8)
    for t, L in enumerate(Ls):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            R = orthogonal_mp_gram(D @ D.T, (X @ D.T).T, n_nonzero_coefs=min(L, 4)).T
        merged, copies = _merge_copies(P[t], D)
        merged_ref, _ = _merge_copies(R, D)
        assert copies.max() <= 1  # never both copies: the second is dependent on the first
        # the atoms that matter (after an exhausted residual, picks are noise-level)
        np.testing.assert_array_equal((np.abs(P[t]) > 1e-8).sum(axis=1),
                                      (np.abs(R) > 1e-8).sum(axis=1))
        np.testing.assert_allclose(merged, merged_ref, atol=1e-8)
        np.testing.assert_allclose(P[t] @ D, R @ D, atol=1e-8)  # the same reconstruction


def test_omp_validates(random_problem):
    X, D, _ = random_problem
    for bad in (0, [5, 0], [], [1.5]):
        with pytest.raises(ValueError, match="n_nonzero"):
            omp_path(X, D, bad) if np.ndim(bad) else omp(X, D, bad)


# ---------------------------------------------------------------------------------------------
# dense encoders


@pytest.mark.parametrize("lam", [0.0, 0.5])
def test_soft_threshold_matches_sklearn(random_problem, lam):
    X, D, _ = random_problem
    A = soft_threshold(X, D, lam, dtype=np.float64)
    R = sparse_encode(X, D, algorithm="threshold", alpha=lam)
    np.testing.assert_allclose(A, R, atol=1e-10)
    np.testing.assert_allclose(soft_threshold(X, D, lam), R, atol=1e-4)


def test_soft_threshold_path_is_each_threshold(random_problem):
    X, D, _ = random_problem
    lams = [1.5, 0.0, 0.5]
    P = soft_threshold_path(X, D, lams, dtype=np.float64)
    assert P.shape == (3, len(X), len(D))
    for t, lam in enumerate(lams):
        np.testing.assert_allclose(P[t], soft_threshold(X, D, lam, dtype=np.float64), atol=1e-12)
    with pytest.raises(ValueError, match="lams"):
        soft_threshold_path(X, D, [0.5, -1.0])


def test_triangle_formula(random_problem):
    X, D, _ = random_problem
    Z = np.linalg.norm(X[:, None, :] - D[None], axis=2)
    ref = np.maximum(Z.mean(axis=1, keepdims=True) - Z, 0)
    np.testing.assert_allclose(kmeans_triangle(X, D, dtype=np.float64), ref, atol=1e-8)
    np.testing.assert_allclose(kmeans_triangle(X, D), ref, atol=1e-3)


@pytest.mark.parametrize("encode", [lambda X, D: soft_threshold(X, D, 0.5, chunk_size=16),
                                    lambda X, D: kmeans_triangle(X, D, chunk_size=16)],
                         ids=["soft_threshold", "triangle"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("row", [0, 37, 99])  # first, a middle and the last chunk
def test_dense_encoders_reject_non_finite_rows(random_problem, encode, bad, row):
    # whatever the BLAS kernels do with NaN and inf (OpenBLAS's AVX-512 ones warn on inf), the
    # error comes first and names the row
    X, D, _ = random_problem
    Xb = np.repeat(X, 5, axis=0)[:100].copy()
    Xb[row, 3] = bad
    with pytest.raises(ValueError, match=f"finite.*row {row}"):  # checked before products
        encode(Xb, D)
    encode(np.repeat(X, 5, axis=0)[:100], D)  # the clean rows pass


def test_triangle_rounding_never_gives_nan():
    # a patch equal to a centroid: ||x||^2 - 2 x.c + ||c||^2 rounds to a tiny negative
    rng = np.random.default_rng(3)
    C = rng.standard_normal((20, 288)).astype(np.float32) * 30
    A = kmeans_triangle(C, C)
    assert np.all(np.isfinite(A)) and np.all(A >= 0)
    assert np.all(A[np.arange(20), np.arange(20)] > 0)  # its own centroid is nearest


def test_polarity_split():
    A = np.array([[1.0, -2.0, 0.0]])
    np.testing.assert_array_equal(polarity_split(A), [[1, 0, 0, 0, 2, 0]])
    with pytest.raises(ValueError):
        polarity_split(np.zeros(3))


# ---------------------------------------------------------------------------------------------
# natural encoders and the estimator


def test_natural_encoders(random_problem):
    X, D, M = random_problem
    d = D.shape[0]
    sc = natural_encoder("SC", D, lam=0.3)
    np.testing.assert_allclose(sc.transform(X), polarity_split(lasso(X, D, 0.3)), atol=1e-6)
    om = natural_encoder("OMP", D, n_nonzero=3)
    np.testing.assert_allclose(om.transform(X), polarity_split(omp(X, D, 3)), atol=1e-6)
    gs = natural_encoder("GSVQ", D)
    codes = gs.transform(X, mask=M)
    np.testing.assert_allclose(codes, polarity_split(omp(X, D, 1, mask=M)), atol=1e-6)
    assert np.all((codes != 0).sum(axis=1) <= 1)
    for m in ("RP", "R"):
        np.testing.assert_allclose(natural_encoder(m, D).transform(X),
                                   polarity_split(X @ D.T), atol=1e-4)
    nkm = natural_encoder("NKM", centroids=D)
    out = nkm.transform(X)
    assert out.shape == (len(X), d)  # no polarity split
    np.testing.assert_allclose(out, kmeans_triangle(X, D), atol=1e-5)
    with pytest.raises(ValueError, match="lam"):
        natural_encoder("SC", D)
    with pytest.raises(ValueError, match="unknown"):
        natural_encoder("XYZ", D)


def test_sparse_encoder_estimator(random_problem):
    X, D, M = random_problem
    enc = SparseEncoder("lasso", dictionary=D, lam=0.2, polarity=False).fit(X)
    np.testing.assert_allclose(enc.transform(X), lasso(X, D, 0.2), atol=1e-6)
    menc = SparseEncoder("omp", dictionary=D, n_nonzero=2, masked=True).fit(X)
    np.testing.assert_allclose(menc.transform(X, mask=M), polarity_split(omp(X, D, 2, mask=M)),
                               atol=1e-6)
    with pytest.raises(ValueError, match="masked=False"):
        enc.transform(X, mask=M)
    with pytest.raises(ValueError, match="features"):
        SparseEncoder(dictionary=D[:, :4]).fit(X)
    with pytest.raises(ValueError, match="unknown encoder"):
        SparseEncoder("nope", dictionary=D).fit(X)
    # no dictionary: random normalised training rows, deterministic for a seed
    a = SparseEncoder(n_atoms=7, random_state=3).fit(X).dictionary_
    b = SparseEncoder(n_atoms=7, random_state=3).fit(X).dictionary_
    assert a.shape == (7, X.shape[1]) and np.array_equal(a, b)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0)


def test_threads_give_same_codes(real_patches):
    X, M, D = real_patches
    a = lasso(X, D, 1.0, mask=M, chunk_size=64)
    b = lasso(X, D, 1.0, mask=M, chunk_size=64, n_jobs=2)
    np.testing.assert_array_equal(a, b)


def test_natural_encode_function(random_problem):
    from dlsr.coding import natural_encode

    X, D, M = random_problem
    C = D * 1.7  # "un-normalised centroids"
    np.testing.assert_allclose(natural_encode(X, M, "NKM", D, centroids=C), kmeans_triangle(X, C),
                               atol=1e-6)
    np.testing.assert_allclose(natural_encode(X, M, "GSVQ", D),
                               polarity_split(omp(X, D, 1, mask=M)), atol=1e-6)
    np.testing.assert_allclose(natural_encode(X, None, "SC", D, param=0.4, polarity=False),
                               lasso(X, D, 0.4), atol=1e-6)
    assert natural_encode(X, None, "OMP", D, param=2).shape == (len(X), 2 * len(D))


def test_natural_spec_names_each_learner_computation():
    from dlsr.coding import natural_spec

    assert natural_spec("SC", 0.7) == dict(method="lasso", masked=False, polarity=True,
                                           value=0.7)
    assert natural_spec("SC")["value"] == 1.0 and natural_spec("OMP")["value"] == 10
    assert natural_spec("OMP", 3.0)["value"] == 3
    assert natural_spec("GSVQ") == dict(method="omp", masked=True, polarity=True, value=1)
    assert natural_spec("RP") == natural_spec("R") == dict(method="threshold", masked=False,
                                                           polarity=True, value=0.0)
    assert natural_spec("NKM") == dict(method="triangle", masked=False, polarity=False,
                                       value=None)
    with pytest.raises(ValueError, match="unknown dictionary method"):
        natural_spec("KSVD")


@pytest.mark.parametrize("p", [8, 288, 291])  # whole, multiple-of-64 and ragged packed widths
def test_group_by_mask_partitions_rows_by_identical_mask(p):
    from dlsr.coding import _group_by_mask

    rng = np.random.default_rng(0)
    kinds = rng.random((6, p)) < 0.7
    M = kinds[rng.integers(0, 6, 500)]
    M[:40] = rng.random((40, p)) < 0.5  # mostly unique masks
    groups, rest = _group_by_mask(M, min_group=20)
    seen = np.concatenate(groups + [rest])
    assert np.array_equal(np.sort(seen), np.arange(500))
    for rows in groups:
        assert len(rows) >= 20 and np.all(np.diff(rows) > 0)
        assert np.all(M[rows] == M[rows[0]])
    # a rest row has fewer than min_group identical rows
    for r in rest[:50]:
        assert np.sum(np.all(M == M[r], axis=1)) < 20


def _padded_masks(rng, n_rows=400, p=288):
    """Masks like a rectangle's patches: a padding pattern per group of rows (whole pixels of
    the 6 x 6 x 8 patch masked), plus depth holes of each row (channels 4-7 of a few pixels,
    of most pixels in every 50th row)."""
    pixels = p // 8
    M = np.ones((n_rows, pixels, 8), dtype=bool)
    for r in range(n_rows):
        M[r, : 6 * (r % 3)] = False  # 0, 6 or 12 padded pixels: three padding patterns
        holes = rng.random(pixels) < (0.9 if r % 50 == 0 else 0.15)
        M[r, holes, 4:] = False
    return M.reshape(n_rows, p)


@pytest.mark.parametrize("path", ["lasso", "omp"])
def test_base_masks_give_the_same_codes_from_the_base_gram(path, monkeypatch):
    """Rows sharing a padding pattern start their masked Gram columns from its Gram matrix and
    subtract only their depth holes: the codes of every row are those computed from D D^T
    (equal up to rounding, here to float32's resolution), the base Gram matrices are formed,
    and a row with holes in most pixels keeps the plain computation."""
    from dlsr import coding as c

    rng = np.random.default_rng(8)
    M = _padded_masks(rng)
    X = (rng.standard_normal(M.shape) * M).astype(np.float32)
    D = rng.standard_normal((40, M.shape[1]))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    base = np.repeat(M.reshape(len(M), -1, 8)[:, :, :1], 8, axis=2).reshape(M.shape) | M
    base[::50] = True  # these rows: padding and most depth masked within an all-valid base
    fn, values = (c.lasso_path, [0.2, 0.5]) if path == "lasso" else (c.omp_path, [1, 5])
    plain = fn(X, D, values, mask=M)
    formed = []
    real = c._group_gram

    def recording(D64, m, cache):
        formed.append(m.copy())
        return real(D64, m, cache)

    monkeypatch.setattr(c, "_group_gram", recording)
    based = fn(X, D, values, mask=M, base_mask=base)
    np.testing.assert_allclose(based, plain, rtol=0, atol=1e-6)
    patterns = {b.tobytes() for b in base}
    assert sum(m.tobytes() in patterns for m in formed) >= 3  # the three padding patterns
    groups, left = c._base_groups(M, base, np.arange(len(M)), 32)
    many = np.count_nonzero(base & ~M, axis=1) * 2 > M.shape[1]
    assert many.any() and set(np.flatnonzero(many)) <= set(left)
    assert sorted(np.r_[np.concatenate(groups), left]) == list(range(len(M)))


def test_a_base_mask_that_does_not_contain_the_mask_is_an_error():
    from dlsr import coding

    rng = np.random.default_rng(0)
    X = rng.standard_normal((10, 16))
    D = rng.standard_normal((4, 16))
    M = rng.random((10, 16)) > 0.3
    with pytest.raises(ValueError, match="base_mask must contain the mask"):
        coding.lasso_path(X, D, [0.5], mask=M, base_mask=M & (rng.random((10, 16)) > 0.5))
    with pytest.raises(ValueError, match="base_mask must have the shape"):
        coding.omp_path(X, D, [2], mask=M, base_mask=M[:5])
