"""Paired grasp trials of DLSR, dlsr-paper, mask-pca and the oracle on an object set; prints JSON.

The README's row for pybullet_data's ``random_urdfs`` test split (isolated objects):

    .venv/bin/python scripts/object_sets.py --objects random_urdfs:test --n 200 \\
        --out runs/object-sets

1. The default job's models: ``graspsim run`` with its defaults except ``offline = false``
   (the offline benchmarks do not change the models), one trial per detector on the built-in
   test objects, no baseline (``--model-run``, default ``<out>/model``; resumed when it
   exists).
2. ``--n`` trials per detector on ``--objects`` (seed ``--seed``), every detector on the same
   scenes, as the default job's trial stage runs them (32 dense labelling candidates per scene,
   DLSR's lattice search with the gripper-aware check, dlsr-paper the paper's grid search):
   ``<out>/<objects>/<detector>/``, resumed trial by trial.
3. Each detector's success with a Wilson 95 % interval, its paired difference to mask-pca
   (Newcombe interval, exact McNemar p), and the trials on objects the physics graspability
   flag (:mod:`graspsim.labels.graspability`, computed and cached when missing) marks not graspable:
   ``<out>/<objects>/table.json`` and ``table.md``.

Nothing is chosen on the trial objects: every setting is the default job's.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from graspsim.eval.compare import compare_outcomes
from graspsim.eval.stats import wilson_interval
from graspsim.eval.trials import TrialConfig, run_trials
from graspsim.pipeline import RunConfig, run_job, trial_detector
from graspsim.runtime.executor import Executor
from graspsim.sim.object_sets import parse_object_set

DETECTORS = ("dlsr", "dlsr-paper", "mask-pca", "oracle")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default="random_urdfs:test", help="object set")
    p.add_argument("--n", type=int, default=200, help="trials per detector")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/object-sets")
    p.add_argument("--detectors", default=",".join(DETECTORS))
    p.add_argument("--model-run", default=None,
                   help="run folder of the default job's models (default: <out>/model)")
    p.add_argument("--jobs", type=int, default=2, help="parallel workers")
    p.add_argument("--graspability", action="store_true",
                   help="also compute the physics graspability flags when not cached "
                        "(otherwise the not-graspable check uses the cached flags only)")
    p.add_argument("--table-only", action="store_true",
                   help="write the table of the trials finished so far, run nothing")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    names = [d.strip() for d in args.detectors.split(",") if d.strip()]
    if args.table_only:
        print(table_markdown(table_only(out, args.objects, names)))
        return 0
    config = RunConfig(offline=False, trials=1, baselines=[])  # the model run: 2 jobs
    model_run = out / "model" if args.model_run is None else Path(args.model_run)
    model_path = model_run / "model" / "dlsr"
    if any(n.startswith("dlsr") for n in names):
        run_job(config, out=model_run)
    oset = parse_object_set(args.objects)
    folder = out / args.objects.replace(":", "-").replace("/", "_")
    executor = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                        progress=True)
    trial_cfg = TrialConfig(n_candidates=config.trial_candidates, sampler=config.label_sampler)
    for name in names:
        run_trials(trial_detector(name, model_path, config), objects=oset, n=args.n,
                   seed=args.seed, out=folder / name, config=trial_cfg, executor=executor,
                   progress=True, detector_name=name, labels=folder / "labels")
    table = trial_table(folder, names, oset, args.graspability)
    (folder / "table.json").write_text(json.dumps(table, indent=1) + "\n")
    (folder / "table.md").write_text(table_markdown(table))
    print(json.dumps(table, indent=1))
    return 0


def trial_table(folder: Path, names, oset, compute: bool) -> dict:
    """Success, intervals, paired verdicts against mask-pca and the not-graspable check, on
    the trial indices every detector has finished (all of them once the runs are complete)."""
    from graspsim.labels.graspability import graspability_flags

    flags = graspability_flags(oset, compute=compute, partial=not compute)
    recs = {}
    for name in names:
        path = folder / name / "trials.jsonl"
        recs[name] = {r["index"]: r for r in map(json.loads, path.open()) if r}
    common = sorted(set.intersection(*(set(r) for r in recs.values())))
    rows = []
    for name in names:
        out = [bool(recs[name][i]["success"]) for i in common]
        k, n = sum(out), len(out)
        row = {"detector": name, "successes": k, "n": n, "rate": k / n if n else None,
               "ci95": list(wilson_interval(k, n))}
        if name != "mask-pca" and "mask-pca" in recs and n:
            c = compare_outcomes(out, [bool(recs["mask-pca"][i]["success"]) for i in common],
                                 names=(name, "mask-pca"))
            row["vs_mask_pca"] = {k_: c[k_] for k_ in ("n", "counts", "difference",
                                                       "difference_ci", "mcnemar_p", "better")}
        objs = [recs[name][i]["object"] for i in common]
        known = [i for i, o in zip(common, objs, strict=True)
                 if flags is not None and all(x in flags for x in o)]
        bad = [i for i in known if not all(flags[x] for x in recs[name][i]["object"])]
        row["trials_with_flags"] = len(known)
        row["not_graspable_trials"] = len(bad)
        row["not_graspable_successes"] = sum(bool(recs[name][i]["success"]) for i in bad)
        rows.append(row)
    return {"objects": oset.text, "fingerprint": oset.fingerprint(), "indices": len(common),
            "rows": rows, "flags": None if flags is None else {
                "n_objects": len(flags), "graspable": sum(flags.values())}}


def table_markdown(t: dict) -> str:
    lines = [f"Object set `{t['objects']}` (fingerprint {t['fingerprint'][:12]}), "
             f"{t['indices']} paired trials", "",
             "| detector | success | 95 % interval | vs mask-pca (paired, Newcombe 95 %, exact "
             "McNemar) | successes on objects not graspable by physics |",
             "|---|---|---|---|---|"]
    for r in t["rows"]:
        lo, hi = r["ci95"]
        v = r.get("vs_mask_pca")
        verdict = "" if v is None else (
            f"{100 * v['difference']:+.1f} [{100 * v['difference_ci'][0]:+.1f}, "
            f"{100 * v['difference_ci'][1]:+.1f}], p = {v['mcnemar_p']:.2g}")
        ng = (f"{r['not_graspable_successes']}/{r['not_graspable_trials']} "
              f"({r['trials_with_flags']} trials with a flag)")
        lines.append(f"| {r['detector']} | {r['successes']}/{r['n']} = {100 * r['rate']:.1f} % "
                     f"| [{100 * lo:.1f}, {100 * hi:.1f}] | {verdict} | {ng} |")
    return "\n".join(lines) + "\n"


def table_only(out: Path, objects: str, names) -> dict:
    """The table of finished trials (no new trial)."""
    oset = parse_object_set(objects)
    folder = out / objects.replace(":", "-").replace("/", "_")
    table = trial_table(folder, names, oset, False)
    (folder / "table.json").write_text(json.dumps(table, indent=1) + "\n")
    (folder / "table.md").write_text(table_markdown(table))
    return table


if __name__ == "__main__":
    sys.exit(main())
