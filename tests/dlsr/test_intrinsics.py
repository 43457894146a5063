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
    cornell_camera_matrix,
    fit_camera_matrix,
    focal_from_jaw_sizes,
    jacquard_camera_matrix,
    read_pcd_points,
)
from dlsr.rectangles import rects_to_array

H, W = 480, 640
FX, FY, CX, CY = 570.3, 568.9, 316.2, 243.7  # not the fallback's, not round


def _write_cornell(root, stem="pcd0100", step=3):
    """A Cornell image in the real layout: ``pcdXXXXr.png`` and a PCD v0.7 ASCII cloud
    (``x y z rgb index``, millimetres, ``index = row * 640 + col``) of a tilted table seen by
    a camera with intrinsics FX FY CX CY; points on a sparse grid with holes."""
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[100:400:step, 120:520:step]
    rows, cols = rows.ravel(), cols.ravel()
    keep = rng.random(len(rows)) > 0.2
    rows, cols = rows[keep], cols[keep]
    z = 700.0 + 0.2 * (rows - 240) + 0.05 * (cols - 320)  # mm
    x, y = (cols - CX) / FX * z, (rows - CY) / FY * z
    header = ("# .PCD v.7 - Point Cloud Data file format\nVERSION .7\nFIELDS x y z rgb index\n"
              "SIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n"
              f"WIDTH {len(rows)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(rows)}\n"
              "DATA ascii\n")
    body = "".join(f"{a:.4f} {b:.4f} {c:.4f} 4.2108e+06 {r * W + k}\n"
                   for a, b, c, r, k in zip(x, y, z, rows, cols, strict=True))
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
