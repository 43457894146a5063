"""``graspsim run``: the default job of ``make run``.

For now (a later issue replaces it with the end-to-end job) it loads the real samples in
``../shared/data`` beside the repository, or, when they are absent, a small built-in
Cornell-format fixture written with :func:`dlsr.datasets.write_cornell`, and writes rectangle
overlays to ``runs/<name>/``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

import graspsim
from dlsr.datasets import GraspSample, load_cornell, load_jacquard, write_cornell
from dlsr.rectangles import GraspRectangle
from dlsr.viz import write_overlays

logger = logging.getLogger(__name__)


def default_shared_data() -> Path:
    """``../shared/data`` beside the repository checkout.

    Resolved from the package location, which is the source tree under the editable install of
    ``make run``; under a regular install it points into site-packages, does not exist, and the
    job falls back to the built-in fixture (pass ``--data`` to override).
    """
    return Path(graspsim.__file__).resolve().parents[2] / "shared" / "data"


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


def default_job(name: str = "default", data=None, runs_dir="runs") -> list[Path]:
    """Write rectangle overlays of the real samples (or the built-in fixture) to ``runs/<name>``.

    Parameters
    ----------
    name : str
        Run name; output goes to ``<runs_dir>/<name>/{jacquard,cornell,fixture}/``.
    data : path-like, optional
        Folder holding ``jacquard_samples/`` and/or ``cornell_samples/``; defaults to
        :func:`default_shared_data`.
    runs_dir : path-like

    Returns
    -------
    list of Path
        The overlays written.
    """
    out = Path(runs_dir) / name
    data = default_shared_data() if data is None else Path(data)
    paths: list[Path] = []
    if (data / "jacquard_samples").is_dir():
        samples = load_jacquard(data / "jacquard_samples", scale=0.5)
        paths += write_overlays(samples, out / "jacquard")
    if (data / "cornell_samples").is_dir():
        paths += write_overlays(load_cornell(data / "cornell_samples"), out / "cornell")
    if not paths:
        logger.info("no real data in %s; using the built-in Cornell-format fixture", data)
        root = write_cornell(builtin_samples(), out / "fixture_data")
        paths += write_overlays(load_cornell(root), out / "fixture")
    return paths


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help="default job (for now: rectangle overlays of the real samples)"
    )
    p.add_argument("--name", default="default", help="run name (output in RUNS/NAME)")
    p.add_argument("--data", default=None, help="folder with jacquard_samples/ cornell_samples/")
    p.add_argument("--runs", default="runs", metavar="RUNS", help="runs folder")
    p.set_defaults(func=_main)


def _main(args) -> int:
    paths = default_job(args.name, args.data, args.runs)
    print(f"wrote {len(paths)} overlays to {Path(args.runs) / args.name}")
    return 0
