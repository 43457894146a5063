"""Label coverage: do the physics-labelled positives cover the grasps that work? Prints JSON.

For each seeded single-object scene of the train objects, independently sampled candidates
(the mixed sampler of ``sample_candidates``, ``--reference`` per scene, from a generator
stream of their own) are executed and their successes kept as the reference "physically good
grasps". Each labelling under test labels the same scene from the trial's own label stream:

* ``mixed``: the current sampler, ``--mixed-n`` candidates per scene (48 as in ``graspsim
  dataset``);
* ``dense``: ``sample_candidates(..., mode="dense")`` with each budget of ``--budgets``
  (0 = the whole lattice).

Coverage is the fraction of reference successes that the labelled positives match by the
rectangle metric (angle within 30 degrees and Jaccard index above 0.25,
:func:`dlsr.metrics.rectangle_metric_many`), pooled over scenes; scenes without a reference
success do not count. All grasps go through ``label_rectangles`` (fast path).

    .venv/bin/python scripts/label_coverage.py [--scenes 20] [--seed 5] [--budgets 128 256 0]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dlsr.metrics import rectangle_metric_many
from graspsim.labels.graspability import resolve_objects
from graspsim.labels.labelling import label_rectangles, sample_candidates
from graspsim.runtime.executor import Executor
from graspsim.sim.bullet import worker_sim
from graspsim.sim.observe import observe_scene


def scene_coverage(seed, index, n_reference, mixed_n, budgets):
    """Reference successes of one scene and, per labelling, how many its positives cover."""
    sim = worker_sim()
    scene, bodies, frame, st = observe_scene(sim, resolve_objects("train"), seed, index)
    ref_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index, 1 << 20)))
    ref = sample_candidates(frame.segmentation, bodies.objects, ref_rng, n_reference,
                            depth=frame.depth_clean)
    ref_pos = label_rectangles(sim, scene, frame, ref).positives
    out = {"index": index, "object": scene.objects[0].spec.name,
           "reference_candidates": len(ref), "reference_successes": len(ref_pos)}
    labellings = [("mixed", None)] + [(f"dense_{b or 'all'}", b) for b in budgets]
    for name, budget in labellings:
        rng = np.random.default_rng(st["label"].bit_generator.seed_seq)  # same stream each
        if budget is None:
            cands = sample_candidates(frame.segmentation, bodies.objects, rng, mixed_n,
                                      depth=frame.depth_clean)
        else:
            cands = sample_candidates(frame.segmentation, bodies.objects, rng, budget or None,
                                      depth=frame.depth_clean, mode="dense",
                                      intrinsics=frame.intrinsics)
        t = time.process_time()
        pos = label_rectangles(sim, scene, frame, cands).positives
        cpu = time.process_time() - t
        covered = (int(rectangle_metric_many(ref_pos, pos).sum()) if ref_pos and pos else 0)
        out[name] = {"labelled": len(cands), "positives": len(pos), "covered": covered,
                     "cpu_seconds": round(cpu, 3)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--reference", type=int, default=96, help="reference candidates per scene")
    p.add_argument("--mixed-n", type=int, default=48)
    p.add_argument("--budgets", type=int, nargs="+", default=[128, 256, 0],
                   help="dense budgets per scene (0: the whole lattice)")
    p.add_argument("--jobs", type=int, default=1)
    args = p.parse_args(argv)
    tasks = [(args.seed, i, args.reference, args.mixed_n, args.budgets)
             for i in range(args.scenes)]
    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=False)
    t = time.perf_counter()
    scenes = list(ex.imap(scene_coverage, tasks, star=True))
    names = ["mixed"] + [f"dense_{b or 'all'}" for b in args.budgets]
    n_ref = sum(s["reference_successes"] for s in scenes)
    summary = {}
    for name in names:
        cov = sum(s[name]["covered"] for s in scenes)
        lab = sum(s[name]["labelled"] for s in scenes)
        summary[name] = {
            "coverage": round(cov / n_ref, 4) if n_ref else None,
            "covered": cov,
            "labelled_per_scene": round(lab / len(scenes), 1),
            "positives_per_scene": round(sum(s[name]["positives"] for s in scenes)
                                         / len(scenes), 1),
            "cpu_ms_per_labelled_grasp": round(
                1000 * sum(s[name]["cpu_seconds"] for s in scenes) / max(lab, 1), 2),
        }
    print(json.dumps({
        "seed": args.seed, "scenes": args.scenes, "objects": "train",
        "reference_candidates_per_scene": args.reference,
        "reference_successes": n_ref,
        "summary": summary,
        "seconds": round(time.perf_counter() - t, 1),
        "per_scene": scenes,
    }, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
