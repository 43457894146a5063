"""Which simulation settings matter for sim -> real detection on the Jacquard samples.

Two parts (``docs/sim_settings.md`` reports both):

* ``measure``: image statistics of the real data (the Jacquard sample views at the scale the
  detector reads them, the two Cornell images) and of simulated scenes under each variant
  (rendered without labelling): object size in pixels, depth of the table, missing depth on
  the object and elsewhere, brightness and saturation of the background.
* ``study``: for each variant, a physics-labelled dataset of the train objects (the same
  seed, so the same objects at the same poses; ``graspsim.data.datagen.make_dataset``), a
  detector trained on it alone and evaluated on every Jacquard sample view
  (``scripts/crossdata_detection.py``, row ``sim_to_real``), and the exact McNemar test of
  each variant against ``default`` over the same images. Everything resumes.

Variants: :data:`graspsim.eval.sim_settings.VARIANTS` (one setting changed at a time).

Usage: python scripts/sim_settings_study.py measure [--scenes 20] [--out runs/sim_settings]
       python scripts/sim_settings_study.py study [--scenes 80] [--variants default closer ...]
       [--out runs/sim_settings] [--jobs 1]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from graspsim.data.datagen import make_dataset
from graspsim.eval.sim_settings import (
    DEFAULT_VARIANTS,
    VARIANTS,
    grasp_sizes,
    measure_settings,
    study_markdown,
)
from graspsim.eval.stats import paired_detection_test
from graspsim.runtime.executor import Executor

REPO = Path(__file__).resolve().parents[1]


def study(args) -> dict:
    sys.path.insert(0, str(REPO / "scripts"))
    import crossdata_detection

    args.out.mkdir(parents=True, exist_ok=True)
    runs, info = {}, {}
    for name in args.variants:
        ds = args.out / f"ds_{name}"
        ex = Executor("sequential" if args.jobs == 1 else "loky", n_jobs=args.jobs,
                      progress=False)
        stats = make_dataset(n_scenes=args.scenes, objects="train", out=ds, seed=args.seed,
                             n_candidates=args.candidates, executor=ex,
                             profile=VARIANTS[name])
        out = args.out / f"x_{name}"
        crossdata_detection.main(["--sim", str(ds), "--rows", "sim_to_real", "--out", str(out),
                                  "--grid-negatives", str(args.grid_negatives),
                                  *([] if args.full_search else ["--coarse-to-fine"]),
                                  "--jobs", str(args.jobs), "--data", args.data])
        runs[name] = json.loads((out / "sim_to_real" / "detection.json").read_text())
        info[name] = {"images": stats["images"], "positives": stats["positives"],
                      "negatives": stats["negatives"], **grasp_sizes(ds),
                      "accuracy": runs[name]["accuracy"],
                      "n_correct": sum(r["success"] for r in runs[name]["per_image"])}
        print(json.dumps({name: info[name]}), flush=True)
    tests = {}
    if "default" in runs:
        for name in runs:
            if name != "default":
                tests[name] = paired_detection_test(runs[name], runs["default"])
    table = study_markdown(info, tests, {n: len(r["per_image"]) for n, r in runs.items()})
    (args.out / "study.md").write_text(table)
    (args.out / "study.json").write_text(json.dumps({"variants": info, "tests": tests,
                                                     "profiles": {n: VARIANTS[n].to_dict()
                                                                  for n in runs}}, indent=1))
    print(table, end="")
    return {"variants": info, "tests": tests}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["measure", "study"])
    ap.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS),
                    choices=list(VARIANTS))
    ap.add_argument("--scenes", type=int, default=None,
                    help="scenes per variant (measure: 20, study: 80)")
    ap.add_argument("--candidates", type=int, default=128)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--grid-negatives", type=float, default=0.0)
    ap.add_argument("--full-search", action="store_true",
                    help="the dense detector's full search (default: coarse-to-fine, ~4x faster)")
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data" / "jacquard_samples"))
    ap.add_argument("--cornell", default=str(REPO.parent / "shared" / "data" /
                                             "cornell_samples"))
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "sim_settings")
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args(argv)
    if args.scenes is None:
        args.scenes = 20 if args.part == "measure" else 80
    if args.part == "measure":
        print(json.dumps(measure_settings(args.data, args.cornell, args.variants, args.scenes,
                                          args.seed, args.out), indent=1))
    else:
        study(args)


if __name__ == "__main__":
    main()
