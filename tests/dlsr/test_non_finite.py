"""A NaN or an infinity gives the documented ValueError at every encoder, learner, whitening and
SVM entry point, before any matrix product.

What a BLAS product does with a non-finite value depends on the kernels the CPU runs: OpenBLAS's
AVX-512 kernels raise the floating-point "invalid" flag on an infinity (numpy then warns
"invalid value encountered in matmul", an error under this suite's ``filterwarnings =
error``), its SSE3 and AVX2 kernels do not. So these tests fail on every kernel set if a check
comes after a product that some kernel set would warn about; ``make portability`` runs them
under each one.
"""

from __future__ import annotations

import numpy as np
import pytest

from dlsr import coding, dictionaries, svm, whitening
from dlsr._dense import check_finite, first_non_finite_row
from dlsr.features import (
    Representation,
    encode_patches,
    encode_patches_multi,
    pack_images,
    rectangle_features,
)

BAD = [np.nan, np.inf, -np.inf]
MESSAGE = r"finite|NaN|infinity"  # ours, or scikit-learn's validate_data


@pytest.fixture(scope="module")
def clean():
    rng = np.random.default_rng(11)
    X = rng.standard_normal((60, 16))
    D = rng.standard_normal((8, 16))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    M = rng.random(X.shape) > 0.3
    return X, D, M


def _spoil(A, bad, row=None, col=3):
    A = np.array(A, dtype=np.float64 if A.dtype.kind != "f" else A.dtype, copy=True)
    flat = A.reshape(A.shape[0], -1) if A.ndim > 1 else A.reshape(1, -1)
    flat[len(flat) // 2 if row is None else row, col] = bad
    return A


# ---------------------------------------------------------------------------------------------
# the check itself


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.float16])
@pytest.mark.parametrize("bad", BAD)
def test_first_non_finite_row_finds_the_first_bad_row(dtype, bad):
    rng = np.random.default_rng(0)
    A = rng.standard_normal((50, 37)).astype(dtype)
    assert first_non_finite_row(A) == -1
    for rows in ([0], [49], [17, 30]):
        B = A.copy()
        B[rows, np.arange(len(rows)) * 10 + 4] = bad  # even columns
        assert first_non_finite_row(B) == rows[0]
        assert first_non_finite_row(np.asfortranarray(B)) == rows[0]  # any layout
        assert first_non_finite_row(B[:, ::2]) == rows[0]  # a strided view
        assert first_non_finite_row(B.reshape(50, 37, 1)) == rows[0]  # rows along axis 0
        with pytest.raises(ValueError, match=f"Y must be finite.*row {rows[0]}"):
            check_finite(B, "Y")
    assert first_non_finite_row(A[:, ::2]) == -1
    assert first_non_finite_row(np.arange(6).reshape(2, 3)) == -1  # integers are finite
    assert first_non_finite_row(np.zeros((4, 0), dtype)) == -1
    with pytest.raises(ValueError, match="^v must be finite \\(no NaN or inf\\)$"):
        check_finite(np.array([1.0, bad]), "v")


# ---------------------------------------------------------------------------------------------
# encoders


def _encoders(mask):
    """Every public encoder entry point, as ``f(X, D)``."""
    return {
        "lasso": lambda X, D: coding.lasso(X, D, 0.1),
        "masked lasso": lambda X, D: coding.lasso(X, D, 0.1, mask=mask),
        "lasso_path": lambda X, D: coding.lasso_path(X, D, [0.1, 0.2]),
        "omp": lambda X, D: coding.omp(X, D, 2),
        "masked omp": lambda X, D: coding.omp(X, D, 2, mask=mask),
        "omp_path": lambda X, D: coding.omp_path(X, D, [1, 2]),
        "soft_threshold": lambda X, D: coding.soft_threshold(X, D, 0.1),
        "projection": lambda X, D: coding.soft_threshold(X, D, 0.0),
        "soft_threshold_path": lambda X, D: coding.soft_threshold_path(X, D, [0.0, 0.1]),
        "kmeans_triangle": lambda X, D: coding.kmeans_triangle(X, D),
        "lasso_rowwise": lambda X, D: coding.lasso_rowwise(X, D, 0.1),
        "omp_rowwise": lambda X, D: coding.omp_rowwise(X, D, 2),
        **{f"encode {m}": (lambda X, D, m=m: coding.encode(X, D, m)) for m in
           coding.ENCODER_METHODS},
        **{f"natural_encode {m}": (lambda X, D, m=m: coding.natural_encode(X, mask, m, D)) for
           m in ("SC", "OMP", "GSVQ", "NKM", "RP", "R")},
        "SparseEncoder.transform": lambda X, D: coding.SparseEncoder(
            "omp", D, n_nonzero=2).fit(np.zeros((1, D.shape[1]))).transform(X),
        "SparseEncoder.fit": lambda X, D: coding.SparseEncoder("lasso", n_atoms=4).fit(X),
    }


