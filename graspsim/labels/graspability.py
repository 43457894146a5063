"""Graspable, measured by physics the same way for every object set.

An object is **graspable** when the dense physics labeller finds at least one successful grasp
of it in at least one of ``K`` settled poses (:data:`DEFAULT_POSES`): the object is dropped
alone on the table (half of the time upright with a random yaw, otherwise in a uniformly random
orientation, as :func:`graspsim.sim.scene.make_scene` drops every trial's object) and left to
settle, the scene is rendered, and the dense candidates of
:func:`graspsim.labels.labelling.dense_candidates` (a lattice over the mask, every 15 degrees,
within
the hand's reach; at most :data:`BUDGET`, in random order) are executed by
:func:`graspsim.labels.labelling.label_rectangles` until one succeeds. The box rule it replaces
(an extent of the bounding box against the 8 cm opening) calls a blob wider than 8 cm in its
box not graspable even when its parts are narrow.

Each object's outcome (the first pose with a success, or None, and how many poses were tried)
is cached in a small JSON manifest per gripper (the gripper's and the harness's parameters as
a dict, hashed), keyed by the object's fingerprint (its files' bytes, its scale, mass and
friction). Lookups read the committed manifest ``objects/graspability.json`` (the built-in set
and those measured for the project's experiments), those of :data:`SET_MANIFESTS` (the YCB
set's, ``objects/ycb/graspability.json``) and then the user's, in
``$GRASPSIM_CACHE_DIR`` or ``$XDG_CACHE_HOME/graspsim`` (default ``~/.cache/graspsim``);
:func:`measure_graspability` writes the user's.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from dlsr.records import read_json, write_json_atomic

from ..runtime.executor import Executor
from ..sim.bullet import Simulation
from ..sim.execution import ExecutionParams
from ..sim.gripper import GripperParams
from ..sim.object_sets import as_object_set, files_fingerprint
from ..sim.objects import ObjectSpec, assets_dir, cache_dir
from ..sim.scene import build_scene, capture, make_scene
from .labelling import dense_candidates, label_rectangles

__all__ = [
    "resolve_objects",
    "DEFAULT_POSES",
    "SET_MANIFESTS",
    "BUDGET",
    "gripper_key",
    "object_key",
    "pose_outcome",
    "object_outcome",
    "measure_graspability",
    "graspability_flags",
    "apply_graspability",
    "object_table",
    "object_table_text",
]

log = logging.getLogger(__name__)

#: Settled poses K an object is tried in (chosen on the train objects: see
#: docs/experiments/2026-12-03-object-sets.md).
DEFAULT_POSES = 16
#: Dense candidates executed per pose at most (192-256 cover 99.5 % of the successful grasps
#: found independently, docs/guides/physics-labels.md).
BUDGET = 256
#: Candidates executed per call of the labeller (the search stops at the first success).
CHUNK = 32
#: The seed of every object's poses.
SEED = 0

_MANIFEST = "graspability.json"
#: Committed manifests read after ``objects/graspability.json``, one per object set kept apart
#: (paths in the package ``graspsim.assets``).
SET_MANIFESTS = ("ycb/graspability.json",)


def gripper_key(params: ExecutionParams | None = None, gripper: dict | None = None) -> dict:
    """The gripper and harness parameters a graspability flag depends on, as a dict.

    Parameters
    ----------
    params : ExecutionParams or None
        The harness's (default: its defaults).
    gripper : dict or None
        Another gripper's geometry and forces (default: the largest opening of ``params``'s
        hand, 8 cm for the built-in and Franka hands, and the default
        :class:`graspsim.sim.gripper.GripperParams`; the hand and its force are in ``execution``).
    """
    hand = (ExecutionParams() if params is None else params).gripper.geometry
    g = ({"name": "parallel_jaw", "max_opening": hand.max_opening, **asdict(GripperParams())}
         if gripper is None else dict(gripper))
    return {"gripper": g, "execution": asdict(ExecutionParams() if params is None else params),
            "budget": BUDGET, "seed": SEED}


def _hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


def object_key(spec: ObjectSpec) -> str:
    """sha256 (hex) of an object's files, scale, mass and friction: its entry in a manifest."""
    files = files_fingerprint((str(spec.urdf),), (spec.name,))
    return _hash({"files": files, "scale": spec.scale, "mass": spec.mass,
                  "friction": spec.friction})


