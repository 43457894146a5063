"""``graspsim show DATA --format cornell|jacquard --out DIR``: write rectangle overlays."""

from __future__ import annotations

import logging

from dlsr.viz import show_dataset

logger = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "show", help="draw the labelled grasp rectangles of a dataset (jaws blue, opening red)"
    )
    p.add_argument("data", metavar="DATA", help="dataset root folder")
    p.add_argument("--format", choices=["cornell", "jacquard"], required=True)
    p.add_argument("--scale", type=float, default=1.0,
                   help="resize images and rectangles (default: %(default)s)")
    p.add_argument("--depth", choices=["stereo", "perfect"], default="stereo",
                   help="Jacquard depth variant (ignored for Cornell) (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for PNG overlays")
    p.set_defaults(func=_main)


def _main(args) -> int:
    paths = show_dataset(args.data, args.format, args.out, scale=args.scale, depth=args.depth)
    print(f"wrote {len(paths)} overlays to {args.out}")
    return 0
