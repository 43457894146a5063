"""Issue 36, part 6: DLSR, dlsr-paper, mask-pca and the oracle in the peers' protocols.

Three rows, each on the built-in test objects, every detector on the same seeded scenes:

* ``pile``: clutter-removal rounds of 5 objects in a pile (``--scene pile --declutter``);
* ``packed``: clutter-removal rounds of 5 objects packed (``--scene packed --declutter``);
* ``franka``: single-object trials (the default drop scene) with the Franka hand
  (``--gripper franka``).

DLSR is the default job's model (``graspsim run`` with the defaults writes it to
``model/dlsr``, and ``model/dlsr-paper`` for the paper's configuration): it is trained here by
:func:`graspsim.pipeline.run_job` with the default configuration, without the offline
benchmarks (which do not change the model) and with one trial per detector, in
``OUT/model-run``. Nothing is chosen on these scenes.

The campaigns grow in steps (every cell to 25 trials or 6 rounds, then 50 / 12, ...) so that
whatever has finished when the script is stopped covers every cell; a rerun resumes every
campaign where it stopped. After each step ``OUT/results.json`` and ``OUT/results.md`` are
written: success with Wilson 95 % intervals, declutter rate with a bootstrap interval over
rounds, and the paired verdict of each detector against mask-pca (exact McNemar on the paired
trials, or on the rounds' first grasps, which are paired scenes; a sign test on the objects
each round removed).

Usage::

    nice -n 10 python scripts/scenes_franka.py --out /work/runs/i36b/scenes-franka --jobs 2
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

ROWS = ("pile", "packed", "franka")
DETECTORS = ("dlsr", "dlsr-paper", "mask-pca", "oracle")
TRIAL_STEPS = (25, 50, 100, 150, 200)
ROUND_STEPS = (6, 12, 25, 50, 100, 200)
N_OBJECTS = 5
CANDIDATES = 32  # labels per observation for the oracle (the default job's trial_candidates)

log = logging.getLogger("scenes_franka")


def model(out: Path, jobs: int) -> tuple[Path, object]:
    """Train (or find) the default job's models; returns the DLSR model path and the config."""
    from graspsim.pipeline import RunConfig, run_job

    cfg = RunConfig(offline=False, trials=1, baselines=[], jobs=jobs)
    root = out / "model-run"
    run_job(cfg, out=root, progress=False)
    return root / "model" / "dlsr", cfg


def detector(name: str, model_path: Path, cfg, hand: str):
    from graspsim.pipeline import _trial_detector

    return _trial_detector(name, model_path, cfg, hand=hand)


def run_cell(row: str, name: str, n: int, out: Path, model_path: Path, cfg, executor) -> dict:
    from graspsim.declutter import run_rounds
    from graspsim.execution import ExecutionParams
    from graspsim.trials import TrialConfig, run_trials

    hand = "franka" if row == "franka" else "builtin"
    det = detector(name, model_path, cfg, hand)
    # Labels only where they are needed: the oracle proposes from them (the others' scenes,
    # camera and detector seeds do not depend on it).
    k = CANDIDATES if name == "oracle" else 0
    params = ExecutionParams.with_hand(hand)
    folder = out / row / name
    if row == "franka":
        s = run_trials(det, objects="test", n=n, seed=0, out=folder,
                       config=TrialConfig(n_candidates=k), params=params, executor=executor,
                       detector_name=name)
    else:
        s = run_rounds(det, objects="test", n=n, seed=0, out=folder,
                       config=TrialConfig(n_candidates=k, n_objects=N_OBJECTS, scene=row),
                       params=params, executor=executor, detector_name=name)
    s.pop("records", None)
    return s


def _records(folder: Path, unit: str) -> dict[int, dict]:
    from dlsr.records import read_jsonl

    path = folder / f"{unit}.jsonl"
    if not path.exists():
        return {}
    out = {}
    for r in read_jsonl(path):
        out.setdefault(int(r["index"]), r)
    return out


