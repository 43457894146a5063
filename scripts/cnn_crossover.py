"""Issue 54, items 2-4: the data-efficiency curve carried to the crossover. DLSR against GG-CNN
and GR-ConvNet, each network trained to its plateau at every size, every detector on the same
labelled test scenes (physical success beside the rectangle metric); library:
graspsim.eval.crossover.

    nice -n 10 .venv/bin/python scripts/cnn_crossover.py [--out results/cnn-crossover] \\
        [--sizes 10 30 100 300 1000 3000] [--max-size 300] [--jobs 2] [--device cpu]

A campaign of many hours: it resumes where it stopped (smallest sizes first), and --max-size
stops after a size, so it lands in pieces. Written after every model and trial folder:
crossover.json and crossover.md in --out. Commit --out as it goes, without the dataset (about
1.3 MB a scene, regenerated from the seed scene for scene) and without the budgets' snapshots
that were not chosen: a rerun needs the record, the chosen and equal-time models (GR-ConvNet's
about 7.6 MB each) and, for a network still training, its checkpoint.
"""

from __future__ import annotations

import argparse
import logging
import sys

from graspsim.cli import sigterm_unwinds, stop_reason
from graspsim.eval.crossover import PEERS, crossover_study


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="results/cnn-crossover")
    p.add_argument("--sizes", type=int, nargs="+", default=[10, 30, 100, 300, 1000, 3000])
    p.add_argument("--max-size", type=int, default=None, help="stop after this size")
    p.add_argument("--peers", nargs="+", default=list(PEERS))
    p.add_argument("--train-objects", default="ycb:train")
    p.add_argument("--test-objects", default="ycb:test")
    p.add_argument("--test-trials", type=int, default=200)
    p.add_argument("--val-trials", type=int, default=100)
    p.add_argument("--max-hours", type=float, default=4.0,
                   help="GR-ConvNet k=32 training time per size before k=16 is used")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--device", default="cpu")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    from graspsim.runtime.executor import Executor

    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=False)
    try:
        with sigterm_unwinds():
            crossover_study(args.out, sizes=args.sizes, peers=args.peers,
                            train_objects=args.train_objects, test_objects=args.test_objects,
                            test_trials=args.test_trials, val_trials=args.val_trials,
                            max_hours=args.max_hours, seed=args.seed, device=args.device,
                            max_size=args.max_size, executor=ex)
    except (ValueError, FileNotFoundError) as exc:
        print(f"cnn_crossover: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"cnn_crossover: {stop_reason(exc)[0]}; rerun to continue", file=sys.stderr)
        return stop_reason(exc)[1]
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
