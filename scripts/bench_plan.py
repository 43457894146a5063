"""Plan time of each detector of ``graspsim run``'s trials (one JSON object on stdout).

The detectors are built as the trial stage builds them from a run configuration's defaults
(:class:`graspsim.pipeline.RunConfig`): ``dlsr`` (the lattice detector made aware of the hand,
with the model's physical term), ``dlsr-paper`` (the paper's dense grid search), ``mask-pca``
and, when torch is importable and a model is given, GG-CNN. Each plans on the observations of
the first ``--scenes`` test scenes of ``--seed`` (the trials' own scenes and camera), each
detector in its own process (none finds another's table fits in the memo); the plan time of a
scene is the wall time of ``predict`` (what the trial records as ``planning_seconds``), the
median over ``--rounds`` rounds, after one call on the next scene to warm up; the median and
95th percentile are over the scenes.

The reference: ``--reference DIR``, a checkout of the code before the change (e.g. ``git
worktree add /tmp/base <commit>``). This script then runs a worker process on that code
(``PYTHONPATH=DIR``) beside one on this checkout, round after round in turn, so that both see
the same load, on the same observations (written once to a temporary file); it reports the
reference's plan times of ``dlsr`` and ``dlsr-paper`` (both rank by DLSR's exact scores)
beside the new ones, and whether both codes propose the same rectangles in the same order on
every scene (``identical_proposals``; ``max_score_difference``: of the scores of the proposed
rectangles, beside ``largest_score``). ``plan_cpu_seconds``: the process's CPU seconds per plan
(all its threads), less sensitive than wall time to other work on a shared machine.

``--scene pile --objects-per-scene 5 --objects ycb:test --paper full`` times the clutter
rounds' first observations with ``dlsr-paper`` built as ``scripts/hands_ycb.py`` builds it.

Usage: python scripts/bench_plan.py [--scenes 20] [--seed 0] [--rounds 3]
       [--model results/ggcnn-curve/models/dlsr_300]
       [--ggcnn results/ggcnn-curve/models/ggcnn_300.pt] [--hand builtin]
       [--reference /tmp/base] [--detectors dlsr,dlsr-paper,mask-pca,ggcnn]
       [--objects test] [--scene drop] [--objects-per-scene 1] [--paper run]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("rgb", "depth", "depth_valid", "K", "T_world_cam", "seed")


def observations(n, seed, path, objects="test", scene="drop", n_objects=1):
    """The first ``n`` scenes' observations of ``seed``, written to ``path`` (npz): ``scene``
    (``drop``, ``pile``, ``packed``) of ``n_objects`` of ``objects``, as the trials and the
    clutter rounds (:mod:`graspsim.eval.declutter`, their first attempt) observe them; a scene
    that cannot be made is passed over, as the rounds do."""
    from graspsim.labels.graspability import resolve_objects
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.observe import SceneError, observation, observe_scene

    sim = Simulation()
    arrays = {}
    try:
        specs = resolve_objects(objects)
        i = j = 0
        while j < n:
            try:
                _, _, frame, _ = observe_scene(sim, specs, seed, i, n_objects, None, scene)
            except SceneError:
                i += 1
                continue
            for k, v in observation(frame, 0).items():
                arrays[f"{j}/{k}"] = np.asarray(v)
            i += 1
            j += 1
    finally:
        sim.close()
    np.savez(path, **arrays)


def _load(path):
    d = np.load(path)
    n = len({k.split("/")[0] for k in d.files})
    out = []
    for i in range(n):
        o = {k: d[f"{i}/{k}"] for k in KEYS}
        o["seed"] = int(o["seed"])
        out.append(o)
    return out


def _detectors(names, model, ggcnn, hand, paper="run"):
    """The trial stage's detectors (``graspsim run``'s defaults), by name; ``paper="full"``
    builds ``dlsr-paper`` as ``scripts/hands_ycb.py`` does (the full grid, the model's saved
    options)."""
    from dlsr.detection import DLSRDetector
    from graspsim.detectors import load_detector
    from graspsim.detectors.dlsr_options import DetectorOptions, build_real_detector
    from graspsim.pipeline import RunConfig

    config = RunConfig()
    out = {}
    for name in names:
        if name == "dlsr":
            opts = DetectorOptions(detector=config.detector,
                                   complete_region=config.complete_region,
                                   physical=config.physical, gripper_aware=config.gripper_aware,
                                   clear_jaws=config.clear_jaws)
            out[name] = build_real_detector(DLSRDetector.load(model), opts,
                                            rescore=config.rescore,
                                            coarse_to_fine=config.coarse_to_fine, hand=hand)
        elif name == "dlsr-paper":
            path = Path(model).with_name(Path(model).name.replace("dlsr", "dlsr-paper"))
            if paper == "full":
                out[name] = DLSRDetector.load(path).detector("dense")
            else:
                out[name] = DLSRDetector.load(path).detector(
                    "dense", coarse_to_fine=config.coarse_to_fine, rescore=config.rescore)
        elif name == "ggcnn":
            try:
                import torch  # noqa: F401
            except ImportError:
                continue
            if ggcnn and Path(ggcnn).exists():
                out[name] = load_detector(ggcnn)
        else:
            out[name] = load_detector(name)
    return out


#: The detectors whose proposals are compared with the reference's (both use DLSR's exact
#: scores: the lattice's 192 candidates, the dense search's rescored best).
COMPARED = ("dlsr", "dlsr-paper")


def worker(obs_path, names, model, ggcnn, hand, paper="run"):
    """Plan every scene once with each detector: wall and process CPU seconds, and the DLSR
    detectors' proposals and scores."""
    obs = _load(obs_path)
    dets = _detectors(names, model, ggcnn, hand, paper)
    out = {}
    for name, det in dets.items():
        det.predict(obs[-1])  # warm up (compiled kernels, model files) on a scene not timed
        seconds, cpu, rects, scores = [], [], [], []
        for o in obs[:-1]:
            t0, c0 = time.perf_counter(), time.process_time()
            det.predict(o)
            seconds.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            if name in COMPARED:
                d = det.detect(o)
                rects.append(np.asarray(d.rects).tolist())
                scores.append(np.asarray(d.scores).tolist())
        out[name] = {"seconds": seconds, "cpu_seconds": cpu}
        if name in COMPARED:
            out[name].update(rects=rects, scores=scores)
    return out