def row_results(out: Path, row: str) -> dict:
    """Every detector's figures in ``row`` and its paired verdict against mask-pca, on the
    trials or rounds all four detectors finished."""
    from graspsim.compare import compare_outcomes, first_grasp, removed_sign_test
    from graspsim.declutter import summarize_rounds
    from graspsim.trials import summarize, wilson_interval

    unit = "trials" if row == "franka" else "rounds"
    recs = {d: _records(out / row / d, unit) for d in DETECTORS}
    shared = sorted(set.intersection(*(set(r) for r in recs.values()))) if recs else []
    res: dict = {"unit": unit, "n": len(shared), "cells": {}}
    if not shared:
        return res
    for d in DETECTORS:
        rs = [recs[d][i] for i in shared]
        if unit == "trials":
            s = summarize(rs)
            cell = {"successes": s["successes"], "n": s["n"], "success_rate": s["success_rate"],
                    "success_ci95": s["success_ci95"]}
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
    base = [recs["mask-pca"][i] for i in shared]
    for d in DETECTORS:
        if d == "mask-pca":
            continue
        rs = [recs[d][i] for i in shared]
        if unit == "trials":
            c = compare_outcomes([r["success"] for r in rs], [r["success"] for r in base],
                                 names=(d, "mask-pca"))
            res["cells"][d]["vs_mask_pca"] = {"p": c["mcnemar_p"], "better": c["better"],
                                              "verdict": c["verdict"]}
        else:
            c = compare_outcomes([first_grasp(r) for r in rs], [first_grasp(r) for r in base],
                                 names=(d, "mask-pca"), unit="first grasps")
            t = removed_sign_test([r["removed"] for r in rs], [b["removed"] for b in base])
            res["cells"][d]["vs_mask_pca"] = {
                "p": c["mcnemar_p"], "better": c["better"], "verdict": c["verdict"],
                "removed_more": t["more"], "removed_fewer": t["fewer"],
                "sign_test_p": t["sign_test_p"]}
    return res


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _ci(v) -> str:
    return "n/a" if v is None or v[0] is None else f"{100 * v[0]:.0f}-{100 * v[1]:.0f}"


def markdown(results: dict) -> str:
    lines = []
    for row, res in results.items():
        if not res.get("n"):
            lines += [f"## {row}", "", "no finished cell yet", ""]
            continue
        lines += [f"## {row} ({res['n']} paired {res['unit']})", ""]
        if res["unit"] == "trials":
            lines += ["| detector | success | 95 % CI | vs mask-pca (exact McNemar) |",
                      "|---|---|---|---|"]
            for d, c in res["cells"].items():
                v = c.get("vs_mask_pca")
                lines.append(f"| {d} | {c['successes']}/{c['n']} = {_pct(c['success_rate'])} | "
                             f"{_ci(c['success_ci95'])} % | "
                             + ("-" if v is None else _verdict(v)) + " |")
        else:
            lines += ["| detector | grasp success | 95 % CI | declutter rate | 95 % CI "
                      "(bootstrap) | first grasp | vs mask-pca: first grasp (McNemar); "
                      "objects removed (sign test) |",
                      "|---|---|---|---|---|---|---|"]
            for d, c in res["cells"].items():
                v = c.get("vs_mask_pca")
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


def _verdict(v: dict) -> str:
    word = {"a": "better", "b": "worse", None: "not separated"}[v["better"]]
    return f"{word} (p = {v['p']:.2g})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rows", default=",".join(ROWS))
    ap.add_argument("--detectors", default=",".join(DETECTORS),
                    help="run only these (the model is trained only for dlsr, dlsr-paper)")
    ap.add_argument("--steps", type=int, default=len(TRIAL_STEPS) + 1,
                    help="growth steps to run (default: all, up to 200 trials and rounds)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    rows = [r.strip() for r in args.rows.split(",") if r.strip()]
    dets = [d.strip() for d in args.detectors.split(",") if d.strip()]
    for given, known, what in ((rows, ROWS, "rows"), (dets, DETECTORS, "detectors")):
        unknown = sorted(set(given) - set(known))
        if unknown:
            raise SystemExit(f"unknown {what} {', '.join(unknown)}; choose from "
                             f"{', '.join(known)}")
    from graspsim.executor import Executor

    args.out.mkdir(parents=True, exist_ok=True)
    model_path, cfg = (model(args.out, args.jobs) if {"dlsr", "dlsr-paper"} & set(dets)
                       else (None, None))
    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=False)
    for step in range(min(args.steps, max(len(TRIAL_STEPS), len(ROUND_STEPS)))):
        for row in rows:
            steps = TRIAL_STEPS if row == "franka" else ROUND_STEPS
            n = steps[min(step, len(steps) - 1)]
            for name in dets:
                s = run_cell(row, name, n, args.out, model_path, cfg, ex)
                log.info("%s %s n=%d: %s", row, name, n,
                         {k: s.get(k) for k in ("success_rate", "declutter_rate")})
            results = {r: row_results(args.out, r) for r in rows}
            (args.out / "results.json").write_text(json.dumps(results, indent=1))
            (args.out / "results.md").write_text(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
