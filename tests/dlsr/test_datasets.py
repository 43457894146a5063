"""dlsr.datasets: Cornell and Jacquard readers, the Cornell writer, negatives and splits.

Cornell fixtures are written here in exactly the real format: ``pcdXXXXr.png``; PCD v0.7 ASCII
point clouds ``pcdXXXX.txt`` (fields ``x y z rgb index`` in millimetres, rgb packed as a float,
``index = row * 640 + col``) and/or uncompressed float32 ``pcdXXXXd.tiff``; ``cpos``/``cneg``
files with four ``x y`` lines per rectangle, including ``NaN NaN`` corners as in the real
pcd0132cpos.txt; folders ``01``.. or a flat folder; both mapping layouts.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from dlsr.datasets import (
    GraspSample,
    groups,
    image_wise_folds,
    load_cornell,
    load_jacquard,
    object_wise_folds,
    read_mapping,
    read_pcd_depth,
    sample_negatives,
    write_cornell,
)
from dlsr.metrics import rectangle_metric_many
from dlsr.rectangles import GraspRectangle, rects_to_array

H, W = 480, 640
FOCAL = 525.0

# --------------------------------------------------------------------------------------------
# Cornell fixture in the real format

# Per image: (folder, object id, positives, negatives); rectangles as (x, y, theta, w, h).
IMAGES = {
    "0100": ("01", "7",
             [(300, 240, 0.4, 40, 20), (330, 250, -1.2, 36, 18), (280, 220, 1.5, 30, 15)],
             [(300, 240, 1.9, 40, 20), (250, 210, 0.0, 44, 22)]),
    "0101": ("01", "7", [(310, 230, 0.1, 42, 21), (320, 260, 0.9, 38, 16)],
             [(300, 230, -0.5, 50, 20)]),
    "0205": ("02", "12", [(320, 240, -0.3, 48, 24)], []),
}
NAN_IMAGE = "0100"  # its cpos gets a NaN rectangle at lines 5-8 and a partly NaN one at 17-20


def _fmt(v: float) -> str:
    return "NaN" if np.isnan(v) else f"{v:.3f}".rstrip("0").rstrip(".")


def _corner_lines(rects) -> list[str]:
    lines = []
    for r in rects:
        for x, y in GraspRectangle(*r).corners():
            lines.append(f"{_fmt(x)} {_fmt(y)}")
    return lines


def _expected_rects(rects) -> np.ndarray:
    """Rectangles as the reader should see them: from the corners as written (3 decimals)."""
    out = []
    for r in rects:
        pts = np.array([[float(_fmt(x)), float(_fmt(y))] for x, y in GraspRectangle(*r).corners()])
        out.append(GraspRectangle.from_corners(pts).as_array())
    return np.array(out).reshape(-1, 5)


def _scene(image_id: str):
    """Deterministic RGB, true depth (m) and validity for one fixture image."""
    seed = int(image_id)
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:H, 0:W]
    rgb = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    depth = 0.70 + 0.0001 * (rows - 240) + 0.00005 * (cols - 320)
    box = (np.abs(rows - 240) < 30) & (np.abs(cols - 310) < 50)
    depth = np.where(box, depth - 0.08, depth)
    # Points exist only in a window (as real clouds cover the table region), with holes.
    valid = (rows >= 180) & (rows < 300) & (cols >= 220) & (cols < 420)
    valid &= rng.random((H, W)) > 0.1
    valid[200:210, 250:270] = False  # a block without points
    return rgb, depth, valid


def _pcd_text(depth, valid, rgb) -> str:
    rows, cols = np.nonzero(valid)
    d = depth[rows, cols] * 1000.0
    ray = np.column_stack([(cols - 320) / FOCAL, (rows - 240) / FOCAL, np.ones(len(rows))])
    xyz = d[:, None] * ray / np.linalg.norm(ray, axis=1, keepdims=True)
    c = rgb[rows, cols].astype(np.uint32)
    packed = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).astype(np.uint32).view(np.float32)
    index = rows * W + cols
    header = (
        "# .PCD v.7 - Point Cloud Data file format\n"
        "VERSION .7\n"
        "FIELDS x y z rgb index\n"
        "SIZE 4 4 4 4 4\n"
        "TYPE F F F F U\n"
        "COUNT 1 1 1 1 1\n"
        f"WIDTH {len(rows)}\n"
        "HEIGHT 1\n"
        "VIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {len(rows)}\n"
        "DATA ascii\n"
    )
    body = "".join(
        f"{x:.4f} {y:.4f} {z:.4f} {p:.8g} {i}\n"
        for (x, y, z), p, i in zip(xyz, packed, index, strict=True)
    )
    return header + body


def _depth_from_pcd_text(text: str) -> tuple[np.ndarray, np.ndarray]:
    """What the common preprocessing script computes (norm in mm / 1000), without inpainting."""
    lines = text.splitlines()[11:]
    data = np.array([[float(v) for v in ln.split()] for ln in lines])
    depth = np.zeros((H, W), dtype=np.float32)
    idx = data[:, 4].astype(int)
    depth[idx // W, idx % W] = (np.sqrt((data[:, :3] ** 2).sum(axis=1)) / 1000.0).astype(
        np.float32
    )
    return depth, depth > 0


def write_fixture(root: Path, variant: str = "pcd", flat: bool = False,
                  mapping: str | None = "per_image") -> Path:
    """Write the Cornell fixture; ``variant`` in {"pcd", "tiff", "both"}."""
    root.mkdir(parents=True, exist_ok=True)
    for image_id, (folder, _obj, pos, neg) in IMAGES.items():
        d = root if flat else root / folder
        d.mkdir(exist_ok=True)
        stem = f"pcd{image_id}"
        rgb, depth, valid = _scene(image_id)
        Image.fromarray(rgb).save(d / f"{stem}r.png")
        text = _pcd_text(depth, valid, rgb)
        if variant in ("pcd", "both"):
            (d / f"{stem}.txt").write_text(text)
        if variant in ("tiff", "both"):
            tiff_depth, _ = _depth_from_pcd_text(text)
            Image.fromarray(tiff_depth).save(d / f"{stem}d.tiff")
        pos_lines = _corner_lines(pos)
        if image_id == NAN_IMAGE:
            pos_lines[4:4] = ["NaN NaN"] * 4
            partial = _corner_lines([(260, 260, 0.2, 30, 15)])
            partial[2] = "NaN NaN"
            pos_lines += partial
        (d / f"{stem}cpos.txt").write_text("".join(ln + "\n" for ln in pos_lines))
        (d / f"{stem}cneg.txt").write_text("".join(ln + "\n" for ln in _corner_lines(neg)))
    if mapping == "per_image":
        (root / "image_objects.txt").write_text(
            "".join(f"{i} {v[1]} object_{v[1]}\n" for i, v in IMAGES.items())
        )
    elif mapping == "objectClasses":
        lines = []
        for i, v in IMAGES.items():
            lines += [f"{i} {v[1]} Thing_{v[1]} pcdb_0001\n"] * (len(v[2]) + 1)
        (root / "objectClasses.txt").write_text("".join(lines))
    return root


@pytest.fixture(scope="module")
def pcd_root(tmp_path_factory) -> Path:
    return write_fixture(tmp_path_factory.mktemp("cornell_pcd"), "pcd")


@pytest.fixture(scope="module")
def pcd_samples(pcd_root):
    return load_cornell(pcd_root)


# --------------------------------------------------------------------------------------------
# Cornell: reading


def test_pcd_variant_ids_objects_and_rectangles(pcd_samples, pcd_root):
    assert [s.image_id for s in pcd_samples] == ["0100", "0101", "0205"]
    assert [s.object_id for s in pcd_samples] == ["7", "7", "12"]
    for s in pcd_samples:
        folder, _obj, pos, neg = IMAGES[s.image_id]
        assert s.source == pcd_root / folder / f"pcd{s.image_id}r.png"
        np.testing.assert_allclose(rects_to_array(s.positives), _expected_rects(pos), atol=1e-9)
        np.testing.assert_allclose(rects_to_array(s.negatives), _expected_rects(neg), atol=1e-9)
        # The rectangles are the ones that were drawn, to the 3 decimals of the files.
        np.testing.assert_allclose(rects_to_array(s.positives)[:, [0, 1, 3, 4]],
                                   np.array(pos)[:, [0, 1, 3, 4]], atol=2e-3)
        assert s.mask is None


def _z_of_range(depth):
    """The fixture's range (metres, along each pixel's ray) as depth along the optical axis."""
    rows, cols = np.mgrid[0:H, 0:W]
    return depth / np.sqrt(((cols - 320) / FOCAL) ** 2 + ((rows - 240) / FOCAL) ** 2 + 1)


def test_pcd_depth_is_z_along_the_optical_axis_and_not_inpainted(pcd_samples):
    for s in pcd_samples:
        rgb, depth, valid = _scene(s.image_id)
        np.testing.assert_array_equal(s.rgb, rgb)
        assert s.depth.dtype == np.float32 and s.depth_valid.dtype == bool
        assert s.depth.shape == (H, W)
        np.testing.assert_array_equal(s.depth_valid, valid)
        # the cloud holds the range (the fixture's depth); the pipeline's depth is z
        assert np.abs(s.depth[valid] - _z_of_range(depth)[valid]).max() < 2e-6
        assert np.abs(s.depth[valid] - depth[valid]).max() > 0.01  # not the range
        assert np.all(s.depth[~valid] == 0)  # holes stay holes
        assert not s.depth_valid[200:210, 250:270].any()
        assert np.isfinite(s.depth).all()


def test_read_pcd_depth_without_camera_is_the_range(pcd_root):
    depth, valid = read_pcd_depth(pcd_root / "01" / "pcd0100.txt", (H, W))
    _rgb, expected, ok = _scene("0100")
    np.testing.assert_array_equal(valid, ok)
    assert np.abs(depth[ok] - expected[ok]).max() < 2e-6


def test_nan_rectangles_dropped_with_file_and_line_logged(pcd_root, caplog):
    with caplog.at_level(logging.WARNING, logger="dlsr.datasets"):
        samples = load_cornell(pcd_root)
    assert len(samples[0].positives) == 3  # 5 written, 2 with NaN corners
    msgs = [r.getMessage() for r in caplog.records if "non-finite" in r.getMessage()]
    assert len(msgs) == 2
    assert "pcd0100cpos.txt:5-8" in msgs[0]
    assert "pcd0100cpos.txt:17-20" in msgs[1]


def test_point_cloud_and_tiff_variants_agree(tmp_path, pcd_samples):
    tiff_samples = load_cornell(write_fixture(tmp_path / "t", "tiff"))
    assert [s.image_id for s in tiff_samples] == [s.image_id for s in pcd_samples]
    for a, b in zip(pcd_samples, tiff_samples, strict=True):
        # a TIFF alone has no camera: its range is used as read, and K is unknown
        assert b.K is None
        np.testing.assert_allclose(b.depth, _scene(a.image_id)[1] * a.depth_valid, atol=2e-6)
        np.testing.assert_array_equal(a.depth_valid, b.depth_valid)
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(rects_to_array(a.positives), rects_to_array(b.positives))
        assert a.object_id == b.object_id
    # With both files present, "auto" and "pcd" read the point cloud; "tiff" reads the TIFF's
    # range and converts it with the camera fitted to the cloud: the same depths.
    both = write_fixture(tmp_path / "b", "both")
    for src in ("auto", "pcd", "tiff"):
        for a, b in zip(pcd_samples, load_cornell(both, depth_source=src), strict=True):
            np.testing.assert_allclose(a.depth, b.depth, atol=2e-6)
            np.testing.assert_array_equal(a.depth_valid, b.depth_valid)
            np.testing.assert_allclose(a.K, b.K)


def test_flat_layout_equals_folders(tmp_path, pcd_samples):
    flat = load_cornell(write_fixture(tmp_path / "flat", "pcd", flat=True))
    assert [s.image_id for s in flat] == [s.image_id for s in pcd_samples]
    for a, b in zip(pcd_samples, flat, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(rects_to_array(a.negatives), rects_to_array(b.negatives))
        assert a.object_id == b.object_id


def test_mapping_formats(tmp_path, pcd_root):
    root = write_fixture(tmp_path / "oc", "tiff", mapping="objectClasses")
    assert [s.object_id for s in load_cornell(root)] == ["7", "7", "12"]
    # An explicit per-image file elsewhere, short image numbers, descriptions with spaces.
    m = tmp_path / "map.txt"
    m.write_text("# image object description\n100 3 a red thing\n\n0101 3\n205 4 x\n")
    assert [s.object_id for s in load_cornell(root, mapping=m)] == ["3", "3", "4"]
    assert [s.object_id for s in load_cornell(root, mapping={100: 1, "0101": 1})] == [
        "1", "1", None
    ]


def test_no_mapping_gives_none_and_object_split_raises(tmp_path):
    samples = load_cornell(write_fixture(tmp_path / "nm", "tiff", mapping=None))
    assert all(s.object_id is None for s in samples)
    with pytest.raises(ValueError, match="object ids"):
        object_wise_folds(samples, k=2)
    assert len(image_wise_folds(samples, k=3)) == 3


def test_image_missing_from_mapping_is_logged(tmp_path, caplog):
    root = write_fixture(tmp_path / "m", "tiff", mapping=None)
    (root / "image_objects.txt").write_text("0100 7\n0101 7\n")
    with caplog.at_level(logging.WARNING, logger="dlsr.datasets"):
        samples = load_cornell(root)
    assert samples[2].object_id is None
    assert any("0205" in r.getMessage() and "mapping" in r.getMessage() for r in caplog.records)


def test_inconsistent_mapping_raises_naming_file_and_line(tmp_path):
    m = tmp_path / "objectClasses.txt"
    m.write_text("0100 26 Remote pcdb_0013\n0100 26 Remote pcdb_0013\n0100 27 Remote pcdb_0013\n")
    with pytest.raises(ValueError, match=r"objectClasses.txt:3.*0100.*line 1"):
        read_mapping(m)
    m.write_text("0100\n")
    with pytest.raises(ValueError, match=r"objectClasses.txt:1"):
        read_mapping(m)
    with pytest.raises(FileNotFoundError, match="nothere.txt"):
        read_mapping(tmp_path / "nothere.txt")


def test_line_count_not_multiple_of_four_raises(tmp_path):
    root = write_fixture(tmp_path / "c", "tiff")
    p = root / "01" / "pcd0101cpos.txt"
    p.write_text(p.read_text() + "1 2\n")
    with pytest.raises(ValueError, match=r"pcd0101cpos.txt: 9 corner lines, not a multiple of 4"):
        load_cornell(root)


def test_malformed_corner_line_raises(tmp_path):
    root = write_fixture(tmp_path / "c", "tiff")
    p = root / "01" / "pcd0101cneg.txt"
    lines = p.read_text().splitlines()
    lines[2] = "12.5 abc"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"pcd0101cneg.txt:3"):
        load_cornell(root)


def test_unreadable_image_raises(tmp_path):
    root = write_fixture(tmp_path / "c", "tiff")
    (root / "01" / "pcd0101r.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"pcd0101r.png"):
        load_cornell(root)


def test_missing_depth_raises(tmp_path):
    root = write_fixture(tmp_path / "c", "tiff")
    (root / "02" / "pcd0205d.tiff").unlink()
    with pytest.raises(FileNotFoundError, match=r"pcd0205r.png.*pcd0205.txt or pcd0205d.tiff"):
        load_cornell(root)
    with pytest.raises(FileNotFoundError, match="not found"):
        load_cornell(tmp_path / "absent")


def test_bad_point_clouds_raise(tmp_path, pcd_root):
    text = (pcd_root / "01" / "pcd0101.txt").read_text()
    p = tmp_path / "pcd.txt"
    p.write_text(text.replace("DATA ascii", "DATA binary"))
    with pytest.raises(ValueError, match="pcd.txt.*DATA ascii"):
        read_pcd_depth(p, (H, W))
    p.write_text(text.replace("POINTS ", "POINTS 1"))
    with pytest.raises(ValueError, match="pcd.txt.*points"):
        read_pcd_depth(p, (H, W))
    p.write_text(text)
    with pytest.raises(ValueError, match="pcd.txt.*pixel index"):
        read_pcd_depth(p, (100, W))  # indices of rows >= 100


def test_images_without_rectangle_files_load_empty_and_log(tmp_path, caplog):
    root = write_fixture(tmp_path / "c", "tiff")
    (root / "01" / "pcd0101cpos.txt").unlink()
    (root / "01" / "pcd0101cneg.txt").unlink()
    with caplog.at_level(logging.WARNING, logger="dlsr.datasets"):
        samples = load_cornell(root)
    assert samples[1].positives == [] and samples[1].negatives == []
    assert any("pcd0101cpos.txt" in r.getMessage() for r in caplog.records)


def test_scale_resizes_images_and_rectangles_together(pcd_root, pcd_samples):
    small = load_cornell(pcd_root, scale=0.5)
    for a, b in zip(pcd_samples, small, strict=True):
        assert b.rgb.shape == (240, 320, 3) and b.rgb.dtype == np.uint8
        assert b.depth.shape == (240, 320) and b.depth.dtype == np.float32
        # Nearest neighbour: every depth is one of the originals, invalid pixels never blended.
        assert np.isin(b.depth[b.depth_valid], a.depth[a.depth_valid]).all()
        assert np.all(b.depth[~b.depth_valid] == 0)
        assert np.all(b.depth[b.depth_valid] > 0)
        assert 0.3 < b.depth_valid.mean() / a.depth_valid.mean() * 1 < 1.5
        # The hole block (rows 200-210, cols 250-270) stays invalid.
        assert not b.depth_valid[101:104, 126:134].any()
        # INTER_AREA averages colour.
        assert abs(b.rgb.mean() - a.rgb.mean()) < 1.0
        ra, rb = rects_to_array(a.positives), rects_to_array(b.positives)
        np.testing.assert_allclose(rb[:, :2], (ra[:, :2] + 0.5) * 0.5 - 0.5)
        np.testing.assert_allclose(rb[:, 2], ra[:, 2])
        np.testing.assert_allclose(rb[:, 3:], ra[:, 3:] * 0.5)
    with pytest.raises(ValueError, match="scale"):
        load_cornell(pcd_root, scale=0)


# --------------------------------------------------------------------------------------------
# Cornell: writing


def test_write_cornell_round_trip(tmp_path, pcd_samples):
    root = write_cornell(pcd_samples, tmp_path / "w")
    assert root == tmp_path / "w"
    assert (root / "01" / "pcd0100d.tiff").is_file() and (root / "02" / "pcd0205r.png").is_file()
    back = load_cornell(root)
    assert [s.image_id for s in back] == [s.image_id for s in pcd_samples]
    assert [s.object_id for s in back] == [s.object_id for s in pcd_samples]
    for a, b in zip(pcd_samples, back, strict=True):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.depth_valid, b.depth_valid)
        for x, y in ((a.positives, b.positives), (a.negatives, b.negatives)):
            assert len(x) == len(y)
            np.testing.assert_allclose(rects_to_array(y), rects_to_array(x), atol=1e-6)
    # The TIFF is float32 metres with 0 where missing.
    t = np.array(Image.open(root / "01" / "pcd0100d.tiff"))
    assert t.dtype == np.float32 and np.all(t[~pcd_samples[0].depth_valid] == 0)


def _toy_sample(image_id, object_id, rng, size=(60, 80), mask=True):
    h, w = size
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 1.0, (h, w)).astype(np.float32)
    valid = rng.random((h, w)) > 0.2
    depth[~valid] = 0
    m = np.zeros((h, w), bool)
    m[20:40, 20:60] = True
    pos = [GraspRectangle(40, 30, 1.3, 16, 8), GraspRectangle(30, 28, 1.5, 14, 6)]
    return GraspSample(image_id, object_id, rgb, depth, valid, pos, [], None, m if mask else None)


def test_write_cornell_renumbers_non_numeric_ids(tmp_path, rng):
    samples = [_toy_sample("0_abc", "abc", rng), _toy_sample("1_abc", "abc", rng),
               _toy_sample("0_def", None, rng)]
    root = write_cornell(samples, tmp_path / "w")
    back = load_cornell(root)
    assert [s.image_id for s in back] == ["0000", "0001", "0002"]
    assert [s.object_id for s in back] == ["abc", "abc", None]
    assert "0000 abc 0_abc" in (root / "image_objects.txt").read_text()
    for a, b in zip(samples, back, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.depth_valid, b.depth_valid)
        np.testing.assert_allclose(rects_to_array(b.positives), rects_to_array(a.positives),
                                   atol=1e-6)


def test_write_cornell_rejects_unwritable_samples(tmp_path, rng):
    s = _toy_sample("0001", "x", rng)
    s.depth_valid[0, 0], s.depth[0, 0] = True, 0.0
    with pytest.raises(ValueError, match="0001.*valid pixels"):
        write_cornell([s], tmp_path / "a")
    with pytest.raises(ValueError, match="one non-empty word"):
        write_cornell([_toy_sample("0001", "two words", rng)], tmp_path / "b")
    with pytest.raises(ValueError, match="duplicate"):
        write_cornell([_toy_sample("1", "x", rng), _toy_sample("1", "x", rng)], tmp_path / "c")


# --------------------------------------------------------------------------------------------
# Negatives


def test_sample_negatives_on_mask(rng):
    s = _toy_sample("0", "o", rng)
    before = rects_to_array(s.positives).copy()
    neg = sample_negatives(s, 40, np.random.default_rng(1))
    again = sample_negatives(s, 40, np.random.default_rng(1))
    other = sample_negatives(s, 40, np.random.default_rng(2))
    arr = rects_to_array(neg)
    assert arr.shape == (40, 5)
    np.testing.assert_array_equal(arr, rects_to_array(again))
    assert not np.allclose(arr, rects_to_array(other))
    assert not rectangle_metric_many(arr, s.positives).any()
    c = np.round(arr[:, :2]).astype(int)
    assert s.mask[c[:, 1], c[:, 0]].all()
    pos = rects_to_array(s.positives)
    assert arr[:, 3].min() >= 0.8 * pos[:, 3].min() and arr[:, 3].max() <= 1.2 * pos[:, 3].max()
    assert arr[:, 4].min() >= 0.8 * pos[:, 4].min() and arr[:, 4].max() <= 1.2 * pos[:, 4].max()
    np.testing.assert_array_equal(rects_to_array(s.positives), before)
    assert s.negatives == []
    assert sample_negatives(s, 0, rng) == []


def test_sample_negatives_without_mask_near_positives(rng):
    s = _toy_sample("0", "o", rng, size=(200, 200), mask=False)
    arr = rects_to_array(sample_negatives(s, 30, 5))
    assert not rectangle_metric_many(arr, s.positives).any()
    assert np.all((arr[:, :2] >= 0) & (arr[:, :2] <= 199))
    assert np.median(np.hypot(arr[:, 0] - 35, arr[:, 1] - 29)) < 40


def test_sample_negatives_errors(rng):
    s = _toy_sample("0", "o", rng)
    with pytest.raises(ValueError, match="no positives"):
        sample_negatives(GraspSample("z", None, s.rgb, s.depth, s.depth_valid), 3, rng)
    # Squares at every 30 degrees on a one-pixel mask at their centre: nothing can fail.
    m = np.zeros_like(s.mask)
    m[30, 40] = True
    full = GraspSample("full", None, s.rgb, s.depth, s.depth_valid,
                       [GraspRectangle(40, 30, k * np.pi / 6, 20, 20) for k in range(6)], [],
                       None, m)
    with pytest.raises(ValueError, match=r"found only 0 of 5 negatives for image full"):
        sample_negatives(full, 5, rng, max_rounds=3)
    with pytest.raises(ValueError, match="non-negative"):
        sample_negatives(s, -1, rng)


# --------------------------------------------------------------------------------------------
# Splits


def _split_samples(rng):
    objs = ["a"] * 5 + ["b"] * 3 + ["c"] * 4 + ["d"] * 2 + ["e"] * 6 + ["f"] * 1
    return [
        GraspSample(f"{i:04d}", o, np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.float32),
                    np.zeros((2, 2), bool))
        for i, o in enumerate(objs)
    ]


def test_image_wise_folds_partition(rng):
    samples = _split_samples(rng)
    folds = image_wise_folds(samples, k=5, seed=0)
    assert len(folds) == 5
    tests = np.concatenate([t for _, t in folds])
    np.testing.assert_array_equal(np.sort(tests), np.arange(len(samples)))
    for train, test in folds:
        assert len(np.intersect1d(train, test)) == 0 and len(train) + len(test) == len(samples)
        assert 4 <= len(test) <= 5
    again = image_wise_folds(samples, k=5, seed=0)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(folds, again, strict=True))
    other = image_wise_folds(samples, k=5, seed=1)
    assert not all(np.array_equal(a[1], b[1]) for a, b in zip(folds, other, strict=True))


def test_object_wise_folds_keep_objects_together(rng):
    samples = _split_samples(rng)
    obj = groups(samples, "object")
    for seed in range(5):
        folds = object_wise_folds(samples, k=3, seed=seed)
        tests = np.concatenate([t for _, t in folds])
        np.testing.assert_array_equal(np.sort(tests), np.arange(len(samples)))
        seen = {}
        for f, (train, test) in enumerate(folds):
            assert not set(obj[train]) & set(obj[test])
            for o in set(obj[test]):
                assert seen.setdefault(o, f) == f
        assert max(len(t) for _, t in folds) - min(len(t) for _, t in folds) <= 2


def test_folds_compose_with_scikit_learn(rng):
    from sklearn.dummy import DummyClassifier
    from sklearn.model_selection import GroupKFold, cross_val_score

    samples = _split_samples(rng)
    X = np.arange(len(samples), dtype=float)[:, None]
    y = np.arange(len(samples)) % 2
    scores = cross_val_score(DummyClassifier(), X, y, cv=object_wise_folds(samples, k=3))
    assert scores.shape == (3,)
    g = groups(samples, "object")
    for train, test in GroupKFold(n_splits=3).split(X, y, groups=g):
        assert not set(g[train]) & set(g[test])
    assert list(groups(samples, "image")) == [s.image_id for s in samples]


def test_fold_errors(rng):
    samples = _split_samples(rng)
    with pytest.raises(ValueError, match="cannot make 7 folds from 6 groups"):
        object_wise_folds(samples, k=7)
    with pytest.raises(ValueError, match="k must be"):
        image_wise_folds(samples, k=1)
    with pytest.raises(ValueError, match="by must be"):
        groups(samples, by="view")


# --------------------------------------------------------------------------------------------
# Jacquard: fixture


def _write_jacquard_view(folder: Path, view: int, obj: str, lines: list[str]) -> str:
    folder.mkdir(parents=True, exist_ok=True)
    prefix = f"{view}_{obj}"
    rgb = np.full((64, 64, 3), 128, np.uint8)
    Image.fromarray(rgb).save(folder / f"{prefix}_RGB.png")
    mask = np.zeros((64, 64), np.uint8)
    mask[20:44, 28:36] = 255
    Image.fromarray(mask).save(folder / f"{prefix}_mask.png")
    perfect = np.full((64, 64), 1.5, np.float32)
    stereo = perfect.copy()
    stereo[:4] = -1.0
    Image.fromarray(perfect).save(folder / f"{prefix}_perfect_depth.tiff", compression="tiff_lzw")
    Image.fromarray(stereo).save(folder / f"{prefix}_stereo_depth.tiff", compression="tiff_lzw")
    (folder / f"{prefix}_grasps.txt").write_text("".join(ln + "\n" for ln in lines))
    return prefix


def test_jacquard_fixture_reading(tmp_path):
    _write_jacquard_view(tmp_path / "abc", 0, "abc", ["32.0;30.5;30.0;12.0;6.0",
                                                      "31;33;-90;10.5;4"])
    _write_jacquard_view(tmp_path / "abc", 1, "abc", ["32;32;0;10;5"])
    samples = load_jacquard(tmp_path)
    assert [s.image_id for s in samples] == ["0_abc", "1_abc"]
    assert {s.object_id for s in samples} == {"abc"}
    r = samples[0].positives[0]
    # Jacquard angles are clockwise as displayed: 30 degrees there is -pi/6 here.
    np.testing.assert_allclose(r.as_array(), [32, 30.5, -np.pi / 6, 12, 6])
    assert samples[0].positives[1].theta == pytest.approx(-np.pi / 2)
    s = samples[0]
    assert s.mask.dtype == bool and s.mask.sum() == 24 * 8
    assert not s.depth_valid[:4].any() and np.all(s.depth[:4] == 0) and s.depth_valid[4:].all()
    assert load_jacquard(tmp_path, depth="perfect")[0].depth_valid.all()
    small = load_jacquard(tmp_path, scale=0.5)[0]
    assert small.mask.shape == (32, 32) and small.mask.sum() == 12 * 4
    with pytest.raises(ValueError, match="depth must be"):
        load_jacquard(tmp_path, depth="kinect")


def test_jacquard_fixture_errors(tmp_path):
    _write_jacquard_view(tmp_path / "a", 0, "abc", ["32;30;0;12;6", "32;30;0;12"])
    with pytest.raises(ValueError, match=r"0_abc_grasps.txt:2"):
        load_jacquard(tmp_path / "a")
    prefix = _write_jacquard_view(tmp_path / "b", 0, "abc", ["32;30;0;12;6"])
    (tmp_path / "b" / f"{prefix}_stereo_depth.tiff").unlink()
    with pytest.raises(FileNotFoundError, match="0_abc_stereo_depth.tiff"):
        load_jacquard(tmp_path / "b")
    assert len(load_jacquard(tmp_path / "b", depth="perfect")) == 1


# --------------------------------------------------------------------------------------------
# Real data


def test_real_cornell_samples(cornell_samples_root, caplog):
    with caplog.at_level(logging.WARNING, logger="dlsr.datasets"):
        samples = load_cornell(cornell_samples_root)
    assert [s.image_id for s in samples] == ["0100", "0101"]
    assert [s.object_id for s in samples] == ["26", "26"]  # from objectClasses.txt
    assert any("pcd0100cpos.txt" in r.getMessage() for r in caplog.records)
    for s in samples:
        assert s.rgb.shape == (480, 640, 3) and s.rgb.dtype == np.uint8
        assert s.positives == [] and s.negatives == []
        raw = np.array(Image.open(cornell_samples_root / f"pcd{s.image_id}d.tiff"))
        np.testing.assert_array_equal(s.depth_valid, np.isfinite(raw) & (raw > 0))
        np.testing.assert_array_equal(s.depth[s.depth_valid], raw[s.depth_valid])
        assert 0.3 < np.median(s.depth[s.depth_valid]) < 1.5  # metres, a table top
    small = load_cornell(cornell_samples_root, scale=0.5)
    assert small[0].rgb.shape == (240, 320, 3)


def test_real_cornell_mapping(cornell_samples_root):
    mapping = read_mapping(cornell_samples_root / "objectClasses.txt")
    assert len(mapping) == 1035  # image numbers, per shared/data/README.md
    assert mapping["0100"] == "26" and mapping["0000"] == "0"
    assert len(set(mapping.values())) > 200


def test_real_cornell_round_trips(cornell_samples_root, tmp_path):
    samples = load_cornell(cornell_samples_root)
    back = load_cornell(write_cornell(samples, tmp_path / "w"))
    assert (tmp_path / "w" / "01" / "pcd0100d.tiff").is_file()
    for a, b in zip(samples, back, strict=True):
        assert (a.image_id, a.object_id) == (b.image_id, b.object_id)
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.depth_valid, b.depth_valid)


@pytest.fixture(scope="module")
def jacquard_samples(jacquard_root):
    return load_jacquard(jacquard_root, depth="perfect")


def test_real_jacquard_inventory(jacquard_root, jacquard_samples):
    assert len(jacquard_samples) == 28
    assert len({s.object_id for s in jacquard_samples}) == 6
    n_lines = sum(
        len([ln for ln in p.read_text().splitlines() if ln.strip()])
        for p in jacquard_root.rglob("*_grasps.txt")
    )
    assert sum(len(s.positives) for s in jacquard_samples) == n_lines
    for s in jacquard_samples:
        assert s.image_id.endswith(s.object_id) and s.source.parent.name == s.object_id
        assert s.rgb.shape == (1024, 1024, 3)
        assert s.mask.dtype == bool and 0 < s.mask.mean() < 0.2
        assert s.depth_valid.all() and 1.0 < np.median(s.depth) < 2.0
        assert s.negatives == []


def test_real_jacquard_stereo_missing_pixels(jacquard_root):
    folder = sorted(p for p in jacquard_root.iterdir() if p.is_dir())[0]
    samples = load_jacquard(folder, depth="stereo")
    raw = np.array(Image.open(next(folder.glob("0_*_stereo_depth.tiff"))))
    s = samples[0]
    assert (raw == -1).any()
    np.testing.assert_array_equal(s.depth_valid, raw > 0)
    assert np.all(s.depth[raw == -1] == 0)


def _closing_axis(theta):
    return np.stack([np.cos(theta), -np.sin(theta)], axis=1)


def _on(mask, pts):
    c = np.clip(np.round(pts).astype(int), 0, [mask.shape[1] - 1, mask.shape[0] - 1])
    return mask[c[..., 1], c[..., 0]]


def test_real_jacquard_grasps_lie_on_the_object(jacquard_samples):
    for s in jacquard_samples:
        a = rects_to_array(s.positives)
        # Every centre lies inside the object's outline (its convex hull: grasps around two legs
        # of a figure have their centre between them, off the mask itself).
        contours, _ = cv2.findContours(s.mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_SIMPLE)
        hull = cv2.convexHull(np.concatenate(contours))
        inside = [cv2.pointPolygonTest(hull, (float(x), float(y)), False) for x, y in a[:, :2]]
        assert min(inside) > 0, s.image_id
        # Every closing segment (from jaw to jaw through the centre) crosses the object.
        t = np.linspace(-0.5, 0.5, 41)
        seg = a[:, None, :2] + t[None, :, None] * a[:, None, 3:4] * _closing_axis(a[:, 2])[:, None]
        assert _on(s.mask, seg).any(axis=1).all(), s.image_id


def test_real_jacquard_angle_convention(jacquard_samples):
    """Jaws sit at the object's boundary or outside it more often than the centres do, and much
    more so than with the opposite angle sign (which would put many jaws on the object)."""

    def jaw_on_fraction(sign):
        hits, centres = [], []
        for s in jacquard_samples:
            a = rects_to_array(s.positives)
            u = _closing_axis(sign * a[:, 2]) * a[:, 3:4] / 2
            hits += [_on(s.mask, a[:, :2] + u), _on(s.mask, a[:, :2] - u)]
            centres.append(_on(s.mask, a[:, :2]))
        return np.concatenate(hits).mean(), np.concatenate(centres).mean()

    ours, centre = jaw_on_fraction(+1)
    flipped, _ = jaw_on_fraction(-1)
    assert centre > 0.8  # measured 0.85
    assert ours < 0.25  # measured 0.16
    assert flipped > ours + 0.15  # measured 0.39


def test_real_jacquard_scale_and_negatives(jacquard_root, jacquard_samples):
    folder = sorted(p for p in jacquard_root.iterdir() if p.is_dir())[0]
    small = load_jacquard(folder, depth="perfect", scale=0.5)
    full = [s for s in jacquard_samples if s.object_id == folder.name]
    for a, b in zip(full, small, strict=True):
        assert b.rgb.shape == (512, 512, 3) and b.mask.shape == (512, 512)
        assert abs(b.mask.mean() - a.mask.mean()) < 0.002
        ra, rb = rects_to_array(a.positives), rects_to_array(b.positives)
        np.testing.assert_allclose(rb[:, 3:], ra[:, 3:] / 2)
    s = small[0]
    neg = rects_to_array(sample_negatives(s, 50, np.random.default_rng(0)))
    assert len(neg) == 50
    assert not rectangle_metric_many(neg, s.positives).any()
    assert _on(s.mask, neg[:, :2]).all()


def test_real_jacquard_object_wise_folds(jacquard_samples):
    folds = object_wise_folds(jacquard_samples, k=3, seed=0)
    g = groups(jacquard_samples, "object")
    for train, test in folds:
        assert not set(g[train]) & set(g[test])
    assert sorted(np.concatenate([t for _, t in folds]).tolist()) == list(range(28))
