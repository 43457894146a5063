"""Time and memory of the paper's Tables 1 and 2 at Cornell's size (one JSON object on stdout).

For each size (images), on the Cornell-sized stand-in (:mod:`graspsim.data.standin`, made or reused
under ``--standin``; the smaller sizes are its first images):

* **table1**: ``graspsim benchmark recognition`` with all 36 learner x encoder cells,
  ``--atoms 300``, nested 5 x 5 cross-validation, the paper's hyper-parameter grids
  (``--paper-grid``), image-wise;
* **table2**: ``graspsim benchmark table2``, the rows of the paper's Table 2 that it records
  (NKM-Natural, NKM-SC, OMP-Natural, RP-Natural), image-wise and object-wise, 5 folds, in one
  pass (the training sets, the NKM dictionary and each test image's work shared; the same
  records as one ``graspsim benchmark detection`` per row and split, which sizes measured
  before it was used ran: their timings say ``one_pass`` only when measured with it).

Each command runs as a child process with ``--jobs`` workers. Per size and table: ``wall_s``,
``cpu_s`` (the whole process tree's user + system seconds, from ``getrusage``),
``peak_pss_mb`` (the largest sum of the tree's proportional set sizes: the memory it holds,
pages shared between its processes counted once; sampled every 10 s), ``peak_rss_mb`` (the
largest sum of the tree's resident sets, which counts shared pages once per process, so it
bounds the proportional peak between samples; sampled every 0.2 s from ``/proc``),
``sampler_cpu_s`` (the CPU seconds the sampling itself took, on the same cores as the command;
measurements before 2026-12-07 read the proportional sizes every 0.2 s, which took 28 % of a
core beside a 7 GB tree, and did not record it: ``scripts/bench_sampler.py``) and ``stages``:
worker seconds per stage, read from the commands' own records --
Table 1: ``patches``, ``whitening``, ``dictionary`` (the representations), ``coding`` and
``svm_inner_cv``; Table 2: ``detection_per_image`` (mean seconds per test image and row; in
the one pass each row's seconds count the candidates and rectangle images it shares in full,
so ``detection``, their sum, is an upper bound of the pass's detection time), and
``phases_last_segment``: the wall seconds of the pass's training and detection phases in its
last run.
``rss_trace_mb`` is the peak memory in each tenth of the run's wall time (flat when nothing
accumulates across cells and folds). ``code`` names the commit that ran (``+dirty`` when
tracked files differed from it), ``cpu`` the processor (:func:`cpu_name`; a measurement of
several segments may span machines) and ``load_average`` the machine's 1-minute load before and
after: a measurement beside other work, or of older code, says so (one entry per part when a
command took several runs). ``growth`` gives, per table and stage, the exponent ``k``
of a least-squares fit of ``time = a * size^k`` over the sizes measured, and ``projected`` the
fit's ``wall_s`` and ``cpu_s`` at Cornell's 885 images when that size was not measured (a
projection, not a measurement). ``per_cell`` gives, per size, what each cell of Table 1 and
each row of Table 2 would cost alone (:func:`per_cell`). ``OUT/scale.md`` gives every size
measured so far as Markdown tables (:func:`scale_markdown`), for the README.

The stand-in is always Cornell's size (``--standin-images``), so a size means the same
images whichever sizes a run asks for; each size's record names its data (``data``: the
stand-in's labelled scenes and the sha256 of the subset's rectangles) and ``standin_blas`` (the
OpenBLAS kernels its stand-in was labelled with). A size measured on other data stops the run
with a message that names those kernels: a stand-in labelled with another kernel set differs in
a few scenes (:mod:`graspsim.data.standin`), and ``OPENBLAS_CORETYPE`` makes the same one again;
``--remeasure`` measures such a size again instead (its folders under ``--out`` removed). On the
same data, ``--remeasure`` measures the asked sizes' asked tables again (newer code, another
machine); a remeasurement stopped midway continues without the flag.

Finished commands are not run again (their output folders under ``--out`` are reused, and the
benchmarks themselves resume at the cell and fold), so a killed run continues; a command's
timing is kept in ``OUT/timings.json`` as soon as it finishes. A measurement longer than a
session is stopped with SIGTERM (or Ctrl-C): the running command saves and stops, the part it
ran (wall, CPU, peak memory) is kept in ``OUT/partial.json``, and the command that finishes it
adds those parts (``segments``: how many runs it took). The default ``--out``,
``results/cornell-scale``, is committed without its bulky files (the subsets, the saved
representations), so the next session continues it on a new machine. (``results/bench_scale``
holds the measurements of 2026-12-04 and 2026-12-05, made by the code before the Table 2 one
pass and the SVM's second pass, beside other work.)

Usage: python scripts/bench_scale.py --sizes 100,300,885 [--jobs 2] [--standin runs/standin]
       [--out results/cornell-scale] [--tables 1,2] [--remeasure]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from dlsr.records import read_json, write_json_atomic, write_text_atomic
from graspsim.cli import sigterm_unwinds, stop_reason
from graspsim.data.standin import CORNELL, standin_subset

TABLE2_ROWS = (("NKM", "Natural"), ("NKM", "SC"), ("OMP", "Natural"), ("RP", "Natural"))


def _pss_kb(pid: int) -> int:
    """Proportional set size of ``pid`` (kB): its private pages plus its share of pages it
    maps with other processes (0 when unreadable)."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as fh:
            for line in fh:
                if line.startswith("Pss:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return 0


PAGE_KB = os.sysconf("SC_PAGE_SIZE") // 1024
SAMPLE_EVERY = 0.2  # seconds between samples of the tree's resident sets and clock ticks
PSS_EVERY = 10.0  # seconds between samples of its proportional set sizes (smaps_rollup)


def _children(pid: int) -> list[int] | None:
    """The children of ``pid`` from /proc (every thread's ``children`` list; None when the
    kernel does not provide those lists)."""
    kids: list[int] = []
    try:
        tasks = list(os.scandir(f"/proc/{pid}/task"))
    except OSError:
        return kids
    for task in tasks:
        try:
            with open(f"{task.path}/children") as fh:
                kids.extend(int(c) for c in fh.read().split())
        except FileNotFoundError:
            if not os.path.exists(f"/proc/{pid}"):
                return kids  # the process ended
            return None  # no children lists in this kernel (CONFIG_PROC_CHILDREN)
        except OSError:
            continue
    return kids


def _parents() -> dict[int, list[int]]:
    """Every process's children, from a scan of /proc (when the kernel gives no lists)."""
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    return children


def _tree(root_pid: int, pss: bool = True) -> tuple[float, float | None, dict]:
    """Resident memory of ``root_pid`` and all its descendants (MiB): the sum of their
    resident sets and, with ``pss``, the sum of their proportional set sizes (shared pages
    counted once, not once per process: loky's memory-mapped arrays, the libraries; None
    without), and their user + system clock ticks per pid, from /proc.

    The tree is walked from ``root_pid`` through the kernel's children lists (a scan of /proc
    only where it has none), and each process's ``stat`` gives both its ticks and its resident
    set. ``smaps_rollup`` walks a process's page tables in the kernel, which costs CPU in
    proportion to the memory mapped (beside a 7 GB tree, 28 % of a core when read every 0.2 s),
    so the proportional sizes are read only when asked (:data:`PSS_EVERY`)."""
    scanned = None
    total, pss_kb, todo, mine = 0, 0, [root_pid], {}
    while todo:
        pid = todo.pop()
        if pid in mine:
            continue
        try:
            with open(f"/proc/{pid}/stat") as fh:
                stat = fh.read().rsplit(")", 1)[1].split()
            mine[pid] = int(stat[11]) + int(stat[12])  # utime, stime
            total += int(stat[21]) * PAGE_KB  # rss (pages)
        except (OSError, IndexError, ValueError):
            continue
        if pss:
            pss_kb += _pss_kb(pid)
        kids = _children(pid)
        if kids is None:
            scanned = _parents() if scanned is None else scanned
            kids = scanned.get(pid, [])
        todo.extend(kids)
    return total / 1024, (pss_kb / 1024 if pss else None), mine


class Interrupted(KeyboardInterrupt):
    """A timed command was stopped (SIGTERM or Ctrl-C) before it finished; ``segment`` is the
    part it ran (``wall_s``, ``cpu_s``, ``peak_rss_mb``, ``rss_trace_mb``), ``cause`` the
    stop itself (:class:`graspsim.cli.Terminated` for SIGTERM), which gives the exit code."""

    def __init__(self, segment: dict, cause: BaseException | None = None):
        super().__init__("interrupted")
        self.segment = segment
        self.cause = cause


def code_version() -> str | None:
    """The repository's commit, with ``+dirty`` when tracked files outside ``results/`` differ
    from it (None outside a git checkout): which code a timing measured."""
    repo = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.check_output(["git", "-C", str(repo), "rev-parse", "--short=12",
                                        "HEAD"], text=True, stderr=subprocess.DEVNULL).strip()
        # results/ is data, not code: a remeasurement removes its committed folders first
        dirty = subprocess.check_output(["git", "-C", str(repo), "status", "--porcelain",
                                         "--untracked-files=no", "--", ".",
                                         ":(exclude)results"], text=True,
                                        stderr=subprocess.DEVNULL).strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+dirty" if dirty else "")


def cpu_name() -> str:
    """The processor as /proc/cpuinfo names it, with its family and model (``"AMD EPYC, family
    26 model 2"``): segments of one measurement run on different machines say so."""
    fields = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        return "unknown"
    return (f"{fields.get('model name', 'unknown')}, family {fields.get('cpu family', '?')} "
            f"model {fields.get('model', '?')}")


def timed(cmd: list[str]) -> dict:
    """Run ``cmd``; its wall and CPU seconds and the peak memory of its process tree, with the
    code it ran (:func:`code_version`) and the machine's 1-minute load average before and
    after (anything else running inflates the wall time).

    Stopped by SIGTERM or Ctrl-C, the command is sent SIGTERM (the benchmarks save and stop)
    and :class:`Interrupted` carries the part it ran: CPU seconds from ``getrusage`` or, when
    larger (workers that were never waited for), the tree's ticks sampled from /proc.
    """
    version, load_before = code_version(), os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd)
    samples: list[tuple[float, float]] = []
    pss: list[float] = []
    ticks: dict = {}
    stop = threading.Event()

    sampler_cpu = [0.0]

    def sample():
        # the sampler's own CPU time (this thread's) is recorded: it runs beside the command
        # on the same cores, so what it takes the command does not get
        c0, next_pss = time.thread_time(), 0.0
        while not stop.wait(SAMPLE_EVERY):
            now_s = time.perf_counter() - t0
            with_pss = now_s >= next_pss
            mb, pss_mb, now = _tree(proc.pid, pss=with_pss)
            samples.append((now_s, mb))
            if with_pss:
                pss.append(pss_mb)
                next_pss = now_s + PSS_EVERY
            for pid, t in now.items():
                ticks[pid] = max(ticks.get(pid, 0), t)
            sampler_cpu[0] = time.thread_time() - c0

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    interrupted = None
    try:
        code = proc.wait()
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (graspsim.cli.Terminated)
        interrupted = exc
        proc.terminate()
        try:
            code = proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait()
    stop.set()
    thread.join()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    cpu = max(cpu, sum(ticks.values()) / os.sysconf("SC_CLK_TCK"))
    peak = max((m for _, m in samples), default=0.0)
    record = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "peak_rss_mb": round(peak, 1),
              "peak_pss_mb": round(max(pss, default=0.0), 1),
              "rss_trace_mb": rss_trace(samples, wall), "sampler_cpu_s": round(sampler_cpu[0], 2),
              "code": version, "cpu": cpu_name(),
              "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)]}
    if interrupted is not None:
        raise Interrupted(record, interrupted) from None
    if code != 0:
        raise SystemExit(f"bench_scale: {' '.join(cmd)} failed with exit code {code}")
    return record


