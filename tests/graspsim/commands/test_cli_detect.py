"""``graspsim detect``: one image from files with a saved model (``saved_model`` and
``obs_files`` in conftest.py)."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image

from dlsr.detection import (
    PAPER_GRID,
    jaws_clear,
    object_region,
    train_detector,
)
from graspsim.cli import main


def test_detect_writes_rectangles_and_an_overlay(saved_model, obs_files, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, mask = obs_files
    out = tmp_path / "overlay.png"
    code = main(["detect", "--model", str(path) + ".json", "--rgb", str(rgb), "--depth",
                 str(depth), "--mask", str(mask), "--top-k", "3", "--out", str(out),
                 "--preset", "paper"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["rectangles"]) == 3
    assert result["scores"] == sorted(result["scores"], reverse=True)
    x, y = result["rectangles"][0]["x"], result["rectangles"][0]["y"]
    assert 20 <= x <= 110 and 25 <= y <= 75  # near the object (dilated region)
    img = np.asarray(Image.open(out))
    assert img.shape == obs["rgb"].shape and not np.array_equal(img, obs["rgb"])


def test_detect_without_mask_uses_the_table_plane(saved_model, obs_files, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, _ = obs_files
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--detector", "exact", "--preset", "paper"])
    assert code == 0
    assert json.loads(capsys.readouterr().out)["rectangles"]


def test_detect_reports_missing_files_in_one_line(saved_model, obs_files, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, _ = obs_files
    code = main(["detect", "--model", str(tmp_path / "nope"), "--rgb", str(rgb), "--depth",
                 str(depth)])
    assert code == 2
    assert "detector model file not found" in capsys.readouterr().err
    code = main(["detect", "--model", str(path), "--rgb", str(tmp_path / "none.png"),
                 "--depth", str(depth)])
    assert code == 2
    assert "none.png" in capsys.readouterr().err


def test_detect_all_masked_depth_exits_nonzero_with_the_reason(saved_model, obs_files,
                                                               capsys):
    path, obs = saved_model
    rgb, depth, _ = obs_files
    tifffile.imwrite(depth, np.zeros_like(obs["depth"]))
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--preset", "paper"])
    assert code == 1
    assert "no valid pixel" in json.loads(capsys.readouterr().out)["reason"]


def test_detect_clear_jaws_flag_keeps_the_jaws_off_the_object(saved_model, obs_files, capsys):
    path, obs = saved_model
    rgb, depth, mask = obs_files
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--mask", str(mask), "--clear-jaws", "--top-k", "20", "--preset", "paper"])
    assert code == 0
    rects = np.array([[r[k] for k in ("x", "y", "theta", "w", "h")]
                      for r in json.loads(capsys.readouterr().out)["rectangles"]])
    assert len(rects) and jaws_clear(obs["mask"], rects).all()
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--mask", str(mask), "--top-k", "20", "--preset", "paper"])
    rects = np.array([[r[k] for k in ("x", "y", "theta", "w", "h")]
                      for r in json.loads(capsys.readouterr().out)["rectangles"]])
    assert not jaws_clear(obs["mask"], rects).all()  # the paper's grid


def test_detect_rejects_depth_in_the_wrong_units(saved_model, obs_files, capsys):
    path, obs = saved_model
    rgb, depth, _ = obs_files
    tifffile.imwrite(depth, obs["depth"] * 1000)  # millimetres
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth)])
    assert code == 2
    err = capsys.readouterr().err
    assert "depth.tiff" in err and "--depth-units 0.001" in err
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--depth-units", "0.001", "--preset", "paper"])
    assert code == 0


# ------------------------------------------------------------------------------------------
# Real Cornell images, no mask and no background: the object from depth alone
# ------------------------------------------------------------------------------------------

# Hand-marked outlines of the remote control in the two Cornell sample images (corners in
# pixels (x, y), read off 4x zoomed crops of pcd0100r.png and pcd0101r.png with a 10 px grid).
REMOTE = {
    "0100": [(274, 254), (305, 254), (299, 360), (262, 358)],  # upright, about 33 x 105 px
    "0101": [(219, 275), (329, 280), (326, 313), (216, 309)],  # lying, about 34 x 110 px
}


def _cornell(root, image):
    return root / f"pcd{image}r.png", root / f"pcd{image}d.tiff"


def _on_remote(image, rect):
    """Whether a rectangle is centred on the hand-marked remote and closes across its short
    side: closing direction within 30 degrees of the short side, both jaw centres outside the
    outline (2 px of slack for the marking)."""
    poly = np.asarray(REMOTE[image], np.float32)
    x, y, theta, w, _ = rect
    if cv2.pointPolygonTest(poly, (float(x), float(y)), False) < 0:
        return False
    edges = [poly[1] - poly[0], poly[2] - poly[1]]
    short = min(edges, key=np.linalg.norm)
    u = np.array([np.cos(theta), -np.sin(theta)])  # closing direction, as displayed
    if abs(u @ short) / np.linalg.norm(short) < np.cos(np.radians(30)):
        return False
    return all(cv2.pointPolygonTest(poly, (float(x + s * w / 2 * u[0]),
                                           float(y + s * w / 2 * u[1])), True) <= 2
               for s in (-1, 1))


@pytest.mark.parametrize("image", ["0100", "0101"])
def test_object_region_from_depth_alone_is_the_remote(cornell_samples_root, image):
    from dlsr.datasets import clean_depth, read_depth_image

    d, valid = clean_depth(read_depth_image(_cornell(cornell_samples_root, image)[1]))
    region, how = object_region({"rgb": np.zeros(d.shape + (3,), np.uint8), "depth": d,
                                 "depth_valid": valid})
    truth = np.zeros(d.shape, np.uint8)
    cv2.fillPoly(truth, [np.asarray(REMOTE[image], np.int32)], 1)
    near = cv2.dilate(truth, np.ones((9, 9), np.uint8)).astype(bool)
    truth = truth.astype(bool)
    assert how == "depth"
    # the region from depth is a few px thinner where the remote's sides are rounded
    assert (region & truth).sum() / (region | truth).sum() > 0.7
    assert (region & near).sum() > 0.98 * region.sum()  # nothing of the table or the board


def _small_cornell_grid():
    """The paper's grid with clear jaws (the search of both test models)."""
    return dataclasses.replace(PAPER_GRID, clear_jaws=True).to_dict()


