"""Grasp trials: a detector's best rectangle executed by the simulated gripper, scored by physics
and by the rectangle metric on the same scenes.

Every trial ``i`` of a run with seed ``s`` gets its own generator streams from
``SeedSequence(s, spawn_key=(i,))`` (scene, camera, labelling candidates, detector seed), and
every scene is built from scratch in the worker's own :class:`~graspsim.sim.Simulation`, so a
trial's result depends only on ``(s, i)``: the same for any ``n_jobs``, for any ``n``, and on
resume.

The detector is anything :func:`graspsim.detectors.load_detector` takes (built-in names,
``package.module:NAME`` plug-ins, entry-point names, saved models) or an object with
``predict(obs)``; :func:`observation` builds ``obs`` and :func:`propose` calls, times and checks
it (see :class:`graspsim.detectors.GraspDetector` for the protocol). A ``predict`` that raises
fails its trial (``reason`` ``"detector error: TypeName: message"``) and the run goes on; a
return value that breaks the protocol stops the run with a one-line ``ValueError``.
Clutter-removal rounds (``graspsim trials --declutter``) are in :mod:`graspsim.declutter`.

Output folder (``out``):

* ``trials.jsonl``: one JSON object per trial, appended and flushed as each trial finishes.
  Rerunning with the same arguments after a kill drops a torn last line, keeps every complete
  record and runs only the missing trial indices (none repeated, none lost). A different
  configuration in an existing folder is refused. Each record has the detector's planning time
  (``planning_seconds``, the wall time of ``predict``) and, when it gave scores, the executed
  rectangle's ``score``.
* ``config.json``: the run's arguments, the execution parameters among them (``execution``,
  :class:`graspsim.execution.ExecutionParams` as a dict; read it back with
  :func:`campaign_execution_params`) and, for a detector given options, ``detector_options``
  (its ``detector`` then names them: :func:`graspsim.detectors.detector_label`). A resume with
  other arguments is refused; a folder written before the execution parameters were recorded
  ran with the defaults.
* ``summary.json`` and ``summary.md``: physical success rate with a Wilson 95 % interval,
  rectangle-metric accuracy on the same trials, the 2x2 table of metric verdict against physical
  outcome, failure reasons, planning time (median and 95th percentile), trials per second.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlsr.metrics import rectangle_metric
from dlsr.records import (
    CorruptFileError,
    read_json,
    read_jsonl,
    write_json_atomic,
    write_text_atomic,
)

from .detectors import (
    check_detections,
    check_detector_options,
    detector_label,
    load_detector,
    one_line,
)
from .execution import (
    ExecutionParams,
    execute_grasp,
    execution_params_from_dict,
    harness_grasps,
    run_grasp,
)
from .graspability import apply_graspability
from .labelling import label_rectangles, rank_order, sample_candidates
from .object_sets import ObjectSet, as_object_set, check_same_object_set
from .objects import ObjectSpec
from .scene import build_scene, capture
from .scenes import check_scene, make_scene_of
from .sim import Simulation
from .trial_summary import (  # noqa: F401 (public here, as before)
    _execution_line,
    _planning_line,
    planning_stats,
    skipped_line,
    summarize,
    summary_markdown,
    wilson_interval,
)

__all__ = [
    "TrialConfig",
    "run_trial",
    "run_trials",
    "summarize",
    "wilson_interval",
    "resolve_objects",
    "object_set_meta",
    "object_folds",
    "trial_streams",
    "observation",
    "propose",
    "planning_stats",
    "campaign_execution_params",
    "SceneError",
    "skipped_record",
    "is_skipped",
]

log = logging.getLogger(__name__)


class SceneError(ValueError):
    """A seeded scene that cannot be made (objects that never come to rest, a pile that never
    settles). It is the same scene for every detector, so a campaign records it as a skip
    (:func:`skipped_record`) and pairs detectors on the scenes that were made."""


def skipped_record(seed: int, index: int, error: Exception) -> dict:
    """The record a campaign keeps for trial or round ``index`` whose scene could not be
    made: ``index``, ``seed`` and ``skipped`` (the reason). Logged as a warning."""
    log.warning("%s: skipped", error)
    return {"index": index, "seed": seed, "skipped": str(error)}


def is_skipped(record: dict) -> bool:
    """Whether a trial or round record is a skip (:func:`skipped_record`)."""
    return "skipped" in record

NO_PROPOSAL = "no grasp proposed"


@dataclass(frozen=True)
class TrialConfig:
    """What every trial of a run shares.

    Attributes
    ----------
    n_candidates : int
        Candidates proposed and executed to label each scene (0: no labelling, so no
        rectangle-metric verdict and no oracle).
    n_objects : int
        Objects per scene (1: Cornell-like).
    label_with_clean_depth : bool
        Turn labelling candidates into poses with the noise-free depth (ground truth
        independent of sensor dropout) instead of the observed depth.
    sampler : {"mixed", "dense"}
        How labelling candidates are drawn (:func:`graspsim.labelling.sample_candidates`;
        ``"dense"`` takes ``n_candidates`` as its budget).
    profile : str
        How scenes are seen: a name in :data:`graspsim.profiles.PROFILES` (camera height and
        intrinsics, table colour, lighting, depth noise); the objects and poses of trial ``i``
        do not depend on it.
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects are put on the table (:mod:`graspsim.scenes`); ``"drop"``, the
        default, is what every campaign ran before the option existed.
    """

    n_candidates: int = 32
    n_objects: int = 1
    label_with_clean_depth: bool = False
    sampler: str = "mixed"
    profile: str = "default"
    scene: str = "drop"


def resolve_objects(objects, params: ExecutionParams | None = None) -> list[ObjectSpec]:
    """The objects of a run, with their graspable flags for the run's hand.

    Parameters
    ----------
    objects : str, ObjectSet or list of ObjectSpec
        An object-set text (:func:`graspsim.object_sets.parse_object_set`: ``"train"``,
        ``"test"``, ``"all"`` (the built-in set's split), comma-separated names of built-in
        objects (``"bottle_water,can_soda"``; kept in the built-in set's order, so the scenes of
        a seed depend on the names chosen, not on how they are listed),
        ``"random_urdfs[:train|test|all]"``, ``"folder:PATH[:train|test|all]"``), an
        :class:`~graspsim.object_sets.ObjectSet`, or ObjectSpecs.
    params : ExecutionParams or None
        The harness and hand the run executes with (default: the built-in hand): the
        ``graspable`` flags are those measured by physics with this hand
        (:func:`graspsim.graspability.apply_graspability`), where a manifest has them.

    Raises
    ------
    ValueError
        Naming an object the built-in set does not have (the message lists them), a bad set
        (see :meth:`graspsim.object_sets.ObjectSet.specs`), or no object.
    """
    oset = as_object_set(objects)
    specs = oset.specs() if oset is not None else list(objects)
    if not specs:
        raise ValueError(f"no objects in {objects!r}")
    # The graspable flag by physics where a manifest has it (graspsim.graspability).
    return apply_graspability(specs, params=params)


def object_set_meta(objects, specs) -> dict:
    """What a campaign folder records of its objects: ``objects`` (the text, or the names of
    ObjectSpecs given in Python) and ``object_set`` (:meth:`graspsim.object_sets.ObjectSet.record`;
    for ObjectSpecs, their fingerprint with ``text`` and ``source`` None)."""
    oset = as_object_set(objects)
    if oset is None:
        probe = ObjectSet(text="", source="specs")
        record = {"text": None, "source": None, "path": None, "split": None,
                  "n_objects": len(specs), "fingerprint": probe.fingerprint(specs),
                  "scale": None, "mass": None, "decompose": None}
        return {"objects": [s.name for s in specs], "object_set": record}
    return {"objects": oset.text, "object_set": oset.record(specs)}


def object_folds(objects="train", n_folds: int = 3, seed: int = 0) -> list[list[str]]:
    """Object-wise folds: ``objects`` split at random into ``n_folds`` disjoint groups.

    For choosing a detector's settings on objects its model has not seen without touching the
    test objects: train on every fold but one, run trials on that one (``RunConfig``'s
    ``train_objects`` / ``trial_objects``; ``scripts/objectwise_validation.py``).

    Parameters
    ----------
    objects : str or list of ObjectSpec
        As :func:`resolve_objects` (default: the built-in train objects).
    n_folds : int
        Between 2 and the number of objects.
    seed : int
        The split's seed (the same seed gives the same folds).

    Returns
    -------
    list of list of str
        Object names per fold, each in the order of ``objects`` (built-in names: the built-in
        order); fold sizes differ by at most one.
    """
    names = [s.name for s in resolve_objects(objects)]
    if isinstance(n_folds, bool) or not isinstance(n_folds, (int, np.integer)) or not (
            2 <= n_folds <= len(names)):
        raise ValueError(f"n_folds must be an integer between 2 and the {len(names)} objects, "
                         f"got {n_folds!r}")
    perm = np.random.default_rng(seed).permutation(len(names))
    return [[names[i] for i in sorted(perm[k::n_folds])] for k in range(int(n_folds))]


def trial_streams(seed: int, index: int) -> dict:
    """Independent generators (scene, camera, labels) and a detector seed for one trial."""
    ss = np.random.SeedSequence(seed, spawn_key=(index,))
    scene_ss, camera_ss, label_ss, det_ss = ss.spawn(4)
    return {
        "scene": np.random.default_rng(scene_ss),
        "camera": np.random.default_rng(camera_ss),
        "label": np.random.default_rng(label_ss),
        "detector_seed": int(det_ss.generate_state(1)[0]),
    }


def observe_scene(sim, specs, seed: int, index: int, n_objects: int = 1, profile=None,
                  scene: str = "drop"):
    """Build trial ``index``'s seeded scene in ``sim`` and take its observation.

    ``scene`` is the protocol (:func:`graspsim.scenes.make_scene_of`). ``profile`` (a
    :class:`graspsim.profiles.SimProfile` or a name in :data:`graspsim.profiles.PROFILES`;
    None for the default) sets the camera height and
    intrinsics, table colour, lighting ranges and depth noise; the objects and their poses are
    the same under every profile.

    Returns
    -------
    scene : Scene
    bodies : the loaded bodies (see :func:`graspsim.scene.build_scene`)
    frame : RGBDFrame
    streams : dict
        The trial's generators (:func:`trial_streams`); ``"label"`` and ``"detector_seed"``
        are still unused.

    Raises
    ------
    SceneError
        When the scene cannot be made (:func:`graspsim.scene.make_scene`); the message names
        the scene's index and seed.
    """
    from .profiles import get_profile

    prof = get_profile(profile)
    st = trial_streams(seed, index)
    try:
        placed = make_scene_of(scene, sim, specs, st["scene"], n_objects=n_objects,
                               table=prof.table)
    except ValueError as exc:
        raise SceneError(f"scene {index} of seed {seed}: {exc}") from None
    bodies = build_scene(sim, placed)
    frame = profile_capture(sim, placed, bodies, st["camera"], prof)
    return placed, bodies, frame, st


def profile_capture(sim, scene, bodies, rng, profile=None, noise=None):
    """:func:`graspsim.scene.capture` with a profile's camera height, intrinsics, lighting
    ranges and depth noise (``profile``: a :class:`graspsim.profiles.SimProfile`, a name, or
    None for the default; ``noise``, when given, replaces the profile's depth noise)."""
    from .profiles import get_profile

    prof = get_profile(profile)
    return capture(sim, scene, bodies, rng, noise=prof.depth_noise if noise is None else noise,
                   intrinsics=prof.intrinsics, height=prof.camera_height,
                   lighting=prof.lighting)


_WORKER = {}


def _worker_sim() -> Simulation:
    """One simulator per worker process (re-created after a fork)."""
    pid = os.getpid()
    sim = _WORKER.get(pid)
    if sim is None:
        sim = Simulation()
        _WORKER.clear()
        _WORKER[pid] = sim
    return sim


def _rect_list(r) -> list[float]:
    return [round(float(v), 4) for v in r.as_array()]


def observation(frame, detector_seed: int) -> dict:
    """What a detector's ``predict`` gets (see :class:`graspsim.detectors.GraspDetector`).

    Parameters
    ----------
    frame : graspsim.camera.RGBDFrame
    detector_seed : int

    Returns
    -------
    dict
        ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres (0 where missing),
        ``depth_valid`` (H, W) uint8, ``K`` (3, 3) float64 pixels, ``T_world_cam`` (4, 4)
        float64 (OpenCV camera frame to world, metres) and ``seed``; copies, so a detector
        cannot change what the gripper then executes.
    """
    return {
        "rgb": np.array(frame.rgb, dtype=np.uint8),
        "depth": np.array(frame.depth, dtype=np.float32),
        "depth_valid": np.asarray(frame.depth_valid).astype(np.uint8),
        "K": np.array(frame.intrinsics.K, dtype=np.float64),
        "T_world_cam": np.array(frame.T_world_cam, dtype=np.float64),
        "seed": int(detector_seed),
    }


def _detector_name(detector) -> str:
    return str(getattr(detector, "label", None) or getattr(detector, "spec", None)
               or type(detector).__name__)


def _label_scene(sim, scene, frame, bodies, rng, detector, config, params, known=None):
    """Physics labels of the observed scene: ``(positives or None, n_labelled, entry)``.

    ``known`` is the scene's entry in a :class:`graspsim.scene_labels.SceneLabels` store (or
    None): the candidates are drawn as always and, when they are the ones it was made from,
    its positives are taken instead of executing them. ``entry`` is the store entry of labels
    executed here (None when ``known`` was used or nothing was labelled).
    """
    from .scene_labels import candidates_digest, known_positives

    if config.n_candidates > 0:
        cands = sample_candidates(frame.segmentation, bodies.objects, rng,
                                  config.n_candidates, depth=frame.depth_clean,
                                  mode=config.sampler, intrinsics=frame.intrinsics,
                                  max_opening=(params or ExecutionParams()).gripper.geometry
                                  .max_opening)
        positives = known_positives(known, cands)
        if positives is not None:
            return positives, len(cands), None
        kw = {}
        if config.label_with_clean_depth:
            kw = {"depth": frame.depth_clean, "depth_valid": frame.depth_clean > 0}
        labelled = label_rectangles(sim, scene, frame, cands, params, **kw)
        order = rank_order(labelled)
        entry = {"positives": order, "n_labelled": len(cands),
                 "candidates": candidates_digest(cands)}
        return [cands[i] for i in order], len(cands), entry
    if getattr(detector, "requires_labels", False):
        raise ValueError("this detector needs labelled scenes: use n_candidates > 0")
    return None, 0, None


def propose(detector, obs, name: str | None = None):
    """Call ``detector.predict(obs)``, time it and validate what it returns.

    Returns
    -------
    rects : list of GraspRectangle (empty when nothing was proposed or predict raised)
    scores : ndarray of shape (n,) or None
    error : str or None
        ``"detector error: TypeName: message"`` when ``predict`` raised (one line).
    seconds : float
        Wall time of ``predict`` (the planning time).

    Raises
    ------
    ValueError
        When the return value breaks the protocol (:func:`graspsim.detectors.check_detections`).
    """
    name = _detector_name(detector) if name is None else name
    t0 = time.perf_counter()
    try:
        out = detector.predict(obs)
    except Exception as exc:
        return [], None, f"detector error: {one_line(exc)}", time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    rects, scores = check_detections(out, name)
    return rects, scores, None, seconds


def _execute(sim, scene, frame, rects, scores, error, positives, params):
    """Execute the first of ``rects`` in ``scene`` (rebuilt from scratch).

    Returns the record fields, the GraspResult (None when nothing ran) and the scene bodies the
    grasp ran in (None when the gripper never moved: no proposal, no valid grasp pose).
    """
    if error is not None or not rects:
        fields = dict(rectangle=None, pose=None, success=False,
                      reason=error if error is not None else NO_PROPOSAL, lift_height=0.0,
                      metric=None if positives is None else False)
        return fields, None, None
    rect = rects[0]
    g = harness_grasps([rect], frame, scene.table_z, params)[0]
    if g.failure is not None:
        res, bodies = run_grasp(sim, scene, g, params), None
    else:
        bodies = build_scene(sim, scene)
        res = execute_grasp(sim, scene, bodies, g, params)
    fields = dict(
        rectangle=_rect_list(rect),
        pose=None if res.T_world_tcp is None else np.round(res.T_world_tcp, 5).tolist(),
        opening=round(float(g.opening), 5),
        success=bool(res.success), reason=res.reason,
        lift_height=round(float(res.lift_height), 5),
        metric=None if positives is None else bool(rectangle_metric(rect, positives)),
    )
    if scores is not None:
        fields["score"] = float(scores[0])
    return fields, res, bodies


def run_trial(sim, specs, detector, seed: int, index: int,
              config: TrialConfig = TrialConfig(),
              params: ExecutionParams | None = None, name: str | None = None,
              known: dict | None = None, share: bool = False) -> dict:
    """One trial: scene, observation, (labels), detection, execution, verdict.

    Parameters
    ----------
    name : str or None
        The detector's name in error messages (default: its plug-in name or class name).
    known : dict or None
        The scene's labels from a :class:`graspsim.scene_labels.SceneLabels` store, used
        instead of executing the candidates (the record is the same).
    share : bool
        Return labels executed here in the record's ``"_labels"``, for the store (the caller
        takes it out).

    Returns
    -------
    dict
        The JSON record (``index``, ``seed``, ``object``, ``rectangle``, ``pose``, ``success``,
        ``reason``, ``lift_height``, ``metric`` (bool or None when unlabelled), ``n_positives``,
        ``n_labelled``, ``planning_seconds`` (the detector's ``predict``), ``score`` (when the
        detector gave scores), ``seconds``). A ``predict`` that raised gives a failed trial
        whose ``reason`` is ``"detector error: TypeName: message"``.

    Raises
    ------
    ValueError
        When the detector's return value breaks the protocol (the message names the trial).
    """
    t0 = time.perf_counter()
    scene, bodies, frame, st = observe_scene(sim, specs, seed, index, config.n_objects,
                                             config.profile, config.scene)
    positives, n_labelled, (rects, scores, error, planning), entry = _label_and_propose(
        sim, scene, frame, bodies, st, detector, config, params, name,
        f"trial {index} (seed {seed})", known)
    record = {
        "index": index, "seed": seed, "object": [o.spec.name for o in scene.objects],
        "graspable": all(o.spec.graspable for o in scene.objects),
        "redraws": scene.redraws, "n_labelled": n_labelled,
        "n_positives": None if positives is None else len(positives),
    }
    record.update(_execute(sim, scene, frame, rects, scores, error, positives, params)[0])
    record["planning_seconds"] = round(planning, 6)
    record["seconds"] = round(time.perf_counter() - t0, 4)
    if share and entry is not None:
        record["_labels"] = {"index": index, **entry}
    return record


def _label_and_propose(sim, scene, frame, bodies, streams, detector, config, params, name,
                       where: str, known: dict | None = None):
    """Label the observed scene (when ``config`` asks; from ``known``, a store's entry, when it
    fits) and ask the detector for rectangles.

    Returns ``(positives or None, n_labelled, propose(...), entry)``, ``entry`` the labels
    executed here for a store (see :func:`_label_scene`); a return value that breaks the
    detector protocol is a ValueError prefixed with ``where`` (the trial, round or attempt).
    """
    obs = observation(frame, streams["detector_seed"])
    positives, n_labelled, entry = _label_scene(sim, scene, frame, bodies, streams["label"],
                                                detector, config, params, known)
    if positives is not None:
        obs["positives"] = positives
    try:
        return positives, n_labelled, propose(detector, obs, name), entry
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def _trial_task(specs, detector, seed, index, config, params, known=None, share=False):
    try:
        return run_trial(_worker_sim(), specs, detector, seed, index, config, params,
                         known=known, share=share)
    except SceneError as exc:
        return skipped_record(seed, index, exc)


def read_done(path: Path) -> dict[int, dict]:
    """Complete records of a resumable JSONL file by their ``index`` (the first of repeats).

    A torn last line (a kill during a write) is dropped and the file repaired, so appended
    records start on a line of their own (see :func:`dlsr.records.read_jsonl`); any other bad
    line, or an ``index`` that is not a non-negative integer, is an error naming the file and
    line.
    """
    path = Path(path)
    done: dict[int, dict] = {}
    for rec in read_jsonl(path, required=("index",), repair=True):
        i = rec["index"]
        if isinstance(i, bool) or not isinstance(i, int) or i < 0:
            raise CorruptFileError(f"results file {path}: a record has index {i!r}, "
                                   "not a non-negative integer")
        done.setdefault(i, rec)
    return done


def _open_campaign(out, meta: dict, filename: str):
    """Create or reopen an output folder: refuse another configuration, read finished records.

    Returns ``(out, jsonl path, {index: record})``; ``(None, None, {})`` for in-memory runs.
    """
    if out is None:
        return None, None, {}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.json"
    if cfg_path.exists():
        old = read_json(cfg_path, "trials configuration")
        if "object_set" in meta:
            check_same_object_set(old.get("object_set"), meta["object_set"], out)
            # Folders written before the object set was recorded hold a built-in set, named
            # by its text (still compared below).
            old.setdefault("object_set", meta["object_set"])
        if isinstance(old.get("config"), dict):
            # A folder written before a TrialConfig field existed ran with its default.
            old["config"] = {**asdict(TrialConfig()), **old["config"]}
        if "execution" in meta:
            # Folders written before the execution parameters were recorded ran the defaults.
            old["execution"] = asdict(execution_params_from_dict(old.get("execution", {}),
                                                                 str(cfg_path)))
        if {k: old.get(k) for k in meta} != json.loads(json.dumps(meta)):
            raise ValueError(
                f"{out} holds trials of another configuration ({cfg_path}); use a new folder"
            )
    write_json_atomic(cfg_path, meta)
    jsonl = out / filename
    return out, jsonl, read_done(jsonl)


def _run_missing(fn, tasks, done: dict, jsonl, executor, desc: str, on_record=None) -> int:
    """Run ``fn(*task)`` for every task, append each record to ``jsonl`` (flushed) as it comes
    and put it in ``done`` by its ``index``; returns the number of new records. ``on_record``,
    when given, sees each record first (and may take fields out of it)."""
    new = 0
    if not tasks:
        return new
    fh = open(jsonl, "a") if jsonl is not None else None  # noqa: SIM115
    try:
        for rec in executor.imap(fn, tasks, desc=desc, star=True):
            if on_record is not None:
                on_record(rec)
            done[rec["index"]] = rec
            new += 1
            if fh is not None:
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
    finally:
        if fh is not None:
            fh.close()
    return new


def _campaign_setup(detector, detector_name, objects, n: int, seed: int, config, params,
                    options=None):
    """The detector, the object specs and the arguments a campaign folder records
    (``config.json``, with the execution parameters and the detector's options, when it has
    any) for :func:`run_trials` and :func:`graspsim.declutter.run_rounds`."""
    check_scene(config.scene, config.n_objects)
    options = check_detector_options(options)
    det, det_name = _resolve(detector, detector_name, options)
    specs = resolve_objects(objects, params)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    meta = {"detector": det_name,
            # recorded only when given, so folders written without options still resume
            **({"detector_options": options} if options else {}),
            **object_set_meta(objects, specs), "seed": seed,
            "config": asdict(config),
            "execution": asdict(ExecutionParams() if params is None else params)}
    return det, specs, meta


def campaign_execution_params(folder) -> ExecutionParams:
    """The execution parameters a trial or clutter-round folder ran with.

    Read from its ``config.json`` (the defaults for a folder written before they were
    recorded), so that a replay executes what the campaign executed.

    Parameters
    ----------
    folder : str or Path
        A :func:`run_trials` or :func:`graspsim.declutter.run_rounds` output folder.

    Returns
    -------
    ExecutionParams
    """
    path = Path(folder) / "config.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found (not a trial folder)")
    cfg = read_json(path, "trials configuration")
    return execution_params_from_dict(cfg.get("execution", {}), str(path))


def _resolve(detector, detector_name, options=None):
    name = detector_name or (detector_label(str(detector), options)
                             if isinstance(detector, str | Path) else _detector_name(detector))
    det = load_detector(detector, options) if isinstance(detector, str | Path) else detector
    return det, name


def _executor(executor, n_jobs, progress):
    from .executor import Executor

    return executor or Executor(backend="loky" if n_jobs != 1 else "sequential",
                                n_jobs=n_jobs, progress=progress)


def run_trials(detector="random", objects="test", n: int = 200, seed: int = 0, out=None,
               n_jobs: int = 1, config: TrialConfig = TrialConfig(),
               params: ExecutionParams | None = None, progress: bool = False,
               executor=None, detector_name: str | None = None, labels=None,
               detector_options=None) -> dict:
    """Run (or finish) ``n`` trials and write records and summaries to ``out``.

    Parameters
    ----------
    detector : str or object
        A built-in name (``random``, ``mask-pca``, ``oracle``), a plug-in
        (``package.module:NAME`` or an installed entry-point name), a model path, or an object
        with ``predict(obs)`` (:class:`graspsim.detectors.GraspDetector`).
    objects : str, ObjectSet or list of ObjectSpec
        An object set (:func:`graspsim.trials.resolve_objects`: a built-in split or names,
        ``random_urdfs[:split]``, ``folder:PATH[:split]``).
    n : int
        Trials (indices ``0 .. n-1``).
    seed : int
    out : str or Path or None
        Output folder; None keeps everything in memory (no resume).
    n_jobs : int
        Worker processes (joblib loky); results do not depend on it.
    config : TrialConfig
    params : ExecutionParams or None
    progress : bool
    executor : graspsim.executor.Executor or None
        Where trials run (local cores or a Ray cluster; ``n_jobs`` is then ignored).
    detector_name : str or None
        Name recorded for a detector object (default: its plug-in name with its options, or
        its class name).
    labels : str or Path or None
        A folder of the scenes' physics labels shared with other detectors' trials on the
        same scenes (:class:`graspsim.scene_labels.SceneLabels`, made when missing): scenes
        it holds are not labelled again, the others are added to it. The records are the
        same with or without it. A folder of other scenes is refused.
    detector_options : dict or None
        Keyword arguments of a plug-in's class or factory (or a built-in detector's class),
        JSON values: ``detector`` (a name) is loaded with them; a detector object is taken
        as built with them. Recorded in ``config.json`` (``detector_options``) and in the
        detector's name (:func:`graspsim.detectors.detector_label`); a resume with other
        options is refused.

    Returns
    -------
    dict
        The summary (see :func:`summarize`), with ``records`` sorted by index.
    """
    det, specs, meta = _campaign_setup(detector, detector_name, objects, n, seed, config,
                                       params, detector_options)
    store, known, on_record = None, {}, None
    if labels is not None and config.n_candidates > 0:
        from .scene_labels import SceneLabels

        store = SceneLabels.open(labels, {k: v for k, v in meta.items()
                                          if k not in ("detector", "detector_options")})
        known = store.read()

        def on_record(rec):
            entry = rec.pop("_labels", None)
            if entry is not None:
                store.add(entry)

    return _campaign(_trial_task, "trials", meta, out, n, [specs, det, seed, config, params],
                     executor, n_jobs, progress, summarize, summary_markdown,
                     item_args=(lambda i: (known.get(i), True)) if store is not None else None,
                     on_record=on_record)


def _campaign(task, unit: str, meta: dict, out, n: int, args: list, executor, n_jobs: int,
              progress: bool, summarize_fn, markdown_fn, item_args=None,
              on_record=None) -> dict:
    """Run (or finish) items ``0 .. n-1`` of a resumable campaign and write its summaries.

    Item ``i`` runs ``task(*args[:3], i, *args[3:], *item_args(i))`` (``specs, detector, seed,
    i, config, params``, then what ``item_args`` gives item ``i``, when given); ``on_record``
    sees each new record before it is kept (:func:`_run_missing`); records go to
    ``out/<unit>.jsonl`` as they come, the summary of
    ``summarize_fn(records)`` over the items whose scene was made (with ``meta``, ``skipped``
    (index and reason of each item whose scene could not be made), ``<unit>_per_second`` and
    ``n_jobs``) to
    ``summary.json`` and ``markdown_fn(summary)`` to ``summary.md``.
    """
    out, jsonl, done = _open_campaign(out, meta, f"{unit}.jsonl")
    todo = [i for i in range(n) if i not in done]
    if done:
        log.info("resuming: %d of %d %s already done", n - len(todo), n, unit)
    t0 = time.perf_counter()
    tasks = [(*args[:3], i, *args[3:], *(item_args(i) if item_args else ())) for i in todo]
    new = _run_missing(task, tasks, done, jsonl,
                       _executor(executor, n_jobs, progress) if tasks else None, unit,
                       on_record)
    wall = time.perf_counter() - t0
    records = [done[i] for i in sorted(done) if i < n]
    skipped = [{"index": r["index"], "reason": r["skipped"]} for r in records if is_skipped(r)]
    records = [r for r in records if not is_skipped(r)]
    summary = summarize_fn(records)
    summary.update(meta)
    summary["skipped"] = skipped
    summary[f"{unit}_per_second"] = (new / wall) if new and wall > 0 else None
    summary["n_jobs"] = n_jobs if executor is None else executor.n_jobs
    if out is not None:
        write_json_atomic(out / "summary.json", summary)
        write_text_atomic(out / "summary.md", markdown_fn(summary))
    summary["records"] = records
    return summary
