"""Rectangle images: geometry, masks, depth handling, normals, real data."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from dlsr.datasets import GraspSample
from dlsr.preprocess import (
    CHANNELS,
    GRAY_WEIGHTS,
    fill_depth_holes,
    image_channels,
    rectangle_images,
    rotated_crop,
    surface_normals,
)
from dlsr.rectangles import GraspRectangle


def _scene(H=60, W=80, seed=0, a=0.001, b=0.002):
    """Random RGB, a tilted plane of depth (metres; a, b metres per pixel), all valid."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    yy, xx = np.mgrid[0:H, 0:W]
    depth = (1.0 + a * xx + b * yy).astype(np.float32)
    return rgb, depth, np.ones((H, W), bool)


def _smooth_scene(H=64, W=64, seed=1):
    rgb, _, valid = _scene(H, W, seed)
    yy, xx = np.mgrid[0:H, 0:W]
    depth = (1.2 + 0.0005 * xx - 0.0003 * yy
             + 0.01 * np.exp(-((xx - 30) ** 2 + (yy - 35) ** 2) / 200.0)).astype(np.float32)
    return rgb, depth, valid


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# ------------------------------------------------------------------------------------------------
# Shapes, geometry


def test_shapes_dtypes_and_no_nan():
    rgb, depth, valid = _scene()
    rects = np.array([[40, 30, 0.3, 30, 12], [20, 20, -1.2, 10, 25], [70, 50, 1.0, 40, 40]])
    im, mk = rectangle_images(rgb, depth, valid, rects)
    assert im.shape == (3, 24, 24, 8) and im.dtype == np.float32
    assert mk.shape == (3, 24, 24, 8) and mk.dtype == bool
    assert np.all(np.isfinite(im))
    assert np.all(im[~mk] == 0)
    assert len(CHANNELS) == 8
    # image-mask channels share one mask, depth-mask channels another
    assert np.array_equal(mk[..., 0], mk[..., 3]) and np.array_equal(mk[..., 4], mk[..., 7])
    im0, mk0 = rectangle_images(rgb, depth, valid, np.zeros((0, 5)))
    assert im0.shape == (0, 24, 24, 8) and mk0.shape == (0, 24, 24, 8)


def test_axis_aligned_rectangle_gives_exact_crop():
    rgb, depth, valid = _scene()
    # w = 24 columns (x 9..32), h = 12 rows (y 10..21): no resize, 6 rows of padding each side.
    rect = GraspRectangle(20.5, 15.5, 0.0, 24, 12)
    im, mk = rectangle_images(rgb, depth, valid, [rect])
    im, mk = im[0], mk[0]
    src = rgb[10:22, 9:33].astype(np.float32) / 255
    np.testing.assert_allclose(im[6:18, :, 1:4], src, atol=1e-6)
    np.testing.assert_allclose(im[6:18, :, 0], src @ np.array(GRAY_WEIGHTS), atol=1e-5)
    d = depth[10:22, 9:33].astype(np.float64)
    np.testing.assert_allclose(im[6:18, :, 4], (d - d.mean()) * 1000, atol=1e-3)
    assert mk[6:18].all()
    assert not mk[:6].any() and not mk[18:].any()
    assert np.all(im[:6] == 0) and np.all(im[18:] == 0)
    # normals of the plane (1 mm/px in x, 2 mm/px in y): (-1, -2, 1)/sqrt(6) everywhere
    np.testing.assert_allclose(im[6:18, :, 5:8], np.broadcast_to(_unit([-1, -2, 1]), (12, 24, 3)),
                               atol=1e-4)


