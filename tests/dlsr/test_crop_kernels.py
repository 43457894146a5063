"""The compiled crop kernels (dlsr._crops) against the numpy code they replaced, bit for bit;
the compiled hole location against scipy's up to float rounding; the nearest valid pixel
against scipy's distance transform, ties included."""

import numpy as np
import pytest
from scipy import ndimage

from dlsr import _crops
from dlsr.preprocess import (
    GRAY_WEIGHTS,
    _check_image,
    _resize_into,
    fill_depth_holes,
    rectangle_images,
    surface_normals,
)

_ONE = 1.0 - 1e-6


# --- the numpy code of dlsr.preprocess before the kernels (the reference) --------------------
def _ref_resize_into(full, imask, dmask, size, interp):
    """The resize, padding and masking as one stack of 10 channels, resized in slices of 4."""
    import cv2

    nrows, ncols = imask.shape
    scale = size / max(nrows, ncols)
    nh = min(size, max(1, int(round(nrows * scale))))
    nw = min(size, max(1, int(round(ncols * scale))))
    stack = np.concatenate(
        [full, imask[..., None].astype(np.float32), dmask[..., None].astype(np.float32)], axis=2
    )
    if (nh, nw) == (nrows, ncols):
        small = stack
    elif interp == cv2.INTER_LINEAR:
        small = cv2.resize(stack, (nw, nh), interpolation=interp)
    else:
        small = np.concatenate(
            [cv2.resize(stack[..., i:i + 4], (nw, nh), interpolation=interp).reshape(nh, nw, -1)
             for i in range(0, 10, 4)], axis=2)
    small = small.reshape(nh, nw, 10)
    img = np.zeros((size, size, 8), dtype=np.float32)
    msk = np.zeros((size, size, 8), dtype=bool)
    r0 = (size - nh) // 2
    c0 = (size - nw) // 2
    im = small[..., 8] > 0.75
    dm = small[..., 9] > 0.75
    msk[r0:r0 + nh, c0:c0 + nw, :4] = im[..., None]
    msk[r0:r0 + nh, c0:c0 + nw, 4:] = dm[..., None]
    img[r0:r0 + nh, c0:c0 + nw] = np.where(msk[r0:r0 + nh, c0:c0 + nw], small[..., :8], 0.0)
    return img, msk


def _ref_normals(z):
    z = np.asarray(z, dtype=np.float64)

    def grad(a, axis):
        a = np.moveaxis(a, axis, 0)
        m = a.shape[0]
        if m == 1:
            return np.moveaxis(np.zeros_like(a), 0, axis)
        if m == 2:
            lo, hi = 2 * a[0] - a[1], 2 * a[1] - a[0]
        else:
            lo = 3 * a[0] - 3 * a[1] + a[2]
            hi = 3 * a[-1] - 3 * a[-2] + a[-3]
        p = np.concatenate([lo[None], a, hi[None]], axis=0)
        return np.moveaxis((p[2:] - p[:-2]) / 2.0, 0, axis)

    gx = grad(z, 1)
    gy = grad(z, 0)
    inv = 1.0 / np.sqrt(gx * gx + gy * gy + 1.0)
    return np.stack([-gx * inv, -gy * inv, inv], axis=-1).astype(np.float32)


