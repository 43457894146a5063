"""``graspsim benchmark recognition|detection|table2``: the paper's offline benchmarks."""

from __future__ import annotations

import argparse

from graspsim.detectors.dlsr_options import add_detector_arguments

from . import add_executor_args, executor_from_args


def register(subparsers) -> None:
    p = subparsers.add_parser("benchmark", help="offline benchmarks (the paper's tables)")
    sub = p.add_subparsers(dest="benchmark", metavar="TASK", required=True)

    r = sub.add_parser(
        "recognition",
        help="nested cross-validation of learner x encoder combinations (Table 1, Figure 5)",
    )
    _add_data_args(r)
    r.add_argument("--learners", nargs="+", default=None, metavar="L",
                   help="subset of SC OMP GSVQ NKM RP R (default: all)")
    r.add_argument("--encoders", nargs="+", default=None, metavar="E",
                   help="subset of SC mSC OMP mOMP ST Natural (default: all)")
    r.add_argument("--atoms", type=int, default=300, help="dictionary size")
    r.add_argument("--patches", type=int, default=100_000,
                   help="random patches for dictionary learning")
    r.add_argument("--split", choices=["image", "object"], default="image")
    r.add_argument("--folds", type=int, default=5)
    r.add_argument("--inner-folds", type=int, default=5)
    r.add_argument("--paper-grid", action="store_true",
                   help="C in {1, 10, 100, 1000} as the paper says (default {1, 10} as its code)")
    r.add_argument("--no-whiten", action="store_true")
    r.add_argument("--extra-patches", default=None, metavar="FILE",
                   help="npz of unlabelled patches joined to dictionary learning (self-taught)")
    r.add_argument("--max-rectangles", type=int, default=None,
                   help="keep a seeded random subset of this many rectangles")
    r.add_argument("--figure5", action="store_true",
                   help="also plot accuracy against dictionary size (50..400), +- whitening")
    r.add_argument("--seed", type=int, default=0)
    add_executor_args(r)
    r.add_argument("--out", required=True, help="output folder (resumes if it has results)")
    r.set_defaults(func=_recognition)
    _register_detection(sub)
    _register_table2(sub)


def _recognition(args: argparse.Namespace) -> int:
    from graspsim.eval.offline.recognition import recognition_benchmark

    summary = recognition_benchmark(
        data=args.data, format=args.format, scale=args.scale, mapping=args.mapping,
        learners=args.learners, encoders=args.encoders, n_atoms=args.atoms,
        n_patches=args.patches, split=args.split, n_folds=args.folds,
        inner_folds=args.inner_folds, paper_grid=args.paper_grid, whiten=not args.no_whiten,
        extra_patches=args.extra_patches, max_rectangles=args.max_rectangles,
        figure5=args.figure5, seed=args.seed, out=args.out,
        executor=executor_from_args(args),
    )
    extra = (f", figure5.md and figure5.png ({len(summary['figure5'])} points)"
             if "figure5" in summary else "")
    print(f"wrote {args.out}/recognition.json and table1.md{extra} "
          f"({len(summary['cells'])} cells, {summary['seconds_this_run']:.0f} s this run)")
    return 0


