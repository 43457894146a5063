"""``graspsim export``: a dataset's copy that the CNN peers' Cornell loaders read unchanged.

The loader contract is checked the way their code reads the folder (glob ``*/pcd*cpos.txt``,
four ``x y`` lines per rectangle rounded to integer pixels, the crop centred on the mean corner,
the depth TIFF read as float metres), written here from what their code does, not copied.
"""

from __future__ import annotations

import dataclasses
import glob
import hashlib
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from dlsr.datasets import inpaint_depth, load_cornell, read_cornell_rectangles, write_cornell
from graspsim.cli import main
from graspsim.data.export import EXPORT_FORMAT, export_cornell


@pytest.fixture
def dataset(tmp_path, box_samples):
    """A Cornell-layout dataset like `graspsim dataset` writes: image 0101 without a positive,
    image 0102 with holes in its depth on the object and at the border."""
    s = box_samples(3)
    s[1] = dataclasses.replace(s[1], positives=[])
    depth, valid = s[2].depth.copy(), s[2].depth_valid.copy()
    valid[230:250, 300:340] = False  # a hole on the box
    valid[:, :3] = False  # a band at the left border
    depth[~valid] = 0
    s[2] = dataclasses.replace(s[2], depth=depth, depth_valid=valid)
    root = write_cornell(s, tmp_path / "ds")
    (root / "scenes.json").write_text('{"format": "graspsim-dataset/1", "images": []}')
    (root / "01" / "pcd0100camera.json").write_text('{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}')
    return root


def _digest(root):
    files = sorted(glob.glob(os.path.join(root, "**", "*"), recursive=True))
    return {p: hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in files
            if os.path.isfile(p)}


def _peer_centre(cpos_path):
    """What the peers' Cornell loader computes first for an image: the mean of the corners of
    its positive rectangles, as integer (row, col); it fails on a file without one."""
    with open(cpos_path) as fh:
        lines = [ln for ln in fh.read().splitlines() if ln.strip()]
    points = [[int(round(float(y))), int(round(float(x)))]
              for x, y in (ln.split() for ln in lines)]
    return np.mean(np.vstack([np.array(points[i:i + 4]) for i in range(0, len(points), 4)]),
                   axis=0).astype(int)


def _peer_inpaint(depth):
    """The peers' DepthImage.inpaint written from its description: pad 1 px (reflect 101),
    mask the zeros, divide by the largest absolute value, Navier-Stokes radius 1, crop,
    multiply back (readings rescaled too)."""
    pad = cv2.copyMakeBorder(depth, 1, 1, 1, 1, cv2.BORDER_DEFAULT)
    mask = (pad == 0).astype(np.uint8)
    scale = np.abs(pad).max()
    out = cv2.inpaint(pad.astype(np.float32) / scale, mask, 1, cv2.INPAINT_NS)
    return out[1:-1, 1:-1] * scale


def test_export_leaves_out_empty_positives_and_fills_depth(dataset, tmp_path):
    before = _digest(dataset)
    out = tmp_path / "peers"
    s = export_cornell(dataset, out)
    assert s["images"] == ["0100", "0102"]
    assert s["skipped"] == [{"image": "0101", "reason": "no positive rectangle"}]
    assert s["positives"] == 6 and s["negatives"] == 2
    assert s["source_fingerprint"] == hashlib.sha256(
        (dataset / "scenes.json").read_bytes()).hexdigest()
    record = json.loads((out / "export.json").read_text())
    assert record["format"] == EXPORT_FORMAT and record["skipped"] == s["skipped"]
    assert _digest(dataset) == before  # the source dataset is not touched
    # The peers' loader contract: every image found by their glob has a positive, RGB and a
    # float32 depth TIFF of Cornell's size without a zero.
    found = sorted(glob.glob(os.path.join(out, "*", "pcd*cpos.txt")))
    assert [os.path.basename(f) for f in found] == ["pcd0100cpos.txt", "pcd0102cpos.txt"]
    for cpos in found:
        assert read_cornell_rectangles(cpos)
        row, col = _peer_centre(cpos)
        assert 0 <= row < 480 and 0 <= col < 640
        depth = tifffile.imread(cpos.replace("cpos.txt", "d.tiff"))
        assert depth.dtype == np.float32 and depth.shape == (480, 640)
        assert np.all(np.isfinite(depth)) and np.all(depth > 0)
        assert os.path.isfile(cpos.replace("cpos.txt", "r.png"))
    with pytest.raises(ValueError, match="need at least one array"):
        _peer_centre(dataset / "01" / "pcd0101cpos.txt")  # why the image is left out
    # Depth: readings kept, holes filled as the peers' preprocessing fills them.
    src = tifffile.imread(dataset / "01" / "pcd0102d.tiff")
    got = tifffile.imread(out / "01" / "pcd0102d.tiff")
    assert (src == 0).sum() > 0
    np.testing.assert_array_equal(got[src > 0], src[src > 0])
    np.testing.assert_allclose(got, _peer_inpaint(src), rtol=1e-6)
    hole = got[230:250, 300:340]
    assert 0.61 < hole.min() and hole.max() < 0.71  # between the box top and the table
    # Numbers, objects and the camera file carried over; the images load back.
    back = load_cornell(out)
    assert [b.image_id for b in back] == ["0100", "0102"]
    assert all(b.object_id == "box" and b.depth_valid.all() for b in back)
    assert (out / "01" / "pcd0100camera.json").is_file()
    assert not (out / "01" / "pcd0101r.png").exists()


