"""BLAS thread limits through one cached threadpoolctl controller.

``threadpoolctl.threadpool_limits`` and ``threadpool_info`` scan the process's shared libraries
on every call (about 3 ms here): the 1,000 mini-batches of online dictionary learning spent
about 3 s of a 41 s fit in them. A controller made once lists the libraries once; its
``limit`` and ``info`` only query and set thread counts.
"""

from __future__ import annotations

import functools
import os


@functools.cache
def controller():
    """The process's ``threadpoolctl.ThreadpoolController``, made on first use."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def limit(limits: int = 1, user_api: str | None = None):
    """Context manager limiting the thread pools (all, or one ``user_api``) to ``limits``."""
    return controller().limit(limits=limits, user_api=user_api)


def one_blas_thread():
    """Context manager: BLAS and LAPACK limited to one thread inside (threadpoolctl).

    scipy's Delaunay computes one barycentric transform per simplex with tiny LAPACK calls; with
    threaded OpenBLAS on a busy machine each call waits for the thread pool: measured under load
    3 on 2 cores, 10.5 s instead of 0.28 s for 100 rectangle images. The detectors' scoring runs
    its own threads and wants BLAS on one. threadpoolctl lets one Python thread at a time
    control OpenBLAS: called in another thread meanwhile, this changes nothing and that
    thread's limits apply (the callers set them in the calling thread).
    """
    return limit(1, user_api="blas")


def blas_libraries() -> list[dict]:
    """The BLAS libraries loaded in this process: ``internal_api``, ``version`` and
    ``architecture`` (OpenBLAS's kernel set, its core type, chosen from the CPU at load time or
    by ``OPENBLAS_CORETYPE``). Worker processes inherit the environment, so the same choice.

    Products, and so the last bits of every result, follow the kernel set; where a result is
    chaotic in its inputs (the physics of a dropped object), whole outcomes can.
    """
    return [{k: lib.get(k) for k in ("internal_api", "version", "architecture")}
            for lib in controller().info() if lib.get("user_api") == "blas"]


def blas_threads() -> int:
    """Threads BLAS may use now (1 when no BLAS library is loaded)."""
    return max([lib.num_threads for lib in controller().lib_controllers
                if lib.user_api == "blas"] or [1])


def thread_budget() -> int:
    """Threads this process should run its own work in: the CPUs it may run on, capped by the
    ``OMP_NUM_THREADS`` environment variable when that is a positive integer.

    A process that shares the machine with other workers of the same job is given its share of
    the cores that way: joblib's loky workers get ``cpu_count() // n_jobs`` (its
    ``inner_max_num_threads`` default), Ray's tasks their ``num_cpus``. Threads beyond that
    share compete with the other workers for the same cores.
    """
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    cap = os.environ.get("OMP_NUM_THREADS", "").strip()
    if cap.isdigit() and int(cap) > 0:
        n = min(n, int(cap))
    return max(1, n)
