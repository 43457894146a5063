"""Table 1's speed-ups against the code before them, in the same run (one JSON object on stdout).

Two measurements, each run once with this checkout's ``dlsr`` and once with a reference
``dlsr`` (``--reference-commit``, default ``main``: ``git archive`` of that commit's ``dlsr/`` into
a temporary folder), each in a child process, alternated so that both see the same load:

* ``svm_fold`` (``--svm-fold``): the SVM of one real outer fold. On the first ``--images``
  images of a Cornell-format folder (the stand-in), outer fold 0 (image-wise, 5 folds), an NKM
  dictionary and the ST features of every ST penalty plus NKM-Natural's are computed once (by
  this checkout, cached in ``--cache``); then each side times the benchmark's inner
  cross-validation of those parameters (5 inner folds, the paper's C grid) and the outer refit
  at the chosen parameters. Reported: seconds, the choices, the mean inner accuracy of every
  (parameter, C) (compared bit for bit) and the test predictions of both sides, and their
  differences.
* ``coding`` (``--coding``): the features of every encoder over its whole grid (one call of
  ``rectangle_features_multi``, as a fold task makes) for ``--coding-rectangles`` training
  rectangles of outer fold 0 of the ``--images`` set, per learner of ``--coding-learners``
  (representations fitted once by this checkout on the fold, cached): CPU seconds per
  computation (lasso, masked lasso, OMP, masked OMP, soft threshold, triangle, patches,
  pooling) on each side, and how far every encoder's features moved (largest absolute and
  relative difference, entries differing).
* ``table`` (``--table``): Table 1 (``nested_cv_cells`` over the 36 cells, ``n_jobs=1``) on the
  first ``--table-images`` images, with ``--table-atoms`` atoms and ``--table-patches`` patches:
  every cell's accuracy, per-fold chosen parameter, C, inner accuracy and predictions compared,
  and the seconds by stage (coding, SVM, representations).

Ratios are reference seconds over this checkout's (> 1: faster now). The machine is shared:
the ratios are what to read, not the absolute seconds.

Usage: python scripts/bench_table1.py --data /work/standin_full/cornell --cache /tmp/t1
       [--svm-fold] [--table] [--images 885] [--table-images 30] [--reference-commit main]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _rectangle_images(data: Path, n_images: int, cache: Path) -> Path:
    """The rectangle images of the first ``n_images`` images of ``data`` (cached npz)."""
    path = cache / f"rectangles_{n_images}.npz"
    if path.exists():
        return path
    from dlsr import datasets
    from dlsr import recognition as rec

    samples = datasets.load_cornell(data, scale=1.0)
    samples = sorted(samples, key=lambda s: str(s.image_id))[:n_images]
    rd = rec.recognition_data(samples, random_state=0)
    np.savez(path, images=rd.images, masks=rd.masks, labels=rd.labels,
             image_ids=rd.image_ids.astype(str))
    return path


def _load(path: Path):
    from dlsr import recognition as rec

    z = np.load(path)
    ids = z["image_ids"].astype(object)
    return rec.RecognitionData(z["images"], z["masks"], z["labels"], ids, ids.copy())


def _fold_features(rect_path: Path, cache: Path) -> Path:
    """Outer fold 0's ST and NKM-Natural features on an NKM dictionary (cached npz)."""
    path = cache / f"fold_features_{rect_path.stem}.npz"
    if path.exists():
        return path
    from dlsr import recognition as rec
    from dlsr.features import ENCODER_GRIDS, fit_representation, rectangle_features_multi

    rd = _load(rect_path)
    groups = rd.groups("image")
    tr, te = rec.outer_folds(groups, 5, rd.labels)[0]
    seed = int(np.random.SeedSequence(0).generate_state(5)[0])
    rep = fit_representation(rd.images, rd.masks, "NKM", n_atoms=300, rows=tr,
                             random_state=seed)
    grids = {"ST": ENCODER_GRIDS["ST"], "Natural": (None,)}
    Ftr = rectangle_features_multi(rd.images, rd.masks, rep, grids, rows=tr)
    Fte = rectangle_features_multi(rd.images, rd.masks, rep, grids, rows=te)
    np.savez(path, st_tr=np.stack(Ftr["ST"]), st_te=np.stack(Fte["ST"]),
             nat_tr=Ftr["Natural"][0], nat_te=Fte["Natural"][0], y_tr=rd.labels[tr],
             y_te=rd.labels[te], g_tr=groups[tr].astype(str))
    return path


