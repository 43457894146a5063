"""Choose K, the settled poses a graspability flag is measured in, on train objects; prints JSON.

For the built-in train objects and every 15th object of pybullet_data's random_urdfs train
split (60 objects), the dense physics labeller searches up to 16 settled poses for a successful
grasp (:func:`graspsim.labels.graspability.measure_graspability`; each object stops at its first
success, so the first pose with a success is known). The flags at K = 1, 2, 4, 8 and 16 follow,
and the objects whose flag changes between consecutive K. The test splits are not used.

    .venv/bin/python scripts/graspability_poses.py [--jobs 2] [--cache objects/graspability.json]
    .venv/bin/python scripts/graspability_poses.py --explain book,plate   # the first success

``--explain`` rebuilds each named built-in object's first pose with a success (from the cache)
and prints how it rests (the body axis pointing up, its height) and the grasp that lifted it
(the rectangle's opening at the grasp depth, the grasp's height above the table).

Resumes: measured objects are cached (``--cache``, default the user's cache).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from graspsim.labels.graspability import measure_graspability
from graspsim.runtime.executor import Executor
from graspsim.sim.objects import builtin_objects, random_urdf_objects

KS = (1, 2, 4, 8, 16)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--cache", default=None, help="manifest written (default: the user's)")
    p.add_argument("--every", type=int, default=15, help="every n-th random_urdfs train object")
    p.add_argument("--explain", default=None, metavar="NAMES",
                   help="comma-separated built-in objects: describe their first success")
    args = p.parse_args(argv)
    if args.explain:
        print(json.dumps([explain(n) for n in args.explain.split(",")], indent=1))
        return 0
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=True)
    sets = {"builtin:train": builtin_objects("train"),
            "random_urdfs:train": random_urdf_objects("train")[::args.every]}
    report = {}
    for label, specs in sets.items():
        out = measure_graspability(specs, max(KS), executor=ex,
                                   cache=None if args.cache is None else Path(args.cache))
        flags = {k: {n: e["first_success"] is not None and e["first_success"] < k
                     for n, e in out.items()} for k in KS}
        report[label] = {
            "n_objects": len(specs),
            "graspable_at": {k: sum(f.values()) for k, f in flags.items()},
            "changed": {f"{a}->{b}": sorted(n for n in flags[a] if flags[a][n] != flags[b][n])
                        for a, b in zip(KS, KS[1:], strict=False)},
            "first_success": {n: e["first_success"] for n, e in out.items()},
        }
    print(json.dumps(report, indent=1))
    return 0


def explain(name: str) -> dict:
    """How ``name`` rests in its first pose with a success, and the grasp that lifted it."""
    import numpy as np

    from graspsim.labels import graspability as g
    from graspsim.labels.labelling import label_rectangles
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.scene import build_scene, capture, make_scene

    spec = next(s for s in builtin_objects("all") if s.name == name)
    entry = g._read_entries(g.gripper_key()).get(g.object_key(spec))
    if entry is None or entry["first_success"] is None:
        return {"name": name, "first_success": None if entry is None else entry}
    pose = entry["first_success"]
    ss = np.random.SeedSequence(g.SEED, spawn_key=(int(g.object_key(spec)[:8], 16), pose))
    scene_ss, cam_ss, cand_ss = ss.spawn(3)
    sim = Simulation()
    try:
        scene = make_scene(sim, [spec], np.random.default_rng(scene_ss), n_objects=1)
        bodies = build_scene(sim, scene)
        frame = capture(sim, scene, bodies, np.random.default_rng(cam_ss))
        rng = np.random.default_rng(cand_ss)
        cands = g.dense_candidates(frame.segmentation, bodies.objects, rng, frame.depth_clean,
                                   frame.intrinsics)
        order = rng.permutation(len(cands))[:g.BUDGET]
        lo, hi = sim.client.getAABB(bodies.objects[0])
        R = np.array(sim.client.getMatrixFromQuaternion(scene.objects[0].orientation)).reshape(3, 3)
        up = int(np.argmax(np.abs(R[2])))
        for start in range(0, len(order), g.CHUNK):
            chunk = [cands[i] for i in order[start:start + g.CHUNK]]
            lab = label_rectangles(sim, scene, frame, chunk, depth=frame.depth_clean,
                                   depth_valid=frame.depth_clean > 0)
            hits = [i for i, r in enumerate(lab.results) if r.success]
            if hits:
                from graspsim.sim.execution import harness_grasps

                grasp = harness_grasps([chunk[hits[0]]], frame, scene.table_z,
                                       depth=frame.depth_clean,
                                       depth_valid=frame.depth_clean > 0)[0]
                return {"name": name, "pose": pose, "up_axis": "xyz"[up],
                        "resting_extent": [round(float(h - l), 3) for l, h in zip(lo, hi,
                                                                                  strict=True)],
                        "grasp_width": round(float(grasp.width), 3),
                        "grasp_height": round(float(grasp.T_world_grasp[2, 3]
                                                    - scene.table_z), 3)}
        return {"name": name, "pose": pose, "found": False}
    finally:
        sim.close()


if __name__ == "__main__":
    sys.exit(main())
