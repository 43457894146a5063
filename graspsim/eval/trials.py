"""Grasp trials: a detector's best rectangle executed by the simulated gripper, scored by physics
and by the rectangle metric on the same scenes.

Every trial ``i`` of a run with seed ``s`` gets its own generator streams from
``SeedSequence(s, spawn_key=(i,))`` (scene, camera, labelling candidates, detector seed), and
every scene is built from scratch in the worker's own :class:`~graspsim.sim.bullet.Simulation`, so a
trial's result depends only on ``(s, i)``: the same for any ``n_jobs``, for any ``n``, and on
resume.

The detector is anything :func:`graspsim.detectors.load_detector` takes (built-in names,
``package.module:NAME`` plug-ins, entry-point names, saved models) or an object with
``predict(obs)``; :func:`graspsim.sim.observe.observation` builds ``obs`` and :func:`propose`
calls, times and checks
it (see :class:`graspsim.detectors.GraspDetector` for the protocol). A ``predict`` that raises
fails its trial (``reason`` ``"detector error: TypeName: message"``) and the run goes on; a
return value that breaks the protocol stops the run with a one-line ``ValueError``.
Clutter-removal rounds (``graspsim trials --declutter``) are in :mod:`graspsim.eval.declutter`.

Output folder (``out``):

* ``trials.jsonl``: one JSON object per trial, appended and flushed as each trial finishes.
  Rerunning with the same arguments after a kill drops a torn last line, keeps every complete
  record and runs only the missing trial indices (none repeated, none lost). A different
  configuration in an existing folder is refused. Each record has the detector's planning time
  (``planning_seconds``, the wall time of ``predict``) and, when it gave scores, the executed
  rectangle's ``score``.
* ``config.json``: the run's arguments, the execution parameters among them (``execution``,
  :class:`graspsim.sim.execution.ExecutionParams` as a dict; read it back with
  :func:`campaign_execution_params`) and, for a detector given options, ``detector_options``
  (its ``detector`` then names them: :func:`graspsim.detectors.detector_label`). A resume with
  other arguments is refused; a folder written before the execution parameters were recorded
  ran with the defaults.
* ``summary.json`` and ``summary.md``: physical success rate with a Wilson 95 % interval,
  rectangle-metric accuracy on the same trials, the 2x2 table of metric verdict against physical
  outcome, failure reasons, planning time (median and 95th percentile), trials per second.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlsr.metrics import rectangle_metric
from dlsr.records import read_json

from ..detectors.base import check_detections, one_line
from ..detectors.loading import check_detector_options, detector_label, load_detector
from ..labels.graspability import resolve_objects
from ..labels.labelling import label_rectangles, rank_order, sample_candidates
from ..labels.store import SceneLabels, candidates_digest, known_positives
from ..runtime.campaign import run_campaign, skipped_record
from ..sim.bullet import worker_sim
from ..sim.execution import (
    ExecutionParams,
    execute_grasp,
    execution_params_from_dict,
    harness_grasps,
    run_grasp,
)
from ..sim.layouts import check_scene
from ..sim.object_sets import check_same_object_set, object_set_meta
from ..sim.observe import SceneError, made_again_if_unmade, observation, observe_scene
from ..sim.scene import build_scene
from .summary import summarize, summary_markdown

__all__ = [
    "NO_PROPOSAL",
    "TrialConfig",
    "run_trial",
    "run_trials",
    "object_folds",
    "propose",
    "label_and_propose",
    "execute_proposal",
    "describe_detector",
    "campaign_setup",
    "upgrade_campaign_config",
    "campaign_execution_params",
]

log = logging.getLogger(__name__)

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
        How labelling candidates are drawn (:func:`graspsim.labels.labelling.sample_candidates`;
        ``"dense"`` takes ``n_candidates`` as its budget).
    profile : str
        How scenes are seen: a name in :data:`graspsim.sim.profiles.PROFILES` (camera height and
        intrinsics, table colour, lighting, depth noise); the objects and poses of trial ``i``
        do not depend on it.
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects are put on the table (:mod:`graspsim.sim.layouts`); ``"drop"``, the
        default, is what every campaign ran before the option existed.
    """

    n_candidates: int = 32
    n_objects: int = 1
    label_with_clean_depth: bool = False
    sampler: str = "mixed"
    profile: str = "default"
    scene: str = "drop"


