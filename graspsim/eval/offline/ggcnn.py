"""The CNN peers' offline benchmark: the rectangle metric on DLSR's object-wise folds, paired.

:func:`ggcnn_detection_benchmark` splits a dataset into the folds that
:func:`graspsim.eval.offline.detection.detection_benchmark` uses
(:func:`dlsr.datasets.object_wise_folds`
with the same seed), trains one network (GG-CNN, or GR-ConvNet with ``network="grconvnet"``)
per fold on the training folds, and checks each test image's best rectangle against its
positives. With ``paired`` it also runs DLSR's benchmark on the same images and compares the
two image by image (exact McNemar).
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from dlsr import datasets
from dlsr.detection import sample_observation
from dlsr.metrics import jaccard_matrix, rectangle_metric
from dlsr.records import read_json, read_jsonl, write_text_atomic
from graspsim.data.samples import load_samples
from graspsim.eval.offline.detection import detection_benchmark
from graspsim.eval.stats import paired_detection_test

from ...detectors.ggcnn.detector import GGCNNDetector
from ...detectors.ggcnn.model import model_paths, network_of, require_torch
from ...detectors.ggcnn.train import trainer
from ..stats import wilson_interval

__all__ = ["ggcnn_detection_benchmark", "ggcnn_markdown", "config_key"]


def ggcnn_detection_benchmark(data, format: str, out, scale=None, mapping=None,
                              split: str = "object", n_folds: int = 5, seed: int = 0,
                              steps: int = 20_000, device: str = "cpu",
                              max_images: int | None = None, paired: bool = False,
                              dlsr_options: dict | None = None, progress: bool = True,
                              network: str = "ggcnn", **train_options) -> dict:
    """Cross-validated GG-CNN (or GR-ConvNet) detection accuracy by the rectangle metric.

    Parameters
    ----------
    data, format, scale, mapping :
        The dataset (:func:`graspsim.data.samples.load_samples`); images without
        positives are
        left out, as DLSR's benchmark does.
    out : str or Path
        Output folder: ``models/`` (one network per fold, resumed), ``NAME_results.jsonl``
        (per test image, resumed), ``NAME.json`` and ``NAME.md``, ``NAME`` the network
        (``ggcnn``, ``grconvnet``); with ``paired`` DLSR's benchmark in ``out/dlsr``.
    split : {"object", "image"}
    n_folds, seed : int
        As DLSR's benchmark (same folds for the same values).
    steps : int
        Sample-steps of each fold's training.
    device : str
    max_images : int or None
        The first images only (as DLSR's ``max_images``).
    paired : bool
        Also run :func:`graspsim.eval.offline.detection.detection_benchmark` on the same folds and
        test
        GG-CNN against DLSR with the exact McNemar test (``vs_dlsr``).
    dlsr_options : dict or None
        Further keyword options of DLSR's benchmark.
    progress : bool
    network : {"ggcnn", "grconvnet"}
        The network trained per fold (:data:`graspsim.detectors.ggcnn.model.NETWORKS`).
    **train_options
        Options of :func:`graspsim.detectors.ggcnn.train.train_ggcnn` or
        :func:`~graspsim.detectors.ggcnn.train.train_grconvnet` (``input_size``, ``crop``,
        ``channels``, ...).

    Returns
    -------
    dict
        The content of ``NAME.json``: ``accuracy``, ``folds``, ``per_image``,
        ``seconds_per_image``, ``training_seconds`` and, when paired, ``dlsr_accuracy`` and
        ``vs_dlsr`` (:func:`graspsim.eval.stats.paired_accuracy_test`, the network as ``a``).
    """
    spec = network_of(network)
    name = spec.name
    require_torch()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    samples = [s for s in load_samples(data, format, scale, mapping) if s.positives]
    if max_images is not None:
        samples = samples[:max_images]
    if len(samples) < n_folds:
        raise ValueError(f"{len(samples)} labelled images cannot make {n_folds} folds")
    if split == "object":
        folds = datasets.object_wise_folds(samples, n_folds, seed)
    elif split == "image":
        folds = datasets.image_wise_folds(samples, n_folds, seed)
    else:
        raise ValueError(f"split must be 'image' or 'object', got {split!r}")
    config = {"data": str(data), "format": format, "scale": scale, "split": split,
              "n_folds": n_folds, "seed": seed, "steps": int(steps), "device": device,
              "n_images": len(samples), "train": {k: (list(v) if isinstance(v, tuple) else v)
                                                  for k, v in sorted(train_options.items())}}
    if name != "ggcnn":  # GG-CNN's keys stay those of its earlier runs (they resume)
        config["network"] = name
    key = config_key(config)
    results = out / f"{name}_results.jsonl"
    done = {r["image_id"]: r for r in read_jsonl(results, required=("image_id",), repair=True)
            if r.get("config_key") == key}
    train_seconds = {}
    bar = tqdm(total=len(samples), initial=len(done), desc=f"{spec.title} detection",
               disable=not progress)
    for k, (train, test) in enumerate(folds):
        mpath = out / "models" / f"{name}_{key}_fold{k}"
        todo = [i for i in test if samples[i].image_id not in done]
        if not model_paths(mpath)[1].is_file():  # resumes from its checkpoint
            trainer(name)([samples[i] for i in train], mpath, steps=steps, seed=seed + k,
                          device=device, progress=progress, **train_options)
        meta = read_json(model_paths(mpath)[1], f"{spec.title} model")
        train_seconds[k] = meta["training"]["seconds"]
        if not todo:
            continue
        det = GGCNNDetector(mpath, device=device, top_k=1)
        for i in todo:
            s = samples[i]
            t0 = time.perf_counter()
            rects, scores = det.predict(sample_observation(s))
            rec = {"config_key": key, "fold": k, "image_id": s.image_id,
                   "object_id": s.object_id, "seconds": time.perf_counter() - t0}
            if len(rects):
                top = rects[0]
                rec.update(rect=top.tolist(), score=float(scores[0]),
                           success=bool(rectangle_metric(top, s.positives)),
                           jaccard=float(jaccard_matrix(top, s.positives).max()))
            else:
                rec.update(rect=None, score=None, success=False, jaccard=0.0)
            with results.open("a") as fh:
                fh.write(json.dumps(rec) + "\n")
            done[s.image_id] = rec
            bar.update(1)
    bar.close()
    recs = [done[s.image_id] for s in samples]
    per_fold = []
    for k, (_, test) in enumerate(folds):
        rs = [done[samples[i].image_id] for i in test]
        per_fold.append({"fold": k, "n_images": len(rs),
                         "accuracy": float(np.mean([r["success"] for r in rs])) if rs else None,
                         "training_seconds": train_seconds.get(k)})
    summary = {
        "config": config,
        "accuracy": float(np.mean([r["success"] for r in recs])),
        "successes": int(sum(r["success"] for r in recs)), "n": len(recs),
        "folds": per_fold,
        "per_image": [{"image_id": r["image_id"], "object_id": r["object_id"],
                       "fold": r["fold"], "success": bool(r["success"]),
                       "jaccard": r["jaccard"]} for r in recs],
        "seconds_per_image": float(np.mean([r["seconds"] for r in recs])),
        "training_seconds": float(sum(v for v in train_seconds.values() if v is not None)),
    }
    if paired:
        dl = detection_benchmark(data, format, out / "dlsr", scale=scale, mapping=mapping,
                                 split=split, n_folds=n_folds, seed=seed,
                                 max_images=max_images, progress=progress,
                                 **(dlsr_options or {}))
        summary["dlsr_accuracy"] = dl["accuracy"]
        summary["dlsr_successes"] = int(sum(r["success"] for r in dl["per_image"]))
        summary["vs_dlsr"] = paired_detection_test(summary, dl)
    write_text_atomic(out / f"{name}.json", json.dumps(summary, indent=2))
    write_text_atomic(out / f"{name}.md", ggcnn_markdown(summary))
    return summary


def config_key(config: dict) -> str:
    """The key of a benchmark configuration (``NAME.json``'s ``config``): it names the fold
    models (``OUT/models/NAME_KEY_foldK``) and marks the per-image results."""
    return hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:12]


def ggcnn_markdown(summary: dict) -> str:
    """The table of :func:`ggcnn_detection_benchmark`'s summary (Markdown)."""
    c = summary["config"]
    title = network_of(c.get("network", "ggcnn")).title
    rows = [(title, summary["successes"], summary["n"])]
    if "dlsr_accuracy" in summary:
        rows.append(("DLSR", summary["dlsr_successes"], summary["n"]))
    lines = [f"Rectangle metric, {c['split']}-wise {c['n_folds']} folds, {c['data']} "
             f"({summary['n']} images); {title} trained {c['steps']} sample-steps per fold.",
             "",
             "| detector | top-1 correct | accuracy | 95 % CI (Wilson) |", "|---|---|---|---|"]
    for name, k, n in rows:
        lo, hi = wilson_interval(k, n)
        lines.append(f"| {name} | {k}/{n} | {100 * k / n:.1f} % | "
                     f"{100 * lo:.1f}-{100 * hi:.1f} % |")
    if "vs_dlsr" in summary:
        t = summary["vs_dlsr"]
        lines += ["", f"Paired (exact McNemar): {title} alone right on {t['a_only']} images, "
                      f"DLSR alone on {t['b_only']}; p = {t['p_value']:.3g}."]
    return "\n".join(lines) + "\n"
