"""Table 2's top rectangles executed: physical success beside the rectangle metric (issue 51).

For each size measured by ``scripts/bench_scale.py`` (its committed ``table2_<size>_<row>_<split>``
folders), every detection row's top-1 rectangle and mask-pca's are executed in each image's
rebuilt scene with :func:`graspsim.eval.scoring.score_predictions` (``graspsim score``). The
stand-in's images are scenes of its labelled dataset (``OUT/labelled`` of
:func:`graspsim.data.standin.make_cornell_standin`): image ``k`` is the ``k``-th labelled scene
with both labels (:func:`graspsim.data.standin.usable_scenes`), so a labelled folder holding the
first scenes is enough; each image's object is checked against the benchmark's record.

Per row and split: physical success (Wilson 95 %), the rectangle metric of Table 2 (against
the stand-in's thinned labels, as reported) and of every labelled candidate, the 2 x 2 table
of metric verdict against physical outcome, and the pair with mask-pca on the same images
(exact McNemar). Writes ``<out>/<size>/...`` score folders (resumable) and
``<out>/table2_physical.{json,md}``.

Usage: python scripts/table2_physical.py --labelled /path/standin/labelled [--sizes 100]
       [--bench results/bench_scale[,OTHER]] [--out results/table2-physical] [--jobs 1]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from dlsr.datasets import load_cornell
from dlsr.records import read_jsonl, write_json_atomic, write_text_atomic
from graspsim.data.standin import usable_scenes
from graspsim.detectors import MaskPCADetector
from graspsim.eval.scoring import score_predictions
from graspsim.eval.stats import mcnemar_exact, paired_counts, wilson_interval

REPO = Path(__file__).resolve().parents[1]


def _csv(path: Path, rects: dict) -> Path:
    lines = ["image,x,y,theta_deg,w,h"]
    for image, r in sorted(rects.items()):
        x, y, theta, w, h = (float(v) for v in r)
        lines.append(f"{image},{x:.4f},{y:.4f},{math.degrees(theta):.6f},{w:.4f},{h:.4f}")
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def _rate(k: int, n: int) -> dict:
    lo, hi = wilson_interval(k, n)
    return {"k": k, "n": n, "rate": k / n if n else float("nan"), "ci95": [lo, hi]}


def size_rows(benches, size: int, labelled: list) -> tuple[dict, dict]:
    """The benchmarks' top-1 rectangles per row (``"<row> <split>"``), keyed by the labelled
    image id, and each row's Table 2 metric verdict per labelled image (``benches``: the
    folders holding ``table2_<size>_<row>_<split>`` benchmark folders)."""
    rects, verdicts = {}, {}
    folders = [f for bench in benches for f in sorted(Path(bench).glob(f"table2_{size}_*"))
               if (f / "results.jsonl").is_file()]
    for folder in folders:
        row, split = folder.name.removeprefix(f"table2_{size}_").rsplit("_", 1)
        name = f"{row} {split}"
        rects[name], verdicts[name] = {}, {}
        for rec in read_jsonl(folder / "results.jsonl", required=("image_id",)):
            k = int(rec["image_id"])
            src = labelled[k]
            if str(src.object_id) != str(rec["object_id"]):
                raise ValueError(f"{folder}: image {rec['image_id']} shows {rec['object_id']}, "
                                 f"but the labelled scene {src.image_id} holds {src.object_id}: "
                                 "not the stand-in this benchmark ran on")
            verdicts[name][src.image_id] = {"metric": bool(rec["success"]),
                                            "mask-pca": bool(rec["baselines"]["mask-pca"])}
            if rec.get("rect") is not None:
                rects[name][src.image_id] = rec["rect"]
    return rects, verdicts


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--labelled", required=True, help="the stand-in's labelled dataset folder")
    ap.add_argument("--bench", default=str(REPO / "results" / "bench_scale"),
                    help="folders of Table 2 benchmark folders, comma-separated")
    ap.add_argument("--sizes", default="100")
    ap.add_argument("--out", default=str(REPO / "results" / "table2-physical"))
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args(argv)
    out = Path(args.out)
    samples = load_cornell(args.labelled)
    usable = usable_scenes(samples)
    report = {"labelled": str(args.labelled), "sizes": {}}
    md = ["# Table 2's top rectangles executed", ""]
    for size in (int(s) for s in args.sizes.split(",")):
        if len(usable) < size:
            raise SystemExit(f"{args.labelled}: {len(usable)} usable scenes, {size} needed: "
                             "label more scenes first")
        kept = usable[:size]
        rects, verdicts = size_rows(args.bench.split(","), size, kept)
        pca = {}
        for s in kept:
            obs = {"rgb": s.rgb, "depth": s.depth, "depth_valid": s.depth_valid}
            found = MaskPCADetector().predict(obs)
            if found:
                pca[s.image_id] = found[0].as_array().tolist()
        rects["mask-pca"] = pca
        ids = [s.image_id for s in kept]
        outcomes = {}
        for name, r in rects.items():
            folder = out / str(size) / name.replace(" ", "_")
            csv = _csv(out / str(size) / "predictions" / f"{name.replace(' ', '_')}.csv", r)
            score_predictions(args.labelled, csv, out=folder, n_jobs=args.jobs)
            recs = {rec["image"]: rec for rec in read_jsonl(folder / "scores.jsonl",
                                                            required=("image",))}
            outcomes[name] = {i: recs[i] for i in ids}
        rows = {}
        pca_ok = np.array([outcomes["mask-pca"][i]["success"] for i in ids])
        for name, recs in outcomes.items():
            ok = np.array([recs[i]["success"] for i in ids])
            all_labels = np.array([bool(recs[i]["metric"]) for i in ids])
            row = {"physical": _rate(int(ok.sum()), size),
                   "metric_all_labels": _rate(int(all_labels.sum()), size),
                   "reasons": {}}
            for i in ids:
                why = recs[i]["reason"] or "lifted"
                row["reasons"][why] = row["reasons"].get(why, 0) + 1
            if name != "mask-pca":
                metric = np.array([verdicts[name][i]["metric"] for i in ids])
                pca_metric = np.array([verdicts[name][i]["mask-pca"] for i in ids])
                row["metric_table2"] = _rate(int(metric.sum()), size)
                row["mask_pca_metric_table2"] = _rate(int(pca_metric.sum()), size)
                c = paired_counts(metric, ok)
                row["metric_vs_physics"] = {"right_lifted": c["both"],
                                            "right_dropped": c["only_a"],
                                            "wrong_lifted": c["only_b"],
                                            "wrong_dropped": c["neither"]}
                pair = paired_counts(ok, pca_ok)
                row["vs_mask_pca"] = {**pair, "p": mcnemar_exact(pair["only_a"],
                                                                 pair["only_b"])}
            rows[name] = row
        report["sizes"][str(size)] = rows
        md += [f"## {size} images", "",
               "| row | physical success (95 % CI) | Table 2 metric | metric, every "
               "labelled candidate | metric right: lifted / dropped; wrong: lifted / dropped |"
               " vs mask-pca (only row / only mask-pca, p) |", "|---|---|---|---|---|---|"]
        for name, row in rows.items():
            ph = row["physical"]
            cell = f"{ph['k']}/{size} = {100 * ph['rate']:.0f} % " \
                   f"({100 * ph['ci95'][0]:.0f} - {100 * ph['ci95'][1]:.0f})"
            if name == "mask-pca":
                m2 = "see each row"
                mvp = pair_cell = ""
            else:
                m2 = f"{row['metric_table2']['k']}/{size}"
                t = row["metric_vs_physics"]
                mvp = (f"{t['right_lifted']} / {t['right_dropped']}; "
                       f"{t['wrong_lifted']} / {t['wrong_dropped']}")
                v = row["vs_mask_pca"]
                pair_cell = f"{v['only_a']} / {v['only_b']}, p = {v['p']:.2g}"
            md.append(f"| {name} | {cell} | {m2} | {row['metric_all_labels']['k']}/{size} | "
                      f"{mvp} | {pair_cell} |")
        md.append("")
    write_json_atomic(out / "table2_physical.json", report, indent=1)
    write_text_atomic(out / "table2_physical.md", "\n".join(md))
    print(json.dumps(report["sizes"], indent=1)[:4000])


if __name__ == "__main__":
    main()
