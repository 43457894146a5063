"""Label coverage: do the physics-labelled positives cover the grasps that work? Prints JSON.

For each seeded single-object scene of the train objects, reference candidates are executed and
their successes kept; each labelling (the mixed sampler, the dense sampler at each budget)
labels the same scene, and its coverage is the fraction of reference successes its positives
match by the rectangle metric (:mod:`graspsim.labels.coverage` says how).

    .venv/bin/python scripts/label_coverage.py [--scenes 20] [--seed 5] [--budgets 128 256 0]
"""

from __future__ import annotations

import argparse
import json

from graspsim.labels.coverage import label_coverage


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--reference", type=int, default=96, help="reference candidates per scene")
    p.add_argument("--mixed-n", type=int, default=48)
    p.add_argument("--budgets", type=int, nargs="+", default=[128, 256, 0],
                   help="dense budgets per scene (0: the whole lattice)")
    p.add_argument("--jobs", type=int, default=1)
    args = p.parse_args(argv)
    print(json.dumps(label_coverage(args.scenes, args.seed, args.reference, args.mixed_n,
                                    args.budgets, n_jobs=args.jobs), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
