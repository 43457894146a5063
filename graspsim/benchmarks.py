"""Library entry points behind ``graspsim benchmark``: load a dataset and run a benchmark."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from dlsr import recognition as rec
from dlsr.features import ENCODERS, LEARNERS

log = logging.getLogger(__name__)

DEFAULT_SCALE = {"cornell": 1.0, "jacquard": 0.5}


def load_samples(data, format: str, scale: float | None = None, mapping=None):
    """Load a Cornell or Jacquard dataset folder as a list of GraspSample."""
    from dlsr import datasets

    root = Path(data)
    if not root.exists():
        raise FileNotFoundError(f"dataset folder not found: {root}")
    scale = DEFAULT_SCALE[format] if scale is None else scale
    if format == "cornell":
        samples = datasets.load_cornell(root, mapping=mapping, scale=scale)
    elif format == "jacquard":
        samples = datasets.load_jacquard(root, scale=scale)
    else:
        raise ValueError(f"format must be 'cornell' or 'jacquard', got {format!r}")
    if not samples:
        raise ValueError(f"no images found in {root} (format {format})")
    return samples


def _subset(data: rec.RecognitionData, n: int, seed: int) -> rec.RecognitionData:
    if n >= len(data):
        return data
    idx = np.sort(np.random.default_rng(seed).choice(len(data), n, replace=False))
    return rec.RecognitionData(data.images[idx], data.masks[idx], data.labels[idx],
                               data.image_ids[idx], data.object_ids[idx])


def recognition_benchmark(
    data, format: str, out, scale=None, mapping=None, learners=None, encoders=None,
    n_atoms=300, n_patches=100_000, split="image", n_folds=5, inner_folds=5,
    paper_grid=False, whiten=True, extra_patches=None, max_rectangles=None, figure5=False,
    n_jobs=1, seed=0, progress=True,
) -> dict:
    """Load ``data`` and run :func:`dlsr.recognition.run_recognition_benchmark`."""
    samples = load_samples(data, format, scale, mapping)
    rd = rec.recognition_data(samples, random_state=seed)
    if max_rectangles is not None:
        rd = _subset(rd, max_rectangles, seed)
    log.info("%d rectangles (%d positive) from %d images", len(rd), int(rd.labels.sum()),
             len(samples))
    extra = None
    if extra_patches is not None:
        from dlsr.patches import load_patch_file

        extra = load_patch_file(extra_patches)
    return rec.run_recognition_benchmark(
        rd, out, learners=learners or LEARNERS, encoders=encoders or ENCODERS, split=split,
        n_folds=n_folds, inner_folds=inner_folds,
        C_grid=rec.PAPER_C_GRID if paper_grid else rec.C_GRID, n_atoms=n_atoms, whiten=whiten,
        n_patches=n_patches, extra=extra, random_state=seed, n_jobs=n_jobs, progress=progress,
        figure5_sizes=(50, 100, 200, 300, 400) if figure5 else None,
    )
