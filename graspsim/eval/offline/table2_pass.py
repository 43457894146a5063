"""The paper's Table 2 in one pass (``graspsim benchmark table2``): every row of the detection
table, image-wise and object-wise, with the work the rows share done once.

Run as separate detection benchmarks (:func:`graspsim.eval.offline.detection.
detection_benchmark`, one per row and split), each row loads the dataset, builds its folds'
training rectangles, fits its dictionary, and lays the candidates, cuts the rectangle images and
runs the baselines on every test image. Here, per split and fold, the training rectangles are
built once for all rows and one representation is fitted per learner (NKM-Natural and NKM-SC
read the same NKM dictionary: :func:`dlsr.detection.train_detectors`), and each test image is
loaded, searched and cut once and scored by every split's and row's model (an image is tested
once per split), the baselines run once
(:func:`graspsim.eval.offline.detection.detect_image`, :func:`dlsr.detection.detect_many`).
Every record, model and summary is the one the separate benchmark writes, in its folder
(``OUT/<learner>-<encoder>_<split>/``), so either resumes the other's.
"""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

from tqdm.auto import tqdm

from dlsr.detection import train_detectors
from dlsr.records import write_text_atomic

from ...data.samples import load_samples, mapped_pixels
from ...runtime.executor import Executor
from .detection import benchmark_baselines, detect_image, finish_detection
from .detection_plan import plan_detection
from .table2 import table2_rows_markdown

__all__ = ["TABLE2_ROWS", "row_folder", "table2_benchmark", "train_fold_rows"]

#: The rows of the paper's Table 2 that its reference facts record: (learner, encoder).
TABLE2_ROWS = (("NKM", "Natural"), ("NKM", "SC"), ("OMP", "Natural"), ("RP", "Natural"))

#: The per-row arguments: the row's own, never shared.
_OWN = ("learner", "encoder", "encoder_param", "C")


def row_folder(out, learner: str, encoder: str, split: str) -> Path:
    """A row's output folder under ``out``: ``<learner>-<encoder>_<split>``."""
    return Path(out) / f"{learner}-{encoder}_{split}"


def train_fold_rows(paths, samples, models, options: dict) -> list[str]:
    """Train several detectors on one fold's training images, the shared work done once
    (:func:`dlsr.detection.train_detectors`), and save each (a task for the executor's
    workers).

    Parameters
    ----------
    paths : list of str or Path
        Where each model goes (``PATH.npz`` + ``PATH.json``).
    samples : list of dlsr.datasets.GraspSample
    models : list of dict
        Per model, its ``learner``, ``encoder``, ``encoder_param`` and ``C``.
    options : dict
        The other keyword arguments of :func:`dlsr.detection.train_detector`, the same for
        every model (``random_state`` included).

    Returns
    -------
    list of str
        The files written.
    """
    trained = train_detectors(samples, models, **options)
    return [str(q) for path, m in zip(paths, trained, strict=True) for q in m.save(path)]


