"""The default end-to-end job behind ``graspsim run`` (and ``make run``).

With no argument and no download it:

1. generates a synthetic, physics-labelled Cornell dataset from the built-in **train** objects;
2. evaluates DLSR recognition by nested cross-validation (object-wise) on it;
3. evaluates DLSR detection by cross-validation (object-wise, rectangle metric) on it;
4. trains the DLSR detector on the whole dataset;
5. runs simulated grasp trials on the held-out **test** objects with the DLSR detector and the
   baselines (mask-pca, random, and the physics oracle);
6. writes ``report.md`` and a self-contained ``report.html``.

Every stage writes its results as it goes and records completion in ``stages.json``, so
``graspsim run --resume DIR`` (or rerunning with the same ``--out``) continues an interrupted run
without redoing finished work. Every run records its configuration, seeds and package versions
in ``run.json``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import platform
import shutil
import time
from dataclasses import asdict
from importlib import metadata
from pathlib import Path

from dlsr import recognition as rec
from dlsr.datasets import load_cornell
from dlsr.detection import DLSRDetector
from dlsr.records import read_json, write_json_atomic

from ..data.datagen import make_dataset
from ..detectors.dlsr_options import DetectorOptions, build_real_detector
from ..detectors.loading import detector_label, load_detector
from ..eval.compare import compare_outcomes, pooled_fold_trials
from ..eval.offline.detection import detection_benchmark, train_saved
from ..eval.summary import summarize
from ..eval.trials import TrialConfig, object_folds, run_trials
from ..runtime.executor import Executor, task_seeds
from ..sim.object_sets import check_same_object_set
from .config import QUICK, RunConfig, check_settings, load_config  # noqa: F401 (public here too)
from .plan import departs_from_paper, trial_names  # noqa: F401 (public here too)
from .report import write_report

log = logging.getLogger(__name__)

__all__ = ["RunConfig", "load_config", "run_folder", "run_job", "resume_job",
           "objectwise_validation", "trial_detector", "QUICK"]


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for pkg in ("dlsr-graspsim", "numpy", "scipy", "scikit-learn", "opencv-python-headless",
                "pybullet", "gymnasium", "trimesh", "shapely", "joblib", "matplotlib", "ray"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


class _Stages:
    """``stages.json``: which stages finished, with their results."""

    def __init__(self, root: Path):
        self.path = root / "stages.json"
        self.data = read_json(self.path, "stage record") if self.path.exists() else {}

    def done(self, name):
        return name in self.data

    def get(self, name):
        return self.data[name]

    def finish(self, name, result):
        self.data[name] = result
        write_json_atomic(self.path, self.data, default=str)


#: Settings of how a run is executed, not of what it computes (every task carries its own seed,
#: so the results are the same on any backend and number of workers): a run continues with
#: other values of these.
EXECUTION_SETTINGS = ("backend", "address", "jobs")


def _identity(config: dict) -> dict:
    """A configuration without its :data:`EXECUTION_SETTINGS`."""
    return {k: v for k, v in config.items() if k not in EXECUTION_SETTINGS}


def _recorded_config(recorded):
    """A recorded configuration with the settings added since it was written at their defaults."""
    try:
        return json.loads(json.dumps(asdict(RunConfig(**recorded))))
    except TypeError:  # a setting this version does not know: another configuration
        return recorded


def run_folder(config: RunConfig, out=None) -> Path:
    """Where :func:`run_job` writes: ``out``, or ``runs/<config.name>`` when it is None."""
    return Path(out) if out is not None else Path("runs") / config.name


def run_job(config: RunConfig | None = None, out=None, resume: bool = True,
            progress: bool = True) -> Path:
    """Run (or continue) the end-to-end job and return the report's path.

    Parameters
    ----------
    config : RunConfig or None
        Defaults when None.
    out : str or Path or None
        Run folder (default ``runs/<config.name>``). An existing folder is continued when its
        ``run.json`` holds the same configuration; another configuration is an error.
    resume : bool
        False refuses to reuse a folder that already holds a run.
    progress : bool
        Progress bars on every long step.
    """
    config = (config or RunConfig()).validated()
    root = run_folder(config, out)
    root.mkdir(parents=True, exist_ok=True)
    run_json = root / "run.json"
    cfg = asdict(config)
    object_sets = {name: config.object_set(name).record()
                   for name in ("train_objects", "trial_objects")}
    if run_json.exists():
        old = read_json(run_json, "run record")
        if not resume:
            raise ValueError(f"{root} already holds a run: use --resume {root} or a new --out")

        for name, record in object_sets.items():
            check_same_object_set((old.get("object_sets") or {}).get(name), record,
                                  f"{root} ({name})")
        recorded = _recorded_config(old.get("config"))
        if not isinstance(recorded, dict) or (_identity(recorded)
                                              != _identity(json.loads(json.dumps(cfg)))):
            raise ValueError(f"{root} holds a run of another configuration ({run_json}); "
                             "use a new --out")
        changed = {k: (recorded.get(k), cfg[k]) for k in EXECUTION_SETTINGS
                   if recorded.get(k) != cfg[k]}
        log.info("continuing the run in %s%s", root, "".join(
            f"; {k} {a} -> {b}" for k, (a, b) in changed.items()))
    else:
        write_json_atomic(run_json, {
            "config": cfg, "object_sets": object_sets, "versions": _versions(),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "machine": {"platform": platform.platform(), "cpus": _cpus()},
        })
    seeds = dict(zip(("dataset", "recognition", "detection", "model", "trials"),
                     task_seeds(config.seed, 5), strict=True))
    ex = Executor(backend=config.backend, n_jobs=config.jobs, address=config.address,
                  progress=progress)
    stages = _Stages(root)
    t_start = time.perf_counter()

    # 1. Synthetic Cornell dataset from the train objects (config.train_objects).
    if not stages.done("dataset"):
        t0 = time.perf_counter()
        stats = make_dataset(n_scenes=config.scenes,
                             objects=config.object_set("train_objects"),
                             out=root / "dataset", seed=seeds["dataset"],
                             n_candidates=config.candidates, sampler=config.label_sampler,
                             executor=ex, n_objects=config.objects_per_scene,
                             scene=config.scene, params=config.execution_params())
        stats["seconds"] = time.perf_counter() - t0
        stages.finish("dataset", stats)

    samples = load_cornell(root / "dataset")

    # 2. Recognition by nested cross-validation (object-wise).
    if config.offline and not stages.done("recognition"):
        t0 = time.perf_counter()
        # The rectangle images go to a file that the workers map (no copy per worker).
        mapped = root / "recognition" / "data"
        data = rec.recognition_data(samples, random_state=seeds["recognition"])
        try:  # the folder goes also when writing it fails (a full disk) or the CV stops
            data = data.memory_mapped(mapped)
            with ex.activate():  # the CV folds run on the chosen backend (joblib inside dlsr)
                summary = rec.run_recognition_benchmark(
                    data, root / "recognition", learners=[config.learner],
                    encoders=[config.encoder], split="object", n_folds=config.folds,
                    inner_folds=config.inner_folds, n_atoms=config.n_atoms,
                    n_patches=config.n_patches, random_state=seeds["recognition"],
                    n_jobs=config.jobs, progress=progress,
                )
        finally:
            shutil.rmtree(mapped, ignore_errors=True)
        cell = summary["cells"][0]
        stages.finish("recognition", {
            "accuracy": cell["accuracy"], "std": cell["std"],
            "n_rectangles": len(data), "n_positive": int(data.labels.sum()),
            "seconds": time.perf_counter() - t0,
        })

    # 3. Detection by cross-validation (object-wise, rectangle metric).
    if config.offline and not stages.done("detection"):
        t0 = time.perf_counter()
        det = detection_benchmark(
            root / "dataset", format="cornell", out=root / "detection", split="object",
            learner=config.learner, encoder=config.encoder, C=config.C,
            detector=config.detector, n_folds=config.folds, n_atoms=config.n_atoms,
            n_patches=config.n_patches, seed=seeds["detection"], progress=progress,
            coarse_to_fine=config.coarse_to_fine, rescore=config.rescore,
            max_images=config.detection_images, fit_grid=config.fit_grid,
            hard_negatives=config.hard_negatives, hard_rounds=config.hard_rounds,
            grid_negatives=config.grid_negatives, clear_jaws=config.gripper_aware,
            physical=config.physical, executor=ex,
        )
        stages.finish("detection", {
            k: det.get(k) for k in ("accuracy", "baselines", "seconds_per_image")
        } | {"seconds": time.perf_counter() - t0})

    # 4. The final detector, trained on every synthetic image (and, with physical features,
    #    the paper's model beside it for the dlsr-paper trials).
    #    Both are trained side by side on the executor's workers (each from the same seed,
    #    wherever it runs); a model's "seconds" is the stage's wall time until it was saved.
    model_path = root / "model" / "dlsr"

    models = [("model", model_path, config.physical, config.detector)]
    if config.physical:
        models.append(("model-paper", _paper_model_path(model_path, config), False, "dense"))
    models = [m for m in models if not stages.done(m[0])]
    model_path.parent.mkdir(parents=True, exist_ok=True)
    tasks = [(path, samples, dict(learner=config.learner, encoder=config.encoder, C=config.C,
                                  n_atoms=config.n_atoms, n_patches=config.n_patches,
                                  random_state=seeds["model"], detector=kind,
                                  fit_grid=config.fit_grid,
                                  hard_negatives=config.hard_negatives,
                                  hard_rounds=config.hard_rounds,
                                  grid_negatives=config.grid_negatives, physical=physical))
             for _, path, physical, kind in models]
    t0 = time.perf_counter()
    for (key, *_), paths in zip(models, ex.imap(train_saved, tasks, desc="models", star=True),
                                strict=True):
        stages.finish(key, {"paths": paths, "seconds": time.perf_counter() - t0})

    # 5. Simulated grasp trials on the held-out test objects (config.trial_objects).
    trial_stage(root, config, stages, model_path, seeds["trials"], ex, progress)

    # 6. The report.

    report = write_report(root, config, stages.data, wall=time.perf_counter() - t_start)
    log.info("report: %s", report)
    return report


def _cpus() -> int:
    return os.cpu_count() or 1


def trial_stage(root: Path, config: RunConfig, stages, model_path: Path, seed: int, executor,
                progress: bool = True) -> None:
    """Stage 5: simulated grasp trials of DLSR and ``config.baselines`` on
    ``config.trial_objects`` (default: the held-out test objects).

    Each detector's trials go to ``root / "trials" / name`` (resumed trial by trial) and its
    summary into ``stages`` as ``"trials/<name>"`` once finished. The scenes are labelled by
    physics once, by the first detector's trials, into ``root / "labels"``
    (:class:`graspsim.labels.store.SceneLabels`), and the others read them. A baseline may be
    any name :func:`graspsim.detectors.load_detector` takes, plug-ins
    (``package.module:NAME``, entry-point names) included.
    """
    trial_cfg = TrialConfig(n_candidates=config.trial_candidates, sampler=config.label_sampler,
                            n_objects=config.objects_per_scene, scene=config.scene)
    for name in trial_names(config):
        key = f"trials/{name}"
        if stages.done(key):
            continue
        t0 = time.perf_counter()
        det = trial_detector(name, model_path, config, hand=config.gripper)
        options = config.detector_options.get(name) or None
        s = run_trials(det, objects=config.object_set("trial_objects"), n=config.trials,
                       seed=seed,
                       out=root / "trials" / name, config=trial_cfg, executor=executor,
                       progress=progress, detector_name=detector_label(name, options),
                       params=config.execution_params(), labels=root / "labels",
                       detector_options=options)
        s.pop("records", None)
        s["seconds"] = time.perf_counter() - t0
        stages.finish(key, s)


def _paper_model_path(model_path: Path, config: RunConfig) -> Path:
    """The model of the ``dlsr-paper`` trials beside DLSR's ``model_path``: its own when DLSR's
    is trained with physical features, else DLSR's."""
    return model_path.with_name("dlsr-paper") if config.physical else model_path