def test_closing_direction_becomes_horizontal():
    # A bright vertical bar crossed by a horizontal closing direction stays vertical in the crop;
    # the same bar rotated, with the rectangle rotated alike, gives a vertical bar too.
    H = W = 81
    yy, xx = np.mgrid[0:H, 0:W]
    for theta in (0.0, np.pi / 6, -np.pi / 3):
        # bar: points whose coordinate along the closing direction u is within 3 px of centre
        u = np.array([np.cos(theta), -np.sin(theta)])
        along = (xx - 40) * u[0] + (yy - 40) * u[1]
        rgb = np.where(np.abs(along)[..., None] < 3, 255, 0).astype(np.uint8).repeat(3, axis=2)
        depth = np.ones((H, W), np.float32)
        im, mk = rectangle_images(rgb, depth, None, [[40, 40, theta, 48, 24]])
        k = im[0, 6:18, :, 0]  # rows of the 24 x 12 resized crop
        col_profile = k.mean(axis=0)
        assert col_profile[11:13].min() > 0.8  # the 5 px bar, halved, in the middle columns
        assert col_profile[:9].max() < 0.05 and col_profile[15:].max() < 0.05
        assert np.ptp(k[:, 11:13], axis=0).max() < 0.2  # constant down the columns


def test_rotation_by_90_degrees_gives_same_crop():
    rgb, depth, valid = _smooth_scene()
    W = rgb.shape[1]
    x, y, theta = 30.3, 28.7, np.radians(-60)
    rect = [x, y, theta, 34, 17]
    rect90 = [y, W - 1 - x, theta + np.pi / 2, 34, 17]  # np.rot90: (x, y) -> (y, W - 1 - x)
    a, ma = rectangle_images(rgb, depth, valid, [rect])
    b, mb = rectangle_images(np.rot90(rgb), np.rot90(depth), np.rot90(valid), [rect90])
    assert np.array_equal(ma, mb)
    # float32 sampling of metric depth (ulp ~1e-4 mm at 1.2 m) limits the normals to ~1e-3
    np.testing.assert_allclose(a[..., :5], b[..., :5], atol=2e-4)
    np.testing.assert_allclose(a[..., 5:], b[..., 5:], atol=1e-3)


def test_half_turn_of_the_rectangle_rotates_the_crop_by_180_degrees():
    rgb, depth, valid = _smooth_scene()
    a, ma = rectangle_images(rgb, depth, valid, [[32, 30, np.radians(30), 48, 24]],
                             interpolation="linear")
    # theta + 90 wraps to theta - 90: equivalent rectangle in the rotated image, jaws swapped
    W = rgb.shape[1]
    b, mb = rectangle_images(np.rot90(rgb), np.rot90(depth), np.rot90(valid),
                             [[30, W - 1 - 32, np.radians(120), 48, 24]],
                             interpolation="linear")
    flipped = a[0, ::-1, ::-1].copy()
    flipped[..., 5:7] *= -1  # in-plane normal components flip with a half turn
    assert np.array_equal(mb[0], ma[0, ::-1, ::-1])
    np.testing.assert_allclose(b[0, ..., :5], flipped[..., :5], atol=2e-4)
    np.testing.assert_allclose(b[0, ..., 5:], flipped[..., 5:], atol=1e-3)
    # equivalent angles give identical crops
    c, _ = rectangle_images(rgb, depth, valid, [[32, 30, np.radians(30) + np.pi, 48, 24]],
                            interpolation="linear")
    np.testing.assert_allclose(c, a, atol=1e-5)


def test_longer_side_resized_to_size_and_centred():
    rgb, depth, valid = _scene(100, 100)
    im, mk = rectangle_images(rgb, depth, valid, [[50, 50, 0.4, 20, 60], [50, 50, 0.4, 60, 60]])
    # h = 60 > w = 20: 24 rows by 8 columns, centred: columns 8..15
    cols = mk[0, :, :, 0].any(axis=0)
    assert np.flatnonzero(cols).tolist() == list(range(8, 16))
    assert mk[0, :, 8:16, 0].all()
    assert mk[1, ..., 0].all()  # square: no padding
    im32, _ = rectangle_images(rgb, depth, valid, [[50, 50, 0.4, 20, 60]], size=32)
    assert im32.shape == (1, 32, 32, 8)


# ------------------------------------------------------------------------------------------------
# Masks and bad input


