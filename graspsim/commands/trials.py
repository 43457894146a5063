"""``graspsim trials``: run a detector's grasps in simulation and score them by physics."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "trials", help="simulated grasp trials of a detector (physics + rectangle metric)"
    )
    p.add_argument("--detector", required=True,
                   help="random, mask-pca, oracle, or the path of a saved model")
    p.add_argument("--objects", default="test", choices=["train", "test", "all"])
    p.add_argument("--n", type=int, default=200, help="number of trials")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="output folder (resumes if it has trials)")
    p.add_argument("--jobs", type=int, default=1, help="worker processes (results do not change)")
    p.add_argument("--candidates", type=int, default=32,
                   help="rectangles executed to label each scene (0: no labels, no metric)")
    p.add_argument("--objects-per-scene", type=int, default=1, help="1: Cornell-like; >1 clutter")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.trials import TrialConfig, run_trials

    s = run_trials(
        detector=args.detector, objects=args.objects, n=args.n, seed=args.seed, out=args.out,
        n_jobs=args.jobs, progress=True,
        config=TrialConfig(n_candidates=args.candidates, n_objects=args.objects_per_scene),
    )
    lo, hi = s["success_ci95"]
    print(f"{args.detector}: success {s['successes']}/{s['n']} = {100 * s['success_rate']:.1f} % "
          f"(95 % CI {100 * lo:.1f}-{100 * hi:.1f} %); summary in {args.out}/summary.md")
    return 0
