"""Benchmark physics labelling: the fast path against the reference execution; prints JSON.

Both paths label the same candidates (by default dense, ``sample_candidates(..., mode="dense")``
with a budget per scene; ``--sampler mixed`` for the mixed sampler) of the same seeded scenes
of the train objects:

* reference: every candidate executed by :func:`graspsim.sim.execution.run_grasp` (scene rebuilt,
  full motion sequence), i.e. ``label_rectangles(..., fast=False)``;
* fast: ``label_rectangles(..., fast=True)`` (geometric precheck of collisions and empty
  closes in one built scene, hold ending once the object is still).

Reported for each: labelled grasps per second (wall) and CPU seconds per grasp
(``time.process_time``, less sensitive to other load on the machine) in one process and with
``--jobs`` worker processes (scenes spread over them), plus the agreement of the verdicts
(success and failure reason) grasp by grasp. Every dense candidate is within the gripper's
reach, so every labelled grasp is a decided or executed one (none skipped as too wide; the
mixed sampler's too-wide candidates are labelled without execution).

    .venv/bin/python scripts/bench_labelling.py [--scenes 8] [--budget 64] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import time

from graspsim.labels.graspability import resolve_objects
from graspsim.labels.labelling import label_rectangles, sample_candidates
from graspsim.runtime.executor import Executor
from graspsim.sim.bullet import worker_sim
from graspsim.sim.observe import observe_scene


def label_scene(seed, index, budget, fast, mode="dense", objects="train"):
    """Label one scene's dense candidates; returns verdicts, wall and CPU seconds, physics count."""
    sim = worker_sim()  # one simulator per process
    t0 = time.perf_counter()
    scene, bodies, frame, st = observe_scene(sim, resolve_objects(objects), seed, index)
    cands = sample_candidates(frame.segmentation, bodies.objects, st["label"], budget,
                              depth=frame.depth_clean, mode=mode, intrinsics=frame.intrinsics)
    t, c = time.perf_counter(), time.process_time()
    lab = label_rectangles(sim, scene, frame, cands, fast=fast)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    verdicts = [(bool(r.success), r.reason) for r in lab.results]
    stepped = sum(r.steps > 0 for r in lab.results)
    return verdicts, wall, cpu, stepped, time.perf_counter() - t0


def _warm_up(j):
    worker_sim()
    return j


def run(seed, scenes, budget, fast, jobs, mode):
    """Label ``scenes`` scenes in 1 or ``jobs`` processes.

    ``grasps_per_second_labelling``: grasps over the time spent in ``label_rectangles`` (one
    process only); ``grasps_per_second_end_to_end``: grasps over the wall time of the whole run
    (scene making, rendering, sampling and labelling; with workers, spread over them).
    """
    tasks = [(seed, i, budget, fast, mode) for i in range(scenes)]
    if jobs == 1:
        parts = [label_scene(*a) for a in tasks]
        wall = sum(p[4] for p in parts)
    else:
        ex = Executor(backend="loky", n_jobs=jobs, progress=False)
        list(ex.imap(_warm_up, [(j,) for j in range(jobs)], star=True))  # start the workers
        t = time.perf_counter()
        parts = list(ex.imap(label_scene, tasks, star=True))
        wall = time.perf_counter() - t
    verdicts = [v for p in parts for v in p[0]]
    n = len(verdicts)
    rates = {"grasps_per_second_end_to_end": round(n / wall, 2)}
    if jobs == 1:
        rates["grasps_per_second_labelling"] = round(n / sum(p[1] for p in parts), 2)
    return verdicts, {
        "grasps": n,
        **rates,
        "cpu_ms_per_grasp": round(1000 * sum(p[2] for p in parts) / n, 3),
        "executed_in_physics": int(sum(p[3] for p in parts)),
        "successes": int(sum(v[0] for v in verdicts)),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=8)
    p.add_argument("--budget", type=int, default=64, help="dense candidates per scene")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--sampler", choices=("dense", "mixed"), default="dense",
                   help="candidates: dense (all within reach) or the mixed sampler (some too "
                   "wide: labelled without execution)")
    args = p.parse_args(argv)
    out = {"scenes": args.scenes, "budget": args.budget, "seed": args.seed,
           "objects": "train", "sampler": args.sampler,
           "note": "wall figures taken on a machine shared with other jobs; cpu_ms_per_grasp "
           "is process time (in the workers for --jobs > 1)"}
    a = (args.seed, args.scenes, args.budget)
    ref, out["reference_1_process"] = run(*a, False, 1, args.sampler)
    new, out["fast_1_process"] = run(*a, True, 1, args.sampler)
    if args.jobs > 1:
        ref2, out[f"reference_{args.jobs}_workers"] = run(*a, False, args.jobs, args.sampler)
        new2, out[f"fast_{args.jobs}_workers"] = run(*a, True, args.jobs, args.sampler)
        out["workers_give_the_same_verdicts"] = bool(ref2 == ref and new2 == new)
    same = [a == b for a, b in zip(ref, new, strict=True)]
    out["verdict_agreement"] = round(sum(same) / len(same), 4)
    out["success_agreement"] = round(
        sum(a[0] == b[0] for a, b in zip(ref, new, strict=True)) / len(ref), 4)
    out["disagreements"] = [{"reference": a, "fast": b}
                            for a, b in zip(ref, new, strict=True) if a != b]
    out["speedup_cpu_1_process"] = round(out["reference_1_process"]["cpu_ms_per_grasp"]
                                         / out["fast_1_process"]["cpu_ms_per_grasp"], 2)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
