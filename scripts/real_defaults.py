"""Choose the real-data detector defaults by nested object-wise cross-validation; prints JSON.

On a real dataset (the Jacquard samples by default), every candidate configuration of
:func:`graspsim.detectors.dlsr_options.candidate_options` (the paper's, each departure from it
alone, all of them) is cross-validated on each outer fold's training objects, the best is
chosen there and reported on the outer fold (:func:`graspsim.eval.offline.detection.
nested_detector_choice`). The record is docs/experiments/2026-12-03-real-defaults.md.

    .venv/bin/python scripts/real_defaults.py --data ../shared/data/jacquard_samples \\
        --out /work/runs/i39/real-defaults [--atoms 50 --patches 10000 --jobs 2]

The same command resumes an interrupted run (every detection is saved as it is made).
Written: out/nested.json, out/nested.md and the runs under out/.
"""

from __future__ import annotations

import argparse
import json
import sys

from graspsim.commands import add_executor_args, executor_from_args
from graspsim.eval.offline.nested import nested_detector_choice


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--format", choices=["cornell", "jacquard"], default="jacquard")
    p.add_argument("--scale", type=float, default=None)
    p.add_argument("--folds", type=int, default=5)
    p.add_argument("--inner-folds", type=int, default=2)
    p.add_argument("--inner-views", type=int, default=3,
                   help="views per object in the inner folds (0: all)")
    p.add_argument("--atoms", type=int, default=50)
    p.add_argument("--patches", type=int, default=10_000)
    p.add_argument("--rescore", type=int, default=50)
    p.add_argument("--train-positives", type=int, default=20,
                   help="positives per training image (a cheaper training; 0: all)")
    p.add_argument("--seed", type=int, default=0)
    add_executor_args(p)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    result = nested_detector_choice(
        args.data, args.format, args.out, n_folds=args.folds, inner_folds=args.inner_folds,
        inner_views=args.inner_views or None, seed=args.seed, scale=args.scale,
        n_atoms=args.atoms, n_patches=args.patches, rescore=args.rescore,
        coarse_to_fine=True, train_positives=args.train_positives or None,
        executor=executor_from_args(args))
    json.dump({k: result[k] for k in ("chosen", "chosen_counts", "table", "tests")},
              sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