def test_export_options_and_bad_input(dataset, tmp_path, caplog):
    s = export_cornell(dataset, tmp_path / "all", keep_empty=True, inpaint=False)
    assert s["images"] == ["0100", "0101", "0102"] and s["skipped"] == []
    raw = tifffile.imread(tmp_path / "all" / "01" / "pcd0102d.tiff")
    assert (raw == 0).sum() == (tifffile.imread(dataset / "01" / "pcd0102d.tiff") == 0).sum()
    assert (tmp_path / "all" / "01" / "pcd0101cpos.txt").read_text() == ""
    # rewriting the same export works; another source or a stray folder is refused
    export_cornell(dataset, tmp_path / "all")
    assert not (tmp_path / "all" / "01" / "pcd0101r.png").exists()
    with pytest.raises(ValueError, match="inside it"):
        export_cornell(dataset, dataset / "peers")
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="not empty"):
        export_cornell(dataset, tmp_path / "busy")
    with pytest.raises(FileNotFoundError, match="not found"):
        export_cornell(tmp_path / "nothing", tmp_path / "x")
    # an image without any depth reading is left out with its reason, the others written
    tiff = dataset / "01" / "pcd0100d.tiff"
    tifffile.imwrite(tiff, np.zeros((480, 640), np.float32))
    with caplog.at_level("WARNING"):
        s = export_cornell(dataset, tmp_path / "nodepth")
    assert s["images"] == ["0102"]
    assert s["skipped"][0] == {"image": "0100", "reason":
                               "depth: the depth image has no valid pixel (all masked)"}
    assert "0100" in caplog.text


def test_cli_export(dataset, tmp_path, capsys):
    assert main(["export", "--data", str(dataset), "--out", str(tmp_path / "e")]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("exported 2 images (6 positives, 2 negatives)")
    assert "1 left out (0101: no positive rectangle)" in out
    assert main(["export", "--data", str(dataset), "--out", str(dataset)]) == 2
    assert "graspsim export: error:" in capsys.readouterr().err


def test_inpaint_depth_matches_the_peers_and_rejects_empty():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 0.8, (40, 50)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = 0
    depth[0, :] = 0  # the border, which the padding is for
    got = inpaint_depth(depth)
    assert got.dtype == np.float32 and np.all(got > 0)
    np.testing.assert_allclose(got, _peer_inpaint(depth), rtol=1e-6)
    full = np.full((4, 4), 0.7, np.float32)
    np.testing.assert_array_equal(inpaint_depth(full), full)
    with pytest.raises(ValueError, match="no valid pixel"):
        inpaint_depth(np.zeros((4, 4), np.float32))


def test_real_cornell_images_export_as_their_preprocessing(cornell_samples_root, tmp_path):
    """The two real Cornell samples (their preprocessed TIFFs, the range in metres; their
    rectangle files are not shared, so they count as images without a positive): left out by
    default, named; with ``keep_empty`` the exported depth is theirs, inpainted."""
    s = export_cornell(cornell_samples_root, tmp_path / "default")
    assert not s["images"] and {x["image"] for x in s["skipped"]} == {"0100", "0101"}
    s = export_cornell(cornell_samples_root, tmp_path / "real", keep_empty=True)
    assert sorted(s["images"]) == ["0100", "0101"] and not s["skipped"]
    for sample in load_cornell(cornell_samples_root):
        got = tifffile.imread(next((tmp_path / "real").glob(f"*/pcd{sample.image_id}d.tiff")))
        np.testing.assert_allclose(got, _peer_inpaint(sample.depth), rtol=1e-6)


@pytest.mark.sim
def test_exported_positives_score_as_labelled_on_the_source(tmp_path):
    """Images keep their numbers and rectangles: the export, read as Cornell predictions, is
    scored on the source dataset's scenes, and every exported image's first positive lifts."""
    from graspsim.data.datagen import make_dataset
    from graspsim.eval.scoring import score_predictions
    from graspsim.sim.objects import builtin_objects

    names = {"can_tall", "box_matches", "toothbrush", "bottle_shampoo", "plate"}
    specs = [s for s in builtin_objects("all") if s.name in names]
    # seed 7: one of the 4 scenes has no successful candidate
    stats = make_dataset(n_scenes=4, objects=specs, out=tmp_path / "ds", seed=7, n_candidates=6)
    s = export_cornell(tmp_path / "ds", tmp_path / "peers")
    assert s["source_fingerprint"] == stats["fingerprint"]
    labelled = {x.image_id for x in load_cornell(tmp_path / "ds") if x.positives}
    assert s["skipped"] and set(s["images"]) == labelled
    assert {x["image"] for x in s["skipped"]} == {f"{i:04d}" for i in range(4)} - labelled
    scored = score_predictions(tmp_path / "ds", tmp_path / "peers", format="cornell")
    outcome = {r["image"]: r["success"] for r in scored["records"]}
    assert all(outcome[i] for i in s["images"])
    assert not any(outcome[x["image"]] for x in s["skipped"])  # nothing predicted there