def _register_detection(sub) -> None:
    d = sub.add_parser(
        "detection",
        help="cross-validated grasp detection by the rectangle metric (Table 2)",
    )
    _add_dataset_args(d)
    d.add_argument("--model", default=None, metavar="PATH",
                   help="evaluate this saved model (PATH.npz + PATH.json, e.g. from "
                        "--save-model) on every labelled image of --data, without training "
                        "(cross-dataset evaluation)")
    d.add_argument("--split", choices=["image", "object"], default="object")
    d.add_argument("--learner", default=None,
                   help="one of SC OMP GSVQ NKM RP R (default NKM, or the --model's)")
    d.add_argument("--encoder", default=None,
                   help="one of SC mSC OMP mOMP ST Natural (default Natural, or the --model's)")
    d.add_argument("--encoder-param", type=float, default=None,
                   help="lambda or number of non-zeros (default: from --recognition, else the "
                        "middle of the reference grid)")
    d.add_argument("--C", type=float, default=None, help="SVM cost (default: from "
                   "--recognition, else 1)")
    add_detector_arguments(d, kinds=("dense", "exact", "lattice", "ggcnn", "grconvnet"))
    d.add_argument("--ggcnn-steps", type=int, default=20_000, metavar="N",
                   help="--detector ggcnn or grconvnet (the CNN peer trained per fold; needs "
                        "the cnn extra): sample-steps of each fold's training")
    d.add_argument("--ggcnn-device", default="cpu", help="GG-CNN, GR-ConvNet: cpu or cuda")
    d.add_argument("--ggcnn-input-size", type=int, default=None, metavar="S",
                   help="GG-CNN, GR-ConvNet: network input side, the crop (300 px, 224 px) "
                        "is resized to it (default: the crop's side)")
    d.add_argument("--grconvnet-channels", type=int, choices=[16, 32], default=32,
                   metavar="K", help="GR-ConvNet: k, the filters of the first layer (16 or 32, "
                                     "default 32)")
    d.add_argument("--paired", action="store_true",
                   help="GG-CNN, GR-ConvNet: also run DLSR's benchmark (the DLSR options given "
                        "here, the preset's detector) on the same folds into OUT/dlsr and test "
                        "the two image by image (exact McNemar)")
    _add_training_args(d)
    d.add_argument("--save-model", default=None, metavar="PATH",
                   help="also train on every image and save the model (PATH.npz + PATH.json)")
    d.add_argument("--seed", type=int, default=0)
    add_executor_args(d)
    d.add_argument("--out", required=True, help="output folder (resumes if it has results)")
    d.set_defaults(func=_detection)


def _add_data_args(d) -> None:
    """The labelled dataset every benchmark reads."""
    d.add_argument("--data", required=True, help="dataset root folder")
    d.add_argument("--format", choices=["cornell", "jacquard"], required=True)
    d.add_argument("--scale", type=float, default=None,
                   help="resize images and rectangles (default 1 for Cornell, 0.5 for Jacquard)")
    d.add_argument("--mapping", default=None,
                   help="Cornell image-to-object mapping file (for --split object)")


def _add_dataset_args(d) -> None:
    """The dataset and the extra training data of ``detection`` and ``table2``."""
    _add_data_args(d)
    d.add_argument("--extra-patches", default=None, metavar="FILE",
                   help="npz of unlabelled patches (graspsim patches) joined to each fold's "
                        "dictionary learning only (self-taught); the SVM's training is unchanged")
    d.add_argument("--extra-train", default=None, metavar="DATA",
                   help="a further labelled dataset joined to every training fold, never to a "
                        "test fold (e.g. synthetic images beside real ones)")
    d.add_argument("--extra-format", choices=["cornell", "jacquard"], default=None,
                   help="format of --extra-train (default: --format)")
    d.add_argument("--extra-scale", type=float, default=None,
                   help="resize --extra-train (default 1 for Cornell, 0.5 for Jacquard)")
    d.add_argument("--extra-mapping", default=None,
                   help="Cornell image-to-object mapping file of --extra-train")


def _add_training_args(d) -> None:
    """The training and search options of ``detection`` and ``table2`` (the rows' shared
    ones)."""
    d.add_argument("--recognition", default=None, metavar="JSON",
                   help="recognition.json: take the most often chosen encoder parameter and C")
    d.add_argument("--coarse-to-fine", action="store_true",
                   help="dense detector: coarse grid first, then the full grid near the best")
    d.add_argument("--rescore", type=int, default=300,
                   help="dense detector: best candidates rescored exactly (0: none)")
    d.add_argument("--region", choices=["auto", "background", "mask", "depth"], default="auto",
                   help="object region: the sample mask when there is one, else depth above "
                        "the table plane")
    d.add_argument("--grid-negatives", type=float, default=1.0, metavar="RATIO",
                   help="training negatives drawn from the detector's own candidate grid (those "
                        "failing the rectangle metric), per labelled rectangle of an image "
                        "(0: the labelled rectangles only)")
    d.add_argument("--fit-grid", type=float, default=None, metavar="Q",
                   help="search only the openings and jaw sizes in the [Q, 1 - Q] quantile range "
                        "of the fold's training positives (plus half a grid step), e.g. 0.025; "
                        "default: the paper's full grid")
    d.add_argument("--hard-negatives", type=int, default=0, metavar="N",
                   help="after training, add the detector's N best failing candidates per "
                        "training image as negatives and refit the SVM (hard-negative mining; "
                        "default 0, as the paper)")
    d.add_argument("--hard-rounds", type=int, default=1, metavar="R",
                   help="rounds of hard-negative mining, each on the refitted model (default 1)")
    d.add_argument("--folds", type=int, default=5)
    d.add_argument("--atoms", type=int, default=300)
    d.add_argument("--patches", type=int, default=100_000)
    d.add_argument("--max-images", type=int, default=None)
    d.add_argument("--overlays", type=int, default=4, help="best and worst overlays to write")


