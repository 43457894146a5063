"""Issue 53, item 4: DLSR's training data per hand, chosen on validation scenes of the YCB train
objects (:mod:`graspsim.eval.hand_choice`); the hands table's ``dlsr-hand`` column runs the choice.

Candidates per hand: the data-efficiency curve's model (300 scenes of the built-in train
objects, built-in hand; the table's ``dlsr`` column), and DLSR trained on 300 scenes of the YCB
train objects labelled with the built-in hand or with the hand itself. Each runs 100
validation trials of the YCB train objects with the hand, beside mask-pca; the most successes
win, ties to the less specialised. Resumable; commit ``OUT`` as it goes.

Usage, from the repository's root (the folders are recorded as given)::

    nice -n 10 python scripts/hands_dlsr_choice.py [--out results/hand-choice]
        [--hands builtin,franka,wsg50,robotiq-2f85] [--n-train 300] [--n-val 100] [--jobs 2]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from graspsim.eval.comparison_grid import pick
from graspsim.eval.hand_choice import choose_per_hand
from graspsim.sim.hands import HAND_NAMES

CURVE_MODEL = Path("results") / "ggcnn-curve" / "models" / "dlsr_300"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default="ycb:train",
                    help="the train objects (default %(default)s)")
    ap.add_argument("--out", type=Path, default=Path("results") / "hand-choice")
    ap.add_argument("--hands", default=",".join(HAND_NAMES))
    ap.add_argument("--n-train", type=int, default=300)
    ap.add_argument("--n-val", type=int, default=100)
    ap.add_argument("--curve-model", type=Path, default=CURVE_MODEL,
                    help="the 'curve' candidate (default %(default)s)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        hands = pick(args.hands, HAND_NAMES, "hands")
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    from graspsim.runtime.executor import Executor

    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=False)
    choose_per_hand(args.out, hands, args.curve_model, objects=args.objects,
                    n_train=args.n_train, n_val=args.n_val, executor=ex)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