def resumed(key: str, cmd: list[str], partial_path: Path) -> dict:
    """:func:`timed` across interruptions: the parts of ``key``'s earlier runs that were
    stopped (kept in ``partial_path``) are added to the run that finishes it -- wall and CPU
    seconds summed, the peak memory the largest, one ``rss_trace_mb`` per part -- and
    ``segments`` says how many runs it took (the benchmarks resume at the cell and fold, so
    a part's work is not done again; each restart re-reads the data, a few seconds)."""
    partial = read_json(partial_path, "partial timings") if partial_path.exists() else {}
    parts = partial.get(key, [])
    try:
        t = timed(cmd)
    except Interrupted as stop:
        partial[key] = [*parts, stop.segment]
        write_json_atomic(partial_path, partial, indent=1)
        raise
    if not parts:
        return t
    allp = [*parts, t]
    out = {"wall_s": round(sum(p["wall_s"] for p in allp), 2),
           "cpu_s": round(sum(p["cpu_s"] for p in allp), 2),
           "peak_rss_mb": max(p["peak_rss_mb"] for p in allp),
           "peak_pss_mb": max(p.get("peak_pss_mb", 0.0) for p in allp),
           "rss_trace_mb": [p["rss_trace_mb"] for p in allp], "segments": len(allp),
           "sampler_cpu_s": [p.get("sampler_cpu_s") for p in allp],
           "code": [p.get("code") for p in allp], "cpu": [p.get("cpu") for p in allp],
           "load_average": [p.get("load_average") for p in allp]}
    partial.pop(key, None)
    write_json_atomic(partial_path, partial, indent=1)
    return out