ENCODER_NAMES = list(_encoders(None))


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("name", ENCODER_NAMES)
def test_encoders_reject_non_finite_patches(clean, name, bad):
    X, D, M = clean
    encode = _encoders(M)[name]
    encode(X, D)  # the clean problem passes
    with pytest.raises(ValueError, match=MESSAGE):
        encode(_spoil(X, bad), D)
    with pytest.raises(ValueError, match=MESSAGE):
        encode(_spoil(X.astype(np.float32), bad, row=0), D)


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("name", [n for n in ENCODER_NAMES if n != "SparseEncoder.fit"])
def test_encoders_reject_non_finite_dictionaries(clean, name, bad):
    X, D, M = clean
    with pytest.raises(ValueError, match=MESSAGE):
        _encoders(M)[name](X, _spoil(D, bad))


@pytest.mark.parametrize("encode", [lambda X, D: coding.soft_threshold(X, D, 0.0),
                                    lambda X, D: coding.kmeans_triangle(X, D)],
                         ids=["projection", "triangle"])
def test_dense_encoders_report_float32_overflow(clean, encode):
    """Finite values whose products overflow float32: an error (no warning, whatever the
    kernels), not infinite codes; values beyond float32 itself, likewise."""
    X, D, _ = clean
    with pytest.raises(ValueError, match="overflow float32"):
        encode(X * 1e25, D * 1e25)
    with pytest.raises(ValueError, match="beyond the range of float32"):
        encode(X, D * 1e39)
    assert np.all(np.isfinite(encode(X * 1e15, D)))  # large but representable: fine


# ---------------------------------------------------------------------------------------------
# learners


LEARNERS = {
    **{f"learn_dictionary {m}": (lambda X, m=m: dictionaries.learn_dictionary(
        X, m, n_atoms=4, n_iter=2, batch_size=20, random_state=0)) for m in dictionaries.METHODS},
    "kmeans": lambda X: dictionaries.kmeans(X, 4, n_iter=2, random_state=0),
    "gsvq": lambda X: dictionaries.gsvq(X, 4, n_iter=2, random_state=0),
    "online_dictionary_learning omp": lambda X: dictionaries.online_dictionary_learning(
        X, 4, "omp", n_nonzero=2, batch_size=20, n_batches=2, random_state=0),
    "random_patches": lambda X: dictionaries.random_patches(X, 4, random_state=0),
    "DictionaryLearner.fit": lambda X: dictionaries.DictionaryLearner(
        "NKM", 4, n_iter=2, random_state=0).fit(X),
}


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("name", list(LEARNERS))
def test_learners_reject_non_finite_patches(clean, name, bad):
    X, _, _ = clean
    LEARNERS[name](X)
    with pytest.raises(ValueError, match=MESSAGE):
        LEARNERS[name](_spoil(X, bad))


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("method", dictionaries.METHODS)
def test_learner_transform_rejects_non_finite_patches(clean, method, bad):
    X, _, _ = clean
    est = dictionaries.DictionaryLearner(method, 4, n_iter=2, batch_size=20,
                                         random_state=0).fit(X)
    with pytest.raises(ValueError, match=MESSAGE):
        est.transform(_spoil(X, bad))


# ---------------------------------------------------------------------------------------------
# whitening, features, SVM


