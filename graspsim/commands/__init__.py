"""Subcommands of the ``graspsim`` command line, one module each (see :mod:`graspsim.cli`).

Shared argument groups live here so every long command spells them the same way.
"""

from __future__ import annotations

import argparse

__all__ = ["add_executor_args", "executor_from_args"]


def add_executor_args(p: argparse.ArgumentParser, jobs_default: int = 1) -> None:
    """``--jobs``, ``--backend loky|ray`` and ``--address HOST:PORT`` on a long command."""
    p.add_argument("--jobs", type=int, default=jobs_default,
                   help="parallel workers (-1: all cores, or all cluster CPUs with Ray); "
                        "results do not depend on it")
    p.add_argument("--backend", choices=["loky", "ray"], default="loky",
                   help="where tasks run: local processes (loky) or a Ray cluster")
    p.add_argument("--address", default=None, metavar="HOST:PORT",
                   help="Ray cluster to join (with --backend ray; default: a local instance)")


def executor_from_args(args: argparse.Namespace, progress: bool = True):
    """The :class:`graspsim.executor.Executor` that :func:`add_executor_args` describes.

    ``--backend loky`` with one job runs in the calling process (no worker start-up).
    """
    from graspsim.executor import Executor

    if args.address is not None and args.backend != "ray":
        raise ValueError("--address needs --backend ray")
    if args.jobs == 0 or args.jobs < -1:
        raise ValueError(f"--jobs must be a positive count or -1 (all cores), got {args.jobs}")
    backend = args.backend
    if backend == "loky" and args.jobs == 1:
        backend = "sequential"
    return Executor(backend=backend, n_jobs=args.jobs, address=args.address, progress=progress)
