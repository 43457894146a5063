"""Write the Cornell-sized stand-in (graspsim.data.standin): 885 simulated images of 240 objects in
the
Cornell layout, with about 5,110 positive and 2,909 negative physics-labelled rectangles.

Resumes: the labelled scenes are kept in OUT/labelled and reused by a rerun.

Usage: python scripts/make_cornell_standin.py [--out runs/standin] [--images 885] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import logging

from graspsim.data.standin import CORNELL, make_cornell_standin


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/standin")
    ap.add_argument("--images", type=int, default=CORNELL["images"])
    ap.add_argument("--objects", type=int, default=CORNELL["objects"])
    ap.add_argument("--positives", type=int, default=None,
                    help="default: Cornell's 5,110 scaled by --images / 885")
    ap.add_argument("--negatives", type=int, default=None,
                    help="default: Cornell's 2,909 scaled by --images / 885")
    ap.add_argument("--candidates", type=int, default=48, help="rectangles executed per scene")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    scale = args.images / CORNELL["images"]
    record = make_cornell_standin(
        args.out, n_images=args.images, n_objects=args.objects,
        positives=args.positives or round(CORNELL["positives"] * scale),
        negatives=args.negatives or round(CORNELL["negatives"] * scale),
        seed=args.seed, n_candidates=args.candidates, n_jobs=args.jobs, progress=True)
    print(json.dumps({k: v for k, v in record.items() if k != "objects"}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