def trial_detector(name: str, model_path: Path, config: RunConfig, hand: str = "builtin"):
    """The detector ``name`` of the trial stage, as ``graspsim run`` builds it.

    Parameters
    ----------
    name : str
        ``"dlsr"`` (the model at ``model_path`` with ``config``'s detector options, made aware
        of ``hand``'s geometry), ``"dlsr-paper"`` (the paper's model beside it, its dense
        search) or any name :func:`graspsim.detectors.load_detector` takes (with
        ``config.detector_options``).
    model_path : Path
        The saved DLSR model (``model/dlsr`` of a run).
    config : RunConfig
    hand : str
        The hand the gripper-aware check judges with.
    """
    if name in ("dlsr", "dlsr-paper"):
        kind = config.detector if name == "dlsr" else "dense"
        if name == "dlsr-paper":
            model_path = _paper_model_path(model_path, config)
        options = {}
        if kind == "dense":
            options = {"coarse_to_fine": config.coarse_to_fine, "rescore": config.rescore}
        model = DLSRDetector.load(model_path)
        if name == "dlsr":
            opts = DetectorOptions(detector=kind, complete_region=config.complete_region,
                                   physical=config.physical,
                                   gripper_aware=config.gripper_aware,
                                   clear_jaws=config.clear_jaws)
            return build_real_detector(model, opts, rescore=config.rescore,
                                       coarse_to_fine=config.coarse_to_fine, hand=hand)
        return model.detector(kind, **options)

    return load_detector(name, config.detector_options.get(name))


