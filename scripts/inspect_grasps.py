"""Replay a trial folder's rectangles and print what the object and the pads do in each phase.

For harness diagnoses (why a thin object slips, what a collision hits): trial ``i``'s scene is
rebuilt (:func:`graspsim.sim.observe.observe_scene`), its recorded rectangle executed with the
current
harness and the folder's execution parameters, and at the end of each phase (pregrasp, approach,
close, lift, hold) one JSON line per trial records, in the gripper frame (x closing, z approach,
TCP at 0, fingertips at +10 mm, palm at -40 mm): the object's roll about its own x axis and tilt
since the start (degrees), its height (m), its centre (mm), the opening between the pads (mm), and
per pad (0, 1) the contact points with the object (mm) and their summed normal force (N); at the
approach, every contact of the gripper (``palm`` or ``finger0/1``, with ``object`` or ``table``).

    .venv/bin/python scripts/inspect_grasps.py runs/default/trials/mask-pca \\
        --objects chopstick [--tip-clearance 0.001] [--out chopstick.jsonl]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dlsr.records import read_jsonl
from dlsr.rectangles import GraspRectangle
from graspsim.eval.trials import campaign_execution_params
from graspsim.labels.graspability import resolve_objects
from graspsim.sim.bullet import Simulation
from graspsim.sim.execution import execute_grasp, harness_grasps
from graspsim.sim.observe import observe_scene
from graspsim.sim.scene import build_scene


def _mm(v) -> list[float]:
    return [round(1000.0 * float(x), 1) for x in v]


def inspect_trial(sim, specs, seed: int, index: int, n_objects: int, rect, params) -> dict:
    """Execute one recorded rectangle in its rebuilt scene; the per-phase record (see above)."""
    scene, _, frame, _ = observe_scene(sim, specs, seed, index, n_objects)
    grasp = harness_grasps([GraspRectangle(*rect)], frame, scene.table_z, params)[0]
    bodies = build_scene(sim, scene)
    c = sim.client
    q0 = [Rotation.from_quat(c.getBasePositionAndOrientation(b)[1]) for b in bodies.objects]
    phases = {}

    def record(phase):
        gripper = c.getBodyUniqueId(c.getNumBodies() - 1)  # loaded last
        g_pos, g_q = c.getBasePositionAndOrientation(gripper)
        to_grip = Rotation.from_quat(g_q).inv()
        # the object nearest the TCP
        k = int(np.argmin([np.linalg.norm(np.subtract(c.getBasePositionAndOrientation(b)[0],
                                                      g_pos)) for b in bodies.objects]))
        body = bodies.objects[k]
        pos, q = c.getBasePositionAndOrientation(body)
        rv = (q0[k].inv() * Rotation.from_quat(q)).as_rotvec()
        pads = {}
        for j in (0, 1):
            cps = c.getContactPoints(bodyA=gripper, bodyB=body, linkIndexA=j)
            pads[j] = {"points_mm": [_mm(to_grip.apply(np.subtract(cp[5], g_pos))) for cp in cps],
                       "force_N": round(sum(cp[9] for cp in cps), 2)}
        out = {"object": scene.objects[k].spec.name,
               "roll_deg": round(float(np.degrees(rv[0])), 1),
               "tilt_deg": round(float(np.degrees(np.linalg.norm(rv[1:]))), 1),
               "height_m": round(float(pos[2]), 4),
               "centre_mm": _mm(to_grip.apply(np.subtract(pos, g_pos))),
               "opening_mm": round(1000.0 * sum(c.getJointState(gripper, j)[0] for j in (0, 1)),
                                   2),
               "pads": pads}
        if phase == "approach":
            out["contacts"] = [
                {"link": "palm" if cp[3] == -1 else f"finger{cp[3]}",
                 "with": "object" if cp[2] in bodies.objects else "table",
                 "at_mm": _mm(to_grip.apply(np.subtract(cp[5], g_pos)))}
                for cp in c.getContactPoints(bodyA=gripper)]
        phases[phase] = out

    res = execute_grasp(sim, scene, bodies, grasp, params, record)
    return {"index": index, "reason": res.reason, "opening_m": round(grasp.opening, 4),
            "lift_height_m": round(res.lift_height, 4), "phases": phases}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="a trial folder (config.json, trials.jsonl)")
    p.add_argument("--objects", default=None, help="only scenes of these objects (comma list)")
    p.add_argument("--tip-clearance", type=float, default=None, help="metres")
    p.add_argument("--out", type=Path, default=None, help="write the JSON lines here too")
    args = p.parse_args(argv)
    cfg_path = args.folder / "config.json"
    if not cfg_path.exists():
        p.error(f"{cfg_path}: not found (not a trial folder)")
    cfg = json.loads(cfg_path.read_text())
    records = {int(r["index"]): r for r in read_jsonl(args.folder / "trials.jsonl")}
    keep = None if args.objects is None else set(args.objects.split(","))
    params = campaign_execution_params(args.folder)
    if args.tip_clearance is not None:
        params = dataclasses.replace(params, tip_clearance=args.tip_clearance)
    sim = Simulation()
    specs = resolve_objects(cfg["objects"])
    out = open(args.out, "w") if args.out is not None else None
    try:
        for i, rec in sorted(records.items()):
            if rec["rectangle"] is None or (keep is not None
                                            and not keep.intersection(rec["object"])):
                continue
            row = inspect_trial(sim, specs, cfg["seed"], i, cfg["config"]["n_objects"],
                                rec["rectangle"], params)
            row["recorded_reason"] = rec["reason"]
            line = json.dumps(row)
            print(line)
            if out is not None:
                out.write(line + "\n")
                out.flush()
    finally:
        if out is not None:
            out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
