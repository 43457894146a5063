"""Detection across datasets on real images: sim -> real, real -> real, sim + real.

Three detectors of the same learner-encoder (NKM-Natural by default), all tested by the
rectangle metric (top-1) on every labelled image of the real data (``--data``, the Jacquard
samples by default), beside the baselines on the same images:

- sim -> real: trained once on the synthetic dataset ``--sim`` only (``graspsim dataset
  --objects train ...``; saved as ``<out>/sim_model``), then evaluated with
  ``graspsim benchmark detection --model`` (no training on real images);
- real -> real: object-wise cross-validation on the real data;
- sim + real: the same folds, with every synthetic image joined to each training fold
  (``--extra-train``), never to a test fold.

All runs go through :func:`graspsim.eval.offline.detection.detection_benchmark` and resume in
``<out>/{sim_to_real,real_cv,sim_plus_real_cv}``; ``<out>/crossdata.md`` and
``crossdata.json`` put them side by side with exact McNemar tests between the rows.

Usage: python scripts/crossdata_detection.py --sim runs/sim_train [--out runs/crossdata]
       [--data ../shared/data/jacquard_samples --format jacquard] [--rows sim_to_real real_cv
       sim_plus_real_cv] [--grid-negatives 1] [--coarse-to-fine] [--jobs 1]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from dlsr.detection import DLSRDetector, train_detector
from graspsim.data.samples import load_samples
from graspsim.eval.offline.detection import detection_benchmark
from graspsim.eval.stats import paired_detection_test
from graspsim.runtime.executor import Executor

REPO = Path(__file__).resolve().parents[1]
ROWS = {"sim_to_real": "sim -> real (trained on synthetic images only)",
        "real_cv": "real -> real (object-wise CV)",
        "sim_plus_real_cv": "sim + real (synthetic images in every training fold)"}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim", required=True, help="synthetic Cornell dataset (graspsim dataset)")
    ap.add_argument("--data", default="../shared/data/jacquard_samples")
    ap.add_argument("--format", choices=["cornell", "jacquard"], default="jacquard")
    ap.add_argument("--scale", type=float, default=None,
                    help="real images (default: the format's, 0.5 for Jacquard)")
    ap.add_argument("--sim-scale", type=float, default=1.0)
    ap.add_argument("--learner", default="NKM")
    ap.add_argument("--encoder", default="Natural")
    ap.add_argument("--rows", nargs="+", default=list(ROWS), choices=list(ROWS))
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "crossdata")
    ap.add_argument("--grid-negatives", type=float, default=1.0,
                    help="training negatives from the search grid per labelled rectangle "
                         "(0: the paper's training)")
    ap.add_argument("--coarse-to-fine", action="store_true",
                    help="the dense detector's coarse-to-fine search (about 4x faster)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    ex = Executor("sequential" if args.jobs == 1 else "loky", n_jobs=args.jobs, progress=False)
    common = dict(scale=args.scale, learner=args.learner, encoder=args.encoder, seed=args.seed,
                  coarse_to_fine=args.coarse_to_fine, executor=ex)
    training = dict(grid_negatives=args.grid_negatives)
    runs, seconds = {}, {}
    for row in args.rows:
        t = time.perf_counter()
        if row == "sim_to_real":
            mpath = args.out / "sim_model"
            if not mpath.with_name("sim_model.json").is_file():
                sim = [s for s in load_samples(args.sim, "cornell", args.sim_scale) if s.positives]
                model = train_detector(sim, learner=args.learner, encoder=args.encoder,
                                       random_state=args.seed, **training)
                model.save(mpath)
            info = DLSRDetector.load(mpath).config
            print(json.dumps({"sim_model": str(mpath), "train_seconds": info["train_seconds"],
                              "n_train_rectangles": info["n_train_rectangles"]}), flush=True)
            common_model = {k: v for k, v in common.items() if k not in ("learner", "encoder")}
            runs[row] = detection_benchmark(args.data, args.format, args.out / row,
                                            model=mpath, **common_model)
        elif row == "real_cv":
            runs[row] = detection_benchmark(args.data, args.format, args.out / row, **common,
                                            **training)
        else:
            runs[row] = detection_benchmark(args.data, args.format, args.out / row,
                                            extra_train=args.sim, extra_format="cornell",
                                            extra_scale=args.sim_scale, **common, **training)
        seconds[row] = round(time.perf_counter() - t, 1)
        print(json.dumps({"row": row, "accuracy": runs[row]["accuracy"],
                          "baselines": runs[row]["baselines"], "seconds": seconds[row]}),
              flush=True)
    n = next(iter(runs.values()))["config"]["n_images"]
    lines = ["| detector | DLSR (%) | mask-pca (%) | random (%) |", "|---|---|---|---|"]
    for row, s in runs.items():
        k = sum(r["success"] for r in s["per_image"])
        lines.append(f"| {ROWS[row]} | {100 * s['accuracy']:.1f} ({k}/{n}) | "
                     f"{100 * s['baselines']['mask-pca']:.1f} | "
                     f"{100 * s['baselines']['random']:.1f} |")
    tests = {}
    names = list(runs)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            tests[f"{a} vs {b}"] = paired_detection_test(runs[a], runs[b])
    lines.append("")
    for name, t in tests.items():
        lines.append(f"- {name}: {t['a_only']} vs {t['b_only']} images won alone, exact "
                     f"McNemar p = {t['p_value']:.3g}")
    (args.out / "crossdata.md").write_text("\n".join(lines) + "\n")
    (args.out / "crossdata.json").write_text(json.dumps(
        {"rows": {r: {"accuracy": s["accuracy"], "baselines": s["baselines"],
                      "config": s["config"], "folder": str(args.out / r)}
                  for r, s in runs.items()}, "tests": tests, "seconds": seconds}, indent=2))
    print(json.dumps({"table": str(args.out / "crossdata.md"), "tests": tests}))


if __name__ == "__main__":
    main()
