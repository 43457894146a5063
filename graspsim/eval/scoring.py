"""Score a detector's rectangles on a graspsim dataset by executing them in the rebuilt scenes.

A dataset written by :func:`graspsim.data.datagen.make_dataset` (``graspsim dataset``) records in
its
manifest ``scenes.json`` everything an exact rebuild of each image's scene needs: the objects at
their settled poses, the table, the camera (``K``, ``T_world_cam``) and the execution
parameters (see :mod:`graspsim.data.datagen`). :func:`score_predictions` (``graspsim score``) reads
predicted rectangles for the dataset's images -- from any detector, run anywhere, on the
dataset's RGB-D images --, rebuilds every scene from its recorded poses
(:func:`graspsim.sim.scene.build_scene`), turns each rectangle into a gripper pose with the image's
own depth (``pcdXXXXd.tiff``) and camera, and executes it exactly as the labelling executed the
dataset's candidates (:func:`graspsim.labels.labelling.label_rectangles`, rectangles snapped to the
same grid, :func:`graspsim.data.datagen.snap_rectangles`). A labelled rectangle written back as a
prediction therefore executes with its label's outcome.

Prediction formats (``format``; by default ``csv`` for a ``.csv`` file, and for a folder
``jacquard`` when it holds ``*_grasps.txt`` files, ``cornell`` when it holds ``pcdXXXX_pred.txt``
or ``pcdXXXXcpos.txt`` files). Rectangles are in the pixels of the dataset's images; the order
of an image's rectangles is their rank (rank 1 is executed for top-1):

* ``csv``: one file, lines ``image,x,y,theta_deg,w,h[,score]`` (an optional header line with
  exactly these names; blank lines and lines starting with ``#`` are ignored). ``image`` is the
  id :func:`dlsr.datasets.load_cornell` gives (``0000`` for ``pcd0000``; ``0`` is read as
  ``0000``); ``x`` column and ``y`` row of the centre, ``theta_deg`` the closing direction in
  degrees counter-clockwise as displayed, ``w`` the opening and ``h`` the jaw size in pixels
  (this project's convention, CONTRIBUTING.md). Rows of an image keep file order unless a
  ``score`` column is present; then they are ranked by decreasing score (ties keep file
  order). A non-numeric or non-finite value, a non-positive size, a wrong column count or an
  image id that is not in the dataset is an error naming the file and line.
* ``cornell``: a folder (searched recursively) with one file per image named
  ``pcdXXXX_pred.txt`` or ``pcdXXXXcpos.txt``: four ``x y`` corner lines per rectangle in
  Cornell order, read with :func:`dlsr.datasets.read_cornell_rectangles` (a rectangle with
  ``NaN`` corners or zero size is dropped with a logged warning naming the file and lines, as
  for the public dataset; other bad lines are errors).
* ``jacquard``: a folder (searched recursively) with one file ``<image>_grasps.txt`` per image
  (``0000_grasps.txt``), lines ``x;y;theta_deg;w;h`` with Jacquard's angle sign (clockwise as
  displayed), read with :func:`dlsr.datasets.read_jacquard_grasps` (which negates the angle;
  non-finite or zero-size lines are dropped with a logged warning naming the file and line).

A file of an image that is not in the dataset is an error; two files for one image too. Images
of the dataset without predictions are scored as failures (``"no grasp proposed"``) and counted
in the summary (``images_without_predictions``).

Output folder (``out``), resumable like trials (:mod:`graspsim.eval.trials`):

* ``scores.jsonl``: one record per image, appended and flushed as it finishes: ``index``,
  ``image``, ``object``, ``graspable``, ``n_predictions``, ``n_positives``, ``rectangle`` (the
  executed top-1 ``[x, y, theta, w, h]``, or None), ``success`` and ``reason`` (top-1 physical
  outcome), ``lift_height``, ``pose``, ``metric`` (the rectangle metric of the top-1 rectangle
  against the image's labelled positives, :func:`dlsr.metrics.rectangle_metric`; False when it
  has none) and, with ``top_k > 1``, ``attempts`` (rank, rectangle, success, reason,
  lift_height, metric of each of the first ``top_k`` rectangles, each executed in a fresh
  rebuild of the scene) and ``success_at_k`` (any of them succeeded).
* ``config.json``: ``data``, ``dataset_fingerprint`` (sha256 of ``scenes.json``),
  ``predictions``, ``predictions_sha256``, ``format``, ``top_k``. A rerun with the same output
  folder finishes the missing images; a different dataset, prediction file, format or ``top_k``
  is refused.
* ``summary.json`` / ``summary.md``: :func:`graspsim.eval.summary.summarize` of the records
  (physical
  success with a Wilson 95 % interval, rectangle-metric accuracy, metric verdict against
  physical outcome, failure reasons, per object) plus success at 1..k with Wilson intervals.
"""