def _coding_inputs(rect_path: Path, learners, n_rect: int, cache: Path) -> Path:
    """Representations of ``learners`` on outer fold 0 and the rows to featurise (cached)."""
    path = cache / f"coding_{rect_path.stem}_{'-'.join(learners)}_{n_rect}.npz"
    if path.exists():
        return path
    from dlsr import recognition as rec
    from dlsr.features import fit_representation

    rd = _load(rect_path)
    tr, _ = rec.outer_folds(rd.groups("image"), 5, rd.labels)[0]
    seed = int(np.random.SeedSequence(0).generate_state(5)[0])
    arrays = {"rows": tr[np.linspace(0, len(tr) - 1, n_rect).astype(int)]}
    meta = {}
    for lrn in learners:
        rep = fit_representation(rd.images, rd.masks, lrn, n_atoms=300, rows=tr,
                                 random_state=seed)
        arrays.update(rep.to_arrays(prefix=f"{lrn}_"))
        p = rep.natural_param
        meta[lrn] = p.item() if isinstance(p, np.generic) else p
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)
    return path


# --- children: run with one dlsr or the other on sys.path ----------------------------------


def _child_coding(rect_path: Path, inputs: Path, out: Path) -> None:
    from dlsr.features import ENCODER_GRIDS, Representation, rectangle_features_multi

    _warm_up()
    rd = _load(rect_path)
    z = np.load(inputs)
    meta = json.loads(str(z["meta"]))
    rows = z["rows"]
    result, arrays = {}, {}
    for lrn, param in meta.items():
        rep = Representation.from_arrays(z, lrn, param, prefix=f"{lrn}_")
        cpu: dict = {}
        c = time.process_time()
        F = rectangle_features_multi(rd.images, rd.masks, rep, dict(ENCODER_GRIDS),
                                     cpu_seconds=cpu, rows=rows)
        result[lrn] = {"cpu_seconds": time.process_time() - c,
                       "by_computation": {"-".join(map(str, k)) if isinstance(k, tuple) else k:
                                          v for k, v in cpu.items()}}
        for enc, arrs in F.items():
            for t, A in enumerate(arrs):
                arrays[f"{lrn}|{enc}|{t}"] = A
    np.savez(out.with_suffix(".npz"), **arrays)
    out.write_text(json.dumps(result))


def _warm_up() -> None:
    """Compile (or load from numba's cache) the coding kernels before anything is timed."""
    from dlsr import coding

    rng = np.random.default_rng(0)
    X, D = rng.normal(size=(40, 288)), rng.normal(size=(12, 288))
    M = rng.random((40, 288)) > 0.2
    for mask in (None, M):
        coding.lasso_path(X, D, [0.5, 1.0], mask=mask)
        coding.omp_path(X, D, [1, 5], mask=mask)


def _child_svm(features: Path, out: Path) -> None:
    import inspect

    from dlsr import recognition as rec

    # the public names since af1314b (inner_choice, outer_test), the private ones before
    choose = getattr(rec, "inner_choice", None) or rec._choose
    test = getattr(rec, "outer_test", None) or rec._test
    memo_ok = "memo" in inspect.signature(choose).parameters
    z = np.load(features)
    inner = rec.outer_folds(z["g_tr"], 5)
    C_grid = rec.PAPER_C_GRID
    y_tr, y_te = z["y_tr"], z["y_te"]
    result = {}
    for name, tr, te, params in (("ST", z["st_tr"], z["st_te"], (0.5, 1.0, 1.5, 2.0)),
                                 ("Natural", z["nat_tr"][None], z["nat_te"][None], (None,))):
        feats = dict(zip(params, tr, strict=True))
        t, c = time.perf_counter(), time.process_time()
        memo: dict = {}
        choice = choose(feats, y_tr, inner, C_grid, *([memo] if memo_ok else []))
        t_inner, c_inner = time.perf_counter() - t, time.process_time() - c
        # every (parameter, C)'s mean inner accuracy (repr: compared bit for bit)
        grid = ({repr(p): [repr(float(np.mean(a))) for a in memo[id(feats[p])][1]]
                 for p in params} if memo_ok else None)
        k = params.index(choice[1])
        t, c = time.perf_counter(), time.process_time()
        if memo_ok:  # as the benchmark refits: from the last inner fold's solution
            start = memo[id(feats[choice[1]])][2][list(C_grid).index(choice[2])]
            res = test(tr[k], te[k], y_tr, y_te, choice, start=start)
        else:
            res = test(tr[k], te[k], y_tr, y_te, choice)
        t_refit, c_refit = time.perf_counter() - t, time.process_time() - c
        result[name] = {"inner_seconds": t_inner, "inner_cpu_seconds": c_inner,
                        "refit_seconds": t_refit, "refit_cpu_seconds": c_refit,
                        "choice": [choice[0], choice[1], choice[2]], "inner_grid": grid,
                        "predictions": res["predictions"], "accuracy": res["accuracy"],
                        "n_train": len(y_tr), "n_features": int(tr.shape[2])}
    out.write_text(json.dumps(result))


