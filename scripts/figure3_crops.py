"""Figure-3-like picture: a Jacquard grasp rectangle, its rotated crop, its 24x24 8-channel image.

Usage: python scripts/figure3_crops.py [--view DIR/PREFIX] [--grasp 0] [--out PNG]
(default output: runs/figures/figure3.png)

Jacquard grasp lines are ``x;y;theta_deg;opening;jaw_size``. Jacquard's angle is measured with
the image y axis pointing down (clockwise as displayed), so the toolkit's counter-clockwise-as-
displayed ``theta`` is ``-radians(theta_deg)`` (checked on this figure: with that sign the
rectangle lies across the object; GR-ConvNet's Jacquard loader negates the angle the same way).
The data are read with Pillow directly (the LZW TIFF depth needs no imagecodecs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from dlsr.figures import crop_figure
from dlsr.rectangles import GraspRectangle

REPO = Path(__file__).resolve().parents[1]
DEFAULT_VIEW = (REPO.parent / "shared" / "data" / "jacquard_samples"
                / "1a9fa4c269cfcc1b738e43095496b061" / "0_1a9fa4c269cfcc1b738e43095496b061")


def jacquard_rect(line: str, angle_sign: float = -1.0) -> GraspRectangle:
    x, y, theta_deg, opening, jaw = (float(v) for v in line.strip().split(";"))
    return GraspRectangle(x, y, angle_sign * np.radians(theta_deg), opening, jaw)


def main(argv=None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--view", type=Path, default=DEFAULT_VIEW,
                    help="path prefix of a Jacquard view (without _RGB.png)")
    ap.add_argument("--grasp", type=int, default=0, help="line of grasps.txt (0-based)")
    ap.add_argument("--depth", choices=("perfect", "stereo"), default="perfect")
    ap.add_argument("--angle-sign", type=float, default=-1.0,
                    help="theta = angle_sign * radians(theta_deg); -1 for Jacquard")
    ap.add_argument("--margin", type=float, default=6.0,
                    help="context around the rectangle in the first panel, in rectangle sizes")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "figures" / "figure3.png")
    args = ap.parse_args(argv)
    prefix = str(args.view)
    for suffix in ("_RGB.png", f"_{args.depth}_depth.tiff", "_grasps.txt"):
        if not Path(prefix + suffix).is_file():
            raise FileNotFoundError(f"missing {prefix + suffix}")
    rgb = np.array(Image.open(prefix + "_RGB.png").convert("RGB"))
    depth = np.array(Image.open(prefix + f"_{args.depth}_depth.tiff"), dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)  # stereo depth marks missing pixels with -1
    depth = np.where(valid, depth, 0.0).astype(np.float32)
    lines = [ln for ln in Path(prefix + "_grasps.txt").read_text().splitlines() if ln.strip()]
    if not 0 <= args.grasp < len(lines):
        raise ValueError(f"{prefix}_grasps.txt has {len(lines)} grasps, asked for {args.grasp}")
    rect = jacquard_rect(lines[args.grasp], args.angle_sign)
    title = (f"{Path(prefix).name}, grasp {args.grasp}: {lines[args.grasp].strip()} "
             f"-> theta = {np.degrees(rect.theta):.1f} deg (CCW as displayed)")
    out = crop_figure(rgb, depth, valid, rect, args.out, title=title, margin=args.margin)
    print(out)
    return out


if __name__ == "__main__":
    main()