from __future__ import annotations

import csv
import hashlib
import logging
import math
import re
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from dlsr.datasets import (
    clean_depth,
    normalize_image_id,
    read_cornell_rectangles,
    read_depth_image,
    read_jacquard_grasps,
)
from dlsr.metrics import rectangle_metric
from dlsr.records import file_errors, read_json, write_json_atomic, write_text_atomic
from dlsr.rectangles import GraspRectangle

from ..data.datagen import snap_rectangles
from ..data.manifest import (
    execution_params,
    load_manifest,
    manifest_specs,
    rebuild_scene,
    relocated_specs,
)
from ..labels.labelling import label_rectangles
from ..runtime.campaign import make_executor, read_done, run_missing
from ..sim.bullet import worker_sim
from .stats import wilson_interval
from .summary import summarize
from .summary import summary_markdown as trials_markdown
from .trials import NO_PROPOSAL

__all__ = [
    "FORMATS",
    "detect_format",
    "read_predictions",
    "score_image",
    "score_predictions",
    "summary_markdown",
]

log = logging.getLogger(__name__)

FORMATS = ("csv", "cornell", "jacquard")

_CSV_COLUMNS = ["image", "x", "y", "theta_deg", "w", "h"]
_CORNELL_FILE = re.compile(r"^pcd(\d+)(?:_pred|cpos)\.txt$")
_JACQUARD_SUFFIX = "_grasps.txt"


# --------------------------------------------------------------------------------------------
# Prediction files


def detect_format(path) -> str:
    """``csv``, ``cornell`` or ``jacquard`` from a prediction path (see the module docstring)."""
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() == ".csv":
            return "csv"
        raise ValueError(f"{path}: cannot tell the prediction format from the name; "
                         "give --format (a single file is read as csv)")
    if not path.is_dir():
        raise FileNotFoundError(f"predictions not found: {path}")
    has_j = any(True for _ in path.rglob(f"*{_JACQUARD_SUFFIX}"))
    has_c = any(_CORNELL_FILE.match(p.name) for p in path.rglob("pcd*.txt"))
    if has_j and has_c:
        raise ValueError(f"{path} holds both Jacquard (*_grasps.txt) and Cornell "
                         "(pcdXXXX_pred.txt / cpos) files; give --format")
    if not (has_j or has_c):
        raise ValueError(f"{path}: no prediction files (expected <image>_grasps.txt, "
                         "pcdXXXX_pred.txt or pcdXXXXcpos.txt)")
    return "jacquard" if has_j else "cornell"


def _image_id(token: str) -> str:
    return normalize_image_id(token.strip())


def _read_csv(path: Path, image_ids) -> dict[str, list[GraspRectangle]]:
    rows: dict[str, list[tuple[float, int, GraspRectangle]]] = {}
    n_cols = None
    with file_errors(path, "prediction file"), open(path, newline="", encoding="utf-8") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            cells = [c.strip() for c in row]
            if n_cols is None and cells[0].lower() == "image":
                if cells not in (_CSV_COLUMNS, _CSV_COLUMNS + ["score"]):
                    raise ValueError(f"{path}:{lineno}: header must be "
                                     f"{','.join(_CSV_COLUMNS)}[,score], got {','.join(cells)}")
                n_cols = len(cells)
                continue
            if len(cells) not in (6, 7) or (n_cols is not None and len(cells) != n_cols):
                want = n_cols or "6 or 7"
                raise ValueError(f"{path}:{lineno}: expected {want} columns "
                                 f"(image,x,y,theta_deg,w,h[,score]), got {len(cells)}")
            n_cols = len(cells)
            image = _image_id(cells[0])
            if image not in image_ids:
                raise ValueError(f"{path}:{lineno}: image {cells[0]!r} is not an image of the "
                                 "dataset")
            try:
                vals = [float(c) for c in cells[1:]]
            except ValueError:
                raise ValueError(f"{path}:{lineno}: expected numbers after the image id, "
                                 f"got {','.join(cells[1:])}") from None
            if not all(math.isfinite(v) for v in vals):
                raise ValueError(f"{path}:{lineno}: non-finite value in {','.join(cells)}")
            x, y, t, w, h = vals[:5]
            if w <= 0 or h <= 0:
                raise ValueError(f"{path}:{lineno}: w and h must be positive, got w={w}, h={h}")
            score = vals[5] if len(vals) == 6 else 0.0
            rows.setdefault(image, []).append((score, GraspRectangle(x, y, math.radians(t), w, h)))
    # Best score first; sorted() is stable, so equal scores (or no score column) keep file order.
    return {k: [r for _, r in sorted(v, key=lambda e: -e[0])] for k, v in rows.items()}


