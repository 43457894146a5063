"""The joblib executor: same results on every backend, in task order, streamed."""

from __future__ import annotations

import gc
import warnings

import numpy as np
import pytest

from graspsim.runtime.executor import Executor, task_seeds


def _draw(seed):
    return float(np.random.default_rng(seed).normal())


def _pair(a, b):
    return a * 10 + b


def test_task_seeds_are_stable_and_distinct():
    s = task_seeds(3, 50)
    assert s == task_seeds(3, 50)
    assert len(set(s)) == 50
    assert s != task_seeds(4, 50)


def test_loky_matches_sequential_in_order():
    seeds = task_seeds(0, 12)
    seq = Executor("sequential", progress=False).map(_draw, seeds)
    loky = Executor("loky", n_jobs=2, progress=False).map(_draw, seeds)
    assert seq == loky
    assert seq == [_draw(s) for s in seeds]


def test_star_arguments():
    out = Executor("sequential", progress=False).map(_pair, [(1, 2), (3, 4)], star=True)
    assert out == [12, 34]


def test_bad_backend_and_address():
    with pytest.raises(ValueError, match="backend"):
        Executor("dask")
    with pytest.raises(ValueError, match="address"):
        Executor("loky", address="127.0.0.1:6379")


def test_ray_matches_loky():
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install '.[ray]')")
    import sys

    from ray import cloudpickle

    # Ray workers cannot import this test module: ship its functions by value.
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    seeds = task_seeds(1, 10)
    loky = Executor("loky", n_jobs=2, progress=False).map(_draw, seeds)
    ray_out = Executor("ray", n_jobs=2, progress=False).map(_draw, seeds)
    assert ray_out == loky


def test_leaving_the_stream_early_stops_the_workers_quietly(pid_after, still_running):
    # An error while the caller handles a result (as Ctrl-C or SIGTERM there): the pending
    # tasks are cancelled and the loky workers stopped, without joblib's "tasks cancelled"
    # warning (an error under this suite's filterwarnings).
    workers = set()
    stream = Executor("loky", n_jobs=2, progress=False).imap(pid_after, [0.05] * 4 + [30.0] * 4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(RuntimeError, match="writing failed"):
            for i, pid in enumerate(stream):
                workers.add(pid)
                if i == 3:
                    raise RuntimeError("writing failed")
        del stream
        gc.collect()
    assert [str(w.message) for w in caught] == []
    assert workers and not still_running(workers)