def _manifest_paths(key: dict) -> list[Path]:
    tag = _hash(key)[:16]
    return [assets_dir() / _MANIFEST, *(assets_dir() / m for m in SET_MANIFESTS),
            cache_dir() / f"graspability-{tag}.json"]


def _read_entries(key: dict) -> dict:
    """Every cached outcome for ``key``: the committed manifest's, then the user's."""
    entries: dict = {}
    for path in _manifest_paths(key):
        if not path.is_file():
            continue
        data = read_json(path, "graspability manifest")
        for block in data.get("grippers", []):
            if block.get("key") == key:
                entries.update(block.get("objects", {}))
    return entries


def _write_entries(path: Path, key: dict, new: dict) -> None:
    data = read_json(path, "graspability manifest") if path.is_file() else {"grippers": []}
    for block in data["grippers"]:
        if block.get("key") == key:
            block["objects"].update(new)
            break
    else:
        data["grippers"].append({"key": key, "objects": dict(new)})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, data, indent=1)


def pose_outcome(sim, spec: ObjectSpec, pose: int, params: ExecutionParams | None = None,
                 budget: int = BUDGET) -> dict:
    """Drop ``spec`` alone in settled pose number ``pose`` and search it for a successful grasp.

    Returns
    -------
    dict
        ``success`` (bool), ``executed`` (candidates executed), ``candidates`` (the lattice's
        size before the budget).
    """
    ss = np.random.SeedSequence(SEED, spawn_key=(int(object_key(spec)[:8], 16), int(pose)))
    scene_ss, cam_ss, cand_ss = ss.spawn(3)
    scene = make_scene(sim, [spec], np.random.default_rng(scene_ss), n_objects=1)
    bodies = build_scene(sim, scene)
    frame = capture(sim, scene, bodies, np.random.default_rng(cam_ss))
    rng = np.random.default_rng(cand_ss)
    hand = (ExecutionParams() if params is None else params).gripper.geometry
    cands = dense_candidates(frame.segmentation, bodies.objects, rng, frame.depth_clean,
                             frame.intrinsics, max_opening=hand.max_opening)
    order = rng.permutation(len(cands))[:budget]
    executed = 0
    for start in range(0, len(order), CHUNK):
        chunk = [cands[i] for i in order[start:start + CHUNK]]
        labelled = label_rectangles(sim, scene, frame, chunk, params, depth=frame.depth_clean,
                                    depth_valid=frame.depth_clean > 0)
        executed += len(chunk)
        if labelled.success.any():
            return {"success": True, "executed": executed, "candidates": len(cands)}
    return {"success": False, "executed": executed, "candidates": len(cands)}


def object_outcome(spec: ObjectSpec, n_poses: int, params: ExecutionParams | None = None,
                   start: int = 0, sim=None) -> dict:
    """Poses ``start .. n_poses - 1`` of ``spec`` until one has a successful grasp.

    Returns
    -------
    dict
        ``name``, ``first_success`` (the first pose index with a success, or None) and
        ``poses_tried`` (``n_poses`` when none succeeded).
    """
    own = sim is None
    sim = Simulation() if own else sim
    try:
        for k in range(start, n_poses):
            try:
                r = pose_outcome(sim, spec, k, params)
            except ValueError as exc:  # the object never settles on the table
                log.warning("graspability of %s, pose %d: %s", spec.name, k, exc)
                continue
            if r["success"]:
                return {"name": spec.name, "first_success": k, "poses_tried": k + 1}
        return {"name": spec.name, "first_success": None, "poses_tried": n_poses}
    finally:
        if own:
            sim.close()