def object_folds(objects="train", n_folds: int = 3, seed: int = 0) -> list[list[str]]:
    """Object-wise folds: ``objects`` split at random into ``n_folds`` disjoint groups.

    For choosing a detector's settings on objects its model has not seen without touching the
    test objects: train on every fold but one, run trials on that one (``RunConfig``'s
    ``train_objects`` / ``trial_objects``; ``scripts/objectwise_validation.py``).

    Parameters
    ----------
    objects : str or list of ObjectSpec
        As :func:`graspsim.labels.graspability.resolve_objects` (default: the built-in train
        objects).
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


def _rect_list(r) -> list[float]:
    return [round(float(v), 4) for v in r.as_array()]


def describe_detector(detector) -> str:
    """A detector object's name in records and messages: its ``label``, its plug-in ``spec``,
    or its class name.

    Parameters
    ----------
    detector : object

    Returns
    -------
    str
    """
    return str(getattr(detector, "label", None) or getattr(detector, "spec", None)
               or type(detector).__name__)


def _label_scene(sim, scene, frame, bodies, rng, detector, config, params, known=None):
    """Physics labels of the observed scene: ``(positives or None, n_labelled, entry)``.

    ``known`` is the scene's entry in a :class:`graspsim.labels.store.SceneLabels` store (or
    None): the candidates are drawn as always and, when they are the ones it was made from,
    its positives are taken instead of executing them. ``entry`` is the store entry of labels
    executed here (None when ``known`` was used or nothing was labelled).
    """
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
    name = describe_detector(detector) if name is None else name
    t0 = time.perf_counter()
    try:
        out = detector.predict(obs)
    except Exception as exc:
        return [], None, f"detector error: {one_line(exc)}", time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    rects, scores = check_detections(out, name)
    return rects, scores, None, seconds


def execute_proposal(sim, scene, frame, rects, scores, error, positives, params):
    """Execute the first of ``rects`` in ``scene`` (rebuilt from scratch) and judge it.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    scene : graspsim.sim.scene.Scene
    frame : graspsim.sim.camera.RGBDFrame
        The observation the rectangles are in.
    rects : list of GraspRectangle
        The proposal, best first (empty: nothing proposed).
    scores : ndarray of shape (n,) or None
    error : str or None
        The detector's error (:func:`propose`); the trial then fails with it as its reason.
    positives : list of GraspRectangle or None
        The scene's physics labels, for the rectangle metric (None: unlabelled).
    params : ExecutionParams or None

    Returns
    -------
    fields : dict
        The record's ``rectangle``, ``pose``, ``opening``, ``success``, ``reason``,
        ``lift_height``, ``metric`` (and ``score``).
    result : GraspResult or None
        None when nothing ran.
    bodies : the scene bodies the grasp ran in, or None
        None when the gripper never moved (no proposal, no valid grasp pose).
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
        The scene's labels from a :class:`graspsim.labels.store.SceneLabels` store, used
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
    positives, n_labelled, (rects, scores, error, planning), entry = label_and_propose(
        sim, scene, frame, bodies, st, detector, config, params, name,
        f"trial {index} (seed {seed})", known)
    record = {
        "index": index, "seed": seed, "object": [o.spec.name for o in scene.objects],
        "graspable": all(o.spec.graspable for o in scene.objects),
        "redraws": scene.redraws, "n_labelled": n_labelled,
        "n_positives": None if positives is None else len(positives),
    }
    record.update(execute_proposal(sim, scene, frame, rects, scores, error, positives, params)[0])
    record["planning_seconds"] = round(planning, 6)
    record["seconds"] = round(time.perf_counter() - t0, 4)
    if share and entry is not None:
        record["_labels"] = {"index": index, **entry}
    return record


