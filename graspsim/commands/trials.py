"""``graspsim trials``: run a detector's grasps in simulation and score them by physics."""

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
        "trials", help="simulated grasp trials of a detector (physics + rectangle metric)",
        description="Simulated grasp trials of a detector. --declutter runs clutter-removal "
                    "rounds instead (VGN/GIGA protocol): grasp until the table is clear, "
                    "nothing is proposed, or 2 consecutive failures.",
    )
    p.add_argument("--detector", required=True,
                   help="random, mask-pca, oracle, a plug-in package.module:NAME (a class or "
                        "factory whose object has predict(obs); the current folder is "
                        "searched too), a name registered in the entry-point group "
                        "graspsim.detectors, or the path of a saved model")
    p.add_argument("--detector-option", action="append", default=[], metavar="KEY=VALUE",
                   dest="detector_options",
                   help="keyword argument of the plug-in's class or factory (or a built-in "
                        "detector's class), repeatable: --detector-option model=runs/net.pt "
                        "--detector-option top_k=5; VALUE is read as JSON where it parses "
                        "(5, 0.5, true, [1, 2]), else as text; recorded in config.json and in "
                        "the detector's name")
    p.add_argument("--gripper-aware", action="store_true",
                   help="keep only the detector's rectangles this gripper can execute, judged "
                        "from the depth image (opening within reach, fingers not landing on a "
                        "seen surface nor on the object's unseen surface); a DLSR model also "
                        "searches only rectangles whose jaws come down beside the object (its "
                        "grid) or openings within reach (its lattice), and ranks its best 40 "
                        "(not in the paper)")
    add_object_args(p, default="test")
    p.add_argument("--n", type=int, default=200,
                   help="number of trials (with --declutter: of rounds) (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="trial i is scene i of this seed for every detector (default: %(default)s)")
    p.add_argument("--out", required=True, help="output folder (resumes if it has trials)")
    add_executor_args(p)
    p.add_argument("--candidates", type=int, default=32,
                   help="rectangles executed to label each scene (0: no labels, no metric); "
                        "with --declutter every observation of a round is labelled "
                        "(default: %(default)s)")
    p.add_argument("--sampler", default="mixed", choices=["mixed", "dense"],
                   help="labelling candidates: mixed (centroid, chord, random) or dense "
                        "(Jacquard-like lattice, every 15 deg; --candidates is its budget)"
                        " (default: %(default)s)")
    p.add_argument("--profile", default="default", choices=sorted(PROFILES),
                   help="how scenes are seen: camera, table, lighting, depth noise "
                        "(docs/sim_settings.md; default: %(default)s)")
    p.add_argument("--objects-per-scene", type=int, default=None,
                   help="1: Cornell-like (default); >1 clutter (default 5 with --declutter, "
                        "--scene packed or --scene pile)")
    add_scene_arg(p)
    p.add_argument("--min-grip", type=float, default=None, metavar="METRES",
                   help="fingers that would meet a surface above the table on the way down "
                        "(a plate or bowl under the object) stop 2 mm short of it when their "
                        "tips still reach this far beyond the surface under the rectangle's "
                        "centre; --gripper-aware judges rectangles the same way. Off by "
                        "default (not adopted: README, 'Clutter removal'); recorded in "
                        "config.json")
    add_gripper_arg(p)
    p.add_argument("--labels", default=None, metavar="DIR",
                   help="a folder of the scenes' physics labels shared with other detectors' "
                        "trials on the same scenes (same --seed, objects and options): scenes "
                        "it holds are not labelled again, the others are added (made when "
                        "missing; the records are the same with or without it)")
    p.add_argument("--declutter", action="store_true",
                   help="clutter-removal rounds: a lifted object leaves the scene and the "
                        "detector grasps again; reports grasp success and declutter rates "
                        "(rounds.jsonl, resumed per round)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.eval.trials import TrialConfig, run_trials
    from graspsim.sim.execution import ExecutionParams

    k = objects_per_scene(args, clutter=args.declutter)
    if args.n < 0:
        raise ValueError(f"--n must be >= 0, got {args.n}")
    config = TrialConfig(n_candidates=args.candidates, n_objects=k, sampler=args.sampler,
                         profile=args.profile, scene=args.scene)
    try:
        params = ExecutionParams.with_hand(args.gripper, min_grip=args.min_grip)
    except ValueError as exc:
        raise ValueError(f"--min-grip: {exc}") from None
    from graspsim.detectors import detector_label, parse_detector_options

    options = parse_detector_options(args.detector_options)
    executor = executor_from_args(args)
    detector, name = args.detector, None
    if args.gripper_aware:
        from graspsim.detectors import gripper_aware, load_detector

        detector = gripper_aware(load_detector(args.detector, options), min_grip=args.min_grip,
                                 hand=args.gripper)
        name = f"{detector_label(args.detector, options)}+aware"
    label = name or detector_label(args.detector, options)
    kwargs = dict(detector=detector, objects=object_set_from_args(args), n=args.n, seed=args.seed,
                  out=args.out, n_jobs=args.jobs, progress=True, config=config,
                  params=params, executor=executor, detector_name=name,
                  detector_options=options or None)
    if args.declutter:
        from graspsim.eval.declutter import run_rounds

        if args.labels is not None:
            raise ValueError("--labels: clutter rounds label every observation of a round, "
                             "which depends on the detector's grasps; not with --declutter")

        s = run_rounds(**kwargs)
        print(f"{label}: grasp success {s['successes']}/{s['attempts']} = "
              f"{_pct(s['success_rate'])}, declutter rate {s['removed']}/"
              f"{s['objects_placed']} = {_pct(s['declutter_rate'])} over {s['rounds']} rounds "
              f"of {k} objects; summary in {args.out}/summary.md")
        return 0
    s = run_trials(**kwargs, labels=args.labels)
    lo, hi = s["success_ci95"]
    print(f"{label}: success {s['successes']}/{s['n']} = {_pct(s['success_rate'])} "
          f"(95 % CI {_pct(lo)}-{_pct(hi)}); summary in {args.out}/summary.md")
    return 0


def _pct(x) -> str:
    return "n/a" if x is None or x != x else f"{100 * x:.1f} %"
