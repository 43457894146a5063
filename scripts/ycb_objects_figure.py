"""The YCB objects as the simulator loads them, in a grid: docs/ycb_objects.png.

    .venv/bin/python scripts/ycb_objects_figure.py            # needs pip install -e ".[ycb]"

Each usable object of ``--objects`` (default ``ycb:all``; the first run decomposes and caches
them) is loaded from its generated URDF into its own DIRECT pybullet client, stood upright with
its lowest point on a grey floor, and rendered by pybullet's TinyRenderer (the renderer of the
simulated camera) from 45 degrees above, framed by its size. The tile's label is the name and
the split (test in red). Prints a JSON line: the objects drawn, the output path.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from graspsim.sim.bullet import connect, quiet_c_output
from graspsim.sim.object_sets import parse_object_set

TILE = 200


def render(spec, size: int = TILE) -> np.ndarray:
    """(size, size, 3) uint8: ``spec`` upright on a floor, seen from 45 degrees above."""
    client = connect()
    try:
        with quiet_c_output():
            body = client.loadURDF(str(spec.urdf), [0, 0, 1.0], [0, 0, 0, 1],
                                   flags=client.URDF_USE_INERTIA_FROM_FILE)
        lo, hi = (np.asarray(v) for v in client.getAABB(body))
        client.resetBasePositionAndOrientation(body, [0, 0, 1.0 - lo[2]], [0, 0, 0, 1])
        floor = client.createVisualShape(client.GEOM_BOX, halfExtents=[2, 2, 0.001],
                                         rgbaColor=[0.85, 0.85, 0.85, 1])
        client.createMultiBody(0, -1, floor, [0, 0, -0.001])
        centre = [0.0, 0.0, float(hi[2] - lo[2]) / 2]
        radius = 0.5 * float(np.linalg.norm(hi - lo))
        distance = radius / math.sin(math.radians(25)) * 1.05
        view = client.computeViewMatrixFromYawPitchRoll(centre, distance, yaw=30, pitch=-45,
                                                        roll=0, upAxisIndex=2)
        proj = client.computeProjectionMatrixFOV(50, 1.0, 0.01, 10.0)
        _, _, rgba, _, _ = client.getCameraImage(
            size, size, view, proj, renderer=client.ER_TINY_RENDERER, shadow=1,
            lightDirection=[1, 1, 2])
        return np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[..., :3]
    finally:
        client.disconnect()


def grid(specs, columns: int = 10) -> Image.Image:
    """The tiles of ``specs`` in rows of ``columns``, each labelled with name and split."""
    rows = math.ceil(len(specs) / columns)
    label = 28
    sheet = Image.new("RGB", (columns * TILE, rows * (TILE + label)), "white")
    draw = ImageDraw.Draw(sheet)
    for k, spec in enumerate(specs):
        x, y = (k % columns) * TILE, (k // columns) * (TILE + label)
        sheet.paste(Image.fromarray(render(spec)), (x, y))
        colour = (180, 0, 0) if spec.split == "test" else (0, 0, 0)
        draw.text((x + 4, y + TILE + 2), spec.name, fill=colour)
        draw.text((x + 4, y + TILE + 14), f"{spec.split}, {spec.tags[0]}, "
                  f"{1000 * spec.mass:.0f} g", fill=colour)
    return sheet


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default="ycb:all")
    p.add_argument("--out", default="docs/ycb_objects.png")
    p.add_argument("--columns", type=int, default=10)
    args = p.parse_args(argv)
    specs = parse_object_set(args.objects).specs()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    grid(specs, args.columns).save(out, optimize=True)
    print(json.dumps({"objects": len(specs), "out": str(out)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