def rss_trace(samples, wall: float, n_bins: int = 10) -> list:
    """The peak of ``samples`` (``(seconds, MiB)`` pairs) in each of ``n_bins`` equal parts of
    ``wall`` seconds (None where a part has no sample)."""
    bins: list = [None] * n_bins
    for t, mb in samples:
        i = min(int(n_bins * t / wall), n_bins - 1) if wall > 0 else 0
        bins[i] = mb if bins[i] is None else max(bins[i], mb)
    return [None if b is None else round(b, 1) for b in bins]


def data_fingerprint(data: Path, made: dict) -> dict:
    """What a size was measured on: its images, the stand-in they come from (its size and
    labelled scenes) and the sha256 of the subset's rectangle files (the thinning)."""
    h = hashlib.sha256()
    for f in sorted(data.glob("*/pcd*c[pn]*.txt")):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return {"images": sum(1 for _ in data.glob("*/pcd*r.png")),
            "standin_images": made["reached"]["images"],
            "standin_labelled": made["labelled_fingerprint"], "rectangles": h.hexdigest()}


def blas_kernels(made: dict) -> str | None:
    """The OpenBLAS kernel sets a stand-in record names (``"SkylakeX"``; None if unrecorded)."""
    names = sorted({str(lib.get("architecture")) for lib in made.get("blas") or []
                    if lib.get("architecture")})
    return "/".join(names) or None


