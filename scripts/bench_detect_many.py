"""Table 2's per-image scoring: every row's model scoring the same rectangle images, each on its
own, against :func:`dlsr.detection.dense.score_images_many` (the patches whitened once for the
models that whiten alike). One JSON object on stdout.

The four rows of Table 2 (NKM-Natural, NKM-SC, OMP-Natural, RP-Natural) are trained together
(:func:`dlsr.detection.train_detectors`, 300 atoms, 100,000 patches, as the benchmark) on the
first ``--train`` images of a Cornell-format folder; on the next ``--test`` images, the lattice
detector's candidates and rectangle images are made once, then, in the same run and process,
one after the other per image:

* **alone**: each model's :meth:`dlsr.detection.DenseDetector.score_images` (what
  :func:`dlsr.detection.detect_many` did until now);
* **shared**: one :func:`~dlsr.detection.dense.score_images_many` for the four.

Per variant, the process CPU seconds per image (``time.process_time``, the threads included:
the detectors use the machine's cores) and the wall seconds; ``ratio`` is alone / shared;
``identical`` whether every score is the same, bit for bit.

Usage: python scripts/bench_detect_many.py --data /work/standin_full/cornell [--train 40]
       [--test 10] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dlsr.detection import sample_observation, train_detectors
from dlsr.detection.dense import DenseDetector, score_images_many
from graspsim.data.samples import load_samples
from graspsim.data.standin import standin_subset

ROWS = (("NKM", "Natural"), ("NKM", "SC"), ("OMP", "Natural"), ("RP", "Natural"))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="Cornell-format folder (e.g. the stand-in)")
    ap.add_argument("--train", type=int, default=40)
    ap.add_argument("--test", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", default="runs/bench_detect_many")
    args = ap.parse_args(argv)
    data = standin_subset(args.data, f"{args.cache}/data_{args.train + args.test}",
                          args.train + args.test)
    samples = [s for s in load_samples(data, "cornell") if s.positives]
    train, test = samples[:args.train], samples[args.train:args.train + args.test]
    t0 = time.perf_counter()
    models = train_detectors(train, [{"learner": lr, "encoder": e} for lr, e in ROWS],
                             random_state=args.seed, n_atoms=300, n_patches=100_000,
                             grid_negatives=1.0, region="auto")
    train_s = time.perf_counter() - t0
    lattice = models[0].detector("lattice")
    cpu = {"alone": 0.0, "shared": 0.0}
    wall = {"alone": 0.0, "shared": 0.0}
    same, n_rects = True, 0
    for s in test:
        obs = sample_observation(s)
        cand, reason, _ = lattice.candidates(obs)
        if reason:
            continue
        images = DenseDetector(models[0]).exact_images(obs, cand)
        n_rects += len(cand)
        c, w = time.process_time(), time.perf_counter()
        alone = [DenseDetector(m).score_images(images) for m in models]
        cpu["alone"] += time.process_time() - c
        wall["alone"] += time.perf_counter() - w
        c, w = time.process_time(), time.perf_counter()
        shared, _ = score_images_many([DenseDetector(m) for m in models], images)
        cpu["shared"] += time.process_time() - c
        wall["shared"] += time.perf_counter() - w
        same &= all(np.array_equal(a, b) for a, b in zip(alone, shared, strict=True))
    n = max(len(test), 1)
    out = {"train_images": len(train), "test_images": len(test), "rectangles": n_rects,
           "train_s": round(train_s, 1),
           **{f"{k}_cpu_s_per_image": round(v / n, 3) for k, v in cpu.items()},
           **{f"{k}_wall_s_per_image": round(v / n, 3) for k, v in wall.items()},
           "ratio": round(cpu["alone"] / max(cpu["shared"], 1e-9), 3),
           "identical": bool(same)}
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
