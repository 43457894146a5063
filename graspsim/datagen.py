"""Simulated data: a physics-labelled Cornell-layout dataset and unlabelled patch files.

* :func:`make_dataset` (``graspsim dataset``): random single-object scenes, rendered with the
  Kinect-like camera, candidates proposed on the object mask and labelled by executing them
  (:func:`graspsim.labelling.label_rectangles`); written through
  :func:`dlsr.datasets.write_cornell` with the object names as object ids, so every dlsr
  benchmark reads it with :func:`dlsr.datasets.load_cornell` unchanged.
* :func:`make_patches` (``graspsim patches``): random scenes and random rectangles on them,
  turned into 24x24 8-channel rectangle images (:func:`dlsr.preprocess.rectangle_images`, layout
  ``[K, R, G, B, D, Nx, Ny, Nz]``), from which random 6x6x8 patches with their masks are drawn
  (:func:`dlsr.patches.sample_patches`) and saved with :func:`dlsr.patches.save_patch_file`.

Scene ``i`` of a run with seed ``s`` draws from ``SeedSequence(s, spawn_key=(i,))``, so results
do not depend on ``n_jobs``.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from .labelling import label_rectangles, sample_candidates

__all__ = ["make_dataset", "make_patches", "scene_sample"]

log = logging.getLogger(__name__)

_WORKER = {}


def _sim():
    from .sim import Simulation

    pid = os.getpid()
    if pid not in _WORKER:
        _WORKER.clear()
        _WORKER[pid] = Simulation()
    return _WORKER[pid]


def scene_sample(specs, seed: int, index: int, n_candidates: int = 48, n_objects: int = 1):
    """One labelled scene as a :class:`dlsr.datasets.GraspSample` (plus labelling counts)."""
    from dlsr.datasets import GraspSample

    from .trials import observe_scene

    sim = _sim()
    scene, bodies, frame, st = observe_scene(sim, specs, seed, index, n_objects)
    cands = sample_candidates(frame.segmentation, bodies.objects, st["label"], n_candidates,
                              depth=frame.depth_clean)
    labelled = label_rectangles(sim, scene, frame, cands)
    mask = np.isin(frame.segmentation, bodies.objects)
    sample = GraspSample(
        image_id=f"{index:04d}",
        object_id="+".join(o.spec.name for o in scene.objects),
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
    return sample, reasons


def _scene_task(specs, seed, index, n_candidates, n_objects):
    return scene_sample(specs, seed, index, n_candidates, n_objects)


def make_dataset(n_scenes: int = 20, objects="train", out="sim_cornell", seed: int = 0,
                 n_candidates: int = 48, n_objects: int = 1, n_jobs: int = 1,
                 progress: bool = False, executor=None) -> dict:
    """Write a synthetic, physics-labelled Cornell dataset; resumes an interrupted run.

    Each scene is written as soon as it is labelled and recorded in ``scenes.jsonl``; a rerun
    with the same arguments skips the recorded scenes (a different configuration in the same
    folder is an error).

    Parameters
    ----------
    n_scenes : int
        Images (one scene each), numbered ``0000`` ... in the Cornell layout.
    objects : {"train", "test", "all"} or list of ObjectSpec
    out : str or Path
        Root folder (``00/pcd0000r.png``, ``pcd0000d.tiff``, ``pcd0000cpos.txt``,
        ``pcd0000cneg.txt``, ..., ``image_objects.txt``) plus ``labels.json`` (counts) and
        ``scenes.jsonl`` (one line per finished scene).
    seed : int
    n_candidates : int
        Rectangles labelled per scene.
    n_objects : int
    n_jobs : int
        Local worker processes (ignored when ``executor`` is given).
    executor : graspsim.executor.Executor or None
        Where scenes run (local cores or a Ray cluster); results do not depend on it.

    Returns
    -------
    dict
        Counts: images, positives, negatives, failure reasons, seconds, labelled rectangles/s.
    """
    from dlsr.datasets import write_cornell_image, write_cornell_mapping

    from .executor import Executor
    from .trials import read_done, resolve_objects

    if n_scenes < 1:
        raise ValueError(f"n_scenes must be >= 1, got {n_scenes}")
    specs = resolve_objects(objects)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    meta = {"objects": objects if isinstance(objects, str) else [s.name for s in specs],
            "seed": seed, "n_candidates": n_candidates, "n_objects": n_objects}
    meta_path = root / "dataset_config.json"
    if meta_path.exists() and json.loads(meta_path.read_text()) != meta:
        raise ValueError(f"{root} holds a dataset of another configuration ({meta_path}); "
                         "use a new folder")
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    log_path = root / "scenes.jsonl"
    done = read_done(log_path)  # a line cut by a kill is dropped: that scene is redone
    todo = [i for i in range(n_scenes) if i not in done]
    if done:
        log.info("resuming dataset: %d of %d scenes already written", n_scenes - len(todo),
                    n_scenes)
    t0 = time.perf_counter()
    ex = executor or Executor(backend="loky" if n_jobs != 1 else "sequential", n_jobs=n_jobs,
                              progress=progress)
    tasks = [(specs, seed, i, n_candidates, n_objects) for i in todo]
    with log_path.open("a") as fh:
        for i, (sample, rs) in zip(todo, ex.imap(_scene_task, tasks, desc="scenes", star=True),
                                   strict=True):
            line = write_cornell_image(sample, root, i)
            rec = {"index": i, "mapping": line, "positives": len(sample.positives),
                   "negatives": len(sample.negatives), "outcomes": rs}
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            done[i] = rec
    records = [done[i] for i in sorted(done) if i < n_scenes]
    write_cornell_mapping(root, [r["mapping"] for r in records if r["mapping"]])
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
        "seconds_this_run": round(seconds, 2),
        "labelled_rectangles_per_second": (round(len(todo) * n_candidates / seconds, 2)
                                           if todo and seconds > 0 else None),
    }
    (root / "labels.json").write_text(json.dumps(stats, indent=2) + "\n")
    return stats


def _patch_scene(specs, seed, index, rects_per_scene, n_objects):
    from dlsr.preprocess import rectangle_images

    from .trials import observe_scene

    sim = _sim()
    scene, bodies, frame, st = observe_scene(sim, specs, seed, index, n_objects)
    rects = sample_candidates(frame.segmentation, bodies.objects, st["label"], rects_per_scene,
                              depth=frame.depth_clean)
    if not rects:
        return np.zeros((0, 24, 24, 8), np.float32), np.zeros((0, 24, 24, 8), bool)
    images, masks = rectangle_images(frame.rgb, frame.depth, frame.depth_valid, rects, size=24)
    return np.asarray(images, np.float32), np.asarray(masks, bool)


def make_patches(n: int = 100_000, out="patches.npz", objects="all", seed: int = 0,
                 n_scenes: int | None = None, rects_per_scene: int = 20, n_objects: int = 1,
                 n_jobs: int = 1, progress: bool = False) -> dict:
    """Random 6x6x8 patches (and masks) of rectangle images from random rendered scenes.

    Parameters
    ----------
    n : int
        Patches to write.
    out : str or Path
        ``.npz`` written by :func:`dlsr.patches.save_patch_file` (read it with
        :func:`dlsr.patches.load_patch_file`).
    objects : {"train", "test", "all"} or list of ObjectSpec
    seed : int
    n_scenes : int or None
        Scenes to render; default ``max(2, ceil(n / 2000))``.
    rects_per_scene : int
        Random rectangles (on the objects) per scene.

    Returns
    -------
    dict
        ``n``, ``scenes``, ``images``, ``path``, ``seconds``.
    """
    from dlsr.patches import sample_patches, save_patch_file

    from .executor import Executor
    from .trials import resolve_objects

    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    specs = resolve_objects(objects)
    n_scenes = max(2, int(np.ceil(n / 2000))) if n_scenes is None else int(n_scenes)
    t0 = time.perf_counter()
    ex = Executor(backend="loky" if n_jobs != 1 else "sequential", n_jobs=n_jobs,
                  progress=progress)
    tasks = [(specs, seed, i, rects_per_scene, n_objects) for i in range(n_scenes)]
    parts = list(ex.imap(_patch_scene, tasks, desc="scenes", star=True))
    images = np.concatenate([p[0] for p in parts])
    masks = np.concatenate([p[1] for p in parts])
    if len(images) == 0:
        raise ValueError("no rectangle images: no object was visible in any scene")
    patch_seed = int(np.random.SeedSequence(seed, spawn_key=(1 << 30,)).generate_state(1)[0])
    X, M = sample_patches(images, masks, n_patches=n, random_state=patch_seed)
    save_patch_file(out, X, M)
    return {"n": int(len(X)), "scenes": n_scenes, "images": int(len(images)), "path": str(out),
            "seconds": round(time.perf_counter() - t0, 2)}