@pytest.fixture(scope="module")
def patches():
    rng = np.random.default_rng(5)
    X = rng.standard_normal((400, 24))
    M = rng.random(X.shape) > 0.05
    M[:100] = True
    X[~M] = 0.0
    return X, M


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("masked_entry", [False, True])
def test_whitening_rejects_non_finite_patches(patches, bad, masked_entry):
    """Masked entries too: they enter the ZCA product as they are."""
    X, M = patches
    row = int(np.flatnonzero(~M.all(axis=1))[0])
    col = int(np.flatnonzero(~M[row])[0] if masked_entry else np.flatnonzero(M[row])[0])
    Xb = _spoil(X, bad, row=row, col=col)
    mean, P = whitening.fit_zca(X, M)
    for fn in (lambda Z: whitening.standardize_patches(Z, M),
               lambda Z: whitening.fit_zca(Z, M),
               lambda Z: whitening.apply_zca(Z, M, mean, P),
               lambda Z: whitening.apply_zca(Z.astype(np.float32), M, mean, P),
               lambda Z: whitening.PatchStandardizer().fit_transform(Z, mask=M),
               lambda Z: whitening.ZCAWhitening().fit(X, mask=M).transform(Z, mask=M)):
        with pytest.raises(ValueError, match=MESSAGE):
            fn(Xb)
    with pytest.raises(ValueError, match=f"row {row}"):
        whitening.standardize_patches(Xb, M)
    with pytest.raises(ValueError, match="ZCA mean"):
        whitening.apply_zca(X, M, _spoil(mean, bad, row=0, col=2), P)
    with pytest.raises(ValueError, match="ZCA matrix"):
        whitening.apply_zca(X, M, mean, _spoil(P, bad))


@pytest.fixture(scope="module")
def representation():
    rng = np.random.default_rng(6)
    D = rng.standard_normal((5, 288)).astype(np.float32)
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    return Representation("NKM", D, 1.3 * D, None, None, None)


@pytest.mark.parametrize("bad", BAD)
def test_features_reject_non_finite_patches_and_images(representation, bad):
    rng = np.random.default_rng(7)
    X = rng.standard_normal((30, 288)).astype(np.float32)
    M = np.ones(X.shape, dtype=bool)
    for grids in ({"SC": [1.0], "OMP": [2]}, {"ST": [0.5]}, {"Natural": [None]}):
        encode_patches_multi(X, M, representation, grids)
        with pytest.raises(ValueError, match=MESSAGE):
            encode_patches_multi(_spoil(X, bad), M, representation, grids)
    with pytest.raises(ValueError, match=MESSAGE):
        encode_patches(_spoil(X, bad), M, representation, "mSC", 1.0)
    images = rng.standard_normal((3, 24, 24, 8)).astype(np.float32)
    masks = np.ones(images.shape, dtype=bool)
    rectangle_features(images, masks, representation, "Natural")
    images[1, 5, 7, 2] = bad
    with pytest.raises(ValueError, match=MESSAGE):
        rectangle_features(images, masks, representation, "Natural")
    assert pack_images(images, masks).shape == (3, 2 * 24 * 24 * 8)  # packing does not check


@pytest.mark.parametrize("bad", BAD)
def test_svm_rejects_non_finite_features(bad):
    rng = np.random.default_rng(8)
    X = rng.standard_normal((40, 6))
    y = np.where(rng.random(40) > 0.5, 1.0, -1.0)
    y[:2] = [1.0, -1.0]
    Xb = _spoil(X, bad)
    for form in ("kernel", "primal"):
        with pytest.raises(ValueError, match=MESSAGE):
            svm.squared_hinge_fit(Xb, y, [1.0], form=form)
    with pytest.raises(ValueError, match=MESSAGE):
        svm.SquaredHingeSVC().fit(Xb, y)
    fitted = svm.SquaredHingeSVC().fit(X, y)
    with pytest.raises(ValueError, match=MESSAGE):
        fitted.decision_function(Xb)
    with pytest.raises(ValueError, match=MESSAGE):
        svm.FeatureStandardizer().fit(Xb)
