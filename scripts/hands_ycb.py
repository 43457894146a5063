"""Issue 53, item 3: one detector, every hand, the same scenes (YCB test objects by default).

Rows (:mod:`graspsim.eval.comparison_grid`): single-object trials with each of the four hands
(``builtin``, ``franka``, ``wsg50``, ``robotiq-2f85``), and pile and packed clutter-removal
rounds of 5 objects with the Franka and the Robotiq hands. Columns: DLSR and ``dlsr-paper``,
GG-CNN (gripper-aware) and mask-pca and the oracle, every detector on the same seeded scenes.

The learned detectors are the data-efficiency curve's models at 300 training scenes
(``results/ggcnn-curve/models``: DLSR, the paper's DLSR and GG-CNN at the budget its
validation chose, all trained on the same 300 scenes of the built-in train objects); nothing
is chosen on these scenes. DLSR and GG-CNN are made aware of each row's hand
(:func:`graspsim.detectors.gripper_aware`), as in the curve; the paper's DLSR runs its dense
search as the paper does. ``dlsr-hand`` is DLSR with the training data chosen for the row's
hand on validation scenes of the YCB train objects (``scripts/hands_dlsr_choice.py``,
``results/hand-choice``); it is not a default column: add it with ``--detectors`` for rows
whose hand has a choice (the WSG 50's choice is the curve's model, the ``dlsr`` column itself).

The cells grow in steps (25, 50, 100, 150, 200 trials; 6 ... 200 rounds), so whatever has
finished when the script is stopped covers every cell; a rerun resumes. ``OUT/results.json``
and ``OUT/results.md`` are rewritten after each step; commit ``OUT`` as it goes.

Usage::

    nice -n 10 python scripts/hands_ycb.py [--objects ycb:test] [--out results/hands-ycb]
        [--rows builtin,franka,...] [--jobs 2]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from graspsim.eval.comparison_grid import Row, grow, pick

REPO = Path(__file__).resolve().parents[1]
CURVE = REPO / "results" / "ggcnn-curve"
HANDS = ("builtin", "franka", "wsg50", "robotiq-2f85")
CLUTTER = tuple(f"{scene}-{hand}" for hand in ("franka", "robotiq-2f85")
                for scene in ("pile", "packed"))
DETECTORS = ("dlsr", "dlsr-paper", "ggcnn+aware", "mask-pca", "oracle")
CHOICE = REPO / "results" / "hand-choice"
SIZE = 300  # the curve's training scenes


def rows(objects: str) -> dict[str, Row]:
    out = {h: Row(h, objects=objects, hand=h) for h in HANDS}
    for name in CLUTTER:
        scene, hand = name.split("-", 1)
        out[name] = Row(name, objects=objects, hand=hand, scene=scene)
    return out


def ggcnn_model(curve: Path = CURVE, size: int = SIZE) -> Path:
    """The curve's GG-CNN at ``size`` scenes, at the budget its validation chose (the most
    validation successes, ties to the smaller budget, as the curve chose it)."""
    from dlsr.records import read_json
    from graspsim.detectors.ggcnn.model import budget_path
    from graspsim.eval.data_efficiency import chosen_budget

    result = read_json(curve / "curve.json", "data-efficiency curve")
    val = result["validation"][str(size)]
    budgets = sorted(int(b) for b in val)
    return budget_path(curve / "models" / f"ggcnn_{size}", chosen_budget(val, budgets),
                       budgets[-1])


def make_detector(name: str, row: Row, curve: Path = CURVE):
    from dlsr.detection import DLSRDetector
    from graspsim.detectors import gripper_aware, load_detector

    if name == "dlsr":
        det = DLSRDetector.load(curve / "models" / f"dlsr_{SIZE}").detector("lattice")
        return gripper_aware(det, hand=row.hand)
    if name == "dlsr-hand":
        from graspsim.eval.hand_choice import chosen_detector

        return chosen_detector(CHOICE, row.hand)
    if name == "dlsr-paper":
        return DLSRDetector.load(curve / "models" / f"dlsr-paper_{SIZE}").detector("dense")
    if name == "ggcnn+aware":
        from graspsim.detectors.ggcnn.detector import GGCNNDetector

        return gripper_aware(GGCNNDetector(ggcnn_model(curve)), hand=row.hand)
    return load_detector(name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default="ycb:test")
    ap.add_argument("--out", type=Path, default=REPO / "results" / "hands-ycb")
    ap.add_argument("--rows", default=",".join(HANDS + CLUTTER))
    ap.add_argument("--detectors", default=",".join(DETECTORS))
    ap.add_argument("--steps", type=int, default=None,
                    help="growth steps to run (default: all, up to 200 trials and rounds)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    table = rows(args.objects)
    try:
        names = pick(args.rows, table, "rows")
        dets = pick(args.detectors, DETECTORS + ("dlsr-hand",), "detectors")
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    from graspsim.runtime.executor import Executor

    ex = Executor(backend="loky" if args.jobs != 1 else "sequential", n_jobs=args.jobs,
                  progress=False)
    grow([table[n] for n in names], dets, make_detector, args.out, executor=ex,
         report=list(table.values()),
         steps=args.steps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