def label_and_propose(sim, scene, frame, bodies, streams, detector, config, params, name,
                      where: str, known: dict | None = None):
    """Label the observed scene (when ``config`` asks) and ask the detector for rectangles.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    scene : graspsim.sim.scene.Scene
    frame : graspsim.sim.camera.RGBDFrame
    bodies : the loaded bodies (:func:`graspsim.sim.scene.build_scene`)
    streams : dict
        The trial's generators (:func:`graspsim.sim.observe.trial_streams`).
    detector : object with ``predict(obs)``
    config : TrialConfig
    params : ExecutionParams or None
    name : str or None
        The detector's name in messages.
    where : str
        What the scene is (the trial, round or attempt), the prefix of a protocol error.
    known : dict or None
        The scene's entry in a :class:`graspsim.labels.store.SceneLabels` store, taken instead
        of executing the candidates when they are the ones it was made from.

    Returns
    -------
    positives : list of GraspRectangle or None
    n_labelled : int
    proposal : tuple
        What :func:`propose` returns.
    entry : dict or None
        The labels executed here, for a store.

    Raises
    ------
    ValueError
        When the detector's return value breaks the protocol (prefixed with ``where``).
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


def upgrade_campaign_config(old: dict, meta: dict, path) -> dict:
    """What an existing trial or round folder's ``config.json`` would record today.

    The ``upgrade`` of :func:`graspsim.runtime.campaign.open_campaign`: a folder written before
    the object set, a :class:`TrialConfig` field or the execution parameters were recorded ran
    with the built-in set named by its text, the field's default and the default parameters.

    Parameters
    ----------
    old : dict
        The folder's configuration.
    meta : dict
        The configuration of the run that reopens it.
    path : Path
        The ``config.json`` file, for messages.

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        When the folder holds another object set (naming the folder).
    """
    old = dict(old)
    if "object_set" in meta:
        check_same_object_set(old.get("object_set"), meta["object_set"], Path(path).parent)
        old.setdefault("object_set", meta["object_set"])
    if isinstance(old.get("config"), dict):
        old["config"] = {**asdict(TrialConfig()), **old["config"]}
    if "execution" in meta:
        old["execution"] = asdict(execution_params_from_dict(old.get("execution", {}),
                                                             str(path)))
    return old


def _trial_task(specs, detector, seed, index, config, params, known=None, share=False):
    try:
        return made_again_if_unmade(lambda: run_trial(
            worker_sim(), specs, detector, seed, index, config, params, known=known,
            share=share))
    except SceneError as exc:
        return skipped_record(index, exc, seed=seed)


def campaign_setup(detector, detector_name, objects, n: int, seed: int, config, params,
                   options=None):
    """The detector, the object specs and the configuration a campaign folder records.

    For :func:`run_trials` and :func:`graspsim.eval.declutter.run_rounds`.

    Parameters
    ----------
    detector : str or object
        As :func:`run_trials`.
    detector_name : str or None
    objects : str, ObjectSet or list of ObjectSpec
    n : int
    seed : int
    config : TrialConfig
    params : ExecutionParams or None
    options : dict or None
        The detector's options.

    Returns
    -------
    detector : object with ``predict(obs)``
    specs : list of ObjectSpec
    meta : dict
        What ``config.json`` records (the execution parameters, and the detector's options
        when it has any).
    """
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
        A :func:`run_trials` or :func:`graspsim.eval.declutter.run_rounds` output folder.

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
                             if isinstance(detector, str | Path) else describe_detector(detector))
    det = load_detector(detector, options) if isinstance(detector, str | Path) else detector
    return det, name


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
        An object set (:func:`graspsim.labels.graspability.resolve_objects`: a built-in
        split or names,
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
    executor : graspsim.runtime.executor.Executor or None
        Where trials run (local cores or a Ray cluster; ``n_jobs`` is then ignored).
    detector_name : str or None
        Name recorded for a detector object (default: its plug-in name with its options, or
        its class name).
    labels : str or Path or None
        A folder of the scenes' physics labels shared with other detectors' trials on the
        same scenes (:class:`graspsim.labels.store.SceneLabels`, made when missing): scenes
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
        The summary (see :func:`graspsim.eval.summary.summarize`), with ``records`` sorted by index.
    """
    det, specs, meta = campaign_setup(detector, detector_name, objects, n, seed, config,
                                      params, detector_options)
    store, known, on_record = None, {}, None
    if labels is not None and config.n_candidates > 0:
        store = SceneLabels.open(labels, {k: v for k, v in meta.items()
                                          if k not in ("detector", "detector_options")})
        known = store.read()

        def on_record(rec):
            entry = rec.pop("_labels", None)
            if entry is not None:
                store.add(entry)

    def task_args(i):
        extra = (known.get(i), True) if store is not None else ()
        return (specs, det, seed, i, config, params, *extra)

    return run_campaign(_trial_task, "trials", meta, out, n, task_args, summarize,
                        summary_markdown, executor=executor, n_jobs=n_jobs, progress=progress,
                        on_record=on_record, upgrade=upgrade_campaign_config)

