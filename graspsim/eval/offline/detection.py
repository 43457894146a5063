"""The paper's detection benchmark (Table 2) behind ``graspsim benchmark detection``:
cross-validated detection accuracy by the rectangle metric, with the baselines on the same
images and paired tests against them.

:func:`detection_benchmark` runs in named steps: the saved model checked (with ``model``), the
extra training images, the labelled images, the folds, the configuration (whose digest keys
the results), the missing fold models trained, the missing test images detected (each fold's
detector: :func:`_fold_detector`), the summary (:func:`summarize_detection`), the overlays,
and the model on every image (``save_model``).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import platform
import time
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm.auto import tqdm

from dlsr import datasets
from dlsr.detection import (
    DETECTOR_KINDS,
    DLSRDetector,
    check_training_options,
    sample_observation,
    train_detector,
)
from dlsr.features import ENCODERS, LEARNERS
from dlsr.metrics import jaccard_matrix, rectangle_metric
from dlsr.patches import load_patch_file
from dlsr.records import read_jsonl, write_text_atomic
from dlsr.rectangles import as_rect_array
from dlsr.viz import draw_rectangles

from ...data.samples import load_samples
from ...detectors.baselines import MaskPCADetector, ObjectRandomDetector
from ...detectors.dlsr_options import build_real_detector
from ...runtime.executor import Executor
from ...sim.gripper import MAX_OPENING
from ..stats import paired_accuracy_test
from .recognition import recognition_choice
from .table2 import table2_markdown

__all__ = ["TRAINING_KEYS", "detection_benchmark", "summarize_detection", "train_saved"]

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
    obs = sample_observation(s)
    d = det.detect(obs)
    rec_ = {**base, "image_id": s.image_id, "object_id": s.object_id, "seconds": d.seconds,
            "n_candidates": d.n_candidates, "n_encodings": d.n_encodings, "reason": d.reason}
    if len(d.rects):
        top = d.rects[0]
        rec_.update(rect=top.tolist(), score=float(d.scores[0]),
                    success=rectangle_metric(top, s.positives),
                    jaccard=float(jaccard_matrix(top, s.positives).max()))
    else:
        rec_.update(rect=None, score=None, success=False, jaccard=0.0)
    rec_["baselines"] = {}
    for name, b in baselines.items():
        rects = b.predict(dict(obs, seed=seed))
        rec_["baselines"][name] = bool(rects) and rectangle_metric(rects[0], s.positives)
    return rec_


def _file_digest(*paths) -> str:
    h = hashlib.sha1()
    for p in paths:
        with open(p, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:12]


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
    if options is not None:
        detector, clear_jaws = options.detector, False
        physical = options.physical and model is None
    if detector not in DETECTOR_KINDS:
        raise ValueError(f"detector must be one of {DETECTOR_KINDS}, got {detector!r}")
    fixed = None
    if model is not None:
        fixed = _saved_model(model, learner, encoder, extra_patches=extra_patches,
                             extra_train=extra_train, save_model=save_model,
                             recognition_json=recognition_json, fit_grid=fit_grid,
                             hard_negatives=hard_negatives, physical=physical,
                             encoder_param=encoder_param, C=C)
        learner, encoder = fixed.representation.learner, fixed.encoder
    learner = "NKM" if learner is None else learner
    encoder = "Natural" if encoder is None else encoder
    if learner not in LEARNERS:
        raise ValueError(f"unknown learner {learner!r}; choose from {LEARNERS}")
    if encoder not in ENCODERS:
        raise ValueError(f"unknown encoder {encoder!r}; choose from {ENCODERS}")
    check_training_options(fit_grid, hard_negatives, hard_rounds, physical)
    extra = None if extra_patches is None else load_patch_file(extra_patches)
    extra_format = format if extra_format is None else extra_format
    extra_samples = _extra_training(extra_train, extra_format, extra_scale, extra_mapping)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    samples = _labelled_samples(data, format, scale, mapping, images, max_images)
    split, n_folds, folds = _benchmark_folds(samples, data, model, split, n_folds, seed)
    if recognition_json is not None:
        p, c = recognition_choice(recognition_json, learner, encoder)
        encoder_param = p if encoder_param is None else encoder_param
        C = c if C is None else C
    C = 1.0 if C is None else float(C)
    training = dict(learner=learner, encoder=encoder, encoder_param=encoder_param, C=C,
                    n_atoms=n_atoms, n_patches=n_patches, grid_negatives=grid_negatives,
                    fit_grid=fit_grid, hard_negatives=hard_negatives, hard_rounds=hard_rounds,
                    extra_patches=extra, physical=physical, region=region)
    config = _benchmark_config(
        data=data, format=format, scale=scale, split=split, n_folds=n_folds, model=model,
        fixed=fixed, training=training, detector=detector, rescore=rescore,
        coarse_to_fine=coarse_to_fine, n_images=len(samples), seed=seed, clear_jaws=clear_jaws,
        options=options, train_positives=train_positives, images=images,
        extra_patches=extra_patches, extra_train=extra_train, extra_format=extra_format,
        extra_scale=extra_scale, n_extra=len(extra_samples))
    key = _digest(config)
    models = out / "models" / _digest({k: config[k] for k in TRAINING_KEYS if k in config})
    results_path = out / "results.jsonl"
    done = {r["image_id"]: r
            for r in read_jsonl(results_path, required=("image_id",), repair=True)
            if r.get("config_key") == key}
    baselines = {"random": ObjectRandomDetector(region=region), "mask-pca": MaskPCADetector()}
    executor = Executor("sequential", progress=False) if executor is None else executor
    t_run = time.perf_counter()
    if model is None:
        _train_fold_models(models, samples, folds, done, extra_samples, training,
                           train_positives, seed, executor)

    fold_detector = functools.partial(
        _fold_detector, fixed=fixed, models=models, options=options, detector=detector,
        region=region, rescore=rescore, coarse_to_fine=coarse_to_fine, clear_jaws=clear_jaws)
    _detect_folds(samples, folds, done, fold_detector, baselines, key, seed, results_path,
                  executor, progress)
    recs = [done[s.image_id] for s in samples]
    summary = summarize_detection(recs, samples, folds, list(baselines), config)
    summary["seconds_this_run"] = time.perf_counter() - t_run
    write_text_atomic(out / "detection.json", json.dumps(summary, indent=2))
    write_text_atomic(out / "table2.md", table2_markdown(summary))
    _write_overlays(out / "overlays", samples, recs, n_overlays)
    if save_model is not None:
        full = train_detector(samples + extra_samples, **training, random_state=seed,
                              detector=detector, rescore=rescore)
        full.save(save_model)
        summary["model"] = str(save_model)
    return summary


#: The configuration keys a fold's model depends on (models are shared by detector options).
TRAINING_KEYS = ("data", "format", "scale", "split", "learner", "encoder", "encoder_param", "C",
                 "n_folds", "n_atoms", "n_patches", "grid_negatives", "fit_grid", "region",
                 "n_images", "seed", "hard_negatives", "hard_rounds", "extra_patches",
                 "extra_train", "physical", "images", "train_positives")


def _digest(config: dict) -> str:
    return hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:12]


def _saved_model(model, learner, encoder, **not_with_a_model):
    """Step 1 with ``model``: the saved detector, checked against the arguments a saved model
    cannot take (``not_with_a_model``, their defaults None, or 0 and False) and against the
    learner and encoder given."""
    defaults = {"hard_negatives": 0, "physical": False}
    refused = [name for name, value in not_with_a_model.items()
               if value != defaults.get(name)]
    if refused:
        raise ValueError(f"a saved model is evaluated without training: "
                         f"{', '.join(refused)} cannot be used with it")
    fixed = DLSRDetector.load(model)  # FileNotFoundError / ValueError naming the file
    for name, given, has in (("learner", learner, fixed.representation.learner),
                             ("encoder", encoder, fixed.encoder)):
        if given is not None and given != has:
            raise ValueError(f"{name} {given!r} given, but the model {model} has {has!r}")
    return fixed


def _extra_training(extra_train, extra_format, extra_scale, extra_mapping) -> list:
    """Step 2: the labelled images of the extra training data (none without it)."""
    if extra_train is None:
        return []
    extra = [s for s in load_samples(extra_train, extra_format, extra_scale, extra_mapping)
             if s.positives]
    if not extra:
        raise ValueError(f"no labelled images in the extra training data {extra_train}")
    return extra


def _labelled_samples(data, format, scale, mapping, images, max_images) -> list:
    """Step 3: the dataset's labelled images, only ``images`` when given, the first
    ``max_images``."""
    samples = [s for s in load_samples(data, format, scale, mapping) if s.positives]
    if images is not None:
        wanted = {str(i) for i in images}
        missing = wanted - {s.image_id for s in samples}
        if missing:
            raise ValueError(f"images not among the labelled images of {data}: "
                             f"{sorted(missing)[:5]}")
        samples = [s for s in samples if s.image_id in wanted]
    if max_images is not None:
        samples = samples[:max_images]
    return samples


def _benchmark_folds(samples, data, model, split, n_folds, seed):
    """Step 4: ``(split, n_folds, folds)``, one fold of every image for a saved model."""
    if model is not None:
        if not samples:
            raise ValueError(f"no labelled images in {data}")
        return "model", 1, [(None, list(range(len(samples))))]
    if len(samples) < n_folds:
        raise ValueError(f"{len(samples)} labelled images cannot make {n_folds} folds")
    if split == "object":
        return split, n_folds, datasets.object_wise_folds(samples, n_folds, seed)
    if split == "image":
        return split, n_folds, datasets.image_wise_folds(samples, n_folds, seed)
    raise ValueError(f"split must be 'image' or 'object', got {split!r}")


def _benchmark_config(*, data, format, scale, split, n_folds, model, fixed, training, detector,
                      rescore, coarse_to_fine, n_images, seed, clear_jaws, options,
                      train_positives, images, extra_patches, extra_train, extra_format,
                      extra_scale, n_extra) -> dict:
    """Step 5: what ``detection.json`` records as the run's configuration; its digest keys the
    per-image results (a rerun of the same configuration resumes)."""
    t = training
    if model is not None:
        model_npz, model_json = DLSRDetector._paths(model)
        config = {
            "data": str(data), "format": format, "scale": scale, "split": split,
            "model": str(model), "model_digest": _file_digest(model_json, model_npz),
            "learner": t["learner"], "encoder": t["encoder"],
            "encoder_param": fixed.encoder_param, "detector": detector, "n_folds": 1,
            "region": t["region"], "rescore": rescore, "coarse_to_fine": coarse_to_fine,
            "n_images": n_images, "seed": seed,
            "model_config": {k: v for k, v in fixed.config.items() if k != "grid"},
        }
    else:
        config = {
            "data": str(data), "format": format, "scale": scale, "split": split,
            "learner": t["learner"], "encoder": t["encoder"],
            "encoder_param": t["encoder_param"], "C": t["C"], "detector": detector,
            "n_folds": n_folds, "n_atoms": t["n_atoms"], "n_patches": t["n_patches"],
            "grid_negatives": float(t["grid_negatives"]),
            "fit_grid": None if t["fit_grid"] is None else float(t["fit_grid"]),
            "region": t["region"], "rescore": rescore, "coarse_to_fine": coarse_to_fine,
            "n_images": n_images, "seed": seed,
        }
    # options added later enter the keys only when used: earlier runs' results still match
    if clear_jaws:
        config["clear_jaws"] = True
    if t["physical"]:
        config["physical"] = True
    if options is not None:
        config["options"] = dataclasses.asdict(options)
    if train_positives is not None:
        config["train_positives"] = int(train_positives)
    if images is not None:
        config["images"] = hashlib.sha1(" ".join(sorted(str(i) for i in images))
                                        .encode()).hexdigest()[:12]
    if t["hard_negatives"]:
        config["hard_negatives"] = int(t["hard_negatives"])
        if t["hard_rounds"] != 1:
            config["hard_rounds"] = int(t["hard_rounds"])
    if t["extra_patches"] is not None:
        config["extra_patches"] = {"path": str(extra_patches),
                                   "n": int(len(t["extra_patches"][0])),
                                   "digest": _file_digest(extra_patches)}
    if n_extra:
        config["extra_train"] = {"data": str(extra_train), "format": extra_format,
                                 "scale": extra_scale, "n_images": n_extra}
    return config


def _fold_model_path(models: Path, k: int) -> Path:
    return models.with_name(f"{models.name}_fold{k}")


def _train_fold_models(models, samples, folds, done, extra_samples, training, train_positives,
                       seed, executor) -> None:
    """Step 6: the folds' models that are missing and still needed, side by side on the
    executor's workers (each fold is trained from its own seed, so where it runs changes
    nothing)."""
    to_train = [k for k, (_, test) in enumerate(folds)
                if any(samples[i].image_id not in done for i in test)
                and not _fold_model_path(models, k).with_name(
                    f"{models.name}_fold{k}.json").is_file()]
    tasks = [(_fold_model_path(models, k),
              _fewer_positives([samples[i] for i in folds[k][0]], train_positives, seed + k)
              + extra_samples, {**training, "random_state": seed + k})
             for k in to_train]
    for _ in executor.imap(train_saved, tasks, desc="fold models", star=True):
        pass


def _fold_detector(k: int, *, fixed, models, options, detector, region, rescore,
                   coarse_to_fine, clear_jaws):
    """Fold ``k``'s detector: the saved model (``fixed``) or the fold's, searched as
    ``options`` say (:func:`graspsim.detectors.dlsr_options.build_real_detector`) or as the
    benchmark's own arguments say."""
    fold_model = fixed if fixed is not None else DLSRDetector.load(_fold_model_path(models, k))
    if options is not None:
        return build_real_detector(fold_model, options, region=region, rescore=rescore,
                                   coarse_to_fine=coarse_to_fine)
    return _benchmark_detector(fold_model, detector, region, rescore, coarse_to_fine, clear_jaws)


