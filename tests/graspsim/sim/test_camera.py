"""graspsim.sim.camera: z-buffer depth, projection, and the Kinect-like depth-noise model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

pybullet = pytest.importorskip("pybullet")
from pybullet_utils.bullet_client import BulletClient  # noqa: E402

from graspsim.sim.camera import (  # noqa: E402
    Camera,
    CameraIntrinsics,
    DepthNoise,
    Lights,
    apply_depth_noise,
    axial_sigma,
    backproject,
    depth_figure,
    look_down_pose,
    project,
    projector_shadow,
    random_table_texture,
)

pytestmark = pytest.mark.sim

INTR = CameraIntrinsics()
OFF = DepthNoise.off()


def only(**switch) -> DepthNoise:
    return replace(OFF, **switch)


def down_pose(h=0.7, xy=(0.0, 0.0), yaw=0.0) -> np.ndarray:
    """Camera at height h looking straight down; image x along world (cos yaw, sin yaw)."""
    rng = np.random.default_rng(0)
    T = look_down_pose(rng, height=(h, h), jitter=(0.0, 0.0, 0.0), target=xy)
    if yaw:
        c, s = np.cos(yaw), np.sin(yaw)
        T[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ T[:3, :3]
    return T


@pytest.fixture
def client():
    c = BulletClient(connection_mode=pybullet.DIRECT)
    yield c
    c.disconnect()


def add_plane(c, z=0.0):
    col = c.createCollisionShape(c.GEOM_BOX, halfExtents=[2, 2, 0.01])
    vis = c.createVisualShape(c.GEOM_BOX, halfExtents=[2, 2, 0.01], rgbaColor=[0.6, 0.6, 0.6, 1])
    return c.createMultiBody(0, col, vis, [0, 0, z - 0.01])


def add_box(c, half, pos, rgba=(0.8, 0.3, 0.2, 1)):
    col = c.createCollisionShape(c.GEOM_BOX, halfExtents=list(half))
    vis = c.createVisualShape(c.GEOM_BOX, halfExtents=list(half), rgbaColor=list(rgba))
    return c.createMultiBody(0, col, vis, list(pos))


def plane_depth_analytic(T, intr, plane_z):
    """z-depth of the plane z = plane_z seen through every pixel."""
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, float)], -1)
    dw = d @ T[:3, :3].T
    return (plane_z - T[2, 3]) / dw[..., 2]  # scale of d (whose z is 1) = z-depth


# --------------------------------------------------------------------------- geometry


def test_intrinsics_defaults_kinect_like():
    K = INTR.K
    assert K.shape == (3, 3)
    assert 525 <= INTR.fx <= 580 and INTR.fx == INTR.fy
    assert (INTR.cx, INTR.cy) == ((640 - 1) / 2, (480 - 1) / 2)
    P = INTR.projection_matrix()
    # a camera-frame point projects through P to the same pixel as through K
    pt = np.array([0.05, -0.03, 0.7])
    uv = K @ pt
    uv = uv[:2] / uv[2]
    gl = np.array([pt[0], -pt[1], -pt[2], 1.0])
    clip = P @ gl
    ndc = clip[:3] / clip[3]
    u = (ndc[0] + 1) / 2 * INTR.width - 0.5
    v = (1 - ndc[1]) / 2 * INTR.height - 0.5
    np.testing.assert_allclose([u, v], uv, atol=1e-9)


def test_bad_intrinsics_raise():
    with pytest.raises(ValueError):
        CameraIntrinsics(near=1.0, far=0.5)


def test_look_down_pose_is_a_rigid_transform_looking_down():
    rng = np.random.default_rng(1)
    for _ in range(20):
        T = look_down_pose(rng, table_z=0.1)
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert R[2, 2] < -0.99  # optical axis (camera z) points down, tilt <= 0.08 rad
        # height above the table along the vertical, within the default range
        assert 0.6 - 1e-9 <= T[2, 3] - 0.1 <= 0.8 + 1e-9


@pytest.mark.parametrize("tilted", [False, True])
def test_zbuffer_depth_matches_plane(client, tilted):
    plane_z = 0.05
    add_plane(client, plane_z)
    T = look_down_pose(np.random.default_rng(3), height=(0.65, 0.65),
                       jitter=(0.02, 0.08 if tilted else 0.0, np.pi), table_z=plane_z)
    rgb, depth, seg = Camera(client).render_clean(T, Lights())
    expected = plane_depth_analytic(T, INTR, plane_z)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8
    assert depth.dtype == np.float32 and seg.dtype == np.int32
    assert np.all(seg >= 0)
    assert np.max(np.abs(depth - expected)) < 1e-3


def test_known_point_projects_where_it_renders(client):
    add_plane(client)
    point = np.array([0.06, -0.04, 0.03])  # centre of the top face of a thin square
    body = add_box(client, (0.01, 0.01, 0.0025), point - [0, 0, 0.0025])
    T = look_down_pose(np.random.default_rng(5), height=(0.7, 0.7), jitter=(0.0, 0.0, np.pi))
    _, depth, seg = Camera(client).render_clean(T, Lights())
    uv, z = project(point, INTR, T)
    vs, us = np.nonzero(seg == body)
    assert len(us) > 50
    np.testing.assert_allclose([us.mean(), vs.mean()], uv[0], atol=0.75)
    u, v = np.rint(uv[0]).astype(int)
    assert depth[v, u] == pytest.approx(z[0], abs=1e-3)
    # and back-projecting that pixel gives the point back (to a pixel's footprint)
    p_cam = backproject(depth, INTR)[v, u]
    p_world = T[:3, :3] @ p_cam + T[:3, 3]
    np.testing.assert_allclose(p_world, point, atol=2e-3)


def test_background_is_missing_not_far(client):
    add_box(client, (0.02, 0.02, 0.02), (0, 0, 0.02))
    frame = Camera(client).render(down_pose(), np.random.default_rng(0), noise=OFF)
    bg = frame.segmentation < 0
    assert bg.any()
    assert np.all(frame.depth_clean[bg] == 0) and not frame.depth_valid[bg].any()


# --------------------------------------------------------------------------- rendering + noise


@pytest.fixture
def box_scene(client):
    plane = add_plane(client)
    box = add_box(client, (0.05, 0.05, 0.05), (0, 0, 0.05))
    return client, plane, box


def test_noise_off_observed_equals_clean(box_scene):
    client, _, _ = box_scene
    f = Camera(client).render(down_pose(), np.random.default_rng(0), noise=OFF)
    np.testing.assert_array_equal(f.depth, f.depth_clean)
    np.testing.assert_array_equal(f.depth_valid, f.depth_clean > 0)


def test_same_seed_same_frame(box_scene):
    client, plane, box = box_scene
    cam = Camera(client)
    mats = {box: "dark"}
    frames = [cam.render(down_pose(), np.random.default_rng(7), materials=mats) for _ in range(2)]
    for name in ("rgb", "depth", "depth_valid", "depth_clean", "segmentation"):
        np.testing.assert_array_equal(getattr(frames[0], name), getattr(frames[1], name))
    other = cam.render(down_pose(), np.random.default_rng(8), materials=mats)
    assert not np.array_equal(other.depth, frames[0].depth)


def test_missing_depth_is_zero_never_nan(box_scene):
    client, plane, box = box_scene
    f = Camera(client).render(down_pose(0.6), np.random.default_rng(1),
                              materials={box: "transparent"})
    assert f.depth.dtype == np.float32 and f.depth_valid.dtype == bool
    assert np.all(np.isfinite(f.depth))
    assert np.all(f.depth[~f.depth_valid] == 0)
    assert np.all(f.depth[f.depth_valid] > 0)
    assert 0 < (~f.depth_valid).sum() < f.depth.size


def test_projector_shadow_falls_beside_the_box_away_from_projector(box_scene):
    client, _, box = box_scene
    f = Camera(client).render(down_pose(), np.random.default_rng(0), noise=only(shadow=True))
    missing = ~f.depth_valid
    # only dropout, no change of the valid depths
    np.testing.assert_array_equal(f.depth[f.depth_valid], f.depth_clean[f.depth_valid])
    vs, us = np.nonzero(f.segmentation == box)
    rows = (np.arange(480) > vs.min() + 3) & (np.arange(480) < vs.max() - 3)
    left = missing[rows][:, : us.min()].sum()
    right = missing[rows][:, us.max() + 1:].sum()
    # box top at 0.6 m, floor at 0.7 m: shadow width f*b*(1/0.6 - 1/0.7) = 9.8 px
    width = INTR.fx * 0.075 * (1 / 0.6 - 1 / 0.7)
    assert left / rows.sum() == pytest.approx(width, abs=2.0)
    assert right == 0
    assert not missing[f.segmentation == box].any()  # the box top is lit
    # moving the projector to the other side mirrors the shadow
    g = Camera(client).render(down_pose(), np.random.default_rng(0),
                              noise=only(shadow=True, projector_offset=(-0.075, 0, 0)))
    assert (~g.depth_valid)[rows][:, us.max() + 1:].sum() / rows.sum() == pytest.approx(width, 2)


def test_material_dropout_only_on_its_bodies(client):
    add_plane(client)
    bodies = {m: add_box(client, (0.04, 0.04, 0.03), (x, 0, 0.03))
              for m, x in (("matte", -0.15), ("dark", -0.05), ("specular", 0.05),
                           ("transparent", 0.15))}
    mats = {b: m for m, b in bodies.items()}
    noise = only(materials=True)
    f = Camera(client).render(down_pose(0.6), np.random.default_rng(2), noise=noise,
                              materials=mats)
    np.testing.assert_array_equal(f.depth[f.depth_valid], f.depth_clean[f.depth_valid])
    frac = {m: 1 - f.depth_valid[f.segmentation == b].mean() for m, b in bodies.items()}
    assert frac["matte"] == 0
    assert frac["dark"] == pytest.approx(noise.p_dark, abs=0.15)
    # the box tops face the camera: specular highlight
    assert frac["specular"] == pytest.approx(noise.p_specular_highlight, abs=0.15)
    assert frac["transparent"] == pytest.approx(noise.p_transparent, abs=0.1)
    others = ~np.isin(f.segmentation, list(mats)[1:])
    assert f.depth_valid[others].all()
    with pytest.raises(ValueError, match="material"):
        Camera(client).render(down_pose(), np.random.default_rng(0), noise=noise,
                              materials={bodies["dark"]: "velvet"})


# ----------------------------------------------------------------- noise on synthetic depth


def step_depth(near=0.6, far=0.7):
    d = np.full((480, 640), far, np.float32)
    d[140:340, 220:420] = near
    return d


def test_axial_noise_matches_nguyen_sigma():
    d = np.full((480, 640), 0.9, np.float32)
    out, valid = apply_depth_noise(d, INTR, np.random.default_rng(0), only(axial=True))
    assert valid.all()
    sigma = axial_sigma(0.9)
    assert sigma == pytest.approx(0.0012 + 0.0019 * 0.5**2)
    assert np.std(out - d) == pytest.approx(sigma, rel=0.03)
    assert abs(np.mean(out - d)) < 1e-4


def test_quantisation_is_one_eighth_pixel_disparity():
    z = np.linspace(0.5, 1.0, 640, dtype=np.float32)[None, :].repeat(480, 0)
    out, valid = apply_depth_noise(z, INTR, np.random.default_rng(0), only(quantisation=True))
    assert valid.all()
    fb = INTR.fx * 0.075
    disparity = fb / out.astype(np.float64)
    np.testing.assert_allclose(disparity * 8, np.rint(disparity * 8), atol=1e-3)
    step = z.astype(np.float64) ** 2 / (8 * fb)
    assert np.all(np.abs(out - z) <= 0.5 * step * 1.01 + 1e-6)
    assert np.any(out != z)


def test_lateral_noise_only_moves_edges():
    d = step_depth()
    out, valid = apply_depth_noise(d, INTR, np.random.default_rng(0), only(lateral=True))
    changed = out != d
    assert changed.any() and valid.all()
    assert set(np.unique(out)) <= {np.float32(0.6), np.float32(0.7)}
    vs, us = np.nonzero(changed)
    dist = np.minimum.reduce([np.abs(us - 220), np.abs(us - 419), np.abs(vs - 140),
                              np.abs(vs - 339)])
    assert dist.max() <= 6  # 0.8 px sigma on a fronto-parallel step


def test_edge_dropout_only_at_depth_jumps():
    d = step_depth()
    noise = only(edges=True)
    out, valid = apply_depth_noise(d, INTR, np.random.default_rng(0), noise)
    missing = ~valid
    np.testing.assert_array_equal(out[valid], d[valid])
    assert np.all(out[missing] == 0)
    vs, us = np.nonzero(missing)
    dist = np.minimum.reduce([np.abs(us - 219.5), np.abs(us - 419.5), np.abs(vs - 139.5),
                              np.abs(vs - 339.5)])
    assert dist.max() <= noise.edge_width + 0.5
    n_band = 2 * 2 * (200 + 200) * noise.edge_width
    assert missing.sum() / n_band == pytest.approx(noise.p_edge, abs=0.15)


def test_grazing_dropout_on_a_steep_plane_only():
    # plane z = z0 + tan(alpha) * x seen from the origin: left half 20 deg, right half 82 deg
    u = np.arange(640)[None, :].repeat(480, 0)
    v = np.arange(480)[:, None].repeat(640, 1)
    xn = (u - INTR.cx) / INTR.fx
    d = np.empty((480, 640))
    for mask, alpha in ((u < 320, 20.0), (u >= 320, 82.0)):
        t = np.tan(np.deg2rad(alpha))
        d[mask] = 0.7 / (1 - t * xn[mask])
    d = d.astype(np.float32)
    out, valid = apply_depth_noise(d, INTR, np.random.default_rng(0), only(grazing=True))
    np.testing.assert_array_equal(out[valid], d[valid])
    inner = (v > 5) & (v < 474)
    assert valid[inner & (u > 5) & (u < 300)].all()
    steep = 1 - valid[inner & (u > 340) & (u < 630)].mean()
    assert steep > 0.3
    del v


def test_each_switch_leaves_the_others_draws_unchanged():
    d = step_depth()
    a, va = apply_depth_noise(d, INTR, np.random.default_rng(4), only(axial=True, edges=True))
    b, vb = apply_depth_noise(d, INTR, np.random.default_rng(4), only(axial=True))
    both = va & vb
    np.testing.assert_array_equal(a[both], b[both])
    np.testing.assert_array_equal(vb, d > 0)


def test_projector_shadow_function_on_synthetic_step():
    d = step_depth()
    s = projector_shadow(d, INTR, (0.075, 0, 0))
    width = INTR.fx * 0.075 * (1 / 0.6 - 1 / 0.7)
    cols = np.nonzero(s[240])[0]
    assert cols.min() >= 220 - width - 1 and cols.max() < 220
    assert len(cols) == pytest.approx(width, abs=1.0)
    assert not s[:130].any() and not s[350:].any()


def test_zero_depth_stays_missing():
    d = step_depth()
    d[:, :50] = 0
    out, valid = apply_depth_noise(d, INTR, np.random.default_rng(0), DepthNoise())
    assert not valid[:, :50].any() and np.all(out[:, :50] == 0)
    assert np.all(np.isfinite(out))


def test_table_texture_and_figure(client, tmp_path):
    plane = add_plane(client)
    tex = random_table_texture(client, np.random.default_rng(0), body=plane)
    assert tex >= 0
    f = Camera(client).render(down_pose(), np.random.default_rng(0))
    assert f.rgb.std() > 1  # textured, not a flat colour
    path = depth_figure(f, tmp_path / "fig.png")
    assert path.exists() and path.stat().st_size > 10_000


def test_table_textures_are_not_cached_by_file_name(client):
    # pybullet caches textures by file name: each new texture must really change the image
    plane = add_plane(client)
    cam, T = Camera(client), down_pose()
    images = []
    for seed in (1, 2, 1):
        random_table_texture(client, np.random.default_rng(seed), body=plane)
        images.append(cam.render_clean(T, Lights())[0])
    assert not np.array_equal(images[0], images[1])
    np.testing.assert_array_equal(images[0], images[2])
