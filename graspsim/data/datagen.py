"""Simulated data: a physics-labelled Cornell-layout dataset and unlabelled patch files.

* :func:`make_dataset` (``graspsim dataset``): random single-object scenes, rendered with the
  Kinect-like camera, candidates proposed on the object mask and labelled by executing them
  (:func:`graspsim.labels.labelling.label_rectangles`); written through
  :func:`dlsr.datasets.write_cornell_image` with the object names as object ids, so every dlsr
  benchmark reads it with :func:`dlsr.datasets.load_cornell` unchanged.
* :func:`make_patches` (``graspsim patches``): random scenes and random rectangles on them,
  turned into 24x24 8-channel rectangle images (:func:`dlsr.preprocess.rectangle_images`, layout
  ``[K, R, G, B, D, Nx, Ny, Nz]``), from which random 6x6x8 patches with their masks are drawn
  (:func:`dlsr.patches.sample_patches`) and saved with :func:`dlsr.patches.save_patch_file`.

Scene ``i`` of a run with seed ``s`` draws from ``SeedSequence(s, spawn_key=(i,))``
(:func:`graspsim.sim.observe.trial_streams`), so results do not depend on ``n_jobs`` or the backend.

Dataset folder
--------------
Besides the Cornell files (``NN/pcdXXXXr.png``, ``NN/pcdXXXXd.tiff`` -- float32 metres, 0 where
the simulated sensor gave no depth --, ``NN/pcdXXXXcpos.txt``, ``NN/pcdXXXXcneg.txt``,
``image_objects.txt``) :func:`make_dataset` writes:

* ``NN/pcdXXXXcamera.json``, one per image, for detectors that need the camera:
  ``{"image", "width", "height", "K", "T_world_cam", "depth_unit", "frame"}`` with ``K`` the
  3x3 intrinsic matrix (pixels; pixel centres at integer coordinates) and ``T_world_cam`` the
  4x4 pose of the camera in the world (metres), camera frame OpenCV (x right, y down, z along
  the optical axis); the world's z axis points up from the table top at ``z = table_z``.
* ``scenes.json``, the manifest :mod:`graspsim.eval.scoring` rebuilds scenes from (its sha256 is the
  dataset's fingerprint): ``format`` (``"graspsim-dataset/1"``), ``generator`` (seed, objects,
  candidates and objects per scene, how scene streams are derived), ``execution``
  (:class:`graspsim.sim.execution.ExecutionParams` as a dict), ``grasp_depth`` (``"observed"``:
  rectangles become poses with the image's own depth, the ``d.tiff``), ``rectangle_grid`` (see
  :func:`snap_rectangles`), ``object_specs`` (name -> what :func:`graspsim.sim.objects.load_object`
  needs: URDF path relative to the built-in assets when it is one of them, mass, friction,
  scale, ...), and ``images``: one entry per image with ``image`` (the id
  :func:`dlsr.datasets.load_cornell` gives, ``"0000"``), ``index`` and ``seed`` (scene ``index``
  of the generator ``seed``), ``files`` (paths relative to the root), ``depth_sha256``,
  ``objects`` (name, settled base-link ``position`` in metres and ``orientation`` quaternion
  ``x, y, z, w``, exactly as simulated), ``table`` (``z``, ``rgba``), ``camera`` (as in the
  per-image file plus ``near``/``far``), ``redraws``, label counts and outcomes.
  A scene that cannot be made (:class:`graspsim.sim.observe.SceneError`, even in a new
  simulation) has no image; it is a logged skip, listed with its reason in ``unmade_scenes``
  (a key present only then).
* ``scenes.jsonl`` (the same image entries, one line per finished scene, for resuming; a scene
  that could not be made is a ``skipped`` record, not made again on a resume),
  ``dataset_config.json`` (the configuration, checked on resume) and ``labels.json`` (counts).

Rebuilding a scene from its recorded poses (:func:`graspsim.sim.scene.build_scene`) gives the state
the labelling executed every candidate in, bit for bit; the poses are also exactly those the
seeded construction gives again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from dlsr.datasets import GraspSample, write_cornell_image, write_cornell_mapping
from dlsr.patches import sample_patches, save_patch_file
from dlsr.preprocess import rectangle_images
from dlsr.records import read_json, write_json_atomic
from dlsr.rectangles import GraspRectangle, normalize_angle

from ..labels.graspability import resolve_objects
from ..labels.labelling import check_sampler, label_rectangles, sample_candidates
from ..runtime.campaign import make_executor, read_done, skipped_record
from ..sim.bullet import worker_sim
from ..sim.execution import ExecutionParams
from ..sim.layouts import check_scene
from ..sim.object_sets import check_same_object_set, object_set_meta
from ..sim.objects import assets_dir
from ..sim.observe import SceneError, made_again_if_unmade, observe_scene
from ..sim.profiles import get_profile

__all__ = [
    "MANIFEST",
    "MANIFEST_FORMAT",
    "RECTANGLE_GRID",
    "make_dataset",
    "make_patches",
    "scene_sample",
    "snap_rectangles",
]

log = logging.getLogger(__name__)

MANIFEST = "scenes.json"
"""File name of a dataset's manifest (see the module docstring)."""

