"""The data-efficiency curve: DLSR (default and paper) against GG-CNN at 10, 30, 100 and 300
training scenes of the train objects, physical success on the same test scenes (README,
docs/experiments/2026-12-03-ggcnn.md; library: graspsim.eval.data_efficiency).

    nice -n 10 .venv/bin/python scripts/ggcnn_data_efficiency.py [--out results/ggcnn-curve] \\
        [--sizes 10 30 100 300] [--budgets 2000 5000 10000 20000] [--test-trials 200] \\
        [--val-trials 50] [--heldout 50] [--jobs 2] [--device cpu]

Resumes: the same command continues where it stopped (smallest sizes are done first).
Written: curve.json, curve.md and curve.png in --out after every size.

The default --out is committed: the README's figure is results/ggcnn-curve/curve.png, with the
models, trial records and checkpoints it came from, so a session on a new machine continues
the campaign from the last commit (the datasets, about 1.3 MB a scene, are left out and
regenerated from the seed, scene for scene the same). To reproduce it from nothing, give
another --out.
"""

from __future__ import annotations

import argparse
import logging
import sys

from graspsim.cli import sigterm_unwinds, stop_reason
from graspsim.eval.data_efficiency import data_efficiency


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="results/ggcnn-curve")
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 30, 100, 300])
    p.add_argument("--budgets", type=int, nargs="+", default=[2000, 5000, 10000, 20000],
                   help="GG-CNN sample-step budgets validated on train-object scenes")
    p.add_argument("--test-trials", type=int, default=200)
    p.add_argument("--val-trials", type=int, default=50)
    p.add_argument("--heldout", type=int, default=50,
                   help="labelled images of the test objects for the rectangle metric")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--device", default="cpu")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        with sigterm_unwinds():
            data_efficiency(args.out, sizes=args.sizes, budgets=args.budgets,
                            test_trials=args.test_trials, val_trials=args.val_trials,
                            heldout_images=args.heldout, seed=args.seed, device=args.device,
                            n_jobs=args.jobs)
    except (ValueError, FileNotFoundError) as exc:
        print(f"ggcnn_data_efficiency: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"ggcnn_data_efficiency: {stop_reason(exc)[0]}; rerun to continue",
              file=sys.stderr)
        return stop_reason(exc)[1]
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
