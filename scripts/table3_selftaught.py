"""The paper's Table 3 on real data: standard against self-taught detection.

Runs :func:`graspsim.eval.offline.selftaught.selftaught_benchmark`: each learner-encoder combination
is
evaluated by object-wise cross-validated detection (rectangle metric, top-1) on ``--data``
twice, without and with the unlabelled patches of ``--patches`` (e.g. ``graspsim patches
--objects train --n 100000 --out patches.npz``) joined to dictionary learning, and the two are
compared per image by an exact McNemar test. Writes ``<out>/table3.md`` and ``table3.json``
after every combination and prints the rows as JSON; rerun with the same ``--out`` to resume.
Rows of other combinations already in ``<out>/table3.json`` with the same options are kept, so
``--combinations NKM-SC`` adds that row to an earlier table.

Usage: python scripts/table3_selftaught.py --patches runs/patches_train.npz
       [--data ../shared/data/jacquard_samples --format jacquard] [--out runs/table3]
       [--combinations NKM-SC NKM-Natural GSVQ-ST OMP-Natural RP-Natural] [--atoms 300]
       [--coarse-to-fine] [--grid-negatives 0] [--jobs 1]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from graspsim.eval.offline.selftaught import TABLE3_COMBINATIONS, selftaught_benchmark
from graspsim.runtime.executor import Executor

REPO = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data/jacquard_samples",
                    help="dataset folder (a run resumes only under the same spelling)")
    ap.add_argument("--format", choices=["cornell", "jacquard"], default="jacquard")
    ap.add_argument("--patches", required=True, help="npz from graspsim patches")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "table3")
    ap.add_argument("--combinations", nargs="+", default=list(TABLE3_COMBINATIONS))
    ap.add_argument("--split", choices=["image", "object"], default="object")
    ap.add_argument("--atoms", type=int, default=300)
    ap.add_argument("--n-patches", type=int, default=100_000)
    ap.add_argument("--coarse-to-fine", action="store_true")
    ap.add_argument("--grid-negatives", type=float, default=0.0,
                    help="negatives per positive from the detector's own grid (0: the paper's "
                         "training, the default here; see graspsim benchmark detection)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    executor = Executor("sequential" if args.jobs == 1 else "loky", n_jobs=args.jobs,
                        progress=False)
    result = selftaught_benchmark(
        args.data, args.format, args.patches, args.out, combinations=args.combinations,
        split=args.split, n_atoms=args.atoms, n_patches=args.n_patches,
        coarse_to_fine=args.coarse_to_fine, grid_negatives=args.grid_negatives, seed=args.seed,
        executor=executor)
    for row in result["rows"]:
        print(json.dumps({k: v for k, v in row.items() if k != "folders"}))
    print(json.dumps({"table": str(args.out / "table3.md"),
                      "seconds": round(time.perf_counter() - t0, 1)}))


if __name__ == "__main__":
    main()