def other_data_message(size: int, row: dict, which: dict, made: dict, standin: Path,
                       out: Path) -> str:
    """Why size ``size`` is not measured on ``standin`` (its committed timings and folders were
    made on other data), and the two ways on."""
    old = row.get("data") or {}
    was = (f"stand-in {str(old.get('standin_labelled'))[:12]} of {old.get('standin_images')} "
           f"images, rectangles {str(old.get('rectangles'))[:12]}")
    now = (f"stand-in {which['standin_labelled'][:12]} of {which['standin_images']} images, "
           f"rectangles {which['rectangles'][:12]}")
    kernels = row.get("standin_blas")
    how = (f"OPENBLAS_CORETYPE={kernels.split('/')[0]}" if kernels else
           "OPENBLAS_CORETYPE set to the BLAS kernels of the machine that made it")
    return (f"bench_scale: size {size} in {out} was measured on {was}; {standin} gives {now} "
            f"(labelled with {blas_kernels(made) or 'unrecorded'} kernels, measured on "
            f"{kernels or 'unrecorded'} ones: another kernel set labels a few scenes otherwise, "
            f"see graspsim.data.standin). Make the stand-in again in a new --standin folder with "
            f"{how}, or pass --remeasure to measure size {size} again (its folders in {out} are "
            f"removed)")