def _split_list(text: str) -> list[str]:
    """``--split image,object``: the splits, in order."""
    splits = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in splits if t not in ("image", "object")]
    if bad or not splits:
        raise argparse.ArgumentTypeError(f"splits are image and/or object, got {text!r}")
    return splits


def _row_list(text: str) -> list[tuple[str, str]]:
    """``--rows NKM-Natural,NKM-SC``: (learner, encoder) pairs."""
    from dlsr.features import ENCODERS, LEARNERS

    rows = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        learner, _, encoder = item.partition("-")
        if learner not in LEARNERS or encoder not in ENCODERS:
            raise argparse.ArgumentTypeError(
                f"a row is LEARNER-ENCODER ({'/'.join(LEARNERS)} - {'/'.join(ENCODERS)}), "
                f"got {item!r}")
        rows.append((learner, encoder))
    if not rows:
        raise argparse.ArgumentTypeError("no row given")
    return rows


def _register_table2(sub) -> None:
    t = sub.add_parser(
        "table2",
        help="every row of Table 2 on both splits in one pass (shared training sets, "
             "dictionary and test-image work; the same records as one detection run per row)",
    )
    _add_dataset_args(t)
    t.add_argument("--split", type=_split_list, default=["image", "object"],
                   metavar="image,object", help="the splits (default: both)")
    t.add_argument("--rows", type=_row_list,
                   default=[("NKM", "Natural"), ("NKM", "SC"), ("OMP", "Natural"),
                            ("RP", "Natural")], metavar="L-E,...",
                   help="learner-encoder rows (default: the paper's Table 2 rows "
                        "NKM-Natural,NKM-SC,OMP-Natural,RP-Natural)")
    add_detector_arguments(t, kinds=("dense", "exact", "lattice"))
    _add_training_args(t)
    t.add_argument("--seed", type=int, default=0)
    add_executor_args(t)
    t.add_argument("--out", required=True,
                   help="output folder: one folder per row and split (LEARNER-ENCODER_SPLIT, "
                        "as graspsim benchmark detection writes it), table2.json and "
                        "table2.md; resumes if it has results")
    t.set_defaults(func=_table2)


def _table2(args: argparse.Namespace) -> int:
    from graspsim.detectors.dlsr_options import options_from_args
    from graspsim.eval.offline.table2_pass import table2_benchmark

    table = table2_benchmark(
        args.data, args.format, args.out, splits=args.split, rows=args.rows,
        scale=args.scale, mapping=args.mapping, extra_train=args.extra_train,
        extra_format=args.extra_format, extra_scale=args.extra_scale,
        extra_mapping=args.extra_mapping, n_overlays=args.overlays,
        executor=executor_from_args(args), options=options_from_args(args),
        recognition_json=args.recognition, n_folds=args.folds, n_atoms=args.atoms,
        n_patches=args.patches, grid_negatives=args.grid_negatives, fit_grid=args.fit_grid,
        hard_negatives=args.hard_negatives, hard_rounds=args.hard_rounds, region=args.region,
        rescore=args.rescore, coarse_to_fine=args.coarse_to_fine, max_images=args.max_images,
        extra_patches=args.extra_patches, seed=args.seed)
    for split, cells in table["splits"].items():
        print(f"{split}-wise: " + ", ".join(
            f"{name} {100 * c['accuracy']:.2f} %" for name, c in cells["rows"].items())
            + "; baselines " + ", ".join(f"{k} {100 * v:.2f} %"
                                         for k, v in cells["baselines"].items()))
    print(f"wrote {args.out}/table2.json and table2.md "
          f"({table['seconds_this_run']:.0f} s this run)")
    return 0


