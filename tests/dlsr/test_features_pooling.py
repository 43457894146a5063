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
