"""Table 2 in one pass against the eight separate detection commands (one JSON object on stdout).

For each size (the first images of a Cornell-format stand-in, :func:`graspsim.data.standin.
standin_subset`), in the same run, one after the other:

* **old**: the eight commands ``scripts/bench_scale.py`` ran for Table 2 until now --
  ``graspsim benchmark detection`` for NKM-Natural, NKM-SC, OMP-Natural and RP-Natural,
  image-wise and object-wise, 5 folds, 300 atoms, 100,000 patches -- with the code of
  ``--reference-commit`` (default: where this branch left ``main``; ``git archive`` of its
  ``dlsr/`` and ``graspsim/`` into a temporary folder);
* **new**: ``graspsim benchmark table2`` with the same settings (every row and split in one
  pass).

Both run with ``--jobs`` workers (default 1: CPU seconds compare the work, not the workers).
Per size and variant: ``wall_s``, ``cpu_s`` (the children's user + system seconds, from
``getrusage``; ``ratio`` is old / new), ``peak_rss_mb`` (``ru_maxrss`` of the children: the
largest of all children so far, so the new figure is an upper bound), and the training stages
read from the fold models' records (wall seconds): ``train_s_per_fold_model`` and, for the one
pass, what it shares once per fold -- ``data_s_per_fold`` (the training rectangles) and
``representation_s_per_fold`` per learner -- and ``own_s_per_fold_model`` (features and SVM).
``identical``: whether every record (the top rectangle, its score, the metric, the baselines;
the timing excepted) and every cell are the same in both (``records_compared``).
``detection`` times, in this process, the first ``--detect-images`` test images of fold 0
image-wise with the new pass's models: the four rows one by one, each with the baselines (as
the separate commands run them), against one ``detect_image`` for all (CPU seconds per image,
and whether the records are the same). With two sizes or more, ``projected`` fits
``cpu_s = a + b * images`` per variant and gives the CPU seconds at 885 images (a projection,
not a measurement).

Usage: python scripts/bench_table2.py --data /work/standin_full/cornell --sizes 20,40
       [--cache runs/bench_table2] [--jobs 1] [--atoms 300] [--patches 100000]
       [--reference-commit COMMIT]
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from graspsim.data.standin import CORNELL, standin_subset

REPO = Path(__file__).resolve().parents[1]
ARGS = None  # the parsed arguments
ROWS = (("NKM", "Natural"), ("NKM", "SC"), ("OMP", "Natural"), ("RP", "Natural"))


def timed(cmd: list[str], root: Path = REPO) -> dict:
    """Wall and CPU seconds and the peak resident memory (MiB) of a child process running
    the code under ``root``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL,
                   env={**os.environ, "PYTHONPATH": str(root)})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "peak_rss_mb": round(after.ru_maxrss / 1024, 1)}


def records(folder: Path) -> dict:
    """A row's ``results.jsonl`` by image, the timing left out."""
    out = {}
    for line in (folder / "results.jsonl").read_text().splitlines():
        r = json.loads(line)
        out[r["image_id"]] = {k: v for k, v in r.items() if k != "seconds"}
    return out


def cells(folder: Path) -> dict:
    d = json.loads((folder / "detection.json").read_text())
    return {k: d[k] for k in ("accuracy", "accuracy_fold_mean", "accuracy_fold_std",
                              "baselines", "vs_baselines", "folds", "per_image", "n_empty")}