MANIFEST_FORMAT = "graspsim-dataset/1"

RECTANGLE_GRID = {"x_y_w_h_decimals": 6, "theta_decimals": 9}
"""Resolution rectangles are executed at: pixels to 6 decimals, radians to 9 (see
:func:`snap_rectangles`)."""

# The grid point closest to pi/2 inside [-pi/2, pi/2) (1.570796326 with 9 decimals).
_DEC = RECTANGLE_GRID["theta_decimals"]
_THETA_EDGE = float(round(np.floor(np.pi / 2 * 10.0**_DEC) / 10.0**_DEC, _DEC))

def snap_rectangles(rects) -> list[GraspRectangle]:
    """Rectangles on the execution grid: ``x, y, w, h`` to 1e-6 px, ``theta`` to 1e-9 rad.

    Labelling and scoring both execute snapped rectangles, so a labelled rectangle written to
    a file with at least 8 significant decimals (the Cornell corner files have 10) and read
    back -- a change of about 1e-10 -- snaps to the very same values and executes exactly as
    it was labelled; physics is not smooth in the last bits of a pose. The change, at most
    5e-7 px and 5e-10 rad (about 1.6e-9 rad at the wrap-around of ``theta``, folded onto the
    grid point inside ``[-pi/2, pi/2)``), has no physical meaning.

    Parameters
    ----------
    rects : sequence of GraspRectangle

    Returns
    -------
    list of GraspRectangle
    """
    px, rad = RECTANGLE_GRID["x_y_w_h_decimals"], RECTANGLE_GRID["theta_decimals"]
    out = []
    for r in rects:
        t = round(float(normalize_angle(r.theta)), rad)
        if abs(t) > _THETA_EDGE:
            t = -_THETA_EDGE
        # Sizes below the grid stay positive (the smallest grid step).
        w, h = (max(round(float(v), px), 10.0**-px) for v in (r.w, r.h))
        out.append(GraspRectangle(round(float(r.x), px), round(float(r.y), px), t, w, h))
    return out


def _spec_record(spec) -> dict:
    """What :func:`graspsim.sim.objects.load_object` needs to load ``spec`` again, as JSON."""
    urdf = Path(spec.urdf)
    try:
        rel = urdf.resolve().relative_to(assets_dir().resolve())
        urdf_rec = {"builtin": rel.as_posix()}
    except ValueError:
        urdf_rec = {"path": str(urdf.resolve())}
    d = asdict(spec)
    d["urdf"] = urdf_rec
    d["size"] = list(spec.size)
    d["tags"] = list(spec.tags)
    d["rgba"] = None if spec.rgba is None else list(spec.rgba)
    return d


def _camera_record(frame) -> dict:
    intr = frame.intrinsics
    return {"width": int(intr.width), "height": int(intr.height),
            "K": np.asarray(intr.K, dtype=float).tolist(),
            "T_world_cam": np.asarray(frame.T_world_cam, dtype=float).tolist(),
            "near": float(intr.near), "far": float(intr.far),
            "depth_unit": "m", "frame": "OpenCV (x right, y down, z forward); T_world_cam "
            "maps camera coordinates to world coordinates (metres, z up)"}


