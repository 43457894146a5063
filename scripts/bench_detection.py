"""Benchmark: the dense detector against the exact grid search on the same images (JSON).

For each image (synthetic Cornell-layout images from ``graspsim dataset``, 640x480, object region
from the depth above the table plane; Jacquard views of objects the model was not trained on,
with their masks; optionally the two real Cornell samples):

* dense detector with the paper's full grid (``rescore`` best candidates rescored exactly):
  seconds (wall and process CPU, per stage), patch encodings, candidates and the achieved
  GFLOP/s of the dense encoding: its useful products (whitening, centroid products and
  quadrant weights, as counted by ``DenseDetector``) over the wall time of the whole dense
  stage (``gflops``; resizing, statistics and table look-ups count as time), over its CPU
  seconds (``gflops_per_cpu_second``, one core's rate) and over the threads' seconds inside
  the encoding itself (``gflops_per_encode_thread_second``);
* coarse-to-fine mode: seconds, encodings, rectangle-metric agreement with the full grid;
* the exact grid search (every candidate through rectangle images and features): on the full
  grid when it has at most ``--exact-max`` candidates, otherwise its per-candidate cost is
  measured on ``--exact-sample`` random candidates and the full-grid time extrapolated, and
  top-1 agreement is measured on a reduced grid that both detectors search
  (``--agreement-grid``);
* score differences on random candidates: correlation and mean absolute difference of the dense
  (no rescoring) and exact scores, separately for candidates without padding (h == w) and with
  padding (h < w);
* on labelled images, the rectangle metric of each detector's top-1.

The model is ``--model`` or, by default, NKM-Natural trained on the Jacquard views of the
objects not benchmarked (``--atoms``, ``--patches``).

The machine is usually shared: every timing records ``os.getloadavg()`` (1-minute) before and
after, and CPU seconds beside wall seconds.

Usage: ``python scripts/bench_detection.py [--sim-cornell DIR] [--n-jacquard 3] [--out bench.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"


def _obs(s):
    obs = {"rgb": s.rgb, "depth": s.depth, "depth_valid": s.depth_valid}
    if s.mask is not None:
        obs["mask"] = s.mask
    return obs


def _agree(a, b):
    from dlsr.metrics import rectangle_metric

    if len(a) == 0 or len(b) == 0:
        return None
    return bool(rectangle_metric(a[0], b[:1]))


def _success(rects, sample):
    from dlsr.metrics import rectangle_metric

    if not sample.positives or len(rects) == 0:
        return None
    return bool(rectangle_metric(rects[0], sample.positives))


def _corr(a, b):
    if len(a) < 3:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def _load():
    return round(os.getloadavg()[0], 2)


def summarise(rows, how, train_s, args=None) -> dict:
    """The benchmark summary of the per-image rows (also written after every image)."""
    ok = [r for r in rows if "dense" in r]

    def mean(vals):
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) if vals else None

    summary = {
        "benchmark": "detection: dense vs exact grid search",
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "python": platform.python_version(), "cpus": os.cpu_count()},
        "options": None if args is None else vars(args),
        "model": how, "train_seconds": train_s,
        "n_images": len(ok),
        "dense_seconds_per_image": mean([r["dense"]["seconds"] for r in ok]),
        "dense_seconds_per_image_cornell_640x480": mean(
            [r["dense"]["seconds"] for r in ok if r["shape"] == [480, 640]]),
        "exact_seconds_per_image": mean([r["exact"]["seconds"] for r in ok]),
        "exact_is_extrapolated": any(not r["exact"]["full_grid"] for r in ok),
        "time_ratio_exact_over_dense": mean([r["ratio_exact_over_dense"] for r in ok]),
        "dense_scoring_seconds_per_image": mean(
            [r["dense"]["timings"]["dense"] for r in ok]),
        "dense_exact_rescoring_seconds_per_image": mean(
            [r["dense"]["timings"]["rescore"] for r in ok]),
        "dense_cpu_seconds_per_image": mean([r["dense"]["cpu_seconds"] for r in ok]),
        "dense_load_average": mean([r["dense"]["load"][0] for r in ok]),
        "dense_encodings_per_image": mean([r["dense"]["n_encodings"] for r in ok]),
        "encoding_ratio_exact_over_dense": mean(
            [r["exact"]["n_encodings"] / r["dense"]["n_encodings"] for r in ok]),
        "exact_encodings_per_image": mean([r["exact"]["n_encodings"] for r in ok]),
        "dense_encoding_gflops": mean([r["dense"]["gflops"] for r in ok]),
        "dense_encoding_gflops_per_cpu_second": mean(
            [r["dense"]["gflops_per_cpu_second"] for r in ok]),
        "top1_agreement": mean([r["top1_agree"] for r in ok]),
        "coarse_to_fine_seconds_per_image": mean([r["coarse_to_fine"]["seconds"] for r in ok]),
        "coarse_to_fine_seconds_per_image_cornell_640x480": mean(
            [r["coarse_to_fine"]["seconds"] for r in ok if r["shape"] == [480, 640]]),
        "coarse_to_fine_cpu_seconds_per_image": mean(
            [r["coarse_to_fine"]["cpu_seconds"] for r in ok]),
        "coarse_to_fine_agrees_with_dense": mean(
            [r["coarse_to_fine"]["agrees_with_dense"] for r in ok]),
        "accuracy_labelled": {
            "dense": mean([r["dense"]["success"] for r in ok]),
            "coarse_to_fine": mean([r["coarse_to_fine"]["success"] for r in ok]),
        },
        "score_corr_no_padding": mean([r["score_difference"]["no_padding"]["corr"] for r in ok]),
        "score_corr_padding": mean([r["score_difference"]["padding"]["corr"] for r in ok]),
        "targets": {"dense_s_per_640x480": 3.0, "ratio": 15, "top1_agreement": 0.95,
                    "coarse_to_fine_s": 0.5, "dense_encoding_gflops": 100},
        "images": rows,
    }
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None, help="saved model (default: train one)")
    ap.add_argument("--n-jacquard", type=int, default=3, help="Jacquard test views")
    ap.add_argument("--jacquard-scale", type=float, default=0.5,
                    help="resize the Jacquard views (1024x1024) by this factor")
    ap.add_argument("--sim-cornell", default=None, metavar="DIR",
                    help="synthetic Cornell dataset (graspsim dataset) for 640x480 images")
    ap.add_argument("--n-sim", type=int, default=2)
    ap.add_argument("--real-cornell", action="store_true",
                    help="also the two real Cornell samples (region from depth: unreliable)")
    ap.add_argument("--atoms", type=int, default=300)
    ap.add_argument("--patches", type=int, default=30_000)
    ap.add_argument("--rescore", type=int, default=None,
                    help="candidates rescored exactly (default: the detector's)")
    ap.add_argument("--threads", type=int, default=None,
                    help="DenseDetector n_threads (default: the CPUs available)")
    ap.add_argument("--exact-max", type=int, default=3000,
                    help="run the full-grid exact search only below this many candidates")
    ap.add_argument("--exact-sample", type=int, default=300)
    ap.add_argument("--score-sample", type=int, default=400)
    ap.add_argument("--agreement-grid", choices=["coarse", "paper"], default="coarse",
                    help="coarse: 6 angles, openings and jaws 20..80, centres every 20 px")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="also write the JSON here")
    args = ap.parse_args(argv)

    from dlsr import datasets
    from dlsr.detection import (
        PAPER_GRID,
        DenseDetector,
        DLSRDetector,
        ExactGridDetector,
        SearchGrid,
        train_detector,
    )

    rng = np.random.default_rng(args.seed)
    jac = datasets.load_jacquard(SHARED / "jacquard_samples", scale=args.jacquard_scale)
    objects = sorted({s.object_id for s in jac})
    test_obj = objects[0]
    test = [s for s in jac if s.object_id == test_obj][: args.n_jacquard]
    t0 = time.perf_counter()
    if args.model:
        model = DLSRDetector.load(args.model)
        how = f"loaded {args.model}"
    else:
        train = [s for s in jac if s.object_id != test_obj]
        model = train_detector(train, "NKM", "Natural", n_atoms=args.atoms,
                               n_patches=args.patches, random_state=args.seed)
        how = (f"NKM-Natural trained on {len(train)} Jacquard views of {len(objects) - 1} other "
               f"objects ({args.atoms} atoms, {args.patches} patches)")
    train_s = time.perf_counter() - t0
    images = []
    if args.sim_cornell:  # synthetic Cornell-layout images (640x480) with their labels
        sim = [s for s in datasets.load_cornell(args.sim_cornell) if s.positives]
        images += sim[: args.n_sim]
    if args.real_cornell:
        # The real samples have no background image and a range-depth table that is not a
        # plane in 1/z, so their depth-plane region is far too large (pessimistic timings).
        images += datasets.load_cornell(SHARED / "cornell_samples")
    images += test
    coarse = SearchGrid(angles_deg=tuple(range(0, 180, 30)), openings=(20, 40, 60, 80),
                        jaws=(20, 40, 60, 80), step=20.0)
    agreement_grid = coarse if args.agreement_grid == "coarse" else PAPER_GRID

    opts = {"n_threads": args.threads}
    if args.rescore is not None:
        opts["rescore"] = args.rescore
    DenseDetector(model, **opts).detect(_obs(images[0]))  # compile and warm up

    def timed(fn, *a):
        """``fn(*a)``, its process CPU seconds and the load average before and after."""
        load0, c0 = _load(), time.process_time()
        out = fn(*a)
        return out, time.process_time() - c0, [load0, _load()]

    rows = []
    for s in images:
        obs = _obs(s)
        dense = DenseDetector(model, **opts)
        d, cpu, load = timed(dense.detect, obs)
        row = {"image": s.image_id, "shape": list(s.rgb.shape[:2]),
               "region": "mask" if "mask" in obs else "depth"}
        if d.reason:
            row["reason"] = d.reason
            rows.append(row)
            continue
        enc = d.timings
        row["dense"] = {"seconds": d.seconds, "cpu_seconds": cpu, "load": load,
                        "n_candidates": d.n_candidates, "n_encodings": d.n_encodings,
                        "encode_flops": enc["encode_flops"],
                        "gflops": enc["encode_flops"] / max(enc["dense"], 1e-9) / 1e9,
                        "gflops_per_cpu_second":
                            enc["encode_flops"] / max(enc["dense_cpu"], 1e-9) / 1e9,
                        "gflops_per_encode_thread_second":
                            enc["encode_flops"] / max(enc["encode"], 1e-9) / 1e9,
                        "timings": {k: v for k, v in enc.items() if k != "encode_flops"},
                        "success": _success(d.rects, s)}
        c2f_det = DenseDetector(model, coarse_to_fine=True, n_threads=args.threads)
        c2f, cpu, load = timed(c2f_det.detect, obs)
        row["coarse_to_fine"] = {"seconds": c2f.seconds, "cpu_seconds": cpu, "load": load,
                                 "n_encodings": c2f.n_encodings,
                                 "timings": {k: v for k, v in c2f.timings.items()
                                             if k != "encode_flops"},
                                 "success": _success(c2f.rects, s),
                                 "agrees_with_dense": _agree(c2f.rects, d.rects)}
        exact = ExactGridDetector(model)
        cand, _ = exact.candidates(obs)
        if len(cand) <= args.exact_max:
            e, cpu, load = timed(exact.detect, obs)
            row["exact"] = {"seconds": e.seconds, "cpu_seconds": cpu, "load": load,
                            "n_encodings": e.n_encodings, "full_grid": True,
                            "success": _success(e.rects, s)}
            row["top1_agree"] = _agree(d.rects, e.rects)
        else:
            sub = cand[rng.choice(len(cand), args.exact_sample, replace=False)]
            t = time.perf_counter()
            _, cpu, load = timed(model.rectangle_scores, obs, sub)
            per = (time.perf_counter() - t) / len(sub)
            row["exact"] = {"seconds": per * len(cand), "seconds_per_candidate": per,
                            "cpu_seconds": cpu * len(cand) / len(sub), "load": load,
                            "n_encodings": len(cand) * 361, "full_grid": False,
                            "extrapolated_from": len(sub)}
            # top-1 agreement on a grid both can afford
            ea = ExactGridDetector(model, grid=agreement_grid).detect(obs)
            da = DenseDetector(model, grid=agreement_grid, **opts).detect(obs)
            row["agreement_grid"] = {"grid": args.agreement_grid,
                                     "n_candidates": ea.n_candidates,
                                     "exact_seconds": ea.seconds, "dense_seconds": da.seconds,
                                     "top1_agree": _agree(da.rects, ea.rects),
                                     "exact_success": _success(ea.rects, s),
                                     "dense_success": _success(da.rects, s)}
            row["top1_agree"] = row["agreement_grid"]["top1_agree"]
        row["ratio_exact_over_dense"] = row["exact"]["seconds"] / d.seconds
        # dense (no rescoring) against exact scores on random candidates
        sub = cand[rng.choice(len(cand), min(len(cand), args.score_sample), replace=False)]
        ds = DenseDetector(model, n_threads=args.threads).score(obs, sub)
        es = model.rectangle_scores(obs, sub)
        sq = sub[:, 3] == sub[:, 4]
        row["score_difference"] = {
            "n": int(len(sub)), "scale_std_exact": float(np.std(es)),
            "no_padding": {"n": int(sq.sum()), "corr": _corr(ds[sq], es[sq]),
                           "mean_abs_diff": float(np.mean(np.abs(ds[sq] - es[sq])))
                           if sq.any() else None},
            "padding": {"n": int((~sq).sum()), "corr": _corr(ds[~sq], es[~sq]),
                        "mean_abs_diff": float(np.mean(np.abs(ds[~sq] - es[~sq])))
                        if (~sq).any() else None},
        }
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
        if args.out:  # results as they go
            Path(args.out).write_text(json.dumps(summarise(rows, how, train_s, args), indent=2))

    text = json.dumps(summarise(rows, how, train_s, args), indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
