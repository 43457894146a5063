"""One executor for every embarrassingly parallel step (labelling, trials, CV cells, detection).

Built on joblib: ``backend="loky"`` (default) uses local processes; ``backend="ray"`` sends the
same tasks to a Ray cluster through Ray's joblib backend (``ray.util.joblib``), either a local
instance started on demand or an existing cluster given by ``address="HOST:PORT"``.

Results are identical across backends for the same inputs because every task receives its own
seed (derived with :class:`numpy.random.SeedSequence` by the caller, never from a worker's
global state) and results come back in task order.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from joblib import Parallel, delayed, parallel_config
from tqdm.auto import tqdm

__all__ = ["Executor", "task_seeds"]

log = logging.getLogger(__name__)

BACKENDS = ("loky", "threading", "sequential", "ray")


def task_seeds(seed: int, n: int) -> list[int]:
    """``n`` independent 32-bit seeds derived from ``seed`` (stable across runs and backends)."""
    return [int(s) for s in np.random.SeedSequence(seed).generate_state(n)]


@dataclass
class Executor:
    """Map a function over tasks on local cores or a Ray cluster.

    Parameters
    ----------
    backend : {"loky", "threading", "sequential", "ray"}
    n_jobs : int
        Worker count (-1: all local cores, or all cluster CPUs with Ray).
    address : str or None
        Ray only: ``"HOST:PORT"`` of an existing cluster, ``"auto"``, or None to start a local
        instance.
    progress : bool
        Show a tqdm progress bar with ETA.
    """

    backend: str = "loky"
    n_jobs: int = -1
    address: str | None = None
    progress: bool = True

    def __post_init__(self):
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.address is not None and self.backend != "ray":
            raise ValueError("address is only meaningful with backend='ray'")

    @contextlib.contextmanager
    def activate(self):
        """Make this backend joblib's default inside the block.

        Code that uses ``joblib.Parallel`` without naming a backend (for example
        :func:`dlsr.recognition.nested_cv_cell`, whose folds run in parallel) then runs its
        tasks here, Ray included.
        """
        if self.backend == "sequential":
            with parallel_config(backend="sequential"):
                yield
            return
        if self.backend != "ray":
            with parallel_config(backend=self.backend, n_jobs=self.n_jobs):
                yield
            return
        try:
            # deferred, optional: Ray (the ray extra)
            import ray
            from ray.util.joblib import register_ray
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise ValueError(
                "backend 'ray' needs Ray: pip install 'dlsr-graspsim[ray]'"
            ) from exc
        started = False
        if not ray.is_initialized():
            kwargs = {"address": self.address} if self.address else {}
            if not self.address:
                # A local instance stays on the loopback interface.
                kwargs.update(include_dashboard=False, log_to_driver=False,
                              _node_ip_address="127.0.0.1")
            ray.init(**kwargs)
            started = True
        register_ray()
        try:
            with parallel_config(backend="ray", n_jobs=self.n_jobs):
                yield
        finally:
            if started:
                ray.shutdown()

    def imap(self, fn: Callable[..., Any], tasks: Iterable[Sequence[Any]] | Iterable[Any],
             desc: str = "tasks", total: int | None = None, star: bool = False) -> Iterator[Any]:
        """Yield ``fn(task)`` (or ``fn(*task)`` with ``star``) in task order, as they finish.

        Results arrive in order, so a caller can write each one to disk as it comes and lose
        nothing finished when interrupted.
        """
        tasks = list(tasks)
        total = len(tasks) if total is None else total

        def calls(chunk):
            return (delayed(fn)(*t) if star else delayed(fn)(t) for t in chunk)

        with self.activate(), tqdm(total=total, desc=desc, disable=not self.progress) as bar:
            if self.backend != "ray":
                outputs = Parallel(return_as="generator")(calls(tasks))
                try:
                    for result in outputs:
                        bar.update(1)
                        yield result
                finally:
                    _close_quietly(outputs)
                return
            # Ray's joblib backend has no generator output: stream chunk by chunk so finished
            # work still reaches the caller (and disk) before the whole map ends. (Deferred,
            # optional: Ray, the ray extra.)
            import ray

            width = max(1, int(ray.cluster_resources().get("CPU", 1)))
            chunk = 4 * width
            for start in range(0, len(tasks), chunk):
                for result in Parallel()(calls(tasks[start:start + chunk])):
                    bar.update(1)
                    yield result

    def map(self, fn: Callable[..., Any], tasks, desc: str = "tasks", star: bool = False):
        """``list(self.imap(...))``."""
        return list(self.imap(fn, tasks, desc=desc, star=star))


def _close_quietly(outputs) -> None:
    """Close a joblib output generator, also one its caller left early.

    Leaving early (an error, Ctrl-C or SIGTERM while the caller handled a result) cancels the
    pending tasks and stops the workers; joblib then warns that tasks were cancelled and suggests
    a shorter task list, advice meant for a loop that breaks on purpose, so the warning is
    silenced here. Closing a generator that ran to its end does nothing.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*adjusting the input task iterator",
                                category=UserWarning)
        outputs.close()
