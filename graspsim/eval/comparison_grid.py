"""Paired comparisons on a grid: detectors (columns of a table) on protocol rows (object set,
hand, scene), every detector on the same seeded scenes, grown in steps, paired with a reference.

A :class:`Row` is one protocol: single-object trials (the drop scene) or clutter-removal rounds
(``pile`` or ``packed``, as VGN and GIGA), on an object set (``--objects`` syntax,
:mod:`graspsim.sim.object_sets`) with a hand (:mod:`graspsim.sim.hands`). :func:`grow` runs every
(row, detector) cell to the next size of its row's steps, then the next, so that whatever has
finished when a long campaign is stopped covers every cell at the same size; each cell is a
resumable trial or round folder (:func:`graspsim.eval.trials.run_trials`,
:func:`graspsim.eval.declutter.run_rounds`), so a rerun continues where it stopped. After each step
``OUT/results.json`` and ``OUT/results.md`` hold :func:`row_results` of every row: success with
Wilson 95 % intervals, the failure reasons, the declutter rate with a bootstrap interval over
rounds, and each detector's paired verdict against the reference (exact McNemar on the paired
trials, or on the rounds' first grasps, which are paired scenes; a sign test on the objects
each round removed).

Only the oracle needs the scenes labelled (``candidates`` per observation); the other
detectors' scenes, cameras and seeds do not depend on it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from dlsr.records import read_jsonl, write_json_atomic, write_text_atomic

from ..runtime.campaign import is_skipped
from ..sim.execution import ExecutionParams
from .compare import compare_outcomes, first_grasp
from .declutter import run_rounds, summarize_rounds
from .stats import removed_sign_test, wilson_interval
from .summary import summarize
from .trials import TrialConfig, run_trials

__all__ = ["Row", "TRIAL_STEPS", "ROUND_STEPS", "pick", "run_cell", "row_results",
           "results_markdown", "grow"]

log = logging.getLogger(__name__)

TRIAL_STEPS = (25, 50, 100, 150, 200)
"""Sizes a trial row grows through (paired trials per cell)."""

ROUND_STEPS = (6, 12, 25, 50, 100, 200)
"""Sizes a clutter row grows through (paired rounds per cell)."""


@dataclass(frozen=True)
class Row:
    """One protocol of the grid.

    Attributes
    ----------
    name : str
        The row's folder and heading.
    objects : str
        The object set (``"test"``, ``"ycb:test"``, ...).
    hand : str
        The hand (:data:`graspsim.sim.hands.HAND_NAMES`).
    scene : {None, "pile", "packed"}
        None: single-object trials in the drop scene; else clutter-removal rounds.
    n_objects : int
        Objects per round (clutter rows).
    sizes : tuple of int or None
        The sizes the row grows through; None: :data:`TRIAL_STEPS` or :data:`ROUND_STEPS`.
    """

    name: str
    objects: str = "test"
    hand: str = "builtin"
    scene: str | None = None
    n_objects: int = 5
    sizes: tuple[int, ...] | None = None

    @property
    def unit(self) -> str:
        """``"trials"`` or ``"rounds"``: the records of the row's folders."""
        return "trials" if self.scene is None else "rounds"

    @property
    def steps(self) -> tuple[int, ...]:
        """The sizes the row grows through."""
        if self.sizes is not None:
            return tuple(self.sizes)
        return TRIAL_STEPS if self.scene is None else ROUND_STEPS


def pick(text: str, known, what: str) -> list[str]:
    """The names of a comma-separated ``text``, each checked against ``known``.

    Raises
    ------
    ValueError
        Naming the unknown ones and the choices, in one line.
    """
    names = [t.strip() for t in text.split(",") if t.strip()]
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise ValueError(f"unknown {what} {', '.join(unknown)}; choose from {', '.join(known)}")
    return names


def run_cell(row: Row, name: str, detector, n: int, out, executor=None, seed: int = 0,
             candidates: int = 32) -> dict:
    """Run (or continue) ``detector`` on ``row`` until ``out/<row>/<name>`` holds ``n`` made
    trials or rounds; returns the folder's summary (without its records).

    A scene that cannot be made (a pile that does not settle, an object off the table) is a
    logged skip in the folder and pairs with nothing; the cell runs one more scene for each,
    so that every cell of a row holds ``n`` paired scenes. Scenes are seeded by index, so every
    detector skips the same ones. At most ``n`` extra scenes are tried.
    """
    k = candidates if name == "oracle" else 0
    params = ExecutionParams.with_hand(row.hand)
    folder = Path(out) / row.name / name
    total = n
    while True:
        if row.scene is None:
            s = run_trials(detector, objects=row.objects, n=total, seed=seed, out=folder,
                           config=TrialConfig(n_candidates=k), params=params,
                           executor=executor, detector_name=name)
        else:
            s = run_rounds(detector, objects=row.objects, n=total, seed=seed, out=folder,
                           config=TrialConfig(n_candidates=k, n_objects=row.n_objects,
                                              scene=row.scene),
                           params=params, executor=executor, detector_name=name)
        want = n + len(s.get("skipped") or ())
        if want <= total or want > 2 * n:
            break
        log.info("%s %s: %d scene(s) could not be made; running to %d", row.name, name,
                 want - n, want)
        total = want
    s.pop("records", None)
    return s


