"""Choose K, the settled poses a graspability flag is measured in, on train objects; prints JSON.

For the built-in train objects and every 15th object of pybullet_data's random_urdfs train
split (60 objects), the dense physics labeller searches up to 16 settled poses for a successful
grasp (:func:`graspsim.graspability.measure_graspability`; each object stops at its first
success, so the first pose with a success is known). The flags at K = 1, 2, 4, 8 and 16 follow,
and the objects whose flag changes between consecutive K. The test splits are not used.

    .venv/bin/python scripts/graspability_poses.py [--jobs 2] [--cache objects/graspability.json]

Resumes: measured objects are cached (``--cache``, default the user's cache).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from graspsim.executor import Executor
from graspsim.graspability import measure_graspability
from graspsim.objects import builtin_objects, random_urdf_objects

KS = (1, 2, 4, 8, 16)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--cache", default=None, help="manifest written (default: the user's)")
    p.add_argument("--every", type=int, default=15, help="every n-th random_urdfs train object")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=True)
    sets = {"builtin:train": builtin_objects("train"),
            "random_urdfs:train": random_urdf_objects("train")[::args.every]}
    report = {}
    for label, specs in sets.items():
        out = measure_graspability(specs, max(KS), executor=ex,
                                   cache=None if args.cache is None else Path(args.cache))
        flags = {k: {n: e["first_success"] is not None and e["first_success"] < k
                     for n, e in out.items()} for k in KS}
        report[label] = {
            "n_objects": len(specs),
            "graspable_at": {k: sum(f.values()) for k, f in flags.items()},
            "changed": {f"{a}->{b}": sorted(n for n in flags[a] if flags[a][n] != flags[b][n])
                        for a, b in zip(KS, KS[1:], strict=False)},
            "first_success": {n: e["first_success"] for n, e in out.items()},
        }
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
