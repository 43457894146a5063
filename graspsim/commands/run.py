"""``graspsim run``: the default end-to-end job (what ``make run`` runs)."""

from __future__ import annotations

import argparse
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="end to end: synthetic data, DLSR learning, CV, simulated trials, report",
        description="Generate a synthetic Cornell dataset from the built-in train objects, "
                    "learn a DLSR detector, evaluate recognition and detection by "
                    "cross-validation, run simulated grasp trials on the test objects with "
                    "DLSR and the baselines, and write runs/<name>/report.{md,html}.",
    )
    p.add_argument("--quick", action="store_true", help="a small 2-minute version")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="TOML or YAML file of settings (see graspsim.pipeline.RunConfig)")
    p.add_argument("--out", default=None, metavar="DIR", help="run folder (default runs/NAME)")
    p.add_argument("--resume", default=None, metavar="DIR",
                   help="continue an interrupted run in DIR with its recorded configuration "
                        "(--jobs, --backend and --address may differ: they do not change the "
                        "results)")
    p.add_argument("--name", default=None)
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--backend", choices=["loky", "ray"], default=None)
    p.add_argument("--address", default=None, help="Ray cluster HOST:PORT (with --backend ray)")
    p.add_argument("--jobs", type=int, default=None, help="parallel workers")
    from graspsim.detectors.dlsr_options import add_detector_arguments

    add_detector_arguments(p, preset=False)  # override the config's settings of these names
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    from graspsim.cli import stop_reason
    from graspsim.pipeline import load_config, resume_job, run_folder, run_job

    if args.resume:
        folder = args.resume
    else:
        from graspsim.detectors.dlsr_options import OPTION_NAMES

        config = load_config(args.config, quick=args.quick, name=args.name, seed=args.seed,
                             backend=args.backend, address=args.address, jobs=args.jobs,
                             **{k: getattr(args, k) for k in OPTION_NAMES})
        folder = run_folder(config, args.out)
    try:
        report = (resume_job(folder, backend=args.backend, address=args.address,
                             jobs=args.jobs)
                  if args.resume else run_job(config, out=folder))
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM (graspsim.cli.Terminated)
        # Finished stages and trials are on disk: say how to go on, not where Python was.
        word, code = stop_reason(exc)
        print(f"graspsim run: {word}; what was finished is saved, continue with "
              f"`graspsim run --resume {folder}`", file=sys.stderr)
        return code
    print(f"report: {report} (and {report.with_suffix('.html')})")
    return 0
