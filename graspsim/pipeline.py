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
import platform
import shutil
import time
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path

from dlsr.records import file_errors, read_json, write_json_atomic

from .runplan import departs_from_paper, trial_names  # noqa: F401 (public here too)

log = logging.getLogger(__name__)

__all__ = ["RunConfig", "load_config", "run_folder", "run_job", "resume_job",
           "objectwise_validation", "trial_detector", "QUICK"]


@dataclass
class RunConfig:
    """Everything a run depends on (all of it is recorded in ``run.json``).

    Attributes
    ----------
    name : str
        Folder name under ``runs/`` when no output folder is given.
    seed : int
        Root seed; every stage derives its own from it.
    scenes : int
        Synthetic Cornell images generated from ``train_objects``.
    train_objects, trial_objects : str
        The objects of the dataset (and so of every model and offline benchmark) and of the
        trials: object sets (:func:`graspsim.object_sets.parse_object_set`: ``"train"``,
        ``"test"``, ``"all"``, comma-separated names of built-in objects,
        ``"random_urdfs[:train|test|all]"``, ``"folder:PATH[:train|test|all]"``). Defaults:
        the built-in split, trials on the held-out test objects. Object-wise validation
        trains on some train objects and runs the trials on the others
        (:func:`graspsim.trials.object_folds`, ``scripts/objectwise_validation.py``), so
        settings are chosen on objects the model has not seen without touching the test
        objects.
    object_scale, object_mass, decompose : float, float or None, bool
        Applied to both object sets (``--object-scale``, ``--object-mass``, ``--decompose`` of
        the commands): a scale factor, every object's mass in kg (None: their own), V-HACD
        decomposition of a folder's OBJ meshes.
    candidates : int
        Rectangles labelled by physics per scene.
    label_sampler : {"mixed", "dense"}
        How the labelled candidates of the dataset and the trial scenes are drawn
        (:func:`graspsim.labelling.sample_candidates`; ``"dense"``: a Jacquard-like lattice
        with ``candidates`` / ``trial_candidates`` as its budget).
    learner, encoder : str
        The DLSR combination (default NKM-Natural: the paper's best image-wise detector, and
        the cheapest to encode: k-means triangle activations are one matrix product).
    n_atoms, n_patches : int
        Dictionary size and the number of random patches it is learned from.
    folds, inner_folds : int
        Cross-validation folds (object-wise) for recognition and detection.
    offline : bool
        Run the offline benchmarks: recognition and detection by cross-validation on the
        dataset. False: dataset, models and trials only (the report says they were not run);
        object-wise validation (:func:`objectwise_validation`) runs its folds so.
    C : float
        SVM cost used for detection and the final model.
    detector : {"lattice", "dense", "exact"}
        DLSR's search: ``"lattice"`` (default) ranks rectangles fitted to the object region
        (:class:`dlsr.detection.LatticeDetector`: at lattice points every 15 degrees, openings
        from the region's chords within the gripper's reach, the labeller's candidates drawn
        from the observation); ``"dense"`` / ``"exact"``: the paper's grid search. Not in the
        paper (see the README for the validation that chose it).
    physical : bool
        Train DLSR's SVM with the rectangles' physical features beside the DLSR features
        (``train_detector(physical=True)``, :mod:`dlsr.detection.physical`: opening and jaw size
        in metres, heights of the centre and the finger footprints above the table, place on
        the object's axes). Not in the paper.
    coarse_to_fine : bool
        Dense detector: coarse scales and angles first, then the full grid around the best few.
    rescore : int
        Dense detector: the best candidates rescored exactly.
    detection_images : int or None
        At most this many labelled images in the detection cross-validation (None: all).
    fit_grid : float or None
        Detector training beyond the paper (as ``graspsim benchmark detection --fit-grid``):
        the candidate grid restricted to the training positives' sizes between this quantile
        and its complement. None: the paper's grid.
    hard_negatives, hard_rounds : int
        Detector training beyond the paper: negatives mined per training image from the
        detector's own best failing candidates, in ``hard_rounds`` rounds (0: none, the paper).
    grid_negatives : float
        Negatives per labelled rectangle drawn from the detector's own search grid in training
        (0: the paper's training, on the labelled rectangles only).
    gripper_aware : bool
        In the trials, DLSR searches only rectangles this gripper can execute
        (:func:`graspsim.detectors.gripper_aware`: jaws beside the object, opening within
        reach, its best 40 checked against the depth image for fingers landing on a seen
        surface or on the object's unseen surface). Not in the paper. When any of
        ``detector``, ``physical`` and ``gripper_aware`` departs from the paper, the paper's
        configuration also runs in the trials, as ``dlsr-paper``: a model trained the paper's
        way on the same images (``model/dlsr-paper``, with ``physical``), the paper's grid
        search (``"dense"``).
    complete_region, clear_jaws : bool
        DLSR's trial detector: candidates on the object region with its unseen surface added
        (the lattice's default), and, for the grid search without ``gripper_aware`` (which
        implies it), only rectangles whose jaws come down beside the object. The names are
        :mod:`graspsim.detector_options`' (shared with ``graspsim detect`` and ``graspsim
        benchmark detection``); ``graspsim run --no-complete-region`` etc. override them.
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects of the dataset and of the trials are put on the table
        (:mod:`graspsim.scenes`); packed and pile scenes have 5 objects (VGN, GIGA). Default
        ``"drop"``: one object dropped at a random pose, the scene of the README's figures.
    gripper : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        The hand that labels the dataset, executes the trials and that DLSR's gripper-aware
        search judges rectangles for (:mod:`graspsim.hands`); default the built-in one.
    trials : int
        Simulated grasp trials per detector on the test objects.
    trial_candidates : int
        Rectangles labelled per trial scene (for the oracle and the rectangle-metric verdict).
    baselines : list of str
        Detectors run beside DLSR in the trials: built-in names, plug-ins
        (``"package.module:NAME"``, entry-point names of ``graspsim.detectors``) or saved
        models (see :func:`graspsim.detectors.load_detector`).
    detector_options : dict
        Options of baselines, by name: keyword arguments of a plug-in's class or factory (or
        a built-in detector's class), JSON values. In a TOML file, one table per baseline::

            [run]
            baselines = ["mask-pca", "mynet:Detector"]

            [run.detector_options."mynet:Detector"]
            model = "runs/mynet/model.pt"
            top_k = 5

        Recorded in each trial folder's ``config.json`` and in the detector's name there
        (:func:`graspsim.detectors.detector_label`); the trial folder keeps the baseline's
        name.
    backend, address, jobs :
        Executor for the parallel stages (see :class:`graspsim.executor.Executor`).
    """

    name: str = "default"
    seed: int = 0
    scenes: int = 60
    train_objects: str = "train"
    trial_objects: str = "test"
    object_scale: float = 1.0
    object_mass: float | None = None
    decompose: bool = False
    candidates: int = 64
    label_sampler: str = "dense"
    learner: str = "NKM"
    encoder: str = "Natural"
    n_atoms: int = 200
    n_patches: int = 50_000
    folds: int = 5
    inner_folds: int = 3
    offline: bool = True
    C: float = 1.0
    detector: str = "lattice"
    physical: bool = True
    coarse_to_fine: bool = True
    rescore: int = 50
    detection_images: int | None = None
    fit_grid: float | None = None
    hard_negatives: int = 0
    hard_rounds: int = 1
    grid_negatives: float = 0.0
    gripper_aware: bool = True
    complete_region: bool = True
    clear_jaws: bool = False
    scene: str = "drop"
    gripper: str = "builtin"
    trials: int = 100
    trial_candidates: int = 32
    baselines: list[str] = field(default_factory=lambda: ["mask-pca", "random", "oracle"])
    detector_options: dict = field(default_factory=dict)
    backend: str = "loky"
    address: str | None = None
    jobs: int = 2

    def validated(self) -> RunConfig:
        from dlsr.detection import check_training_options
        from dlsr.features import ENCODERS, LEARNERS

        if self.learner not in LEARNERS:
            raise ValueError(f"learner must be one of {LEARNERS}, got {self.learner!r}")
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        from dlsr.detection import DETECTOR_KINDS

        if self.detector not in DETECTOR_KINDS:
            raise ValueError(f"detector must be one of {DETECTOR_KINDS}, got {self.detector!r}")
        if not self.grid_negatives >= 0:
            raise ValueError(f"grid_negatives must be >= 0, got {self.grid_negatives}")
        for name in ("scenes", "candidates", "n_atoms", "n_patches", "folds", "trials"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        check_training_options(self.fit_grid, self.hard_negatives, self.hard_rounds,
                               self.physical)
        from .labelling import check_sampler

        check_sampler(self.label_sampler)
        from .hands import HAND_NAMES
        from .scenes import check_scene

        check_scene(self.scene, self.objects_per_scene)
        if self.gripper not in HAND_NAMES:
            raise ValueError(f"gripper must be one of {', '.join(HAND_NAMES)}, "
                             f"got {self.gripper!r}")
        for name in ("train_objects", "trial_objects"):
            value = getattr(self, name)
            if not isinstance(value, str):
                raise ValueError(f"{name} must be a string (an object set: train, test, all, "
                                 "comma-separated object names, random_urdfs[:split], "
                                 f"ycb[:split] or folder:PATH[:split]), got {value!r}")
            try:
                self.object_set(name).specs()
            except (ValueError, FileNotFoundError) as exc:
                raise ValueError(f"{name}: {exc}") from None
        self._check_baselines()
        if self.scenes < self.folds:
            raise ValueError(f"{self.folds} folds need at least {self.folds} scenes")
        return self

    @property
    def objects_per_scene(self) -> int:
        """Objects per scene: 5 in packed and pile scenes (VGN, GIGA), else 1."""
        from .scenes import default_objects_per_scene

        return default_objects_per_scene(self.scene)

    def execution_params(self):
        """The :class:`graspsim.execution.ExecutionParams` of the dataset's labelling and of
        the trials: the defaults with ``gripper``'s hand."""
        from .execution import ExecutionParams

        return ExecutionParams.with_hand(self.gripper)

    def object_set(self, name: str = "trial_objects"):
        """The :class:`graspsim.object_sets.ObjectSet` of ``train_objects`` or
        ``trial_objects``, with ``object_scale``, ``object_mass`` and ``decompose``."""
        from .object_sets import parse_object_set

        return parse_object_set(getattr(self, name), scale=self.object_scale,
                                mass=self.object_mass, decompose=self.decompose)

    def _check_baselines(self) -> None:
        """Every baseline loads (built-in, plug-in or model), so a bad name fails before the
        run rather than at its trial stage."""
        from .detectors import check_detector

        if isinstance(self.baselines, str) or not all(isinstance(b, str)
                                                      for b in self.baselines):
            raise ValueError(f"baselines must be a list of detector names, "
                             f"got {self.baselines!r}")
        if not isinstance(self.detector_options, dict):
            raise ValueError(f"detector_options must be a table of tables (one per baseline), "
                             f"got {self.detector_options!r}")
        unknown = sorted(set(self.detector_options) - set(self.baselines))
        if unknown:
            raise ValueError(f"detector_options: {unknown} not among the baselines "
                             f"{self.baselines}")
        seen = set()
        for name in self.baselines:
            if name in ("dlsr", "dlsr-paper"):
                raise ValueError(f"baselines: {name!r} is DLSR's own trial name (DLSR always "
                                 f"runs, and dlsr-paper with the gripper-aware search)")
            if name in seen:
                raise ValueError(f"baselines: {name!r} is listed twice")
            seen.add(name)
            try:
                check_detector(name, self.detector_options.get(name))
            except (ValueError, FileNotFoundError) as exc:
                raise ValueError(f"baselines: {exc}") from None


# The 2-minute version (``--quick``).
QUICK = {
    "name": "quick", "scenes": 16, "candidates": 32, "n_atoms": 50, "n_patches": 10_000,
    "folds": 3, "inner_folds": 2, "trials": 16, "trial_candidates": 16,
}


def load_config(path=None, quick: bool = False, **overrides) -> RunConfig:
    """A :class:`RunConfig` from defaults, ``--quick``, a TOML or YAML file, then overrides.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        The file is empty of settings, not TOML/YAML (truncated, garbage), or has unknown
        settings or settings of the wrong type; the message names the file and the setting.
    """
    values: dict = {}
    if quick:
        values.update(QUICK)
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"config file not found: {path}")
        suffix = path.suffix.lower()
        if suffix == ".toml":
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                import tomli as tomllib
            parse, errors = tomllib.loads, ()
        elif suffix in (".yaml", ".yml"):
            try:
                import yaml
            except ModuleNotFoundError as exc:
                raise ValueError(f"{path}: YAML configs need PyYAML (pip install pyyaml); "
                                 "TOML works out of the box") from exc
            parse, errors = yaml.safe_load, (yaml.YAMLError,)
        else:
            raise ValueError(f"{path}: config must be .toml, .yaml or .yml")
        with file_errors(path, "config file", errors):
            data = parse(path.read_bytes().decode("utf-8"))
        if not data:  # an empty (or truncated to nothing) file is not "the defaults"
            raise ValueError(f"config file {path}: no settings (empty file)")
        if not isinstance(data, dict):
            raise ValueError(f"config file {path}: expected a table of settings, got "
                             f"{type(data).__name__}")
        data = data.get("run", data)
        values.update(_settings(data, f"config file {path}"))
    values.update({k: v for k, v in overrides.items() if v is not None})
    return RunConfig(**values).validated()


