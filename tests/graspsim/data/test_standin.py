"""The Cornell-sized stand-in: quotas, near-miss negatives, and a tiny stand-in end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dlsr.datasets import load_cornell
from dlsr.rectangles import GraspRectangle
from graspsim.data.standin import (
    CORNELL,
    make_cornell_standin,
    spread_quota,
    standin_objects,
    standin_subset,
    thin_labels,
)


@pytest.mark.parametrize("total,available", [
    (10, [5, 5, 5]), (10, [1, 9, 9]), (7, [0, 3, 3, 3]), (100, [2, 3]), (0, [4, 4]),
])
def test_spread_quota_is_even_capped_and_complete(total, available):
    q = spread_quota(total, available, np.random.default_rng(0))
    avail = np.asarray(available)
    assert np.all(q <= avail) and np.all(q >= 0)
    assert q.sum() == min(total, avail.sum())
    # Where no cap binds, the quotas differ by at most one.
    free = q < avail
    if free.sum() > 1:
        assert q[free].max() - q[free].min() <= 1


def test_spread_quota_rejects_bad_counts():
    with pytest.raises(ValueError, match="counts"):
        spread_quota(3, [], np.random.default_rng(0))
    with pytest.raises(ValueError, match="counts"):
        spread_quota(3, [1, -1], np.random.default_rng(0))


def test_thin_labels_keeps_the_negatives_nearest_a_positive():
    pos = [GraspRectangle(100.0, 100.0, 0.0, 40.0, 10.0)]
    far = GraspRectangle(300.0, 300.0, 0.0, 40.0, 10.0)
    near_rotated = GraspRectangle(105.0, 100.0, 1.2, 40.0, 10.0)
    near_aligned = GraspRectangle(100.0, 105.0, 0.1, 40.0, 10.0)
    keep_pos, keep_neg = thin_labels(pos, [far, near_rotated, near_aligned], 1, 2,
                                     np.random.default_rng(0))
    assert keep_pos == pos
    # Both near ones (5 px); the same distance is broken by the smaller angle difference.
    assert keep_neg == [near_aligned, near_rotated]
    with pytest.raises(ValueError, match="cannot keep"):
        thin_labels(pos, [far], 2, 1, np.random.default_rng(0))


def test_standin_objects_are_builtin_then_random_urdfs_train():
    specs = standin_objects(CORNELL["objects"])
    assert len(specs) == CORNELL["objects"] == len({s.name for s in specs})
    extra = [s for s in specs if "random_urdf" in s.tags]
    assert extra and all(s.split == "train" for s in extra)
    with pytest.raises(ValueError, match="n_objects"):
        standin_objects(0)


@pytest.mark.sim
def test_a_tiny_standin_has_the_counts_it_records(tmp_path):
    rec = make_cornell_standin(tmp_path, n_images=3, n_objects=57, positives=5, negatives=3,
                               seed=1, n_candidates=12)
    samples = load_cornell(tmp_path / "cornell")
    assert len(samples) == rec["reached"]["images"] <= 3
    assert sum(len(s.positives) for s in samples) == rec["reached"]["positives"] <= 5
    assert sum(len(s.negatives) for s in samples) == rec["reached"]["negatives"] <= 3
    assert all(s.positives for s in samples)
    assert all(s.K is not None for s in samples)  # the cameras came along
    saved = json.loads((tmp_path / "standin.json").read_text())
    assert saved == rec
    assert saved["labelled_scenes"] >= saved["reached"]["images"]
    # A rerun reuses the labelled scenes and writes the same thinned dataset.
    again = make_cornell_standin(tmp_path, n_images=3, n_objects=57, positives=5,
                                 negatives=3, seed=1, n_candidates=12)
    assert again == rec
    assert [s.positives for s in load_cornell(tmp_path / "cornell")] == \
        [s.positives for s in samples]
    # The smaller sizes of the scaling benchmark: its first images, as a dataset of their own.
    sub = standin_subset(tmp_path / "cornell", tmp_path / "sub", 2)
    first = load_cornell(sub)
    assert [s.positives for s in first] == [s.positives for s in samples[:2]]
    assert [s.object_id for s in first] == [s.object_id for s in samples[:2]]
    with pytest.raises(ValueError, match="fewer than"):
        standin_subset(tmp_path / "cornell", tmp_path / "sub", 4)


def _bench_scale():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[3] / "scripts" / "bench_scale.py"
    spec = importlib.util.spec_from_file_location("bench_scale", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_bench_scale_fits_the_growth_exponent_and_projects_to_cornell():
    bench = _bench_scale()

    def row(n):  # table 1 quadratic in size, its coding linear; table 2 linear
        return {"table1": {"wall_s": 0.01 * n**2, "cpu_s": 0.02 * n**2,
                           "stages": {"coding": 3.0 * n, "svm_inner_cv": 0.0}},
                "table2": {"wall_s": 5.0 * n, "cpu_s": 9.0 * n, "stages": {"detection": n}}}

    rows = {str(n): row(n) for n in (30, 100)}
    k = bench.growth(rows)
    assert k["table1"]["wall_s"] == pytest.approx(2.0)
    assert k["table1"]["coding"] == pytest.approx(1.0)
    assert "svm_inner_cv" not in k["table1"]  # a stage that took no time has no exponent
    assert k["table2"]["detection"] == pytest.approx(1.0)
    proj = bench.projected(rows)
    assert proj["table1"]["images"] == CORNELL["images"] == 885
    assert proj["table1"]["wall_s"] == pytest.approx(0.01 * 885**2, rel=1e-3)
    assert proj["table2"]["cpu_s"] == pytest.approx(9.0 * 885, rel=1e-3)
    # measured at Cornell's size, or at one size only: nothing is projected
    assert bench.projected({**rows, "885": row(885)}) == {}
    assert bench.projected({"100": row(100)}) == {}
    assert bench.growth({"100": row(100)}) == {}


def test_bench_scale_memory_trace_keeps_each_part_of_the_run_peak():
    bench = _bench_scale()
    samples = [(0.1, 100.0), (0.5, 120.0), (4.0, 300.0), (9.9, 110.0)]
    trace = bench.rss_trace(samples, wall=10.0, n_bins=5)
    assert trace == [120.0, None, 300.0, None, 110.0]
    assert bench.rss_trace([], wall=0.0, n_bins=2) == [None, None]


def test_bench_scale_reads_the_phases_of_table2s_last_run(tmp_path):
    import json

    bench = _bench_scale()
    assert bench.table2_phases(tmp_path) == {}  # no table2.json
    (tmp_path / "table2.json").write_text(json.dumps({"splits": {}}))
    assert bench.table2_phases(tmp_path) == {}  # a pass that did not record them
    phases = {"training": 12.5, "detection": 30.25}
    (tmp_path / "table2.json").write_text(json.dumps({"phase_seconds_this_run": phases}))
    assert bench.table2_phases(tmp_path) == {"phases_last_segment": phases}


def test_bench_scale_names_the_data_each_size_was_measured_on(tmp_path):
    bench = _bench_scale()
    folder = tmp_path / "00"
    folder.mkdir()
    for i in range(2):
        (folder / f"pcd{i:04d}r.png").write_bytes(b"png")
        (folder / f"pcd{i:04d}cpos.txt").write_text("1 2\n3 4\n5 6\n7 8\n")
        (folder / f"pcd{i:04d}cneg.txt").write_text("")
    made = {"reached": {"images": 885}, "labelled_fingerprint": "abc"}
    first = bench.data_fingerprint(tmp_path, made)
    assert first["images"] == 2 and first["standin_images"] == 885
    assert bench.data_fingerprint(tmp_path, made) == first
    (folder / "pcd0001cneg.txt").write_text("1 2\n3 4\n5 6\n7 8\n")  # another thinning
    assert bench.data_fingerprint(tmp_path, made)["rectangles"] != first["rectangles"]
    other = {"reached": {"images": 100}, "labelled_fingerprint": "abc"}  # another stand-in
    assert bench.data_fingerprint(tmp_path, other) != first


def _replayed(outcomes):
    """A stand-in for ``bench.timed`` giving ``outcomes`` in turn: a record is returned, an
    exception (a stopped command's ``Interrupted``) raised."""
    runs = iter(outcomes)

    def fake_timed(cmd):
        r = next(runs)
        if isinstance(r, BaseException):
            raise r
        return r

    return fake_timed


def test_bench_scale_adds_the_parts_of_a_command_stopped_across_sessions(tmp_path, monkeypatch):
    bench = _bench_scale()
    partial = tmp_path / "partial.json"
    part = {"wall_s": 10.0, "cpu_s": 18.0, "peak_rss_mb": 900.0, "rss_trace_mb": [900.0]}
    monkeypatch.setattr(bench, "timed", _replayed(
        [bench.Interrupted(part), bench.Interrupted(dict(part, peak_rss_mb=950.0)),
         {"wall_s": 5.0, "cpu_s": 9.0, "peak_rss_mb": 700.0, "rss_trace_mb": [700.0]}]))
    for _ in range(2):  # two sessions stopped, each keeps the part it ran
        with pytest.raises(bench.Interrupted):
            bench.resumed("table1_885", ["cmd"], partial)
    assert len(bench.read_json(partial, "p")["table1_885"]) == 2
    t = bench.resumed("table1_885", ["cmd"], partial)
    assert t["wall_s"] == 25.0 and t["cpu_s"] == 45.0 and t["segments"] == 3
    assert t["peak_rss_mb"] == 950.0 and len(t["rss_trace_mb"]) == 3
    assert "table1_885" not in bench.read_json(partial, "p")  # used up


def test_bench_scale_timing_names_the_code_and_the_load_it_ran_beside(tmp_path, monkeypatch):
    import subprocess
    import sys
    from pathlib import Path

    bench = _bench_scale()
    t = bench.timed([sys.executable, "-c", "pass"])
    assert isinstance(t["cpu"], str) and t["cpu"]
    repo = str(Path(bench.__file__).parents[1])
    head = subprocess.run(["git", "-C", repo, "rev-parse", "--short=12", "HEAD"],
                          capture_output=True, text=True)
    if head.returncode == 0:  # a checkout: the commit, marked when tracked files differ
        assert t["code"].split("+")[0] == head.stdout.strip()
        assert t["code"].endswith("+dirty") == bool(subprocess.run(
            ["git", "-C", repo, "status", "--porcelain",
             "--untracked-files=no"], capture_output=True, text=True).stdout.strip())
    else:
        assert t["code"] is None
    assert len(t["load_average"]) == 2 and all(v >= 0 for v in t["load_average"])
    # parts of one command run by different code are all named
    partial = tmp_path / "partial.json"
    monkeypatch.setattr(bench, "timed", _replayed([bench.Interrupted(dict(t, code="aaa")),
                                                   dict(t, code="bbb")]))
    with pytest.raises(bench.Interrupted):
        bench.resumed("table2_300", ["cmd"], partial)
    assert bench.resumed("table2_300", ["cmd"], partial)["code"] == ["aaa", "bbb"]


def test_bench_scale_tree_memory_counts_shared_pages_once_in_its_pss(monkeypatch):
    import subprocess
    import sys
    from pathlib import Path

    if not Path("/proc/self/smaps_rollup").exists():
        pytest.skip("no /proc/PID/smaps_rollup on this kernel")
    bench = _bench_scale()
    # a child that maps 200 MB of anonymous shared memory and writes it, then forks, and both
    # read every page: the two processes hold the same pages, which their resident sets count
    # twice. Each says when its pages are in; both end when their input closes.
    code = ("import mmap, os, sys; m = mmap.mmap(-1, 200 << 20); m.write(b'x' * (200 << 20));"
            " os.fork(); m[::4096]; print('ready', flush=True); sys.stdin.read()")
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert [proc.stdout.readline() for _ in range(2)] == ["ready\n"] * 2
        rss, pss, ticks = bench._tree(proc.pid)
        # without the proportional sizes (read less often), and through a scan of /proc on a
        # kernel without children lists: the same processes and resident sets
        rss_only, no_pss, ticks_only = bench._tree(proc.pid, pss=False)
        monkeypatch.setattr(bench, "_children", lambda pid: None)
        rss_scan, pss_scan, ticks_scan = bench._tree(proc.pid)
    finally:
        proc.stdin.close()
        proc.wait()
        proc.stdout.close()
    assert len(ticks) == 2  # the child and its fork
    assert rss > 400 and pss < rss - 150, (rss, pss)
    assert pss > 200
    assert no_pss is None and set(ticks_only) == set(ticks_scan) == set(ticks)
    assert abs(rss_only - rss) < 5 and abs(rss_scan - rss) < 5 and abs(pss_scan - pss) < 5


def test_bench_scale_timed_command_stopped_keeps_its_cpu_and_ends_the_child():
    import signal
    import subprocess
    import sys

    bench = _bench_scale()

    def stop(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, 1.5)
    try:
        with pytest.raises(bench.Interrupted) as info:
            bench.timed([sys.executable, "-c", "while True: pass"])
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    seg = info.value.segment
    assert seg["wall_s"] > 0 and seg["cpu_s"] > 0 and seg["peak_rss_mb"] > 0
    # the child was ended: nothing of it is left running
    out = subprocess.run(["pgrep", "-f", "while True: pass"], capture_output=True, text=True)
    assert out.stdout.strip() == ""


def test_bench_scale_stopped_by_sigterm_says_so_in_one_line(monkeypatch, capsys):
    from graspsim.cli import Terminated

    bench = _bench_scale()

    def stopped(args):  # a timed command stopped by SIGTERM, as timed() reports it
        raise bench.Interrupted({"wall_s": 1.0}, Terminated())

    monkeypatch.setattr(bench, "_run", stopped)
    assert bench.main(["--sizes", "100"]) == 143  # the shell's code for SIGTERM, no traceback
    err = capsys.readouterr().err
    assert "terminated; the same command continues" in err and "Traceback" not in err


def test_bench_scale_size_stopped_in_its_first_command_continues_it(tmp_path, monkeypatch):
    import argparse
    import json

    bench = _bench_scale()
    standin, out = tmp_path / "standin", tmp_path / "out"
    standin.mkdir()
    (standin / "standin.json").write_text(json.dumps({"reached": {"images": 885}}))
    monkeypatch.setattr(bench.subprocess, "run", lambda *a, **k: None)  # the stand-in is made
    monkeypatch.setattr(bench, "code_version", lambda: "abc")
    monkeypatch.setattr(bench, "standin_subset", lambda src, dst, n: dst)
    monkeypatch.setattr(bench, "data_fingerprint", lambda data, made: {"images": 100})
    monkeypatch.setattr(bench, "table1_stages", lambda dest: {})
    part = {"wall_s": 10.0, "cpu_s": 18.0, "peak_rss_mb": 900.0, "rss_trace_mb": [900.0]}

    def stopped(cmd):  # the benchmark saved some cells in its folder, then SIGTERM
        (out / "table1_100").mkdir(parents=True, exist_ok=True)
        (out / "table1_100" / "cells.jsonl").write_text("{}\n")
        raise bench.Interrupted(part)

    args = argparse.Namespace(sizes="100", tables="1", standin=str(standin), out=str(out),
                              standin_images=885, jobs=2, seed=0, detection_preset=None,
                              remeasure=False)
    monkeypatch.setattr(bench, "timed", stopped)
    with pytest.raises(bench.Interrupted):
        bench._run(args)
    monkeypatch.setattr(bench, "timed", lambda cmd: dict(part, wall_s=5.0))
    assert bench._run(args) == 0
    assert (out / "table1_100" / "cells.jsonl").exists()  # its saved cells were kept
    t = json.loads((out / "timings.json").read_text())["100"]["table1"]
    assert t["segments"] == 2 and t["wall_s"] == 15.0


def test_bench_scale_refuses_a_size_measured_on_another_standin_unless_asked(tmp_path,
                                                                           monkeypatch, capsys):
    import argparse
    import json

    bench = _bench_scale()
    standin, out = tmp_path / "standin", tmp_path / "out"
    standin.mkdir()
    made = {"reached": {"images": 885}, "labelled_fingerprint": "a" * 64,
            "blas": [{"internal_api": "openblas", "architecture": "SkylakeX"}]}
    (standin / "standin.json").write_text(json.dumps(made))
    monkeypatch.setattr(bench.subprocess, "run", lambda *a, **k: None)
    monkeypatch.setattr(bench, "code_version", lambda: "abc")
    monkeypatch.setattr(bench, "standin_subset", lambda src, dst, n: dst)
    data = {"images": 100, "standin_images": 885, "standin_labelled": "a" * 64,
            "rectangles": "r" * 64}
    monkeypatch.setattr(bench, "data_fingerprint", lambda d, m: dict(data))
    monkeypatch.setattr(bench, "table1_stages", lambda dest: {})

    def measured(cmd):
        (out / "table1_100").mkdir(parents=True, exist_ok=True)
        (out / "table1_100" / "cells.jsonl").write_text("{}\n")
        return {"wall_s": 5.0, "cpu_s": 9.0, "peak_rss_mb": 1.0, "rss_trace_mb": [1.0]}

    monkeypatch.setattr(bench, "timed", measured)
    args = argparse.Namespace(sizes="100", tables="1", standin=str(standin), out=str(out),
                              standin_images=885, jobs=2, seed=0, detection_preset=None,
                              remeasure=False)
    assert bench._run(args) == 0
    capsys.readouterr()
    assert json.loads((out / "timings.json").read_text())["100"]["standin_blas"] == "SkylakeX"
    # the same stand-in made with other kernels: other scenes, so other rectangles
    made_here = dict(made, labelled_fingerprint="b" * 64,
                     blas=[{"internal_api": "openblas", "architecture": "Haswell"}])
    (standin / "standin.json").write_text(json.dumps(made_here))
    monkeypatch.setattr(bench, "data_fingerprint",
                        lambda d, m: dict(data, standin_labelled="b" * 64, rectangles="s" * 64))
    before = (out / "timings.json").read_text()
    with pytest.raises(SystemExit) as stop:
        bench._run(args)
    msg = str(stop.value)
    assert "\n" not in msg and "size 100" in msg and "OPENBLAS_CORETYPE=SkylakeX" in msg
    assert "Haswell" in msg and "--remeasure" in msg
    # nothing measured was thrown away
    assert (out / "timings.json").read_text() == before
    assert (out / "table1_100" / "cells.jsonl").exists()
    # asked to, it measures the size again on this stand-in
    args.remeasure = True
    assert bench._run(args) == 0
    row = json.loads((out / "timings.json").read_text())["100"]
    assert row["data"]["standin_labelled"] == "b" * 64 and row["standin_blas"] == "Haswell"
    assert "measuring again" in capsys.readouterr().err


def test_bench_scale_remeasure_measures_the_asked_table_again_on_the_same_data(tmp_path,
                                                                                monkeypatch):
    import argparse
    import json
    from pathlib import Path

    bench = _bench_scale()
    standin, out = tmp_path / "standin", tmp_path / "out"
    standin.mkdir()
    (standin / "standin.json").write_text(json.dumps({"reached": {"images": 885}}))
    monkeypatch.setattr(bench.subprocess, "run", lambda *a, **k: None)
    monkeypatch.setattr(bench, "code_version", lambda: "abc")
    monkeypatch.setattr(bench, "standin_subset", lambda src, dst, n: dst)
    monkeypatch.setattr(bench, "data_fingerprint", lambda d, m: {"images": 100})
    monkeypatch.setattr(bench, "table1_stages", lambda dest: {})
    monkeypatch.setattr(bench, "table2_stages", lambda dests: {})
    monkeypatch.setattr(bench, "table2_detector", lambda dest: {})
    runs = []

    def measured(cmd):
        dest = Path(cmd[cmd.index("--out") + 1])
        dest.mkdir(parents=True, exist_ok=True)
        (dest / "run.txt").write_text(str(len(runs)))
        runs.append(dest.name)
        return {"wall_s": float(len(runs)), "cpu_s": 1.0, "peak_rss_mb": 1.0,
                "rss_trace_mb": [1.0]}

    monkeypatch.setattr(bench, "timed", measured)
    # a size's neighbour whose name starts alike, and a stopped part of this size's Table 1
    (out / "table1_1000").mkdir(parents=True)
    (out / "partial.json").write_text(json.dumps({"table1_100": [{"wall_s": 3.0}],
                                                  "table1_1000": [{"wall_s": 4.0}]}))
    args = argparse.Namespace(sizes="100", tables="1,2", standin=str(standin), out=str(out),
                              standin_images=885, jobs=2, seed=0, detection_preset=None,
                              remeasure=False)
    assert bench._run(args) == 0 and runs == ["table1_100", "table2_100"]
    assert bench._run(args) == 0 and len(runs) == 2  # measured: not run again
    args.tables, args.remeasure = "1", True
    assert bench._run(args) == 0 and runs[2:] == ["table1_100"]
    row = json.loads((out / "timings.json").read_text())["100"]
    assert row["table1"]["wall_s"] == 3.0 and "segments" not in row["table1"]
    assert row["table2"]["wall_s"] == 2.0  # the table not asked for is kept
    assert (out / "table1_100" / "run.txt").read_text() == "2"
    assert (out / "table2_100" / "run.txt").read_text() == "1"
    assert (out / "table1_1000").is_dir()
    assert json.loads((out / "partial.json").read_text()) == {"table1_1000": [{"wall_s": 4.0}]}


def test_bench_scale_per_cell_costs_count_the_shared_representation_in_each_cell(tmp_path):
    bench = _bench_scale()
    t1 = tmp_path / "table1_50"
    t1.mkdir()
    fold = {"coding_seconds": 3.0, "svm_seconds": 1.0}
    cells = [{"learner": "NKM", "encoder": "SC", "folds": [fold] * 5,
              "representation_stages": {"patches": 1.0, "whitening": 2.0, "dictionary": 57.0}},
             {"learner": "NKM", "encoder": "ST", "folds": [{"coding_seconds": 0.5,
                                                          "svm_seconds": 2.0}] * 5,
              "representation_stages": {}},
             {"learner": "RP", "encoder": "Natural", "folds": [fold] * 5,
              "representation_stages": {"dictionary": 0.5}}]
    (t1 / "recognition.json").write_text(json.dumps({"cells": cells}))
    row = tmp_path / "table2_50" / "NKM-SC_image"
    (row / "models").mkdir(parents=True)
    for k in range(5):
        (row / "models" / f"abc_fold{k}.json").write_text(
            json.dumps({"config": {"train_seconds": 10.0 + k}}))
    (row / "detection.json").write_text(json.dumps({"seconds_per_image": 2.5,
                                                    "per_image": [{}] * 50}))
    costs = bench.per_cell(tmp_path, 50)
    nkm_sc, nkm_st = costs["table1"]["NKM-SC"], costs["table1"]["NKM-ST"]
    # the NKM representation, recorded on the first NKM cell, is paid by either cell alone
    assert nkm_sc["representation_s"] == nkm_st["representation_s"] == 60.0
    assert nkm_sc["worker_s"] == 60.0 + 15.0 + 5.0
    assert nkm_st["worker_s"] == 60.0 + 2.5 + 10.0
    assert costs["table1"]["RP-Natural"]["worker_s"] == 0.5 + 20.0
    assert nkm_sc["two_workers_min"] == round(80.0 / 120, 1)
    assert costs["table2"] == {"NKM-SC image": {"train_s": 60.0, "detection_s": 125.0,
                                                "worker_s": 185.0, "two_workers_min": 1.5}}
    assert bench.per_cell(tmp_path, 100) == {}  # nothing measured at that size


def test_bench_scale_markdown_has_each_size_the_exponents_and_the_costs_alone():
    bench = _bench_scale()

    def t2(n):
        return {"wall_s": 6.0 * n, "cpu_s": 12.0 * n, "peak_pss_mb": 10.0 * n,
                "stages": {"detection_per_image": 1.0, "detection": 9.0 * n},
                "code": ["abc+dirty", None, "def"], "load_average": [[1.0, 2.0], [0.5, 1.5]]}

    rows = {"100": {"table1": {"wall_s": 1200.0, "cpu_s": 2400.0, "code": "abc",
                               "load_average": [0.8, 1.9],
                               "stages": {"coding": 1800.0, "svm_inner_cv": 60.0}},
                    "table2": t2(100)},
            "300": {"data": {}, "table2": t2(300)}}
    per_cells = {100: {"table1": {"NKM-SC": {"worker_s": 240.0, "two_workers_min": 2.0}}},
                 300: {"table2": {"NKM-SC image": {"worker_s": 600.0, "two_workers_min": 5.0}}}}
    md = bench.scale_markdown(rows, per_cells, jobs=2)
    assert "| 100 | 20.0 | 40.0 |  | 30.0 | 1.0 | abc | 0.8, 1.9 |" in md  # table 1, minutes
    assert "| 300 | 30.0 | 60.0 | 3000.0 | 45.0 | abc+dirty, def | 1.0, 2.0; 0.5, 1.5 |" in md
    assert "| k | 1.0 | | | 1.0 | | |" in md  # table 2 grows linearly; table 1 has one size
    assert md.count("| k |") == 1
    assert "| 885 (projected) | 88.5 | 177.0 |" in md
    assert "## One cell alone, Table 1 at 100 images" in md and "| NKM-SC | 4.0 | 2.0 |" in md
    assert "## One row alone, Table 2 at 300 images" in md
    assert "| NKM-SC image | 10.0 | 5.0 |" in md