def _jacquard_training_views(jacquard_root):
    """14 of the 28 real Jacquard views at half size with perfect depth, 40 positives each
    (fewer where a view has fewer), the same for every model trained on them."""
    from dlsr.datasets import load_jacquard

    rng = np.random.default_rng(0)
    views = load_jacquard(jacquard_root, depth="perfect", scale=0.5)
    views = [views[i] for i in np.sort(rng.choice(len(views), 14, replace=False))]
    views = [dataclasses.replace(v, positives=[v.positives[i] for i in np.sort(
        rng.choice(len(v.positives), min(40, len(v.positives)), replace=False))])
        for v in views]
    return views


@pytest.fixture(scope="module")
def jacquard_model(jacquard_root, tmp_path_factory):
    """A small model trained on 14 of the 28 real Jacquard views at half size (40 grasps each,
    perfect depth), 50 atoms: about 25 s on 2 cores."""
    views = _jacquard_training_views(jacquard_root)
    model = train_detector(views, n_atoms=50, n_patches=10_000, random_state=0,
                           grid=_small_cornell_grid())
    path = tmp_path_factory.mktemp("jacquard_model") / "m"
    model.save(path)
    return path


@pytest.fixture(scope="module")
def sim_model(cornell_samples_root, tmp_path_factory):
    """A small model trained on 8 physics-labelled synthetic scenes (32 rectangles each, 87
    positives), its grid fitted to the positives' sizes (``fit_grid``): about 30 s on 2
    cores. (With the 32 positives of seed 0's scenes the top rectangle on pcd0100 was a
    diagonal one; seeds 1 and 2, models with 4 seeds each: 15 of 16 right.)"""
    from dlsr.datasets import load_cornell
    from graspsim.data.datagen import make_dataset

    root = tmp_path_factory.mktemp("sim")
    make_dataset(n_scenes=8, objects="train", out=root / "data", seed=2, n_candidates=32)
    model = train_detector(load_cornell(root / "data"), n_atoms=50, n_patches=10_000,
                           random_state=0, fit_grid=0.025, grid=_small_cornell_grid())
    model.save(root / "m")
    return root / "m"