def forget(out: Path, partial_path: Path, size: int, tables: set) -> None:
    """Remove what ``tables`` ("1", "2") measured at ``size`` under ``out``: the benchmarks'
    folders and the stopped parts kept in ``partial_path`` (the caller drops their timings)."""
    for t in tables:  # table1_100 and table2_100_*, not table1_1000
        for old in [out / f"table{t}_{size}", *out.glob(f"table{t}_{size}_*")]:
            if old.is_dir():
                shutil.rmtree(old)
    if partial_path.exists():
        partial = read_json(partial_path, "partial timings")
        stale = [k for k in partial for t in tables
                 if k == f"table{t}_{size}" or k.startswith(f"table{t}_{size}_")]
        for key in set(stale):
            del partial[key]
        write_json_atomic(partial_path, partial, indent=1)


def table1_stages(out: Path) -> dict:
    rec = json.loads((out / "recognition.json").read_text())
    stages = {"patches": 0.0, "whitening": 0.0, "dictionary": 0.0, "coding": 0.0,
              "svm_inner_cv": 0.0}
    for cell in rec["cells"]:
        for name, secs in cell.get("representation_stages", {}).items():
            stages[name] = stages.get(name, 0.0) + secs
        for fold in cell["folds"]:
            stages["coding"] += fold.get("coding_seconds", 0.0)
            stages["svm_inner_cv"] += fold.get("svm_seconds", 0.0)
    return {k: round(v, 2) for k, v in stages.items()}


def table2_stages(outs: list[Path]) -> dict:
    per_image, total, n = [], 0.0, 0
    for out in outs:
        det = json.loads((out / "detection.json").read_text())
        k = len(det["per_image"])
        per_image.append(det["seconds_per_image"])
        total += det["seconds_per_image"] * k
        n += k
    return {"detection_per_image": round(total / max(n, 1), 3), "detection": round(total, 2)}


def table2_phases(out: Path) -> dict:
    """``{"phases_last_segment": {"training": s, "detection": s}}``: the wall seconds of the
    one pass's two phases in its last run (``table2.json``); empty for a pass that did not
    record them."""
    path = out / "table2.json"
    phases = json.loads(path.read_text()).get("phase_seconds_this_run") if path.is_file() \
        else None
    return {"phases_last_segment": phases} if phases else {}


def table2_detector(out: Path) -> dict:
    """The detector Table 2 timed: its search and options, as ``detection.json`` records them."""
    cfg = json.loads((out / "detection.json").read_text())["config"]
    return {k: cfg.get(k) for k in ("detector", "options", "rescore", "coarse_to_fine")}


def per_cell(out: Path, size: int) -> dict:
    """What one cell or row would cost alone at ``size`` images, in worker-seconds, from the
    commands' own records (what a user running only that cell pays; the table shares work
    between cells, so these do not add up to the table).

    Table 1 (``recognition.json``): a cell's learner's representation (patches, whitening and
    dictionary of the five outer folds, recorded on the first cell of that learner) plus the
    cell's own coding and SVM (inner cross-validation and refit). Table 2 (each row's
    ``models/*.json`` and ``detection.json``): the row's five fold models' ``train_seconds``
    (the work shared with the other rows counted in full) plus its seconds per test image times
    the images. ``two_workers_min``: the worker-seconds over two workers, in minutes.
    """
    cells: dict = {}
    rec_path = out / f"table1_{size}" / "recognition.json"
    if rec_path.is_file():
        rec = json.loads(rec_path.read_text())
        rep: dict = {}
        for cell in rec["cells"]:
            stages = cell.get("representation_stages") or {}
            # recorded on the cell that built it (once more if a resumed run rebuilt it)
            rep[cell["learner"]] = max(rep.get(cell["learner"], 0.0), sum(stages.values()))
        table1 = {}
        for cell in rec["cells"]:
            coding = sum(f.get("coding_seconds", 0.0) for f in cell["folds"])
            svm = sum(f.get("svm_seconds", 0.0) for f in cell["folds"])
            total = rep[cell["learner"]] + coding + svm
            table1[f"{cell['learner']}-{cell['encoder']}"] = {
                "representation_s": round(rep[cell["learner"]], 1), "coding_s": round(coding, 1),
                "svm_s": round(svm, 1), "worker_s": round(total, 1),
                "two_workers_min": round(total / 2 / 60, 1)}
        cells["table1"] = table1
    table2 = {}
    for learner, encoder in TABLE2_ROWS:
        for split in ("image", "object"):
            folder = out / f"table2_{size}" / f"{learner}-{encoder}_{split}"
            if not (folder / "detection.json").is_file():
                continue
            det = json.loads((folder / "detection.json").read_text())
            train = sum(json.loads(f.read_text())["config"].get("train_seconds", 0.0)
                        for f in sorted((folder / "models").glob("*.json")))
            detect = det["seconds_per_image"] * len(det["per_image"])
            table2[f"{learner}-{encoder} {split}"] = {
                "train_s": round(train, 1), "detection_s": round(detect, 1),
                "worker_s": round(train + detect, 1),
                "two_workers_min": round((train + detect) / 2 / 60, 1)}
    if table2:
        cells["table2"] = table2
    return cells