# The Python types each RunConfig annotation accepts (an int is a float; a bool is no int).
_TYPES = {"int": (int,), "float": (int, float), "bool": (bool,), "str": (str,),
          "None": (type(None),), "list[str]": (list,)}


def _settings(data, where: str) -> dict:
    """``data`` checked to be settings of :class:`RunConfig`: known names, right types.

    An annotation this check does not know is not checked (``validated`` still runs).
    """
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a table of settings, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(RunConfig)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{where}: unknown settings {unknown}; known: {sorted(fields)}")
    for name, value in data.items():
        kinds = [_TYPES.get(t.strip()) for t in str(fields[name].type).split("|")]
        if any(k is None for k in kinds):
            continue
        ok = any(isinstance(value, k) for k in kinds)
        if isinstance(value, bool) and bool not in sum(kinds, ()):
            ok = False
        if isinstance(value, list) and not all(isinstance(v, str) for v in value):
            ok = False
        if not ok:
            raise ValueError(f"{where}: setting {name!r} must be {fields[name].type}, "
                             f"got {value!r}")
    return data


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
    from .executor import Executor, task_seeds

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
        from .object_sets import check_same_object_set

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
        from .datagen import make_dataset

        t0 = time.perf_counter()
        stats = make_dataset(n_scenes=config.scenes,
                             objects=config.object_set("train_objects"),
                             out=root / "dataset", seed=seeds["dataset"],
                             n_candidates=config.candidates, sampler=config.label_sampler,
                             executor=ex, n_objects=config.objects_per_scene,
                             scene=config.scene, params=config.execution_params())
        stats["seconds"] = time.perf_counter() - t0
        stages.finish("dataset", stats)
    from dlsr.datasets import load_cornell

    samples = load_cornell(root / "dataset")

    # 2. Recognition by nested cross-validation (object-wise).
    if config.offline and not stages.done("recognition"):
        from dlsr import recognition as rec

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
        from .benchmarks import detection_benchmark

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
    from .benchmarks import _train_saved

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
    for (key, *_), paths in zip(models, ex.imap(_train_saved, tasks, desc="models", star=True),
                                strict=True):
        stages.finish(key, {"paths": paths, "seconds": time.perf_counter() - t0})

    # 5. Simulated grasp trials on the held-out test objects (config.trial_objects).
    trial_stage(root, config, stages, model_path, seeds["trials"], ex, progress)

    # 6. The report.
    from .report import write_report

    report = write_report(root, config, stages.data, wall=time.perf_counter() - t_start)
    log.info("report: %s", report)
    return report


