"""A detection benchmark resolved before any work (steps 1 to 5 of
:func:`graspsim.eval.offline.detection.detection_benchmark`): the arguments checked, the
labelled images, the folds, the configuration whose digest keys the results and the fold
models, and what a previous run already wrote (:func:`plan_detection`,
:class:`DetectionPlan`); and each fold's detector.

Shared by :func:`~graspsim.eval.offline.detection.detection_benchmark` (one row of Table 2)
and :func:`graspsim.eval.offline.table2_pass.table2_benchmark` (every row in one pass), so
both key, train and search alike.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np

from dlsr import datasets
from dlsr.detection import DETECTOR_KINDS, DLSRDetector, check_training_options
from dlsr.features import ENCODERS, LEARNERS
from dlsr.patches import load_patch_file
from dlsr.records import read_jsonl

from ...data.samples import load_samples
from ...detectors.dlsr_options import build_real_detector
from ...sim.gripper import MAX_OPENING
from .recognition import recognition_choice

__all__ = ["TRAINING_KEYS", "DetectionPlan", "plan_detection"]


def _file_digest(*paths) -> str:
    h = hashlib.sha1()
    for p in paths:
        with open(p, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:12]


@dataclasses.dataclass
class DetectionPlan:
    """A detection benchmark resolved before any work: what :func:`detection_benchmark` runs
    (its steps 1 to 5, :func:`plan_detection`) and what it has already done.

    Attributes
    ----------
    out : Path
        The output folder.
    samples : list of dlsr.datasets.GraspSample
        The labelled images benchmarked.
    folds : list of (train, test)
        Index lists into ``samples``.
    config : dict
        The configuration ``detection.json`` records.
    key : str
        Its digest, which keys the per-image results (``config_key``).
    models : Path
        The fold models' stem (``models/<digest of the training keys>``).
    done : dict
        The results already in ``results.jsonl`` for this configuration, by image id.
    training : dict
        The keyword arguments of :func:`dlsr.detection.train_detector` a fold's model is
        trained with (``random_state`` apart).
    extra_samples : list of dlsr.datasets.GraspSample
        The extra labelled training images (joined to every training fold).
    seed : int
    train_positives : int or None
    fixed : dlsr.detection.DLSRDetector or None
        The saved model evaluated (no fold models), if any.
    detector_args : dict
        How a fold's model is searched (:func:`graspsim.detectors.dlsr_options.
        build_real_detector` with ``options``, or the benchmark's own arguments).
    """

    out: Path
    samples: list
    folds: list
    config: dict
    key: str
    models: Path
    done: dict
    training: dict
    extra_samples: list
    seed: int
    train_positives: int | None
    fixed: object
    detector_args: dict

    @property
    def results_path(self) -> Path:
        """``out/results.jsonl``."""
        return self.out / "results.jsonl"

    def add_result(self, record: dict) -> None:
        """Append one image's result to ``results.jsonl`` and put it in ``done``."""
        with self.results_path.open("a") as fh:
            fh.write(json.dumps(record) + "\n")
        self.done[record["image_id"]] = record

    def fold_model_path(self, k: int) -> Path:
        """Fold ``k``'s model stem (``PATH.npz`` + ``PATH.json``)."""
        return self.models.with_name(f"{self.models.name}_fold{k}")

    def folds_to_train(self) -> list[int]:
        """The folds whose model is missing and still needed (a test image not done)."""
        return [k for k, (_, test) in enumerate(self.folds)
                if any(self.samples[i].image_id not in self.done for i in test)
                and not self.fold_model_path(k).with_name(
                    f"{self.models.name}_fold{k}.json").is_file()]

    def fold_training_samples(self, k: int) -> list:
        """Fold ``k``'s training images: its labelled images (at most ``train_positives``
        positives each, seeded by ``seed + k``) and the extra training images."""
        return (_fewer_positives([self.samples[i] for i in self.folds[k][0]],
                                 self.train_positives, self.seed + k) + self.extra_samples)

    def fold_detector(self, k: int):
        """Fold ``k``'s detector: the saved model's or the fold's, searched as the options
        say (:func:`graspsim.detectors.dlsr_options.build_real_detector`) or as the
        benchmark's own arguments say."""
        return _fold_detector(k, fixed=self.fixed, models=self.models, **self.detector_args)


def plan_detection(
    data, format: str, out, scale=None, mapping=None, split: str = "object",
    learner: str | None = None, encoder: str | None = None, encoder_param=None,
    C: float | None = None, recognition_json=None, detector: str = "dense", n_folds: int = 5,
    n_atoms: int = 300, n_patches: int = 100_000, grid_negatives: float = 1.0,
    fit_grid: float | None = None, hard_negatives: int = 0, hard_rounds: int = 1,
    region: str = "auto", rescore: int = 300, clear_jaws: bool = False,
    coarse_to_fine: bool = False, max_images: int | None = None, save_model=None,
    extra_patches=None, extra_train=None, extra_format: str | None = None, extra_scale=None,
    extra_mapping=None, model=None, physical: bool = False, seed: int = 0, options=None,
    images=None, train_positives: int | None = None, dataset=None, extra_dataset=None,
) -> DetectionPlan:
    """Steps 1 to 5 of :func:`detection_benchmark` (same arguments): the arguments checked,
    the images loaded, the folds, the configuration and its key, and the results already
    written; ``out`` is created. Nothing is trained or detected.

    Parameters
    ----------
    data, format, out, ... :
        See :func:`detection_benchmark`.
    dataset : list of dlsr.datasets.GraspSample or None
        The images of ``data`` already loaded (``load_samples(data, format, scale,
        mapping)``), so that several plans on one dataset read it once; None loads them.
    extra_dataset : list of dlsr.datasets.GraspSample or None
        Likewise for ``extra_train``.

    Returns
    -------
    DetectionPlan
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
    extra_samples = _extra_training(extra_train, extra_format, extra_scale, extra_mapping,
                                    extra_dataset)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    samples = _labelled_samples(data, format, scale, mapping, images, max_images, dataset)
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
    done = {r["image_id"]: r
            for r in read_jsonl(out / "results.jsonl", required=("image_id",), repair=True)
            if r.get("config_key") == key}
    return DetectionPlan(
        out=out, samples=samples, folds=folds, config=config, key=key, models=models,
        done=done, training=training, extra_samples=extra_samples, seed=seed,
        train_positives=train_positives, fixed=fixed,
        detector_args=dict(options=options, detector=detector, region=region, rescore=rescore,
                           coarse_to_fine=coarse_to_fine, clear_jaws=clear_jaws))


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


def _extra_training(extra_train, extra_format, extra_scale, extra_mapping,
                    loaded=None) -> list:
    """Step 2: the labelled images of the extra training data (none without it)."""
    if extra_train is None:
        return []
    if loaded is None:
        loaded = load_samples(extra_train, extra_format, extra_scale, extra_mapping)
    extra = [s for s in loaded if s.positives]
    if not extra:
        raise ValueError(f"no labelled images in the extra training data {extra_train}")
    return extra


def _labelled_samples(data, format, scale, mapping, images, max_images, loaded=None) -> list:
    """Step 3: the dataset's labelled images (of ``loaded`` when given), only ``images`` when
    given, the first ``max_images``."""
    if loaded is None:
        loaded = load_samples(data, format, scale, mapping)
    samples = [s for s in loaded if s.positives]
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
