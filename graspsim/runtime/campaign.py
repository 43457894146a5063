"""Resumable campaigns: numbered items run on an executor, each record appended to a JSONL file
as it comes, and a folder that a resume must reopen with the same configuration.

A campaign folder holds ``config.json`` (what the caller says the campaign is: any JSON
dictionary) and ``<unit>.jsonl`` (one record per finished item, each with its ``index``).
Rerunning after a kill drops a torn last line, keeps every complete record and runs only the
missing indices (none repeated, none lost); a folder of another configuration is refused. What
the items are (trials, clutter rounds, scored images, dataset scenes) is the caller's business:
this module knows nothing of trials, scenes or detectors. A caller whose configuration gained
fields passes ``upgrade``, which turns an old folder's configuration into what it would record
today, so that folders written before still resume.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from dlsr.records import (
    CorruptFileError,
    read_json,
    read_jsonl,
    write_json_atomic,
    write_text_atomic,
)

from .executor import Executor

__all__ = ["read_done", "open_campaign", "run_missing", "make_executor", "run_campaign",
           "skipped_record", "is_skipped"]

log = logging.getLogger(__name__)


def skipped_record(index: int, error: Exception, **fields) -> dict:
    """The record a campaign keeps for an item that could not be run (a scene that could not
    be made): ``index``, ``fields`` and ``skipped`` (the reason). Logged as a warning.

    A skip is a finished record: a resume does not run the item again, and
    :func:`run_campaign` leaves it out of the summary's figures and lists it in ``skipped``.

    Parameters
    ----------
    index : int
    error : Exception
        Its message is the reason.
    **fields
        Recorded too (a trial's ``seed``).

    Returns
    -------
    dict
    """
    log.warning("%s: skipped", error)
    return {"index": index, **fields, "skipped": str(error)}


def is_skipped(record: dict) -> bool:
    """Whether a record is a skip (:func:`skipped_record`).

    Parameters
    ----------
    record : dict

    Returns
    -------
    bool
    """
    return "skipped" in record


def read_done(path) -> dict[int, dict]:
    """Complete records of a resumable JSONL file by their ``index`` (the first of repeats).

    A torn last line (a kill during a write) is dropped and the file repaired, so appended
    records start on a line of their own (see :func:`dlsr.records.read_jsonl`).

    Parameters
    ----------
    path : str or Path
        The JSONL file (missing: no record).

    Returns
    -------
    dict of int to dict

    Raises
    ------
    dlsr.records.CorruptFileError
        For any other bad line, or an ``index`` that is not a non-negative integer (naming the
        file and line).
    """
    path = Path(path)
    done: dict[int, dict] = {}
    for rec in read_jsonl(path, required=("index",), repair=True):
        i = rec["index"]
        if isinstance(i, bool) or not isinstance(i, int) or i < 0:
            raise CorruptFileError(f"results file {path}: a record has index {i!r}, "
                                   "not a non-negative integer")
        done.setdefault(i, rec)
    return done


def open_campaign(out, meta: dict, filename: str,
                  upgrade: Callable[[dict, dict, Path], dict] | None = None):
    """Create or reopen a campaign folder: refuse another configuration, read finished records.

    Parameters
    ----------
    out : str or Path or None
        The folder (created when missing); None for a campaign kept in memory.
    meta : dict
        The campaign's configuration (JSON values), written to ``out/config.json``.
    filename : str
        The records' file in ``out`` (``"trials.jsonl"``).
    upgrade : callable or None
        ``upgrade(old, meta, path)`` gives the configuration an existing folder's
        ``config.json`` (``old``, read from ``path``) would record today, before it is
        compared with ``meta``; it may raise a ``ValueError`` of its own (naming the folder).

    Returns
    -------
    out : Path or None
    jsonl : Path or None
        The records' file.
    done : dict of int to dict
        Finished records by index (:func:`read_done`); empty for a new or in-memory campaign.

    Raises
    ------
    ValueError
        When ``out`` holds a campaign of another configuration.
    """
    if out is None:
        return None, None, {}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.json"
    if cfg_path.exists():
        old = read_json(cfg_path, "campaign configuration")
        if upgrade is not None:
            old = upgrade(old, meta, cfg_path)
        if {k: old.get(k) for k in meta} != json.loads(json.dumps(meta)):
            raise ValueError(
                f"{out} holds trials of another configuration ({cfg_path}); use a new folder"
            )
    write_json_atomic(cfg_path, meta)
    jsonl = out / filename
    return out, jsonl, read_done(jsonl)


def run_missing(fn: Callable, tasks: list, done: dict, jsonl, executor, desc: str,
                on_record: Callable[[dict], None] | None = None) -> int:
    """Run ``fn(*task)`` for every task and keep each record as it comes.

    Each record (a dict with an ``index``) is appended to ``jsonl`` and flushed, and put in
    ``done`` by its ``index``.

    Parameters
    ----------
    fn : callable
        Returns one record per task; it must be importable by the executor's workers.
    tasks : list of tuple
        The arguments of each call.
    done : dict of int to dict
        Updated in place.
    jsonl : Path or None
        None keeps the records in memory only.
    executor : graspsim.runtime.executor.Executor or None
        Where the tasks run (may be None when ``tasks`` is empty).
    desc : str
        The progress bar's label.
    on_record : callable or None
        Sees each record first (and may take fields out of it).

    Returns
    -------
    int
        The number of new records.
    """
    new = 0
    if not tasks:
        return new
    fh = open(jsonl, "a") if jsonl is not None else None  # noqa: SIM115
    try:
        for rec in executor.imap(fn, tasks, desc=desc, star=True):
            if on_record is not None:
                on_record(rec)
            done[rec["index"]] = rec
            new += 1
            if fh is not None:
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
    finally:
        if fh is not None:
            fh.close()
    return new


def make_executor(executor: Executor | None, n_jobs: int, progress: bool) -> Executor:
    """``executor`` when given, else local processes (loky) for ``n_jobs != 1`` or a
    sequential executor.

    Parameters
    ----------
    executor : Executor or None
    n_jobs : int
    progress : bool

    Returns
    -------
    Executor
    """
    return executor or Executor(backend="loky" if n_jobs != 1 else "sequential",
                                n_jobs=n_jobs, progress=progress)


def run_campaign(task: Callable, unit: str, meta: dict, out, n: int,
                 task_args: Callable[[int], Iterable], summarize: Callable[[list], dict],
                 markdown: Callable[[dict], str], executor: Executor | None = None,
                 n_jobs: int = 1, progress: bool = False,
                 on_record: Callable[[dict], None] | None = None,
                 upgrade: Callable[[dict, dict, Path], dict] | None = None) -> dict:
    """Run (or finish) items ``0 .. n-1`` of a resumable campaign and write its summaries.

    Parameters
    ----------
    task : callable
        ``task(*task_args(i))`` runs item ``i`` and returns its record (a dict with
        ``"index": i``).
    unit : str
        What an item is (``"trials"``): the records go to ``out/<unit>.jsonl``.
    meta : dict
        The configuration (:func:`open_campaign`).
    out : str or Path or None
        The folder; None keeps everything in memory (no resume).
    n : int
        Items.
    task_args : callable
        Item index to the task's arguments.
    summarize : callable
        Records (sorted by index) to a summary dict.
    markdown : callable
        Summary to the text of ``summary.md``.
    executor : Executor or None
        Where items run (default: :func:`make_executor` of ``n_jobs``).
    n_jobs : int
    progress : bool
    on_record : callable or None
        Sees each new record before it is kept (:func:`run_missing`).
    upgrade : callable or None
        See :func:`open_campaign`.

    Returns
    -------
    dict
        ``summarize(records)`` over the items that ran (not the skips,
        :func:`skipped_record`) with ``meta``, ``skipped`` (``index`` and ``reason`` of each
        skip), ``<unit>_per_second`` (None when nothing ran) and ``n_jobs``, also written to
        ``out/summary.json`` (and ``summary.md``), then ``records`` (sorted by index, skips
        left out).
    """
    out, jsonl, done = open_campaign(out, meta, f"{unit}.jsonl", upgrade)
    todo = [i for i in range(n) if i not in done]
    if done:
        log.info("resuming: %d of %d %s already done", n - len(todo), n, unit)
    t0 = time.perf_counter()
    tasks = [tuple(task_args(i)) for i in todo]
    new = run_missing(task, tasks, done, jsonl,
                      make_executor(executor, n_jobs, progress) if tasks else None, unit,
                      on_record)
    wall = time.perf_counter() - t0
    records = [done[i] for i in sorted(done) if i < n]
    skipped = [{"index": r["index"], "reason": r["skipped"]} for r in records if is_skipped(r)]
    records = [r for r in records if not is_skipped(r)]
    summary = summarize(records)
    summary.update(meta)
    summary["skipped"] = skipped
    summary[f"{unit}_per_second"] = (new / wall) if new and wall > 0 else None
    summary["n_jobs"] = n_jobs if executor is None else executor.n_jobs
    if out is not None:
        write_json_atomic(out / "summary.json", summary)
        write_text_atomic(out / "summary.md", markdown(summary))
    summary["records"] = records
    return summary
