"""Benchmark the simulation harness; prints JSON.

Measures render ms per frame (Kinect-like noise on), seconds per single-object grasp trial (one
worker), trials per second on 2 cores, and labelled rectangles per second (one worker and
2 cores). Targets (issue 5): >= 4 single-object trials/s on 2 cores, >= 20 labelled rect/s.

Reference in the same run: the same physics-labelled positive grasps executed with VGN-like
slow motions (approach at 5 cm/s, lift at 10 cm/s, as a careful arm trajectory would move)
instead of the brisk constraint motions: time per grasp, and the share that still succeeds
(the brisk motions should not change outcomes).

    .venv/bin/python scripts/bench_sim.py [--trials 32] [--scenes 8] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from graspsim.eval.trials import TrialConfig, run_trials
from graspsim.labels.graspability import resolve_objects
from graspsim.labels.labelling import label_rectangles, sample_candidates
from graspsim.sim.bullet import Simulation
from graspsim.sim.execution import ExecutionParams, harness_grasps, run_grasp
from graspsim.sim.observe import observe_scene, trial_streams
from graspsim.sim.scene import build_scene, capture, make_scene


def render_ms(specs, n=10):
    sim = Simulation()
    times, clean = [], []
    from graspsim.sim.camera import Camera

    for i in range(n):
        st = trial_streams(123, i)
        scene = make_scene(sim, specs, st["scene"])
        bodies = build_scene(sim, scene)
        t = time.perf_counter()
        frame = capture(sim, scene, bodies, st["camera"])
        times.append(time.perf_counter() - t)
        t = time.perf_counter()
        Camera(sim.client, frame.intrinsics).render_clean(frame.T_world_cam)
        clean.append(time.perf_counter() - t)
    sim.close()
    return 1000 * float(np.median(times)), 1000 * float(np.median(clean))


def label_rate(specs, n_scenes, n_candidates=32):
    """Labelling speed on one worker; also returns the positives for the motion reference."""
    sim = Simulation()
    n_rects, n_exec, seconds, positives = 0, 0, 0.0, []
    for i in range(n_scenes):
        scene, bodies, frame, st = observe_scene(sim, specs, 321, i)
        cands = sample_candidates(frame.segmentation, bodies.objects, st["label"], n_candidates,
                                  depth=frame.depth_clean)
        t = time.perf_counter()
        lab = label_rectangles(sim, scene, frame, cands)
        seconds += time.perf_counter() - t
        n_rects += len(cands)
        n_exec += sum(r.steps > 0 for r in lab.results)
        positives += [(scene, frame, r) for r in lab.positives[:3]]
    sim.close()
    return n_rects / seconds, n_exec / max(n_rects, 1), n_exec / seconds, positives


def motion_reference(positives):
    """The same successful grasps executed with brisk and with slow (VGN-like) motions."""
    sim = Simulation()
    out = {}
    for name, params in (("fast", ExecutionParams()),
                         ("slow", ExecutionParams(approach_speed=0.05, lift_speed=0.10))):
        t = time.perf_counter()
        ok = []
        for scene, frame, rect in positives:
            g = harness_grasps([rect], frame, scene.table_z, params)[0]
            ok.append(run_grasp(sim, scene, g, params).success)
        out[name] = ((time.perf_counter() - t) / max(len(positives), 1), np.array(ok))
    sim.close()
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=32)
    p.add_argument("--scenes", type=int, default=8)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--objects", default="test")
    args = p.parse_args(argv)
    specs = resolve_objects(args.objects)
    out = {"objects": args.objects}
    out["render_ms_per_frame"], out["render_clean_ms_per_frame"] = render_ms(specs)

    no_labels = TrialConfig(n_candidates=0)
    t = time.perf_counter()
    one = run_trials("mask-pca", specs, n=args.trials // 2, seed=0, config=no_labels)
    out["seconds_per_trial_1_worker"] = (time.perf_counter() - t) / (args.trials // 2)
    out["trial_success_rate_mask_pca"] = one["success_rate"]
    t = time.perf_counter()
    run_trials("mask-pca", specs, n=args.trials, seed=1, n_jobs=args.jobs, config=no_labels)
    wall = time.perf_counter() - t
    out[f"trials_per_second_{args.jobs}_cores"] = args.trials / wall

    rate, frac, exec_rate, positives = label_rate(specs, args.scenes)
    out["labelled_rects_per_second_1_worker"] = rate
    out["labelled_fraction_executed_in_physics"] = frac
    out["physically_executed_rects_per_second_1_worker"] = exec_rate
    t = time.perf_counter()
    lab = run_trials("random", specs, n=args.scenes * 2, seed=2, n_jobs=args.jobs,
                     config=TrialConfig(n_candidates=32))
    wall = time.perf_counter() - t
    out[f"labelled_rects_per_second_{args.jobs}_cores"] = (
        sum(r["n_labelled"] for r in lab["records"]) / wall)

    ref = motion_reference(positives)
    out["reference_grasps"] = len(positives)
    out["seconds_per_successful_grasp_fast_motion"] = ref["fast"][0]
    out["reference_seconds_per_successful_grasp_slow_motion"] = ref["slow"][0]
    out["speedup_vs_slow_motion"] = ref["slow"][0] / ref["fast"][0]
    out["slow_motion_also_succeeds"] = float(ref["slow"][1].mean()) if len(positives) else None
    out["targets"] = {
        "trials_per_second_2_cores": 4.0, "labelled_rects_per_second": 20.0,
        "met": bool(out.get("trials_per_second_2_cores", 0) >= 4.0
                    and out.get("labelled_rects_per_second_2_cores", 0) >= 20.0),
    }
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()},
                     indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
