"""Clutter-removal rounds as VGN and GIGA run them, and the scene update they share with
``graspsim/Grasp-v0``'s declutter mode.

A round places ``K`` objects (``TrialConfig.n_objects``) and grasps repeatedly: observe, ask the
detector, execute its first rectangle. A lifted object is removed from the scene; objects the
grasp pushes off the table are removed too (they leave the table but do not count as
successes); the rest settle where the grasp left them and are observed again. A round ends when
the table is clear, when the detector proposes nothing (or its ``predict`` raises), or after
2 consecutive failed grasps -- the end conditions and the two figures of the clutter-removal
benchmark of VGN (Breyer et al., CoRL 2020, ``MAX_CONSECUTIVE_FAILURES = 2``) that GIGA
(Jiang et al., RSS 2021) reuses:

* grasp success rate = successful grasps / executed grasps, over all rounds;
* declutter rate ("percent cleared") = objects removed by successful grasps / objects placed,
  over all rounds (VGN sums over the rounds in which at least one grasp was executed; here every
  round counts, so a round whose first call proposes nothing lowers the rate).

Round ``i`` of a run with seed ``s`` starts from the same scene, observation and labels as
trial ``i`` of :func:`graspsim.eval.trials.run_trials` with the same ``n_objects`` (its first
attempt
is that trial); attempt ``a >= 1`` draws its camera, labels and detector seed from
``SeedSequence(s, spawn_key=(i, 3 + a))``, so a round depends only on ``(s, i)``.

Output folder: ``rounds.jsonl`` (one record per finished round, with its attempts; appended and
flushed, resumed per round like ``trials.jsonl``), ``config.json`` (``"mode": "declutter"``),
``summary.json`` and ``summary.md``.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..runtime.campaign import run_campaign, skipped_record
from ..sim.bullet import worker_sim
from ..sim.execution import ExecutionParams
from ..sim.observe import SceneError, made_again_if_unmade, observe_scene, profile_capture
from ..sim.scene import build_scene, scene_after_grasp
from .stats import bootstrap_ratio_interval, wilson_interval
from .summary import execution_line, planning_line, planning_stats, skipped_line
from .trials import (
    NO_PROPOSAL,
    TrialConfig,
    campaign_setup,
    describe_detector,
    execute_proposal,
    label_and_propose,
    upgrade_campaign_config,
)

__all__ = [
    "MAX_CONSECUTIVE_FAILURES",
    "CLEARED",
    "FAILURES",
    "run_round",
    "run_rounds",
    "summarize_rounds",
]

log = logging.getLogger(__name__)

MAX_CONSECUTIVE_FAILURES = 2
CLEARED = "table cleared"
FAILURES = f"{MAX_CONSECUTIVE_FAILURES} consecutive failures"
#: Five objects per round (VGN's clutter-removal default), 32 labelling candidates.
DEFAULT_CONFIG = TrialConfig(n_objects=5)
def _attempt_streams(seed: int, index: int, attempt: int) -> dict:
    ss = np.random.SeedSequence(seed, spawn_key=(index, 3 + attempt))
    camera_ss, label_ss, det_ss = ss.spawn(3)
    return {"camera": np.random.default_rng(camera_ss), "label": np.random.default_rng(label_ss),
            "detector_seed": int(det_ss.generate_state(1)[0])}


def run_round(sim, specs, detector, seed: int, index: int,
              config: TrialConfig = DEFAULT_CONFIG,
              params: ExecutionParams | None = None, name: str | None = None) -> dict:
    """One clutter-removal round (see the module docstring).

    Returns
    -------
    dict
        The JSON record: ``index``, ``seed``, ``objects`` (names placed), ``n_objects``,
        ``redraws``, ``attempts`` (one dict per executed grasp: ``attempt``, ``objects_left``
        before it, ``rectangle``, ``pose``, ``opening``, ``success``, ``reason``,
        ``lift_height``, ``grasped`` (the lifted object's name or None), ``fell_off`` (names),
        ``metric``, ``n_positives``, ``planning_seconds``, ``score`` when given), ``end`` (why
        the round ended: ``"table cleared"``, ``"no grasp proposed"``,
        ``"2 consecutive failures"`` or ``"detector error: ..."``), ``end_planning_seconds``
        (the last call when it ended the round, else None), ``successes``, ``removed`` (objects
        removed by successful grasps), ``fell_off`` (objects that left the table), ``left``,
        ``seconds``.

    Raises
    ------
    ValueError
        When the detector's return value breaks the protocol (the message names the round).
    """
    t0 = time.perf_counter()
    name = describe_detector(detector) if name is None else name
    scene, bodies, frame, st = observe_scene(sim, specs, seed, index, config.n_objects,
                                             config.profile, config.scene)
    placed = [o.spec.name for o in scene.objects]
    record = {"index": index, "seed": seed, "objects": placed, "n_objects": len(placed),
              "redraws": list(scene.redraws)}
    attempts: list[dict] = []
    failures, end, end_planning = 0, None, None
    while True:
        if not scene.objects:
            end = CLEARED
            break
        if failures >= MAX_CONSECUTIVE_FAILURES:
            end = FAILURES
            break
        a = len(attempts)
        if a > 0:
            st = _attempt_streams(seed, index, a)
            bodies = build_scene(sim, scene)
            frame = profile_capture(sim, scene, bodies, st["camera"], config.profile)
        positives, n_labelled, (rects, scores, error, planning), _ = label_and_propose(
            sim, scene, frame, bodies, st, detector, config, params, name,
            f"round {index} (seed {seed}), attempt {a}")
        if error is not None or not rects:
            end, end_planning = (error or NO_PROPOSAL), round(planning, 6)
            break
        fields, res, ran = execute_proposal(sim, scene, frame, rects, scores, None, positives,
        params)
        grasped = (scene.objects[res.object_index].spec.name
                   if res is not None and res.success else None)
        names = [o.spec.name for o in scene.objects]
        left_before = len(scene.objects)
        scene, fell = scene_after_grasp(sim, scene, ran, res)
        attempts.append({"attempt": a, "objects_left": left_before, **fields,
                         "grasped": grasped, "fell_off": [names[i] for i in fell],
                         "n_labelled": n_labelled,
                         "n_positives": None if positives is None else len(positives),
                         "planning_seconds": round(planning, 6)})
        failures = 0 if fields["success"] else failures + 1
    record.update(
        attempts=attempts, end=end, end_planning_seconds=end_planning,
        successes=sum(bool(t["success"]) for t in attempts),
        removed=sum(t["grasped"] is not None for t in attempts),
        fell_off=sum(len(t["fell_off"]) for t in attempts), left=len(scene.objects),
        seconds=round(time.perf_counter() - t0, 4),
    )
    return record


def _round_task(specs, detector, seed, index, config, params):
    try:
        return made_again_if_unmade(lambda: run_round(
            worker_sim(), specs, detector, seed, index, config, params))
    except SceneError as exc:
        return skipped_record(index, exc, seed=seed)


def run_rounds(detector="mask-pca", objects="test", n: int = 20, seed: int = 0, out=None,
               n_jobs: int = 1, config: TrialConfig = DEFAULT_CONFIG,
               params: ExecutionParams | None = None, progress: bool = False, executor=None,
               detector_name: str | None = None, detector_options=None) -> dict:
    """Run (or finish) ``n`` clutter-removal rounds of ``config.n_objects`` objects each.

    Parameters are those of :func:`graspsim.eval.trials.run_trials` (``n`` counts rounds); rounds
    run in parallel, the attempts of a round in sequence.

    Returns
    -------
    dict
        The summary (see :func:`summarize_rounds`), with ``records`` sorted by index.
    """
    det, specs, meta = campaign_setup(detector, detector_name, objects, n, seed, config,
                                      params, detector_options)
    if config.n_objects < 1:
        raise ValueError(f"objects per scene must be >= 1, got {config.n_objects}")
    meta["mode"] = "declutter"
    return run_campaign(_round_task, "rounds", meta, out, n,
                        lambda i: (specs, det, seed, i, config, params),
                        lambda records: summarize_rounds(records, random_state=seed),
                        rounds_markdown, executor=executor, n_jobs=n_jobs, progress=progress,
                        upgrade=upgrade_campaign_config)


def summarize_rounds(records: list[dict], random_state=None) -> dict:
    """Grasp success rate (Wilson 95 % and bootstrap over rounds), declutter rate (bootstrap
    over rounds), end reasons, failure reasons, planning time."""
    attempts = [t for r in records for t in r["attempts"]]
    n_att = len(attempts)
    k = sum(bool(t["success"]) for t in attempts)
    placed = sum(r["n_objects"] for r in records)
    removed = sum(r["removed"] for r in records)
    ss = np.random.SeedSequence(random_state)
    rng_s, rng_d = (np.random.default_rng(c) for c in ss.spawn(2))
    ends: dict[str, int] = {}
    for r in records:
        ends[r["end"]] = ends.get(r["end"], 0) + 1
    reasons: dict[str, int] = {}
    for t in attempts:
        if not t["success"]:
            reasons[t["reason"]] = reasons.get(t["reason"], 0) + 1
    verdicts = [t for t in attempts if t.get("metric") is not None]
    return {
        "rounds": len(records),
        "objects_placed": placed,
        "attempts": n_att,
        "successes": k,
        "success_rate": k / n_att if n_att else None,
        "success_ci95": list(wilson_interval(k, n_att)) if n_att else [None, None],
        "success_ci95_bootstrap": bootstrap_ratio_interval(
            [r["successes"] for r in records], [len(r["attempts"]) for r in records],
            random_state=rng_s),
        "removed": removed,
        "fell_off": sum(r["fell_off"] for r in records),
        "declutter_rate": removed / placed if placed else None,
        "declutter_ci95_bootstrap": bootstrap_ratio_interval(
            [r["removed"] for r in records], [r["n_objects"] for r in records],
            random_state=rng_d),
        "rounds_cleared": sum(r["left"] == 0 for r in records),
        "end_reasons": dict(sorted(ends.items(), key=lambda kv: -kv[1])),
        "failure_reasons": dict(sorted(reasons.items(), key=lambda kv: -kv[1])),
        "metric_n": len(verdicts),
        "metric_accuracy": (sum(bool(t["metric"]) for t in verdicts) / len(verdicts)
                            if verdicts else None),
        "planning_seconds": planning_stats(
            [t.get("planning_seconds") for t in attempts]
            + [r.get("end_planning_seconds") for r in records]),
        "seconds_per_round": (float(np.mean([r["seconds"] for r in records]))
                              if records else None),
    }


def rounds_markdown(s: dict) -> str:
    """The clutter-removal summary as a Markdown report."""
    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f} %"

    def ci(v):
        return "n/a" if v is None or v[0] is None else f"{pct(v[0])} - {pct(v[1])}"

    n_obj = (s.get("config") or {}).get("n_objects")
    lines = [
        f"# Clutter removal: detector `{s.get('detector')}` on `{s.get('objects')}` objects",
        "",
        f"- rounds: {s['rounds']} of {n_obj} objects (seed {s.get('seed')}; scene "
        f"{(s.get('config') or {}).get('scene', 'drop')}); a round ends when "
        f"the table is clear, nothing is proposed, or after {MAX_CONSECUTIVE_FAILURES} "
        "consecutive failures",
        f"- grasp success rate: {s['successes']}/{s['attempts']} = {pct(s['success_rate'])} "
        f"(Wilson 95 % {ci(s['success_ci95'])}; bootstrap over rounds "
        f"{ci(s['success_ci95_bootstrap'])})",
        f"- declutter rate: {s['removed']}/{s['objects_placed']} objects removed by successful "
        f"grasps = {pct(s['declutter_rate'])} (bootstrap over rounds "
        f"{ci(s['declutter_ci95_bootstrap'])}); {s['fell_off']} fell off the table (removed, "
        "not counted as successes); "
        f"{s['rounds_cleared']} of {s['rounds']} rounds ended with an empty table",
        f"- rectangle-metric accuracy of the executed grasps: {pct(s['metric_accuracy'])} "
        f"(n = {s['metric_n']})",
        planning_line(s.get("planning_seconds")),
        *filter(None, [execution_line(s), skipped_line(s)]),
        "",
        "| round ended by | rounds |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v} |" for k, v in s["end_reasons"].items()]
    lines += ["", "| failure reason | grasps |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in s["failure_reasons"].items()]
    return "\n".join(lines) + "\n"
