"""``graspsim patches``: unlabelled 6x6x8 patches from random rendered scenes."""

from __future__ import annotations

import argparse

from . import (
    add_executor_args,
    add_object_args,
    add_scene_arg,
    executor_from_args,
    object_set_from_args,
    objects_per_scene,
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "patches", help="random 6x6x8 patches of simulated rectangle images (self-taught data)"
    )
    p.add_argument("--n", type=int, default=100_000,
                   help="number of patches (default: %(default)s)")
    p.add_argument("--out", required=True, help=".npz file (dlsr.patches.load_patch_file)")
    add_object_args(p, default="all")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--scenes", type=int, default=None, help="default: n / 2000")
    p.add_argument("--objects-per-scene", type=int, default=None,
                   help="default: 1, or 5 with --scene packed or pile")
    add_scene_arg(p)
    add_executor_args(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.data.datagen import make_patches

    k = objects_per_scene(args)
    s = make_patches(n=args.n, out=args.out, objects=object_set_from_args(args), seed=args.seed,
                     n_scenes=args.scenes, n_objects=k, executor=executor_from_args(args),
                     scene=args.scene)
    unmade = len(s["unmade_scenes"])
    print(f"wrote {s['n']} patches from {s['scenes'] - unmade} scenes to {s['path']}"
          + (f" ({unmade} scenes could not be made)" if unmade else ""))
    return 0
