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
import logging
from pathlib import Path

from graspsim.eval.comparison_grid import Row, grow, pick

ROWS = {"pile": Row("pile", scene="pile"), "packed": Row("packed", scene="packed"),
        "franka": Row("franka", hand="franka")}
DETECTORS = ("dlsr", "dlsr-paper", "mask-pca", "oracle")
CANDIDATES = 32  # labels per observation for the oracle (the default job's trial_candidates)


def model(out: Path, jobs: int) -> tuple[Path, object]:
    """Train (or find) the default job's models; returns the DLSR model path and the config."""
    from graspsim.pipeline import RunConfig, run_job

    cfg = RunConfig(offline=False, trials=1, baselines=[], jobs=jobs)
    root = out / "model-run"
    run_job(cfg, out=root, progress=False)
    return root / "model" / "dlsr", cfg


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rows", default=",".join(ROWS))
    ap.add_argument("--detectors", default=",".join(DETECTORS),
                    help="run only these (the model is trained only for dlsr, dlsr-paper)")
    ap.add_argument("--steps", type=int, default=None,
                    help="growth steps to run (default: all, up to 200 trials and rounds)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        rows = pick(args.rows, ROWS, "rows")
        dets = pick(args.detectors, DETECTORS, "detectors")
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    from graspsim.pipeline import trial_detector
    from graspsim.runtime.executor import Executor

    args.out.mkdir(parents=True, exist_ok=True)
    model_path, cfg = (model(args.out, args.jobs) if {"dlsr", "dlsr-paper"} & set(dets)
                       else (None, None))
    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=False)
    grow([ROWS[r] for r in rows], dets,
         lambda name, row: trial_detector(name, model_path, cfg, hand=row.hand),
         args.out, executor=ex, steps=args.steps, candidates=CANDIDATES)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
