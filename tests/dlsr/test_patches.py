"""Dense patch extraction, random sampling with the validity rule, patch files."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.patches import extract_patches, load_patch_file, sample_patches, save_patch_file
from dlsr.preprocess import rectangle_images


def _images(n=3, seed=0):
    rng = np.random.default_rng(seed)
    images = rng.normal(size=(n, 24, 24, 8)).astype(np.float32)
    masks = np.ones(images.shape, bool)
    masks[:, :6] = False  # padding rows
    masks[:, 6:, :, 4:] = rng.random((n, 18, 24, 1)) > 0.3  # missing depth
    images[~masks] = 0
    return images, masks


def test_extract_patches_order_and_shapes():
    images, masks = _images()
    X, M = extract_patches(images, masks)
    assert X.shape == (3, 361, 288) and X.dtype == np.float32
    assert M.shape == (3, 361, 288) and M.dtype == bool
    for n, r, c in [(0, 0, 0), (1, 4, 17), (2, 18, 18), (2, 7, 0)]:
        np.testing.assert_array_equal(X[n, r * 19 + c], images[n, r:r + 6, c:c + 6].ravel())
        np.testing.assert_array_equal(M[n, r * 19 + c], masks[n, r:r + 6, c:c + 6].ravel())
    # feature j is channel j % 8
    assert np.all(X[0, 100].reshape(36, 8)[:, 3] == images[0, 5:11, 5:11, 3].ravel())
    X2, M2 = extract_patches(images, None, patch_size=4)
    assert X2.shape == (3, 21 * 21, 128) and M2.all()
    with pytest.raises(ValueError, match="patch_size"):
        extract_patches(images, masks, patch_size=30)
    with pytest.raises(ValueError, match="does not match"):
        extract_patches(images, masks[:2])


def test_sample_patches_respects_min_valid_and_returns_the_windows():
    images, masks = _images()
    masks[1] = False  # an image with nothing valid is never sampled
    images[1] = 0
    X, M, idx = sample_patches(images, masks, n_patches=2000, random_state=0, return_index=True)
    assert X.shape == (2000, 288) and X.dtype == np.float32 and M.dtype == bool
    assert np.all(M.mean(axis=1) >= 0.2)
    assert np.all(X[~M] == 0)
    assert not np.any(idx[:, 0] == 1)
    for k in range(0, 2000, 97):
        n, r, c = idx[k]
        np.testing.assert_array_equal(X[k], images[n, r:r + 6, c:c + 6].ravel())
        np.testing.assert_array_equal(M[k], masks[n, r:r + 6, c:c + 6].ravel())
    # positions starting in the padding rows are accepted only when >= 20 % valid
    frac_pad_row0 = M[idx[:, 1] == 0].mean(axis=1)
    assert np.all(frac_pad_row0 >= 0.2)
    # a stricter threshold rejects more
    X9, M9 = sample_patches(images, masks, n_patches=500, min_valid=0.9, random_state=0)
    assert np.all(M9.mean(axis=1) >= 0.9)


def test_sample_patches_is_deterministic_for_a_seed():
    images, masks = _images()
    a = sample_patches(images, masks, n_patches=300, random_state=3)
    b = sample_patches(images, masks, n_patches=300, random_state=3)
    c = sample_patches(images, masks, n_patches=300, random_state=4)
    np.testing.assert_array_equal(a[0], b[0])
    assert not np.array_equal(a[0], c[0])
    d = sample_patches(images, masks, n_patches=300, random_state=np.random.default_rng(3))
    assert d[0].shape == (300, 288)


def test_sample_patches_errors():
    images, masks = _images()
    with pytest.raises(ValueError, match="no patch"):
        sample_patches(images, np.zeros_like(masks), n_patches=10)
    with pytest.raises(ValueError, match="min_valid"):
        sample_patches(images, masks, min_valid=1.5)


def test_extra_patches_are_mixed_in(tmp_path):
    images, masks = _images()
    rng = np.random.default_rng(1)
    extra = rng.normal(size=(50, 6, 6, 8)).astype(np.float32) + 100  # recognisable
    emask = np.ones(extra.shape, bool)
    emask[:10] = False  # never valid enough
    path = tmp_path / "extra.npz"
    save_patch_file(path, extra, emask)
    for source in (path, str(path), (extra, emask), (extra.reshape(50, -1), emask.reshape(50, -1))):
        X, M, idx = sample_patches(images, masks, n_patches=400, random_state=0, extra=source,
                                   extra_fraction=0.5, return_index=True)
        from_extra = idx[:, 0] == -1
        assert from_extra.sum() == 200
        assert np.all(idx[from_extra, 1] >= 10)
        np.testing.assert_array_equal(X[from_extra], extra.reshape(50, -1)[idx[from_extra, 1]])
        assert np.all(X[~from_extra] < 50)
    # union: drawn in proportion to the accepted candidates (40 extra vs ~1000 image positions)
    _, _, idx = sample_patches(images, masks, n_patches=4000, random_state=0, extra=path,
                               return_index=True)
    share = np.mean(idx[:, 0] == -1)
    assert 0.005 < share < 0.08
    X1, _, idx1 = sample_patches(images, masks, n_patches=100, random_state=0, extra=path,
                                 extra_fraction=1.0, return_index=True)
    assert np.all(idx1[:, 0] == -1) and np.all(X1 > 50)
    with pytest.raises(ValueError, match="values each"):
        sample_patches(images, masks, n_patches=10, extra=(extra[:, :4], emask[:, :4]))


def test_patch_file_roundtrip_and_bad_files(tmp_path):
    rng = np.random.default_rng(0)
    P = rng.normal(size=(7, 288)).astype(np.float32)
    Q = rng.random((7, 288)) > 0.5
    path = tmp_path / "sub" / "patches.npz"
    save_patch_file(path, P, Q)
    P2, Q2 = load_patch_file(path)
    assert P2.shape == (7, 6, 6, 8) and P2.dtype == np.float32 and Q2.dtype == bool
    np.testing.assert_array_equal(P2.reshape(7, -1), P)
    np.testing.assert_array_equal(Q2.reshape(7, -1), Q)

    missing = tmp_path / "nope.npz"
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        load_patch_file(missing)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip at all")
    with pytest.raises(ValueError, match="garbage.npz"):
        load_patch_file(garbage)
    nokey = tmp_path / "nokey.npz"
    np.savez(nokey, patches=P2)
    with pytest.raises(ValueError, match=r"nokey.npz.*masks"):
        load_patch_file(nokey)
    shape = tmp_path / "shape.npz"
    np.savez(shape, patches=P2[:, :5], masks=Q2[:, :5])
    with pytest.raises(ValueError, match="shape.npz"):
        load_patch_file(shape)
    nan = tmp_path / "nan.npz"
    bad = P2.copy()
    bad[0, 0, 0, 0] = np.nan
    np.savez(nan, patches=bad, masks=Q2)
    with pytest.raises(ValueError, match=r"nan.npz.*non-finite"):
        load_patch_file(nan)
    with pytest.raises(ValueError, match="differ in shape"):
        save_patch_file(tmp_path / "x.npz", P, Q[:3])


def _jacquard_crops(view, n=40):
    """Rectangle images of the first grasps of one real Jacquard view (stereo depth)."""
    rgb, d, valid, rects = view(depth="stereo")
    return rectangle_images(rgb, d, valid, rects[:n])


def test_real_patches(jacquard_view):
    im, mk = _jacquard_crops(jacquard_view)
    X, M = extract_patches(im, mk)
    assert X.shape == (40, 361, 288) and np.all(np.isfinite(X))
    Xs, Ms = sample_patches(im, mk, n_patches=5000, random_state=0)
    assert np.all(Ms.mean(axis=1) >= 0.2)
    # every sampled patch is one of the dense patches
    flatX = X.reshape(-1, 288)
    rows = {r.tobytes() for r in flatX[M.reshape(-1, 288).mean(axis=1) >= 0.2]}
    assert all(x.tobytes() in rows for x in Xs[:200])


def test_drawing_from_rows_is_drawing_from_those_images():
    images, masks = _images(n=9, seed=3)
    masks[4] = False  # one selected image with nothing valid
    images[4] = 0
    rows = np.array([7, 2, 4, 2, 0])  # any order, repeats allowed
    for extra in (None, (np.ones((50, 288), np.float32), np.ones((50, 288), bool))):
        a = sample_patches(images, masks, n_patches=700, random_state=5, extra=extra,
                           return_index=True, rows=rows)
        b = sample_patches(images[rows], masks[rows], n_patches=700, random_state=5,
                           extra=extra, return_index=True)
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
    assert not np.any(a[2][:, 0] == 2)  # position 2 of rows is the empty image 4
    X, _ = sample_patches(images, masks, n_patches=300, random_state=5, rows=rows[:1])
    assert np.all(np.isin(X[:, 0], images[7, :19, :19, 0]))  # image 7 only
    for bad, match in [([9], "in \\[0, 9\\)"), ([-1], "in \\[0, 9\\)"), ([0.5], "1-d array"),
                       ([[0, 1]], "1-d array")]:
        with pytest.raises(ValueError, match=match):
            sample_patches(images, masks, n_patches=10, rows=np.array(bad))
