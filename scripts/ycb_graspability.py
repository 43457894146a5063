"""Measure the YCB objects' physics graspability flags for one hand into the committed manifest.

    .venv/bin/python scripts/ycb_graspability.py --hand builtin --split test --jobs 1
    .venv/bin/python scripts/ycb_graspability.py --hand franka --jobs 1

The flags are :mod:`graspsim.labels.graspability`'s (a successful grasp of the dense labeller in one
of K = 16 settled poses), keyed by hand (the gripper and harness parameters) and by object (its
mesh, decomposition, mass and friction) in ``objects/ycb/graspability.json``, the manifest the
loader reads beside ``objects/graspability.json``. Objects already measured are not measured
again, so a stopped run resumes and a new hand (any name
:meth:`graspsim.sim.execution.ExecutionParams.with_hand` knows) is added by the same command.
Prints a JSON summary: per object its first successful pose (or null) and the count graspable.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from graspsim.labels.graspability import DEFAULT_POSES, SET_MANIFESTS, measure_graspability
from graspsim.runtime.executor import Executor
from graspsim.sim.execution import ExecutionParams
from graspsim.sim.object_sets import parse_object_set
from graspsim.sim.objects import assets_dir


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--hand", default="builtin", help="builtin, franka or another known hand")
    p.add_argument("--split", default="all", choices=("train", "test", "all"))
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--poses", type=int, default=DEFAULT_POSES)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    manifest = assets_dir() / SET_MANIFESTS[0]
    executor = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                        progress=True)
    out = measure_graspability(parse_object_set(f"ycb:{args.split}"), args.poses,
                               ExecutionParams.with_hand(args.hand), executor, cache=manifest)
    n = sum(v["first_success"] is not None for v in out.values())
    print(json.dumps({"hand": args.hand, "split": args.split, "graspable": n,
                      "objects": len(out), "manifest": str(manifest), "outcomes": out},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