def _read_folder(path: Path, fmt: str, image_ids) -> dict[str, list[GraspRectangle]]:
    if not path.is_dir():
        raise ValueError(f"{path}: the {fmt} format is a folder of per-image files")
    found: dict[str, Path] = {}
    for p in sorted(path.rglob("*.txt")):
        if fmt == "cornell":
            m = _CORNELL_FILE.match(p.name)
            if m is None:
                continue
            image = _image_id(m.group(1))
        else:
            if not p.name.endswith(_JACQUARD_SUFFIX):
                continue
            image = _image_id(p.name[:-len(_JACQUARD_SUFFIX)])
        if image not in image_ids:
            raise ValueError(f"{p}: image {image!r} is not an image of the dataset")
        if image in found:
            raise ValueError(f"two prediction files for image {image}: {found[image]} and {p}")
        found[image] = p
    if not found:
        raise ValueError(f"{path}: no {fmt} prediction files")
    reader = read_cornell_rectangles if fmt == "cornell" else read_jacquard_grasps
    return {image: reader(p) for image, p in found.items()}


def read_predictions(path, format: str | None = None, image_ids=None
                     ) -> dict[str, list[GraspRectangle]]:
    """Ranked predicted rectangles per image from a prediction file or folder.

    Parameters
    ----------
    path : path-like
    format : {"csv", "cornell", "jacquard"} or None
        None: :func:`detect_format`.
    image_ids : collection of str or None
        The dataset's image ids; an image outside them is an error. None accepts any id.

    Returns
    -------
    dict
        ``image_id -> list of GraspRectangle``, best first.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"predictions not found: {path}")
    fmt = detect_format(path) if format is None else format
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, got {fmt!r}")

    class _Any:
        def __contains__(self, item):
            return True

    ids = _Any() if image_ids is None else set(image_ids)
    if fmt == "csv":
        if not path.is_file():
            raise ValueError(f"{path}: the csv format is one file")
        return _read_csv(path, ids)
    return _read_folder(path, fmt, ids)


def _predictions_sha256(path: Path, fmt: str) -> str:
    h = hashlib.sha256()
    if path.is_file():
        h.update(path.read_bytes())
        return h.hexdigest()
    for p in sorted(path.rglob("*.txt")):
        keep = (_CORNELL_FILE.match(p.name) if fmt == "cornell"
                else p.name.endswith(_JACQUARD_SUFFIX))
        if keep:
            h.update(p.relative_to(path).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# Execution


def _rect_list(r: GraspRectangle) -> list[float]:
    return [float(v) for v in r.as_array()]


def score_image(sim, root, entry: dict, specs: dict, params, rects, top_k: int = 1,
                n_predictions: int | None = None) -> dict:
    """Execute an image's first ``top_k`` rectangles, each in a fresh rebuild of its scene.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    root : path-like
        The dataset folder.
    entry : dict
        The image's manifest entry.
    specs : dict
        ``name -> ObjectSpec`` (:func:`manifest_specs`).
    params : ExecutionParams
    rects : list of GraspRectangle
        Ranked predictions (may be empty).
    top_k : int
    n_predictions : int or None
        How many rectangles the detector gave for the image, when ``rects`` holds only the
        first ones (default ``len(rects)``).

    Returns
    -------
    dict
        The image's record (see the module docstring).

    Raises
    ------
    ValueError
        If the image's depth file is not the one the dataset was labelled with.
    """
    t0 = time.perf_counter()
    root = Path(root)
    depth_path = root / entry["files"]["depth"]
    raw = depth_path.read_bytes() if depth_path.is_file() else None
    if raw is None:
        raise FileNotFoundError(f"depth file of image {entry['image']} not found: {depth_path}")
    if hashlib.sha256(raw).hexdigest() != entry["depth_sha256"]:
        raise ValueError(f"{depth_path} differs from the depth the dataset was labelled with "
                         "(sha256 in scenes.json)")
    depth, valid = clean_depth(read_depth_image(depth_path))
    positives = read_cornell_rectangles(root / entry["files"]["positives"])
    scene = rebuild_scene(entry, specs)
    cam = entry["camera"]
    frame = SimpleNamespace(intrinsics=np.asarray(cam["K"], dtype=float),
                            T_world_cam=np.asarray(cam["T_world_cam"], dtype=float),
                            depth=depth, depth_valid=valid)
    chosen = snap_rectangles(list(rects)[:top_k])
    labelled = label_rectangles(sim, scene, frame, chosen, params)
    attempts = []
    for rank, (rect, res) in enumerate(zip(chosen, labelled.results, strict=True), start=1):
        attempts.append({
            "rank": rank, "rectangle": _rect_list(rect), "success": bool(res.success),
            "reason": res.reason, "lift_height": round(float(res.lift_height), 6),
            "metric": bool(rectangle_metric(rect, positives)) if positives else False,
            "pose": None if res.T_world_tcp is None else np.round(res.T_world_tcp, 6).tolist(),
        })
    record = {
        "index": int(entry["index"]), "image": entry["image"],
        "object": [o["name"] for o in entry["objects"]],
        "graspable": all(specs[o["name"]].graspable for o in entry["objects"]),
        "n_predictions": len(rects) if n_predictions is None else int(n_predictions),
        "n_positives": len(positives),
    }
    if attempts:
        first = attempts[0]
        record.update({k: first[k] for k in ("rectangle", "success", "reason", "lift_height",
                                             "pose", "metric")})
    else:
        record.update(rectangle=None, success=False, reason=NO_PROPOSAL, lift_height=0.0,
                      pose=None, metric=False)
    if top_k > 1:
        record["attempts"] = [{k: v for k, v in a.items() if k != "pose"} for a in attempts]
        record["success_at_k"] = any(a["success"] for a in attempts)
    record["seconds"] = round(time.perf_counter() - t0, 4)
    return record


def _score_task(root, entry, spec_records, execution, rects, top_k, n_predictions):
    manifest = {"object_specs": spec_records, "execution": execution}
    return score_image(worker_sim(), root, entry, manifest_specs(manifest),
                       execution_params(manifest), [GraspRectangle(*r) for r in rects], top_k,
                       n_predictions)


def score_predictions(data, predictions, out=None, format: str | None = None, top_k: int = 1,
                      n_jobs: int = 1, executor=None, progress: bool = False,
                      objects=None, images=None) -> dict:
    """Execute predicted rectangles in the rebuilt scenes of a dataset and summarise.

    Parameters
    ----------
    data : path-like
        Dataset folder written by :func:`graspsim.data.datagen.make_dataset`.
    predictions : path-like
        Prediction file or folder (see the module docstring for the formats).
    out : path-like or None
        Output folder (``scores.jsonl``, ``config.json``, ``summary.json``, ``summary.md``);
        resumes when it holds records of the same configuration. None: in memory only.
    format : {"csv", "cornell", "jacquard"} or None
        None: from the extension or the folder's files (:func:`detect_format`).
    top_k : int
        Rectangles executed per image (best first); ``success`` is always the top-1 outcome.
    n_jobs : int
        Local worker processes when ``executor`` is None.
    executor : graspsim.runtime.executor.Executor or None
        Where images run (local cores or a Ray cluster, which must see the dataset folder at
        the same path); results do not depend on it.
    progress : bool
    objects : str, ObjectSet or None
        Where the dataset's objects are on this machine, when not where the manifest says
        (a folder set moved): an object set (:func:`graspsim.labels.graspability.resolve_objects`)
        whose
        files have the fingerprint the dataset recorded (``generator.object_set``) and that
        has every object of the manifest. None: the manifest's paths.
    images : sequence of str or None
        Score only these images of the dataset (their ids, as in the predictions); the summary
        is over them. None: every image. Records already in ``out`` for other images are kept.

    Returns
    -------
    dict
        The summary (:func:`graspsim.eval.summary.summarize` plus ``top_k``, ``success_at``,
        ``images_without_predictions`` and the configuration), with ``records`` by index.
    """
    if isinstance(top_k, bool) or not isinstance(top_k, int | np.integer) or top_k < 1:
        raise ValueError(f"top_k must be an integer >= 1, got {top_k!r}")
    top_k = int(top_k)
    root = Path(data)
    manifest, fingerprint = load_manifest(root)
    by_id = {e["image"]: e for e in manifest["images"]}
    all_ids = set(by_id)
    if images is None:
        images = manifest["images"]
    else:
        asked = [str(i) for i in images]
        unknown = [i for i in asked if i not in by_id]
        if unknown:
            raise ValueError(f"{root}: no image {unknown[0]!r} in the dataset "
                             f"({len(unknown)} of the {len(asked)} images asked for)")
        images = [by_id[i] for i in dict.fromkeys(asked)]
        by_id = {e["image"]: e for e in images}
    pred_path = Path(predictions)
    fmt = detect_format(pred_path) if format is None else format
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {FORMATS}, got {fmt!r}")
    preds = read_predictions(pred_path, fmt, all_ids)
    missing = [i for i in by_id if i not in preds]
    if missing:
        log.warning("%d of %d images have no predictions in %s: scored as failures (no grasp "
                    "proposed)", len(missing), len(by_id), pred_path)
    spec_records, object_set = relocated_specs(manifest, objects, root)
    config = {"data": str(root.resolve()), "dataset_fingerprint": fingerprint,
              "object_set": object_set,
              "predictions": str(pred_path.resolve()),
              "predictions_sha256": _predictions_sha256(pred_path, fmt),
              "format": fmt, "top_k": top_k,
              # the hand and harness the dataset was labelled with, which execute the
              # predictions too (named in the summary when not the defaults)
              "execution": manifest["execution"]}
    done: dict[int, dict] = {}
    jsonl = None
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        cfg_path = out / "config.json"
        if cfg_path.exists():
            old = read_json(cfg_path, "scoring configuration")
            keys = ("dataset_fingerprint", "predictions_sha256", "format", "top_k")
            changed = [k for k in keys if old.get(k) != config[k]]
            if changed:
                raise ValueError(f"{out} holds scores of another configuration ({cfg_path}: "
                                 f"{', '.join(changed)} differ); use a new folder")
        write_json_atomic(cfg_path, config)
        jsonl = out / "scores.jsonl"
        done = read_done(jsonl)
    todo = [e for e in images if int(e["index"]) not in done]
    if done:
        log.info("resuming: %d of %d images already scored", len(images) - len(todo),
                 len(images))
    t0 = time.perf_counter()
    tasks = [(str(root.resolve()), e, spec_records, manifest["execution"],
              [_rect_list(r) for r in preds.get(e["image"], [])[:top_k]], top_k,
              len(preds.get(e["image"], [])))
             for e in todo]
    new = run_missing(_score_task, tasks, done, jsonl,
                       make_executor(executor, n_jobs, progress) if tasks else None, "images")
    wall = time.perf_counter() - t0
    wanted = {int(e["index"]) for e in images}
    records = [done[i] for i in sorted(done) if i in wanted]
    summary = summarize(records)
    success_at = []
    for k in range(1, top_k + 1):
        hits = sum(any(a["success"] for a in r["attempts"][:k]) if top_k > 1 else r["success"]
                   for r in records)
        success_at.append({"k": k, "successes": int(hits), "n": len(records),
                           "rate": hits / len(records) if records else float("nan"),
                           "ci95": list(wilson_interval(hits, len(records)))})
    summary.update(config)
    summary.update({
        "seed": manifest.get("generator", {}).get("seed"),
        "success_at": success_at,
        "images_without_predictions": sum(r["n_predictions"] == 0 for r in records),
        "trials_per_second": (new / wall) if new and wall > 0 else None,
        "n_jobs": getattr(executor, "n_jobs", n_jobs),
    })
    if out is not None:
        write_json_atomic(out / "summary.json", summary)
        write_text_atomic(out / "summary.md", summary_markdown(summary))
    summary["records"] = records
    return summary


def summary_markdown(s: dict) -> str:
    """The summary of :func:`score_predictions` as Markdown (each image counts as a trial)."""
    body = trials_markdown(s).splitlines()
    head = [
        f"# Scores of `{s['predictions']}` ({s['format']}) on dataset `{s['data']}`",
        "",
        f"- dataset fingerprint (sha256 of scenes.json): `{s['dataset_fingerprint']}`",
        f"- images without predictions (scored as failures): "
        f"{s['images_without_predictions']}",
    ]
    lines = head + body[1:]
    if s["top_k"] > 1:
        lines += ["", "| k | success at k | 95 % CI (Wilson) |", "|---|---|---|"]
        for a in s["success_at"]:
            lo, hi = a["ci95"]
            lines.append(f"| {a['k']} | {a['successes']}/{a['n']} = {100 * a['rate']:.1f} % | "
                         f"{100 * lo:.1f} - {100 * hi:.1f} % |")
    return "\n".join(lines) + "\n"
