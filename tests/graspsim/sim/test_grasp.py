"""rectangle_to_grasp: pure geometry, no pybullet."""

from __future__ import annotations

import numpy as np
import pytest

from dlsr.rectangles import GraspRectangle
from graspsim.sim.grasp import (
    DEPTH_MISSING,
    TOO_WIDE,
    central_depth,
    fingers_collide,
    nearest_depth,
    rectangle_to_grasp,
    settle_fingers,
    table_plane_depth,
)
from graspsim.sim.gripper import FINGER_THICKNESS, PAD_WIDTH, PALM_OFFSET, TIP_OFFSET

F, CX, CY = 550.0, 319.5, 239.5
K = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1.0]])


def look_down(height=0.7):
    """Camera at (0, 0, height) looking straight down; image x = world x, image y = -world y."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = height
    return T


def tilted(rng):
    """A random camera rotation with the optical axis within 20 degrees of straight down."""
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    ang = np.radians(rng.uniform(0, 20))
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R = np.eye(3) + np.sin(ang) * Kx + (1 - np.cos(ang)) * Kx @ Kx
    T = look_down(0.7)
    T[:3, :3] = R @ T[:3, :3]
    T[:3, 3] = rng.uniform(-0.05, 0.05, 3) + [0, 0, 0.7]
    return T


def flat(z=0.7):
    return np.full((480, 640), z, np.float32), np.ones((480, 640), bool)


def test_centre_opening_and_axes_looking_down():
    depth, valid = flat(0.7)
    rect = GraspRectangle(CX, CY, 0.0, 55.0, 20.0)
    g = rectangle_to_grasp(rect, depth, valid, K, look_down(0.7), depth_offset=0.015,
                           margin=0.005)
    assert g.failure is None
    # w z / f = 55 * 0.7 / 550 = 0.07 m; opening adds the margin.
    assert g.width == pytest.approx(0.07)
    assert g.opening == pytest.approx(0.075)
    # Surface at world z = 0, centre 1.5 cm below it along the (downward) approach.
    np.testing.assert_allclose(g.position, [0.0, 0.0, -0.015], atol=1e-6)  # float32 depth
    np.testing.assert_allclose(g.approach, [0.0, 0.0, -1.0], atol=1e-12)
    # theta = 0: closing along the image x axis = world x.
    np.testing.assert_allclose(np.abs(g.T_world_grasp[:3, 0]), [1.0, 0.0, 0.0], atol=1e-12)


def test_theta_is_counter_clockwise_as_displayed():
    depth, valid = flat(0.7)
    # 45 degrees CCW as displayed: image direction (1, -1)/sqrt2 (up and right), i.e. camera
    # (1, -1, 0)/sqrt2, i.e. world (1, 1, 0)/sqrt2 for this camera (image y = -world y).
    g = rectangle_to_grasp(GraspRectangle(CX, CY, np.pi / 4, 40.0, 20.0), depth, valid, K,
                           look_down())
    np.testing.assert_allclose(g.T_world_grasp[:3, 0], np.array([1, 1, 0]) / np.sqrt(2),
                               atol=1e-12)


def test_pose_is_a_rigid_transform_and_reprojects_to_the_rectangle(rng):
    for _ in range(10):
        T_wc = tilted(rng)
        z = rng.uniform(0.5, 0.8)
        depth, valid = flat(z)
        rect = GraspRectangle(rng.uniform(100, 540), rng.uniform(100, 380),
                              rng.uniform(-1.5, 1.5), rng.uniform(20, 60), 15.0)
        g = rectangle_to_grasp(rect, depth, valid, K, T_wc, depth_offset=0.0)
        R = g.T_world_grasp[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-10)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(g.approach, T_wc[:3, 2], atol=1e-12)
        p_cam = np.linalg.inv(T_wc) @ np.append(g.position, 1.0)
        uv = (K @ p_cam[:3])[:2] / p_cam[2]
        np.testing.assert_allclose(uv, [rect.x, rect.y], atol=1e-6)
        assert p_cam[2] == pytest.approx(z)
        # The closing axis projects onto the rectangle's closing direction.
        q = np.linalg.inv(T_wc) @ np.append(g.position + 0.01 * g.T_world_grasp[:3, 0], 1.0)
        d = (K @ q[:3])[:2] / q[2] - uv
        d /= np.linalg.norm(d)
        assert abs(d @ [np.cos(rect.theta), -np.sin(rect.theta)]) == pytest.approx(1.0, abs=1e-9)


def test_robust_depth_is_the_median_of_the_central_region():
    depth, valid = flat(0.7)
    depth[235:245, 315:325] = 0.6  # an object top under the centre
    depth[238, 318] = 5.0  # an outlier
    rect = GraspRectangle(CX, CY, 0.0, 20.0, 20.0)  # central region 10 x 10 px
    assert central_depth(rect, depth, valid) == pytest.approx(0.6)


def test_all_masked_centre_falls_back_to_the_failure_reason():
    depth, valid = flat(0.7)
    valid[200:280, 280:360] = False
    depth[~valid] = 0.0
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.3, 40.0, 20.0), depth, valid, K,
                           look_down())
    assert g.failure == DEPTH_MISSING
    assert g.T_world_grasp is None and g.position is None
    # Valid depth in the outer half of the rectangle is not used: still missing ...
    g2 = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 150.0, 20.0), depth, valid, K,
                            look_down())
    assert g2.failure == DEPTH_MISSING
    # ... until the central half (here +-50 px) reaches valid pixels.
    g3 = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 200.0, 20.0), depth, valid, K,
                            look_down())
    assert g3.failure in (None, TOO_WIDE) and g3.depth == pytest.approx(0.7)


def test_too_wide_for_the_gripper():
    depth, valid = flat(0.7)
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 100.0, 20.0), depth, valid, K,
                           look_down())
    assert g.failure == TOO_WIDE
    assert g.width == pytest.approx(100 * 0.7 / F)
    assert g.opening == pytest.approx(0.08)


def test_inputs_are_not_mutated_and_bad_shapes_raise():
    depth, valid = flat(0.7)
    d0, v0 = depth.copy(), valid.copy()
    T = look_down()
    T0 = T.copy()
    rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth, valid, K, T)
    assert np.array_equal(depth, d0) and np.array_equal(valid, v0) and np.array_equal(T, T0)
    with pytest.raises(ValueError, match="4x4"):
        rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth, valid, K, np.eye(3))
    with pytest.raises(ValueError, match="same"):
        rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth, valid[:10], K, T)
    # a camera matrix that would make every pose NaN or infinite is refused, by both functions
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth, valid, K, T)
    for bad in (np.full((3, 3), np.nan), np.diag([0.0, F, 1.0]), np.eye(2)):
        with pytest.raises(ValueError, match="intrinsics must be a 3x3 camera matrix"):
            rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth, valid, bad, T)
        with pytest.raises(ValueError, match="intrinsics must be a 3x3 camera matrix"):
            fingers_collide(g, depth, valid, bad, T)


def cup(rim_depth=0.60, inner_depth=0.68, rim_px=(20, 28)):
    """An open cup seen from above: a rim ring between ``rim_px`` radii, a deep cavity inside."""
    depth, valid = flat(0.75)  # the table
    yy, xx = np.mgrid[0:480, 0:640]
    r = np.hypot(xx - CX, yy - CY)
    depth[r < rim_px[1]] = rim_depth
    depth[r < rim_px[0]] = inner_depth
    return depth, valid


def test_grasp_over_a_deep_cavity_keeps_the_palm_clear_of_the_rim():
    depth, valid = cup()
    rect = GraspRectangle(CX, CY, 0.0, 60.0, 20.0)  # jaws outside the rim, centre over the hole
    g = rectangle_to_grasp(rect, depth, valid, K, look_down(0.75), palm_clearance=0.005)
    assert g.failure is None
    assert g.depth == pytest.approx(0.68)  # the surface under the centre is the cup's bottom
    # Camera looks straight down from 0.75 m: the centre's camera depth is 0.75 - world z.
    centre_depth = 0.75 - g.position[2]
    assert centre_depth == pytest.approx(0.60 + PALM_OFFSET - 0.005, abs=1e-6)
    assert centre_depth < 0.68 + 0.015  # shallower than depth_offset alone would put it
    # A shallow cavity leaves the requested depth offset untouched.
    depth2, valid2 = cup(inner_depth=0.61)
    g2 = rectangle_to_grasp(rect, depth2, valid2, K, look_down(0.75))
    assert 0.75 - g2.position[2] == pytest.approx(0.61 + 0.015, abs=1e-6)


def test_nearest_depth_ignores_a_few_noisy_pixels_but_not_a_rim():
    depth, valid = flat(0.7)
    rect = GraspRectangle(CX, CY, 0.0, 60.0, 20.0)
    depth[240, 320] = 0.2  # one flying pixel
    assert nearest_depth(rect, depth, valid) == pytest.approx(0.7)
    depth[230:250, 290:296] = 0.65  # a 6 px wide wall across the band (10 % of the rectangle)
    assert nearest_depth(rect, depth, valid) == pytest.approx(0.65)
    assert np.isnan(nearest_depth(rect, depth, np.zeros_like(valid)))
    with pytest.raises(ValueError, match="percentile"):
        nearest_depth(rect, depth, valid, percentile=101.0)


def test_the_palm_stays_clear_of_a_rim_outside_the_rectangle():
    """A small rectangle on the floor of a wide open box: the walls lie outside the rectangle
    but under the 11 cm palm, so the grasp is no deeper than the palm allows."""
    depth, valid = flat(0.75)
    depth[180:300, 240:400] = 0.70  # the box's floor (5 cm above the table)
    depth[180:300, 280:290] = 0.64  # one wall, 4-5 cm from the centre: under the palm
    rect = GraspRectangle(CX, CY, 0.0, 20.0, 10.0)
    g = rectangle_to_grasp(rect, depth, valid, K, look_down(0.75))
    assert 0.75 - g.position[2] == pytest.approx(0.64 + PALM_OFFSET - 0.005, abs=1e-6)
    # Turned a quarter, the palm's length runs between the walls: the full depth offset.
    g2 = rectangle_to_grasp(GraspRectangle(CX, CY, np.pi / 2, 20.0, 10.0), depth, valid, K,
                            look_down(0.75))
    assert 0.75 - g2.position[2] == pytest.approx(0.70 + 0.015, abs=1e-6)


def _block(top=0.65, cols=(300, 340), rows=(200, 280)):
    """A block standing on a table 0.75 m below a camera looking straight down."""
    depth, valid = flat(0.75)
    depth[rows[0]:rows[1], cols[0]:cols[1]] = top
    return depth, valid


def test_fingers_beside_the_object_do_not_collide_and_fingers_on_it_do():
    depth, valid = _block()  # 40 px = 4.7 cm wide at the top (0.65 m)
    table = np.full(depth.shape, 0.75)
    across = GraspRectangle(CX, CY, 0.0, 52.0, 20.0)  # jaws beside the block's x sides
    g = rectangle_to_grasp(across, depth, valid, K, look_down(0.75))
    assert g.failure is None
    assert not fingers_collide(g, depth, valid, K, look_down(0.75), table)
    narrow = GraspRectangle(CX, CY, 0.0, 20.0, 20.0)  # fingers come down on the block's top
    g = rectangle_to_grasp(narrow, depth, valid, K, look_down(0.75))
    assert fingers_collide(g, depth, valid, K, look_down(0.75), table)
    # ... unless the surface there is missing (nothing seen, nothing to collide with).
    hidden = valid.copy()
    hidden[200:280, 300:340] = False
    assert not fingers_collide(g, depth, hidden, K, look_down(0.75), table)


def test_fingers_stop_at_the_table_so_flat_objects_are_not_collisions():
    depth, valid = _block(top=0.742)  # an 8 mm thin object: the tips would go under the table
    rect = GraspRectangle(CX, CY, 0.0, 52.0, 20.0)
    g = rectangle_to_grasp(rect, depth, valid, K, look_down(0.75))
    tip = 0.75 - g.position[2] + TIP_OFFSET
    assert tip > 0.75 + 0.003  # below the table surface if nothing stopped it
    assert fingers_collide(g, depth, valid, K, look_down(0.75))  # no table known: the table
    table = np.full(depth.shape, 0.75)
    assert not fingers_collide(g, depth, valid, K, look_down(0.75), table)


def test_fingers_outside_the_image_or_without_a_pose_collide():
    depth, valid = flat(0.75)
    g = rectangle_to_grasp(GraspRectangle(5.0, CY, 0.0, 40.0, 20.0), depth, valid, K,
                           look_down(0.75))
    assert fingers_collide(g, depth, valid, K, look_down(0.75))
    none = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth,
                              np.zeros_like(valid), K, look_down(0.75))
    assert none.T_world_grasp is None
    assert fingers_collide(none, depth, valid, K, look_down(0.75))


def test_a_surface_on_any_pixel_of_a_finger_footprint_is_a_collision():
    """One raised pixel anywhere inside a finger's footprint (a thin rim, a handle's edge) is
    met on the way down: the footprint is sampled finer than a pixel, so nothing falls
    between two samples."""
    depth, valid = _block()
    table = np.full(depth.shape, 0.75)
    T = look_down(0.75)
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 52.0, 20.0), depth, valid, K, T)
    assert not fingers_collide(g, depth, valid, K, T, table)
    z_tcp = 0.75 - g.position[2]  # depth of the TCP under a camera looking straight down
    # The +x finger's footprint (closing direction = image x), in pixels, one pixel inset.
    u0 = CX + F * (g.opening / 2) / z_tcp + 1
    u1 = CX + F * (g.opening / 2 + FINGER_THICKNESS) / z_tcp - 1
    v0, v1 = CY - F * (PAD_WIDTH / 2) / z_tcp + 1, CY + F * (PAD_WIDTH / 2) / z_tcp - 1
    pixels = [(u, v) for u in range(int(np.ceil(u0)), int(np.floor(u1)) + 1)
              for v in range(int(np.ceil(v0)), int(np.floor(v1)) + 1)]
    assert len(pixels) > 20
    missed = []
    for u, v in pixels:
        pinned = depth.copy()
        pinned[v, u] = 0.66  # a 1-pixel post rising 15 mm above the fingertips
        if not fingers_collide(g, pinned, valid, K, T, table):
            missed.append((u, v))
    assert missed == []


def test_table_plane_depth_back_projects_onto_the_plane():
    T = look_down(0.75)
    np.testing.assert_allclose(table_plane_depth(K, T, 0.0, (48, 64)), 0.75)
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = tilted(rng)
        d = table_plane_depth(K, T, 0.02, (480, 640))
        v, u = rng.integers(0, 480, 50), rng.integers(0, 640, 50)
        z = d[v, u]
        p_cam = np.stack([(u - CX) / F * z, (v - CY) / F * z, z, np.ones_like(z)])
        np.testing.assert_allclose((T @ p_cam)[2], 0.02, atol=1e-9)
    up = np.eye(4)  # looking straight up: the rays never meet the plane below
    assert np.isinf(table_plane_depth(K, up, -1.0, (4, 4))).all()


def _block_on_plate(top=0.71, plate=0.73):
    """A block resting on a plate that reaches beyond the fingers, on a table at 0.75 m."""
    depth, valid = _block(top=top)
    depth[150:330, 230:410][depth[150:330, 230:410] > plate] = plate
    return depth, valid


def test_fingers_settle_above_the_support_when_they_still_grip():
    depth, valid = _block_on_plate()
    T, table = look_down(0.75), np.full((480, 640), 0.75)
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 52.0, 20.0), depth, valid, K, T)
    assert fingers_collide(g, depth, valid, K, T, table)  # the tips go 2.5 cm past the top
    s = settle_fingers(g, depth, valid, K, T, table, min_grip=0.01, clearance=0.002)
    assert not fingers_collide(s, depth, valid, K, T, table)
    tip = 0.75 - s.position[2] + TIP_OFFSET  # the fingertips' camera depth
    assert tip == pytest.approx(0.73 - 0.002, abs=1e-6)
    np.testing.assert_allclose(s.T_world_grasp[:3, :3], g.T_world_grasp[:3, :3])
    assert (s.opening, s.width, s.depth, s.rect) == (g.opening, g.width, g.depth, g.rect)
    assert g.position[2] == pytest.approx(0.75 - 0.71 - 0.015, abs=1e-6)  # input unchanged


def test_fingers_do_not_settle_when_too_little_of_the_object_is_left_to_grip():
    depth, valid = _block_on_plate(top=0.725)  # 5 mm above the plate
    T, table = look_down(0.75), np.full((480, 640), 0.75)
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 52.0, 20.0), depth, valid, K, T)
    s = settle_fingers(g, depth, valid, K, T, table, min_grip=0.01)
    assert s is g and fingers_collide(s, depth, valid, K, T, table)
    s = settle_fingers(g, depth, valid, K, T, table, min_grip=0.002)
    assert not fingers_collide(s, depth, valid, K, T, table)


def test_fingers_with_nothing_in_the_way_or_without_a_pose_are_left_as_they_are():
    depth, valid = _block()
    T, table = look_down(0.75), np.full((480, 640), 0.75)
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 52.0, 20.0), depth, valid, K, T)
    assert settle_fingers(g, depth, valid, K, T, table) is g
    # A thin object: the tips stop at the table (the executor's clamp), not a collision.
    flat_depth, flat_valid = _block(top=0.742)
    g = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 52.0, 20.0), flat_depth, flat_valid,
                           K, T)
    assert settle_fingers(g, flat_depth, flat_valid, K, T, table) is g
    none = rectangle_to_grasp(GraspRectangle(CX, CY, 0.0, 40.0, 20.0), depth,
                              np.zeros_like(valid), K, T)
    assert settle_fingers(none, depth, valid, K, T, table) is none


def test_the_harness_settles_the_fingers_only_when_asked():
    from types import SimpleNamespace

    from graspsim.sim.execution import ExecutionParams, harness_grasps

    depth, valid = _block_on_plate()
    frame = SimpleNamespace(depth=depth, depth_valid=valid, intrinsics=K,
                            T_world_cam=look_down(0.75))
    rects = [GraspRectangle(CX, CY, 0.0, 52.0, 20.0), GraspRectangle(CX, CY, 0.0, 20.0, 20.0)]
    plain = harness_grasps(rects, frame, 0.0)
    for g, r in zip(plain, rects, strict=True):
        ref = rectangle_to_grasp(r, depth, valid, K, frame.T_world_cam)
        np.testing.assert_array_equal(g.T_world_grasp, ref.T_world_grasp)
    settled = harness_grasps(rects, frame, 0.0, ExecutionParams(min_grip=0.01))
    table = table_plane_depth(K, frame.T_world_cam, 0.0, depth.shape)
    assert settled[0].position[2] > plain[0].position[2] + 0.005  # stopped above the plate
    assert not fingers_collide(settled[0], depth, valid, K, frame.T_world_cam, table)
    # the narrow one lands on the block's own top: nothing to grip below it, left as it was
    np.testing.assert_array_equal(settled[1].T_world_grasp, plain[1].T_world_grasp)
    offset = harness_grasps(rects[:1], frame, 0.0, depth_offset=0.005)[0]
    assert offset.position[2] == pytest.approx(plain[0].position[2] + 0.01, abs=1e-6)
