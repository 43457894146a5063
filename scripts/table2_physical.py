"""Table 2's top rectangles executed: physical success beside the rectangle metric (issue 51;
library: :mod:`graspsim.eval.offline.table2_physical`).

For each size measured by ``scripts/bench_scale.py`` (its committed Table 2 folders), every
detection row's top-1 rectangle and mask-pca's are executed in each image's rebuilt scene
(``graspsim score``). The stand-in's images are scenes of its labelled dataset (``OUT/labelled``
of :func:`graspsim.data.standin.make_cornell_standin`). Writes ``<out>/<size>/...`` score
folders (resumable) and ``<out>/table2_physical.{json,md}``, keeping sizes run before.

Usage: python scripts/table2_physical.py --labelled /path/standin/labelled [--sizes 100]
       [--bench results/cornell-scale[,OTHER]] [--out results/table2-physical] [--jobs 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from graspsim.eval.offline.table2_physical import execute_table2

REPO = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--labelled", required=True, help="the stand-in's labelled dataset folder")
    ap.add_argument("--bench", default=str(REPO / "results" / "cornell-scale"),
                    help="folders of Table 2 benchmark folders, comma-separated")
    ap.add_argument("--sizes", default="100", help="comma-separated stand-in sizes")
    ap.add_argument("--out", default=str(REPO / "results" / "table2-physical"))
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args(argv)
    try:
        execute_table2(args.labelled, args.bench.split(","), args.sizes.split(","), args.out,
                       n_jobs=args.jobs)
    except (ValueError, FileNotFoundError) as exc:
        print(f"table2_physical: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print((Path(args.out) / "table2_physical.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
