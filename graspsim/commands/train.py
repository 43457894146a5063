"""``graspsim train ggcnn|grconvnet``: train a CNN peer detector on a labelled dataset."""

from __future__ import annotations

import argparse


def _add_common(g, crop: int, multiple: int) -> None:
    """The options both networks take (data, output, budget, optimiser, crop, checkpoints)."""
    g.add_argument("--data", required=True,
                   help="dataset folder: a `graspsim dataset` folder or a Cornell copy "
                        "(--format cornell), or a Jacquard copy (--format jacquard)")
    g.add_argument("--format", choices=["cornell", "jacquard"], default="cornell")
    g.add_argument("--scale", type=float, default=None,
                   help="resize images and rectangles (default 1 for Cornell, 0.5 for Jacquard)")
    g.add_argument("--mapping", default=None, help="Cornell image-to-object mapping file")
    g.add_argument("--out", required=True, help="MODEL (writes MODEL.pt and MODEL.json)")
    g.add_argument("--steps", type=int, default=20_000,
                   help="sample-steps (images seen, in batches of --batch-size), whatever the "
                        "dataset size (default %(default)s)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    g.add_argument("--batch-size", type=int, default=8)
    g.add_argument("--lr", type=float, default=1e-3)
    g.add_argument("--crop", type=int, default=crop,
                   help="side of the square crop around the object found from depth, pixels "
                        "(default %(default)s)")
    g.add_argument("--input-size", type=int, default=crop,
                   help=f"network input side (a multiple of {multiple}); the crop is resized "
                        "to it (default %(default)s)")
    g.add_argument("--checkpoint-every", type=int, default=1000, metavar="STEPS")
    g.add_argument("--snapshots", type=int, nargs="*", default=[], metavar="STEPS",
                   help="also save the model as MODEL_stepN at these sample-steps")
    g.add_argument("--threads", type=int, default=2, help="torch threads")


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help="train a peer detector (GG-CNN, GR-ConvNet) on a "
                                            "dataset")
    sub = p.add_subparsers(dest="learner", metavar="DETECTOR", required=True)
    g = sub.add_parser(
        "ggcnn", help="GG-CNN (Morrison et al. 2018; needs the cnn extra: pip install -e .[cnn])",
        description="Train GG-CNN on every positive rectangle of a dataset and save MODEL.pt "
                    "(weights) + MODEL.json. Resumes from MODEL.ckpt.pt when rerun with the "
                    "same data and options. Use the model with `graspsim trials --detector "
                    "MODEL`. 20,000 sample-steps take 35-50 min on 2 CPU cores.",
    )
    _add_common(g, crop=300, multiple=12)
    g.set_defaults(func=_ggcnn)
    r = sub.add_parser(
        "grconvnet",
        help="GR-ConvNet (Kumra et al. 2020), RGB-D (needs the cnn extra)",
        description="Train GR-ConvNet (depth and colour in, k filters, five residual blocks) "
                    "on every positive rectangle of a dataset and save MODEL.pt (weights) + "
                    "MODEL.json. Resumes from MODEL.ckpt.pt when rerun with the same data and "
                    "options. Use the model with `graspsim trials --detector MODEL`. A "
                    "sample-step costs about twice as much at k = 32 as at k = 16 "
                    "(scripts/bench_grconvnet.py).",
    )
    _add_common(r, crop=224, multiple=4)
    r.add_argument("--channels", type=int, choices=[16, 32], default=32,
                   help="k, the filters of the first layer: 32 the paper's (1.9M parameters), "
                        "16 the authors' small model (0.48M), about half the cost per step")
    r.add_argument("--dropout", type=float, default=0.1,
                   help="dropout probability before each head while training (0: none; "
                        "default %(default)s, the authors' training default)")
    r.set_defaults(func=_grconvnet)


def _options(args: argparse.Namespace) -> dict:
    return dict(steps=args.steps, seed=args.seed, device=args.device,
                batch_size=args.batch_size, lr=args.lr, crop=args.crop,
                input_size=args.input_size, checkpoint_every=args.checkpoint_every,
                snapshots=args.snapshots, threads=args.threads)


def _report(args, meta: dict, title: str) -> int:
    t = meta["training"]
    print(f"wrote {args.out}.pt and {args.out}.json: {title}, {t['sample_steps']} sample-steps "
          f"on {t['n_images']} images, loss {t['loss']}, {t['seconds']:.0f} s of training")
    return 0


def _ggcnn(args: argparse.Namespace) -> int:
    from graspsim.detectors.ggcnn.train import train_from_folder

    meta = train_from_folder(args.data, args.format, args.out, scale=args.scale,
                             mapping=args.mapping, **_options(args))
    return _report(args, meta, "GG-CNN")


def _grconvnet(args: argparse.Namespace) -> int:
    from graspsim.detectors.ggcnn.train import train_from_folder

    meta = train_from_folder(args.data, args.format, args.out, scale=args.scale,
                             mapping=args.mapping, network="grconvnet",
                             channels=args.channels, dropout=args.dropout, **_options(args))
    return _report(args, meta, f"GR-ConvNet k = {meta['channels']}")