def scene_sample(specs, seed: int, index: int, n_candidates: int = 48, n_objects: int = 1,
                 sampler: str = "mixed", profile=None, scene: str = "drop", params=None):
    """One labelled scene (``sampler``: the candidates' mode, see
    :func:`graspsim.labels.labelling.sample_candidates`; ``profile``: how the scene is seen, see
    :mod:`graspsim.sim.profiles`; ``scene``: how the objects are put on the table, see
    :mod:`graspsim.sim.layouts`; ``params``: the :class:`graspsim.sim.execution.ExecutionParams`,
    hand included, the candidates are executed with, None for the defaults).

    Returns
    -------
    sample : dlsr.datasets.GraspSample
    reasons : dict
        Outcome counts (``"success"`` or the failure reason).
    entry : dict
        The scene's manifest entry without ``files`` and ``depth_sha256`` (objects and their
        exact poses, table, camera); see the module docstring.
    """
    params = ExecutionParams() if params is None else params
    sim = worker_sim()
    placed, bodies, frame, st = observe_scene(sim, specs, seed, index, n_objects, profile,
                                              scene)
    cands = sample_candidates(frame.segmentation, bodies.objects, st["label"], n_candidates,
                              depth=frame.depth_clean, mode=sampler,
                              intrinsics=frame.intrinsics,
                              max_opening=params.gripper.geometry.max_opening)
    labelled = label_rectangles(sim, placed, frame, snap_rectangles(cands), params)
    mask = np.isin(frame.segmentation, bodies.objects)
    sample = GraspSample(
        image_id=f"{index:04d}",
        object_id="+".join(o.spec.name for o in placed.objects),
        rgb=frame.rgb,
        depth=np.where(frame.depth_valid, frame.depth, 0).astype(np.float32),
        depth_valid=frame.depth_valid.astype(bool),
        positives=labelled.positives,
        negatives=labelled.negatives,
        mask=mask,
    )
    reasons = {}
    for r in labelled.results:
        reasons[r.reason or "success"] = reasons.get(r.reason or "success", 0) + 1
    entry = {
        "image": sample.image_id, "index": int(index), "seed": int(seed),
        "objects": [{"name": o.spec.name, "position": [float(v) for v in o.position],
                     "orientation": [float(v) for v in o.orientation]} for o in placed.objects],
        "table": {"z": float(placed.table_z), "rgba": [float(v) for v in placed.table_rgba]},
        "camera": _camera_record(frame),
        "redraws": list(placed.redraws),
    }
    return sample, reasons, entry


def _scene_task(specs, seed, index, n_candidates, n_objects, sampler, profile, scene, params):
    """:func:`scene_sample`, or ``(None, None, skipped record)`` for a scene that cannot be made
    even in a new simulation (:func:`graspsim.sim.observe.made_again_if_unmade`)."""
    try:
        return made_again_if_unmade(lambda: scene_sample(
            specs, seed, index, n_candidates, n_objects, sampler, profile, scene, params))
    except SceneError as exc:
        return None, None, skipped_record(index, exc, seed=seed)