def _records(folder: Path, unit: str) -> tuple[dict[int, dict], set[int]]:
    """A cell's records by index, and the indices of scenes that could not be made (they
    pair with nothing)."""
    out: dict[int, dict] = {}
    skipped: set[int] = set()
    for r in read_jsonl(folder / f"{unit}.jsonl", required=("index",)):
        if is_skipped(r):
            skipped.add(int(r["index"]))
        else:
            out.setdefault(int(r["index"]), r)
    return out, skipped


def _reasons(records) -> dict:
    counts: dict = {}
    for r in records:
        why = r.get("reason") or ("lifted" if r.get("success") else "failed")
        counts[why] = counts.get(why, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def row_results(out, row: Row, detectors: Sequence[str], reference: str = "mask-pca") -> dict:
    """Every detector's figures in ``row`` and its paired verdict against ``reference``, on
    the trials or rounds that every detector has finished.

    Returns
    -------
    dict
        ``unit``, ``n`` (paired scenes), ``skipped`` (indices of scenes that could not be
        made, left out of every cell), ``objects``, ``hand``, ``scene`` and ``cells``:
        per detector its successes, rate and Wilson interval, failure reasons (trials), or
        grasp success, declutter rate with its bootstrap interval and first-grasp success
        (rounds), and ``vs_reference`` (exact McNemar p, which is better, verdict; for rounds
        also the sign test on objects removed).
    """
    out = Path(out)
    unit = row.unit
    # a detector not run on this row yet (a column added later) is left out of it
    detectors = [d for d in detectors if (out / row.name / d / f"{unit}.jsonl").is_file()]
    read = {d: _records(out / row.name / d, unit) for d in detectors}
    recs = {d: r for d, (r, _) in read.items()}
    shared = sorted(set.intersection(*(set(r) for r in recs.values()))) if recs else []
    skipped = sorted(set().union(*(s for _, s in read.values())))
    res: dict = {"unit": unit, "n": len(shared), "skipped": skipped, "objects": row.objects,
                 "hand": row.hand, "scene": row.scene, "reference": reference, "cells": {}}
    if not shared:
        return res
    for d in detectors:
        rs = [recs[d][i] for i in shared]
        if unit == "trials":
            s = summarize(rs)
            cell = {"successes": s["successes"], "n": s["n"], "success_rate": s["success_rate"],
                    "success_ci95": s["success_ci95"], "reasons": _reasons(rs)}
        else:
            s = summarize_rounds(rs, random_state=0)
            kf = sum(first_grasp(r) for r in rs)
            cell = {"successes": s["successes"], "attempts": s["attempts"],
                    "success_rate": s["success_rate"], "success_ci95": s["success_ci95"],
                    "removed": s["removed"], "placed": s["objects_placed"],
                    "declutter_rate": s["declutter_rate"],
                    "declutter_ci95_bootstrap": s["declutter_ci95_bootstrap"],
                    "first_grasp": kf, "first_grasp_ci95": list(wilson_interval(kf, len(rs)))}
        res["cells"][d] = cell
    if reference not in recs:
        return res
    base = [recs[reference][i] for i in shared]
    for d in detectors:
        if d == reference:
            continue
        rs = [recs[d][i] for i in shared]
        if unit == "trials":
            c = compare_outcomes([r["success"] for r in rs], [r["success"] for r in base],
                                 names=(d, reference))
            res["cells"][d]["vs_reference"] = {"p": c["mcnemar_p"], "better": c["better"],
                                               "verdict": c["verdict"]}
        else:
            c = compare_outcomes([first_grasp(r) for r in rs], [first_grasp(r) for r in base],
                                 names=(d, reference), unit="first grasps")
            t = removed_sign_test([r["removed"] for r in rs], [b["removed"] for b in base])
            res["cells"][d]["vs_reference"] = {
                "p": c["mcnemar_p"], "better": c["better"], "verdict": c["verdict"],
                "removed_more": t["more"], "removed_fewer": t["fewer"],
                "sign_test_p": t["sign_test_p"]}
    return res


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _ci(v) -> str:
    return "n/a" if v is None or v[0] is None else f"{100 * v[0]:.0f}-{100 * v[1]:.0f}"


def _verdict(v: dict) -> str:
    word = {"a": "better", "b": "worse", None: "not separated"}[v["better"]]
    return f"{word} (p = {v['p']:.2g})"


def results_markdown(results: dict) -> str:
    """The tables of :func:`row_results` for every row (``results``: row name to result)."""
    lines = []
    for name, res in results.items():
        if not res.get("n"):
            lines += [f"## {name}", "", "no finished cell yet", ""]
            continue
        where = f"{res['objects']}, {res['hand']} hand" + (f", {res['scene']}"
                                                           if res["scene"] else "")
        ref = res.get("reference", "mask-pca")
        lines += [f"## {name} ({res['n']} paired {res['unit']}; {where})", ""]
        if res.get("skipped"):
            lines += [f"Left out: {len(res['skipped'])} scene(s) that could not be made "
                      f"(indices {', '.join(map(str, res['skipped']))}).", ""]
        if res["unit"] == "trials":
            lines += [f"| detector | success | 95 % CI | vs {ref} (exact McNemar) | failures |",
                      "|---|---|---|---|---|"]
            for d, c in res["cells"].items():
                v = c.get("vs_reference")
                fails = ", ".join(f"{k} {n}" for k, n in c["reasons"].items() if k != "lifted")
                lines.append(f"| {d} | {c['successes']}/{c['n']} = {_pct(c['success_rate'])} | "
                             f"{_ci(c['success_ci95'])} % | "
                             + ("-" if v is None else _verdict(v)) + f" | {fails or '-'} |")
        else:
            lines += ["| detector | grasp success | 95 % CI | declutter rate | 95 % CI "
                      f"(bootstrap) | first grasp | vs {ref}: first grasp (McNemar); "
                      "objects removed (sign test) |",
                      "|---|---|---|---|---|---|---|"]
            for d, c in res["cells"].items():
                v = c.get("vs_reference")
                extra = "-" if v is None else (
                    f"{_verdict(v)}; removed more in {v['removed_more']} rounds, fewer in "
                    f"{v['removed_fewer']} (p = {v['sign_test_p']:.2g})")
                lines.append(
                    f"| {d} | {c['successes']}/{c['attempts']} = {_pct(c['success_rate'])} | "
                    f"{_ci(c['success_ci95'])} % | {c['removed']}/{c['placed']} = "
                    f"{_pct(c['declutter_rate'])} | {_ci(c['declutter_ci95_bootstrap'])} % | "
                    f"{c['first_grasp']}/{res['n']} ({_ci(c['first_grasp_ci95'])} %) | {extra} |")
        lines.append("")
    return "\n".join(lines)


def grow(rows: Sequence[Row], detectors: Sequence[str], make_detector: Callable, out,
         executor=None, steps: int | None = None, seed: int = 0, candidates: int = 32,
         reference: str = "mask-pca", report: Sequence[Row] | None = None) -> dict:
    """Grow every (row, detector) cell step by step, writing the results after each step.

    Parameters
    ----------
    rows : sequence of Row
    detectors : sequence of str
        The detectors' names (folders and columns), ``reference`` among them for the
        verdicts.
    make_detector : callable
        ``make_detector(name, row)`` returns the detector to run on ``row`` (e.g. DLSR made
        aware of ``row.hand``).
    out : path-like
    executor : graspsim.runtime.executor.Executor or None
    steps : int or None
        How many growth steps to run (None: all, up to each row's last size).
    seed : int
    candidates : int
        Labelled candidates per observation for the oracle.
    reference : str
    report : sequence of Row or None
        The rows ``results.json`` and ``results.md`` cover (default: ``rows``): a campaign
        grown a few rows at a time keeps the others' figures in its results. A row of
        ``report`` with no folder in ``out`` yet is left out.

    Returns
    -------
    dict
        Row name to :func:`row_results`, as written to ``out/results.json``.
    """
    out = Path(out)
    grown = {r.name for r in rows}
    shown = [r for r in (rows if report is None else report)
             if r.name in grown or (out / r.name).is_dir()]
    out.mkdir(parents=True, exist_ok=True)
    n_steps = max(len(r.steps) for r in rows)
    results: dict = {}
    for step in range(n_steps if steps is None else min(steps, n_steps)):
        for row in rows:
            n = row.steps[min(step, len(row.steps) - 1)]
            for name in detectors:
                s = run_cell(row, name, make_detector(name, row), n, out, executor, seed=seed,
                             candidates=candidates)
                log.info("%s %s n=%d: %s", row.name, name, n,
                         {k: s.get(k) for k in ("success_rate", "declutter_rate")})
            results = {r.name: row_results(out, r, detectors, reference) for r in shown}
            write_json_atomic(out / "results.json", results, indent=1)
            write_text_atomic(out / "results.md", results_markdown(results))
    return results