def growth(rows: dict) -> dict:
    """Per table and stage, the exponent k of time = a * size^k (least squares in log-log)."""
    out: dict = {}
    sizes = sorted(rows, key=int)
    if len(sizes) < 2:
        return out
    for table in ("table1", "table2"):
        have = [s for s in sizes if table in rows[s]]
        if len(have) < 2:
            continue
        x = np.log([int(s) for s in have])
        names = ["wall_s", *rows[have[0]][table]["stages"]]
        fits = {}
        for name in names:
            y = [rows[s][table].get(name, rows[s][table]["stages"].get(name)) for s in have]
            if all(v and v > 0 for v in y):
                fits[name] = round(float(np.polyfit(x, np.log(y), 1)[0]), 2)
        out[table] = fits
    return out


def projected(rows: dict, size: int = CORNELL["images"]) -> dict:
    """Per table, ``wall_s`` and ``cpu_s`` at ``size`` images from the power law fitted to the
    sizes measured (empty for a table measured at ``size`` or at fewer than two sizes)."""
    out: dict = {}
    for table in ("table1", "table2"):
        have = sorted(int(s) for s in rows if table in rows[s])
        if len(have) < 2 or size in have:
            continue
        x = np.log(have)
        fit = {}
        for name in ("wall_s", "cpu_s"):
            y = np.log([rows[str(s)][table][name] for s in have])
            k, log_a = np.polyfit(x, y, 1)
            fit[name] = round(float(np.exp(log_a + k * np.log(size))), 1)
        out[table] = {"images": size, **fit}
    return out


def _minutes(seconds) -> str:
    return "" if seconds is None else f"{seconds / 60:,.1f}"


