"""BLAS thread limits through one cached threadpoolctl controller.

``threadpoolctl.threadpool_limits`` and ``threadpool_info`` scan the process's shared libraries
on every call (about 3 ms here): the 1,000 mini-batches of online dictionary learning spent
about 3 s of a 41 s fit in them. A controller made once lists the libraries once; its
``limit`` and ``info`` only query and set thread counts.
"""

from __future__ import annotations

import functools


@functools.cache
def controller():
    """The process's ``threadpoolctl.ThreadpoolController``, made on first use."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def limit(limits: int = 1, user_api: str | None = None):
    """Context manager limiting the thread pools (all, or one ``user_api``) to ``limits``."""
    return controller().limit(limits=limits, user_api=user_api)


def blas_threads() -> int:
    """Threads BLAS may use now (1 when no BLAS library is loaded)."""
    return max([lib.num_threads for lib in controller().lib_controllers
                if lib.user_api == "blas"] or [1])