def _sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def make_dataset(n_scenes: int = 20, objects="train", out="sim_cornell", seed: int = 0,
                 n_candidates: int = 48, n_objects: int = 1, n_jobs: int = 1,
                 progress: bool = False, executor=None, sampler: str = "mixed",
                 profile=None, scene: str = "drop", params=None) -> dict:
    """Write a synthetic, physics-labelled Cornell dataset; resumes an interrupted run.

    Each scene is written as soon as it is labelled and recorded in ``scenes.jsonl``; a rerun
    with the same arguments skips the recorded scenes (a different configuration in the same
    folder is an error). At the end the manifest ``scenes.json`` lists every image with what
    an exact rebuild of its scene needs (see the module docstring).

    Parameters
    ----------
    n_scenes : int
        Images (one scene each), numbered ``0000`` ... in the Cornell layout.
    objects : str, ObjectSet or list of ObjectSpec
        An object set (:func:`graspsim.labels.graspability.resolve_objects`: a built-in split or
        names,
        ``random_urdfs[:split]``, ``folder:PATH[:split]``).
    out : str or Path
        Root folder (``00/pcd0000r.png``, ``pcd0000d.tiff``, ``pcd0000cpos.txt``,
        ``pcd0000cneg.txt``, ``pcd0000camera.json``, ..., ``image_objects.txt``) plus
        ``scenes.json`` (the manifest), ``labels.json`` (counts) and ``scenes.jsonl`` (one line
        per finished scene).
    seed : int
    n_candidates : int
        Rectangles labelled per scene (snapped with :func:`snap_rectangles`).
    n_objects : int
    n_jobs : int
        Local worker processes (ignored when ``executor`` is given).
    executor : graspsim.runtime.executor.Executor or None
        Where scenes run (local cores or a Ray cluster); results do not depend on it.
    sampler : {"mixed", "dense"}
        How the labelled candidates are drawn (:func:`graspsim.labels.labelling.sample_candidates`):
        ``"mixed"`` (centroid, chord and random candidates) or ``"dense"`` (a Jacquard-like
        lattice over the objects, every 15 degrees; ``n_candidates`` is its budget: 192-256
        cover 99.5 % of independently found successful grasps, see the README).
    profile : str, graspsim.sim.profiles.SimProfile or None
        How scenes are seen (camera height and intrinsics, table colour, lighting, depth
        noise; :mod:`graspsim.sim.profiles`); None or ``"default"``: the simulator's default. The
        objects and their poses do not depend on it. Any other than the default is recorded
        with its settings in ``dataset_config.json`` and ``scenes.json``
        (``generator.profile``).
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects are put on the table (:mod:`graspsim.sim.layouts`); ``"drop"``, the default,
        drops them one by one at random poses. Packed and pile scenes need ``n_objects`` > 1
        (VGN and GIGA use 5). Any other than the default is recorded
        (``generator.scene``).
    params : graspsim.sim.execution.ExecutionParams or None
        The harness and hand the candidates are executed with (None: the defaults, the
        built-in hand; ``ExecutionParams.with_hand("franka")`` for the Franka
        hand). Recorded in ``scenes.json`` (``execution``), so :mod:`graspsim.eval.scoring` executes
        predictions with the same hand; any other than the defaults also in
        ``dataset_config.json``.

    Returns
    -------
    dict
        Counts: images, positives, negatives, failure reasons, ``unmade_scenes`` (index and
        reason of each scene that could not be made), seconds, labelled rectangles/s,
        and ``manifest`` (the path of ``scenes.json``) with its ``fingerprint`` (sha256).
    """
    if n_scenes < 1:
        raise ValueError(f"n_scenes must be >= 1, got {n_scenes}")

    check_sampler(sampler)
    check_scene(scene, n_objects)
    if params is not None and not isinstance(params, ExecutionParams):
        raise TypeError(f"params must be an ExecutionParams or None, got "
                        f"{type(params).__name__}")
    params = ExecutionParams() if params is None else params
    prof = get_profile(profile)
    specs = resolve_objects(objects, params)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    meta = {"format": MANIFEST_FORMAT, **object_set_meta(objects, specs),
            "seed": seed, "n_candidates": n_candidates, "n_objects": n_objects}
    if sampler != "mixed":  # datasets of the default sampler keep their recorded configuration
        meta["sampler"] = sampler
    if prof != get_profile(None):  # likewise datasets of the default profile
        meta["profile"] = prof.to_dict()
    if scene != "drop":  # ... and of the default scene and hand
        meta["scene"] = scene
    if params != ExecutionParams():
        meta["execution"] = asdict(params)
    _open_dataset(root, meta)
    log_path = root / "scenes.jsonl"
    done = read_done(log_path)  # a line cut by a kill is dropped: that scene is redone
    todo = [i for i in range(n_scenes) if i not in done]
    if done:
        log.info("resuming dataset: %d of %d scenes already written", n_scenes - len(todo),
                 n_scenes)
    t0 = time.perf_counter()
    ex = make_executor(executor, n_jobs, progress)
    tasks = [(specs, seed, i, n_candidates, n_objects, sampler, prof, scene, params)
             for i in todo]
    with log_path.open("a") as fh:
        for i, (sample, rs, entry) in zip(
                todo, ex.imap(_scene_task, tasks, desc="scenes", star=True), strict=True):
            rec = entry if sample is None else _write_scene(root, i, sample, rs, entry)
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            done[i] = rec
    finished = [done[i] for i in sorted(done) if i < n_scenes]
    records = [r for r in finished if "skipped" not in r]
    unmade = _unmade(finished)
    write_cornell_mapping(root, [r["mapping"] for r in records if r["mapping"]])
    used = {o["name"] for r in records for o in r["objects"]}
    manifest = {
        "format": MANIFEST_FORMAT,
        "generator": {**{k: meta[k] for k in ("seed", "objects", "object_set", "n_candidates",
                                              "n_objects")},
                      "sampler": sampler,
                      **({"profile": meta["profile"]} if "profile" in meta else {}),
                      **({"scene": scene} if scene != "drop" else {}),
                      # recorded as first written (now graspsim.sim.observe.trial_streams), so
                      # that manifests, and the fingerprints scores record, stay the same
                      "scene_streams": "numpy SeedSequence(seed, spawn_key=(index,)), "
                                       "graspsim.trials.trial_streams"},
        "execution": asdict(params),
        "grasp_depth": "observed",
        "rectangle_grid": dict(RECTANGLE_GRID),
        "object_specs": {s.name: _spec_record(s) for s in specs if s.name in used},
        "images": [{k: v for k, v in r.items() if k != "mapping"} for r in records],
        # only when a scene could not be made, so other datasets' fingerprints stay the same
        **({"unmade_scenes": unmade} if unmade else {}),
    }
    manifest_path = root / MANIFEST
    write_json_atomic(manifest_path, manifest, indent=1)
    reasons: dict[str, int] = {}
    for r in records:
        for k, v in r["outcomes"].items():
            reasons[k] = reasons.get(k, 0) + v
    seconds = time.perf_counter() - t0
    stats = {
        "images": len(records),
        **meta,
        "positives": int(sum(r["positives"] for r in records)),
        "negatives": int(sum(r["negatives"] for r in records)),
        "outcomes": reasons,
        "unmade_scenes": unmade,
        "seconds_this_run": round(seconds, 2),
        "labelled_rectangles_per_second": (round(len(todo) * n_candidates / seconds, 2)
                                           if todo and seconds > 0 else None),
        "manifest": str(manifest_path),
        "fingerprint": _sha256(manifest_path),
    }
    write_json_atomic(root / "labels.json", stats)
    return stats