def stages(out: Path, splits) -> dict:
    """The fold models' training seconds read from their records (wall seconds of one
    process): per fold and row, ``train_s``; for the one pass also what was shared, once per
    fold: ``data_s`` (the training rectangles) and ``representation_s`` (one per learner)."""
    own, total, shared = [], [], {}
    for split in splits:
        for learner, encoder in ROWS:
            folder = out / f"{learner}-{encoder}_{split}"
            for f in sorted(glob.glob(str(folder / "models" / "*.json"))):
                cfg = json.loads(Path(f).read_text())["config"]
                total.append(cfg["train_seconds"])
                own.append(cfg["train_seconds"] - cfg.get("shared_train_seconds", 0.0))
                if "shared_train_seconds" in cfg:
                    fold = (split, Path(f).stem.rsplit("_", 1)[1])
                    rep = cfg["shared_train_seconds"] - cfg["training_data_seconds"]
                    shared.setdefault(fold, {"data": cfg["training_data_seconds"]})[learner] = rep
    out_ = {"fold_models": len(total), "train_s_per_fold_model": round(float(np.mean(total)), 2)}
    if shared:
        out_.update(
            own_s_per_fold_model=round(float(np.mean(own)), 2),
            data_s_per_fold=round(float(np.mean([v["data"] for v in shared.values()])), 2),
            representation_s_per_fold={
                learner: round(float(np.mean([v[learner] for v in shared.values()])), 2)
                for learner in dict.fromkeys(r[0] for r in ROWS)})
    return out_


def detection_cpu(new_out: Path, data: Path, n_images: int) -> dict:
    """CPU seconds per test image of fold 0 (image-wise), in this process: the four rows'
    detectors one by one, each with the baselines (as the separate commands run them),
    against one :func:`graspsim.eval.offline.detection.detect_image` for all; and whether
    they give the same records."""
    from graspsim.detectors.dlsr_options import PRESETS
    from graspsim.eval.offline.detection import benchmark_baselines, detect_image
    from graspsim.eval.offline.detection_plan import plan_detection

    plans = [plan_detection(data, "cornell", new_out / f"{learner}-{encoder}_image",
                            split="image", learner=learner, encoder=encoder,
                            options=PRESETS["real"], n_atoms=ARGS.atoms, n_patches=ARGS.patches,
                            seed=ARGS.seed) for learner, encoder in ROWS]
    dets = [p.fold_detector(0) for p in plans]
    test = plans[0].folds[0][1][:n_images]
    baselines = benchmark_baselines()
    old_s = new_s = 0.0
    same = True
    for i in test:
        s = plans[0].samples[i]
        bases = [{"config_key": p.key, "fold": 0} for p in plans]
        t = time.process_time()
        one_by_one = [detect_image([d], s, baselines, ARGS.seed + i, [b])[0]
                      for d, b in zip(dets, bases, strict=True)]
        old_s += time.process_time() - t
        t = time.process_time()
        together = detect_image(dets, s, baselines, ARGS.seed + i, bases)
        new_s += time.process_time() - t
        strip = [{k: v for k, v in r.items() if k != "seconds"} for r in one_by_one]
        same &= strip == [{k: v for k, v in r.items() if k != "seconds"} for r in together]
    n = max(len(test), 1)
    return {"images": len(test), "old_cpu_s_per_image": round(old_s / n, 3),
            "new_cpu_s_per_image": round(new_s / n, 3),
            "ratio": round(old_s / max(new_s, 1e-9), 3), "identical": bool(same)}


