"""Draw the top rectangle on the two real Cornell images: docs/real_cornell_top.png.

A small model is trained on the real Jacquard samples as the real-data default
(``--preset real``) trains it (the paper's training; 14 views, 40 grasps each, 50 atoms, as
the test of ``graspsim detect`` on the remote), or ``--model`` is used; each Cornell
image is then searched with the default options and with the paper's configuration
(``--preset paper``), the Cornell camera matrix found by ``graspsim detect``'s own rule
(:func:`dlsr.intrinsics.cornell_camera_matrix`). Top row: default; bottom row: the paper's.

    .venv/bin/python scripts/real_cornell_figure.py [--cornell ../shared/data/cornell_samples] \\
        [--jacquard ../shared/data/jacquard_samples] [--model PATH] [--out docs/...png]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from dlsr.datasets import load_jacquard
from dlsr.detection import DLSRDetector, detect_files, train_detector
from graspsim.detectors.dlsr_options import PRESETS, REAL_DEFAULT, build_real_detector

CROP = (150, 200, 450, 420)  # x0, y0, x1, y1: the remote and the table around it


def small_jacquard_model(root, seed: int = 0) -> DLSRDetector:
    """The test's small model: 14 random views, 40 grasps each, trained as the real-data
    default trains (physical features only if it has them)."""
    rng = np.random.default_rng(seed)
    views = load_jacquard(root, depth="perfect", scale=0.5)
    views = [views[i] for i in np.sort(rng.choice(len(views), 14, replace=False))]
    views = [dataclasses.replace(v, positives=[v.positives[i] for i in np.sort(
        rng.choice(len(v.positives), min(40, len(v.positives)), replace=False))])
        for v in views]
    return train_detector(views, n_atoms=50, n_patches=10_000, random_state=seed,
                          physical=PRESETS[REAL_DEFAULT].physical)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cornell", default="../shared/data/cornell_samples")
    p.add_argument("--jacquard", default="../shared/data/jacquard_samples")
    p.add_argument("--model", default=None)
    p.add_argument("--out", default="docs/real_cornell_top.png")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        model = args.model
        if model is None:
            model = Path(tmp) / "m"
            small_jacquard_model(args.jacquard).save(model)
        model = DLSRDetector.load(model)
        rows, found = [], {}
        for preset in (REAL_DEFAULT, "paper"):
            tiles = []
            for image in ("0100", "0101"):
                rgb = Path(args.cornell) / f"pcd{image}r.png"
                depth = Path(args.cornell) / f"pcd{image}d.tiff"

                def build(m, top_k, background, obs, preset=preset):
                    return build_real_detector(m, PRESETS[preset], top_k=top_k,
                                               background=background, coarse_to_fine=True)

                det = detect_files(model, rgb, depth, top_k=1, build=build,
                                   out=Path(tmp) / f"{preset}_{image}.png")
                found[f"{preset} pcd{image}"] = [round(float(v), 1) for v in det.rects[0]]
                tile = Image.open(Path(tmp) / f"{preset}_{image}.png").crop(CROP)
                ImageDraw.Draw(tile).text((6, 4), f"pcd{image}, {preset}", fill=(255, 255, 0))
                tiles.append(np.asarray(tile.convert("RGB")))
            rows.append(np.concatenate(tiles, axis=1))
        Image.fromarray(np.concatenate(rows, axis=0)).save(args.out)
    json.dump({"out": args.out, "top_rectangles": found}, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
