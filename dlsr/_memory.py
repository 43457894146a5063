"""numpy's transparent-huge-page advice, switched off around allocation-heavy streaming.

numpy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every array of
4 MB or more. The feature pipeline (:func:`dlsr.features.rectangle_features_multi`) allocates and
frees about 2 GB of such temporaries per chunk of 64 rectangles (codes for every penalty, their
polarity splits), each freshly faulted in. On the development machine (a 2-core virtual machine,
THP ``madvise`` mode) one outer fold of the recognition benchmark with random-patch atoms took
166 s of wall time with the advice off and 186 s with it on (NKM atoms: 83 s and 88 s); the OMP
and soft-threshold stages, which write large outputs and compute little, were 1.4 to 2.3 times
faster. :func:`small_pages` turns the advice off for a block and restores it after; it is
reference counted, so overlapping blocks in several threads restore the caller's setting once
the last one ends. Without numpy's private switch it does nothing.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager

try:
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # pragma: no cover - other numpy layouts
    _set_madvise_hugepage = None

__all__ = ["small_pages"]

_lock = threading.Lock()
_depth = 0
_saved = True


@contextmanager
def small_pages():
    """No transparent-huge-page advice on numpy arrays allocated inside the block."""
    global _depth, _saved
    if _set_madvise_hugepage is None:  # pragma: no cover
        yield
        return
    with _lock:
        if _depth == 0:
            _saved = _set_madvise_hugepage(False)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _set_madvise_hugepage(_saved)
