"""Object-wise validation of a `graspsim run` configuration on the train objects; prints JSON.

The train objects are split into object folds; for each fold the whole job runs with the other
folds' objects as its train objects and the fold's as its trial objects, so every detector is
tried on objects the model never saw, without touching the test objects. The trials are pooled
over the folds and DLSR is compared with each other detector scene by scene (exact McNemar).
Use it to choose settings: validate two configurations with the same --folds and --fold-seed
and compare them with `graspsim compare A B` (their DLSR trials pooled over the folds, paired
scene by scene). The fold runs skip the offline benchmarks (recognition and detection CV) unless
--offline is given.

    .venv/bin/python scripts/objectwise_validation.py [--config configs/x.toml] [--quick] \\
        [--folds 3] [--fold-seed 0] [--out runs/default-objectwise] [--offline]

Runs resume: the same command continues an interrupted validation. Written: the fold runs,
objectwise.json and objectwise.md in the output folder.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from graspsim.cli import sigterm_unwinds, stop_reason
from graspsim.pipeline import load_config, objectwise_validation


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=None, help="TOML or YAML run configuration")
    p.add_argument("--quick", action="store_true", help="the two-minute run's settings")
    p.add_argument("--folds", type=int, default=3, help="object folds (default 3)")
    p.add_argument("--fold-seed", type=int, default=0, help="seed of the split (default 0)")
    p.add_argument("--out", default=None, help="output folder (default "
                   "runs/<name>-objectwise)")
    p.add_argument("--offline", action="store_true", help="also run each fold's offline "
                   "benchmarks (recognition and detection CV; not used by the validation)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        config = load_config(args.config, quick=args.quick)
        with sigterm_unwinds():  # kill / scancel stop the workers too, as Ctrl-C does
            result = objectwise_validation(config, n_folds=args.folds,
                                           fold_seed=args.fold_seed, out=args.out,
                                           progress=sys.stderr.isatty(),
                                           offline=args.offline)
    except (ValueError, FileNotFoundError) as exc:
        print(f"objectwise_validation: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        word, code = stop_reason(exc)
        print(f"objectwise_validation: {word}; the same command continues", file=sys.stderr)
        return code
    keep = ("successes", "n", "success_rate", "success_ci95", "graspable_success_rate")
    print(json.dumps({
        "folder": result["folder"],
        "folds": [f["objects"] for f in result["folds"]],
        "detectors": {k: {x: v[x] for x in keep} for k, v in result["detectors"].items()},
        "comparisons": [{k: c[k] for k in ("a", "b", "counts", "difference", "difference_ci",
                                            "mcnemar_p", "verdict")}
                        for c in result["comparisons"]],
    }, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