def _child_table(rect_path: Path, atoms: int, patches: int, out: Path) -> None:
    from dlsr import recognition as rec
    from dlsr.features import ENCODERS, LEARNERS

    rd = _load(rect_path)
    _warm_up()
    cells = [(lrn, enc) for lrn in LEARNERS for enc in ENCODERS]
    t, c = time.perf_counter(), time.process_time()
    records = list(rec.nested_cv_cells(rd, cells, C_grid=rec.PAPER_C_GRID, n_atoms=atoms,
                                       n_patches=patches, random_state=0, n_jobs=1))
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    out.write_text(json.dumps({"wall_seconds": wall, "cpu_seconds": cpu, "cells": records},
                              default=lambda v: v.item()))


# --- the parent ----------------------------------------------------------------------------


def _reference_tree(commit: str, where: Path) -> Path:
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit, "dlsr"], check=True,
                             capture_output=True).stdout
    tar = where / "dlsr.tar"
    tar.write_bytes(archive)
    with tarfile.open(tar) as tf:
        tf.extractall(where, filter="data")
    return where


def _run_child(root: Path, args: list[str]) -> None:
    env = {**os.environ, "PYTHONPATH": str(root)}
    subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", *args],
                   check=True, env=env, cwd=root)


def _ratio(a, b):
    return round(a / b, 3) if b > 0 else None


def _compare_svm(old: dict, new: dict) -> dict:
    out = {}
    for name in old:
        o, n = old[name], new[name]
        po, pn = np.asarray(o["predictions"]), np.asarray(n["predictions"])
        out[name] = {
            "n_train": n["n_train"], "n_features": n["n_features"],
            "reference": {k: round(o[k], 2) for k in ("inner_seconds", "inner_cpu_seconds",
                                                      "refit_seconds", "refit_cpu_seconds")},
            "now": {k: round(n[k], 2) for k in ("inner_seconds", "inner_cpu_seconds",
                                                "refit_seconds", "refit_cpu_seconds")},
            "ratio_inner_cpu": _ratio(o["inner_cpu_seconds"], n["inner_cpu_seconds"]),
            "ratio_refit_cpu": _ratio(o["refit_cpu_seconds"], n["refit_cpu_seconds"]),
            "choice_reference": o["choice"], "choice_now": n["choice"],
            "inner_accuracy_difference": n["choice"][0] - o["choice"][0],
            "same_choice": o["choice"][1:] == n["choice"][1:],
            "same_inner_accuracies": (o.get("inner_grid") == n.get("inner_grid")
                                      if o.get("inner_grid") is not None else None),
            "test_predictions_differing": int(np.sum(po != pn)),
            "test_accuracy": [o["accuracy"], n["accuracy"]],
        }
    return out


def _compare_coding(old: dict, new: dict, old_f, new_f) -> dict:
    out = {}
    for lrn in old:
        o, n = old[lrn], new[lrn]
        moved = {}
        for key in old_f.files:
            if not key.startswith(f"{lrn}|"):
                continue
            a, b = old_f[key].astype(np.float64), new_f[key].astype(np.float64)
            diff = np.abs(a - b)
            if diff.max() > 0:
                moved[key.split("|", 1)[1]] = {
                    "entries_differing": int(np.sum(diff > 0)), "of": int(diff.size),
                    "max_abs": float(diff.max()),
                    "max_rel": float(np.max(diff / np.maximum(np.abs(a), 1e-30)))}
        out[lrn] = {
            "cpu_seconds": [round(o["cpu_seconds"], 2), round(n["cpu_seconds"], 2)],
            "ratio_cpu": _ratio(o["cpu_seconds"], n["cpu_seconds"]),
            "by_computation_reference": {k: round(v, 2) for k, v in
                                         o["by_computation"].items()},
            "by_computation_now": {k: round(v, 2) for k, v in n["by_computation"].items()},
            "features_identical": not moved, "features_moved": moved,
        }
    return out