def _task(spec, n_poses, params, start):
    return object_outcome(spec, n_poses, params, start)


def _known(entry: dict | None, n_poses: int) -> bool:
    """Whether a cached entry decides the flag at ``n_poses`` poses."""
    if entry is None:
        return False
    first = entry.get("first_success")
    return (first is not None and first < n_poses) or entry.get("poses_tried", 0) >= n_poses


def measure_graspability(objects, n_poses: int = DEFAULT_POSES,
                         params: ExecutionParams | None = None, executor=None,
                         cache: Path | None = None) -> dict:
    """Measure (or read from the caches) every object's outcome over ``n_poses`` poses.

    Parameters
    ----------
    objects : str, ObjectSet or list of ObjectSpec
    n_poses : int
        K.
    params : ExecutionParams or None
    executor : graspsim.runtime.executor.Executor or None
        Where objects run (default: in this process).
    cache : Path or None
        The manifest written (default: the user's, see :func:`graspsim.sim.objects.cache_dir`).

    Returns
    -------
    dict
        ``name -> {"first_success", "poses_tried"}`` for every object.
    """
    if isinstance(n_poses, bool) or not isinstance(n_poses, int) or n_poses < 1:
        raise ValueError(f"n_poses must be an integer >= 1, got {n_poses!r}")
    specs = _specs(objects)
    key = gripper_key(params)
    entries = _read_entries(key)
    keys = [object_key(s) for s in specs]
    todo = [(s, k) for s, k in zip(specs, keys, strict=True)
            if not _known(entries.get(k), n_poses)]
    if todo:
        path = cache if cache is not None else _manifest_paths(key)[-1]
        ex = executor or Executor(backend="sequential")
        tasks = [(s, n_poses, params, entries.get(k, {}).get("poses_tried", 0))
                 for s, k in todo]
        for (_s, k), out in zip(todo, ex.imap(_task, tasks, desc="objects", star=True),
                               strict=True):
            entries[k] = out
            _write_entries(path, key, {k: out})
    return {s.name: {k_: entries[k][k_] for k_ in ("first_success", "poses_tried")}
            for s, k in zip(specs, keys, strict=True)}


def graspability_flags(objects, n_poses: int = DEFAULT_POSES,
                       params: ExecutionParams | None = None, compute: bool = False,
                       executor=None, partial: bool = False) -> dict | None:
    """``name -> graspable`` by physics over ``n_poses`` poses.

    Returns None when some object is not cached and ``compute`` is False, unless
    ``partial``: then the objects that are cached only.
    """
    if compute:
        out = measure_graspability(objects, n_poses, params, executor)
    else:
        specs = _specs(objects)
        entries = _read_entries(gripper_key(params))
        got = [entries.get(object_key(s)) for s in specs]
        if not partial and not all(_known(e, n_poses) for e in got):
            return None
        out = {s.name: e for s, e in zip(specs, got, strict=True) if _known(e, n_poses)}
    return {name: e["first_success"] is not None and e["first_success"] < n_poses
            for name, e in out.items()}


def apply_graspability(specs: list[ObjectSpec], n_poses: int = DEFAULT_POSES,
                       params: ExecutionParams | None = None) -> list[ObjectSpec]:
    """``specs`` with ``graspable`` set by physics where a manifest has the object (the others
    keep their box-rule flag; a debug line says how many)."""
    entries = _read_entries(gripper_key(params))
    out, missing = [], 0
    for s in specs:
        e = entries.get(object_key(s))
        if _known(e, n_poses):
            s = replace(s, graspable=e["first_success"] is not None
                        and e["first_success"] < n_poses)
        else:
            missing += 1
        out.append(s)
    if missing:
        log.debug("%d of %d objects have no physics graspability flag cached: box rule",
                  missing, len(specs))
    return out


