"""``graspsim objects SET``: the objects of a set with their size, graspable flag and split."""

from __future__ import annotations

import argparse
import json

from . import (
    add_executor_args,
    add_gripper_arg,
    add_object_args,
    executor_from_args,
    object_set_from_args,
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "objects", help="list an object set: name, size, graspable (by physics), split",
        description="List the objects of a set with their size, split and graspable flag. "
                    "Graspable: the dense physics labeller finds a successful grasp in at "
                    "least one of K settled poses (graspsim.labels.graspability), read from the "
                    "committed or the user's cache; --measure computes the missing flags and "
                    "caches them. Objects without a physics flag show the box rule's, marked.",
    )
    add_object_args(p, default="all", positional=True)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--poses", type=int, default=None, metavar="K",
                   help="settled poses tried per object (default: graspsim.labels.graspability's "
                        "DEFAULT_POSES)")
    p.add_argument("--measure", action="store_true",
                   help="measure the flags not yet cached (minutes for 100 objects)")
    add_gripper_arg(p)
    add_executor_args(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.labels.graspability import DEFAULT_POSES, object_table, object_table_text
    from graspsim.sim.execution import ExecutionParams

    rows = object_table(object_set_from_args(args),
                        DEFAULT_POSES if args.poses is None else args.poses,
                        measure=args.measure,
                        executor=executor_from_args(args) if args.measure else None,
                        params=ExecutionParams.with_hand(args.gripper))
    print(json.dumps(rows, indent=1) if args.json else object_table_text(rows), end="\n")
    return 0