def test_partly_outside_rectangle_is_masked_not_rejected():
    rgb, depth, valid = _scene()
    # columns x = -8 .. 15: crop columns 0..7 lie outside the image
    im, mk = rectangle_images(rgb, depth, valid, [[3.5, 15.5, 0.0, 24, 12]])
    assert not mk[0, 6:18, :8].any()
    assert mk[0, 6:18, 8:].all()
    assert np.all(im[0, 6:18, :8] == 0)
    np.testing.assert_allclose(im[0, 6:18, 8:, 1:4], rgb[10:22, 0:16] / 255, atol=1e-6)
    # entirely outside: all masked, zeros, no error
    im, mk = rectangle_images(rgb, depth, valid, [[-100, -100, 0.3, 20, 10]])
    assert not mk.any() and not im.any()


def test_invalid_depth_is_masked_on_depth_channels_only():
    rgb, depth, valid = _scene()
    valid = valid.copy()
    valid[12:15, 20:25] = False
    depth = np.where(valid, depth, 0).astype(np.float32)
    im, mk = rectangle_images(rgb, depth, valid, [[20.5, 15.5, 0.0, 24, 12]])
    dm = mk[0, 6:18, :, 4]
    np.testing.assert_array_equal(dm, valid[10:22, 9:33])
    assert mk[0, 6:18, :, :4].all()
    assert np.all(im[0, 6:18][~dm][:, 4:] == 0)
    # D has zero mean over valid pixels; normals elsewhere still the plane's
    assert abs(im[0, 6:18, :, 4][dm].mean()) < 1e-3
    far = np.zeros((12, 24), bool)
    far[:, 20:] = True
    np.testing.assert_allclose(im[0, 6:18][far][:, 5:8],
                               np.broadcast_to(_unit([-1, -2, 1]), (far.sum(), 3)), atol=1e-4)
    # depth 0 or NaN without a mask also counts as missing
    d2 = depth.copy()
    d2[12, 30] = np.nan
    im2, mk2 = rectangle_images(rgb, d2, None, [[20.5, 15.5, 0.0, 24, 12]])
    assert not mk2[0, 6 + 2, 30 - 9, 4] and np.all(np.isfinite(im2))
    np.testing.assert_array_equal(mk2[0, 6:18, :, 4] | (np.arange(24) == 21)[None] & (
        np.arange(12) == 2)[:, None], dm)


def test_depth_outliers_are_masked():
    rgb, depth, valid = _scene()
    depth = depth.copy()
    depth[15, 20] += 0.5  # a 0.5 m spike
    im, mk = rectangle_images(rgb, depth, valid, [[20.5, 15.5, 0.0, 24, 12]])
    dm = mk[0, 6:18, :, 4]
    assert not dm[5, 11]
    assert dm.sum() == 12 * 24 - 1
    assert np.abs(im[0, 6:18, :, 4]).max() < 60  # only the plane's +-(11.5 + 2 * 5.5) mm left


def test_degenerate_and_nonfinite_rectangles_raise_naming_the_index():
    rgb, depth, valid = _scene()
    ok = [40, 30, 0.0, 20, 10]
    with pytest.raises(ValueError, match="rectangle 1 is degenerate"):
        rectangle_images(rgb, depth, valid, [ok, [40, 30, 0.0, 1.5, 10]])
    with pytest.raises(ValueError, match="rectangle 2 is degenerate"):
        rectangle_images(rgb, depth, valid, [ok, ok, [40, 30, 0.0, 10, 0.5]])
    with pytest.raises(ValueError, match="rectangle 0 is not finite"):
        rectangle_images(rgb, depth, valid, [[np.nan, 30, 0.0, 20, 10]])
    with pytest.raises(ValueError, match="shape"):
        rectangle_images(rgb, depth, valid, np.zeros((2, 4)))
    with pytest.raises(ValueError, match="no valid pixel"):
        rectangle_images(rgb, np.zeros_like(depth), None, [ok])
    with pytest.raises(ValueError, match="does not match"):
        rectangle_images(rgb, depth[:-1], None, [ok])


