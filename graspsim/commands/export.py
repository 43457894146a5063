"""``graspsim export``: a dataset's copy for the CNN peers' own Cornell loaders."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="copy a dataset for the GG-CNN / GR-ConvNet Cornell loaders (images with a "
             "positive, inpainted depth)",
        description="Write a copy of a `graspsim dataset` (or any Cornell-layout) folder that "
                    "the published Cornell loaders of GG-CNN and GR-ConvNet read unchanged: "
                    "only images with at least one positive rectangle (the others are logged "
                    "and listed in export.json), depth in float32 metres with missing pixels "
                    "inpainted as their generate_cornell_depth.py does (OpenCV Navier-Stokes), "
                    "the RGB, rectangle and camera files, the same image numbers. The source "
                    "folder is not changed (docs/guides/data-formats.md).",
    )
    p.add_argument("--data", required=True,
                   help="dataset folder written by `graspsim dataset` (or real Cornell)")
    p.add_argument("--out", required=True, help="export folder (a new one)")
    p.add_argument("--keep-empty", action="store_true",
                   help="also write images without a positive rectangle (default: left out; "
                        "real Cornell has none and the peers' loaders fail on them)")
    p.add_argument("--no-inpaint", dest="inpaint", action="store_false",
                   help="keep 0 where depth is missing (default: inpainted as the peers' "
                        "preprocessing)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from graspsim.data.export import export_cornell

    s = export_cornell(args.data, args.out, keep_empty=args.keep_empty, inpaint=args.inpaint)
    left = (f"; {len(s['skipped'])} left out ("
            + ", ".join(f"{x['image']}: {x['reason']}" for x in s["skipped"][:5])
            + (", ..." if len(s["skipped"]) > 5 else "") + ")") if s["skipped"] else ""
    print(f"exported {len(s['images'])} images ({s['positives']} positives, "
          f"{s['negatives']} negatives) to {args.out}{left}; record {s['path']}")
    return 0
