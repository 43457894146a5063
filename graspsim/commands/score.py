"""``graspsim score``: execute a detector's predicted rectangles in a dataset's rebuilt scenes."""

from __future__ import annotations

import argparse

from . import add_executor_args, add_object_args, executor_from_args, object_set_from_args


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "score",
        help="execute predicted rectangles in the rebuilt scenes of a `graspsim dataset` folder",
        description="Score predictions made anywhere on a dataset written by `graspsim dataset`: "
                    "each image's rectangles are executed in its scene rebuilt from the "
                    "manifest (scenes.json). Formats: csv (image,x,y,theta_deg,w,h[,score]), "
                    "cornell (folder of pcdXXXX_pred.txt corner files), jacquard (folder of "
                    "<image>_grasps.txt, x;y;theta;w;h with Jacquard's angle sign).",
    )
    p.add_argument("--data", required=True, help="dataset folder written by `graspsim dataset`")
    p.add_argument("--predictions", required=True, help="prediction file (csv) or folder")
    p.add_argument("--out", required=True, help="output folder (resumes if it has scores)")
    p.add_argument("--format", choices=["csv", "cornell", "jacquard"], default=None,
                   help="default: csv for a .csv file; for a folder, from its file names")
    p.add_argument("--top-k", type=int, default=1, metavar="K",
                   help="execute each image's first K rectangles (success at k = any of the "
                        "first k); the top-1 outcome is always recorded (default: %(default)s)")
    add_object_args(p, default=None)
    add_executor_args(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.eval.scoring import score_predictions

    s = score_predictions(args.data, args.predictions, out=args.out, format=args.format,
                          top_k=args.top_k, executor=executor_from_args(args),
                          objects=object_set_from_args(args))
    lo, hi = s["success_ci95"]
    metric = s["metric_accuracy"]
    line = (f"top-1 success {s['successes']}/{s['n']} = {100 * s['success_rate']:.1f} % "
            f"(95 % CI {100 * lo:.1f}-{100 * hi:.1f} %), rectangle metric "
            + ("n/a" if metric is None else f"{100 * metric:.1f} %"))
    if args.top_k > 1:
        last = s["success_at"][-1]
        line += f", success at {args.top_k} {100 * last['rate']:.1f} %"
    print(f"{line}; summary in {args.out}/summary.md")
    return 0
