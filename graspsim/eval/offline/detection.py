"""The paper's detection benchmark (Table 2) behind ``graspsim benchmark detection``:
cross-validated detection accuracy by the rectangle metric, with the baselines on the same
images and paired tests against them.

:func:`detection_benchmark` runs in named steps: the saved model checked (with ``model``), the
extra training images, the labelled images, the folds, the configuration (whose digest keys
the results) -- these five are :func:`~graspsim.eval.offline.detection_plan.plan_detection` --,
the missing fold models trained, the missing test images detected (each fold's detector:
:meth:`~graspsim.eval.offline.detection_plan.DetectionPlan.fold_detector`), the summary
(:func:`summarize_detection`), the overlays, and the model on every image (``save_model``).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm.auto import tqdm

from dlsr.detection import detect_many, sample_observation, train_detector
from dlsr.metrics import jaccard_matrix, rectangle_metric
from dlsr.records import machine_record, write_text_atomic
from dlsr.rectangles import as_rect_array
from dlsr.viz import draw_rectangles

from ...detectors.baselines import MaskPCADetector, ObjectRandomDetector
from ...runtime.executor import Executor
from ..stats import paired_accuracy_test
from .detection_plan import DetectionPlan, plan_detection
from .table2 import table2_markdown

__all__ = ["benchmark_baselines", "detect_image", "detection_benchmark", "finish_detection",
           "summarize_detection", "train_saved"]

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------------------------
# Detection (the paper's Table 2)

def train_saved(path, samples, options: dict) -> list[str]:
    """Train a DLSR detector (:func:`dlsr.detection.train_detector`) and save it at ``path``
    (a task for the executor's workers).

    Parameters
    ----------
    path : str or Path
        Where the model goes (``MODEL.npz`` + ``MODEL.json``).
    samples : list of dlsr.datasets.GraspSample
    options : dict
        Keyword arguments of :func:`dlsr.detection.train_detector`.

    Returns
    -------
    list of str
        The files written.
    """
    return [str(q) for q in train_detector(samples, **options).save(path)]


def _detect_one(det, s, baselines, seed, base: dict) -> dict:
    """Detect on one labelled image and score it and the baselines by the rectangle metric."""
    return detect_image([det], s, baselines, seed, [base])[0]


def detect_image(detectors, s, baselines: dict, seed: int, bases: list[dict]) -> list[dict]:
    """One labelled image's results for several detectors (a task for the executor's
    workers): each detector's top rectangle scored by the rectangle metric against the
    image's positives, beside the baselines' (run once for all).

    The detectors detect through :func:`dlsr.detection.detect_many`, so lattice detectors
    that differ only in their model share their candidates and rectangle images; each
    result is the one the detector gives alone.

    Parameters
    ----------
    detectors : sequence of objects with ``detect(obs)``
    s : dlsr.datasets.GraspSample
    baselines : dict
        Name to detector with ``predict(obs)`` (:func:`benchmark_baselines`).
    seed : int
        The baselines' seed on this image.
    bases : list of dict
        Per detector, the fields its result starts from (``config_key``, ``fold``).

    Returns
    -------
    list of dict
        One ``results.jsonl`` record per detector.
    """
    obs = sample_observation(s)
    found = detect_many(detectors, obs)
    outcomes = {}
    for name, b in baselines.items():
        rects = b.predict(dict(obs, seed=seed))
        outcomes[name] = bool(rects) and rectangle_metric(rects[0], s.positives)
    out = []
    for d, base in zip(found, bases, strict=True):
        rec_ = {**base, "image_id": s.image_id, "object_id": s.object_id,
                "seconds": d.seconds, "n_candidates": d.n_candidates,
                "n_encodings": d.n_encodings, "reason": d.reason}
        if len(d.rects):
            top = d.rects[0]
            rec_.update(rect=top.tolist(), score=float(d.scores[0]),
                        success=rectangle_metric(top, s.positives),
                        jaccard=float(jaccard_matrix(top, s.positives).max()))
        else:
            rec_.update(rect=None, score=None, success=False, jaccard=0.0)
        rec_["baselines"] = dict(outcomes)
        out.append(rec_)
    return out


def detection_benchmark(
    data, format: str, out, scale=None, mapping=None, split: str = "object",
    learner: str | None = None, encoder: str | None = None, encoder_param=None,
    C: float | None = None, recognition_json=None, detector: str = "dense", n_folds: int = 5,
    n_atoms: int = 300, n_patches: int = 100_000, grid_negatives: float = 1.0,
    fit_grid: float | None = None, hard_negatives: int = 0, hard_rounds: int = 1,
    region: str = "auto", rescore: int = 300, clear_jaws: bool = False,
    coarse_to_fine: bool = False, max_images: int | None = None, n_overlays: int = 4,
    save_model=None, extra_patches=None, extra_train=None, extra_format: str | None = None,
    extra_scale=None, extra_mapping=None, model=None, physical: bool = False, seed: int = 0,
    progress: bool = True, executor=None, options=None, images=None,
    train_positives: int | None = None,
) -> dict:
    """Cross-validated detection accuracy by the rectangle metric (the paper's Table 2).

    Per fold (image- or object-wise), the recognition model is trained on the training images'
    rectangles plus ``grid_negatives`` negatives per labelled rectangle drawn from the
    detector's own candidate grid on the ``region``, the grid's sizes restricted to those of
    the fold's training positives when ``fit_grid`` is a quantile, and ``hard_negatives``
    per training image mined from the detector's own best failing candidates (``hard_rounds``
    rounds of mining and refitting)
    (:func:`dlsr.detection.train_detector`; saved to ``out/models/<key>_fold<k>``, keyed by
    the training configuration, so runs with other detector options reuse it) and
    each test image's best rectangle is checked against every positive with the rectangle
    metric; the baselines (``random`` on the object, ``mask-pca``) run on the same images.
    Results are appended per test image to ``out/results.jsonl`` and a rerun with the same
    configuration skips finished images and reuses saved fold models.

    ``clear_jaws`` searches only rectangles whose jaws come down beside the object region
    (:attr:`dlsr.detection.SearchGrid.clear_jaws`; detection only, the training is the same);
    with ``detector="lattice"`` (:class:`dlsr.detection.LatticeDetector`, whose candidates span
    the object by construction) it keeps the openings within this gripper's reach
    (:data:`graspsim.sim.gripper.MAX_OPENING`), which needs the images' camera matrices.
    ``physical`` trains each fold's SVM with the rectangles' physical features
    (``train_detector(physical=True)``; graspsim datasets record the camera matrices it needs).

    ``extra_patches`` (a patch file, :func:`dlsr.patches.load_patch_file`) joins unlabelled
    patches to each fold's whitening and dictionary learning only (self-taught learning, the
    paper's Table 3); the labelled training rectangles are unchanged. ``extra_train`` (a
    dataset folder in ``extra_format``, default ``format``, resized by ``extra_scale``, default
    that format's) adds its labelled images to every training fold, never to a test fold
    (for example synthetic images beside real ones).

    With ``model`` (a saved :class:`dlsr.detection.DLSRDetector`, ``PATH`` of ``PATH.npz`` and
    ``PATH.json``) nothing is trained: the model detects on every labelled image of ``data``
    (cross-dataset evaluation, e.g. trained in simulation and tested on real images), with
    the same per-image results and baselines; the split, folds and training options do not
    apply and are refused. ``learner`` and ``encoder`` default to NKM and Natural, or to the
    model's (a different one given with a model is refused).

    Writes ``detection.json`` (accuracy per fold and overall, seconds per image, candidates per
    second, baselines, the per-image outcomes and exact McNemar tests of the detector against
    each baseline on the same images), ``table2.md`` and ``overlays/{best,worst}_*.png``
    (detection in red and blue, the labelled positives in yellow and grey).

    ``options`` (a :class:`graspsim.detectors.dlsr_options.DetectorOptions`, the command's
    ``--preset`` and detector flags) replaces ``detector``, ``physical`` and ``clear_jaws``:
    its ``physical`` trains the folds' SVMs with physical features (with ``model``: keeps the
    model's physical term), and each fold's detector is
    :func:`graspsim.detectors.dlsr_options.build_real_detector` (the lattice or grid search, the
    completed region, the clear-jaws grid and the gripper-aware check on the images' camera
    matrices, :mod:`dlsr.intrinsics`).

    ``images`` (a collection of image ids) keeps only those images of ``data`` (for the
    inner folds of :func:`nested_detector_choice`). ``train_positives`` trains each fold on a
    seeded random subset of at most that many positives per training image (a cheaper
    training; the test images keep all theirs for the rectangle metric).

    Test images of a fold are detected through ``executor`` (a
    :class:`graspsim.runtime.executor.Executor`: local processes or a Ray cluster; sequential when
    None); results are written in image order as they arrive.

    Returns
    -------
    dict
        The content of ``detection.json``.
    """
    plan = plan_detection(
        data, format, out, scale=scale, mapping=mapping, split=split, learner=learner,
        encoder=encoder, encoder_param=encoder_param, C=C, recognition_json=recognition_json,
        detector=detector, n_folds=n_folds, n_atoms=n_atoms, n_patches=n_patches,
        grid_negatives=grid_negatives, fit_grid=fit_grid, hard_negatives=hard_negatives,
        hard_rounds=hard_rounds, region=region, rescore=rescore, clear_jaws=clear_jaws,
        coarse_to_fine=coarse_to_fine, max_images=max_images, save_model=save_model,
        extra_patches=extra_patches, extra_train=extra_train, extra_format=extra_format,
        extra_scale=extra_scale, extra_mapping=extra_mapping, model=model, physical=physical,
        seed=seed, options=options, images=images, train_positives=train_positives)
    executor = Executor("sequential", progress=False) if executor is None else executor
    t_run = time.perf_counter()
    if model is None:
        _train_fold_models(plan, executor)
    _detect_folds(plan, executor, progress)
    summary = finish_detection(plan, time.perf_counter() - t_run, n_overlays)
    if save_model is not None:
        cfg = plan.config
        full = train_detector(plan.samples + plan.extra_samples, **plan.training,
                              random_state=seed, detector=cfg["detector"],
                              rescore=cfg["rescore"])
        full.save(save_model)
        summary["model"] = str(save_model)
    return summary


def benchmark_baselines(region: str = "auto") -> dict:
    """The baselines a detection benchmark scores on every image: ``random`` (a rectangle on
    the object ``region``) and ``mask-pca``."""
    return {"random": ObjectRandomDetector(region=region), "mask-pca": MaskPCADetector()}


def finish_detection(plan: DetectionPlan, seconds: float, n_overlays: int = 4) -> dict:
    """Steps 8 and 9 of :func:`detection_benchmark`, once every image of ``plan`` is in
    ``plan.done``: ``detection.json`` (with ``seconds_this_run``), ``table2.md`` and the
    overlays written.

    Returns
    -------
    dict
        The content of ``detection.json``.
    """
    recs = [plan.done[s.image_id] for s in plan.samples]
    baselines = list(benchmark_baselines())
    summary = summarize_detection(recs, plan.samples, plan.folds, baselines, plan.config)
    summary["seconds_this_run"] = seconds
    write_text_atomic(plan.out / "detection.json", json.dumps(summary, indent=2))
    write_text_atomic(plan.out / "table2.md", table2_markdown(summary))
    _write_overlays(plan.out / "overlays", plan.samples, recs, n_overlays)
    return summary


def _train_fold_models(plan: DetectionPlan, executor) -> None:
    """Step 6: the folds' models that are missing and still needed, side by side on the
    executor's workers (each fold is trained from its own seed, so where it runs changes
    nothing)."""
    tasks = [(plan.fold_model_path(k), plan.fold_training_samples(k),
              {**plan.training, "random_state": plan.seed + k})
             for k in plan.folds_to_train()]
    for _ in executor.imap(train_saved, tasks, desc="fold models", star=True):
        pass


def _detect_folds(plan: DetectionPlan, executor, progress) -> None:
    """Step 7: each fold's missing test images detected with its model, appended to
    ``results.jsonl`` as they arrive and put in ``plan.done``."""
    samples, done = plan.samples, plan.done
    baselines = benchmark_baselines(plan.training["region"])
    bar = tqdm(total=len(samples), initial=len(done), desc="detection", disable=not progress)
    for k, (_, test) in enumerate(plan.folds):
        todo = [i for i in test if samples[i].image_id not in done]
        if not todo:
            continue
        det = plan.fold_detector(k)
        tasks = [(det, samples[i], baselines, plan.seed + i,
                  {"config_key": plan.key, "fold": k}) for i in todo]
        for rec_ in executor.imap(_detect_one, tasks, desc=f"fold {k}", star=True):
            plan.add_result(rec_)
            bar.update(1)
    bar.close()


def summarize_detection(recs: list[dict], samples, folds, baselines: list[str],
                        config: dict) -> dict:
    """Accuracy per fold and overall, the baselines and the paired tests of a detection
    benchmark (step 8; ``detection.json`` without ``seconds_this_run``).

    Parameters
    ----------
    recs : list of dict
        One result per image of ``samples``, in their order.
    samples : list of dlsr.datasets.GraspSample
    folds : list of (train, test)
        Index lists into ``samples``.
    baselines : list of str
        The baselines' names (their outcomes are in each result's ``baselines``).
    config : dict
        The run's configuration.

    Returns
    -------
    dict
    """
    fold_of = {samples[i].image_id: k for k, (_, te) in enumerate(folds) for i in te}
    per_fold = []
    for k in range(len(folds)):
        rs = [r for r in recs if fold_of[r["image_id"]] == k]
        per_fold.append({
            "fold": k, "n_images": len(rs),
            "accuracy": float(np.mean([r["success"] for r in rs])) if rs else None,
            "baselines": {n: float(np.mean([r["baselines"][n] for r in rs])) if rs else None
                          for n in baselines},
        })
    secs = np.array([r["seconds"] for r in recs])
    cands = np.array([r["n_candidates"] for r in recs])
    success = [bool(r["success"]) for r in recs]
    return {
        "config": config,
        "machine": machine_record(),
        "accuracy": float(np.mean(success)),
        "accuracy_fold_mean": float(np.mean([f["accuracy"] for f in per_fold])),
        "accuracy_fold_std": float(np.std([f["accuracy"] for f in per_fold])),
        "baselines": {n: float(np.mean([r["baselines"][n] for r in recs])) for n in baselines},
        "vs_baselines": {n: paired_accuracy_test(success, [r["baselines"][n] for r in recs])
                         for n in baselines},
        "folds": per_fold,
        "per_image": [{"image_id": r["image_id"], "object_id": r["object_id"],
                       "fold": fold_of[r["image_id"]], "success": bool(r["success"]),
                       "jaccard": r["jaccard"],
                       "baselines": {n: bool(r["baselines"][n]) for n in baselines}}
                      for r in recs],
        "seconds_per_image": float(secs.mean()),
        "candidates_per_second": float(cands.sum() / max(secs.sum(), 1e-9)),
        "n_empty": int(sum(r["rect"] is None for r in recs)),
    }


def _write_overlays(folder: Path, samples, recs, n_overlays: int) -> None:
    """Step 9: pictures of the best and worst detections (by the best Jaccard index with a
    positive): the detection in red and blue, the labelled positives in yellow and grey."""
    folder.mkdir(exist_ok=True)
    by_id = {s.image_id: s for s in samples}
    ranked = sorted(recs, key=lambda r: (r["success"], r["jaccard"]))
    picks = [("worst", r) for r in ranked[:n_overlays]]
    picks += [("best", r) for r in ranked[::-1][:n_overlays]]
    for tag, r in picks:
        s = by_id[r["image_id"]]
        rects = [] if r["rect"] is None else as_rect_array(np.asarray(r["rect"]))
        img = draw_rectangles(s.rgb, rects, negatives=s.positives)
        name = "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in str(s.image_id))
        Image.fromarray(img).save(folder / f"{tag}_{name}.png")
