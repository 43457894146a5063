"""Pictures of one simulated grasp trial: docs/trial_strip.png and docs/trial.gif.

The oracle's rectangle (the best physics-labelled positive) on a seeded test-object scene,
seen as observed, then pre-grasp, approach, close, lift and hold from the side.

    .venv/bin/python scripts/trial_picture.py [--seed 0] [--object can_tall] [--out docs]
"""

from __future__ import annotations

import argparse

from graspsim.eval.trialviz import save_gif, save_strip, trial_frames
from graspsim.labels.labelling import label_rectangles, rank_positives, sample_candidates
from graspsim.sim.bullet import Simulation
from graspsim.sim.objects import builtin_objects
from graspsim.sim.observe import observe_scene


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--object", default="mug_espresso", help="a built-in object name")
    p.add_argument("--out", default="docs")
    args = p.parse_args(argv)
    specs = [s for s in builtin_objects("all") if s.name == args.object]
    if not specs:
        raise SystemExit(f"unknown object {args.object!r}")
    sim = Simulation()
    for i in range(20):
        scene, bodies, frame, st = observe_scene(sim, specs, args.seed, i)
        cands = sample_candidates(frame.segmentation, bodies.objects, st["label"], 32,
                                  depth=frame.depth_clean)
        positives = rank_positives(label_rectangles(sim, scene, frame, cands))
        if positives:
            break
    else:
        raise SystemExit("no positive found")
    frames, result = trial_frames(sim, scene, frame, positives[0])
    print(f"trial {i}: {args.object} success={result.success} reason={result.reason} "
          f"lift={result.lift_height:.3f} m")
    print(save_strip(frames, f"{args.out}/trial_strip.png"))
    print(save_gif(frames, f"{args.out}/trial.gif"))
    sim.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
