"""A Cornell-sized stand-in: a simulated dataset in the Cornell layout with Cornell's proportions.

The Cornell grasping dataset has 885 RGB-D images of 240 distinct objects (Jiang, Moseson and
Saxena, ICRA 2011; the count of objects is Lenz, Lee and Saxena's, IJRR 2015, and the seed
paper's) with 8,019 labelled rectangles, 5,110 positive and 2,909 negative. Its negatives were
drawn by hand on the object, as near misses of the grasps, not anywhere in the image.

:func:`make_cornell_standin` builds the same shape from simulation, for timing the offline
benchmarks at Cornell's size (``scripts/bench_scale.py``) where the real dataset is absent:

1. **Objects**: the 57 built-in objects, then pybullet_data's ``random_urdfs`` *train* objects in
   folder order to make up ``n_objects`` (the ``random_urdfs`` test split is never used).
2. **Labelled scenes**: :func:`graspsim.data.datagen.make_dataset` into ``OUT/labelled`` (one
   object per
   scene, drawn by the scene's own seed stream; ``n_candidates`` rectangles executed by the
   physics each), resumable.
3. **Thinning** (:func:`thin_labels`) into ``OUT/cornell``: the first ``n_images`` scenes with at
   least one positive and one negative are kept (scenes without are replaced by the next ones:
   more scenes are labelled until there are enough); the image quotas of positives and negatives
   are spread over the images as evenly as the labels allow (:func:`spread_quota`), positives
   are drawn at random among the labelled ones, and negatives are the labelled failures nearest
   to a positive's centre (near misses on the object), as Cornell's are.

``OUT/standin.json`` records how it was made (objects, seeds, counts asked for and reached, the
labelled dataset's fingerprint, the BLAS kernels). Rerunning with the same arguments reuses both
folders.

**The same stand-in on another machine.** The labels are physics: objects dropped on a table,
rectangles executed. Their inputs pass through numpy's products, whose last bits follow the kernel
set OpenBLAS chose for the CPU, and a dropped object can settle otherwise when a pose differs in
its 16th digit. Measured on 2026-12-06 (AMD EPYC of family 26, where OpenBLAS 0.3.31 chooses its
Haswell kernels): 81 of the 962 labelled scenes differed from the build with
``OPENBLAS_CORETYPE=SkylakeX`` in the last digits of their recorded poses, 7 of them in their
images and 3 in their labels, so the fingerprints and the thinned subsets differed; with
``OPENBLAS_CORETYPE=SkylakeX`` the same machine rebuilt the stand-in of the earlier sessions (AMD
EPYC, where OpenBLAS chose SkylakeX), fingerprint for fingerprint. ``standin.json`` names the
kernels (``blas``); set ``OPENBLAS_CORETYPE`` to them to make the same stand-in on a CPU that
has their instructions.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from dlsr.datasets import (
    MAPPING_FILENAMES,
    load_cornell,
    write_cornell_image,
    write_cornell_mapping,
)
from dlsr.records import machine_record, read_json, write_json_atomic

from ..runtime.campaign import read_done
from ..sim.objects import builtin_objects, random_urdf_objects
from .datagen import make_dataset

__all__ = [
    "CORNELL",
    "make_cornell_standin",
    "spread_quota",
    "standin_objects",
    "standin_subset",
    "thin_labels",
    "usable_scenes",
]

log = logging.getLogger(__name__)

CORNELL = {"images": 885, "objects": 240, "positives": 5110, "negatives": 2909}
"""The real dataset's counts (images, distinct objects, positive and negative rectangles)."""

STANDIN_FORMAT = "graspsim-cornell-standin/1"


