"""The six dictionaries: shapes, constraints, determinism and the reference semantics."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.coding import kmeans_triangle, lasso, polarity_split
from dlsr.dictionaries import (
    METHODS,
    DictionaryLearner,
    gsvq,
    kmeans,
    learn_dictionary,
    online_dictionary_learning,
    random_patches,
)


@pytest.fixture(scope="module")
def data():
    """Clustered data with structure a dictionary can find (8 directions + noise)."""
    rng = np.random.default_rng(0)
    basis = rng.standard_normal((8, 24))
    basis /= np.linalg.norm(basis, axis=1, keepdims=True)
    codes = rng.standard_normal((3000, 8)) * (rng.random((3000, 8)) < 0.25)
    X = codes @ basis + 0.01 * rng.standard_normal((3000, 24))
    return X, basis


FAST = {"SC": dict(n_iter=30, batch_size=100, lam=0.1), "OMP": dict(n_iter=30, batch_size=100,
        n_nonzero=3), "GSVQ": dict(n_iter=10), "NKM": dict(n_iter=10)}


@pytest.mark.parametrize("method", METHODS)
def test_shapes_norms_determinism(data, method):
    X, _ = data
    kw = FAST.get(method, {})
    D1 = learn_dictionary(X, method, 16, random_state=3, **kw)
    D2 = learn_dictionary(X, method, 16, random_state=3, **kw)
    D3 = learn_dictionary(X, method, 16, random_state=4, **kw)
    assert D1.shape == (16, X.shape[1])
    assert np.all(np.isfinite(D1))
    np.testing.assert_array_equal(D1, D2)
    assert not np.array_equal(D1, D3)
    norms = np.linalg.norm(D1, axis=1)
    if method in ("SC", "OMP"):
        assert np.all(norms <= 1 + 1e-9)
    else:
        np.testing.assert_allclose(norms, 1.0, atol=1e-6)


def test_rp_atoms_are_patches(data):
    X, _ = data
    D = random_patches(X, 10, random_state=0)
    Xn = X / np.linalg.norm(X, axis=1, keepdims=True)
    # each atom is one of the normalised patches
    assert np.all(np.max(D @ Xn.T, axis=1) > 1 - 1e-9)


@pytest.mark.parametrize("method", ["SC", "OMP"])
def test_online_learning_recovers_structure(data, method):
    X, basis = data
    D = online_dictionary_learning(X, 8, "lasso" if method == "SC" else "omp", lam=0.05,
                                   n_nonzero=2, batch_size=200, n_batches=150, random_state=0)
    # every true direction is matched by a learned atom
    match = np.abs(basis @ (D / np.linalg.norm(D, axis=1, keepdims=True)).T).max(axis=1)
    assert np.median(match) > 0.95


def test_sc_learning_lowers_the_lasso_objective(data):
    X, _ = data
    D0 = random_patches(X, 12, random_state=0)
    D = online_dictionary_learning(X, 12, "lasso", lam=0.1, batch_size=200, n_batches=100,
                                   random_state=0)

    def obj(Dd):
        A = lasso(X[:500], Dd, 0.1, dtype=np.float64)
        R = X[:500] - A @ Dd
        return 0.5 * (R * R).sum() + 0.1 * np.abs(A).sum()

    assert obj(D) < 0.7 * obj(D0)


def test_kmeans_lloyd_and_empty_cluster_reset(data):
    X, _ = data
    C, labels, inertia = kmeans(X, 20, n_iter=100, random_state=0)
    # a Lloyd fixed point up to the last update: centroids are the means of their clusters
    for k in np.unique(labels)[:5]:
        np.testing.assert_allclose(C[k], X[labels == k].mean(axis=0), atol=1e-3)
    d2 = ((X[:, None, :] - C[None]) ** 2).sum(-1)
    # each row at its nearest centroid, up to the float32 rounding of the assignment's
    # ||c||^2 / 2 - x.c (a few 1e-7 of ||x||^2 + ||c||^2): which of two centroids at distances
    # that close wins depends on the BLAS kernels, so only (nearly) all rows must agree exactly
    nearest = d2.min(axis=1)
    scale = (X**2).sum(axis=1) + (C**2).sum(axis=1).max()
    assert np.all(d2[np.arange(len(X)), labels] - nearest <= 1e-5 * scale)
    assert np.mean(labels == d2.argmin(axis=1)) > 0.99
    np.testing.assert_allclose(inertia, nearest.sum(), rtol=1e-4)
    # far-away random init: most clusters start empty and must be reset, not left at 0 / NaN
    C2, labels2, _ = kmeans(X, 20, n_iter=5, random_state=0, init_scale=100.0)
    assert np.all(np.isfinite(C2))
    assert len(np.unique(labels2)) > 10


def test_kmeans_gives_a_tie_between_identical_centroids_to_the_first():
    """Their distances differ by rounding only, which depends on the BLAS kernels and on each
    copy's column in the product: the rows go to the first copy, on every machine."""
    from dlsr.dictionaries import _assign

    rng = np.random.default_rng(2)
    C = rng.standard_normal((21, 40)).astype(np.float32)
    C[[7, 13, 20]] = C[2]  # copies in other places of the product's tiles
    X = (C[2] + 0.05 * rng.standard_normal((500, 40))).astype(np.float32)
    X[:100] = rng.standard_normal((100, 40))  # rows nearest to other centroids too
    labels = _assign(X, C)
    assert not np.isin(labels, [7, 13, 20]).any()
    assert np.sum(labels == 2) >= 400
    d2 = ((X[:, None, :].astype(np.float64) - C[None]) ** 2).sum(-1)
    d2[:, [7, 13, 20]] = np.inf  # without the copies, the plain nearest centroid
    assert np.mean(labels == d2.argmin(axis=1)) > 0.99


