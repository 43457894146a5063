"""Subcommands of the ``graspsim`` command line, one module each (see :mod:`graspsim.cli`).

Shared argument groups live here so every long command spells them the same way.
"""

from __future__ import annotations

import argparse

__all__ = ["add_executor_args", "executor_from_args", "add_object_args", "object_set_from_args"]


def add_executor_args(p: argparse.ArgumentParser, jobs_default: int = 1) -> None:
    """``--jobs``, ``--backend loky|ray`` and ``--address HOST:PORT`` on a long command."""
    p.add_argument("--jobs", type=int, default=jobs_default,
                   help="parallel workers (-1: all cores, or all cluster CPUs with Ray); "
                        "results do not depend on it (default: %(default)s)")
    p.add_argument("--backend", choices=["loky", "ray"], default="loky",
                   help="where tasks run: local processes (loky) or a Ray cluster "
                        "(default: %(default)s)")
    p.add_argument("--address", default=None, metavar="HOST:PORT",
                   help="Ray cluster to join (with --backend ray; default: a local instance)")


def executor_from_args(args: argparse.Namespace, progress: bool = True):
    """The :class:`graspsim.runtime.executor.Executor` that :func:`add_executor_args` describes.

    ``--backend loky`` with one job runs in the calling process (no worker start-up).
    """
    from graspsim.runtime.executor import Executor

    if args.address is not None and args.backend != "ray":
        raise ValueError("--address needs --backend ray")
    if args.jobs == 0 or args.jobs < -1:
        raise ValueError(f"--jobs must be a positive count or -1 (all cores), got {args.jobs}")
    backend = args.backend
    if backend == "loky" and args.jobs == 1:
        backend = "sequential"
    return Executor(backend=backend, n_jobs=args.jobs, address=args.address, progress=progress)


def add_object_args(p: argparse.ArgumentParser, default: str | None = "test",
                    positional: bool = False) -> None:
    """``--objects SET`` (or a positional ``SET``), ``--object-scale``, ``--object-mass`` and
    ``--decompose``: one object-set syntax on every command
    (:func:`graspsim.sim.object_sets.parse_object_set`)."""
    names = ["objects"] if positional else ["--objects"]
    extra = {"nargs": "?"} if positional else {}
    p.add_argument(*names, default=default, metavar="SET", **extra,
                   help="train, test, all (the built-in split), comma-separated names of "
                        "built-in objects, random_urdfs[:train|test|all] (pybullet_data's; "
                        "test: the 100 folders ending in 0), ycb[:train|test|all] (the YCB "
                        "objects; pip install -e \".[ycb]\") or folder:PATH[:train|test|all] "
                        "(URDF and OBJ files)"
                        + ("" if default is None else " (default: %(default)s)"))
    p.add_argument("--object-scale", type=float, default=1.0, metavar="FACTOR",
                   help="scale every object (0.001 for meshes in millimetres; default: "
                        "%(default)s)")
    p.add_argument("--object-mass", type=float, default=None, metavar="KG",
                   help="give every object this mass (default: each object's own; 0.1 kg for "
                        "a folder's OBJ files)")
    p.add_argument("--decompose", action="store_true",
                   help="convex-decompose a folder's OBJ meshes with V-HACD (cached beside "
                        "them); default: one convex hull per OBJ group")


def add_scene_arg(p: argparse.ArgumentParser) -> None:
    """``--scene drop|isolated|packed|pile`` (:mod:`graspsim.sim.layouts`), one definition for every
    command that builds scenes."""
    from graspsim.sim.layouts import SCENES

    p.add_argument("--scene", default="drop", choices=list(SCENES),
                   help="how objects are put on the table: drop (default: dropped one by one "
                        "at random poses), isolated (drop with one object), packed (upright "
                        "side by side, VGN/GIGA), pile (dropped into a box, then the box "
                        "removed, VGN/GIGA); recorded in the output's configuration")


def objects_per_scene(args: argparse.Namespace, clutter: bool = False) -> int:
    """``--objects-per-scene``, or its default: 5 for ``--scene packed|pile`` (and for
    ``clutter``, the declutter rounds), else 1."""
    from graspsim.sim.layouts import default_objects_per_scene

    k = args.objects_per_scene
    if k is None:
        k = default_objects_per_scene(args.scene, clutter)
    if k < 1:
        raise ValueError(f"--objects-per-scene must be >= 1, got {k}")
    return k


def add_gripper_arg(p: argparse.ArgumentParser) -> None:
    """``--gripper builtin|franka|wsg50|robotiq-2f85`` (:mod:`graspsim.sim.hands`), one
    definition for every command that executes grasps."""
    from graspsim.sim.hands import HAND_NAMES

    p.add_argument("--gripper", default="builtin", choices=list(HAND_NAMES),
                   help="the hand: builtin (default: graspsim's parallel jaw, 8 cm stroke), "
                        "franka (the Franka Emika hand of pybullet_data's franka_panda, "
                        "floating as in VGN/GIGA: 8 cm stroke, 70 N grasp force), wsg50 (the "
                        "Schunk WSG 50 of pybullet_data: 110 mm stroke, 80 N) or robotiq-2f85 "
                        "(the Robotiq 2F-85 as two parallel pads: 85 mm stroke, 235 N); "
                        "labelling, --gripper-aware and execution use its geometry; recorded "
                        "in the output's configuration")


def object_set_from_args(args: argparse.Namespace):
    """The :class:`graspsim.sim.object_sets.ObjectSet` that :func:`add_object_args` describes
    (None when ``--objects`` was not given and has no default)."""
    from graspsim.sim.object_sets import parse_object_set

    if args.objects is None:
        if args.object_scale != 1.0 or args.object_mass is not None or args.decompose:
            raise ValueError("--object-scale, --object-mass and --decompose need --objects")
        return None
    return parse_object_set(args.objects, scale=args.object_scale, mass=args.object_mass,
                            decompose=args.decompose)
