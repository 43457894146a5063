"""dlsr.viz: Figure 1 look (jaw plates blue, opening edges red), overlays on disk."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from dlsr.datasets import GraspSample
from dlsr.rectangles import GraspRectangle
from dlsr.viz import (
    JAW_COLOR,
    NEGATIVE_JAW_COLOR,
    OPENING_COLOR,
    draw_rectangles,
    to_rgb8,
    write_overlays,
)


def _dominant(img, x, y, r=1):
    """Mean colour of a small window around (x, y) (column, row)."""
    return img[y - r : y + r + 1, x - r : x + r + 1].reshape(-1, 3).mean(axis=0)


def test_jaws_blue_along_h_and_opening_red_along_w():
    img = np.zeros((100, 160, 3), np.uint8)
    # theta = 0: closing direction along x; w = 60 (opening edges horizontal, length 60),
    # h = 20 (jaw plates vertical, at x = 80 +- 30).
    out = draw_rectangles(img, [GraspRectangle(80, 50, 0.0, 60, 20)], thickness=2)
    for x in (50, 110):  # jaw plates
        r, g, b = _dominant(out, x, 50)
        assert b > 100 and r < 30 and g < 30
    for y in (40, 60):  # opening edges
        r, g, b = _dominant(out, 80, y)
        assert r > 100 and b < 30 and g < 30
    assert out[50, 80].sum() == 0  # inside stays untouched
    assert out[5, 5].sum() == 0


def test_rotation_moves_the_jaws():
    img = np.zeros((160, 160, 3), np.uint8)
    # theta = pi/2: closing direction points up on screen; jaws are horizontal at y = 80 -+ 30.
    out = draw_rectangles(img, [GraspRectangle(80, 80, np.pi / 2, 60, 20)], thickness=2)
    for y in (50, 110):
        r, g, b = _dominant(out, 80, y)
        assert b > 100 and r < 30
    for x in (70, 90):
        r, g, b = _dominant(out, x, 80)
        assert r > 100 and b < 30


def test_anti_aliased_copy_and_input_untouched():
    img = np.full((120, 120, 3), 0, np.uint8)
    before = img.copy()
    out = draw_rectangles(img, np.array([[60, 60, 0.3, 50, 20]]))
    np.testing.assert_array_equal(img, before)
    assert out.dtype == np.uint8 and out.shape == img.shape
    blue = out[..., 2]
    # Anti-aliasing leaves partial intensities along a slanted edge.
    assert np.any((blue > 20) & (blue < 200))
    assert out is not img


def test_negatives_in_their_own_colours():
    img = np.zeros((100, 160, 3), np.uint8)
    out = draw_rectangles(img, [], negatives=[GraspRectangle(80, 50, 0.0, 60, 20)], thickness=2)
    np.testing.assert_allclose(_dominant(out, 50, 50, r=0), NEGATIVE_JAW_COLOR, atol=40)
    custom = draw_rectangles(img, [], [GraspRectangle(80, 50, 0.0, 60, 20)], thickness=2,
                             negative_jaw_color=(0, 255, 0))
    r, g, b = _dominant(custom, 50, 50, r=0)
    assert g > 150 and r < 30 and b < 30
    # Positives are drawn over negatives.
    both = draw_rectangles(img, [GraspRectangle(80, 50, 0.0, 60, 20)],
                           [GraspRectangle(80, 50, 0.0, 60, 20)], thickness=2)
    np.testing.assert_allclose(_dominant(both, 50, 50, r=0), JAW_COLOR, atol=40)
    assert OPENING_COLOR == (255, 0, 0)


def test_grey_input_and_errors():
    depth = np.linspace(0.5, 1.0, 50 * 60, dtype=np.float32).reshape(50, 60)
    depth[0, 0] = np.nan
    out = draw_rectangles(depth, [])
    assert out.shape == (50, 60, 3) and out[0, 0].sum() == 0 and out[-1, -1, 0] == 255
    assert np.array_equal(to_rgb8(np.zeros((4, 4, 3), np.uint8)), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ValueError, match="shape"):
        draw_rectangles(np.zeros((4, 4, 4, 4)), [])
    with pytest.raises(ValueError, match="thickness"):
        draw_rectangles(np.zeros((4, 4, 3), np.uint8), [], thickness=0)


def test_write_overlays(tmp_path):
    rgb = np.full((40, 50, 3), 200, np.uint8)
    z = np.zeros((40, 50), np.float32)
    samples = [
        GraspSample("0_a/b", "a", rgb, z, z > 0, [GraspRectangle(25, 20, 0.2, 20, 8)]),
        GraspSample("1", "a", rgb, z, z > 0, [], [GraspRectangle(25, 20, 0.2, 20, 8)]),
    ]
    paths = write_overlays(samples, tmp_path / "out")
    assert [p.name for p in paths] == ["0_a_b.png", "1.png"]
    for p in paths:
        im = np.array(Image.open(p))
        assert im.shape == (40, 50, 3)
        assert (im != 200).any()  # something was drawn