def _open_dataset(root: Path, meta: dict) -> None:
    """Write ``dataset_config.json``, refusing a folder that holds another dataset."""
    meta_path = root / "dataset_config.json"
    old = read_json(meta_path, "dataset configuration") if meta_path.exists() else None
    if old is not None:
        check_same_object_set(old.get("object_set"), meta["object_set"], root)
        # A dataset written before the object set was recorded holds a built-in set.
        old.setdefault("object_set", meta["object_set"])
    if old is not None and old != json.loads(json.dumps(meta)):
        raise ValueError(f"{root} holds a dataset of another configuration ({meta_path}); "
                         "use a new folder")
    write_json_atomic(meta_path, meta)


def _write_scene(root: Path, i: int, sample, outcomes: dict, entry: dict) -> dict:
    """Write scene ``i``'s Cornell files and camera; its ``scenes.jsonl`` record."""
    line = write_cornell_image(sample, root, i)
    stem = f"{i // 100:02d}/pcd{i:04d}"
    files = {"rgb": f"{stem}r.png", "depth": f"{stem}d.tiff",
             "positives": f"{stem}cpos.txt", "negatives": f"{stem}cneg.txt",
             "camera": f"{stem}camera.json"}
    cam = {"image": entry["image"], **{k: entry["camera"][k] for k in
           ("width", "height", "K", "T_world_cam", "depth_unit", "frame")}}
    write_json_atomic(root / files["camera"], cam, indent=1)
    return {**entry, "files": files, "depth_sha256": _sha256(root / files["depth"]),
            "object_id": sample.object_id, "mapping": line,
            "positives": len(sample.positives), "negatives": len(sample.negatives),
            "outcomes": outcomes}


def _unmade(records) -> list[dict]:
    """Index and reason of each skipped record
    (:func:`graspsim.runtime.campaign.skipped_record`)."""
    return [{"index": r["index"], "reason": r["skipped"]} for r in records if "skipped" in r]