def _ggcnn(args: argparse.Namespace) -> int:
    from graspsim.detectors.dlsr_options import options_from_args
    from graspsim.eval.offline.ggcnn import ggcnn_detection_benchmark

    network = args.detector
    if network == "ggcnn":  # the options of GG-CNN's earlier runs (the same fold models)
        cnn = {"input_size": args.ggcnn_input_size or 300}
    else:
        cnn = {"input_size": args.ggcnn_input_size or 224, "channels": args.grconvnet_channels}
    s = ggcnn_detection_benchmark(
        data=args.data, format=args.format, out=args.out, scale=args.scale,
        mapping=args.mapping, split=args.split, n_folds=args.folds, seed=args.seed,
        steps=args.ggcnn_steps, device=args.ggcnn_device, max_images=args.max_images,
        paired=args.paired, network=network, **cnn,
        dlsr_options=dict(  # DLSR's options on this command line (the dense grid search)
            learner=args.learner, encoder=args.encoder, encoder_param=args.encoder_param,
            C=args.C, recognition_json=args.recognition, n_atoms=args.atoms,
            n_patches=args.patches, grid_negatives=args.grid_negatives,
            fit_grid=args.fit_grid, hard_negatives=args.hard_negatives,
            hard_rounds=args.hard_rounds, region=args.region, rescore=args.rescore,
            coarse_to_fine=args.coarse_to_fine,
            # the preset's DLSR detector, with the DLSR flags given here
            options=options_from_args(argparse.Namespace(**{**vars(args), "detector": None})),
            executor=executor_from_args(args)))
    title = "GG-CNN" if network == "ggcnn" else "GR-ConvNet"
    line = (f"wrote {args.out}/{network}.json and {network}.md: {title} accuracy "
            f"{100 * s['accuracy']:.2f} % ({s['successes']}/{s['n']}, {args.split}-wise)")
    if "vs_dlsr" in s:
        line += (f"; DLSR {100 * s['dlsr_accuracy']:.2f} % on the same images, exact McNemar "
                 f"p = {s['vs_dlsr']['p_value']:.3g}")
    print(line)
    return 0


def _detection(args: argparse.Namespace) -> int:
    from graspsim.detectors.dlsr_options import options_from_args
    from graspsim.eval.offline.detection import detection_benchmark

    if args.detector in ("ggcnn", "grconvnet"):
        return _ggcnn(args)
    if args.paired:
        raise ValueError("--paired is for --detector ggcnn or grconvnet")

    param = args.encoder_param
    if param is not None and args.encoder in ("OMP", "mOMP"):
        param = int(param)
    summary = detection_benchmark(
        data=args.data, format=args.format, out=args.out, scale=args.scale,
        mapping=args.mapping, split=args.split, learner=args.learner, encoder=args.encoder,
        encoder_param=param, C=args.C, recognition_json=args.recognition,
        options=options_from_args(args), n_folds=args.folds, n_atoms=args.atoms,
        n_patches=args.patches, grid_negatives=args.grid_negatives,
        fit_grid=args.fit_grid, hard_negatives=args.hard_negatives,
        hard_rounds=args.hard_rounds, region=args.region,
        rescore=args.rescore,
        coarse_to_fine=args.coarse_to_fine, max_images=args.max_images,
        n_overlays=args.overlays, save_model=args.save_model,
        extra_patches=args.extra_patches, extra_train=args.extra_train,
        extra_format=args.extra_format, extra_scale=args.extra_scale,
        extra_mapping=args.extra_mapping, model=args.model,
        seed=args.seed,
        executor=executor_from_args(args),
    )
    how = ("saved model, no training" if args.model is not None
           else f"{summary['config']['split']}-wise")
    print(f"wrote {args.out}/detection.json and table2.md: accuracy "
          f"{100 * summary['accuracy']:.2f} % ({how}, "
          f"{summary['seconds_per_image']:.2f} s/image); baselines "
          + ", ".join(f"{k} {100 * v:.2f} %" for k, v in summary["baselines"].items()))
    return 0
