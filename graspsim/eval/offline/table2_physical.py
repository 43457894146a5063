"""Table 2's top rectangles executed: physical success beside the rectangle metric.

On the Cornell-sized stand-in (:mod:`graspsim.data.standin`) every image is a simulated scene
the harness can rebuild, so the detections of Table 2 (``graspsim benchmark table2``, as
``scripts/bench_scale.py`` runs it) can be executed. For each size, every detection row's
top-1 rectangle and mask-pca's on the same image are executed in the image's rebuilt scene
(:func:`graspsim.eval.scoring.score_predictions`, ``graspsim score``), and per row and split
this module reports:

* physical success (Wilson 95 % interval);
* the rectangle metric of Table 2 (against the stand-in's labels thinned to Cornell's counts,
  as the benchmark reported it) and against every candidate the labeller executed;
* the 2 x 2 table of Table 2's verdict against the physical outcome;
* the pair with mask-pca on the same images (exact McNemar).

The stand-in's image ``k`` is the ``k``-th usable scene of its labelled dataset
(:func:`graspsim.data.standin.usable_scenes`), so a labelled folder holding the first scenes
is enough; each image's object is checked against the benchmark's record.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from dlsr.datasets import load_cornell
from dlsr.records import read_jsonl, write_json_atomic, write_text_atomic

from ...data.standin import usable_scenes
from ...detectors import MaskPCADetector
from ..scoring import score_predictions
from ..stats import mcnemar_exact, paired_counts, wilson_interval

__all__ = ["benchmark_folders", "execute_table2", "render_markdown", "table2_rows"]

REPORT = "table2_physical"


def benchmark_folders(benches, size: int) -> list[tuple[Path, str, str]]:
    """The Table 2 benchmark folders of one size: ``(folder, row, split)``.

    Two layouts are read: ``<bench>/table2_<size>_<row>_<split>/`` (one folder per command)
    and ``<bench>/table2_<size>/<row>_<split>/`` (the one-pass ``graspsim benchmark table2``).
    Folders without ``results.jsonl`` are left out.
    """
    found = []
    for bench in benches:
        bench = Path(bench)
        named = [(f, f.name.removeprefix(f"table2_{size}_"))
                 for f in sorted(bench.glob(f"table2_{size}_*"))]
        named += [(f, f.name) for f in sorted(bench.glob(f"table2_{size}/*_*"))]
        for folder, key in named:
            if (folder / "results.jsonl").is_file():
                row, split = key.rsplit("_", 1)
                found.append((folder, row, split))
    return found


def table2_rows(benches, size: int, labelled) -> tuple[dict, dict]:
    """The benchmarks' top-1 rectangles and metric verdicts per row.

    Parameters
    ----------
    benches : sequence of path-like
        Folders holding Table 2 benchmark folders (:func:`benchmark_folders`).
    size : int
        The stand-in size (images) the benchmarks ran on.
    labelled : list of dlsr.datasets.GraspSample
        The stand-in's first ``size`` usable labelled scenes, in order.

    Returns
    -------
    rects : dict
        ``{"<row> <split>": {labelled image id: [x, y, theta, w, h]}}`` (pixels, radians);
        an image without a detection is absent.
    verdicts : dict
        ``{"<row> <split>": {labelled image id: {"metric": bool, "mask-pca": bool}}}``.
    """
    rects, verdicts = {}, {}
    for folder, row, split in benchmark_folders(benches, size):
        name = f"{row} {split}"
        rects[name], verdicts[name] = {}, {}
        for rec in read_jsonl(folder / "results.jsonl", required=("image_id", "object_id")):
            try:
                k = int(rec["image_id"])
            except ValueError:
                raise ValueError(f"{folder}: image {rec['image_id']!r} is not a stand-in "
                                 "image number") from None
            if not 0 <= k < len(labelled):
                raise ValueError(f"{folder}: image {rec['image_id']} is past the "
                                 f"{len(labelled)} labelled scenes given")
            src = labelled[k]
            if str(src.object_id) != str(rec["object_id"]):
                raise ValueError(f"{folder}: image {rec['image_id']} shows {rec['object_id']}, "
                                 f"but the labelled scene {src.image_id} holds {src.object_id}: "
                                 "not the stand-in this benchmark ran on")
            verdicts[name][src.image_id] = {
                "metric": bool(rec.get("success")),
                "mask-pca": bool((rec.get("baselines") or {}).get("mask-pca"))}
            if rec.get("rect") is not None:
                rects[name][src.image_id] = rec["rect"]
    return rects, verdicts


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


def _row(recs: dict, ids: list, verdicts: dict | None, pca_ok: np.ndarray) -> dict:
    ok = np.array([bool(recs[i]["success"]) for i in ids])
    all_labels = np.array([bool(recs[i]["metric"]) for i in ids])
    row = {"physical": _rate(int(ok.sum()), len(ids)),
           "metric_all_labels": _rate(int(all_labels.sum()), len(ids)), "reasons": {}}
    for i in ids:
        why = recs[i]["reason"] or "lifted"
        row["reasons"][why] = row["reasons"].get(why, 0) + 1
    if verdicts is None:  # mask-pca itself
        return row
    metric = np.array([verdicts[i]["metric"] for i in ids])
    pca_metric = np.array([verdicts[i]["mask-pca"] for i in ids])
    row["metric_table2"] = _rate(int(metric.sum()), len(ids))
    row["mask_pca_metric_table2"] = _rate(int(pca_metric.sum()), len(ids))
    c = paired_counts(metric, ok)
    row["metric_vs_physics"] = {"right_lifted": c["both"], "right_dropped": c["only_a"],
                                "wrong_lifted": c["only_b"], "wrong_dropped": c["neither"]}
    pair = paired_counts(ok, pca_ok)
    row["vs_mask_pca"] = {**pair, "p": mcnemar_exact(pair["only_a"], pair["only_b"])}
    return row


def execute_table2(labelled, benches, sizes, out, n_jobs: int = 1, executor=None) -> dict:
    """Execute Table 2's top rectangles and mask-pca's in the stand-in's rebuilt scenes.

    Parameters
    ----------
    labelled : path-like
        The stand-in's labelled dataset (``OUT/labelled`` of
        :func:`graspsim.data.standin.make_cornell_standin`, or its first scenes labelled again
        with the same seed).
    benches : sequence of path-like
        Folders holding the Table 2 benchmark folders (:func:`benchmark_folders`).
    sizes : sequence of int
        Stand-in sizes to execute; each needs that many usable labelled scenes.
    out : path-like
        Writes ``<out>/<size>/<row>_<split>/`` score folders (resumable),
        ``<out>/<size>/predictions/*.csv`` and ``<out>/table2_physical.{json,md}``. Sizes
        already in the report and not asked for are kept.
    n_jobs : int
        Local worker processes for the trials when ``executor`` is None.
    executor : graspsim.runtime.executor.Executor or None

    Returns
    -------
    dict
        The report: ``sizes`` (per size, per row: ``physical``, ``metric_all_labels``,
        ``reasons``, and for detection rows ``metric_table2``, ``metric_vs_physics``,
        ``vs_mask_pca``) and ``labelled_per_size``.
    """
    out = Path(out)
    sizes = [int(s) for s in sizes]
    if not sizes or min(sizes) < 1:
        raise ValueError(f"sizes must be positive image counts, got {sizes}")
    usable = usable_scenes(load_cornell(labelled))
    if len(usable) < max(sizes):
        raise ValueError(f"{labelled}: {len(usable)} usable labelled scenes, {max(sizes)} "
                         "needed: label more scenes first")
    previous = out / f"{REPORT}.json"
    report = {"sizes": {}}
    if previous.is_file():
        report = json.loads(previous.read_text())
    report.setdefault("sizes", {})
    report.setdefault("labelled_per_size", {})
    for size in sizes:
        kept = usable[:size]
        rects, verdicts = table2_rows(benches, size, kept)
        if not rects:
            raise ValueError(f"no Table 2 benchmark of {size} images in "
                             f"{', '.join(str(b) for b in benches)}")
        for name, v in verdicts.items():
            absent = [i for i in (s.image_id for s in kept) if i not in v]
            if absent:
                raise ValueError(f"Table 2 row {name} of {size} images has no record of the "
                                 f"image of labelled scene {absent[0]}")
        pca = {}
        for s in kept:
            obs = {"rgb": s.rgb, "depth": s.depth, "depth_valid": s.depth_valid}
            found = MaskPCADetector().predict(obs)
            if found:
                pca[s.image_id] = found[0].as_array().tolist()
        ids = [s.image_id for s in kept]
        outcomes = {}
        for name, r in {**rects, "mask-pca": pca}.items():
            slug = name.replace(" ", "_")
            csv = _csv(out / str(size) / "predictions" / f"{slug}.csv", r)
            folder = out / str(size) / slug
            score_predictions(labelled, csv, out=folder, n_jobs=n_jobs, executor=executor,
                              images=ids)
            recs = {rec["image"]: rec for rec in read_jsonl(folder / "scores.jsonl",
                                                            required=("image",))}
            missing = [i for i in ids if i not in recs]
            if missing:
                raise ValueError(f"{folder / 'scores.jsonl'}: no record of image {missing[0]}")
            outcomes[name] = recs
        pca_ok = np.array([bool(outcomes["mask-pca"][i]["success"]) for i in ids])
        report["sizes"][str(size)] = {
            name: _row(recs, ids, verdicts.get(name), pca_ok) for name, recs in outcomes.items()}
        report["labelled_per_size"][str(size)] = str(labelled)
    write_json_atomic(previous, report, indent=1)
    write_text_atomic(out / f"{REPORT}.md", render_markdown(report))
    return report


def render_markdown(report: dict) -> str:
    """The report as Markdown tables, one per size (smallest first)."""
    md = ["# Table 2's top rectangles executed", ""]
    for key, rows in sorted(report["sizes"].items(), key=lambda kv: int(kv[0])):
        size = int(key)
        md += [f"## {size} images", "",
               "| row | physical success (95 % CI) | Table 2 metric | metric, every "
               "labelled candidate | metric right: lifted / dropped; wrong: lifted / dropped |"
               " vs mask-pca (only row / only mask-pca, p) |", "|---|---|---|---|---|---|"]
        for name, row in rows.items():
            ph = row["physical"]
            cell = (f"{ph['k']}/{size} = {100 * ph['rate']:.0f} % "
                    f"({100 * ph['ci95'][0]:.0f} - {100 * ph['ci95'][1]:.0f})")
            if "metric_table2" not in row:
                m2, mvp, pair_cell = "see each row", "", ""
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
    return "\n".join(md)