def scale_markdown(rows: dict, per_cells: dict, jobs: int) -> str:
    """The measurements as Markdown (``OUT/scale.md``): per table, one line per size (wall and
    CPU minutes, peak memory, worker-minutes per stage, the code and load it ran beside), the
    growth exponent of each column, the projection to 885 images when that size is not
    measured, and what each cell or row costs alone at the largest size measured."""
    sizes = sorted(rows, key=int)
    k = growth(rows)
    proj = projected(rows)
    lines = ["# The paper's tables at Cornell's size (the stand-in), measured", "",
             f"`scripts/bench_scale.py`, {jobs} workers. Minutes; a stage is worker-minutes "
             "summed over the workers; `k` is the exponent of `time = a * size^k` fitted over "
             "the sizes measured.", ""]
    for table, title in (("table1", "Table 1 (36 cells, nested 5 x 5, d = 300)"),
                         ("table2", "Table 2 (4 rows x 2 splits, one pass)")):
        have = [n for n in sizes if table in rows[n]]
        if not have:
            continue
        stages = [st for st in rows[have[0]][table]["stages"] if st != "detection_per_image"]
        lines += [f"## {title}", "",
                  "| images | wall | CPU | peak PSS (MB) | "
                  + " | ".join(stages) + " | code | load before, after |",
                  "|---" * (6 + len(stages)) + "|"]
        for n in have:
            r = rows[n][table]
            code = r.get("code")
            code = ", ".join(str(c) for c in code if c) if isinstance(code, list) \
                else (code or "")
            load = r.get("load_average") or []
            parts = load if load and isinstance(load[0], list | None) else [load]
            load = "; ".join(", ".join(str(x) for x in part) for part in parts if part)
            lines.append(f"| {n} | {_minutes(r['wall_s'])} | {_minutes(r['cpu_s'])} | "
                         f"{r.get('peak_pss_mb') or ''} | "
                         + " | ".join(_minutes(r["stages"].get(st)) for st in stages)
                         + f" | {code} | {load} |")
        if table in k:
            fits = k[table]
            lines.append(f"| k | {fits.get('wall_s', '')} | | | "
                         + " | ".join(str(fits.get(st, "")) for st in stages) + " | | |")
        if table in proj:
            lines.append(f"| {proj[table]['images']} (projected) | "
                         f"{_minutes(proj[table]['wall_s'])} | {_minutes(proj[table]['cpu_s'])}"
                         " | | " + " | " * len(stages) + " | |")
        lines.append("")
    for table, unit in (("table1", "cell"), ("table2", "row")):
        measured = [n for n in sizes if table in per_cells.get(int(n), {})]
        if not measured:
            continue
        n = measured[-1]
        lines += [f"## One {unit} alone, {table.replace('table', 'Table ')} at {n} images", "",
                  f"| {unit} | worker-minutes | on two workers, minutes |", "|---|---|---|"]
        for name, c in per_cells[int(n)][table].items():
            lines.append(f"| {name} | {_minutes(c['worker_s'])} | {c['two_workers_min']} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100,300,885")
    ap.add_argument("--tables", default="1,2")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--standin", default="runs/standin", help="stand-in folder (made or reused)")
    ap.add_argument("--out", default="results/cornell-scale",
                    help="timings and the benchmarks' records (the default is committed, so a "
                         "measurement of several sessions continues on a new machine)")
    ap.add_argument("--standin-images", type=int, default=CORNELL["images"],
                    help="the stand-in's size; every size measured is its first images")
    ap.add_argument("--detection-preset", default=None,
                    help="graspsim benchmark table2's --preset for Table 2 (default: the "
                         "command's default, what a user runs; 'paper' times the paper's dense "
                         "search); recorded with the timings")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--remeasure", action="store_true",
                    help="measure the asked sizes and tables again, already measured or not (on "
                         "newer code, another machine, or another stand-in: their folders under "
                         "--out are removed); without it a size measured on another stand-in is "
                         "an error that names the BLAS kernels to make the same stand-in with")
    args = ap.parse_args(argv)
    try:
        with sigterm_unwinds():
            return _run(args)
    except KeyboardInterrupt as exc:  # Interrupted too: a timed command was stopped
        word, code = stop_reason(getattr(exc, "cause", None) or exc)
        print(f"bench_scale: {word}; the same command continues where it stopped",
              file=sys.stderr)
        return code