def test_grasp_sample_input_and_depth_scale():
    rgb, depth, valid = _scene()
    rects = [GraspRectangle(20.5, 15.5, 0.0, 24, 12), GraspRectangle(40, 30, 0.7, 30, 14)]
    sample = GraspSample("s", None, rgb, depth, valid, positives=rects)
    a, ma = rectangle_images(rgb, depth, valid, rects)
    b, mb = rectangle_images(sample, rects)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ma, mb)
    # metres instead of mm: D 1000x smaller, normals of a much flatter plane
    c, _ = rectangle_images(sample, rects, depth_scale=1.0)
    np.testing.assert_allclose(c[0, 6:18, :, 4] * 1000, a[0, 6:18, :, 4], atol=1e-3)
    np.testing.assert_allclose(c[0, 6:18, :, 5:8],
                               np.broadcast_to(_unit([-0.001, -0.002, 1]), (12, 24, 3)), atol=1e-5)
    with pytest.raises(TypeError):
        rectangle_images(sample)


# ------------------------------------------------------------------------------------------------
# Normals and hole filling


@pytest.mark.parametrize("shape", [(2, 5), (5, 2), (9, 13)])
def test_surface_normals_of_a_plane(shape):
    a, b = 0.7, -1.9
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    n = surface_normals(a * xx + b * yy + 5)
    np.testing.assert_allclose(n, np.broadcast_to(_unit([-a, -b, 1]), (*shape, 3)), atol=1e-6)
    if shape[1] < 3:
        return
    # a paraboloid: central differences inside, one-sided second-order at the border
    z = (xx**2).astype(float)
    gx = surface_normals(z)[..., 0] * -1 / surface_normals(z)[..., 2]
    np.testing.assert_allclose(gx, 2.0 * xx, atol=1e-9)


def test_normals_of_a_rotated_plane_in_the_crop_frame():
    rgb, depth, valid = _scene(120, 120)  # 1 mm/px in x, 2 mm/px in y
    theta = np.radians(25)
    full, imask, dmask = rotated_crop(rgb, depth, valid, [60, 60, theta, 40, 20])
    assert full.shape == (20, 40, 8) and imask.all() and dmask.all()
    u = np.array([np.cos(theta), -np.sin(theta)])
    v = np.array([np.sin(theta), np.cos(theta)])
    grad = np.array([1.0, 2.0])
    expected = _unit([-(grad @ u), -(grad @ v), 1])
    np.testing.assert_allclose(full[..., 5:8], np.broadcast_to(expected, (20, 40, 3)), atol=2e-4)
    im, mk = rectangle_images(rgb, depth, valid, [[60, 60, theta, 40, 20]])
    np.testing.assert_allclose(im[0][mk[0, ..., 4]][:, 5:8],
                               np.broadcast_to(expected, (mk[0, ..., 4].sum(), 3)), atol=2e-4)


@pytest.mark.parametrize("method", ["band", "griddata"])
def test_hole_filling_is_linear_then_nearest(method):
    yy, xx = np.mgrid[0:30, 0:40]
    z = 3.0 * xx - 2.0 * yy + 7
    valid = np.ones(z.shape, bool)
    valid[10:16, 12:20] = False  # interior hole: linear interpolation is exact on a plane
    valid[:, 35:] = False  # outside the hull of valid pixels: nearest
    zz = np.where(valid, z, -1e6)
    out = fill_depth_holes(zz, valid, method)
    np.testing.assert_allclose(out[:, :35], z[:, :35], atol=1e-9)
    np.testing.assert_allclose(out[:, 35:], np.repeat(z[:, 34:35], 5, axis=1), atol=1e-9)
    assert np.all(fill_depth_holes(zz, np.zeros_like(valid)) == 0)
    with pytest.raises(ValueError, match="unknown fill"):
        fill_depth_holes(zz, valid, "cubic")


