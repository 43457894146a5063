"""The offline benchmarks' samples: a Cornell or Jacquard dataset folder loaded at the scale
the benchmarks use.
"""

from __future__ import annotations

from pathlib import Path

from dlsr import datasets

__all__ = ["DEFAULT_SCALE", "load_samples"]

DEFAULT_SCALE = {"cornell": 1.0, "jacquard": 0.5}


def load_samples(data, format: str, scale: float | None = None, mapping=None):
    """Load a Cornell or Jacquard dataset folder as a list of GraspSample."""
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
