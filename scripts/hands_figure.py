"""Picture of the hands side by side at one scale: docs/hands.png.

Every hand of ``--gripper`` open to its largest opening, fingers down, seen from the side by an
orthographic camera above a ruler of 1 cm ticks (:func:`graspsim.eval.trialviz.hands_picture`).

    .venv/bin/python scripts/hands_figure.py [--out docs/hands.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from graspsim.eval.trialviz import hands_picture


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="docs/hands.png")
    p.add_argument("--px-per-mm", type=float, default=1.5)
    args = p.parse_args(argv)
    img = hands_picture(px_per_mm=args.px_per_mm)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
        raise SystemExit(f"could not write {out}")
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