def _run(args) -> int:
    sizes = sorted({int(s) for s in args.sizes.split(",")})
    tables = {t.strip() for t in args.tables.split(",")}
    standin = Path(args.standin)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n_standin = max(args.standin_images, max(sizes))
    scale = n_standin / CORNELL["images"]
    # In a child process: checking the labelled scenes loads all of them (2.5 GB at 885
    # images), which this process would otherwise hold for the whole benchmark.
    subprocess.run([sys.executable, str(Path(__file__).with_name("make_cornell_standin.py")),
                    "--out", str(standin), "--images", str(n_standin),
                    "--positives", str(round(CORNELL["positives"] * scale)),
                    "--negatives", str(round(CORNELL["negatives"] * scale)),
                    "--seed", str(args.seed), "--jobs", str(args.jobs)],
                   check=True, stdout=subprocess.DEVNULL)
    made = read_json(standin / "standin.json", "stand-in record")
    timings_path = out / "timings.json"
    partial_path = out / "partial.json"
    timings = read_json(timings_path, "timings") if timings_path.exists() else {}
    graspsim = [sys.executable, "-m", "graspsim.cli"]
    for size in sizes:
        data = standin_subset(standin / "cornell", out / f"data_{size}", size)
        which = data_fingerprint(data, made)
        row = timings.setdefault(str(size), {})
        if row.get("data") != which:
            # measured on other data (another stand-in, or another thinning of it): measured
            # again only when asked, as the benchmarks' folders (committed) are removed
            if row and not args.remeasure:
                raise SystemExit(other_data_message(size, row, which, made, standin, out))
            if row:
                print(f"bench_scale: size {size} was measured on other data; measuring again",
                      file=sys.stderr)
            forget(out, partial_path, size, {"1", "2"})
            row.clear()
            row["data"] = which
            # kept before any command runs: a size stopped in its first command continues on
            # the same data next time (its folders and partial timings are not thrown away)
            write_json_atomic(timings_path, timings, indent=1)
        elif args.remeasure and any(f"table{t}" in row or (out / f"table{t}_{size}").exists()
                                    for t in tables):
            # the same data measured again when asked (newer code, another machine): only the
            # asked tables are forgotten; a remeasurement stopped midway continues without
            # --remeasure (with it, it would start over)
            print(f"bench_scale: measuring table(s) {','.join(sorted(tables))} at size {size} "
                  f"again", file=sys.stderr)
            forget(out, partial_path, size, tables)
            for t in tables:
                row.pop(f"table{t}", None)
            write_json_atomic(timings_path, timings, indent=1)
        # the kernels the stand-in was labelled with (graspsim.data.standin: another set gives
        # another stand-in), named in the message above when a later run's stand-in differs
        row.setdefault("standin_blas", blas_kernels(made))
        common = ["--data", str(data), "--format", "cornell", "--jobs", str(args.jobs),
                  "--seed", str(args.seed)]
        if "1" in tables and "table1" not in row:
            dest = out / f"table1_{size}"
            t = resumed(dest.name, graspsim + [
                "benchmark", "recognition", *common, "--atoms", "300", "--folds", "5",
                "--inner-folds", "5", "--paper-grid", "--split", "image", "--out", str(dest)],
                partial_path)
            row["table1"] = {**t, "stages": table1_stages(dest)}
            write_json_atomic(timings_path, timings, indent=1)
        if "2" in tables and "table2" not in row:
            # every row and split in one pass (graspsim benchmark table2: the same records as
            # one detection command per row and split, in the same per-row folders)
            dest = out / f"table2_{size}"
            preset = ["--preset", args.detection_preset] if args.detection_preset else []
            row.pop("table2_runs", None)  # the separate commands' timings of an older run
            t = resumed(dest.name, graspsim + [
                "benchmark", "table2", *common, "--split", "image,object", "--folds", "5",
                "--overlays", "0", *preset, "--out", str(dest)], partial_path)
            dests = [dest / f"{learner}-{encoder}_{split}" for learner, encoder in TABLE2_ROWS
                     for split in ("image", "object")]
            row["table2"] = {**t, "stages": table2_stages(dests),
                             "detector": table2_detector(dests[0]), "one_pass": True,
                             **table2_phases(dest)}
            write_json_atomic(timings_path, timings, indent=1)
    result = {"machine": {"cpus": os.cpu_count(), "jobs": args.jobs, "code": code_version(),
                          "platform": sys.platform},
              "standin": made["reached"], "sizes": {s: timings[str(s)] for s in map(str, sizes)},
              "growth": growth({s: timings[s] for s in map(str, sizes)}),
              "projected": projected({s: timings[s] for s in map(str, sizes)})}
    # every size measured so far, each size's records read once
    measured = {s: timings[s] for s in timings if s.isdigit()}
    costs = {int(s): per_cell(out, int(s)) for s in measured}
    result["per_cell"] = {s: costs.get(s) or per_cell(out, s) for s in sizes}
    write_text_atomic(out / "scale.md", scale_markdown(measured, costs, args.jobs))
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
