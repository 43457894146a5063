"""Tasks that the tests hand to loky workers.

A worker unpickles a task by its module's name. Functions defined in a ``conftest.py`` are
pickled as ``conftest.<name>``, and with two ``conftest.py`` files in the suite a worker may
import the other one (``tests/conftest.py``) and not find the function: the tasks live here,
under a name no other module of the suite has.
"""

from __future__ import annotations

import os
import time


def pid_after(seconds: float) -> int:
    """Sleep ``seconds``, then return the worker's process id."""
    time.sleep(seconds)
    return os.getpid()


def depth_source(sample) -> tuple[str, str | None, str]:
    """The class of a sample's depth array as the worker received it, the file it maps (None
    for an array in memory) and the sha256 of its values (C order)."""
    import hashlib

    import numpy as np

    depth = sample.depth
    digest = hashlib.sha256(np.ascontiguousarray(depth).tobytes()).hexdigest()
    return type(depth).__name__, getattr(depth, "filename", None), digest