@pytest.mark.parametrize("which", ["jacquard_model", "sim_model"])
@pytest.mark.parametrize("image", ["0100", "0101"])
def test_detect_grasps_the_remote_across_from_depth_alone(cornell_samples_root, which, image,
                                                          request, tmp_path, capsys):
    model = request.getfixturevalue(which)
    rgb, depth = _cornell(cornell_samples_root, image)
    out = tmp_path / "overlay.png"
    # the models' own search: the paper's grid with clear jaws (their saved grids)
    code = main(["detect", "--model", str(model), "--rgb", str(rgb), "--depth", str(depth),
                 "--top-k", "1", "--out", str(out), "--preset", "paper", "--clear-jaws"])
    assert code == 0
    best = json.loads(capsys.readouterr().out)["rectangles"][0]
    rect = [best[k] for k in ("x", "y", "theta", "w", "h")]
    assert _on_remote(image, rect), rect
    assert out.exists()


@pytest.fixture(scope="module")
def jacquard_default_model(jacquard_root, tmp_path_factory):
    """A small model trained on 14 of the 28 real Jacquard views as the real-data default
    trains (``--preset real``: the paper's training, no physical features): about 25 s on 2
    cores."""
    from graspsim.detectors.dlsr_options import PRESETS, REAL_DEFAULT

    views = _jacquard_training_views(jacquard_root)
    model = train_detector(views, n_atoms=50, n_patches=10_000, random_state=0,
                           physical=PRESETS[REAL_DEFAULT].physical)
    path = tmp_path_factory.mktemp("jacquard_default_model") / "m"
    model.save(path)
    return path


@pytest.fixture(scope="module")
def jacquard_physical_model(jacquard_root, tmp_path_factory):
    """The same views with physical features (on the estimated Jacquard camera matrix), as
    ``--preset all`` trains: about 30 to 90 s on 2 shared cores."""
    views = _jacquard_training_views(jacquard_root)
    model = train_detector(views, n_atoms=50, n_patches=10_000, random_state=0, physical=True)
    path = tmp_path_factory.mktemp("jacquard_physical_model") / "m"
    model.save(path)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("preset,which", [(None, "jacquard_default_model"),
                                          ("all", "jacquard_physical_model")])
@pytest.mark.parametrize("image", ["0100", "0101"])
def test_default_options_grasp_the_real_remote_across(cornell_samples_root, preset, which,
                                                     image, request, capsys):
    """With default options (``--preset real``: rectangles fitted to the object region), and
    with every departure (``--preset all``, a model with physical features), the top rectangle
    closes across the remote's short side, centred on it, opening wider than the remote."""
    model = request.getfixturevalue(which)
    rgb, depth = _cornell(cornell_samples_root, image)
    code = main(["detect", "--model", str(model), "--rgb", str(rgb), "--depth", str(depth),
                 "--top-k", "1", *(["--preset", preset] if preset else [])])
    assert code == 0
    best = json.loads(capsys.readouterr().out)["rectangles"][0]
    rect = [best[k] for k in ("x", "y", "theta", "w", "h")]
    poly = np.asarray(REMOTE[image], np.float32)
    short = min(np.linalg.norm(poly[1] - poly[0]), np.linalg.norm(poly[2] - poly[1]))
    assert _on_remote(image, rect), rect
    assert rect[3] > short - 4, (rect, short)  # the hand-marked outline is a few px loose


