"""Per-patch group standardisation and masked ZCA whitening."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.patches import sample_patches
from dlsr.preprocess import rectangle_images
from dlsr.whitening import (
    CHANNEL_GROUPS,
    ESTIMATORS,
    PatchStandardizer,
    ZCAWhitening,
    apply_zca,
    fit_zca,
    standardize_patches,
)

GROUP_CHANNELS = [list(g) for g in CHANNEL_GROUPS]


def _patches(n=500, seed=0, p_valid=0.8):
    rng = np.random.default_rng(seed)
    # groups on very different scales, as K / RGB / D (mm) / normals are
    scale = np.array([1, 1, 1, 1, 50, 0.3, 0.3, 0.3])
    X = (rng.normal(size=(n, 36, 8)) * scale + rng.normal(size=(n, 1, 8)) * 3).reshape(n, 288)
    M = rng.random((n, 288)) < p_valid
    return X.astype(np.float32), M


def _naive_standardize(X, M, eps=1e-4):
    out = np.zeros(X.shape)
    for i in range(len(X)):
        x = X[i].reshape(36, 8).astype(float)
        m = M[i].reshape(36, 8)
        o = np.zeros((36, 8))
        for chans in GROUP_CHANNELS:
            v = x[:, chans][m[:, chans]]
            if v.size == 0:
                continue
            var = v.var(ddof=1) if v.size >= 2 else 0.0
            sub = (x[:, chans] - v.mean()) / np.sqrt(var + eps)
            o[:, chans] = np.where(m[:, chans], sub, 0)
        out[i] = o.ravel()
    return out


def test_standardize_matches_definition_and_moments():
    X, M = _patches()
    Z = standardize_patches(X, M)
    assert Z.dtype == np.float32 and Z.shape == X.shape
    np.testing.assert_allclose(Z, _naive_standardize(X, M), atol=1e-4)
    assert np.all(Z[~M] == 0)
    for chans in GROUP_CHANNELS:
        sel = np.zeros((36, 8), bool)
        sel[:, chans] = True
        sel = sel.ravel()
        z = np.where(M[:, sel], Z[:, sel], np.nan)
        np.testing.assert_allclose(np.nanmean(z, axis=1), 0, atol=1e-5)
        np.testing.assert_allclose(np.nanvar(z, axis=1, ddof=1), 1, atol=2e-3)
    # float64 in, float64 out; any leading shape
    Z64 = standardize_patches(X.astype(np.float64).reshape(5, 100, 288), M.reshape(5, 100, 288))
    assert Z64.dtype == np.float64 and Z64.shape == (5, 100, 288)
    np.testing.assert_allclose(Z64.reshape(500, 288), Z, atol=1e-4)


def test_standardize_small_groups_give_no_nan():
    X, M = _patches(n=4)
    M[0] = False  # nothing valid
    M[1] = False
    M[1, 0] = True  # a single valid K entry
    M[2, 4::8] = False  # no valid D
    M[2, 4] = M[2, 12] = True  # two valid D entries
    Z = standardize_patches(X, M)
    assert np.all(np.isfinite(Z))
    assert np.all(Z[0] == 0) and np.all(Z[1] == 0)
    d = Z[2, [4, 12]]
    assert d[0] == pytest.approx(-d[1]) and abs(d[0]) > 0.5
    Z_all = standardize_patches(X)  # no mask: all valid
    np.testing.assert_allclose(Z_all, standardize_patches(X, np.ones_like(M)))


def test_zca_on_fully_valid_data_matches_the_analytic_covariance():
    rng = np.random.default_rng(0)
    n, p = 20000, 16
    A = rng.normal(size=(p, p)) * np.linspace(0.05, 3, p)
    X = rng.normal(size=(n, p)) @ A + 5
    mean, P = fit_zca(X, None, epsilon=0.1)
    np.testing.assert_allclose(mean, X.mean(axis=0))
    np.testing.assert_allclose(P, P.T)
    Y = apply_zca(X, None, mean, P)
    C = np.cov(X, rowvar=False)
    eig, V = np.linalg.eigh(C)
    expected = (V * (eig / (eig + 0.1))) @ V.T
    np.testing.assert_allclose(np.cov(Y, rowvar=False), expected, atol=1e-8)
    # directions with variance >> epsilon are whitened to ~1, small ones are damped
    out_eig = np.linalg.eigvalsh(np.cov(Y, rowvar=False))
    assert out_eig.max() < 1 and out_eig.max() > 0.95 and out_eig.min() < 0.5
    np.testing.assert_allclose(Y.mean(axis=0), 0, atol=1e-9)


def test_zca_masks_mean_over_valid_and_covariance_from_complete_patches():
    rng = np.random.default_rng(1)
    p = 8
    Xf = rng.normal(size=(300, p)) @ rng.normal(size=(p, p))
    Mf = np.ones(Xf.shape, bool)
    Xp = rng.normal(size=(200, p)) * 100 + 40  # partial patches with wild values
    Mp = rng.random(Xp.shape) < 0.5
    Mp[:, 0] = False  # never complete
    X = np.vstack([Xf, Xp])
    M = np.vstack([Mf, Mp])
    mean, P = fit_zca(X, M)
    _, P_full = fit_zca(Xf, None)
    np.testing.assert_allclose(P, P_full)  # partial patches do not enter the covariance
    expected_mean = np.array([X[M[:, j], j].mean() for j in range(p)])
    np.testing.assert_allclose(mean, expected_mean)
    Y = apply_zca(X, M, mean, P)
    assert np.all(Y[~M] == 0)
    np.testing.assert_allclose(Y[M], ((X - mean) @ P)[M])
    with pytest.raises(ValueError, match=r"at least n_features \+ 1 = 9 fully valid"):
        fit_zca(Xp, Mp)
    with pytest.raises(ValueError, match="do not fit"):
        apply_zca(X, M, mean[:3], P)


def test_transformers():
    assert [type(e) for e in ESTIMATORS] == [PatchStandardizer, ZCAWhitening]
    X, M = _patches(n=800, p_valid=0.999)
    std = PatchStandardizer()
    np.testing.assert_array_equal(std.fit_transform(X, mask=M), standardize_patches(X, M))
    np.testing.assert_array_equal(std.transform(X), standardize_patches(X))
    Z = standardize_patches(X, M)
    zca = ZCAWhitening(epsilon=0.1)
    Y = zca.fit_transform(Z, mask=M)  # the mask reaches transform too
    mean, P = fit_zca(Z, M, 0.1)
    np.testing.assert_allclose(zca.mean_, mean)
    np.testing.assert_allclose(zca.whitening_, P)
    np.testing.assert_allclose(Y, apply_zca(Z, M, mean, P), rtol=1e-5, atol=1e-5)
    assert np.all(Y[~M] == 0)
    assert Y.dtype == np.float32
    assert zca.get_params() == {"epsilon": 0.1}
    with pytest.raises(ValueError, match="mask shape"):
        zca.transform(Z, mask=M[:, :5])


def _jacquard_crops(view, n=60):
    """Rectangle images of the first grasps of one real Jacquard view (stereo depth)."""
    rgb, d, valid, rects = view(depth="stereo")
    return rectangle_images(rgb, d, valid, rects[:n])


def test_real_patches_standardise_and_whiten(jacquard_view):
    im, mk = _jacquard_crops(jacquard_view)
    X, M = sample_patches(im, mk, n_patches=20000, random_state=0)
    Z = standardize_patches(X, M)
    assert np.all(np.isfinite(Z)) and np.all(Z[~M] == 0)
    zf = Z.reshape(-1, 36, 8)
    mf = M.reshape(-1, 36, 8)
    for chans in GROUP_CHANNELS:
        cnt = mf[:, :, chans].sum(axis=(1, 2))
        s = np.where(mf[:, :, chans], zf[:, :, chans], 0).sum(axis=(1, 2))
        np.testing.assert_allclose(s[cnt > 0] / cnt[cnt > 0], 0, atol=1e-4)
    mean, P = fit_zca(Z, M)
    Y = apply_zca(Z, M, mean, P)
    full = M.all(axis=1)
    assert full.sum() > 289
    C = np.cov(Y[full].astype(np.float64), rowvar=False)
    # whitened: eigenvalues eig / (eig + 0.1) of the standardised covariance, all < 1
    eig = np.linalg.eigvalsh(np.cov(Z[full].astype(np.float64), rowvar=False))
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(C)), np.sort(eig / (eig + 0.1)),
                               atol=1e-3)


def test_zca_does_not_depend_on_the_blas_threads():
    # with two threads the covariance's product sums in another order: a model trained in a
    # worker (one thread) differed from the same model trained in the main process
    from dlsr import _threads
    from dlsr.whitening import fit_zca

    rng = np.random.default_rng(0)
    X = rng.normal(size=(20000, 288)).astype(np.float32)
    X[:, :8] *= 30.0  # uneven scales, as whitened patches' channels
    fits = []
    for n in (1, 2):
        with _threads.limit(n, user_api="blas"):
            fits.append(fit_zca(X, np.ones(X.shape, bool)))
    assert fits[0][1].tobytes() == fits[1][1].tobytes()
    assert fits[0][0].tobytes() == fits[1][0].tobytes()
