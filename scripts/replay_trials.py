"""Re-execute the rectangles of finished trial folders in their rebuilt scenes; prints JSON.

Paired harness experiments: trial ``i`` of every folder of one run (same seed and objects) is the
same scene, rebuilt exactly by :func:`graspsim.sim.observe.observe_scene`; each folder's recorded
rectangle is turned into a grasp and executed again with the current harness and the execution
parameters the folder recorded (``config.json``), optionally with one execution or grasp
parameter changed. The oracle's rectangles are replayed as recorded (they
were labelled under the harness of the original run). Printed: per folder, successes and failure
reasons, and the trials gained and lost against the recorded outcomes.

    .venv/bin/python scripts/replay_trials.py runs/default/trials/{dlsr,mask-pca,oracle} \\
        [--objects chopstick,bottle_wine] [--tip-clearance 0.003] [--margin 0.01] \\
        [--depth-offset 0.015] [--out replay.json]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
from pathlib import Path

from dlsr.records import read_jsonl
from dlsr.rectangles import GraspRectangle
from graspsim.eval.trials import campaign_execution_params
from graspsim.labels.graspability import resolve_objects
from graspsim.sim.bullet import Simulation
from graspsim.sim.execution import harness_grasps, run_grasp
from graspsim.sim.observe import observe_scene


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path, help="trial folders of one run")
    p.add_argument("--objects", default=None, help="only scenes of these objects (comma list)")
    p.add_argument("--tip-clearance", type=float, default=None, help="metres")
    p.add_argument("--margin", type=float, default=None, help="metres")
    p.add_argument("--depth-offset", type=float, default=None, help="metres")
    p.add_argument("--out", type=Path, default=None, help="per-trial outcomes (JSON)")
    args = p.parse_args(argv)

    configs, records = [], {}
    for f in args.folders:
        cfg = f / "config.json"
        if not cfg.exists():
            p.error(f"{cfg}: not found (not a trial folder)")
        configs.append(json.loads(cfg.read_text()))
        # Read only (graspsim.runtime.campaign.read_done would rewrite a torn file).
        records[f.name] = {int(r["index"]): r for r in read_jsonl(f / "trials.jsonl")}
    keys = {(c["seed"], json.dumps(c["objects"]), c["config"]["n_objects"]) for c in configs}
    if len(keys) != 1:
        p.error("the folders come from runs with different seeds, objects or objects per scene")
    seed, objects, n_objects = configs[0]["seed"], configs[0]["objects"], \
        configs[0]["config"]["n_objects"]
    keep = None if args.objects is None else set(args.objects.split(","))
    params = {f.name: campaign_execution_params(f) for f in args.folders}
    if args.tip_clearance is not None:
        params = {k: dataclasses.replace(v, tip_clearance=args.tip_clearance)
                  for k, v in params.items()}
    gkw = {k: v for k, v in (("margin", args.margin), ("depth_offset", args.depth_offset))
           if v is not None}

    sim = Simulation()
    specs = resolve_objects(objects)
    common = sorted(set.intersection(*(set(r) for r in records.values())))
    outcomes = {name: {} for name in records}
    for i in common:
        names = next(iter(records.values()))[i]["object"]
        if keep is not None and not keep.intersection(names):
            continue
        scene, _, frame, _ = observe_scene(sim, specs, seed, i, n_objects)
        for name, recs in records.items():
            rect = recs[i]["rectangle"]
            if rect is None:
                outcomes[name][i] = recs[i]["reason"]
                continue
            g = harness_grasps([GraspRectangle(*rect)], frame, scene.table_z, params[name],
                               **gkw)[0]
            outcomes[name][i] = run_grasp(sim, scene, g, params[name]).reason

    summary = {}
    for name, out in outcomes.items():
        rec = records[name]
        summary[name] = {
            "trials": len(out),
            "success": sum(r is None for r in out.values()),
            "recorded_success": sum(rec[i]["success"] for i in out),
            "gained": sorted(i for i, r in out.items() if r is None and not rec[i]["success"]),
            "lost": sorted(i for i, r in out.items() if r is not None and rec[i]["success"]),
            "reasons": dict(collections.Counter(str(r) for r in out.values())),
        }
    result = {"seed": seed, "objects": objects, "tip_clearance": args.tip_clearance,
              **gkw, "folders": summary}
    print(json.dumps(result, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps({n: {str(i): r for i, r in o.items()}
                                        for n, o in outcomes.items()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
