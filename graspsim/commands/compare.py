"""``graspsim compare``: paired comparison of detectors run on the same scenes."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "compare",
        help="paired comparison of trial (or score) folders run on the same scenes",
        description="Compare every pair of the given folders scene by scene: both / only A / "
                    "only B / neither, the difference in success rate with Newcombe's 95 % "
                    "interval for paired proportions, the exact McNemar p-value and a verdict. "
                    "Trial folders must share seed, objects and objects per scene; score "
                    "folders the dataset fingerprint; object-wise validation folders "
                    "(objectwise.json) the same object folds, and their DLSR trials are pooled "
                    "over the folds. Scenes present in only one folder are left out (and "
                    "counted). Trials on graspable objects are also compared on their own, "
                    "and trial folders run with different execution parameters are named as "
                    "such.",
    )
    p.add_argument("folders", nargs="+", metavar="DIR",
                   help="graspsim trials (or graspsim score, or object-wise validation) output "
                        "folders, at least two")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="also write the comparisons as JSON to FILE")
    p.add_argument("--alpha", type=float, default=0.05,
                   help="test level; the interval has level 1 - alpha (default 0.05)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.eval.compare import compare_folders, comparison_text

    comparisons = compare_folders(args.folders, alpha=args.alpha)
    print("\n\n".join(comparison_text(c) for c in comparisons))
    if args.out is not None:
        from dlsr.records import write_json_atomic

        out = write_json_atomic(args.out, {"alpha": args.alpha, "comparisons": comparisons})
        print(f"written: {out}")
    return 0