def _compare_table(old: dict, new: dict) -> dict:
    by_old = {(c["learner"], c["encoder"]): c for c in old["cells"]}
    cells, stages = [], {"reference": {}, "now": {}}
    for side, rec in (("reference", old), ("now", new)):
        st = stages[side]
        for c in rec["cells"]:
            st["representations"] = st.get("representations", 0.0) + c[
                "representation_cpu_seconds"]
            for f in c["folds"]:
                st["coding"] = st.get("coding", 0.0) + f["coding_seconds"]
                st["svm"] = st.get("svm", 0.0) + f["svm_seconds"]
        st["wall"] = rec["wall_seconds"]
        st["cpu"] = rec["cpu_seconds"]
    differing = []
    for c in new["cells"]:
        o = by_old[(c["learner"], c["encoder"])]
        same = {
            "accuracy": o["accuracy"] == c["accuracy"],
            "encoder_param": [f["encoder_param"] for f in o["folds"]]
            == [f["encoder_param"] for f in c["folds"]],
            "C": [f["C"] for f in o["folds"]] == [f["C"] for f in c["folds"]],
            "inner_accuracy": [f["inner_accuracy"] for f in o["folds"]]
            == [f["inner_accuracy"] for f in c["folds"]],
            "predictions": [f["predictions"] for f in o["folds"]]
            == [f["predictions"] for f in c["folds"]],
        }
        cells.append({"cell": f"{c['learner']}-{c['encoder']}", "accuracy": c["accuracy"],
                      **{f"same_{k}": v for k, v in same.items()}})
        if not all(same.values()):
            differing.append({"cell": f"{c['learner']}-{c['encoder']}",
                              "accuracy": [o["accuracy"], c["accuracy"]],
                              "inner_accuracy": [[f["inner_accuracy"] for f in o["folds"]],
                                                 [f["inner_accuracy"] for f in c["folds"]]]})
    for side in stages:
        stages[side] = {k: round(v, 1) for k, v in stages[side].items()}
    return {"n_cells": len(cells), "cells_identical": len(cells) - len(differing),
            "differing": differing, "seconds": stages,
            "ratios": {k: _ratio(stages["reference"][k], stages["now"][k])
                       for k in stages["now"]}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--data", type=Path, help="Cornell-format folder (the stand-in)")
    ap.add_argument("--cache", type=Path, default=Path("runs/bench_table1"))
    ap.add_argument("--svm-fold", action="store_true")
    ap.add_argument("--images", type=int, default=885, help="images of the SVM fold")
    ap.add_argument("--coding", action="store_true")
    ap.add_argument("--coding-rectangles", type=int, default=128)
    ap.add_argument("--coding-learners", default="R,RP,NKM")
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--table-images", type=int, default=30)
    ap.add_argument("--table-atoms", type=int, default=300)
    ap.add_argument("--table-patches", type=int, default=10_000)
    ap.add_argument("--reference-commit", default="main")
    args = ap.parse_args(argv)
    if args.child:
        kind, *rest = args.child
        if kind == "svm":
            _child_svm(Path(rest[0]), Path(rest[1]))
        elif kind == "coding":
            _child_coding(Path(rest[0]), Path(rest[1]), Path(rest[2]))
        else:
            _child_table(Path(rest[0]), int(rest[1]), int(rest[2]), Path(rest[3]))
        return 0
    if args.data is None:
        ap.error("--data is needed")
    args.cache.mkdir(parents=True, exist_ok=True)
    result = {"machine": {"cpus": os.cpu_count(), "load_before": os.getloadavg()},
              "reference_commit": args.reference_commit}
    with tempfile.TemporaryDirectory() as tmp:
        ref = _reference_tree(args.reference_commit, Path(tmp))
        sides = (("reference", ref), ("now", REPO))
        if args.svm_fold:
            feats = _fold_features(_rectangle_images(args.data, args.images, args.cache),
                                   args.cache)
            got = {}
            for side, root in sides:
                out = Path(tmp) / f"svm_{side}.json"
                _run_child(root, ["svm", str(feats), str(out)])
                got[side] = json.loads(out.read_text())
            result["svm_fold"] = {"images": args.images,
                                  **_compare_svm(got["reference"], got["now"])}
        if args.coding:
            rects = _rectangle_images(args.data, args.images, args.cache)
            learners = args.coding_learners.split(",")
            inputs = _coding_inputs(rects, learners, args.coding_rectangles, args.cache)
            got, feats = {}, {}
            for side, root in sides:
                out = Path(tmp) / f"coding_{side}.json"
                _run_child(root, ["coding", str(rects), str(inputs), str(out)])
                got[side] = json.loads(out.read_text())
                feats[side] = np.load(out.with_suffix(".npz"))
            result["coding"] = {"images": args.images, "rectangles": args.coding_rectangles,
                                **_compare_coding(got["reference"], got["now"],
                                                  feats["reference"], feats["now"])}
        if args.table:
            rects = _rectangle_images(args.data, args.table_images, args.cache)
            got = {}
            for side, root in sides:
                out = Path(tmp) / f"table_{side}.json"
                _run_child(root, ["table", str(rects), str(args.table_atoms),
                                  str(args.table_patches), str(out)])
                got[side] = json.loads(out.read_text())
            result["table"] = {"images": args.table_images, "atoms": args.table_atoms,
                               "patches": args.table_patches,
                               **_compare_table(got["reference"], got["now"])}
    result["machine"]["load_after"] = os.getloadavg()
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
