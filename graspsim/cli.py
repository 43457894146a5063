"""The ``graspsim`` command line.

Each subcommand lives in its own module under :mod:`graspsim.commands` and exposes
``register(subparsers)``; it only parses arguments and calls a library function that the tests
call directly.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import signal
import sys
import threading

# Subcommand modules, in the order `graspsim --help` lists them.
COMMANDS = [
    "run",
    "show",
    "detect",
    "benchmark",
    "trials",
    "train",
    "dataset",
    "export",
    "patches",
    "score",
    "compare",
    "objects",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="graspsim",
        description="DLSR grasp detection with simulation in the loop.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"graspsim.commands.{name}").register(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived (``kill``, a batch scheduler's cancel or time limit).

    A :class:`KeyboardInterrupt`, so that it unwinds as Ctrl-C does: joblib stops the loky
    workers, Ray is shut down, files being written are closed. Left to Python's default, SIGTERM
    ends the main process at once and leaves its loky workers running until their idle timeout.
    """


def stop_reason(exc: KeyboardInterrupt) -> tuple[str, int]:
    """``("terminated", 143)`` for :class:`Terminated`, else ``("interrupted", 130)``: the word a
    command prints and its exit code (the shell's 128 + signal number)."""
    return ("terminated", 143) if isinstance(exc, Terminated) else ("interrupted", 130)


def _terminate(signum, frame):
    raise Terminated


@contextlib.contextmanager
def sigterm_unwinds():
    """SIGTERM raises :class:`Terminated` inside the block (main thread only); the previous
    handler is restored after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose > 1 else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        with sigterm_unwinds():
            result = args.func(args)
    except (FileNotFoundError, ValueError) as exc:
        # Bad input is reported in one line naming the file or item, not as a stack trace.
        return _error(args.command, exc)
    except OSError as exc:
        if exc.filename is None:  # not about a file the user gave: a real failure
            raise
        return _error(args.command, exc)  # a folder given as a file, no permission, ...
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: one line, the shell's exit code
        word, code = stop_reason(exc)
        print(f"graspsim {args.command}: {word}", file=sys.stderr)
        return code
    return int(result or 0)


def _error(command: str, exc: BaseException) -> int:
    """Print ``graspsim CMD: error: MESSAGE`` on one line of stderr; the exit code 2."""
    message = " ".join(str(exc).split()) or type(exc).__name__
    print(f"graspsim {command}: error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
