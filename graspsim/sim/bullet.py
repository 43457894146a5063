"""A pybullet simulator wrapper that owns its own connection.

Every :class:`Simulation` holds a private ``BulletClient`` in DIRECT mode (rendering through
TinyRenderer, no display); there is no global connection, so several instances can live in one
process (and one per worker process in parallel runs).

Determinism: a scene is always rebuilt from scratch with ``resetSimulation`` followed by the same
loads in the same order (see :func:`graspsim.sim.scene.build_scene`), and the physics parameters are
set again after every reset, including ``deterministicOverlappingPairs``. Given the same seed and
the same commands the result is bit-for-bit the same; ``restoreState`` is not relied upon.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile

__all__ = ["Simulation", "TIME_STEP", "connect", "worker_sim", "renew_worker_sim",
           "quiet_c_output", "pybullet", "pybullet_data", "BulletClient"]


def _flush_c_streams() -> None:
    """Flush C stdio buffers (pybullet's printf) so they land where fd 1 points now."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def quiet_c_output(fds: tuple[int, ...] = (1, 2), logger=None):
    """Keep what C libraries write to file descriptors ``fds`` off the terminal in the block.

    pybullet prints ``pybullet build time: ...`` when imported and ``argv[0]=`` when a client
    connects, and V-HACD its whole log, from C straight to the process's stdout/stderr, which
    :data:`sys.stdout` redirection does not catch; a command whose stdout is JSON would be
    spoiled. Without ``logger`` the output goes to ``/dev/null``; with a
    :class:`logging.Logger` it is captured in a temporary file and each line logged at debug
    level after the block. Python's own streams are flushed first and C's before the
    descriptors are restored, so nothing written before or after the block is lost or delayed.
    Where a descriptor cannot be duplicated (closed), the block runs unchanged.
    """
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    _flush_c_streams()
    saved: list[tuple[int, int]] = []
    capture = None
    try:
        if logger is None:
            sink = os.open(os.devnull, os.O_WRONLY)
        else:
            capture = tempfile.TemporaryFile()
            sink = os.dup(capture.fileno())
    except OSError:
        yield
        return
    try:
        for fd in fds:
            try:
                saved.append((fd, os.dup(fd)))
            except OSError:
                continue
            os.dup2(sink, fd)
        yield
    finally:
        _flush_c_streams()
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        os.close(sink)
        if capture is not None:
            capture.seek(0)
            for line in capture.read().decode("utf-8", "replace").splitlines():
                if line.strip():
                    logger.debug("%s", line.rstrip())
            capture.close()


# Every pybullet import of the package goes through here (``from .sim import pybullet``).
with quiet_c_output():
    import pybullet
    import pybullet_data
    from pybullet_utils.bullet_client import BulletClient


def connect() -> BulletClient:
    """A new private pybullet client in DIRECT mode, its connection banner silenced."""
    with quiet_c_output():
        return BulletClient(connection_mode=pybullet.DIRECT)

TIME_STEP = 1.0 / 240.0  #: s; pybullet's default and the step VGN uses.


class Simulation:
    """A private pybullet world.

    Parameters
    ----------
    time_step : float
        Physics step, seconds (default 1/240 s).
    solver_iterations : int
        Constraint-solver iterations per step.
    gravity : float
        Downward gravitational acceleration, m/s^2.

    Attributes
    ----------
    client : pybullet_utils.bullet_client.BulletClient
        The connection; pass it to :func:`graspsim.sim.objects.load_object` and the camera.
    steps : int
        Physics steps taken since the last :meth:`reset`.
    """

    def __init__(self, time_step: float = TIME_STEP, solver_iterations: int = 50,
                 gravity: float = 9.81):
        self.time_step = time_step
        self.solver_iterations = solver_iterations
        self.gravity = gravity
        self.client = connect()
        self.steps = 0
        self.reset()

    def reset(self) -> None:
        """Empty the world (``resetSimulation``) and set the physics parameters again."""
        c = self.client
        c.resetSimulation()
        c.setGravity(0.0, 0.0, -self.gravity)
        c.setPhysicsEngineParameter(
            fixedTimeStep=self.time_step,
            numSolverIterations=self.solver_iterations,
            numSubSteps=0,
            deterministicOverlappingPairs=1,
            enableFileCaching=1,
        )
        self.steps = 0

    def step(self, n: int = 1) -> None:
        """Advance the world by ``n`` steps of ``time_step`` seconds."""
        for _ in range(n):
            self.client.stepSimulation()
        self.steps += n

    def close(self) -> None:
        """Disconnect (idempotent)."""
        if getattr(self, "client", None) is not None:
            try:
                self.client.disconnect()
            except pybullet.error:
                pass
            self.client = None

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


_WORKER: dict[int, Simulation] = {}


def worker_sim() -> Simulation:
    """The simulator of this process, made on first use (one per worker process of a parallel
    run; made again after a fork, whose parent's connection the child cannot use).

    Returns
    -------
    Simulation
    """
    pid = os.getpid()
    sim = _WORKER.get(pid)
    if sim is None:
        sim = Simulation()
        _WORKER.clear()
        _WORKER[pid] = sim
    return sim


def renew_worker_sim() -> Simulation:
    """Replace this process's simulator (:func:`worker_sim`) by a new connection.

    A scene is rebuilt after ``resetSimulation`` in the reused connection, and whatever the
    physics server keeps across resets stays. A scene that could not be made there is made
    again in a new connection, as a fresh process would make it (see
    :func:`graspsim.data.datagen.make_dataset`).

    Returns
    -------
    Simulation
        The new simulator, which :func:`worker_sim` returns from now on in this process.
    """
    old = _WORKER.pop(os.getpid(), None)
    if old is not None:
        old.close()
    return worker_sim()