def standin_objects(n_objects: int = CORNELL["objects"]) -> list:
    """The stand-in's objects: every built-in object, then ``random_urdfs`` train objects.

    Parameters
    ----------
    n_objects : int
        How many distinct objects (at least 1; at most 57 + 900).

    Returns
    -------
    list of graspsim.sim.objects.ObjectSpec
    """
    builtin = builtin_objects("all")
    if n_objects < 1:
        raise ValueError(f"n_objects must be >= 1, got {n_objects}")
    if n_objects <= len(builtin):
        return builtin[:n_objects]
    extra = random_urdf_objects("train")
    need = n_objects - len(builtin)
    if need > len(extra):
        raise ValueError(f"n_objects={n_objects}: only {len(builtin) + len(extra)} objects "
                         "(built-in and random_urdfs train) are available")
    return builtin + extra[:need]


def spread_quota(total: int, available, rng: np.random.Generator) -> np.ndarray:
    """Split ``total`` items over images as evenly as their ``available`` counts allow.

    Every image gets ``floor(total / n)`` or one more (the extra ones at random), capped by what
    it has; what the caps leave is handed, one at a time, to the images with the most left.

    Parameters
    ----------
    total : int
    available : array-like of int, shape (n,)
    rng : numpy.random.Generator

    Returns
    -------
    quota : ndarray of int, shape (n,)
        ``quota <= available``; ``quota.sum() == min(total, available.sum())``.
    """
    avail = np.asarray(available, dtype=int)
    if avail.ndim != 1 or avail.size == 0 or np.any(avail < 0):
        raise ValueError("available must be a non-empty 1-D array of counts >= 0")
    if total < 0:
        raise ValueError(f"total must be >= 0, got {total}")
    n = avail.size
    base = np.full(n, total // n)
    base[rng.permutation(n)[: total % n]] += 1
    quota = np.minimum(base, avail)
    short = min(total, int(avail.sum())) - int(quota.sum())
    while short > 0:
        room = avail - quota
        order = np.lexsort((rng.random(n), -room))  # most room first, ties at random
        take = order[: min(short, int(np.count_nonzero(room)))]
        quota[take] += 1
        short -= take.size
    return quota


def thin_labels(positives, negatives, n_pos: int, n_neg: int, rng: np.random.Generator):
    """Keep ``n_pos`` positives at random and the ``n_neg`` negatives nearest a positive.

    Parameters
    ----------
    positives, negatives : list of dlsr.rectangles.GraspRectangle
    n_pos, n_neg : int
        How many to keep (at most what there is).
    rng : numpy.random.Generator

    Returns
    -------
    kept_positives, kept_negatives : list of GraspRectangle
        Positives in their original order; negatives nearest first (distance from the
        negative's centre to the nearest kept positive's centre, pixels; ties by the smaller
        angle difference).
    """
    if n_pos > len(positives) or n_neg > len(negatives) or n_pos < 0 or n_neg < 0:
        raise ValueError(f"cannot keep {n_pos} of {len(positives)} positives and {n_neg} of "
                         f"{len(negatives)} negatives")
    keep = np.sort(rng.choice(len(positives), size=n_pos, replace=False))
    pos = [positives[i] for i in keep]
    if n_neg == 0:
        return pos, []
    ref = pos if pos else list(positives)
    if not ref:
        return pos, list(negatives)[:n_neg]
    pc = np.array([[r.x, r.y] for r in ref], dtype=float)
    pt = np.array([r.theta for r in ref], dtype=float)
    nc = np.array([[r.x, r.y] for r in negatives], dtype=float)
    nt = np.array([r.theta for r in negatives], dtype=float)
    dist = np.linalg.norm(nc[:, None, :] - pc[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    dtheta = np.abs(np.angle(np.exp(2j * (nt - pt[nearest])))) / 2  # in [0, pi/2]
    order = np.lexsort((dtheta, dist.min(axis=1)))
    return pos, [negatives[i] for i in order[:n_neg]]


def _labelled_scenes(root: Path) -> int:
    """How many scenes a (possibly interrupted) labelled dataset holds in a row from 0."""
    path = root / "scenes.jsonl"
    done = read_done(path) if path.exists() else {}
    n = 0
    while n in done:
        n += 1
    return n


def standin_subset(src, dst, n_images: int) -> Path:
    """The first ``n_images`` images of a stand-in's ``cornell/`` folder, as a dataset of its own.

    Files are hard-linked where the file system allows it (copied otherwise); the mapping
    file lists the kept images. Used for the smaller sizes of ``scripts/bench_scale.py``
    (nested subsets, as the first images of Cornell are a subset of it).

    Parameters
    ----------
    src : path
        A Cornell-layout folder written by :func:`make_cornell_standin` (``OUT/cornell``).
    dst : path
        Created (or refreshed) with the subset.
    n_images : int

    Returns
    -------
    Path
        ``dst``.
    """
    src, dst = Path(src), Path(dst)
    mapping = src / MAPPING_FILENAMES[0]
    if not mapping.exists():
        raise FileNotFoundError(f"{src}: no {MAPPING_FILENAMES[0]}; not a stand-in folder")
    lines = [ln for ln in mapping.read_text().splitlines(keepends=True)
             if ln.strip() and not ln.startswith("#")]
    if len(lines) < n_images:
        raise ValueError(f"{src} holds {len(lines)} images, fewer than the {n_images} asked")
    if dst.exists():
        shutil.rmtree(dst)
    for number in range(n_images):
        folder = f"{number // 100:02d}"
        (dst / folder).mkdir(parents=True, exist_ok=True)
        for f in (src / folder).glob(f"pcd{number:04d}*"):
            try:
                (dst / folder / f.name).hardlink_to(f)
            except OSError:
                shutil.copyfile(f, dst / folder / f.name)
    write_cornell_mapping(dst, lines[:n_images])
    return dst


def usable_scenes(samples) -> list:
    """The labelled scenes a stand-in keeps, in order: those with at least one positive and one
    negative rectangle. The stand-in's image ``k`` is the ``k``-th of them (its first
    ``n_images``), so the images of any size are found from a partly labelled folder too.

    Parameters
    ----------
    samples : list of dlsr.datasets.GraspSample
        The labelled dataset (``OUT/labelled``, :func:`dlsr.datasets.load_cornell`), in
        scene order.

    Returns
    -------
    list of dlsr.datasets.GraspSample
    """
    return [s for s in samples if s.positives and s.negatives]


def make_cornell_standin(out, n_images: int = CORNELL["images"],
                         n_objects: int = CORNELL["objects"],
                         positives: int = CORNELL["positives"],
                         negatives: int = CORNELL["negatives"], seed: int = 0,
                         n_candidates: int = 48, n_jobs: int = 1, executor=None,
                         progress: bool = False, max_scenes: int | None = None) -> dict:
    """Write the Cornell-sized stand-in (see the module docstring); resumes.

    Parameters
    ----------
    out : str or Path
        Root: ``labelled/`` (every executed rectangle), ``cornell/`` (the thinned dataset that
        :func:`dlsr.datasets.load_cornell` reads, with each image's ``pcdXXXXcamera.json``) and
        ``standin.json``.
    n_images, n_objects, positives, negatives : int
        The counts to reach (Cornell's by default; smaller for tests or timing subsets: the
        quotas scale with ``n_images``).
    seed : int
        Seeds the scenes (:func:`graspsim.data.datagen.make_dataset`) and the thinning.
    n_candidates : int
        Rectangles executed per scene.
    n_jobs, executor, progress
        As :func:`graspsim.data.datagen.make_dataset`.
    max_scenes : int, optional
        Stop labelling after this many scenes even if fewer than ``n_images`` have both labels
        (default ``2 * n_images``); the stand-in is then smaller and ``standin.json`` says so.

    Returns
    -------
    dict
        What ``standin.json`` holds: ``format``, ``asked`` and ``reached`` counts (images,
        distinct objects, positives, negatives), ``objects``, ``seed``, ``n_candidates``,
        ``labelled_scenes``, ``skipped_scenes`` (no positive or no negative),
        ``labelled_fingerprint``, ``blas`` (the BLAS kernels of the run that wrote the record:
        :func:`dlsr.records.machine_record`) and ``how``.
    """
    for name, v in (("n_images", n_images), ("positives", positives),
                    ("negatives", negatives), ("n_candidates", n_candidates)):
        if v < 1:
            raise ValueError(f"{name} must be >= 1, got {v}")
    specs = standin_objects(n_objects)
    root = Path(out)
    labelled = root / "labelled"
    cornell = root / "cornell"
    limit = 2 * n_images if max_scenes is None else int(max_scenes)
    # Never fewer scenes than already labelled: make_dataset's mapping file lists its first
    # n_scenes images, so asking for fewer would hide written ones from load_cornell.
    n_scenes = max(min(n_images, limit), _labelled_scenes(labelled))
    while True:
        stats = make_dataset(n_scenes=n_scenes, objects=specs, out=labelled, seed=seed,
                             n_candidates=n_candidates, n_jobs=n_jobs, executor=executor,
                             progress=progress)
        samples = load_cornell(labelled)
        usable = usable_scenes(samples)
        if len(usable) >= n_images or n_scenes >= limit:
            break
        short = n_images - len(usable)
        rate = max(len(usable) / len(samples), 0.1)
        n_scenes = min(limit, n_scenes + int(np.ceil(short / rate)))
        log.info("stand-in: %d of %d scenes usable; labelling up to %d", len(usable),
                 len(samples), n_scenes)
    kept = usable[:n_images]
    if len(kept) < n_images:
        log.warning("stand-in: only %d images have both positive and negative labels after %d "
                    "scenes (asked for %d)", len(kept), n_scenes, n_images)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(885,)))
    q_pos = spread_quota(positives, [len(s.positives) for s in kept], rng)
    q_neg = spread_quota(negatives, [len(s.negatives) for s in kept], rng)
    if cornell.exists():
        shutil.rmtree(cornell)  # rebuilt from labelled/ every time: cheap and always consistent
    lines = []
    for number, (s, n_p, n_n) in enumerate(zip(kept, q_pos, q_neg, strict=True)):
        pos, neg = thin_labels(s.positives, s.negatives, int(n_p), int(n_n), rng)
        thinned = replace(s, positives=pos, negatives=neg)
        line = write_cornell_image(thinned, cornell, number)
        if line:
            lines.append(line)
        src = int(s.image_id)  # make_dataset's image ids are the scene numbers
        cam = labelled / f"{src // 100:02d}" / f"pcd{src:04d}camera.json"
        if cam.exists():
            dst = cornell / f"{number // 100:02d}" / f"pcd{number:04d}camera.json"
            shutil.copyfile(cam, dst)
    write_cornell_mapping(cornell, lines)
    record = {
        "format": STANDIN_FORMAT,
        "asked": {"images": n_images, "objects": len(specs), "positives": positives,
                  "negatives": negatives},
        "reached": {"images": len(kept), "objects": len({s.object_id for s in kept}),
                    "positives": int(q_pos.sum()), "negatives": int(q_neg.sum())},
        "objects": [s.name for s in specs],
        "seed": seed,
        "n_candidates": n_candidates,
        "labelled_scenes": len(samples),
        "skipped_scenes": len(samples) - len(usable),
        "labelled_fingerprint": stats["fingerprint"],
        # The physics follow the last bits of numpy's products: another OpenBLAS kernel set
        # labels a few scenes otherwise (OPENBLAS_CORETYPE reproduces a stand-in elsewhere).
        "blas": machine_record()["blas"],
        # as first recorded (the functions are now in graspsim.data), so stand-ins stay the same
        "how": "graspsim.standin.make_cornell_standin: built-in objects then random_urdfs "
               "train objects; one object per scene, every candidate executed by the physics "
               "(graspsim.datagen.make_dataset); the first scenes with both labels kept; "
               "quotas spread evenly (spread_quota); positives at random, negatives the "
               "failures nearest a positive (thin_labels)",
    }
    old = root / "standin.json"
    if old.exists() and read_json(old, "stand-in record").get("asked") not in (None,
                                                                               record["asked"]):
        log.info("stand-in: %s rewritten for new counts", old)
    write_json_atomic(old, record, indent=1)
    return record