def table2_benchmark(data, format: str, out, splits=("image", "object"), rows=TABLE2_ROWS,
                     scale=None, mapping=None, extra_train=None, extra_format=None,
                     extra_scale=None, extra_mapping=None, n_overlays: int = 4,
                     executor=None, progress: bool = True, **options) -> dict:
    """The detection benchmark of every row of Table 2 on every split, in one pass.

    Each (row, split) is the detection benchmark
    ``detection_benchmark(data, format, OUT/<learner>-<encoder>_<split>, split=split,
    learner=learner, encoder=encoder, **options)`` and writes what it writes (its fold
    models, ``results.jsonl``, ``detection.json``, ``table2.md``, the overlays), the same
    numbers on the same seed; the work the rows share is done once:

    * the dataset is loaded once;
    * per split and fold, one task trains every row whose model is missing: the training
      rectangles (labelled and grid negatives) are built once and one representation is
      fitted per learner (:func:`train_fold_rows`);
    * per test image, one task detects with every split's and row's fold model that has no
      result yet (an image is tested once in each split, by another fold's models): the image
      is loaded, the lattice's candidates laid and their rectangle images cut once and scored
      by each model, the baselines run once
      (:func:`graspsim.eval.offline.detection.detect_image`; other searches detect one model
      at a time).

    Training tasks, then detection tasks, run through ``executor``; results are written in
    task order as they arrive, so a stopped run resumes at the (row, fold) model and the
    (row, image) result, and the records do not depend on the number of workers.

    Writes ``OUT/table2.json`` (per split and row: accuracy, fold mean and deviation, the
    baselines, seconds per image, the folder; the wall seconds of this run's training and
    detection phases, ``phase_seconds_this_run``) and ``OUT/table2.md`` (the paper's Table 2
    with every row measured).

    Parameters
    ----------
    data : path
        The dataset folder.
    format : {"cornell", "jacquard"}
    out : path
        The output folder.
    splits : sequence of {"image", "object"}
    rows : sequence of (learner, encoder)
        Default :data:`TABLE2_ROWS`.
    scale, mapping, extra_train, extra_format, extra_scale, extra_mapping :
        As :func:`~graspsim.eval.offline.detection.detection_benchmark` (loaded once).
    n_overlays : int
        Best and worst overlays per row and split.
    executor : graspsim.runtime.executor.Executor or None
        Where the tasks run (sequential when None).
    progress : bool
    **options
        The other arguments of :func:`~graspsim.eval.offline.detection.detection_benchmark`
        shared by every row (``options``, ``n_folds``, ``n_atoms``, ``n_patches``,
        ``recognition_json`` (each row takes its own cell's choice), ``seed``, ...); a saved
        ``model``, ``save_model``, ``learner``, ``encoder``, ``encoder_param`` and ``C`` are
        refused (they are per row, or not a table).

    Returns
    -------
    dict
        The content of ``table2.json``.
    """
    refused = [k for k in ("model", "save_model", "split", *_OWN) if k in options]
    if refused:
        raise ValueError(f"table2_benchmark sets or refuses {', '.join(refused)}: each row is "
                         f"a learner and encoder of rows, each split one of splits")
    splits = list(dict.fromkeys(splits))
    rows = [tuple(r) for r in dict.fromkeys(tuple(r) for r in rows)]
    if not splits or not rows:
        raise ValueError("table2_benchmark needs at least one split and one row")
    for split in splits:
        if split not in ("image", "object"):
            raise ValueError(f"split must be 'image' or 'object', got {split!r}")
    out = Path(out)
    with contextlib.ExitStack() as stack:
        dataset = stack.enter_context(mapped_pixels(load_samples(data, format, scale, mapping)))
        extra_dataset = (None if extra_train is None else stack.enter_context(mapped_pixels(
            load_samples(extra_train, extra_format or format, extra_scale, extra_mapping))))
        plans = {(row, split): plan_detection(
            data, format, row_folder(out, *row, split), scale=scale, mapping=mapping,
            split=split, learner=row[0], encoder=row[1], extra_train=extra_train,
            extra_format=extra_format, extra_scale=extra_scale, extra_mapping=extra_mapping,
            dataset=dataset, extra_dataset=extra_dataset, **options)
            for split in splits for row in rows}
        del dataset, extra_dataset  # the plans hold the labelled images
        executor = Executor("sequential", progress=False) if executor is None else executor
        t_run = time.perf_counter()
        _train(plans, splits, rows, executor)
        t_trained = time.perf_counter()
        _detect(plans, splits, rows, executor, progress)
        t_end = time.perf_counter()
        seconds = t_end - t_run
        phases = {"training": t_trained - t_run, "detection": t_end - t_trained}
        summaries = {key: finish_detection(plan, seconds, n_overlays)
                     for key, plan in plans.items()}
    table = _table(out, summaries, splits, rows, seconds)
    table["phase_seconds_this_run"] = {k: round(v, 2) for k, v in phases.items()}
    write_text_atomic(out / "table2.json", json.dumps(table, indent=2))
    write_text_atomic(out / "table2.md", table2_rows_markdown(table))
    return table


