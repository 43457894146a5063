"""Label coverage: do a scene's physics-labelled positives cover the grasps that work?

For a seeded single-object scene (:func:`graspsim.sim.observe.observe_scene`), independently
sampled candidates (the mixed sampler of :func:`graspsim.labels.labelling.sample_candidates`,
``n_reference`` per scene, from a generator stream of their own) are executed and their
successes kept as the reference "physically good grasps". Each labelling under test labels the
same scene from the trial's own label stream:

* ``mixed``: the mixed sampler, ``mixed_n`` candidates per scene (48 as in
  ``graspsim dataset``);
* ``dense_<budget>``: ``sample_candidates(..., mode="dense")`` with that budget
  (``dense_all``: the whole lattice).

Coverage is the fraction of reference successes that the labelled positives match by the
rectangle metric (angle within 30 degrees and Jaccard index above 0.25,
:func:`dlsr.metrics.rectangle_metric_many`), pooled over scenes; scenes without a reference
success do not count. ``scripts/label_coverage.py`` prints it for the train objects.
"""

from __future__ import annotations

import time

import numpy as np

from dlsr.metrics import rectangle_metric_many

from ..runtime.campaign import make_executor
from ..sim.bullet import worker_sim
from ..sim.observe import observe_scene
from .graspability import resolve_objects
from .labelling import label_rectangles, sample_candidates

__all__ = ["labelling_names", "scene_coverage", "coverage_summary", "label_coverage"]


def labelling_names(budgets) -> list[str]:
    """The labellings compared: ``"mixed"`` and one ``"dense_<budget>"`` per budget.

    Parameters
    ----------
    budgets : sequence of int
        Dense budgets per scene (0: the whole lattice, ``"dense_all"``).

    Returns
    -------
    list of str
    """
    return ["mixed"] + [f"dense_{b or 'all'}" for b in budgets]


def scene_coverage(seed: int, index: int, n_reference: int, mixed_n: int, budgets,
                   objects="train") -> dict:
    """Reference successes of one scene and, per labelling, how many its positives cover.

    Parameters
    ----------
    seed, index : int
        The scene (:func:`graspsim.sim.observe.observe_scene`).
    n_reference : int
        Reference candidates executed.
    mixed_n : int
        Candidates of the mixed labelling.
    budgets : sequence of int
        Dense budgets (0: the whole lattice).
    objects : str or ObjectSet or list of ObjectSpec
        The object set (:func:`graspsim.labels.graspability.resolve_objects`).

    Returns
    -------
    dict
        ``index``, ``object``, ``reference_candidates``, ``reference_successes`` and, per
        labelling (:func:`labelling_names`), ``labelled``, ``positives``, ``covered`` (reference
        successes matched) and ``cpu_seconds``.
    """
    sim = worker_sim()
    scene, bodies, frame, st = observe_scene(sim, resolve_objects(objects), seed, index)
    ref_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index, 1 << 20)))
    ref = sample_candidates(frame.segmentation, bodies.objects, ref_rng, n_reference,
                            depth=frame.depth_clean)
    ref_pos = label_rectangles(sim, scene, frame, ref).positives
    out = {"index": index, "object": scene.objects[0].spec.name,
           "reference_candidates": len(ref), "reference_successes": len(ref_pos)}
    for name, budget in zip(labelling_names(budgets), [None, *budgets], strict=True):
        rng = np.random.default_rng(st["label"].bit_generator.seed_seq)  # same stream each
        if budget is None:
            cands = sample_candidates(frame.segmentation, bodies.objects, rng, mixed_n,
                                      depth=frame.depth_clean)
        else:
            cands = sample_candidates(frame.segmentation, bodies.objects, rng, budget or None,
                                      depth=frame.depth_clean, mode="dense",
                                      intrinsics=frame.intrinsics)
        t = time.process_time()
        pos = label_rectangles(sim, scene, frame, cands).positives
        cpu = time.process_time() - t
        covered = int(rectangle_metric_many(ref_pos, pos).sum()) if ref_pos and pos else 0
        out[name] = {"labelled": len(cands), "positives": len(pos), "covered": covered,
                     "cpu_seconds": round(cpu, 3)}
    return out


def coverage_summary(scenes: list[dict], names) -> dict:
    """Coverage per labelling, pooled over scenes.

    Parameters
    ----------
    scenes : list of dict
        :func:`scene_coverage` records.
    names : sequence of str
        The labellings (:func:`labelling_names`).

    Returns
    -------
    dict
        Per labelling: ``coverage`` (covered reference successes / reference successes, None
        without any), ``covered``, ``labelled_per_scene``, ``positives_per_scene``,
        ``cpu_ms_per_labelled_grasp``.
    """
    if not scenes:
        raise ValueError("no scene to summarise")
    n_ref = sum(s["reference_successes"] for s in scenes)
    summary = {}
    for name in names:
        cov = sum(s[name]["covered"] for s in scenes)
        lab = sum(s[name]["labelled"] for s in scenes)
        summary[name] = {
            "coverage": round(cov / n_ref, 4) if n_ref else None,
            "covered": cov,
            "labelled_per_scene": round(lab / len(scenes), 1),
            "positives_per_scene": round(sum(s[name]["positives"] for s in scenes)
                                         / len(scenes), 1),
            "cpu_ms_per_labelled_grasp": round(
                1000 * sum(s[name]["cpu_seconds"] for s in scenes) / max(lab, 1), 2),
        }
    return summary


def label_coverage(n_scenes: int = 20, seed: int = 5, n_reference: int = 96,
                   mixed_n: int = 48, budgets=(128, 256, 0), objects="train", n_jobs: int = 1,
                   executor=None) -> dict:
    """The coverage of each labelling on ``n_scenes`` scenes (see the module docstring).

    Parameters
    ----------
    n_scenes, seed : int
    n_reference, mixed_n : int
    budgets : sequence of int
    objects : str
        An object-set text (recorded as given).
    n_jobs : int
    executor : graspsim.runtime.executor.Executor or None

    Returns
    -------
    dict
        ``seed``, ``scenes``, ``objects``, ``reference_candidates_per_scene``,
        ``reference_successes``, ``summary`` (:func:`coverage_summary`), ``seconds`` and
        ``per_scene``.
    """
    if n_scenes < 1:
        raise ValueError(f"n_scenes must be >= 1, got {n_scenes}")
    budgets = [int(b) for b in budgets]
    tasks = [(seed, i, n_reference, mixed_n, budgets, objects) for i in range(n_scenes)]
    t = time.perf_counter()
    ex = make_executor(executor, n_jobs, progress=False)
    scenes = list(ex.imap(scene_coverage, tasks, star=True))
    return {
        "seed": seed, "scenes": n_scenes, "objects": objects,
        "reference_candidates_per_scene": n_reference,
        "reference_successes": sum(s["reference_successes"] for s in scenes),
        "summary": coverage_summary(scenes, labelling_names(budgets)),
        "seconds": round(time.perf_counter() - t, 1),
        "per_scene": scenes,
    }
