"""The scoped switch of numpy's transparent-huge-page advice."""

from __future__ import annotations

import threading

import pytest

from dlsr.memory import small_pages

_NO_SWITCH = ("this numpy has no numpy._core.multiarray._set_madvise_hugepage (numpy < 2 keeps "
              "it elsewhere): dlsr.memory.small_pages is then a no-op, with nothing to check")
multiarray = pytest.importorskip("numpy._core.multiarray", reason=_NO_SWITCH)
if not hasattr(multiarray, "_get_madvise_hugepage"):
    pytest.skip(_NO_SWITCH, allow_module_level=True)


@pytest.mark.parametrize("before", [True, False])
def test_small_pages_turns_the_advice_off_and_restores_it(before):
    previous = multiarray._set_madvise_hugepage(before)
    try:
        with small_pages():
            assert multiarray._get_madvise_hugepage() is False
            with small_pages():  # nested
                assert multiarray._get_madvise_hugepage() is False
            assert multiarray._get_madvise_hugepage() is False
        assert multiarray._get_madvise_hugepage() is before
        with pytest.raises(RuntimeError), small_pages():
            raise RuntimeError("restored on errors too")
        assert multiarray._get_madvise_hugepage() is before
    finally:
        multiarray._set_madvise_hugepage(previous)


def test_overlapping_blocks_in_threads_restore_once_the_last_ends():
    previous = multiarray._set_madvise_hugepage(True)
    try:
        inside, release = threading.Event(), threading.Event()

        def worker():
            with small_pages():
                inside.set()
                release.wait(10)

        t = threading.Thread(target=worker)
        with small_pages():
            t.start()
            assert inside.wait(10)
        # this thread's block ended first: the other one still holds the switch off
        assert multiarray._get_madvise_hugepage() is False
        release.set()
        t.join(10)
        assert multiarray._get_madvise_hugepage() is True
    finally:
        multiarray._set_madvise_hugepage(previous)


def _faults_of_second_allocation(nbytes):
    """Minor page faults taken by filling a fresh array after one of the same size was freed."""
    resource = pytest.importorskip("resource", reason="page-fault counts need the resource "
                                   "module (Unix)")
    np = pytest.importorskip("numpy")
    with small_pages():  # 4 kB pages: one fault per page, whatever numpy advises
        a = np.ones(nbytes // 8)
        del a
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        b = np.ones(nbytes // 8)
        after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        del b
    return after - before


def test_reused_heap_keeps_freed_blocks_and_restores_on_leaving():
    from dlsr import memory as _memory

    if _memory._libc is None:
        pytest.skip("the C library is not glibc: reused_heap is a no-op there")
    size = 64 * 2**20  # above glibc's largest mmap threshold (32 MB): mmapped by default
    pages = size // 4096
    outside = _faults_of_second_allocation(size)
    with _memory.reused_heap():
        with _memory.reused_heap():  # nested
            _faults_of_second_allocation(size)
        inside = _faults_of_second_allocation(size)  # the outer block still holds it
    after = _faults_of_second_allocation(size)
    mid = 8 * 2**20  # below the 32 MB ceiling the thresholds are left at
    after_mid = _faults_of_second_allocation(mid)
    assert outside > pages // 2  # a fresh mapping, faulted in again
    assert inside < pages // 10  # the freed block served again from the heap
    assert after > pages // 2  # mmap and trimming are back once the last block ended
    # but not at glibc's initial 128 kB: an 8 MB block freed is served again from the heap,
    # as in a process whose adaptive threshold has risen
    assert after_mid < mid // 4096 // 10
