"""The detector's configuration chosen by nested object-wise cross-validation
(``graspsim benchmark detection --nested``): each outer fold's choice made on its training
objects alone, reported on its test objects.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np

from dlsr import datasets
from dlsr.records import write_text_atomic

from ...data.samples import load_samples
from ...detectors.dlsr_options import candidate_options
from ..stats import paired_accuracy_test, wilson_interval
from .detection import detection_benchmark

__all__ = ["nested_detector_choice", "nested_markdown"]

log = logging.getLogger(__name__)


def nested_detector_choice(data, format: str, out, candidates=None, n_folds: int = 5,
                           inner_folds: int = 3, inner_views: int | None = 3,
                           report=("paper", "all"), seed: int = 0, progress: bool = True,
                           executor=None, **benchmark) -> dict:
    """Choose the detector configuration by nested object-wise cross-validation.

    For each outer object-wise fold (the folds of :func:`detection_benchmark` with the same
    ``seed``), every candidate configuration is cross-validated on the outer training
    objects alone (``inner_folds`` object-wise folds over their first ``inner_views`` views
    each, sorted by image id; None: every view), and the one with the best inner accuracy is
    chosen (ties: the earlier candidate, the paper's first); it is then reported on the outer
    fold's images, never seen by the choice. The chosen configurations and those in ``report``
    run on every outer fold (:func:`detection_benchmark`, ``out/outer``), so the table also
    has each of them on all images, and the nested outcome is image by image the chosen
    configuration's of its fold. The configurations in ``report`` run first, and the tables
    are rewritten after every outer fold (partial until the last). Everything resumes from
    ``out``.

    Parameters
    ----------
    data, format :
        As :func:`detection_benchmark`.
    out : path-like
        ``out/outer<k>/`` (inner runs of outer fold k), ``out/outer/``, ``out/nested.json``
        and ``out/nested.md``.
    candidates : dict of str to DetectorOptions or None
        Default :func:`graspsim.detectors.dlsr_options.candidate_options` (the paper's, each
        departure alone, all of them).
    n_folds, inner_folds : int
    inner_views : int or None
        Views per object in the inner folds (fewer: a cheaper choice).
    report : sequence of str
        Candidates also run on every outer fold.
    seed : int
    progress : bool
    executor : Executor or None
    **benchmark :
        Further options of :func:`detection_benchmark` (``scale``, ``n_atoms``, ``n_patches``,
        ``rescore``, ``coarse_to_fine``, ...).

    Returns
    -------
    dict
        ``choices`` (per outer fold: the inner accuracy of every candidate and the choice),
        ``chosen`` (the most often chosen; ties by mean inner accuracy), ``outer`` (per
        reported configuration: accuracy, Wilson interval, per-image outcomes), ``nested``
        (the same for the nested outcome), ``baselines`` and ``tests`` (exact McNemar tests
        on the same images); also written to ``out/nested.json`` and ``out/nested.md``.
    """
    candidates = candidate_options() if candidates is None else dict(candidates)
    unknown = [r for r in report if r not in candidates]
    if unknown:
        raise ValueError(f"report {unknown} not among the candidates {sorted(candidates)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    samples = [s for s in load_samples(data, format, benchmark.get("scale"),
                                       benchmark.get("mapping")) if s.positives]
    folds = datasets.object_wise_folds(samples, n_folds, seed)
    bench = dict(benchmark, progress=False, executor=executor, seed=seed)
    runs = {}

    def outer(name):  # a configuration on every outer fold (resumes)
        if name not in runs:
            runs[name] = detection_benchmark(data, format, out / "outer", split="object",
                                             n_folds=n_folds, options=candidates[name],
                                             **bench)
        return runs[name]

    for name in report:  # first, so that an interrupted choice still reports them
        outer(name)
    choices = []
    for k, (train, _test) in enumerate(folds):
        by_object: dict = {}
        for i in sorted(train, key=lambda i: samples[i].image_id):
            by_object.setdefault(samples[i].object_id, []).append(samples[i].image_id)
        ids = [v for views in by_object.values() for v in views[:inner_views]]
        accs = {}
        for name, opts in candidates.items():
            summary = detection_benchmark(data, format, out / f"outer{k}", split="object",
                                          n_folds=inner_folds, options=opts, images=ids,
                                          **bench)
            accs[name] = summary["accuracy"]
            if progress:
                log.warning("outer fold %d: inner accuracy of %s %.3f", k, name, accs[name])
        best = max(accs.values())
        chosen = next(name for name in candidates if accs[name] == best)
        choices.append({"fold": k, "n_inner_images": len(ids),
                        "inner_objects": sorted(by_object), "inner_accuracy": accs,
                        "chosen": chosen})
        outer(chosen)
        result = _nested_result(data, format, n_folds, inner_folds, inner_views, seed,
                                candidates, benchmark, choices, runs, len(folds))
        write_text_atomic(out / "nested.json", json.dumps(result, indent=2))
        write_text_atomic(out / "nested.md", nested_markdown(result))
    return result


def _nested_result(data, format, n_folds, inner_folds, inner_views, seed, candidates,
                   benchmark, choices, runs, n_outer) -> dict:
    """The summary of :func:`nested_detector_choice` from the outer folds chosen so far (the
    nested row covers their images only until every fold is done)."""

    counts = Counter(c["chosen"] for c in choices)
    mean_inner = {n: float(np.mean([c["inner_accuracy"][n] for c in choices]))
                  for n in candidates}
    chosen = max(counts, key=lambda n: (counts[n], mean_inner[n]))
    first = next(iter(runs.values()))["per_image"]
    ids = [r["image_id"] for r in first]
    fold_of = {r["image_id"]: r["fold"] for r in first}
    outcome = {name: {r["image_id"]: bool(r["success"]) for r in run["per_image"]}
               for name, run in runs.items()}
    baselines = {b: {r["image_id"]: bool(r["baselines"][b]) for r in first}
                 for b in first[0]["baselines"]}
    chosen_of = {c["fold"]: c["chosen"] for c in choices}
    nested_ids = [i for i in ids if fold_of[i] in chosen_of]
    rows = {"nested": {i: outcome[chosen_of[fold_of[i]]][i] for i in nested_ids},
            **{f"config:{n}": outcome[n] for n in runs},
            **{f"baseline:{b}": v for b, v in baselines.items()}}

    def cell(res: dict) -> dict:
        n, k_ = len(res), sum(res.values())
        lo, hi = wilson_interval(k_, n)
        return {"successes": k_, "n": n, "accuracy": k_ / n, "ci95": [lo, hi]}

    table = {name: cell(res) for name, res in rows.items()}
    tests = {}
    for a in ["nested", *[f"config:{n}" for n in runs]]:
        for b in ["baseline:mask-pca", "config:paper"]:
            if a != b and b in rows:
                same = [i for i in rows[a] if i in rows[b]]
                tests[f"{a} vs {b}"] = paired_accuracy_test([rows[a][i] for i in same],
                                                     [rows[b][i] for i in same])
    return {"config": {"data": str(data), "format": format, "n_folds": n_folds,
                       "inner_folds": inner_folds, "inner_views": inner_views, "seed": seed,
                       "candidates": {n: dataclasses.asdict(o) for n, o in candidates.items()},
                       **{k: v for k, v in benchmark.items() if k != "executor"}},
            "complete": len(choices) == n_outer, "outer_folds_done": len(choices),
            "choices": choices, "chosen": chosen, "chosen_counts": dict(counts),
            "mean_inner_accuracy": mean_inner, "table": table, "tests": tests,
            "per_image": [{"image_id": i, "fold": fold_of[i],
                           **{n: rows[n].get(i) for n in rows}} for i in ids]}


def nested_markdown(result: dict) -> str:
    """The tables of :func:`nested_detector_choice`: inner accuracies and choices per outer
    fold, then outer accuracies with Wilson intervals and the paired tests."""
    names = list(result["config"]["candidates"])
    lines = ["| outer fold | inner images | " + " | ".join(names) + " | chosen |",
             "|---" * (len(names) + 3) + "|"]
    for c in result["choices"]:
        lines.append(f"| {c['fold']} | {c['n_inner_images']} | " + " | ".join(
            f"{100 * c['inner_accuracy'][n]:.1f}" for n in names) + f" | {c['chosen']} |")
    done = ("" if result["complete"] else f" (partial: {result['outer_folds_done']} of "
            f"{result['config']['n_folds']} outer folds; the nested row covers their images)")
    lines += ["", f"Chosen overall: **{result['chosen']}** "
              f"({result['chosen_counts']}){done}", "",
              "| detector | success | accuracy | 95 % CI (Wilson) |", "|---|---|---|---|"]
    for name, t in result["table"].items():
        lo, hi = t["ci95"]
        lines.append(f"| {name} | {t['successes']}/{t['n']} | {100 * t['accuracy']:.1f} % | "
                     f"{100 * lo:.1f} to {100 * hi:.1f} % |")
    lines += ["", "| paired test (exact McNemar) | a only | b only | p |", "|---|---|---|---|"]
    for name, t in result["tests"].items():
        lines.append(f"| {name} | {t['a_only']} | {t['b_only']} | {t['p_value']:.3g} |")
    return "\n".join(lines) + "\n"
