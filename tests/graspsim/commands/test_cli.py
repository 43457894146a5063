"""The ``graspsim`` entry point: SIGTERM (a batch scheduler's cancel or time limit) unwinds as
Ctrl-C does."""

from __future__ import annotations

import os
import signal
import sys
import time

import pytest

from graspsim.cli import main
from graspsim.runtime.executor import Executor

pytestmark = pytest.mark.skipif(
    sys.platform == "win32",
    reason="Windows has no SIGTERM delivery: os.kill(pid, SIGTERM) ends the process at once, "
           "so the handler under test never runs (and pytest would end with it)")


@pytest.fixture
def sigterm_caught_here():
    """A SIGTERM that graspsim does not handle is recorded here instead of ending pytest."""
    seen = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    yield seen
    signal.signal(signal.SIGTERM, previous)


def _terminate_self(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGTERM)
    end = time.monotonic() + 10.0  # a handler that raises ends this loop at once
    while time.monotonic() < end:
        time.sleep(0.01)
    return 0


def test_sigterm_ends_a_command_in_one_line(monkeypatch, capsys, sigterm_caught_here):
    handler = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr("graspsim.eval.compare.compare_folders", _terminate_self)
    assert main(["compare", "a", "b"]) == 143
    assert capsys.readouterr().err.strip() == "graspsim compare: terminated"
    assert sigterm_caught_here == []  # graspsim's handler took it
    assert signal.getsignal(signal.SIGTERM) is handler  # and gave the previous one back


def test_sigterm_on_run_says_how_to_continue(tmp_path, monkeypatch, capsys,
                                             sigterm_caught_here):
    monkeypatch.setattr("graspsim.pipeline.run_job", _terminate_self)
    assert main(["run", "--quick", "--out", str(tmp_path / "r")]) == 143
    assert capsys.readouterr().err.strip() == (
        f"graspsim run: terminated; what was finished is saved, continue with "
        f"`graspsim run --resume {tmp_path / 'r'}`")


def test_sigterm_stops_the_loky_workers(monkeypatch, capsys, sigterm_caught_here, pid_after,
                                        still_running):
    workers = set()

    def busy(*args, **kwargs):
        # Four short tasks, then long ones: SIGTERM comes while the workers run them.
        tasks = [0.05] * 4 + [30.0] * 4
        for i, pid in enumerate(Executor("loky", n_jobs=2, progress=False).imap(pid_after,
                                                                                 tasks)):
            workers.add(pid)
            if i == 3:
                os.kill(os.getpid(), signal.SIGTERM)
        return 0

    monkeypatch.setattr("graspsim.eval.compare.compare_folders", busy)
    assert main(["compare", "a", "b"]) == 143
    assert "terminated" in capsys.readouterr().err
    assert workers and os.getpid() not in workers
    assert not still_running(workers), "loky workers still running after SIGTERM"


@pytest.mark.parametrize("command", ["dataset", "export", "trials", "patches", "score",
                                     "show", "detect"])
def test_help_shows_every_default(command):
    """Every option with a default value says it in its help (``dataset --help`` did not)."""
    import argparse

    from graspsim.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    parser = sub.choices[command]
    flags = (None, False, True, argparse.SUPPRESS)
    missing = [a.option_strings[0] for a in parser._actions
               if a.option_strings and not any(a.default is x for x in flags)
               and a.default != [] and "default" not in (a.help or "")]
    assert not missing, f"graspsim {command} --help shows no default for {missing}"
    text = parser.format_help()
    if command == "dataset":
        assert "(default: 48)" in text and "(default: 0)" in text