def _run_worker(obs_path, names, args, pythonpath=None):
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    cmd = [sys.executable, __file__, "--worker", str(obs_path), "--detectors", ",".join(names),
           "--model", str(args.model), "--ggcnn", str(args.ggcnn or ""), "--hand", args.hand,
           "--paper", args.paper]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if res.returncode:
        raise RuntimeError(f"worker failed ({pythonpath or 'this checkout'}): "
                           f"{res.stderr.strip().splitlines()[-1:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _stats(per_round):
    """Median and 95th percentile over scenes of each scene's median over rounds."""
    x = np.median(np.asarray(per_round, dtype=float), axis=0)
    return {"median": float(np.median(x)), "p95": float(np.percentile(x, 95)),
            "n_scenes": int(len(x)), "n_rounds": len(per_round)}


def _same(new, ref, name):
    """Whether ``name`` proposed the same rectangles in the same order on every scene, in every
    round of both codes, and how far apart the proposed rectangles' scores are."""
    a, b = new[0][name], ref[0][name]
    same = [x == y for x, y in zip(a["rects"], b["rects"], strict=True)]
    diffs = [float(np.max(np.abs(np.subtract(x, y)))) if len(x) and len(x) == len(y)
             else 0.0 for x, y in zip(a["scores"], b["scores"], strict=True)]
    stable = all(r[name]["rects"] == a["rects"] for r in new + ref)
    return {"scenes": len(same), "identical": int(sum(same)), "same_every_round": stable,
            "max_score_difference": max(diffs, default=0.0),
            "largest_score": max((abs(v) for x in b["scores"] for v in x), default=0.0)}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--model", default=str(ROOT / "results/ggcnn-curve/models/dlsr_300"))
    p.add_argument("--ggcnn", default=str(ROOT / "results/ggcnn-curve/models/ggcnn_300.pt"))
    p.add_argument("--hand", default="builtin")
    p.add_argument("--reference", default=None,
                   help="a checkout of the code before the change, timed beside this one")
    p.add_argument("--detectors", default="dlsr,dlsr-paper,mask-pca,ggcnn")
    p.add_argument("--objects", default="test", help="object set (e.g. test, ycb:test)")
    p.add_argument("--scene", default="drop", choices=("drop", "pile", "packed"),
                   help="scene layout (the clutter rounds' pile or packed)")
    p.add_argument("--objects-per-scene", type=int, default=1)
    p.add_argument("--paper", default="run", choices=("run", "full"),
                   help="dlsr-paper as graspsim run builds it (coarse to fine) or as "
                        "scripts/hands_ycb.py does (the full grid)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    names = args.detectors.split(",")
    if args.worker:
        print(json.dumps(worker(args.worker, names, args.model, args.ggcnn or None, args.hand,
                                args.paper)))
        return
    load_before = list(os.getloadavg())
    with tempfile.TemporaryDirectory() as tmp:
        obs_path = Path(tmp) / "obs.npz"
        observations(args.scenes + 1, args.seed, obs_path, args.objects, args.scene,
                     args.objects_per_scene)
        new, ref = [], []
        for _ in range(args.rounds):  # in turn, so that both see the same load
            # one process per detector: none finds another's table fits in the memo
            new.append({k: v for name in names
                        for k, v in _run_worker(obs_path, [name], args).items()})
            if args.reference:
                ref.append({k: v for name in names if name in COMPARED
                            for k, v in _run_worker(obs_path, [name], args,
                                                    pythonpath=args.reference).items()})
    out = {"scenes": args.scenes, "seed": args.seed, "hand": args.hand,
           "objects": args.objects, "scene": args.scene,
           "objects_per_scene": args.objects_per_scene, "paper": args.paper,
           "cpus": len(os.sched_getaffinity(0)),
           "load_average": {"start": load_before, "end": list(os.getloadavg())},
           "plan_seconds": {}, "plan_cpu_seconds": {}}
    for name in new[0]:
        out["plan_seconds"][name] = _stats([r[name]["seconds"] for r in new])
        out["plan_cpu_seconds"][name] = _stats([r[name]["cpu_seconds"] for r in new])
    if ref:
        out["identical_proposals"], out["speedup_median"] = {}, {}
        for name in ref[0]:
            for what in ("seconds", "cpu_seconds"):
                key = "plan_" + what
                out[key][f"{name} (reference)"] = _stats([r[name][what] for r in ref])
            out["identical_proposals"][name] = _same(new, ref, name)
            out["speedup_median"][name] = {
                what: out[key][f"{name} (reference)"]["median"] / out[key][name]["median"]
                for what, key in (("wall", "plan_seconds"), ("cpu", "plan_cpu_seconds"))}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
