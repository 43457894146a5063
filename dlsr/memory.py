"""Memory settings switched around allocation-heavy streaming: numpy's transparent-huge-page
advice and glibc's return of large freed blocks to the kernel.

The feature pipeline (:func:`dlsr.features.rectangle_features_multi`) allocates and frees about
2 GB of temporaries per chunk of 64 rectangles (codes for every penalty, their polarity splits),
and the recognition benchmark's classifiers more. Two defaults make each of them cost page
faults:

* numpy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every array
  of 4 MB or more, each then freshly faulted in as 2 MB pages. On the development machine (a
  2-core virtual machine, THP ``madvise`` mode) one outer fold of the recognition benchmark
  with random-patch atoms took 166 s of wall time with the advice off and 186 s with it on (NKM
  atoms: 83 s and 88 s); the OMP and soft-threshold stages, which write large outputs and
  compute little, were 1.4 to 2.3 times faster. :func:`small_pages` turns the advice off.
* glibc serves blocks above its mmap threshold (at most 32 MB) with a fresh ``mmap`` and
  unmaps them when freed, so every such array is faulted in again, 4 kB at a time: the
  36-cell recognition benchmark took 126 million page faults and 242 s of system time (6 %
  of its CPU time). :func:`reused_heap` serves them from the heap instead and keeps freed
  memory there for the next allocation (``mallopt``: no mmap, no trimming), and on leaving
  hands the free memory back (``malloc_trim``). One outer fold with NKM atoms: 87.8 -> 79.9
  CPU s (system time 7.1 -> 1.0 s, page faults 4.5 M -> 0.5 M), random-patch atoms 168.9 ->
  163.2 s; the peak resident memory grows by about 15 % (1.8 -> 2.1 GB). The whole benchmark:
  8 million page faults, 39 s of system time, 3,679 CPU s instead of 3,798 (32 min 33 s ->
  31 min 8 s on 2 cores), the same table. The detectors' scoring runs under it too
  (:mod:`dlsr.detection.dense`): a process scoring on two threads after an earlier block took
  0.39 million faults and 0.93 s of system time per image without it, 5,000 and 0.02 s with it,
  the same scores (with the thresholds left at 128 kB, before the change below).

Both switches are process-wide and reference counted: overlapping blocks in several threads
restore the settings once the last one ends. Each does nothing where its switch is missing
(numpy's private one, or a C library other than glibc). glibc's adaptive mmap threshold stays
off once ``mallopt`` has been called, so :func:`reused_heap` leaves the thresholds where the
adaptive ones end up after a large array is freed (mmap above 32 MB, trimming above 64 MB):
left at glibc's initial 128 kB, every array above it would be mapped afresh for the rest of the
process. Measured per simulated scene built, rendered and observed (20 scenes, one process
each): 14,500 page faults and 0.14 CPU s in a fresh process; 53,000 and 0.22 s after a block
that left the thresholds at 128 kB; 4 and 0.11 s after a block that leaves them at the ceiling.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
from contextlib import contextmanager

try:
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # pragma: no cover - other numpy layouts
    _set_madvise_hugepage = None

__all__ = ["reused_heap", "small_pages"]


def _glibc():
    """The C library when it is glibc (``mallopt``, ``malloc_trim``), else None."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 - glibc only
        libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        libc.malloc_trim.argtypes = [ctypes.c_size_t]
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return None
    return libc


_libc = _glibc()
# glibc's malloc.h: parameters, and the settings left on leaving. ``mallopt`` turns glibc's
# adaptive mmap threshold off for good (it starts at 128 kB and rises to the largest block
# freed, at most 32 MB on 64-bit systems, the trim threshold at twice that), so on leaving the
# thresholds are set to that ceiling: what an adaptive process reaches once it has freed a
# large array, not the 128 kB of a process that had never freed one.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4
_LEFT_MMAP_THRESHOLD = 32 * 2**20
_LEFT_TRIM_THRESHOLD, _DEFAULT_MMAP_MAX = 2 * _LEFT_MMAP_THRESHOLD, 65536


class _Switch:
    """A process-wide setting held on while at least one block is inside."""

    def __init__(self, on, off):
        self._on, self._off = on, off
        self._lock = threading.Lock()
        self._depth = 0
        self._saved = None

    @contextmanager
    def held(self):
        with self._lock:
            if self._depth == 0:
                self._saved = self._on()
            self._depth += 1
        try:
            yield
        finally:
            with self._lock:
                self._depth -= 1
                if self._depth == 0:
                    self._off(self._saved)


def _no_hugepages():
    return _set_madvise_hugepage(False)


def _heap_on():
    _libc.mallopt(_M_MMAP_MAX, 0)
    _libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)


def _heap_off(_):
    _libc.mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
    _libc.mallopt(_M_MMAP_THRESHOLD, _LEFT_MMAP_THRESHOLD)
    _libc.mallopt(_M_TRIM_THRESHOLD, _LEFT_TRIM_THRESHOLD)
    _libc.malloc_trim(0)


_hugepage_switch = _Switch(_no_hugepages, _set_madvise_hugepage)
_heap_switch = _Switch(_heap_on, _heap_off)


@contextmanager
def small_pages():
    """No transparent-huge-page advice on numpy arrays allocated inside the block."""
    if _set_madvise_hugepage is None:  # pragma: no cover
        yield
        return
    with _hugepage_switch.held():
        yield


@contextmanager
def reused_heap():
    """Large blocks freed inside the block stay in the heap for the next allocation."""
    if _libc is None:  # pragma: no cover
        yield
        return
    with _heap_switch.held():
        yield
