"""``graspsim detect``: one image from files with a saved model."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from PIL import Image

from dlsr import patches, whitening
from dlsr.detection import DLSRDetector, SearchGrid
from dlsr.features import Representation, rectangle_features
from dlsr.preprocess import rectangle_images
from dlsr.svm import FeatureStandardizer, SquaredHingeSVC
from graspsim.cli import main

H, W = 100, 130


def _scene():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:H, 0:W]
    rgb = 100 + 60 * np.sin(xx / 7.0)[..., None] + 40 * rng.random((H, W, 3))
    depth = (0.8 + 0.0003 * xx).astype(np.float32)
    mask = np.zeros((H, W), bool)
    mask[40:60, 30:100] = True
    depth[mask] -= 0.03
    rgb[mask] = [200, 40, 40]
    return {"rgb": np.clip(rgb, 0, 255).astype(np.uint8), "depth": depth,
            "depth_valid": np.ones((H, W), bool), "mask": mask}


def _small_model(obs):
    """NKM-Natural on random whitened patches, an SVM on random labels: enough for the CLI."""
    rng = np.random.default_rng(0)
    R = np.column_stack([rng.uniform(35, 95, 40), rng.uniform(40, 60, 40),
                         rng.uniform(-1.5, 1.5, 40), np.full(40, 30.0), np.full(40, 20.0)])
    im, mk = rectangle_images(obs["rgb"], obs["depth"], obs["depth_valid"], R)
    X, M = patches.extract_patches(im, mk, 6)
    X, M = X.reshape(-1, 288), M.reshape(-1, 288)
    Xs = whitening.standardize_patches(X, M)
    mean, P = whitening.fit_zca(Xs, M)
    Xw = whitening.apply_zca(Xs, M, mean, P)
    cents = Xw[rng.choice(np.flatnonzero(M.all(1)), 16, replace=False)].astype(np.float32)
    rep = Representation("NKM", cents / np.linalg.norm(cents, axis=1, keepdims=True), cents,
                         mean, P, None)
    F = rectangle_features(im, mk, rep, "Natural", None, polarity=False)
    scaler = FeatureStandardizer().fit(F)
    svm = SquaredHingeSVC().fit(scaler.transform(F), np.arange(40) % 2)
    return DLSRDetector(rep, "Natural", None, False, scaler.mean_, scaler.scale_,
                        np.asarray(svm.coef_[0]), float(svm.intercept_[0]))


@pytest.fixture(scope="module")
def saved_model(tmp_path_factory):
    obs = _scene()
    model = _small_model(obs)
    grid = SearchGrid(angles_deg=(0, 90), openings=(20, 30), jaws=(10, 20), step=10.0,
                      dilate=5)
    model.config.update(grid=grid.to_dict(), rescore=10)
    path = tmp_path_factory.mktemp("model") / "m"
    model.save(path)
    return path, obs


def _write_obs(tmp_path, obs):
    rgb, depth, mask = tmp_path / "rgb.png", tmp_path / "depth.tiff", tmp_path / "mask.png"
    Image.fromarray(obs["rgb"]).save(rgb)
    tifffile.imwrite(depth, obs["depth"])
    Image.fromarray(obs["mask"].astype(np.uint8) * 255).save(mask)
    return rgb, depth, mask


def test_detect_writes_rectangles_and_an_overlay(saved_model, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, mask = _write_obs(tmp_path, obs)
    out = tmp_path / "overlay.png"
    code = main(["detect", "--model", str(path) + ".json", "--rgb", str(rgb), "--depth",
                 str(depth), "--mask", str(mask), "--top-k", "3", "--out", str(out)])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["rectangles"]) == 3
    assert result["scores"] == sorted(result["scores"], reverse=True)
    x, y = result["rectangles"][0]["x"], result["rectangles"][0]["y"]
    assert 20 <= x <= 110 and 25 <= y <= 75  # near the object (dilated region)
    img = np.asarray(Image.open(out))
    assert img.shape == obs["rgb"].shape and not np.array_equal(img, obs["rgb"])


def test_detect_without_mask_uses_the_table_plane(saved_model, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, _ = _write_obs(tmp_path, obs)
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--detector", "exact"])
    assert code == 0
    assert json.loads(capsys.readouterr().out)["rectangles"]


def test_detect_reports_missing_files_in_one_line(saved_model, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, _ = _write_obs(tmp_path, obs)
    code = main(["detect", "--model", str(tmp_path / "nope"), "--rgb", str(rgb), "--depth",
                 str(depth)])
    assert code == 2
    assert "detector model file not found" in capsys.readouterr().err
    code = main(["detect", "--model", str(path), "--rgb", str(tmp_path / "none.png"),
                 "--depth", str(depth)])
    assert code == 2
    assert "none.png" in capsys.readouterr().err


def test_detect_all_masked_depth_exits_nonzero_with_the_reason(saved_model, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, _ = _write_obs(tmp_path, obs)
    tifffile.imwrite(depth, np.zeros_like(obs["depth"]))
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth)])
    assert code == 1
    assert "no valid pixel" in json.loads(capsys.readouterr().out)["reason"]
