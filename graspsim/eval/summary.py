"""Summaries of grasp trials: success with Wilson intervals, the rectangle metric's verdicts
against the physical outcomes, failure reasons, per-object counts and planning times
(``summary.json`` and ``summary.md`` of a :func:`graspsim.eval.trials.run_trials` folder)."""

from __future__ import annotations

import numpy as np

from ..sim.execution import describe_changes, execution_changes, execution_params_from_dict
from .stats import wilson_interval

__all__ = ["planning_stats", "summarize", "summary_markdown", "planning_line", "execution_line",
           "skipped_line"]


def planning_stats(seconds) -> dict:
    """Median and 95th percentile (linear interpolation) of planning times, seconds."""
    x = np.asarray([s for s in seconds if s is not None], dtype=float)
    if x.size == 0:
        return {"n": 0, "median": None, "p95": None}
    return {"n": int(x.size), "median": float(np.median(x)), "p95": float(np.percentile(x, 95))}


def summarize(records: list[dict]) -> dict:
    """Success rate (Wilson 95 %), metric accuracy, verdict-vs-outcome table, failure reasons."""
    n = len(records)
    k = sum(bool(r["success"]) for r in records)
    lo, hi = wilson_interval(k, n)
    verdicts = [r for r in records if r.get("metric") is not None]
    table = {"metric_true": {"success": 0, "failure": 0},
             "metric_false": {"success": 0, "failure": 0}}
    for r in verdicts:
        table["metric_true" if r["metric"] else "metric_false"][
            "success" if r["success"] else "failure"] += 1
    reasons: dict[str, int] = {}
    for r in records:
        if not r["success"]:
            reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
    m = len(verdicts)
    mk = sum(bool(r["metric"]) for r in verdicts)
    per_object: dict[str, list[int]] = {}
    for r in records:
        name = "+".join(r["object"])
        per_object.setdefault(name, [0, 0])
        per_object[name][0] += int(bool(r["success"]))
        per_object[name][1] += 1
    seconds = [r.get("seconds", 0.0) for r in records]
    g = [r for r in records if r.get("graspable", True)]
    gk = sum(bool(r["success"]) for r in g)
    return {
        "n": n,
        "successes": k,
        "success_rate": k / n if n else float("nan"),
        "success_ci95": [lo, hi],
        "graspable_n": len(g),
        "graspable_success_rate": gk / len(g) if g else None,
        "graspable_success_ci95": list(wilson_interval(gk, len(g))) if g else None,
        "metric_n": m,
        "metric_accuracy": mk / m if m else None,
        "metric_ci95": list(wilson_interval(mk, m)) if m else None,
        "verdict_vs_outcome": table,
        "agreement": ((table["metric_true"]["success"] + table["metric_false"]["failure"]) / m
                      if m else None),
        "failure_reasons": dict(sorted(reasons.items(), key=lambda kv: -kv[1])),
        "per_object": {k_: {"successes": v[0], "n": v[1]} for k_, v in sorted(per_object.items())},
        "seconds_per_trial": float(np.mean(seconds)) if seconds else None,
        "planning_seconds": planning_stats(r.get("planning_seconds") for r in records),
    }


def summary_markdown(s: dict) -> str:
    """The summary as a Markdown report."""
    def pct(x):
        return "n/a" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{100 * x:.1f} %"

    t = s["verdict_vs_outcome"]
    tps = "n/a" if s.get("trials_per_second") is None else f"{s['trials_per_second']:.2f}"
    lines = [
        f"# Grasp trials: detector `{s.get('detector')}` on `{s.get('objects')}` objects",
        "",
        f"- trials: {s['n']} (seed {s.get('seed')}; scene "
        f"{(s.get('config') or {}).get('scene', 'drop')})",
        f"- physical success: {s['successes']}/{s['n']} = {pct(s['success_rate'])} "
        f"(Wilson 95 % interval {pct(s['success_ci95'][0])} - {pct(s['success_ci95'][1])})",
        f"- on graspable objects: {pct(s['graspable_success_rate'])} "
        f"(n = {s['graspable_n']}"
        + (f", Wilson 95 % {pct(s['graspable_success_ci95'][0])} - "
           f"{pct(s['graspable_success_ci95'][1])})" if s["graspable_n"] else ")"),
        f"- rectangle-metric accuracy on the same trials: {pct(s['metric_accuracy'])} "
        f"(n = {s['metric_n']})",
        f"- metric/physics agreement: {pct(s['agreement'])}",
        f"- trials per second (this run): {tps} with {s.get('n_jobs')} job(s); "
        f"mean {s['seconds_per_trial'] or 0:.2f} s per trial per worker",
        planning_line(s.get("planning_seconds")),
        *filter(None, [execution_line(s), skipped_line(s)]),
        "",
        "| rectangle metric \\ physics | success | failure |",
        "|---|---|---|",
        f"| correct | {t['metric_true']['success']} | {t['metric_true']['failure']} |",
        f"| wrong | {t['metric_false']['success']} | {t['metric_false']['failure']} |",
        "",
        "| failure reason | trials |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v} |" for k, v in s["failure_reasons"].items()]
    lines += ["", "| object | successes | trials |", "|---|---|---|"]
    lines += [f"| {k} | {v['successes']} | {v['n']} |" for k, v in s["per_object"].items()]
    return "\n".join(lines) + "\n"


def skipped_line(s: dict) -> str | None:
    """The summary line listing the scenes that could not be made.

    Parameters
    ----------
    s : dict
        A summary with ``skipped`` (each ``index`` and ``reason``).

    Returns
    -------
    str or None
        None when there is none.
    """
    skipped = s.get("skipped") or []
    if not skipped:
        return None
    shown = ", ".join(str(x["index"]) for x in skipped[:20])
    more = f" and {len(skipped) - 20} more" if len(skipped) > 20 else ""
    return (f"- skipped: {len(skipped)} scene(s) that could not be made (indices {shown}{more};"
            f" first reason: {skipped[0]['reason']}); the figures above leave them out")


def planning_line(p) -> str:
    """The summary line of the detector's planning times.

    Parameters
    ----------
    p : dict or None
        :func:`planning_stats` of the run (None or ``n == 0``: not recorded).

    Returns
    -------
    str
    """
    if not p or not p.get("n"):
        return "- detector planning time: not recorded"
    return (f"- detector planning time (predict): median {1000 * p['median']:.3g} ms, "
            f"95th percentile {1000 * p['p95']:.3g} ms (n = {p['n']})")


def execution_line(s: dict) -> str | None:
    """The summary line naming the execution parameters that differ from the defaults.

    Parameters
    ----------
    s : dict
        A summary with the run's ``execution`` parameters (as a dict).

    Returns
    -------
    str or None
        None when the run executed with the defaults or did not record its parameters.
    """
    if not isinstance(s.get("execution"), dict):
        return None
    changes = execution_changes(execution_params_from_dict(s["execution"], "summary"))
    if not changes:
        return None
    return f"- execution parameters other than the defaults: {describe_changes(changes)}"