def test_kmeans_beats_sklearn_or_matches(data):
    from sklearn.cluster import KMeans

    X, _ = data
    _, _, ours = kmeans(X, 10, n_iter=100, random_state=0)
    ref = KMeans(10, init="random", n_init=1, max_iter=100, tol=0, random_state=0).fit(X)
    assert ours <= 1.2 * ref.inertia_


def test_gsvq_fixed_point(data):
    X, basis = data
    D = gsvq(X, 8, n_iter=30, random_state=0)
    P = X @ D.T
    j = np.argmax(np.abs(P), axis=1)
    for k in range(8):
        sel = j == k
        if sel.any():
            u = (P[sel, k][:, None] * X[sel]).sum(axis=0)
            np.testing.assert_allclose(D[k], u / np.linalg.norm(u), atol=1e-3)
    match = np.abs(basis @ D.T).max(axis=1)
    assert np.median(match) > 0.9


def test_learner_estimator_and_natural_transform(data):
    X, _ = data
    nkm = DictionaryLearner("NKM", 12, n_iter=10, random_state=0).fit(X)
    assert nkm.components_.shape == (12, X.shape[1])
    assert nkm.centroids_.shape == (12, X.shape[1])
    np.testing.assert_allclose(np.linalg.norm(nkm.components_, axis=1), 1.0)
    np.testing.assert_allclose(nkm.transform(X[:50]), kmeans_triangle(X[:50], nkm.centroids_),
                               atol=1e-5)
    sc = DictionaryLearner("SC", 12, lam=0.2, n_iter=10, batch_size=100, random_state=0).fit(X)
    np.testing.assert_allclose(sc.transform(X[:50]),
                               polarity_split(lasso(X[:50], sc.components_, 0.2)), atol=1e-6)
    gs = DictionaryLearner("GSVQ", 12, n_iter=5, random_state=0).fit(X)
    M = np.ones((50, X.shape[1]), dtype=bool)
    M[:, :5] = False
    codes = gs.transform(X[:50], mask=M)
    assert codes.shape == (50, 24) and np.all((codes != 0).sum(axis=1) <= 1)
    with pytest.raises(ValueError, match="no mask"):
        nkm.transform(X[:5], mask=M[:5])


def test_errors(data):
    X, _ = data
    with pytest.raises(ValueError, match="unknown dictionary method"):
        learn_dictionary(X, "PCA")
    with pytest.raises(ValueError, match="n_atoms"):
        learn_dictionary(X, "R", n_atoms=0)
    with pytest.raises(ValueError, match="finite"):
        Xn = X.copy()
        Xn[3, 3] = np.inf
        learn_dictionary(Xn, "NKM", 4, n_iter=2)
    with pytest.raises(ValueError, match="return_centroids"):
        learn_dictionary(X, "SC", 4, return_centroids=True)


def test_does_not_mutate(data):
    X, _ = data
    Xc = X.copy()
    learn_dictionary(X, "SC", 6, random_state=0, n_iter=3, batch_size=50)
    learn_dictionary(X, "NKM", 6, random_state=0, n_iter=3)
    np.testing.assert_array_equal(X, Xc)


def test_real_patches_smoke(jacquard_root):
    """NKM and SC on whitened real patches: finite, well-spread atoms."""
    from dlsr.datasets import load_jacquard
    from dlsr.patches import sample_patches
    from dlsr.preprocess import rectangle_images
    from dlsr.rectangles import rects_to_array
    from dlsr.whitening import apply_zca, fit_zca, standardize_patches

    s = load_jacquard(jacquard_root)[0]
    im, m = rectangle_images(s, rects_to_array(s.positives)[::4])
    X, M = sample_patches(im, m, 3000, 0.2, 0)
    Xs = standardize_patches(X, M)
    Xw = apply_zca(Xs, M, *fit_zca(Xs, M))
    for method, kw in (("NKM", dict(n_iter=20)), ("SC", dict(n_iter=20, batch_size=200))):
        D = learn_dictionary(Xw, method, 50, random_state=0, **kw)
        assert np.all(np.isfinite(D))
        G = np.abs(D @ D.T / np.outer(np.linalg.norm(D, axis=1), np.linalg.norm(D, axis=1)))
        np.fill_diagonal(G, 0)
        assert np.mean(G.max(axis=1) > 0.999) < 0.2  # atoms are not mostly duplicates


def test_learned_dictionary_carries_natural_parameters(data):
    from dlsr.dictionaries import LearnedDictionary

    X, _ = data
    D = learn_dictionary(X, "NKM", 5, random_state=0, n_iter=5)
    assert isinstance(D, LearnedDictionary) and isinstance(D, np.ndarray)
    assert D.centroids.shape == D.shape and D.method == "NKM"
    assert type(D.components) is np.ndarray
    np.testing.assert_allclose(D.components, D.centroids / np.linalg.norm(D.centroids, axis=1,
                                                                           keepdims=True))
    assert D[:2].centroids is None  # derived arrays drop the extras
    S = learn_dictionary(X, "SC", 5, random_state=0, lam=0.3, n_iter=3, batch_size=50)
    assert S.natural_param == 0.3 and S.centroids is None
    assert learn_dictionary(X, "OMP", 5, random_state=0, n_nonzero=2, n_iter=2,
                            batch_size=50).natural_param == 2
    assert learn_dictionary(X, "RP", 5, random_state=0).natural_param == 0.0