def _no_images():
    return np.zeros((0, 24, 24, 8), np.float32), np.zeros((0, 24, 24, 8), bool)


def _patch_task(specs, seed, index, rects_per_scene, n_objects, scene="drop"):
    """:func:`_patch_scene` and None, or no images and the skipped record of a scene that cannot
    be made."""
    try:
        return (*made_again_if_unmade(lambda: _patch_scene(
            specs, seed, index, rects_per_scene, n_objects, scene)), None)
    except SceneError as exc:
        return (*_no_images(), skipped_record(index, exc, seed=seed))


def _patch_scene(specs, seed, index, rects_per_scene, n_objects, scene="drop"):
    sim = worker_sim()
    _, bodies, frame, st = observe_scene(sim, specs, seed, index, n_objects, None, scene)
    rects = sample_candidates(frame.segmentation, bodies.objects, st["label"], rects_per_scene,
                              depth=frame.depth_clean)
    if not rects:
        return _no_images()
    images, masks = rectangle_images(frame.rgb, frame.depth, frame.depth_valid, rects, size=24)
    return np.asarray(images, np.float32), np.asarray(masks, bool)


def make_patches(n: int = 100_000, out="patches.npz", objects="all", seed: int = 0,
                 n_scenes: int | None = None, rects_per_scene: int = 20, n_objects: int = 1,
                 n_jobs: int = 1, progress: bool = False, executor=None,
                 scene: str = "drop") -> dict:
    """Random 6x6x8 patches (and masks) of rectangle images from random rendered scenes.

    Parameters
    ----------
    n : int
        Patches to write.
    out : str or Path
        ``.npz`` written by :func:`dlsr.patches.save_patch_file` (read it with
        :func:`dlsr.patches.load_patch_file`).
    objects : str, ObjectSet or list of ObjectSpec
        An object set (:func:`graspsim.labels.graspability.resolve_objects`: a built-in split or
        names,
        ``random_urdfs[:split]``, ``folder:PATH[:split]``).
    seed : int
    n_scenes : int or None
        Scenes to render; default ``max(2, ceil(n / 2000))``.
    rects_per_scene : int
        Random rectangles (on the objects) per scene.
    n_objects : int
        Objects per scene.
    n_jobs : int
        Local worker processes (ignored when ``executor`` is given).
    progress : bool
    executor : graspsim.runtime.executor.Executor or None
        Where scenes run (local cores or a Ray cluster); results do not depend on it.
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects are put on the table (:mod:`graspsim.sim.layouts`); packed and pile scenes
        need ``n_objects`` > 1.

    Returns
    -------
    dict
        ``n``, ``scenes``, ``images``, ``path``, ``unmade_scenes`` (index and reason of each
        scene that could not be made, even in a new simulation: a logged skip), ``seconds``.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    check_scene(scene, n_objects)
    specs = resolve_objects(objects)
    n_scenes = max(2, int(np.ceil(n / 2000))) if n_scenes is None else int(n_scenes)
    t0 = time.perf_counter()
    ex = make_executor(executor, n_jobs, progress)
    tasks = [(specs, seed, i, rects_per_scene, n_objects, scene) for i in range(n_scenes)]
    parts = list(ex.imap(_patch_task, tasks, desc="scenes", star=True))
    images = np.concatenate([p[0] for p in parts])
    masks = np.concatenate([p[1] for p in parts])
    unmade = _unmade(p[2] for p in parts if p[2] is not None)
    if len(images) == 0:
        raise ValueError("no rectangle images: no object was visible in any scene"
                         + (f" ({len(unmade)} of {n_scenes} scenes could not be made)"
                            if unmade else ""))
    patch_seed = int(np.random.SeedSequence(seed, spawn_key=(1 << 30,)).generate_state(1)[0])
    X, M = sample_patches(images, masks, n_patches=n, random_state=patch_seed)
    save_patch_file(out, X, M)
    return {"n": int(len(X)), "scenes": n_scenes, "images": int(len(images)), "path": str(out),
            "unmade_scenes": unmade, "seconds": round(time.perf_counter() - t0, 2)}
