"""Shared fixtures: the real data in ../shared/data, skipped with a reason when absent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dlsr.datasets import (
    GraspSample,
    clean_depth,
    read_depth_image,
    read_jacquard_grasps,
    read_rgb,
    write_cornell,
)
from dlsr.rectangles import GraspRectangle, rects_to_array

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real data not available: {path} is absent (see shared/data/README.md)")
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    return _require(SHARED_DATA)


@pytest.fixture(scope="session")
def jacquard_root() -> Path:
    return _require(SHARED_DATA / "jacquard_samples")


JACQUARD_VIEW = "1a9fa4c269cfcc1b738e43095496b061/0_1a9fa4c269cfcc1b738e43095496b061"


@pytest.fixture(scope="session")
def jacquard_view(jacquard_root):
    """``jacquard_view(depth="perfect"|"stereo", view=JACQUARD_VIEW)`` -> rgb, depth (m, 0 where
    missing), validity and the (n, 5) rectangles of one real view, via the dataset readers."""

    def load(depth: str = "perfect", view: str = JACQUARD_VIEW):
        prefix = str(jacquard_root / view)
        d, valid = clean_depth(read_depth_image(Path(f"{prefix}_{depth}_depth.tiff")))
        rects = rects_to_array(read_jacquard_grasps(Path(f"{prefix}_grasps.txt")))
        return read_rgb(Path(f"{prefix}_RGB.png")), d, valid, rects

    return load


@pytest.fixture(scope="session")
def cornell_samples_root() -> Path:
    return _require(SHARED_DATA / "cornell_samples")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def builtin_samples(n: int = 3) -> list[GraspSample]:
    """``n`` synthetic 480x640 Cornell-like images: a box on a table with grasps across it.

    Box angles cycle through 0, 0.5 and -1 rad; each image is its own object ("box<i // 2>"
    groups two images per object when ``n > 3``, "box" otherwise).
    """
    samples = []
    rows, cols = np.mgrid[0:480, 0:640]
    for i in range(n):
        angle = (0.0, 0.5, -1.0)[i % 3]
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
        obj = f"box{i // 2}" if n > 3 else "box"
        samples.append(GraspSample(f"{100 + i:04d}", obj, rgb, depth, valid, pos, neg))
    return samples


@pytest.fixture
def cornell_root(tmp_path):
    return write_cornell(builtin_samples(), tmp_path / "cornell")

@pytest.fixture(scope="session")
def box_samples():
    """Factory of synthetic Cornell-like samples: ``box_samples(n)``."""
    return builtin_samples
