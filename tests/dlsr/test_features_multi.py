"""Several encoders at once: shared patches and shared codes give each encoder's own codes."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr import coding
from dlsr.features import (
    ENCODER_GRIDS,
    ENCODERS,
    Representation,
    encode_patches_multi,
    rectangle_features_grid,
    rectangle_features_multi,
)

P = 288


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(4)
    X = rng.standard_normal((120, P)).astype(np.float32)
    M = rng.random((120, P)) > 0.2
    M[:40] = True  # a group of fully valid rows beside per-row masks
    X[~M] = 0.0
    D = rng.standard_normal((24, P))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    return X, M, D.astype(np.float32)


def _alone(X, M, rep, encoder, param):
    """Each encoder computed on its own by the coding functions."""
    D = rep.dictionary
    if encoder == "SC":
        return coding.polarity_split(coding.lasso(X, D, param))
    if encoder == "mSC":
        return coding.polarity_split(coding.lasso(X, D, param, mask=M))
    if encoder == "OMP":
        return coding.polarity_split(coding.omp(X, D, param))
    if encoder == "mOMP":
        return coding.polarity_split(coding.omp(X, D, param, mask=M))
    if encoder == "ST":
        return coding.polarity_split(coding.soft_threshold(X, D, param))
    return coding.natural_encode(X, M, rep.learner, D, centroids=rep.centroids,
                                 param=rep.natural_param)


@pytest.mark.parametrize("zero_masked", [True, False])
@pytest.mark.parametrize("learner,natural_param", [("SC", 1.0), ("OMP", 5), ("GSVQ", None),
                                                   ("RP", None), ("NKM", None)])
def test_multi_equals_each_encoder_alone(problem, learner, natural_param, zero_masked):
    """Also with values under the mask: then the masked computations cannot share the
    unmasked ones' product ``X D^T`` (which they otherwise read)."""
    X, M, D = problem
    if not zero_masked:
        X = np.where(M, X, np.float32(3.0))
    centroids = 1.5 * D if learner == "NKM" else None
    rep = Representation(learner, D, centroids, None, None, natural_param)
    grids = {enc: ENCODER_GRIDS[enc] for enc in ENCODERS}
    cpu = {}
    out = encode_patches_multi(X, M, rep, grids, cpu_seconds=cpu)
    assert set(out) == set(ENCODERS)
    for enc in ENCODERS:
        assert len(out[enc]) == len(grids[enc])
        for param, A in zip(grids[enc], out[enc], strict=True):
            np.testing.assert_allclose(A, _alone(X, M, rep, enc, param), atol=2e-5,
                                       err_msg=f"{learner}-{enc} {param}")
    # the natural encoder reads the codes of the encoder computing the same thing
    shared = {"SC": ("SC", 1), "OMP": ("OMP", 1), "GSVQ": ("mOMP", 0), "RP": None, "NKM": None}
    if shared[learner] is not None:
        enc, t = shared[learner]
        assert out["Natural"][0] is out[enc][t]
    assert set(cpu) == {("lasso", False), ("lasso", True), ("omp", False), ("omp", True),
                        ("threshold", False)} | ({("triangle", False)} if learner == "NKM"
                                                 else set())


def test_rectangle_features_multi_equals_one_encoder_at_a_time():
    rng = np.random.default_rng(5)
    images = rng.standard_normal((7, 24, 24, 8)).astype(np.float32)
    masks = rng.random((7, 24, 24, 8)) > 0.1
    masks[:, :, 20:] = False  # padding columns
    D = rng.standard_normal((16, P))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    rep = Representation("RP", D.astype(np.float32), None, None, None, None)
    grids = {"SC": (0.5, 1.0), "ST": (0.5, 1.0), "Natural": (None,), "mOMP": (1, 5)}
    cpu = {}
    multi = rectangle_features_multi(images, masks, rep, grids, chunk_size=3, cpu_seconds=cpu)
    for enc, params in grids.items():
        alone = rectangle_features_grid(images, masks, rep, enc, params, chunk_size=5)
        for a, b in zip(multi[enc], alone, strict=True):
            assert a.shape == (7, 4 * 2 * 16)
            np.testing.assert_allclose(a, b, atol=1e-3, rtol=1e-5)
    assert cpu["patches"] > 0 and "pooling" in cpu
    rows = np.array([6, 1, 1, 3])  # a fold's rectangles, without copying them first
    picked = rectangle_features_multi(images, masks, rep, grids, chunk_size=3, rows=rows)
    copied = rectangle_features_multi(images[rows], masks[rows], rep, grids, chunk_size=3)
    for enc in grids:
        for a, b in zip(picked[enc], copied[enc], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="rows must be in"):
        rectangle_features_multi(images, masks, rep, grids, rows=[7])
    with pytest.raises(ValueError, match="no rectangles"):
        rectangle_features_multi(images, masks, rep, grids, rows=np.zeros(0, int))
    with pytest.raises(ValueError, match="does not match"):
        rectangle_features_multi(images, masks[:6], rep, grids)
    with pytest.raises(ValueError, match="unknown encoder"):
        rectangle_features_multi(images, masks, rep, {"XYZ": (1,)})
    with pytest.raises(ValueError, match="at least one encoder parameter"):
        rectangle_features_multi(images, masks, rep, {"SC": ()})


