"""Paired grasp trials of DLSR, dlsr-paper, mask-pca and the oracle on an object set; prints JSON.

The README's row for pybullet_data's ``random_urdfs`` test split (isolated objects):

    .venv/bin/python scripts/object_sets.py --objects random_urdfs:test --n 200 \\
        --out runs/object-sets

1. The default job's models: ``graspsim run`` with its defaults except ``offline = false``
   (the offline benchmarks do not change the models), one trial per detector on the built-in
   test objects, no baseline (``--model-run``, default ``<out>/model``; resumed when it
   exists).
2. ``--n`` trials per detector on ``--objects`` (seed ``--seed``), every detector on the same
   scenes, as the default job's trial stage runs them (32 dense labelling candidates per scene,
   DLSR's lattice search with the gripper-aware check, dlsr-paper the paper's grid search):
   ``<out>/<objects>/<detector>/``, resumed trial by trial.
3. Each detector's success with a Wilson 95 % interval, its paired difference to mask-pca
   (Newcombe interval, exact McNemar p), and the trials on objects the physics graspability
   flag (:mod:`graspsim.labels.graspability`, computed and cached when missing) marks not graspable:
   ``<out>/<objects>/table.json`` and ``table.md``.

Nothing is chosen on the trial objects: every setting is the default job's
(:mod:`graspsim.pipeline.campaigns`).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from graspsim.pipeline.campaigns import DETECTORS, object_set_campaign, table_markdown, table_only


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default="random_urdfs:test", help="object set")
    p.add_argument("--n", type=int, default=200, help="trials per detector")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/object-sets")
    p.add_argument("--detectors", default=",".join(DETECTORS))
    p.add_argument("--model-run", default=None,
                   help="run folder of the default job's models (default: <out>/model)")
    p.add_argument("--jobs", type=int, default=2, help="parallel workers")
    p.add_argument("--graspability", action="store_true",
                   help="also compute the physics graspability flags when not cached "
                        "(otherwise the not-graspable check uses the cached flags only)")
    p.add_argument("--table-only", action="store_true",
                   help="write the table of the trials finished so far, run nothing")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    names = [d.strip() for d in args.detectors.split(",") if d.strip()]
    if args.table_only:
        print(table_markdown(table_only(args.out, args.objects, names)))
        return 0
    table = object_set_campaign(args.objects, args.n, args.seed, args.out, names,
                                args.model_run, args.jobs, args.graspability)
    print(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