def resume_job(folder, progress: bool = True, **execution) -> Path:
    """Continue the run in ``folder`` with the configuration recorded in its ``run.json``.

    ``execution`` may set :data:`EXECUTION_SETTINGS` (``backend``, ``address``, ``jobs``) to
    other values than the recorded ones (None keeps the recorded value): they do not change
    the results.
    """
    folder = Path(folder)
    run_json = folder / "run.json"
    if not run_json.exists():
        raise FileNotFoundError(f"no run to resume: {run_json} is missing")
    recorded = read_json(run_json, "run record")
    if "config" not in recorded:
        raise ValueError(f"run record {run_json}: no 'config'")
    unknown = set(execution) - set(EXECUTION_SETTINGS)
    if unknown:
        raise TypeError(f"resume_job takes only {EXECUTION_SETTINGS} besides the folder, got "
                        f"{sorted(unknown)}")
    settings = dict(check_settings(recorded["config"], f"run record {run_json} config"))
    settings.update({k: v for k, v in execution.items() if v is not None})
    config = RunConfig(**settings).validated()
    return run_job(config, out=folder, resume=True, progress=progress)


def objectwise_validation(config: RunConfig | None = None, n_folds: int = 3, fold_seed: int = 0,
                          out=None, progress: bool = True, offline: bool = False) -> dict:
    """Object-wise validation of a run configuration: trials on train objects it never saw.

    ``config.train_objects`` (default: the built-in train objects) is split into ``n_folds``
    object folds (:func:`graspsim.eval.trials.object_folds`); for each fold the whole job runs
    (:func:`run_job`: dataset, CV, models, trials of DLSR and the baselines) with the other
    folds' objects as its train objects and the fold's as its trial objects. The trials of
    all folds are then pooled, detector by detector, and DLSR is compared with each other
    detector scene by scene (exact McNemar, :func:`graspsim.eval.compare.compare_outcomes`). With
    the default ``train_objects`` the test objects are never used: this is where settings are
    chosen. Each fold's run is resumed like any run. Two configurations validated with the same
    folds compare with ``graspsim compare A B`` (:func:`graspsim.eval.compare.compare_pair`), which
    pools their DLSR trials over the folds.

    Parameters
    ----------
    config : RunConfig or None
        The configuration to validate (defaults when None); its ``trial_objects`` is not used.
    n_folds : int
        Object folds (at least 2).
    fold_seed : int
        Seed of the split into folds.
    out : str or Path or None
        Folder of the fold runs and the summary (default ``runs/<config.name>-objectwise``).
    progress : bool
        Progress bars.
    offline : bool
        Also run each fold's offline benchmarks (recognition and detection CV: about a third
        of a fold's time, and not used here); the fold runs' ``offline`` setting.

    Returns
    -------
    dict
        ``folds`` (per fold: ``objects``, ``run`` folder and per-detector ``successes`` /
        ``n``), ``detectors`` (pooled :func:`graspsim.eval.summary.summarize` of each detector, DLSR
        first, without the per-trial records), ``comparisons`` (DLSR against each other
        detector), ``folder``. Also written to ``objectwise.json`` and ``objectwise.md``.
    """
    config = (config or RunConfig()).validated()
    folds = object_folds(config.train_objects, n_folds, fold_seed)
    root = Path(out) if out is not None else Path("runs") / f"{config.name}-objectwise"
    names = trial_names(config)
    fold_info = []
    for k, fold in enumerate(folds):
        others = [n for j, f in enumerate(folds) if j != k for n in f]
        cfg = dataclasses.replace(config, name=f"{config.name}-fold{k}", offline=offline,
                                  train_objects=",".join(others), trial_objects=",".join(fold))
        folder = root / f"fold{k}"
        log.info("object fold %d of %d: trials on %s", k + 1, len(folds), ", ".join(fold))
        run_job(cfg, out=folder, resume=True, progress=progress)
        fold_info.append({"objects": fold, "run": str(folder), "detectors": {}})
    pooled = {}  # detector -> {(fold, trial index): record}
    for name in names:
        runs, pooled[name] = pooled_fold_trials(root, len(folds), name)
        for info, run in zip(fold_info, runs, strict=True):
            recs = run["records"].values()
            info["detectors"][name] = {"successes": sum(bool(r["success"]) for r in recs),
                                       "n": len(recs)}
    detectors = {name: summarize(list(pooled[name].values())) for name in names}
    comparisons = []
    for name in names[1:]:  # paired by fold and trial index, as graspsim compare pairs
        keys = sorted(pooled["dlsr"].keys() & pooled[name].keys())
        c = compare_outcomes([bool(pooled["dlsr"][k]["success"]) for k in keys],
                             [bool(pooled[name][k]["success"]) for k in keys],
                             names=("dlsr", name))
        comparisons.append({"a": "dlsr", "b": name, **c})
    result = {"config": asdict(config), "n_folds": len(folds), "fold_seed": fold_seed,
              "folds": fold_info, "detectors": detectors, "comparisons": comparisons,
              "folder": str(root)}
    write_json_atomic(root / "objectwise.json", result)
    (root / "objectwise.md").write_text(objectwise_markdown(result))
    return result


