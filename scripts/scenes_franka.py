"""Issue 36, part 6: DLSR, dlsr-paper, mask-pca and the oracle in the peers' protocols.

Three rows, each on the built-in test objects, every detector on the same seeded scenes:

* ``pile``: clutter-removal rounds of 5 objects in a pile (``--scene pile --declutter``);
* ``packed``: clutter-removal rounds of 5 objects packed (``--scene packed --declutter``);
* ``franka``: single-object trials (the default drop scene) with the Franka hand
  (``--gripper franka``).

DLSR is the default job's model (``graspsim run`` with the defaults writes it to
``model/dlsr``, and ``model/dlsr-paper`` for the paper's configuration): it is trained here by
:func:`graspsim.pipeline.run_job` with the default configuration
(:mod:`graspsim.pipeline.campaigns`), without the offline
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

from graspsim.eval.comparison_grid import pick
from graspsim.pipeline.campaigns import DETECTORS, PEER_ROWS, peer_protocol_campaign


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rows", default=",".join(PEER_ROWS))
    ap.add_argument("--detectors", default=",".join(DETECTORS),
                    help="run only these (the model is trained only for dlsr, dlsr-paper)")
    ap.add_argument("--steps", type=int, default=None,
                    help="growth steps to run (default: all, up to 200 trials and rounds)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        rows = pick(args.rows, PEER_ROWS, "rows")
        dets = pick(args.detectors, DETECTORS, "detectors")
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    peer_protocol_campaign(args.out, rows, dets, args.jobs, args.steps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
