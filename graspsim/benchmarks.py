"""Library entry points behind ``graspsim benchmark``: load a dataset and run a benchmark."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from dlsr import recognition as rec
from dlsr.features import ENCODERS, LEARNERS
from dlsr.metrics import jaccard_matrix, rectangle_metric
from dlsr.records import CorruptFileError, file_errors, read_json, read_jsonl, write_text_atomic

log = logging.getLogger(__name__)

DEFAULT_SCALE = {"cornell": 1.0, "jacquard": 0.5}


def load_samples(data, format: str, scale: float | None = None, mapping=None):
    """Load a Cornell or Jacquard dataset folder as a list of GraspSample."""
    from dlsr import datasets

    root = Path(data)
    if not root.exists():
        raise FileNotFoundError(f"dataset folder not found: {root}")
    scale = DEFAULT_SCALE[format] if scale is None else scale
    if format == "cornell":
        samples = datasets.load_cornell(root, mapping=mapping, scale=scale)
    elif format == "jacquard":
        samples = datasets.load_jacquard(root, scale=scale)
    else:
        raise ValueError(f"format must be 'cornell' or 'jacquard', got {format!r}")
    if not samples:
        raise ValueError(f"no images found in {root} (format {format})")
    return samples


def recognition_benchmark(
    data, format: str, out, scale=None, mapping=None, learners=None, encoders=None,
    n_atoms=300, n_patches=100_000, split="image", n_folds=5, inner_folds=5,
    paper_grid=False, whiten=True, extra_patches=None, max_rectangles=None, figure5=False,
    n_jobs=1, seed=0, progress=True,
) -> dict:
    """Load ``data`` and run :func:`dlsr.recognition.run_recognition_benchmark`."""
    extra = None
    if extra_patches is not None:  # first: a bad file is reported before any long work
        from dlsr.patches import load_patch_file

        extra = load_patch_file(extra_patches)
    samples = load_samples(data, format, scale, mapping)
    rd = rec.recognition_data(samples, random_state=seed, max_rectangles=max_rectangles,
                              subset_random_state=seed)
    log.info("%d rectangles (%d positive) from %d images", len(rd), int(rd.labels.sum()),
             len(samples))
    # the rectangle images are all the benchmark reads: the whole images (2.5 MB each, 2.2 GB
    # at Cornell's 885) are not held through the hours of the table
    del samples
    return rec.run_recognition_benchmark(
        rd, out, learners=learners or LEARNERS, encoders=encoders or ENCODERS, split=split,
        n_folds=n_folds, inner_folds=inner_folds,
        C_grid=rec.PAPER_C_GRID if paper_grid else rec.C_GRID, n_atoms=n_atoms, whiten=whiten,
        n_patches=n_patches, extra=extra, random_state=seed, n_jobs=n_jobs, progress=progress,
        figure5_sizes=(50, 100, 200, 300, 400) if figure5 else None,
    )


# ---------------------------------------------------------------------------------------------
# Detection (the paper's Table 2)

#: Table 2 of the paper (detection accuracy %, Cornell, rectangle metric): (image-wise,
#: object-wise); None where shared/reference/dlsr-reference-facts.md records no number.
PAPER_TABLE2 = (
    ("Jiang et al. (2011)", 60.5, 58.3, "prior work"),
    ("Lenz et al. (2015)", 73.9, 75.6, "prior work"),
    ("Redmon and Angelova (2015)", 88.0, 87.1, "prior work"),
    ("NKM-Natural", 89.40, None, "paper"),
    ("GSVQ-ST", None, 88.79, "paper"),
    ("NKM-SC", 88.67, 88.07, "paper"),
    ("OMP-Natural", 89.34, 88.56, "paper"),
    ("RP-Natural", 87.70, 86.61, "paper"),
)


class ObjectRandomDetector:
    """Baseline: a uniformly random rectangle on the object region (the issue's ``random``).

    Centre on a random object pixel, angle uniform, opening and jaw uniform in ``[10, 90]``
    with opening >= jaw. The region is found as the DLSR detectors find it
    (:func:`dlsr.detection.object_region`); with no region, anywhere in the image.
    """

    requires_labels = False

    def __init__(self, region: str = "auto", random_state=None):
        self.region = region
        self.random_state = random_state

    def predict(self, obs):
        from dlsr.detection import object_region
        from dlsr.rectangles import GraspRectangle

        rng = np.random.default_rng(obs.get("seed", self.random_state))
        region, _ = object_region(obs, method=self.region)
        if region.any():
            rows, cols = np.nonzero(region)
            i = rng.integers(len(rows))
            x, y = float(cols[i]), float(rows[i])
        else:
            H, W = np.asarray(obs["depth"]).shape
            x, y = rng.uniform(0, W - 1), rng.uniform(0, H - 1)
        w, h = sorted(rng.uniform(10, 90, size=2), reverse=True)
        return [GraspRectangle(x, y, rng.uniform(-np.pi / 2, np.pi / 2), w, h)]


def _recognition_choice(path, learner: str, encoder: str):
    """The most often chosen (encoder_param, C) of a recognition.json cell, or (None, None)."""
    import json
    from collections import Counter

    summary = read_json(path, "recognition results")
    with file_errors(path, "recognition results"):
        for cell in summary.get("cells", []):
            if cell.get("learner") == learner and cell.get("encoder") == encoder:
                params = Counter(json.dumps(f.get("encoder_param")) for f in cell["folds"])
                Cs = Counter(f.get("C") for f in cell["folds"])
                return json.loads(params.most_common(1)[0][0]), Cs.most_common(1)[0][0]
    raise ValueError(f"{path}: no {learner}-{encoder} cell to take hyper-parameters from")


def _train_saved(path, samples, options: dict) -> list[str]:
    """Train a DLSR detector (:func:`dlsr.detection.train_detector`) and save it at ``path``
    (a task for the executor's workers); returns the files written."""
    from dlsr.detection import train_detector

    return [str(q) for q in train_detector(samples, **options).save(path)]


def _detect_one(det, s, baselines, seed, base: dict) -> dict:
    """Detect on one labelled image and score it and the baselines by the rectangle metric."""
    from dlsr.detection import sample_observation

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


def mcnemar_exact(a, b) -> dict:
    """Exact McNemar test of two paired per-image outcomes (two-sided binomial on discordants).

    Parameters
    ----------
    a, b : array-like of bool, shape (n,)
        Per-image success of two methods on the same images, in the same order.

    Returns
    -------
    dict
        ``n`` images, ``a_only`` and ``b_only`` (images one method wins alone), the accuracies
        ``a`` and ``b``, and ``p_value`` (:func:`graspsim.compare.mcnemar_exact`); 1.0 when
        there is no discordant pair.
    """
    from . import compare

    counts = compare.paired_counts(a, b)
    n = sum(counts.values())
    return {"n": n,
            "a": (counts["both"] + counts["only_a"]) / n if n else None,
            "b": (counts["both"] + counts["only_b"]) / n if n else None,
            "a_only": counts["only_a"], "b_only": counts["only_b"],
            "p_value": compare.mcnemar_exact(counts["only_a"], counts["only_b"])}


def _file_digest(*paths) -> str:
    import hashlib

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
    (:data:`graspsim.gripper.MAX_OPENING`), which needs the images' camera matrices.
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

    ``options`` (a :class:`graspsim.detector_options.DetectorOptions`, the command's
    ``--preset`` and detector flags) replaces ``detector``, ``physical`` and ``clear_jaws``:
    its ``physical`` trains the folds' SVMs with physical features (with ``model``: keeps the
    model's physical term), and each fold's detector is
    :func:`graspsim.detector_options.build_real_detector` (the lattice or grid search, the
    completed region, the clear-jaws grid and the gripper-aware check on the images' camera
    matrices, :mod:`dlsr.intrinsics`).

    ``images`` (a collection of image ids) keeps only those images of ``data`` (for the
    inner folds of :func:`nested_detector_choice`). ``train_positives`` trains each fold on a
    seeded random subset of at most that many positives per training image (a cheaper
    training; the test images keep all theirs for the rectangle metric).

    Test images of a fold are detected through ``executor`` (a
    :class:`graspsim.executor.Executor`: local processes or a Ray cluster; sequential when
    None); results are written in image order as they arrive.

    Returns
    -------
    dict
        The content of ``detection.json``.
    """
    import hashlib
    import json
    import platform
    import time

    from PIL import Image
    from tqdm.auto import tqdm

    from dlsr import datasets
    from dlsr.detection import DETECTOR_KINDS, DLSRDetector, check_training_options, train_detector
    from dlsr.rectangles import as_rect_array
    from dlsr.viz import draw_rectangles

    from .detectors import MaskPCADetector

    if options is not None:
        detector, clear_jaws = options.detector, False
        physical = options.physical and model is None
    if detector not in DETECTOR_KINDS:
        raise ValueError(f"detector must be one of {DETECTOR_KINDS}, got {detector!r}")
    if model is not None:
        refused = [name for name, value, default in (
            ("extra_patches", extra_patches, None), ("extra_train", extra_train, None),
            ("save_model", save_model, None), ("recognition_json", recognition_json, None),
            ("fit_grid", fit_grid, None), ("hard_negatives", hard_negatives, 0),
            ("physical", physical, False),
            ("encoder_param", encoder_param, None), ("C", C, None)) if value != default]
        if refused:
            raise ValueError(f"a saved model is evaluated without training: "
                             f"{', '.join(refused)} cannot be used with it")
        model_npz, model_json = DLSRDetector._paths(model)
        fixed = DLSRDetector.load(model)  # FileNotFoundError / ValueError naming the file
        for name, given, has in (("learner", learner, fixed.representation.learner),
                                 ("encoder", encoder, fixed.encoder)):
            if given is not None and given != has:
                raise ValueError(f"{name} {given!r} given, but the model {model} has {has!r}")
        learner, encoder = fixed.representation.learner, fixed.encoder
    learner = "NKM" if learner is None else learner
    encoder = "Natural" if encoder is None else encoder
    if learner not in LEARNERS:
        raise ValueError(f"unknown learner {learner!r}; choose from {LEARNERS}")
    if encoder not in ENCODERS:
        raise ValueError(f"unknown encoder {encoder!r}; choose from {ENCODERS}")
    check_training_options(fit_grid, hard_negatives, hard_rounds, physical)
    extra = None
    if extra_patches is not None:
        from dlsr.patches import load_patch_file

        extra = load_patch_file(extra_patches)
    extra_samples = []
    if extra_train is not None:
        extra_format = format if extra_format is None else extra_format
        extra_samples = [s for s in load_samples(extra_train, extra_format, extra_scale,
                                                 extra_mapping) if s.positives]
        if not extra_samples:
            raise ValueError(f"no labelled images in the extra training data {extra_train}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    samples = load_samples(data, format, scale, mapping)
    samples = [s for s in samples if s.positives]
    if images is not None:
        wanted = {str(i) for i in images}
        missing = wanted - {s.image_id for s in samples}
        if missing:
            raise ValueError(f"images not among the labelled images of {data}: "
                             f"{sorted(missing)[:5]}")
        samples = [s for s in samples if s.image_id in wanted]
    if max_images is not None:
        samples = samples[:max_images]
    if model is not None:
        if not samples:
            raise ValueError(f"no labelled images in {data}")
        split, n_folds = "model", 1
        folds = [(None, list(range(len(samples))))]
    else:
        if len(samples) < n_folds:
            raise ValueError(f"{len(samples)} labelled images cannot make {n_folds} folds")
        folds = (datasets.object_wise_folds(samples, n_folds, seed) if split == "object"
                 else datasets.image_wise_folds(samples, n_folds, seed) if split == "image"
                 else None)
        if folds is None:
            raise ValueError(f"split must be 'image' or 'object', got {split!r}")
    if recognition_json is not None:
        p, c = _recognition_choice(recognition_json, learner, encoder)
        encoder_param = p if encoder_param is None else encoder_param
        C = c if C is None else C
    C = 1.0 if C is None else float(C)
    if model is not None:
        config = {
            "data": str(data), "format": format, "scale": scale, "split": split,
            "model": str(model), "model_digest": _file_digest(model_json, model_npz),
            "learner": learner, "encoder": encoder, "encoder_param": fixed.encoder_param,
            "detector": detector, "n_folds": 1, "region": region, "rescore": rescore,
            "coarse_to_fine": coarse_to_fine, "n_images": len(samples), "seed": seed,
            "model_config": {k: v for k, v in fixed.config.items() if k != "grid"},
        }
    else:
        config = {
            "data": str(data), "format": format, "scale": scale, "split": split,
            "learner": learner, "encoder": encoder, "encoder_param": encoder_param, "C": C,
            "detector": detector, "n_folds": n_folds, "n_atoms": n_atoms,
            "n_patches": n_patches, "grid_negatives": float(grid_negatives),
            "fit_grid": None if fit_grid is None else float(fit_grid), "region": region,
            "rescore": rescore, "coarse_to_fine": coarse_to_fine, "n_images": len(samples),
            "seed": seed,
        }
    # options added later enter the keys only when used: earlier runs' results still match
    if clear_jaws:
        config["clear_jaws"] = True
    if physical:
        config["physical"] = True
    if options is not None:
        config["options"] = dataclasses.asdict(options)
    if train_positives is not None:
        config["train_positives"] = int(train_positives)
    if images is not None:
        config["images"] = hashlib.sha1(" ".join(sorted(str(i) for i in images))
                                        .encode()).hexdigest()[:12]
    if hard_negatives:
        config["hard_negatives"] = int(hard_negatives)
        if hard_rounds != 1:
            config["hard_rounds"] = int(hard_rounds)
    if extra is not None:
        config["extra_patches"] = {"path": str(extra_patches), "n": int(len(extra[0])),
                                   "digest": _file_digest(extra_patches)}
    if extra_samples:
        config["extra_train"] = {"data": str(extra_train), "format": extra_format,
                                 "scale": extra_scale, "n_images": len(extra_samples)}
    key = hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:12]
    # fold models depend on the training configuration only (shared by detector options)
    train_cfg = {k: config[k] for k in ("data", "format", "scale", "split", "learner", "encoder",
                                        "encoder_param", "C", "n_folds", "n_atoms",
                                        "n_patches", "grid_negatives", "fit_grid", "region",
                                        "n_images", "seed", "hard_negatives", "hard_rounds",
                                        "extra_patches", "extra_train", "physical",
                                        "images", "train_positives")
                 if k in config}
    train_key = hashlib.sha1(json.dumps(train_cfg, sort_keys=True).encode()).hexdigest()[:12]
    results_path = out / "results.jsonl"
    done = {r["image_id"]: r
            for r in read_jsonl(results_path, required=("image_id",), repair=True)
            if r.get("config_key") == key}
    baselines = {"random": ObjectRandomDetector(region=region), "mask-pca": MaskPCADetector()}
    if executor is None:
        from .executor import Executor

        executor = Executor("sequential", progress=False)
    ex = executor
    t_run = time.perf_counter()

    def model_path(k):
        return out / "models" / f"{train_key}_fold{k}"

    # The folds' models first, side by side on the executor's workers (each fold is trained
    # from its own seed, so where it runs changes nothing), then each fold's test images.
    to_train = [k for k, (_, test) in enumerate(folds)
                if model is None and any(samples[i].image_id not in done for i in test)
                and not model_path(k).with_name(model_path(k).name + ".json").is_file()]
    train_tasks = [(model_path(k),
                    _fewer_positives([samples[i] for i in folds[k][0]], train_positives, seed + k)
                    + extra_samples,
                    dict(learner=learner, encoder=encoder, encoder_param=encoder_param, C=C,
                         n_atoms=n_atoms, n_patches=n_patches, grid_negatives=grid_negatives,
                         fit_grid=fit_grid, hard_negatives=hard_negatives,
                         hard_rounds=hard_rounds, extra_patches=extra, physical=physical,
                         random_state=seed + k, region=region))
                   for k in to_train]
    for _ in ex.imap(_train_saved, train_tasks, desc="fold models", star=True):
        pass
    bar = tqdm(total=len(samples), initial=len(done), desc="detection", disable=not progress)
    for k, (_, test) in enumerate(folds):
        todo = [i for i in test if samples[i].image_id not in done]
        if not todo:
            continue
        fold_model = fixed if model is not None else DLSRDetector.load(model_path(k))
        if options is not None:
            from .detector_options import build_real_detector

            det = build_real_detector(fold_model, options, region=region, rescore=rescore,
                                      coarse_to_fine=coarse_to_fine)
        else:
            det = _benchmark_detector(fold_model, detector, region, rescore, coarse_to_fine,
                                      clear_jaws)
        tasks = [(det, samples[i], baselines, seed + i, {"config_key": key, "fold": k})
                 for i in todo]
        for rec_ in ex.imap(_detect_one, tasks, desc=f"fold {k}", star=True):
            with results_path.open("a") as fh:
                fh.write(json.dumps(rec_) + "\n")
            done[rec_["image_id"]] = rec_
            bar.update(1)
    bar.close()
    recs = [done[s.image_id] for s in samples]
    fold_of = {samples[i].image_id: k for k, (_, te) in enumerate(folds) for i in te}
    per_fold = []
    for k in range(n_folds):
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
    summary = {
        "config": config,
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "python": platform.python_version()},
        "accuracy": float(np.mean(success)),
        "accuracy_fold_mean": float(np.mean([f["accuracy"] for f in per_fold])),
        "accuracy_fold_std": float(np.std([f["accuracy"] for f in per_fold])),
        "baselines": {n: float(np.mean([r["baselines"][n] for r in recs])) for n in baselines},
        "vs_baselines": {n: mcnemar_exact(success, [r["baselines"][n] for r in recs])
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
        "seconds_this_run": time.perf_counter() - t_run,
    }
    write_text_atomic(out / "detection.json", json.dumps(summary, indent=2))
    write_text_atomic(out / "table2.md", table2_markdown(summary))
    # overlays of the best and worst detections (by the best Jaccard index with a positive)
    ov = out / "overlays"
    ov.mkdir(exist_ok=True)
    by_id = {s.image_id: s for s in samples}
    ranked = sorted(recs, key=lambda r: (r["success"], r["jaccard"]))
    picks = [("worst", r) for r in ranked[:n_overlays]]
    picks += [("best", r) for r in ranked[::-1][:n_overlays]]
    for tag, r in picks:
        s = by_id[r["image_id"]]
        rects = [] if r["rect"] is None else as_rect_array(np.asarray(r["rect"]))
        img = draw_rectangles(s.rgb, rects, negatives=s.positives)
        name = "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in str(s.image_id))
        Image.fromarray(img).save(ov / f"{tag}_{name}.png")
    if save_model is not None:
        full = train_detector(samples + extra_samples, learner=learner, encoder=encoder,
                              encoder_param=encoder_param, C=C, n_atoms=n_atoms,
                              n_patches=n_patches, grid_negatives=grid_negatives,
                              fit_grid=fit_grid, hard_negatives=hard_negatives,
                              hard_rounds=hard_rounds, extra_patches=extra, random_state=seed,
                              physical=physical, detector=detector, region=region,
                              rescore=rescore)
        full.save(save_model)
        summary["model"] = str(save_model)
    return summary


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
        from .gripper import MAX_OPENING

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


def table2_markdown(summary: dict) -> str:
    """The paper's Table 2 layout (image-wise | object-wise) with our run and the baselines."""
    cfg = summary["config"]
    if cfg["split"] == "model":
        return _cross_markdown(summary)
    col = 1 if cfg["split"] == "image" else 2

    def cell(v):
        return "—" if v is None else f"{v:.2f}"

    lines = ["| method | image-wise (%) | object-wise (%) | source |", "|---|---|---|---|"]
    for name, img, obj, src in PAPER_TABLE2:
        lines.append(f"| {name} | {cell(img)} | {cell(obj)} | {src} (Cornell) |")
    where = f"{cfg['format']} `{Path(cfg['data']).name}`, {cfg['n_images']} images"
    ours = [(f"{cfg['learner']}-{cfg['encoder']} ({cfg['detector']} detector)",
             summary["accuracy"])]
    ours += [(f"baseline: {n}", v) for n, v in summary["baselines"].items()]
    for name, acc in ours:
        vals = [None, None]
        vals[col - 1] = 100 * acc
        lines.append(f"| {name} | {cell(vals[0])} | {cell(vals[1])} | this run ({where}) |")
    lines.append("")
    lines.append(
        f"Detection accuracy by the rectangle metric (top-1 rectangle within 30 degrees and "
        f"Jaccard > 0.25 of some positive), {cfg['n_folds']}-fold {cfg['split']}-wise cross-"
        f"validation. Paper and prior-work rows: Trottier et al. 2016, Table 2, on Cornell; "
        f"only the cells recorded in the reference facts are shown. Seconds per image: "
        f"{summary['seconds_per_image']:.2f}."
    )
    return "\n".join(lines) + "\n"


def _cross_markdown(summary: dict) -> str:
    """A saved model evaluated on another dataset, beside the baselines on the same images."""
    cfg = summary["config"]
    n = cfg["n_images"]
    scale = DEFAULT_SCALE[cfg["format"]] if cfg["scale"] is None else cfg["scale"]
    lines = ["| method | accuracy (%) | images won | won alone vs it | McNemar p |",
             "|---|---|---|---|---|"]
    k = sum(r["success"] for r in summary["per_image"])
    lines.append(f"| {cfg['learner']}-{cfg['encoder']} model `{Path(cfg['model']).name}` "
                 f"({cfg['detector']} detector) | {100 * summary['accuracy']:.2f} | {k}/{n} "
                 f"| — | — |")
    for name, t in summary["vs_baselines"].items():
        kb = sum(r["baselines"][name] for r in summary["per_image"])
        lines.append(f"| baseline: {name} | {100 * summary['baselines'][name]:.2f} | {kb}/{n} "
                     f"| {t['b_only']} vs {t['a_only']} | {t['p_value']:.3g} |")
    lines.append("")
    lines.append(
        f"Cross-dataset detection: the saved model, trained elsewhere, on every labelled image "
        f"of {cfg['format']} `{Path(cfg['data']).name}` (scale {scale:g}), top-1 rectangle "
        f"by the rectangle metric (within 30 degrees and Jaccard > 0.25 of some positive); "
        f"\"won alone\" counts the images the baseline gets right and the model not, against "
        f"the reverse (exact McNemar test). Seconds per image: "
        f"{summary['seconds_per_image']:.2f}."
    )
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# Self-taught learning in detection (the paper's Table 3)

#: The five combinations of the paper's Table 3 (learner, encoder).
TABLE3_COMBINATIONS = ("NKM-SC", "NKM-Natural", "GSVQ-ST", "OMP-Natural", "RP-Natural")


def paired_detection_test(a: dict, b: dict) -> dict:
    """Exact McNemar test of two detection runs on the same images (per-image top-1 success).

    Parameters
    ----------
    a, b : dict
        Summaries of :func:`detection_benchmark` (``per_image`` outcomes) on the same images.

    Returns
    -------
    dict
        :func:`mcnemar_exact` of ``a`` against ``b``.
    """
    sa = {r["image_id"]: bool(r["success"]) for r in a["per_image"]}
    sb = {r["image_id"]: bool(r["success"]) for r in b["per_image"]}
    if set(sa) != set(sb):
        raise ValueError(f"the two runs were tested on different images ({len(sa)} and "
                         f"{len(sb)}, {len(set(sa) ^ set(sb))} not in both)")
    ids = sorted(sa)
    return mcnemar_exact([sa[i] for i in ids], [sb[i] for i in ids])


def nested_detector_choice(data, format: str, out, candidates=None, n_folds: int = 5,
                           inner_folds: int = 3, inner_views: int | None = 3,
                           report=("paper", "all"), seed: int = 0, progress: bool = True,
                           executor=None, **benchmark) -> dict:
    """Choose the detector configuration by nested object-wise cross-validation.

    For each outer object-wise fold (the folds of :func:`detection_benchmark` with the same
    ``seed``), every candidate configuration is cross-validated on the outer training
    objects alone (``inner_folds`` object-wise folds over their first ``inner_views`` views
    each, sorted by image id; None: every view), and the one with the best inner accuracy is
    chosen (ties: the earlier candidate, the paper's first); it is then reported on the outer
    fold's images, never seen by the choice. The chosen configurations and those in ``report``
    run on every outer fold (:func:`detection_benchmark`, ``out/outer``), so the table also
    has each of them on all images, and the nested outcome is image by image the chosen
    configuration's of its fold. The configurations in ``report`` run first, and the tables
    are rewritten after every outer fold (partial until the last). Everything resumes from
    ``out``.

    Parameters
    ----------
    data, format :
        As :func:`detection_benchmark`.
    out : path-like
        ``out/outer<k>/`` (inner runs of outer fold k), ``out/outer/``, ``out/nested.json``
        and ``out/nested.md``.
    candidates : dict of str to DetectorOptions or None
        Default :func:`graspsim.detector_options.candidate_options` (the paper's, each
        departure alone, all of them).
    n_folds, inner_folds : int
    inner_views : int or None
        Views per object in the inner folds (fewer: a cheaper choice).
    report : sequence of str
        Candidates also run on every outer fold.
    seed : int
    progress : bool
    executor : Executor or None
    **benchmark :
        Further options of :func:`detection_benchmark` (``scale``, ``n_atoms``, ``n_patches``,
        ``rescore``, ``coarse_to_fine``, ...).

    Returns
    -------
    dict
        ``choices`` (per outer fold: the inner accuracy of every candidate and the choice),
        ``chosen`` (the most often chosen; ties by mean inner accuracy), ``outer`` (per
        reported configuration: accuracy, Wilson interval, per-image outcomes), ``nested``
        (the same for the nested outcome), ``baselines`` and ``tests`` (exact McNemar tests
        on the same images); also written to ``out/nested.json`` and ``out/nested.md``.
    """
    import json

    from dlsr import datasets

    from .detector_options import candidate_options

    candidates = candidate_options() if candidates is None else dict(candidates)
    unknown = [r for r in report if r not in candidates]
    if unknown:
        raise ValueError(f"report {unknown} not among the candidates {sorted(candidates)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    samples = [s for s in load_samples(data, format, benchmark.get("scale"),
                                       benchmark.get("mapping")) if s.positives]
    folds = datasets.object_wise_folds(samples, n_folds, seed)
    bench = dict(benchmark, progress=False, executor=executor, seed=seed)
    runs = {}

    def outer(name):  # a configuration on every outer fold (resumes)
        if name not in runs:
            runs[name] = detection_benchmark(data, format, out / "outer", split="object",
                                             n_folds=n_folds, options=candidates[name],
                                             **bench)
        return runs[name]

    for name in report:  # first, so that an interrupted choice still reports them
        outer(name)
    choices = []
    for k, (train, _test) in enumerate(folds):
        by_object: dict = {}
        for i in sorted(train, key=lambda i: samples[i].image_id):
            by_object.setdefault(samples[i].object_id, []).append(samples[i].image_id)
        ids = [v for views in by_object.values() for v in views[:inner_views]]
        accs = {}
        for name, opts in candidates.items():
            summary = detection_benchmark(data, format, out / f"outer{k}", split="object",
                                          n_folds=inner_folds, options=opts, images=ids,
                                          **bench)
            accs[name] = summary["accuracy"]
            if progress:
                log.warning("outer fold %d: inner accuracy of %s %.3f", k, name, accs[name])
        best = max(accs.values())
        chosen = next(name for name in candidates if accs[name] == best)
        choices.append({"fold": k, "n_inner_images": len(ids),
                        "inner_objects": sorted(by_object), "inner_accuracy": accs,
                        "chosen": chosen})
        outer(chosen)
        result = _nested_result(data, format, n_folds, inner_folds, inner_views, seed,
                                candidates, benchmark, choices, runs, len(folds))
        write_text_atomic(out / "nested.json", json.dumps(result, indent=2))
        write_text_atomic(out / "nested.md", nested_markdown(result))
    return result


def _nested_result(data, format, n_folds, inner_folds, inner_views, seed, candidates,
                   benchmark, choices, runs, n_outer) -> dict:
    """The summary of :func:`nested_detector_choice` from the outer folds chosen so far (the
    nested row covers their images only until every fold is done)."""
    from collections import Counter

    from .trials import wilson_interval

    counts = Counter(c["chosen"] for c in choices)
    mean_inner = {n: float(np.mean([c["inner_accuracy"][n] for c in choices]))
                  for n in candidates}
    chosen = max(counts, key=lambda n: (counts[n], mean_inner[n]))
    first = next(iter(runs.values()))["per_image"]
    ids = [r["image_id"] for r in first]
    fold_of = {r["image_id"]: r["fold"] for r in first}
    outcome = {name: {r["image_id"]: bool(r["success"]) for r in run["per_image"]}
               for name, run in runs.items()}
    baselines = {b: {r["image_id"]: bool(r["baselines"][b]) for r in first}
                 for b in first[0]["baselines"]}
    chosen_of = {c["fold"]: c["chosen"] for c in choices}
    nested_ids = [i for i in ids if fold_of[i] in chosen_of]
    rows = {"nested": {i: outcome[chosen_of[fold_of[i]]][i] for i in nested_ids},
            **{f"config:{n}": outcome[n] for n in runs},
            **{f"baseline:{b}": v for b, v in baselines.items()}}

    def cell(res: dict) -> dict:
        n, k_ = len(res), sum(res.values())
        lo, hi = wilson_interval(k_, n)
        return {"successes": k_, "n": n, "accuracy": k_ / n, "ci95": [lo, hi]}

    table = {name: cell(res) for name, res in rows.items()}
    tests = {}
    for a in ["nested", *[f"config:{n}" for n in runs]]:
        for b in ["baseline:mask-pca", "config:paper"]:
            if a != b and b in rows:
                same = [i for i in rows[a] if i in rows[b]]
                tests[f"{a} vs {b}"] = mcnemar_exact([rows[a][i] for i in same],
                                                     [rows[b][i] for i in same])
    return {"config": {"data": str(data), "format": format, "n_folds": n_folds,
                       "inner_folds": inner_folds, "inner_views": inner_views, "seed": seed,
                       "candidates": {n: dataclasses.asdict(o) for n, o in candidates.items()},
                       **{k: v for k, v in benchmark.items() if k != "executor"}},
            "complete": len(choices) == n_outer, "outer_folds_done": len(choices),
            "choices": choices, "chosen": chosen, "chosen_counts": dict(counts),
            "mean_inner_accuracy": mean_inner, "table": table, "tests": tests,
            "per_image": [{"image_id": i, "fold": fold_of[i],
                           **{n: rows[n].get(i) for n in rows}} for i in ids]}


def nested_markdown(result: dict) -> str:
    """The tables of :func:`nested_detector_choice`: inner accuracies and choices per outer
    fold, then outer accuracies with Wilson intervals and the paired tests."""
    names = list(result["config"]["candidates"])
    lines = ["| outer fold | inner images | " + " | ".join(names) + " | chosen |",
             "|---" * (len(names) + 3) + "|"]
    for c in result["choices"]:
        lines.append(f"| {c['fold']} | {c['n_inner_images']} | " + " | ".join(
            f"{100 * c['inner_accuracy'][n]:.1f}" for n in names) + f" | {c['chosen']} |")
    done = ("" if result["complete"] else f" (partial: {result['outer_folds_done']} of "
            f"{result['config']['n_folds']} outer folds; the nested row covers their images)")
    lines += ["", f"Chosen overall: **{result['chosen']}** "
              f"({result['chosen_counts']}){done}", "",
              "| detector | success | accuracy | 95 % CI (Wilson) |", "|---|---|---|---|"]
    for name, t in result["table"].items():
        lo, hi = t["ci95"]
        lines.append(f"| {name} | {t['successes']}/{t['n']} | {100 * t['accuracy']:.1f} % | "
                     f"{100 * lo:.1f} to {100 * hi:.1f} % |")
    lines += ["", "| paired test (exact McNemar) | a only | b only | p |", "|---|---|---|---|"]
    for name, t in result["tests"].items():
        lines.append(f"| {name} | {t['a_only']} | {t['b_only']} | {t['p_value']:.3g} |")
    return "\n".join(lines) + "\n"


def selftaught_benchmark(data, format: str, extra_patches, out,
                         combinations=TABLE3_COMBINATIONS, progress: bool = True,
                         **detection_options) -> dict:
    """Standard against self-taught detection for learner-encoder combinations (Table 3).

    For each ``"LEARNER-ENCODER"`` of ``combinations``, :func:`detection_benchmark` runs twice
    with the same folds, seeds and options (``detection_options``): without extra patches
    (standard) and with ``extra_patches`` joined to each fold's dictionary learning
    (self-taught); the two are compared per image by an exact McNemar test
    (:func:`paired_detection_test`). Each run lives in ``out/<combination>_<standard|
    selftaught>`` and resumes there; ``out/table3.json`` and ``out/table3.md`` are rewritten
    after every combination, so an interrupted run keeps the finished rows. Rows of other
    combinations already in ``out/table3.json`` with the same configuration (data, patches,
    options) are kept, in their place, so a run of one combination adds its row to the table
    (a row of the same combination is replaced); a table of another configuration is replaced.

    Returns
    -------
    dict
        ``rows``: per combination, the two accuracies, images right, the test and the run
        folders (this run's combinations and the kept ones); ``config``: the shared options.
    """
    import json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for combo in combinations:
        parts = str(combo).split("-")
        if len(parts) != 2 or parts[0] not in LEARNERS or parts[1] not in ENCODERS:
            raise ValueError(f"combination must be LEARNER-ENCODER with a learner in {LEARNERS} "
                             f"and an encoder in {ENCODERS}, got {combo!r}")
    from dlsr.patches import load_patch_file

    n_extra = len(load_patch_file(extra_patches)[0])  # a clear error before any work
    result = {"config": {"data": str(data), "format": format,
                         "extra_patches": str(extra_patches), "n_extra_patches": n_extra,
                         **{k: v for k, v in detection_options.items() if k != "executor"}},
              "rows": []}
    result["rows"] = _table3_rows_kept(out / "table3.json", result["config"])
    for combo in combinations:
        learner, encoder = combo.split("-")
        runs = {}
        for variant, extra in (("standard", None), ("selftaught", extra_patches)):
            folder = out / f"{combo}_{variant}"
            runs[variant] = detection_benchmark(data, format, folder, learner=learner,
                                                encoder=encoder, extra_patches=extra,
                                                progress=progress, **detection_options)
            runs[variant]["folder"] = str(folder)
        test = paired_detection_test(runs["selftaught"], runs["standard"])
        row = {
            "combination": combo,
            "standard": runs["standard"]["accuracy"],
            "selftaught": runs["selftaught"]["accuracy"],
            "n_images": test["n"], "selftaught_only": test["a_only"],
            "standard_only": test["b_only"], "p_value": test["p_value"],
            "baselines": runs["standard"]["baselines"],
            "encoder_param": runs["standard"]["config"]["encoder_param"],
            "folders": {v: runs[v]["folder"] for v in runs},
        }
        at = [i for i, r in enumerate(result["rows"]) if r["combination"] == combo]
        if at:
            result["rows"][at[0]] = row
        else:
            result["rows"].append(row)
        write_text_atomic(out / "table3.json", json.dumps(result, indent=2))
        write_text_atomic(out / "table3.md", table3_markdown(result))
    return result


def _table3_rows_kept(path, config: dict) -> list[dict]:
    """The rows of an earlier ``table3.json`` at ``path`` when its configuration is ``config``.

    A missing file, or a table of another configuration, gives no rows (the table is then
    rewritten); a corrupt file is an error naming it (:func:`dlsr.records.read_json`).
    """
    import json

    if not Path(path).is_file():
        return []
    earlier = read_json(path, "Table 3 results")
    if earlier.get("config") != json.loads(json.dumps(config)):
        return []
    rows = earlier.get("rows")
    if not isinstance(rows, list) or not all(isinstance(r, dict) and "combination" in r
                                             for r in rows):
        raise CorruptFileError(f"Table 3 results {path}: 'rows' must be a list of rows, "
                               f"each with its 'combination'")
    return rows


def table3_markdown(result: dict) -> str:
    """The rows of :func:`selftaught_benchmark` as the paper's Table 3 (plus the paired test)."""
    cfg = result["config"]
    lines = ["| combination | standard (%) | self-taught (%) | difference (points) | "
             "images won alone (self-taught vs standard) | McNemar p |",
             "|---|---|---|---|---|---|"]
    for r in result["rows"]:
        n = r["n_images"]
        lines.append(
            f"| {r['combination']} | {100 * r['standard']:.1f} ({round(r['standard'] * n)}/{n})"
            f" | {100 * r['selftaught']:.1f} ({round(r['selftaught'] * n)}/{n}) | "
            f"{100 * (r['selftaught'] - r['standard']):+.1f} | {r['selftaught_only']} vs "
            f"{r['standard_only']} | {r['p_value']:.3g} |")
    lines.append("")
    lines.append(
        f"Detection accuracy by the rectangle metric (top-1), {cfg.get('split', 'object')}-wise "
        f"cross-validation on {cfg['format']} `{Path(cfg['data']).name}`; self-taught adds "
        f"{cfg['n_extra_patches']:,} unlabelled patches (`{Path(cfg['extra_patches']).name}`) "
        f"to each fold's whitening and dictionary learning, the labelled training being the "
        f"same. Exact McNemar test on the images one variant gets right and the other not "
        f"(two-sided binomial test of the discordant pairs)."
    )
    return "\n".join(lines) + "\n"