def objectwise_markdown(result: dict) -> str:
    """:func:`objectwise_validation`'s result as a short Markdown summary."""
    det = result["detectors"]
    lines = [f"# Object-wise validation: {result['n_folds']} folds of the train objects "
             f"(fold seed {result['fold_seed']})", "",
             "| detector | success | 95 % CI (Wilson) | on graspable objects | "
             + " | ".join(f"fold {k}" for k in range(result["n_folds"])) + " |",
             "|---|---|---|---|" + "---|" * result["n_folds"]]
    for name, s in det.items():
        g = s["graspable_success_rate"]
        per = [f"{f['detectors'][name]['successes']}/{f['detectors'][name]['n']}"
               for f in result["folds"]]
        lines.append(f"| {name} | {s['successes']}/{s['n']} | {100 * s['success_ci95'][0]:.1f}"
                     f" - {100 * s['success_ci95'][1]:.1f} % | "
                     f"{'n/a' if g is None else f'{100 * g:.1f} %'} | " + " | ".join(per) + " |")
    lines += ["", "Paired, pooled over the folds:", ""]
    lines += [f"- {c['verdict']}" for c in result["comparisons"]]
    lines += ["", "Folds (trial objects):", ""]
    lines += [f"- fold {k}: {', '.join(f['objects'])}" for k, f in enumerate(result["folds"])]
    return "\n".join(lines) + "\n"
