"""``graspsim detect``: the best grasp rectangles of one RGB-D image with a trained model."""

from __future__ import annotations

import argparse
import json

from graspsim.detectors.dlsr_options import add_detector_arguments


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "detect", help="detect grasps in one RGB-D image with a trained DLSR model",
        description="Detect grasps in one RGB-D image. stdout is one JSON object (rectangles "
                    "best first, scores, candidates, seconds, reason), so `graspsim detect ... "
                    "> result.json` keeps it; progress and errors go to stderr. Exit code 0 "
                    "with detections, 1 without (the reason says why), 2 on bad input.",
    )
    p.add_argument("--model", required=True,
                   help="saved model (PATH.npz + PATH.json, e.g. from benchmark --save-model)")
    p.add_argument("--rgb", required=True, help="colour image")
    p.add_argument("--depth", required=True,
                   help="depth image: float TIFF in metres (or .npy), <= 0 means missing; or a "
                        "Cornell point cloud pcdXXXX.txt in any frame (its camera is fitted)")
    p.add_argument("--depth-units", type=float, default=1.0,
                   help="multiplies the depth values to give metres (0.001 for millimetres)"
                        " (default: %(default)s)")
    p.add_argument("--mask", default=None, help="object mask image (non-zero = object)")
    p.add_argument("--background", default=None,
                   help="background image: object region by background subtraction")
    add_detector_arguments(p)
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                     default=None, help="camera intrinsics in pixels (needed by a model "
                     "trained with physical features and by the gripper-aware check; found "
                     "by itself for Cornell files pcdXXXXr.png: fitted to pcdXXXX.txt)")
    cam.add_argument("--camera", default=None, metavar="JSON",
                     help="camera file with the matrix K (graspsim datasets' "
                          "pcdXXXXcamera.json)")
    p.add_argument("--coarse-to-fine", action="store_true")
    p.add_argument("--top-k", type=int, default=5,
                   help="rectangles detected, best first (default: %(default)s)")
    p.add_argument("--out", default=None, help="overlay PNG (best in red/blue, others in "
                   "yellow/grey)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from dlsr.detection import detect_files
    from graspsim.detectors.dlsr_options import build_real_detector, options_from_args

    opts = options_from_args(args)
    K = args.camera
    if args.intrinsics is not None:
        fx, fy, cx, cy = args.intrinsics
        K = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]

    def build(model, top_k, background, obs):
        if opts.gripper_aware and obs.get("K") is None:
            raise ValueError("the gripper-aware check needs the camera matrix: give "
                             "--intrinsics FX FY CX CY or --camera FILE (found by itself only "
                             "for Cornell files pcdXXXXr.png), or --no-gripper-aware")
        return build_real_detector(model, opts, top_k=top_k, background=background,
                                   coarse_to_fine=args.coarse_to_fine)

    det = detect_files(args.model, args.rgb, args.depth, mask=args.mask,
                       background=args.background, depth_units=args.depth_units,
                       top_k=args.top_k, out=args.out, K=K, build=build)
    print(json.dumps({
        "rectangles": [dict(zip(("x", "y", "theta", "w", "h"), map(float, r), strict=True))
                       for r in det.rects],
        "scores": [float(s) for s in det.scores],
        "n_candidates": det.n_candidates,
        "seconds": round(det.seconds, 3),
        "reason": det.reason,
    }, indent=2))
    return 0 if len(det.rects) else 1