def reference_tree(commit: str, where: Path) -> Path:
    """``dlsr/`` and ``graspsim/`` of ``commit`` under ``where``."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit, "dlsr", "graspsim"],
                             check=True, capture_output=True).stdout
    tar = where / "code.tar"
    tar.write_bytes(archive)
    with tarfile.open(tar) as tf:
        tf.extractall(where, filter="data")
    return where


def run_size(n: int, args, graspsim: list[str], reference: Path) -> dict:
    cache = Path(args.cache)
    data = standin_subset(args.data, cache / f"data_{n}", n)
    common = ["--data", str(data), "--format", "cornell", "--jobs", str(args.jobs),
              "--seed", str(args.seed), "--folds", "5", "--atoms", str(args.atoms),
              "--patches", str(args.patches), "--overlays", "0"]
    row: dict = {"images": n}
    old_out, new_out = cache / f"old_{n}", cache / f"new_{n}"
    for d in (old_out, new_out):
        shutil.rmtree(d, ignore_errors=True)
    parts = []
    splits = ARGS.splits.split(",")
    for split in splits:
        for learner, encoder in ROWS:
            parts.append(timed(graspsim + [
                "benchmark", "detection", *common, "--learner", learner, "--encoder",
                encoder, "--split", split, "--out",
                str(old_out / f"{learner}-{encoder}_{split}")], reference))
    row["old"] = {"wall_s": round(sum(p["wall_s"] for p in parts), 2),
                  "cpu_s": round(sum(p["cpu_s"] for p in parts), 2),
                  "peak_rss_mb": max(p["peak_rss_mb"] for p in parts),
                  **stages(old_out, splits)}
    row["new"] = {**timed(graspsim + ["benchmark", "table2", *common, "--split",
                                      ",".join(splits), "--out", str(new_out)]),
                  **stages(new_out, splits)}
    same, n_records = True, 0
    for split in splits:
        for learner, encoder in ROWS:
            name = f"{learner}-{encoder}_{split}"
            a, b = records(old_out / name), records(new_out / name)
            n_records += len(a)
            same &= a == b and cells(old_out / name) == cells(new_out / name)
    row["identical"] = bool(same)
    row["records_compared"] = n_records
    row["ratio"] = round(row["old"]["cpu_s"] / row["new"]["cpu_s"], 3)
    (cache / f"row_{n}.json").write_text(json.dumps(row, indent=1))  # kept if what follows fails
    if "image" in splits and ARGS.detect_images:
        row["detection"] = detection_cpu(new_out, data, ARGS.detect_images)
    return row


def projection(rows: list[dict], size: int = CORNELL["images"]) -> dict:
    """``cpu_s = a + b * images`` per variant, at ``size`` images (needs two sizes)."""
    if len(rows) < 2:
        return {}
    x = np.array([r["images"] for r in rows], float)
    out = {"images": size}
    for which in ("old", "new"):
        y = np.array([r[which]["cpu_s"] for r in rows])
        b, a = np.polyfit(x, y, 1)
        cpu = float(a + b * size)
        out[which] = {"fixed_cpu_s": round(float(a), 1), "cpu_s_per_image": round(float(b), 2),
                      "cpu_s": round(cpu, 0), "hours_on_2_cores": round(cpu / 2 / 3600, 2)}
    out["ratio"] = round(out["old"]["cpu_s"] / out["new"]["cpu_s"], 3)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="a stand-in's Cornell folder (OUT/cornell)")
    ap.add_argument("--sizes", default="20,40")
    ap.add_argument("--cache", default="runs/bench_table2")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--atoms", type=int, default=300)
    ap.add_argument("--patches", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reference-commit", default=None,
                    help="the old commands' code (default: git merge-base HEAD main)")
    ap.add_argument("--splits", default="image,object",
                    help="the splits timed (image,object; one halves the run)")
    ap.add_argument("--detect-images", type=int, default=10,
                    help="test images of fold 0 whose detection CPU is timed in this process, "
                         "the rows one by one against all at once (0: none)")
    global ARGS
    args = ARGS = ap.parse_args(argv)
    commit = args.reference_commit or subprocess.run(
        ["git", "-C", str(REPO), "merge-base", "HEAD", "main"], check=True,
        capture_output=True, text=True).stdout.strip()
    graspsim = [sys.executable, "-m", "graspsim.cli"]
    sizes = sorted({int(s) for s in args.sizes.split(",")})
    with tempfile.TemporaryDirectory() as tmp:
        reference = reference_tree(commit, Path(tmp))
        rows = [run_size(n, args, graspsim, reference) for n in sizes]
    load = os.getloadavg()
    print(json.dumps({"machine": {"cpus": os.cpu_count(), "jobs": args.jobs,
                                  "loadavg_at_end": [round(v, 2) for v in load]},
                      "reference_commit": commit,
                      "settings": {"atoms": args.atoms, "patches": args.patches, "folds": 5,
                                   "rows": ["-".join(r) for r in ROWS],
                                   "splits": args.splits.split(",")},
                      "sizes": rows, "projected": projection(rows)}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
