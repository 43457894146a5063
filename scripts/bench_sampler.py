"""What ``scripts/bench_scale.py``'s memory sampling costs (one JSON object on stdout).

``bench_scale.py`` samples the measured command's process tree from /proc while it runs, on
the same cores. This times that sampling against a tree like Table 1's at 885 images: a parent
and ``--workers`` children, each holding ``--gb`` GB of written anonymous memory (default 2 x
3.5 GB, about the 7 GB of the 885-image Table 1), idle. Each side samples the tree for
``--seconds`` at the cadence it uses in a campaign, in a thread whose CPU time
(``time.thread_time``) is the cost; the sides alternate ``--rounds`` times so both see the
same machine:

* ``reference``: the sampler of ``--reference-commit`` (``git show`` of its
  ``scripts/bench_scale.py`` into a temporary module); the default, ``ebd7ce6``, is the last
  commit whose sampler read every process's status and the tree's ``smaps_rollup`` every 0.2 s;
* ``current``: this checkout's (:data:`SAMPLE_EVERY`, :data:`PSS_EVERY`).

Reported per side: CPU seconds per minute of sampling (a core's share in percent), the peak
resident and proportional sizes it saw, and their ratio.

Usage: python scripts/bench_sampler.py [--gb 3.5] [--workers 2] [--seconds 30] [--rounds 2]
       [--reference-commit ebd7ce6]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HOLDER = ("import mmap, os, sys; n = int(float(sys.argv[1]) * (1 << 30)); m = mmap.mmap(-1, n, "
          "flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS); step = 1 << 20; chunk = b'x' * step\n"
          "for i in range(0, n, step): m[i:i + step] = chunk[:min(step, n - i)]\n"
          "print('ready', flush=True); sys.stdin.read()")


def load_module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def sample_for(tree, root: int, seconds: float, every: float, pss_every: float | None) -> dict:
    """Sample ``root``'s tree with ``tree`` for ``seconds`` in a thread, every ``every``
    seconds, its proportional sizes every ``pss_every`` (None: ``tree`` takes no ``pss``
    argument and reads them every sample); the thread's CPU seconds and what it saw."""
    seen = {"rss": 0.0, "pss": 0.0, "samples": 0, "cpu_s": 0.0}

    def run():
        c0, t0, next_pss = time.thread_time(), time.perf_counter(), 0.0
        stop = t0 + seconds
        while time.perf_counter() < stop:
            time.sleep(every)
            now = time.perf_counter() - t0
            if pss_every is None:
                rss, pss, _ = tree(root)
            else:
                want = now >= next_pss
                rss, pss, _ = tree(root, pss=want)
                if want:
                    next_pss = now + pss_every
            seen["rss"] = max(seen["rss"], rss)
            seen["pss"] = max(seen["pss"], pss or 0.0)
            seen["samples"] += 1
        seen["cpu_s"] = time.thread_time() - c0

    th = threading.Thread(target=run)
    th.start()
    th.join()
    return seen


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gb", type=float, default=3.5, help="memory each child holds (GB)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--reference-commit", default="ebd7ce6")
    args = ap.parse_args(argv)
    here = Path(__file__).resolve()
    current = load_module(here.with_name("bench_scale.py"), "bench_scale_current")
    with tempfile.TemporaryDirectory() as tmp:
        ref_path = Path(tmp) / "bench_scale_reference.py"
        ref_path.write_text(subprocess.check_output(
            ["git", "-C", str(here.parents[1]), "show",
             f"{args.reference_commit}:scripts/bench_scale.py"], text=True))
        reference = load_module(ref_path, "bench_scale_reference")
    # a parent (like the benchmark's main process) whose children hold the memory
    parent = subprocess.Popen(
        [sys.executable, "-c",
         "import subprocess, sys\n"
         f"kids = [subprocess.Popen([sys.executable, '-c', {HOLDER!r}, '{args.gb}'], "
         "stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) "
         f"for _ in range({args.workers})]\n"
         "[k.stdout.readline() for k in kids]\nprint('ready', flush=True)\n"
         "sys.stdin.read()\n[k.stdin.close() for k in kids]\n[k.wait() for k in kids]"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    rows: dict[str, list] = {"reference": [], "current": []}
    try:
        if parent.stdout.readline() != "ready\n":
            raise SystemExit("bench_sampler: the memory holders did not start")
        for _ in range(args.rounds):
            for side, mod in (("reference", reference), ("current", current)):
                # each side at its own cadence; a sampler without PSS_EVERY (before
                # 2026-12-07) read the proportional sizes at every sample, every 0.2 s
                rows[side].append(sample_for(mod._tree, parent.pid, args.seconds,
                                             getattr(mod, "SAMPLE_EVERY", 0.2),
                                             getattr(mod, "PSS_EVERY", None)))
    finally:
        parent.stdin.close()
        parent.wait()
        parent.stdout.close()
    out = {"tree": {"workers": args.workers, "gb_each": args.gb}, "seconds": args.seconds,
           "reference_commit": args.reference_commit}
    for side, runs in rows.items():
        per_min = [60 * r["cpu_s"] / args.seconds for r in runs]
        out[side] = {"cpu_s_per_min": [round(x, 2) for x in per_min],
                     "core_percent": round(100 * min(per_min) / 60, 2),
                     "samples": [r["samples"] for r in runs],
                     "peak_rss_mb": round(max(r["rss"] for r in runs), 1),
                     "peak_pss_mb": round(max(r["pss"] for r in runs), 1)}
    out["ratio_reference_to_current"] = round(
        min(out["reference"]["cpu_s_per_min"]) / max(min(out["current"]["cpu_s_per_min"]), 1e-9),
        2)
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