def _train(plans, splits, rows, executor) -> None:
    """Per split and fold, one task that trains the rows whose model is missing."""
    tasks = []
    for split in splits:
        first = plans[(rows[0], split)]
        for k in range(len(first.folds)):
            need = [plans[(row, split)] for row in rows
                    if k in plans[(row, split)].folds_to_train()]
            if not need:
                continue
            shared = {n: v for n, v in need[0].training.items() if n not in _OWN}
            tasks.append(([p.fold_model_path(k) for p in need], need[0].fold_training_samples(k),
                          [{n: p.training[n] for n in _OWN} for p in need],
                          {**shared, "random_state": need[0].seed + k}))
    for _ in executor.imap(train_fold_rows, tasks, desc="fold models", star=True):
        pass


def _detect(plans, splits, rows, executor, progress) -> None:
    """Per test image, one task that detects with every split's and row's fold model that
    has no result for it yet; each result appended to its row's and split's
    ``results.jsonl``.

    Every split's folds cover every image once, so an image is tested once per split, by
    another fold model in each: one task holds them all, and the image is loaded, its
    candidates laid and its rectangle images cut once for both splits, the baselines run once
    (their seed is the image's, the same in every split). Tasks follow the first split's
    folds."""
    tasks, targets = [], []
    detectors = {}
    first = plans[(rows[0], splits[0])]
    baselines = benchmark_baselines(first.training["region"])
    fold_of = {split: {i: k for k, (_, test) in enumerate(plans[(rows[0], split)].folds)
                       for i in test} for split in splits}
    for _, test in first.folds:
        for i in test:
            s = first.samples[i]
            need, dets, bases = [], [], []
            for split in splits:
                k = fold_of[split][i]
                for row in rows:
                    p = plans[(row, split)]
                    if s.image_id in p.done:
                        continue
                    if (id(p), k) not in detectors:
                        detectors[(id(p), k)] = p.fold_detector(k)
                    need.append(p)
                    dets.append(detectors[(id(p), k)])
                    bases.append({"config_key": p.key, "fold": k})
            if need:
                tasks.append((dets, s, baselines, first.seed + i, bases))
                targets.append(need)
    bar = tqdm(total=len(tasks), desc="table 2 images", disable=not progress)
    results = executor.imap(detect_image, tasks, desc="detection", star=True)
    for need, recs in zip(targets, results, strict=True):
        for plan, rec_ in zip(need, recs, strict=True):
            plan.add_result(rec_)
        bar.update(1)
    bar.close()


def _table(out: Path, summaries: dict, splits, rows, seconds: float) -> dict:
    """``table2.json``: per split, each row's accuracy and the baselines."""
    table = {"out": str(out), "seconds_this_run": seconds, "splits": {}}
    for split in splits:
        cells = {}
        for learner, encoder in rows:
            s = summaries[((learner, encoder), split)]
            cells[f"{learner}-{encoder}"] = {
                "accuracy": s["accuracy"], "accuracy_fold_mean": s["accuracy_fold_mean"],
                "accuracy_fold_std": s["accuracy_fold_std"],
                "seconds_per_image": s["seconds_per_image"], "n_empty": s["n_empty"],
                "folder": row_folder(out, learner, encoder, split).name}
        any_row = summaries[(rows[0], split)]
        table["splits"][split] = {
            "n_images": len(any_row["per_image"]), "n_folds": any_row["config"]["n_folds"],
            "rows": cells, "baselines": any_row["baselines"],
            "config": {k: v for k, v in any_row["config"].items() if k not in _OWN}}
    return table
