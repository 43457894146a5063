"""Replay a trial folder's rectangles and print what the object and the pads do in each phase.

One JSON line per trial (:mod:`graspsim.eval.inspection` says what it records):

    .venv/bin/python scripts/inspect_grasps.py runs/default/trials/mask-pca \\
        --objects chopstick [--tip-clearance 0.001] [--out chopstick.jsonl]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from graspsim.eval.inspection import inspect_folder


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="a trial folder (config.json, trials.jsonl)")
    p.add_argument("--objects", default=None, help="only scenes of these objects (comma list)")
    p.add_argument("--tip-clearance", type=float, default=None, help="metres")
    p.add_argument("--out", type=Path, default=None, help="write the JSON lines here too")
    args = p.parse_args(argv)
    objects = None if args.objects is None else args.objects.split(",")
    out = open(args.out, "w") if args.out is not None else None  # noqa: SIM115
    try:
        rows = inspect_folder(args.folder, objects, args.tip_clearance)
        for row in rows:
            line = json.dumps(row)
            print(line)
            if out is not None:
                out.write(line + "\n")
                out.flush()
    except FileNotFoundError as exc:
        p.error(str(exc))
    finally:
        if out is not None:
            out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