def _specs(objects) -> list[ObjectSpec]:
    oset = as_object_set(objects)
    return oset.specs() if oset is not None else list(objects)


def object_table(objects, n_poses: int = DEFAULT_POSES, measure: bool = False,
                 executor=None, params: ExecutionParams | None = None) -> list[dict]:
    """One row per object: ``name``, ``size`` (m, x y z), ``split``, ``graspable`` and
    ``graspable_by`` (``"physics"``, or ``"box rule"`` when no manifest has the object and
    ``measure`` is False), ``first_success`` (the first pose with a success) and
    ``poses_tried``."""
    if isinstance(n_poses, bool) or not isinstance(n_poses, int) or n_poses < 1:
        raise ValueError(f"n_poses must be an integer >= 1, got {n_poses!r}")
    specs = _specs(objects)
    if measure:
        measure_graspability(specs, n_poses, params, executor)
    entries = _read_entries(gripper_key(params))
    rows = []
    for s in specs:
        e = entries.get(object_key(s))
        known = _known(e, n_poses)
        rows.append({
            "name": s.name, "size": [round(float(x), 4) for x in s.size], "split": s.split,
            "graspable": (e["first_success"] is not None and e["first_success"] < n_poses)
            if known else bool(s.graspable),
            "graspable_by": "physics" if known else "box rule",
            "first_success": e.get("first_success") if known else None,
            "poses_tried": e.get("poses_tried") if known else None,
        })
    return rows


def object_table_text(rows: list[dict]) -> str:
    """The rows of :func:`object_table` as an aligned text table with a count line."""
    head = ("name", "size (cm)", "graspable", "split")
    body = [(r["name"], " x ".join(f"{100 * x:.1f}" for x in r["size"]),
             ("yes" if r["graspable"] else "no")
             + ("" if r["graspable_by"] == "physics" else " (box rule)"), r["split"])
            for r in rows]
    widths = [max(len(str(c)) for c in col) for col in zip(head, *body, strict=True)]
    lines = ["  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
             for row in (head, *body)]
    n = sum(r["graspable"] for r in rows)
    by = sum(r["graspable_by"] == "physics" for r in rows)
    lines.append(f"{n} of {len(rows)} graspable ({by} flags by physics)")
    return "\n".join(lines)


def resolve_objects(objects, params: ExecutionParams | None = None) -> list[ObjectSpec]:
    """The objects of a run, with their graspable flags for the run's hand.

    Parameters
    ----------
    objects : str, ObjectSet or list of ObjectSpec
        An object-set text (:func:`graspsim.sim.object_sets.parse_object_set`: ``"train"``,
        ``"test"``, ``"all"`` (the built-in set's split), comma-separated names of built-in
        objects (``"bottle_water,can_soda"``; kept in the built-in set's order, so the scenes of
        a seed depend on the names chosen, not on how they are listed),
        ``"random_urdfs[:train|test|all]"``, ``"folder:PATH[:train|test|all]"``), an
        :class:`~graspsim.sim.object_sets.ObjectSet`, or ObjectSpecs.
    params : ExecutionParams or None
        The harness and hand the run executes with (default: the built-in hand): the
        ``graspable`` flags are those measured by physics with this hand
        (:func:`graspsim.labels.graspability.apply_graspability`), where a manifest has them.

    Raises
    ------
    ValueError
        Naming an object the built-in set does not have (the message lists them), a bad set
        (see :meth:`graspsim.sim.object_sets.ObjectSet.specs`), or no object.
    """
    oset = as_object_set(objects)
    specs = oset.specs() if oset is not None else list(objects)
    if not specs:
        raise ValueError(f"no objects in {objects!r}")
    # The graspable flag by physics where a manifest has it (graspsim.labels.graspability).
    return apply_graspability(specs, params=params)
