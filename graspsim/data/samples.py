"""The offline benchmarks' samples: a Cornell or Jacquard dataset folder loaded at the scale
the benchmarks use.
"""

from __future__ import annotations

import contextlib
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from dlsr import datasets

__all__ = ["DEFAULT_SCALE", "PIXEL_FIELDS", "load_samples", "mapped_pixels"]

#: The arrays of a :class:`dlsr.datasets.GraspSample` that :func:`mapped_pixels` maps.
PIXEL_FIELDS = ("rgb", "depth", "depth_valid", "mask")

_ALIGN = 64  # bytes: each array starts on a cache line

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


@contextlib.contextmanager
def mapped_pixels(samples, folder=None):
    """The samples with their pixel arrays read from one file on disk (read-only memory maps),
    for as long as the ``with`` block lasts.

    A benchmark at Cornell's size holds about 2.4 MB of pixels per image (2.1 GB at 885
    images) in its main process, and every task that took some of its images to a worker
    process used to get its own copy. Memory-mapped arrays go to joblib's (loky's) workers as
    a reference to the file (its memmap reducer), so every process reads the same pages of the
    page cache, held once, and a task's arguments cost nothing to send. Values, dtypes and
    shapes are unchanged; the arrays are read-only (nothing in the pipeline writes into a
    sample). Ray and the sequential executor get ordinary arrays' behaviour.

    Parameters
    ----------
    samples : sequence of dlsr.datasets.GraspSample
    folder : path-like or None
        Where the file goes (in a temporary folder made there, removed on exit); None: the
        system's temporary folder (``TMPDIR``).

    Yields
    ------
    list of dlsr.datasets.GraspSample
        Copies of ``samples`` (rectangles and other fields shared) whose :data:`PIXEL_FIELDS`
        that are arrays are ``numpy.memmap`` views of ``pixels.bin``.
    """
    samples = list(samples)
    with tempfile.TemporaryDirectory(prefix="graspsim-pixels-", dir=folder,
                                     ignore_cleanup_errors=True) as tmp:
        path = Path(tmp) / "pixels.bin"
        layout = []  # per sample: {field: (offset, dtype, shape)}
        offset = 0
        with open(path, "wb") as f:
            for s in samples:
                where = {}
                for name in PIXEL_FIELDS:
                    a = getattr(s, name)
                    if not isinstance(a, np.ndarray) or a.size == 0:
                        continue
                    pad = -offset % _ALIGN
                    f.write(b"\0" * pad)
                    offset += pad
                    a = np.ascontiguousarray(a)
                    f.write(a.tobytes())
                    where[name] = (offset, a.dtype, a.shape)
                    offset += a.nbytes
                layout.append(where)
        mapped = [dataclasses.replace(s, **{
            name: np.memmap(path, dtype=dtype, mode="r", offset=off, shape=shape)
            for name, (off, dtype, shape) in where.items()})
            for s, where in zip(samples, layout, strict=True)]
        yield mapped
