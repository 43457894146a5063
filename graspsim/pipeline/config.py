"""The configuration of ``graspsim run``: :class:`RunConfig` (every setting a run depends on,
recorded in its ``run.json``) and :func:`load_config` (defaults, a TOML or YAML file, the
``--quick`` settings and command-line overrides, checked).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path

from dlsr.detection import DETECTOR_KINDS, check_training_options
from dlsr.features import ENCODERS, LEARNERS
from dlsr.records import file_errors

from ..detectors.loading import check_detector
from ..labels.labelling import check_sampler
from ..sim.execution import ExecutionParams
from ..sim.hands import HAND_NAMES
from ..sim.layouts import check_scene, default_objects_per_scene
from ..sim.object_sets import parse_object_set

__all__ = ["RunConfig", "load_config", "check_settings", "QUICK"]

log = logging.getLogger(__name__)


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
        trials: object sets (:func:`graspsim.sim.object_sets.parse_object_set`: ``"train"``,
        ``"test"``, ``"all"``, comma-separated names of built-in objects,
        ``"random_urdfs[:train|test|all]"``, ``"folder:PATH[:train|test|all]"``). Defaults:
        the built-in split, trials on the held-out test objects. Object-wise validation
        trains on some train objects and runs the trials on the others
        (:func:`graspsim.eval.trials.object_folds`, ``scripts/objectwise_validation.py``), so
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
        (:func:`graspsim.labels.labelling.sample_candidates`; ``"dense"``: a Jacquard-like lattice
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
        :mod:`graspsim.detectors.dlsr_options`' (shared with ``graspsim detect`` and ``graspsim
        benchmark detection``); ``graspsim run --no-complete-region`` etc. override them.
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects of the dataset and of the trials are put on the table
        (:mod:`graspsim.sim.layouts`); packed and pile scenes have 5 objects (VGN, GIGA). Default
        ``"drop"``: one object dropped at a random pose, the scene of the README's figures.
    gripper : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        The hand that labels the dataset, executes the trials and that DLSR's gripper-aware
        search judges rectangles for (:mod:`graspsim.sim.hands`); default the built-in one.
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
        Executor for the parallel stages (see :class:`graspsim.runtime.executor.Executor`).
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
        if self.learner not in LEARNERS:
            raise ValueError(f"learner must be one of {LEARNERS}, got {self.learner!r}")
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")

        if self.detector not in DETECTOR_KINDS:
            raise ValueError(f"detector must be one of {DETECTOR_KINDS}, got {self.detector!r}")
        if not self.grid_negatives >= 0:
            raise ValueError(f"grid_negatives must be >= 0, got {self.grid_negatives}")
        for name in ("scenes", "candidates", "n_atoms", "n_patches", "folds", "trials"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        check_training_options(self.fit_grid, self.hard_negatives, self.hard_rounds,
                               self.physical)

        check_sampler(self.label_sampler)

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
        return default_objects_per_scene(self.scene)

    def execution_params(self):
        """The :class:`graspsim.sim.execution.ExecutionParams` of the dataset's labelling and of
        the trials: the defaults with ``gripper``'s hand."""
        return ExecutionParams.with_hand(self.gripper)

    def object_set(self, name: str = "trial_objects"):
        """The :class:`graspsim.sim.object_sets.ObjectSet` of ``train_objects`` or
        ``trial_objects``, with ``object_scale``, ``object_mass`` and ``decompose``."""
        return parse_object_set(getattr(self, name), scale=self.object_scale,
                                mass=self.object_mass, decompose=self.decompose)

    def _check_baselines(self) -> None:
        """Every baseline loads (built-in, plug-in or model), so a bad name fails before the
        run rather than at its trial stage."""
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
            # deferred: tomllib is only read for TOML configs, tomli (optional) on Python 3.10
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                import tomli as tomllib
            parse, errors = tomllib.loads, ()
        elif suffix in (".yaml", ".yml"):
            try:
                # deferred, optional: PyYAML, for YAML configs only
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
        values.update(check_settings(data, f"config file {path}"))
    values.update({k: v for k, v in overrides.items() if v is not None})
    return RunConfig(**values).validated()


# The Python types each RunConfig annotation accepts (an int is a float; a bool is no int).
_TYPES = {"int": (int,), "float": (int, float), "bool": (bool,), "str": (str,),
          "None": (type(None),), "list[str]": (list,)}


def check_settings(data, where: str) -> dict:
    """``data`` checked to be settings of :class:`RunConfig`: known names, right types.

    An annotation this check does not know is not checked (``validated`` still runs).

    Parameters
    ----------
    data : dict
        Setting names to values (a config file's table, a recorded run's ``config``).
    where : str
        What ``data`` is, for messages.

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        Naming ``where`` and the unknown or ill-typed settings.
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
