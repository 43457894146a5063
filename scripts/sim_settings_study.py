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

Variants (one setting changed at a time; ``graspsim.sim.profiles.SimProfile`` fields):

- ``default``: the simulator's defaults;
- ``closer``: the camera 0.40-0.50 m above the table instead of 0.6-0.8 m (objects about
  1.5x larger in pixels);
- ``farther``: the camera 1.0-1.3 m above the table (labelled grasp openings about as wide in
  pixels as Jacquard's at the scale the detector reads them);
- ``clean_depth``: no depth noise or dropout (``DepthNoise.off()``; the ``jacquard`` profile);
- ``no_material_dropout``: the Kinect model without its dropout on dark, specular and
  transparent objects (``DepthNoise(materials=False)``);
- ``jacquard_look``: Jacquard's appearance: light grey table, even light without cast
  shadows;
- ``grey_table``: the grey table alone (default lights).

Usage: python scripts/sim_settings_study.py measure [--scenes 20] [--out runs/sim_settings]
       python scripts/sim_settings_study.py study [--scenes 80] [--variants default closer ...]
       [--out runs/sim_settings] [--jobs 1]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from graspsim.sim.camera import DepthNoise, LightRanges
from graspsim.sim.profiles import PROFILES, SimProfile

REPO = Path(__file__).resolve().parents[1]
DEFAULT = PROFILES["default"]
# Jacquard's look: even light from high above, no cast shadows (with the grey table).
SOFT_LIGHT = LightRanges(elevation=(60.0, 90.0), tint=(0.0, 0.05), ambient=(0.6, 0.75),
                         diffuse=(0.2, 0.35), specular=(0.0, 0.1), shadow=0.0)
VARIANTS: dict[str, SimProfile] = {
    "default": DEFAULT,
    "closer": replace(DEFAULT, name="closer", camera_height=(0.40, 0.50)),
    "farther": replace(DEFAULT, name="farther", camera_height=(1.0, 1.3)),
    "clean_depth": replace(DEFAULT, name="clean_depth", depth_noise=DepthNoise.off()),
    "no_material_dropout": replace(DEFAULT, name="no_material_dropout",
                                   depth_noise=DepthNoise(materials=False)),
    "jacquard_look": replace(DEFAULT, name="jacquard_look", table="grey", lighting=SOFT_LIGHT),
    "grey_table": replace(DEFAULT, name="grey_table", table="grey"),
}


def _stats(rgb, depth, valid, mask) -> dict:
    """Per-image figures: object area and bounding box (px), depth of the object and of the
    rest (m, medians), missing depth on the object and elsewhere (fractions), background
    brightness and saturation (0-255, medians)."""
    ys, xs = np.nonzero(mask)
    rest = ~mask
    rgbf = np.asarray(rgb, float)
    sat = rgbf.max(axis=2) - rgbf.min(axis=2)
    return {
        "object_px": int(mask.sum()),
        "bbox_long_px": int(max(np.ptp(xs), np.ptp(ys)) + 1) if len(xs) else 0,
        "object_depth_m": float(np.median(depth[mask & valid])) if (mask & valid).any() else None,
        "table_depth_m": float(np.median(depth[rest & valid])) if (rest & valid).any() else None,
        "missing_object": float(1 - valid[mask].mean()) if mask.any() else None,
        "missing_elsewhere": float(1 - valid[rest].mean()),
        "background_gray": float(np.median(rgbf[rest].mean(axis=1))),
        "background_saturation": float(np.median(sat[rest])),
    }


def _summary(rows: list[dict]) -> dict:
    out = {"images": len(rows)}
    for k in rows[0]:
        v = np.array([r[k] for r in rows if r[k] is not None], float)
        out[k] = [round(float(q), 4) for q in np.percentile(v, [10, 50, 90])]
    return out


def measure(args) -> dict:
    from dlsr.datasets import load_jacquard, read_depth_image
    from graspsim.labels.graspability import resolve_objects
    from graspsim.sim.bullet import worker_sim
    from graspsim.sim.observe import observe_scene

    res = {"percentiles": [10, 50, 90]}
    for depth in ("stereo", "perfect"):
        rows = [_stats(s.rgb, s.depth, s.depth_valid, s.mask)
                for s in load_jacquard(args.data, depth=depth, scale=0.5)]
        res[f"jacquard_{depth}_scale0.5"] = _summary(rows)
    cornell = {}
    for path in sorted(Path(args.cornell).glob("pcd*d.tiff")):
        d = np.asarray(read_depth_image(path), np.float32)
        ok = np.isfinite(d) & (d > 0)
        cornell[path.name] = {"missing": float(1 - ok.mean()),
                              "depth_m_p5_p50_p95": np.percentile(d[ok], [5, 50, 95]).round(3)
                              .tolist()}
    res["cornell"] = cornell
    sim = worker_sim()
    specs = resolve_objects("train")
    for name in args.variants:
        rows = []
        for i in range(args.scenes):
            _, bodies, frame, _ = observe_scene(sim, specs, args.seed, i,
                                                    profile=VARIANTS[name])
            mask = np.isin(frame.segmentation, bodies.objects)
            rows.append(_stats(frame.rgb, frame.depth, frame.depth_valid, mask))
        res[f"sim_{name}"] = _summary(rows)
        print(json.dumps({name: res[f"sim_{name}"]}), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "measure.json").write_text(json.dumps(res, indent=1))
    return res


def _grasp_sizes(ds) -> dict:
    from dlsr.datasets import load_cornell

    w = [r.w for s in load_cornell(ds) for r in s.positives]
    return {"positives": len(w), "opening_px_median": round(float(np.median(w)), 1) if w else None}


def study(args) -> dict:
    sys.path.insert(0, str(REPO / "scripts"))
    import crossdata_detection

    from graspsim.data.datagen import make_dataset
    from graspsim.eval.stats import paired_detection_test
    from graspsim.runtime.executor import Executor

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
                      "negatives": stats["negatives"], **_grasp_sizes(ds),
                      "accuracy": runs[name]["accuracy"],
                      "n_correct": sum(r["success"] for r in runs[name]["per_image"])}
        print(json.dumps({name: info[name]}), flush=True)
    tests = {}
    if "default" in runs:
        for name in runs:
            if name != "default":
                tests[name] = paired_detection_test(runs[name], runs["default"])
    lines = ["| variant | sim -> real (%) | images won alone vs default (variant / default) | "
             "exact McNemar p | positives (median opening, px) |", "|---|---|---|---|---|"]
    for name, s in info.items():
        t = tests.get(name)
        lines.append(f"| {name} | {100 * s['accuracy']:.1f} ({s['n_correct']}/"
                     f"{len(runs[name]['per_image'])}) | "
                     + (f"{t['a_only']} / {t['b_only']} | {t['p_value']:.3g}" if t else " | ")
                     + f" | {s['positives']} ({s['opening_px_median']}) |")
    (args.out / "study.md").write_text("\n".join(lines) + "\n")
    (args.out / "study.json").write_text(json.dumps({"variants": info, "tests": tests,
                                                     "profiles": {n: VARIANTS[n].to_dict()
                                                                  for n in runs}}, indent=1))
    print("\n".join(lines))
    return {"variants": info, "tests": tests}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=["measure", "study"])
    ap.add_argument("--variants", nargs="+", default=["default", "closer", "farther",
                                                      "clean_depth", "jacquard_look"],
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
    (measure if args.part == "measure" else study)(args)


if __name__ == "__main__":
    main()
