"""Camera matrices of real datasets (:mod:`dlsr.intrinsics`): the Cornell fit from a point
cloud written in the real PCD format, its cache, the estimates for Jacquard and for Cornell
images without a cloud."""

from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest
from PIL import Image

from dlsr.datasets import load_cornell, load_jacquard
from dlsr.intrinsics import (
    CORNELL_FALLBACK_K,
    JACQUARD_FOCAL_PX,
    cornell_camera,
    cornell_camera_matrix,
    fit_camera_matrix,
    focal_from_jaw_sizes,
    jacquard_camera_matrix,
    range_to_depth,
    read_pcd_points,
)
from dlsr.rectangles import rects_to_array

H, W = 480, 640
FX, FY, CX, CY = 570.3, 568.9, 316.2, 243.7  # not the fallback's, not round


def _cloud(step=3, jitter=0.0, seed=0):
    """Optical-frame points (mm) of a tilted table with a box on it, seen by a camera with
    intrinsics FX FY CX CY, on a sparse grid with holes, and their pixels (col, row). With
    ``jitter``, each point projects up to that many pixels away from its integer pixel (a
    registered cloud's points fall anywhere inside their pixel)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[100:400:step, 120:520:step]
    rows, cols = rows.ravel(), cols.ravel()
    keep = rng.random(len(rows)) > 0.2
    rows, cols = rows[keep], cols[keep]
    z = 700.0 + 0.2 * (rows - 240) + 0.05 * (cols - 320)  # mm
    box = (np.abs(rows - 250) < 40) & (np.abs(cols - 300) < 50)
    z = np.where(box, z - 60.0, z)
    u = cols + rng.uniform(-jitter, jitter, len(cols))
    v = rows + rng.uniform(-jitter, jitter, len(rows))
    xyz = np.column_stack([(u - CX) / FX * z, (v - CY) / FY * z, z])
    return xyz, rows, cols


# Real Cornell clouds are forward-left-up (x forward, y left, z up) and tilted with the camera:
# optical (right, down, forward) -> (forward, left, up) is this rotation.
OPTICAL_TO_FLU = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _tilt(deg):
    """Rotation of the forward-left-up frame about its left axis (a camera pitched down)."""
    a = np.radians(deg)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


FRAMES = {
    "optical": np.eye(3),
    "forward-left-up": OPTICAL_TO_FLU,
    "forward-left-up tilted 25 deg": _tilt(25.0) @ OPTICAL_TO_FLU,
}


def _write_cornell(root, stem="pcd0100", step=3, R=None, t=(0.0, 0.0, 0.0), jitter=0.0,
                   shuffle=False):
    """A Cornell image in the real layout: ``pcdXXXXr.png`` and a PCD v0.7 ASCII cloud
    (``x y z rgb index``, millimetres, ``index = row * 640 + col``) of :func:`_cloud`, its
    points rotated by ``R`` and moved by ``t`` (the cloud's frame); ``shuffle`` gives the
    points another image's pixels (a cloud no camera fits)."""
    xyz, rows, cols = _cloud(step, jitter)
    xyz = xyz @ (np.eye(3) if R is None else R).T + np.asarray(t)
    index = rows * W + cols
    if shuffle:
        index = np.random.default_rng(1).permutation(index)
    header = ("# .PCD v.7 - Point Cloud Data file format\nVERSION .7\nFIELDS x y z rgb index\n"
              "SIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n"
              f"WIDTH {len(rows)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(rows)}\n"
              "DATA ascii\n")
    body = "".join(f"{a:.4f} {b:.4f} {c:.4f} 4.2108e+06 {i}\n"
                   for (a, b, c), i in zip(xyz, index, strict=True))
    (root / f"{stem}.txt").write_text(header + body)
    Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(root / f"{stem}r.png")
    return root / f"{stem}r.png"


def test_fit_recovers_the_camera_of_a_cornell_point_cloud(tmp_path):
    rgb = _write_cornell(tmp_path)
    K, source = cornell_camera_matrix(rgb)
    assert source == "point cloud"
    # the index is quantised to whole pixels and the cloud written to 0.1 um: exact to 0.05 px
    np.testing.assert_allclose(K[[0, 1, 0, 1], [0, 1, 2, 2]], [FX, FY, CX, CY], atol=0.05)
    cache = tmp_path / "pcd0100camera.json"
    body = json.loads(cache.read_text())
    assert body["source"] == "fitted to pcd0100.txt" and body["rms_px"] < 0.05
    again, source = cornell_camera_matrix(tmp_path / "pcd0100d.tiff")  # any of its files
    assert source == "camera file"
    np.testing.assert_allclose(again, K)


def test_load_cornell_takes_the_fitted_matrix(tmp_path):
    _write_cornell(tmp_path)
    (sample,) = load_cornell(tmp_path)
    np.testing.assert_allclose(sample.K[0, 0], FX, atol=0.05)
    assert (tmp_path / "pcd0100camera.json").is_file()
    (half,) = load_cornell(tmp_path, scale=0.5)
    np.testing.assert_allclose(half.K[0, 0], FX / 2, atol=0.05)


def test_fit_refuses_degenerate_points():
    with pytest.raises(ValueError, match="at least 10"):
        fit_camera_matrix(np.ones((5, 3)), np.ones((5, 2)), "tiny")
    pts = np.column_stack([np.zeros(20), np.linspace(-1, 1, 20), np.ones(20)])
    with pytest.raises(ValueError, match="do not spread"):
        fit_camera_matrix(pts, np.ones((20, 2)), "a line")


def test_bad_point_cloud_is_named(tmp_path):
    bad = tmp_path / "pcd0100.txt"
    bad.write_text("VERSION .7\nFIELDS x y z index\nPOINTS 2\nDATA ascii\n1 2 3 4\n")
    with pytest.raises(ValueError, match="pcd0100.txt.*header says 2 points"):
        read_pcd_points(bad)
    with pytest.raises(ValueError, match="not a Cornell file name"):
        cornell_camera_matrix(tmp_path / "image.png")


def test_real_cornell_tiff_only_gets_the_kinect_estimate(cornell_samples_root, tmp_path,
                                                         caplog):
    # the shared samples have no point cloud: the estimate, with a warning, nothing written
    for name in ("pcd0100r.png", "pcd0100d.tiff"):
        shutil.copy(cornell_samples_root / name, tmp_path / name)
    with caplog.at_level(logging.WARNING, logger="dlsr.intrinsics"):
        K, source = cornell_camera_matrix(tmp_path / "pcd0100r.png")
    assert source == "estimate" and "Kinect v1 estimate" in caplog.text
    np.testing.assert_array_equal(K, CORNELL_FALLBACK_K)
    assert not (tmp_path / "pcd0100camera.json").exists()


def test_jacquard_focal_length_from_the_real_jaw_sizes(jacquard_root):
    views = load_jacquard(jacquard_root, depth="perfect")
    pooled_h, pooled_z = [], []
    for v in views:
        r = rects_to_array(v.positives)
        col = np.clip(np.rint(r[:, 0]).astype(int), 0, W * 2 - 1)
        row = np.clip(np.rint(r[:, 1]).astype(int), 0, W * 2 - 1)
        z = v.depth[row, col]
        # every view alone gives the constant within 2 %: one camera for all renders
        assert abs(focal_from_jaw_sizes(r[:, 4], z) / JACQUARD_FOCAL_PX - 1) < 0.02, v.image_id
        pooled_h.append(r[:, 4])
        pooled_z.append(z)
        np.testing.assert_allclose(v.K, jacquard_camera_matrix(v.rgb.shape[:2]))
    f = focal_from_jaw_sizes(np.concatenate(pooled_h), np.concatenate(pooled_z))
    assert abs(f - JACQUARD_FOCAL_PX) < 1.0


def test_jacquard_matrix_scales_with_the_image(jacquard_root):
    K = jacquard_camera_matrix((512, 512))
    np.testing.assert_allclose(K[[0, 1, 0, 1], [0, 1, 2, 2]],
                               [JACQUARD_FOCAL_PX / 2] * 2 + [255.5, 255.5])
    # the loader's resized views get the same matrix (resize_sample scales K)
    half = load_jacquard(jacquard_root / "1d7830c5d0322518d95aa859a460a9ec", scale=0.5)
    np.testing.assert_allclose(half[0].K, K)


@pytest.mark.parametrize("frame", list(FRAMES))
def test_any_frame_gives_the_camera(tmp_path, frame):
    # a registered cloud: points anywhere inside their pixel (0.5 px jitter)
    rgb = _write_cornell(tmp_path, R=FRAMES[frame], jitter=0.5)
    cam = cornell_camera(rgb)
    assert cam.source == "point cloud" and cam.rms_px < 0.5
    fx, fy, cx, cy = cam.K[[0, 1, 0, 1], [0, 1, 2, 2]]
    # the tolerances: 1 % in the focal lengths, 3 px in the principal point
    assert abs(fx / FX - 1) < 0.01 and abs(fy / FY - 1) < 0.01
    assert abs(cx - CX) < 3 and abs(cy - CY) < 3
    # T_cam_cloud takes the cloud back to the optical frame
    np.testing.assert_allclose(cam.T_cam_cloud[:3, :3] @ FRAMES[frame], np.eye(3), atol=2e-3)
    cache = json.loads((tmp_path / "pcd0100camera.json").read_text())
    assert cache["rms_px"] == pytest.approx(cam.rms_px, abs=1e-4)
    assert cache["model"] == "centred" and np.shape(cache["T_cam_cloud"]) == (4, 4)


def test_frames_give_the_same_camera_and_depth(tmp_path):
    samples = {}
    for i, (frame, R) in enumerate(FRAMES.items()):
        root = tmp_path / str(i)
        root.mkdir()
        _write_cornell(root, R=R)
        (samples[frame],) = load_cornell(root)
    ref = samples["optical"]
    xyz, rows, cols = _cloud()
    np.testing.assert_allclose(ref.depth[rows, cols], xyz[:, 2] / 1000, atol=1e-6)
    for frame, s in samples.items():
        np.testing.assert_allclose(s.K, ref.K, atol=0.05, err_msg=frame)
        np.testing.assert_array_equal(s.depth_valid, ref.depth_valid)
        np.testing.assert_allclose(s.depth, ref.depth, atol=1e-6, err_msg=frame)


def test_a_cloud_away_from_the_optical_centre_is_a_projection(tmp_path):
    R = FRAMES["forward-left-up tilted 25 deg"]
    rgb = _write_cornell(tmp_path, R=R, t=(350.0, -120.0, 800.0))  # a robot's base frame
    cam = cornell_camera(rgb)
    assert cam.source == "point cloud" and cam.rms_px < 0.1
    np.testing.assert_allclose(cam.K[[0, 1, 0, 1], [0, 1, 2, 2]], [FX, FY, CX, CY], rtol=2e-3)
    assert json.loads((tmp_path / "pcd0100camera.json").read_text())["model"] == "projection"
    (sample,) = load_cornell(tmp_path)
    xyz, rows, cols = _cloud()
    np.testing.assert_allclose(sample.depth[rows, cols], xyz[:, 2] / 1000, atol=1e-5)


def test_a_cloud_that_fits_no_camera_loads_with_the_estimate(tmp_path, caplog):
    _write_cornell(tmp_path, shuffle=True)
    with caplog.at_level(logging.WARNING, logger="dlsr.intrinsics"):
        (sample,) = load_cornell(tmp_path)
    msg = " ".join(r.getMessage() for r in caplog.records)
    assert "pcd0100.txt fits no pinhole camera" in msg and "reprojection error" in msg
    np.testing.assert_array_equal(sample.K, CORNELL_FALLBACK_K)
    assert not (tmp_path / "pcd0100camera.json").exists()  # an estimate is not cached
    # its depth is the range converted with the estimate
    assert sample.depth_valid.sum() > 1000 and np.isfinite(sample.depth).all()


def test_too_few_points_loads_with_the_estimate(tmp_path, caplog):
    rgb = _write_cornell(tmp_path, step=120)  # 9 points or fewer
    with caplog.at_level(logging.WARNING, logger="dlsr.intrinsics"):
        cam = cornell_camera(rgb)
    assert cam.source == "estimate" and "at least 10" in caplog.text
    assert "pcd0100.txt" in caplog.text


def test_an_old_optical_frame_cache_is_fitted_again(tmp_path):
    rgb = _write_cornell(tmp_path, R=FRAMES["forward-left-up"])
    (tmp_path / "pcd0100camera.json").write_text(json.dumps(
        {"K": [[0.0017, 0, 320], [0, 0.0017, 240], [0, 0, 1]], "source": "fitted to pcd0100.txt",
         "rms_px": 300.0}))
    cam = cornell_camera(rgb)
    assert cam.source == "point cloud"
    np.testing.assert_allclose(cam.K[0, 0], FX, atol=0.05)
    assert "T_cam_cloud" in json.loads((tmp_path / "pcd0100camera.json").read_text())


def test_range_to_depth_is_the_ray_projection():
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    rows, cols = np.mgrid[0:H, 0:W]
    z = 0.8 + 0.001 * rows
    ray = np.stack([(cols - CX) / FX, (rows - CY) / FY, np.ones_like(z)])
    rng = z * np.linalg.norm(ray, axis=0)
    np.testing.assert_allclose(range_to_depth(rng, K), z, rtol=1e-6)
    # at a 640 x 480 image's corner and 585 px the range is 21 % more than z
    corner = range_to_depth(np.ones((H, W)), CORNELL_FALLBACK_K)[0, 0]
    assert 1 / corner == pytest.approx(1.21, abs=0.005)
