"""The scoped switch of numpy's transparent-huge-page advice."""

from __future__ import annotations

import threading

import pytest

from dlsr._memory import small_pages

_NO_SWITCH = ("this numpy has no numpy._core.multiarray._set_madvise_hugepage (numpy < 2 keeps "
              "it elsewhere): dlsr._memory.small_pages is then a no-op, with nothing to check")
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