def _detect_folds(samples, folds, done, fold_detector, baselines, key, seed, results_path,
                  executor, progress) -> None:
    """Step 7: each fold's missing test images detected with its model, appended to
    ``results.jsonl`` as they arrive and put in ``done``."""
    bar = tqdm(total=len(samples), initial=len(done), desc="detection", disable=not progress)
    for k, (_, test) in enumerate(folds):
        todo = [i for i in test if samples[i].image_id not in done]
        if not todo:
            continue
        det = fold_detector(k)
        tasks = [(det, samples[i], baselines, seed + i, {"config_key": key, "fold": k})
                 for i in todo]
        for rec_ in executor.imap(_detect_one, tasks, desc=f"fold {k}", star=True):
            with results_path.open("a") as fh:
                fh.write(json.dumps(rec_) + "\n")
            done[rec_["image_id"]] = rec_
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
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "python": platform.python_version()},
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

def _fewer_positives(samples, n: int | None, seed: int):
    """``samples`` with at most ``n`` of their positives each (a seeded random subset, in
    their order); ``samples`` itself when ``n`` is None."""
    if n is None:
        return samples
    if n < 1:
        raise ValueError(f"train_positives must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    out = []
    for s in samples:
        keep = np.sort(rng.choice(len(s.positives), min(n, len(s.positives)), replace=False))
        out.append(dataclasses.replace(s, positives=[s.positives[i] for i in keep]))
    return out


def _benchmark_detector(model, kind: str, region: str, rescore: int, coarse_to_fine: bool,
                        clear_jaws: bool):
    """The detector of :func:`detection_benchmark` on a (fold) model."""
    if kind == "lattice":
        return model.detector("lattice", region=region,
                              max_width=MAX_OPENING if clear_jaws else None)
    if kind == "exact":
        det = model.detector("exact", region=region)
    else:
        det = model.detector("dense", region=region, rescore=rescore,
                             **({"coarse_to_fine": True} if coarse_to_fine else {}))
    if clear_jaws:
        det.grid = dataclasses.replace(det.grid, clear_jaws=True)
    return det


# ---------------------------------------------------------------------------------------------
# Self-taught learning in detection (the paper's Table 3)