@pytest.mark.parametrize(("unmasked", "masked", "method"), [("SC", "mSC", coding.lasso_path),
                                                            ("OMP", "mOMP", coding.omp_path)])
def test_fully_valid_rows_take_their_masked_codes_from_the_unmasked_computation(
        problem, unmasked, masked, method):
    """With the unmasked encoder beside it, a masked encoder solves only the rows with a masked
    entry (the same codes as the masked computation of all rows, bit for bit); the fully valid
    rows get the unmasked computation's codes, the same problem (equal up to rounding: the Gram
    matrix is D D^T rather than (D diag(1)) D^T). The unmasked codes are those of its own
    grid: recording the masked grid's penalties too does not change them."""
    X, M, D = problem
    rep = Representation("R", D, None, None, None, 0.0)
    grids = {unmasked: ENCODER_GRIDS[unmasked], masked: ENCODER_GRIDS[masked]}
    calls = []

    def counting(X_, D_, values, mask=None, **kw):
        calls.append((None if mask is None else len(mask), list(values)))
        return method(X_, D_, values, mask=mask, **kw)

    mp = pytest.MonkeyPatch()
    mp.setattr(coding, method.__name__, counting)
    try:
        out = encode_patches_multi(X, M, rep, grids, polarity=False)
    finally:
        mp.undo()
    full = M.all(axis=1)
    assert calls[0][0] is None and set(calls[0][1]) == set(grids[unmasked]) | set(grids[masked])
    assert calls[1][0] == int((~full).sum())  # the masked solve: only rows with a mask
    for t, v in enumerate(grids[unmasked]):
        np.testing.assert_array_equal(out[unmasked][t], method(X, D, [v])[0])
    for t, v in enumerate(grids[masked]):
        alone = method(X, D, [v], mask=M)[0]
        np.testing.assert_array_equal(out[masked][t][~full], alone[~full])
        np.testing.assert_allclose(out[masked][t][full], alone[full], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(out[masked][t][full], method(X, D, [v])[0][full])


def test_a_chunk_never_holds_every_computations_codes_at_once():
    """Each computation's codes are pooled and dropped before the next one runs, and a
    method's masked computation follows its unmasked one: a chunk of every encoder peaks at
    what its largest computation (the two lasso runs of SC and mSC) needs alone, not at the
    sum of all of them (1.6 times as much before: about 600 MB of codes a chunk of 64
    rectangles at 300 atoms)."""
    import tracemalloc

    rng = np.random.default_rng(6)
    n = 4
    images = rng.standard_normal((n, 24, 24, 8)).astype(np.float32)
    masks = np.ones((n, 24, 24, 8), dtype=bool)
    masks[:, :, 20:] = False  # padding columns, as a rectangle near the image border
    masks[::2, 3:6, 3:9, 3:] = False  # missing depth on half of them
    D = rng.standard_normal((300, P))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    rep = Representation("RP", D.astype(np.float32), None, None, None, None)

    def peak(encoders):
        grids = {enc: ENCODER_GRIDS[enc] for enc in encoders}
        rectangle_features_multi(images, masks, rep, grids, chunk_size=n)  # imports, caches
        tracemalloc.start()
        try:
            rectangle_features_multi(images, masks, rep, grids, chunk_size=n)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    every, lasso = peak(ENCODERS), peak(("SC", "mSC"))
    assert lasso > 10 * n * 361 * 300 * 4  # the two lasso runs' codes and work are measured
    assert every < 1.1 * lasso, every / lasso


def test_rectangle_features_many_whitens_once_per_whitening(monkeypatch):
    from dlsr.features import pooling, rectangle_features, rectangle_features_many

    rng = np.random.default_rng(6)
    images = rng.standard_normal((5, 24, 24, 8)).astype(np.float32)
    masks = rng.random((5, 24, 24, 8)) > 0.1
    masks[:, :, 21:] = False  # padding columns
    A = rng.standard_normal((P, P)) * 0.05 + np.eye(P)
    mean = rng.standard_normal(P) * 0.1
    D = rng.standard_normal((12, P))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    one = Representation("RP", D, None, mean, A, None)
    same = Representation("NKM", D[::-1].copy(), 1.5 * D[::-1], mean.copy(), A.copy(), None)
    other = Representation("RP", D, None, mean, A + 0.01, None)  # another whitening
    models = [(one, "SC", 1.0, True), (same, "Natural", None, False),
              (other, "Natural", None, True), (one, "OMP", 3, True)]
    alone = [rectangle_features(images, masks, rep, enc, param, polarity, chunk_size=2)
             for rep, enc, param, polarity in models]
    calls = []
    whiten = pooling.preprocess_patches
    monkeypatch.setattr(pooling, "preprocess_patches",
                        lambda *a: calls.append(a[2][1]) or whiten(*a))
    many = rectangle_features_many(images, masks, models, chunk_size=2)
    for a, b in zip(many, alone, strict=True):
        np.testing.assert_array_equal(a, b)
    # 3 chunks, two whitenings: 6 preprocessings, not 12
    assert len(calls) == 6
    assert sum(c is other.zca_matrix for c in calls) == 3