def _ref_sample(src, rect, ncols, nrows):
    x, y, theta, _, _ = rect
    c, s = np.cos(theta), np.sin(theta)
    u = np.array([c, -s])
    v = np.array([s, c])
    cols = np.arange(ncols) - (ncols - 1) / 2.0
    rows = np.arange(nrows) - (nrows - 1) / 2.0
    H, W = src.shape[0] - 2, src.shape[1] - 2
    xs = np.clip(x + 1 + rows[:, None] * v[0] + cols[None, :] * u[0], 0.0, W + 1.0)
    ys = np.clip(y + 1 + rows[:, None] * v[1] + cols[None, :] * u[1], 0.0, H + 1.0)
    x0 = np.minimum(np.floor(xs).astype(np.intp), W)
    y0 = np.minimum(np.floor(ys).astype(np.intp), H)
    fx = (xs - x0)[..., None].astype(np.float32)
    fy = (ys - y0)[..., None].astype(np.float32)
    top = src[y0, x0] * (1 - fx) + src[y0, x0 + 1] * fx
    bot = src[y0 + 1, x0] * (1 - fx) + src[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bot * fy


def _ref_crop(src, rect, depth_scale=1000.0, outlier_sigma=4.0, outlier_passes=2, fill="band",
              band=1):
    ncols = int(round(rect[3]))
    nrows = int(round(rect[4]))
    smp = _ref_sample(src, rect, ncols, nrows)
    inside = smp[..., 5] >= _ONE
    dvalid = (smp[..., 4] >= _ONE) & inside
    dep = smp[..., 3].astype(np.float64)
    for _ in range(outlier_passes):
        vals = dep[dvalid]
        if vals.size < 2:
            break
        mu = vals.mean()
        sd = vals.std(ddof=1)
        dvalid &= ~(np.abs(dep - mu) > outlier_sigma * sd)
    full = np.zeros((nrows, ncols, 8), dtype=np.float32)
    rgb = smp[..., :3] * inside[..., None]
    full[..., 1:4] = rgb
    r, g, b = GRAY_WEIGHTS
    full[..., 0] = r * rgb[..., 0] + g * rgb[..., 1] + b * rgb[..., 2]
    if dvalid.any():
        d = np.where(dvalid, (dep - dep[dvalid].mean()) * depth_scale, 0.0)
        full[..., 4] = d
        full[..., 5:8] = _ref_normals(fill_depth_holes(d, dvalid, fill, band))
    return full, inside, dvalid


def _scene(seed, H=90, W=120, holes=0.08):
    """An RGB-D view: a table, a box and a cylinder on it, dropouts and a shadow."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    depth = 0.60 + 0.0004 * xx + 0.0002 * yy + rng.normal(0, 0.0015, (H, W))
    box = (abs(xx - 40) < 14) & (abs(yy - 45) < 10)
    depth[box] -= 0.05 + 0.001 * (xx[box] - 40)
    cyl = (xx - 85) ** 2 + (yy - 40) ** 2 < 12 ** 2
    depth[cyl] = 0.54 + 0.0003 * ((xx[cyl] - 85) ** 2 + (yy[cyl] - 40) ** 2)
    valid = rng.random((H, W)) > holes
    valid &= ~((xx > 54) & (xx < 58) & (abs(yy - 45) < 10))  # a shadow beside the box
    depth[~valid] = 0.0
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    n = 60
    rects = np.column_stack([rng.uniform(5, W - 5, n), rng.uniform(5, H - 5, n),
                             rng.uniform(-np.pi / 2, np.pi / 2, n), rng.uniform(3, 70, n),
                             rng.uniform(2, 30, n)])
    rects[:4, 3:] = [[2.2, 2.4], [7.0, 1.6 + 0.6], [30.0, 30.0], [45.5, 12.5]]
    return rgb, depth.astype(np.float32), valid, rects


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rectangle_images_equal_the_numpy_code_bit_for_bit(seed):
    rgb, depth, valid, rects = _scene(seed)
    images, masks = rectangle_images(rgb, depth, valid, rects)
    src = _check_image(rgb, depth, valid)
    import cv2

    from dlsr.preprocess import _check_rects

    for i, rect in enumerate(_check_rects(rects)):
        full, im, dm = _ref_crop(src, rect)
        img, msk = _ref_resize_into(full, im, dm, 24, cv2.INTER_AREA)
        np.testing.assert_array_equal(images[i], img, err_msg=f"rectangle {i}")
        np.testing.assert_array_equal(masks[i], msk, err_msg=f"rectangle {i}")


@pytest.mark.parametrize("seed", [0, 3])
def test_compiled_hole_location_agrees_with_scipy(seed):
    rgb, depth, valid, rects = _scene(seed, holes=0.2)
    a = rectangle_images(rgb, depth, valid, rects)
    b = rectangle_images(rgb, depth, valid, rects, locate="compiled")
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_allclose(b[0], a[0], rtol=0, atol=1e-6)
    # the filled depth itself: the same triangles, the values up to rounding
    rng = np.random.default_rng(seed)
    for _ in range(40):
        m, n = rng.integers(2, 30, 2)
        z = np.cumsum(rng.normal(size=(m, n)), axis=1) * 10
        ok = rng.random((m, n)) > rng.uniform(0.05, 0.6)
        ref = fill_depth_holes(z, ok, "band", 1)
        got = fill_depth_holes(z, ok, "band", 1, locate="compiled")
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-9)


def test_compiled_fill_edge_cases():
    z = np.arange(12.0).reshape(3, 4)
    row = np.zeros((3, 4), bool)
    row[1] = True  # collinear support: nearest only, as scipy's
    np.testing.assert_array_equal(fill_depth_holes(z, row, locate="compiled"),
                                  fill_depth_holes(z, row))
    one = np.ones((3, 4), bool)
    one[1, 2] = False  # a single hole: the value of one diagonal of its square
    got = fill_depth_holes(z, one, locate="compiled")
    assert got[1, 2] == pytest.approx(fill_depth_holes(z, one)[1, 2])
    with pytest.raises(ValueError, match="locate"):
        fill_depth_holes(z, one, locate="qhull")
    with pytest.raises(ValueError, match="locate"):
        rectangle_images(np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.float32), None,
                         np.array([[2.0, 2, 0, 3, 3]]), locate="?")


def test_hole_band_is_the_dilated_holes():
    rng = np.random.default_rng(4)
    for band in (1, 2, 3):
        ok = rng.random((17, 23)) > 0.1
        ref = ok & ndimage.binary_dilation(~ok, structure=np.ones((3, 3), bool),
                                           iterations=band)
        np.testing.assert_array_equal(_crops.hole_band(ok, band), ref)


@pytest.mark.parametrize("interpolation", ["area", "linear", "cubic"])
def test_resize_into_is_the_stack_resized_in_slices(interpolation):
    """Every crop shape of the lattice (2 to 44 rows, 2 to 120 columns), bit for bit."""
    import cv2

    interp = {"area": cv2.INTER_AREA, "linear": cv2.INTER_LINEAR,
              "cubic": cv2.INTER_CUBIC}[interpolation]
    rng = np.random.default_rng(6)
    shapes = [(r, c) for r in range(2, 45, 3) for c in list(range(2, 60, 2)) + [75, 101, 120]]
    shapes += [(24, 24), (24, 10), (10, 24), (1, 7), (7, 1)]
    for nrows, ncols in shapes:
        full = rng.normal(size=(nrows, ncols, 8)).astype(np.float32)
        im = rng.random((nrows, ncols)) > 0.1
        dm = rng.random((nrows, ncols)) > 0.3
        got = _resize_into(full, im, dm, 24, interp)
        ref = _ref_resize_into(full, im, dm, 24, interp)
        np.testing.assert_array_equal(got[0], ref[0], err_msg=f"{nrows} x {ncols}")
        np.testing.assert_array_equal(got[1], ref[1], err_msg=f"{nrows} x {ncols}")


def _site_masks(seed, n):
    rng = np.random.default_rng(seed)
    for t in range(n):
        m, k = int(rng.integers(1, 40)), int(rng.integers(1, 90))
        site = rng.random((m, k)) < rng.choice([0.02, 0.1, 0.5, 0.9, 0.99])
        if t % 3 == 0:  # rectangular holes: equidistant sites everywhere
            site = np.ones((m, k), bool)
            for _ in range(int(rng.integers(1, 5))):
                a, b = rng.integers(0, m), rng.integers(0, k)
                site[a:a + rng.integers(1, 12), b:b + rng.integers(1, 12)] = False
        if site.any():
            yield site


@pytest.mark.parametrize("seed", [0, 1])
def test_nearest_sites_are_scipys_distance_transform_ties_included(seed):
    n_cases = 0
    for site in _site_masks(seed, 600):
        _, (ry, rx) = ndimage.distance_transform_edt(~site, return_indices=True)
        iy = np.empty(site.shape, np.int64)
        ix = np.empty(site.shape, np.int64)
        _crops.nearest_sites(site, np.ones(site.shape[0], bool), iy, ix)
        np.testing.assert_array_equal(iy, ry)
        np.testing.assert_array_equal(ix, rx)
        need = np.random.default_rng(n_cases).random(site.shape[0]) < 0.3  # some rows only
        iy[:], ix[:] = -7, -7
        _crops.nearest_sites(site, need, iy, ix)
        np.testing.assert_array_equal(iy[need], ry[need])
        np.testing.assert_array_equal(ix[need], rx[need])
        n_cases += 1
    assert n_cases > 500


def test_fill_depth_holes_nearest_part_is_scipys():
    """The holes outside the triangulation (and every hole with ``"nearest"``) take the value
    of the pixel scipy's distance transform names."""
    rng = np.random.default_rng(8)
    for site in _site_masks(3, 200):
        z = rng.normal(size=site.shape)
        _, (ry, rx) = ndimage.distance_transform_edt(~site, return_indices=True)
        ref = np.where(site, z, z[ry, rx])
        np.testing.assert_array_equal(fill_depth_holes(z, site, "nearest"), ref)


@pytest.mark.parametrize("shape", [(1, 1), (1, 5), (2, 2), (2, 7), (3, 3), (6, 1), (14, 57)])
def test_surface_normals_equal_the_numpy_code(shape):
    z = np.random.default_rng(5).normal(size=shape) * 100
    np.testing.assert_array_equal(surface_normals(z), _ref_normals(z))


def test_pairwise_sum_is_numpys():
    rng = np.random.default_rng(6)
    for n in [*range(0, 300, 7), 1000, 2345, 9000]:
        a = rng.normal(size=n) * 10.0 ** rng.uniform(-3, 3)
        assert _crops.pairwise_sum(a, 0, n) == a.sum()
        if n > 3:
            assert _crops.pairwise_sum(a, 3, n - 3) == a[3:].sum()