def test_detect_uses_the_camera_file_beside_a_cornell_image(cornell_samples_root,
                                                            jacquard_physical_model,
                                                            tmp_path, capsys):
    """``graspsim detect`` finds a Cornell image's camera matrix itself (the cache of the fit
    to its point cloud, ``pcdXXXXcamera.json``) for the options that need it (here every
    departure, ``--preset all``): with a focal length of 150 px a rectangle across the remote
    (over 30 px) would be wider than the gripper opens (8 cm at about 0.75 m is 16 px), so the
    top rectangle is a narrow one."""
    from dlsr.intrinsics import camera_matrix, write_camera_file

    for name in ("pcd0100r.png", "pcd0100d.tiff"):
        (tmp_path / name).write_bytes((cornell_samples_root / name).read_bytes())
    write_camera_file(tmp_path / "pcd0100camera.json", camera_matrix(150, 150, 319.5, 239.5),
                      "test")
    code = main(["detect", "--model", str(jacquard_physical_model), "--rgb",
                 str(tmp_path / "pcd0100r.png"), "--depth", str(tmp_path / "pcd0100d.tiff"),
                 "--top-k", "1", "--preset", "all"])
    out = capsys.readouterr().out
    if code == 0:
        assert json.loads(out)["rectangles"][0]["w"] <= 0.08 * 150 / 0.7, out
    else:
        assert code == 1 and "reason" in out


def test_detect_without_intrinsics_on_other_files_says_what_to_give(saved_model, obs_files,
                                                                    capsys):
    path, _ = saved_model
    rgb, depth, mask = obs_files
    # the gripper-aware check needs the camera matrix; the default (--preset real) does not
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--mask", str(mask), "--gripper-aware"])
    assert code == 2
    assert "--intrinsics" in capsys.readouterr().err
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--mask", str(mask)])
    assert code == 0


def test_detect_reads_a_tilted_forward_left_up_point_cloud(cornell_samples_root,
                                                           jacquard_physical_model, tmp_path,
                                                           capsys):
    """A real Cornell image with its point cloud written as real Cornell clouds are
    (forward-left-up, tilted 25 deg with the camera, millimetres, ``index = row * 640 +
    col``), made from the image's preprocessed range: ``graspsim detect --depth pcd0100.txt``
    fits the camera and finds what ``--depth pcd0100d.tiff`` (the range, converted with that
    camera) finds, with the model that needs the camera (``--preset all``)."""
    from dlsr.datasets import clean_depth, read_depth_image
    from dlsr.intrinsics import camera_matrix, read_camera_matrix

    for name in ("pcd0100r.png", "pcd0100d.tiff"):
        (tmp_path / name).write_bytes((cornell_samples_root / name).read_bytes())
    rng_m, valid = clean_depth(read_depth_image(tmp_path / "pcd0100d.tiff"))
    K0 = camera_matrix(580.0, 578.0, 322.0, 236.0)
    rows, cols = np.nonzero(valid)
    ray = np.linalg.solve(K0, np.stack([cols, rows, np.ones_like(rows)]).astype(float)).T
    xyz = rng_m[rows, cols, None] * 1000.0 * ray / np.linalg.norm(ray, axis=1, keepdims=True)
    a = np.radians(25.0)
    tilt = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    flu = xyz @ (tilt @ np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])).T
    header = ("# .PCD v.7 - Point Cloud Data file format\nVERSION .7\nFIELDS x y z rgb index\n"
              "SIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n"
              f"WIDTH {len(rows)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(rows)}\n"
              "DATA ascii\n")
    lines = [f"{x:.4f} {y:.4f} {z:.4f} 0 {i}\n"
             for (x, y, z), i in zip(flu, rows * 640 + cols, strict=True)]
    (tmp_path / "pcd0100.txt").write_text(header + "".join(lines))
    found = []
    for depth in ("pcd0100.txt", "pcd0100d.tiff"):
        code = main(["detect", "--model", str(jacquard_physical_model), "--rgb",
                     str(tmp_path / "pcd0100r.png"), "--depth", str(tmp_path / depth),
                     "--top-k", "1", "--preset", "all"])
        out = capsys.readouterr().out
        assert code == 0, out
        found.append([json.loads(out)["rectangles"][0][k] for k in ("x", "y", "theta", "w")])
    np.testing.assert_allclose(found[0], found[1], atol=1e-3)
    K = read_camera_matrix(tmp_path / "pcd0100camera.json")  # the fit, cached
    np.testing.assert_allclose(K[[0, 1], [0, 1]], [580.0, 578.0], rtol=1e-3)
    np.testing.assert_allclose(K[:2, 2], [322.0, 236.0], atol=0.5)
