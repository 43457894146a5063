"""``graspsim detect``: one image from files with a saved model (``saved_model`` and
``obs_files`` in conftest.py)."""

from __future__ import annotations

import json

import numpy as np
import tifffile
from PIL import Image

from graspsim.cli import main


def test_detect_writes_rectangles_and_an_overlay(saved_model, obs_files, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, mask = obs_files
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


def test_detect_without_mask_uses_the_table_plane(saved_model, obs_files, tmp_path, capsys):
    path, obs = saved_model
    rgb, depth, _ = obs_files
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth),
                 "--detector", "exact"])
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
    code = main(["detect", "--model", str(path), "--rgb", str(rgb), "--depth", str(depth)])
    assert code == 1
    assert "no valid pixel" in json.loads(capsys.readouterr().out)["reason"]
