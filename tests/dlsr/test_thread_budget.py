"""The process's share of the cores (dlsr._threads.thread_budget), which the dense and lattice
detectors use for their threads when none is given."""

import os

import pytest
from joblib import Parallel, delayed

from dlsr._threads import thread_budget


def _available():
    return len(os.sched_getaffinity(0))


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="needs os.sched_getaffinity")
@pytest.mark.parametrize(("value", "expected"), [
    (None, "all"), ("1", 1), ("100000", "all"), ("0", "all"), ("two", "all"), ("", "all"),
])
def test_the_budget_is_the_available_cpus_capped_by_omp_num_threads(monkeypatch, value,
                                                                    expected):
    if value is None:
        monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("OMP_NUM_THREADS", value)
    assert thread_budget() == (_available() if expected == "all" else expected)


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="needs os.sched_getaffinity")
def test_two_loky_workers_each_get_at_most_half_the_cpus():
    budgets = Parallel(n_jobs=2, backend="loky")(delayed(thread_budget)() for _ in range(2))
    assert all(1 <= b <= max(1, _available() // 2) for b in budgets)
