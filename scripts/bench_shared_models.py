"""The four models of a Table 2 fold sharing their whitened patches, against each model on its
own. One JSON object on stdout.

The four rows of Table 2 (NKM-Natural, NKM-SC, OMP-Natural, RP-Natural) are trained together
(:func:`dlsr.detection.train_detectors`, 300 atoms, 100,000 patches, as the benchmark) on the
first ``--train`` images of a Cornell-format folder. Then, in the same run and process, one
after the other:

* **training features** (``features``): the features of the fold's training rectangles, each
  model's :func:`dlsr.features.rectangle_features` (what :func:`~dlsr.detection.
  train_detectors` did until now) against one :func:`dlsr.features.rectangle_features_many`;
* **test scoring** (``scoring``): on the next ``--test`` images, the lattice detector's
  candidates and rectangle images made once, then each model's
  :meth:`dlsr.detection.DenseDetector.score_images` (what :func:`dlsr.detection.detect_many`
  did until now) against one :func:`dlsr.detection.dense.score_images_many`.

Per part and variant, the process CPU seconds (``time.process_time``, the threads included:
the detectors use the machine's cores; per image for the scoring) and the wall seconds;
``ratio`` is alone / shared in CPU seconds; ``identical`` whether every feature and score is
the same, bit for bit.

Usage: python scripts/bench_shared_models.py --data /work/standin_full/cornell [--train 40]
       [--test 10] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dlsr.detection import sample_observation, train_detectors
from dlsr.detection.dense import DenseDetector, score_images_many
from dlsr.features import rectangle_features, rectangle_features_many
from graspsim.data.samples import load_samples
from graspsim.data.standin import standin_subset

ROWS = (("NKM", "Natural"), ("NKM", "SC"), ("OMP", "Natural"), ("RP", "Natural"))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="Cornell-format folder (e.g. the stand-in)")
    ap.add_argument("--train", type=int, default=40)
    ap.add_argument("--test", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", default="runs/bench_shared_models")
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
    # the training features: the rectangles of train_detectors (the same seed and options)
    from dlsr.detection.training import detection_training_data

    data = detection_training_data(train, 1.0, random_state=args.seed)
    jobs = [(m.representation, m.encoder, m.encoder_param, m.polarity) for m in models]
    c, w = time.process_time(), time.perf_counter()
    alone_f = [rectangle_features(data.images, data.masks, *job[:3], polarity=job[3])
               for job in jobs]
    features = {"alone_cpu_s": time.process_time() - c, "alone_wall_s": time.perf_counter() - w}
    c, w = time.process_time(), time.perf_counter()
    many_f = rectangle_features_many(data.images, data.masks, jobs)
    features.update(shared_cpu_s=time.process_time() - c, shared_wall_s=time.perf_counter() - w)
    features = {k: round(v, 2) for k, v in features.items()}
    features.update(rectangles=len(data.labels),
                    ratio=round(features["alone_cpu_s"] / max(features["shared_cpu_s"], 1e-9), 3),
                    identical=all(np.array_equal(a, b)
                                  for a, b in zip(alone_f, many_f, strict=True)))
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
    out = {"train_images": len(train), "test_images": len(test), "train_s": round(train_s, 1),
           "features": features,
           "scoring": {"rectangles": n_rects,
                       **{f"{k}_cpu_s_per_image": round(v / n, 3) for k, v in cpu.items()},
                       **{f"{k}_wall_s_per_image": round(v / n, 3) for k, v in wall.items()},
                       "ratio": round(cpu["alone"] / max(cpu["shared"], 1e-9), 3),
                       "identical": bool(same)}}
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
