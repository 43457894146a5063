"""`graspsim show`: rectangle overlays of Cornell and Jacquard data."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from dlsr.datasets import load_cornell, write_cornell
from dlsr.viz import show_dataset
from graspsim.cli import main


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


def test_builtin_fixture_round_trips(tmp_path, box_samples):
    samples = box_samples()
    back = load_cornell(write_cornell(samples, tmp_path / "f"))
    assert [s.object_id for s in back] == ["box"] * 3
    for a, b in zip(samples, back, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        assert len(b.positives) == 3 and len(b.negatives) == 1