def _cpus() -> int:
    import os

    return os.cpu_count() or 1


def trial_stage(root: Path, config: RunConfig, stages, model_path: Path, seed: int, executor,
                progress: bool = True) -> None:
    """Stage 5: simulated grasp trials of DLSR and ``config.baselines`` on
    ``config.trial_objects`` (default: the held-out test objects).

    Each detector's trials go to ``root / "trials" / name`` (resumed trial by trial) and its
    summary into ``stages`` as ``"trials/<name>"`` once finished. The scenes are labelled by
    physics once, by the first detector's trials, into ``root / "labels"``
    (:class:`graspsim.scene_labels.SceneLabels`), and the others read them. A baseline may be
    any name :func:`graspsim.detectors.load_detector` takes, plug-ins
    (``package.module:NAME``, entry-point names) included.
    """
    from .detectors import detector_label
    from .trials import TrialConfig, run_trials

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
        from dlsr.detection import DLSRDetector

        kind = config.detector if name == "dlsr" else "dense"
        if name == "dlsr-paper":
            model_path = _paper_model_path(model_path, config)
        options = {}
        if kind == "dense":
            options = {"coarse_to_fine": config.coarse_to_fine, "rescore": config.rescore}
        model = DLSRDetector.load(model_path)
        if name == "dlsr":
            from .detector_options import DetectorOptions, build_real_detector

            opts = DetectorOptions(detector=kind, complete_region=config.complete_region,
                                   physical=config.physical,
                                   gripper_aware=config.gripper_aware,
                                   clear_jaws=config.clear_jaws)
            return build_real_detector(model, opts, rescore=config.rescore,
                                       coarse_to_fine=config.coarse_to_fine, hand=hand)
        return model.detector(kind, **options)
    from .detectors import load_detector

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
    settings = dict(_settings(recorded["config"], f"run record {run_json} config"))
    settings.update({k: v for k, v in execution.items() if v is not None})
    config = RunConfig(**settings).validated()
    return run_job(config, out=folder, resume=True, progress=progress)


