"""`graspsim show`: rectangle overlays of Cornell and Jacquard data."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from dlsr.datasets import GraspSample, load_cornell, write_cornell
from dlsr.rectangles import GraspRectangle
from dlsr.viz import show_dataset
from graspsim.cli import main


def builtin_samples() -> list[GraspSample]:
    """Three synthetic 480x640 Cornell-like images: a box on a table with grasps across it."""
    samples = []
    rows, cols = np.mgrid[0:480, 0:640]
    for i, angle in enumerate((0.0, 0.5, -1.0)):
        c, s = np.cos(angle), np.sin(angle)
        # Box frame: long axis at `angle` (counter-clockwise as displayed), 200 x 60 px.
        dx, dy = cols - 320.0, rows - 240.0
        along = dx * c - dy * s
        across = dx * s + dy * c
        box = (np.abs(along) < 100) & (np.abs(across) < 30)
        rgb = np.full((480, 640, 3), 200, dtype=np.uint8)
        rgb[box] = (40, 120, 200)
        depth = np.where(box, 0.62, 0.70).astype(np.float32)
        valid = np.ones_like(box)
        valid[:8] = False  # a band without depth, as real sensors have
        depth[~valid] = 0
        # Grasps close across the box (closing direction perpendicular to its long axis).
        pos = [
            GraspRectangle(320 + t * c, 240 - t * s, angle + np.pi / 2, 90, 30)
            for t in (-60.0, 0.0, 60.0)
        ]
        neg = [GraspRectangle(320, 240, angle, 90, 30)]  # along the box: too long to close
        samples.append(GraspSample(f"{100 + i:04d}", "box", rgb, depth, valid, pos, neg))
    return samples

@pytest.fixture
def cornell_root(tmp_path):
    return write_cornell(builtin_samples(), tmp_path / "cornell")


def test_show_dataset_writes_overlays(cornell_root, tmp_path):
    paths = show_dataset(cornell_root, "cornell", tmp_path / "out", scale=0.5)
    assert [p.name for p in paths] == ["0100.png", "0101.png", "0102.png"]
    im = np.array(Image.open(paths[0]))
    assert im.shape == (240, 320, 3)
    assert ((im[..., 2] > 200) & (im[..., 0] < 60)).any()  # blue jaw plates drawn
    with pytest.raises(ValueError, match="unknown dataset format"):
        show_dataset(cornell_root, "coco", tmp_path / "x")
    with pytest.raises(FileNotFoundError, match="no jacquard images"):
        show_dataset(cornell_root, "jacquard", tmp_path / "x")


def test_cli_show(cornell_root, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["show", str(cornell_root), "--format", "cornell", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["0100.png", "0101.png", "0102.png"]
    assert "wrote 3 overlays" in capsys.readouterr().out


def test_cli_show_bad_input_is_one_line_error(tmp_path, capsys):
    code = main(["show", str(tmp_path / "absent"), "--format", "cornell", "--out",
                 str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "graspsim show: error:" in err and "absent" in err
    with pytest.raises(SystemExit):
        main(["show", str(tmp_path), "--format", "coco", "--out", str(tmp_path)])


def test_cli_show_real_jacquard(jacquard_root, tmp_path):
    folder = sorted(p for p in jacquard_root.iterdir() if p.is_dir())[0]
    out = tmp_path / "jq"
    code = main(["show", str(folder), "--format", "jacquard", "--scale", "0.25",
                 "--depth", "perfect", "--out", str(out)])
    assert code == 0
    files = sorted(out.glob("*.png"))
    assert len(files) == len(list(folder.glob("*_RGB.png")))
    assert np.array(Image.open(files[0])).shape == (256, 256, 3)


def test_builtin_fixture_round_trips(tmp_path):
    samples = builtin_samples()
    back = load_cornell(write_cornell(samples, tmp_path / "f"))
    assert [s.object_id for s in back] == ["box"] * 3
    for a, b in zip(samples, back, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        assert len(b.positives) == 3 and len(b.negatives) == 1
