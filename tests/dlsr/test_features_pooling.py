"""Quadrant pooling and the packed layout of rectangle images."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.features import pack_images, quadrant_pool, unpack_images


def test_quadrant_pool_order_and_split(rng):
    codes = rng.normal(size=(3, 19, 19, 4))
    pooled = quadrant_pool(codes)
    assert pooled.shape == (3, 16)
    tl = codes[:, :10, :10].sum((1, 2))
    tr = codes[:, :10, 10:].sum((1, 2))
    bl = codes[:, 10:, :10].sum((1, 2))
    br = codes[:, 10:, 10:].sum((1, 2))
    np.testing.assert_allclose(pooled, np.concatenate([tl, tr, bl, br], 1))
    # The four quadrants partition the grid.
    np.testing.assert_allclose(pooled.reshape(3, 4, 4).sum(1), codes.sum((1, 2)))


def test_quadrant_pool_localises_a_single_code():
    codes = np.zeros((1, 19, 19, 2))
    codes[0, 12, 3, 1] = 5.0  # bottom-left quadrant, atom 1
    pooled = quadrant_pool(codes).reshape(4, 2)
    assert pooled[2, 1] == 5.0 and pooled.sum() == 5.0


def test_pack_roundtrip(rng):
    images = rng.normal(size=(5, 24, 24, 8)).astype(np.float32)
    masks = rng.random((5, 24, 24, 8)) > 0.3
    X = pack_images(images, masks)
    assert X.shape == (5, 2 * 24 * 24 * 8) and X.dtype == np.float32
    im2, mk2 = unpack_images(X)
    np.testing.assert_array_equal(im2, images)
    np.testing.assert_array_equal(mk2, masks)


def test_unpack_rejects_wrong_width():
    with pytest.raises(ValueError, match="packed rectangle images"):
        unpack_images(np.zeros((2, 100)))


@pytest.mark.parametrize("polarity", [True, False])
def test_fused_split_pool_equals_split_then_pool(rng, polarity):
    from dlsr.coding import polarity_split
    from dlsr.features.pooling import split_pool

    codes = rng.normal(size=(3, 19, 19, 5)).astype(np.float32)
    codes[codes < 0.3] = 0.0  # sparse, with exact zeros
    split = polarity_split(codes.reshape(-1, 5)).reshape(3, 19, 19, -1) if polarity else codes
    expected = quadrant_pool(split.astype(np.float64))
    got = split_pool(codes, polarity)
    assert got.shape == expected.shape == (3, 4 * 5 * (2 if polarity else 1))
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-5)