def test_image_channels():
    rgb, depth, valid = _scene()
    valid = valid.copy()
    valid[5, 5] = False
    im, mk = image_channels(rgb, depth, valid)
    assert im.shape == (60, 80, 8) and mk.shape == (60, 80, 8)
    assert not mk[5, 5, 4:].any() and mk[5, 5, :4].all()
    np.testing.assert_allclose(im[20, 30, 5:8], _unit([-1, -2, 1]), atol=1e-4)
    np.testing.assert_allclose(im[20, 30, 4], depth[20, 30] * 1000, rtol=1e-6)


# ------------------------------------------------------------------------------------------------
# Real data


def _check_real(im, mk):
    assert np.all(np.isfinite(im))
    assert np.all(im[~mk] == 0)
    assert mk[..., 0].mean() > 0.3
    assert mk[..., 4].mean() > 0.2
    assert np.all(im[..., :4][mk[..., :4]] >= 0) and np.all(im[..., :4] <= 1)
    norms = np.linalg.norm(im[..., 5:8], axis=-1)[mk[..., 5]]
    # unit before resizing; averaging differing normals (noisy stereo depth) shortens them
    assert norms.max() <= 1.0 + 1e-5 and np.median(norms) > 0.95
    assert np.mean(im[..., 7][mk[..., 7]] > 0) > 0.99  # normals face the camera


@pytest.mark.parametrize("depth_kind", ["perfect", "stereo"])
def test_real_jacquard_rectangles(jacquard_view, depth_kind):
    rgb, depth, valid, rects = jacquard_view(depth=depth_kind)
    im, mk = rectangle_images(rgb, depth, valid, rects)
    assert im.shape == (len(rects), 24, 24, 8)
    _check_real(im, mk)
    if depth_kind == "stereo":
        assert not valid.all()
        # the fast hole filling agrees with griddata on the masked output
        ref, mref = rectangle_images(rgb, depth, valid, rects[:30], fill="griddata")
        np.testing.assert_array_equal(mk[:30], mref)
        diff = np.abs(im[:30, ..., 5:] - ref[..., 5:])[mref[..., 5:]]
        assert diff.mean() < 0.01


def test_real_cornell_rectangles(cornell_samples_root):
    rgb = np.array(Image.open(cornell_samples_root / "pcd0100r.png").convert("RGB"))
    depth = np.array(Image.open(cornell_samples_root / "pcd0100d.tiff"), dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    depth = np.where(valid, depth, 0).astype(np.float32)
    # rectangles around the image centre (the object) plus one partly outside the image
    rng = np.random.default_rng(0)
    n = 40
    rects = np.column_stack([rng.uniform(250, 390, n), rng.uniform(180, 300, n),
                             rng.uniform(-np.pi / 2, np.pi / 2, n), rng.uniform(20, 80, n),
                             rng.uniform(10, 40, n)])
    rects = np.vstack([rects, [5.0, 240.0, 0.2, 60.0, 30.0]])
    im, mk = rectangle_images(rgb, depth, valid, rects)
    _check_real(im[:-1], mk[:-1])
    assert 0 < mk[-1, ..., 0].mean() < mk[:-1, ..., 0].mean()


def test_one_blas_thread_limits_inside_nests_and_restores():
    """BLAS is single-threaded inside (also for a worker thread started inside, e.g. the dense
    detector's), nested use keeps the limit, and the limits before are restored."""
    import threading

    from threadpoolctl import threadpool_info, threadpool_limits

    from dlsr._threads import one_blas_thread

    def blas_threads():
        return sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")

    with threadpool_limits(2, user_api="blas"):
        before = blas_threads()
        assert before and max(before) == 2
        seen = []
        with one_blas_thread():
            seen.append(blas_threads())
            with one_blas_thread():
                seen.append(blas_threads())
            seen.append(blas_threads())
            worker = threading.Thread(target=lambda: seen.append(blas_threads()))
            worker.start()
            worker.join(10)
        assert len(seen) == 4 and all(max(s) == 1 for s in seen)
        assert blas_threads() == before