def objectwise_validation(config: RunConfig | None = None, n_folds: int = 3, fold_seed: int = 0,
                          out=None, progress: bool = True, offline: bool = False) -> dict:
    """Object-wise validation of a run configuration: trials on train objects it never saw.

    ``config.train_objects`` (default: the built-in train objects) is split into ``n_folds``
    object folds (:func:`graspsim.trials.object_folds`); for each fold the whole job runs
    (:func:`run_job`: dataset, CV, models, trials of DLSR and the baselines) with the other
    folds' objects as its train objects and the fold's as its trial objects. The trials of
    all folds are then pooled, detector by detector, and DLSR is compared with each other
    detector scene by scene (exact McNemar, :func:`graspsim.compare.compare_outcomes`). With
    the default ``train_objects`` the test objects are never used: this is where settings are
    chosen. Each fold's run is resumed like any run. Two configurations validated with the same
    folds compare with ``graspsim compare A B`` (:func:`graspsim.compare.compare_pair`), which
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
        ``n``), ``detectors`` (pooled :func:`graspsim.trials.summarize` of each detector, DLSR
        first, without the per-trial records), ``comparisons`` (DLSR against each other
        detector), ``folder``. Also written to ``objectwise.json`` and ``objectwise.md``.
    """
    from .compare import compare_outcomes, pooled_fold_trials
    from .trials import object_folds, summarize

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
