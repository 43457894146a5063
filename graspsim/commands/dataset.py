"""``graspsim dataset``: a synthetic, physics-labelled Cornell dataset."""

from __future__ import annotations

import argparse

from graspsim.sim.profiles import PROFILES

from . import (
    add_executor_args,
    add_gripper_arg,
    add_object_args,
    add_scene_arg,
    executor_from_args,
    object_set_from_args,
    objects_per_scene,
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "dataset", help="render scenes, label rectangles by physics, write the Cornell layout",
        description="Render scenes, label candidate rectangles by executing them, and write the "
                    "Cornell layout with a manifest (scenes.json) that `graspsim score` "
                    "rebuilds the scenes from. Every scene is kept: an image where no "
                    "candidate lifted the object has an empty pcdXXXXcpos.txt, and missing "
                    "depth stays 0 in pcdXXXXd.tiff. For the GG-CNN / GR-ConvNet Cornell "
                    "loaders, `graspsim export` writes a copy with only images that have a "
                    "positive and inpainted depth (docs/guides/data-formats.md).",
    )
    p.add_argument("--scenes", type=int, required=True, help="number of images")
    add_object_args(p, default="train")
    p.add_argument("--out", required=True, help="dataset root folder")
    p.add_argument("--seed", type=int, default=0, help="scene i draws from SeedSequence(seed, "
                   "spawn_key=(i,)) (default: %(default)s)")
    p.add_argument("--candidates", type=int, default=48,
                   help="rectangles labelled per scene (default: %(default)s)")
    p.add_argument("--sampler", default="mixed", choices=["mixed", "dense"],
                   help="labelling candidates: mixed (centroid, chord, random) or dense "
                        "(Jacquard-like lattice, every 15 deg; --candidates is its budget) "
                        "(default: %(default)s)")
    p.add_argument("--objects-per-scene", type=int, default=None,
                   help="default: 1, or 5 with --scene packed or pile")
    add_scene_arg(p)
    add_gripper_arg(p)
    p.add_argument("--profile", default="default", choices=sorted(PROFILES),
                   help="how scenes are seen: camera, table, lighting, depth noise "
                        "(docs/sim_settings.md; default: %(default)s)")
    add_executor_args(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.data.datagen import make_dataset
    from graspsim.sim.execution import ExecutionParams

    k = objects_per_scene(args)
    s = make_dataset(n_scenes=args.scenes, objects=object_set_from_args(args), out=args.out,
                     seed=args.seed,
                     n_candidates=args.candidates, n_objects=k,
                     sampler=args.sampler, profile=args.profile,
                     executor=executor_from_args(args), scene=args.scene,
                     params=ExecutionParams.with_hand(args.gripper))
    print(f"wrote {s['images']} images ({s['positives']} positives, {s['negatives']} negatives) "
          f"to {args.out}; manifest {s['manifest']} (sha256 {s['fingerprint'][:12]}...)"
          + (f"; {len(s['unmade_scenes'])} scenes could not be made (manifest: unmade_scenes)"
             if s["unmade_scenes"] else ""))
    return 0
