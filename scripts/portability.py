"""Run the test suite once per BLAS kernel set this CPU supports, and once with the compiled
(numba) kernels built for a generic x86-64 CPU (``make portability``).

numpy's and scipy's OpenBLAS pick their kernels for the CPU at load time (``DYNAMIC_ARCH``);
``OPENBLAS_CORETYPE`` forces a kernel set. Products, and so the last bits of every result, and
even whether numpy warns (the AVX-512 kernels raise "invalid value" on an infinity), differ
between kernel sets; the tests must pass on each. The configurations, each named explicitly:

* ``OPENBLAS_CORETYPE=Prescott`` (SSE3; ``pni`` in ``/proc/cpuinfo``),
* ``OPENBLAS_CORETYPE=Haswell`` (AVX2; where the CPU has ``avx2``),
* ``OPENBLAS_CORETYPE=SkylakeX`` (AVX-512; only where the CPU has ``avx512f``),
* ``NUMBA_CPU_NAME=generic`` with OpenBLAS's own choice: dlsr's kernels are compiled with
  ``cache=True``, and numba's cache would hand back code compiled for this CPU from
  ``dlsr/__pycache__``; the run gets a fresh, empty ``NUMBA_CACHE_DIR`` so that every kernel is
  compiled for the generic CPU (no AVX), and the line reports how many were.

Each configuration runs in its own ``pytest`` process (the kernel set is chosen when the
library loads) and gets one line: the kernels OpenBLAS reports it actually runs (a pin it
ignored is a failure), passed / failed / skipped counts, the time. A failing configuration
also lists its failing tests and keeps its log. Exit status 1 if any configuration failed.

Usage: python scripts/portability.py [--only KEYS] [TEST_PATH ...] [-- PYTEST_ARGS ...]
(default: the whole suite, :data:`TESTS`; ``--only Haswell,generic`` runs the configurations
whose name contains one of the comma-separated keys; it is not part of ``.ci/run``).
"""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: The whole suite: a test anywhere may depend on rounding (the object generator's test compared
#: files byte for byte and failed under Prescott's kernels while the numerical modules passed).
TESTS = ["tests"]

#: OpenBLAS core types, the /proc/cpuinfo flag each needs, and the names OpenBLAS reports for
#: it: builds without the older cores (DYNAMIC_OLDER off, as numpy's and scipy's wheels) alias
#: the Katmai, Coppermine, Northwood and Banias tables to Prescott's (driver/others/dynamic.c)
#: and report the first alias, "Katmai", for the Prescott kernels.
OPENBLAS_KERNELS = [("Prescott", "pni", "SSE3", ("Prescott", "Katmai")),
                    ("Haswell", "avx2", "AVX2", ("Haswell",)),
                    ("SkylakeX", "avx512f", "AVX-512", ("SkylakeX",))]

_PINS = ("OPENBLAS_CORETYPE", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES", "NUMBA_CACHE_DIR")

_BLAS_PROBE = (
    "import numpy, scipy.linalg\n"
    "from threadpoolctl import threadpool_info\n"
    "print(' '.join(sorted({str(i.get('architecture')) for i in threadpool_info()\n"
    "                       if i.get('internal_api') == 'openblas'})))\n"
)


def cpu_flags() -> set[str]:
    """The CPU's feature flags (Linux ``/proc/cpuinfo``; empty elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():  # the first processor's (they are all the same)
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def configurations(flags: set[str]) -> list[dict]:
    """``name``, ``env`` (variables to set) and ``expect`` (OpenBLAS architecture) of each run."""
    out = []
    if platform.machine().lower() in ("x86_64", "amd64"):
        for core, flag, isa, names in OPENBLAS_KERNELS:
            if flag in flags:
                out.append(dict(name=f"OPENBLAS_CORETYPE={core} ({isa})",
                                env={"OPENBLAS_CORETYPE": core}, expect=names))
    else:
        print(f"portability: {platform.machine()} is not x86-64: OpenBLAS's own kernels only")
        out.append(dict(name="OpenBLAS's own kernels", env={}, expect=None))
    out.append(dict(name="NUMBA_CPU_NAME=generic (fresh numba cache)",
                    env={"NUMBA_CPU_NAME": "generic"}, expect=None, numba_generic=True))
    return out


def _counts(junit: Path) -> dict:
    """Passed / failed / skipped counts and the failing test ids of a junit XML report."""
    root = ET.parse(junit).getroot()
    suites = [root] if root.tag == "testsuite" else list(root)
    total = sum(int(s.get("tests", 0)) for s in suites)
    failed = sum(int(s.get("failures", 0)) + int(s.get("errors", 0)) for s in suites)
    skipped = sum(int(s.get("skipped", 0)) for s in suites)
    ids = []
    for case in root.iter("testcase"):
        if case.find("failure") is not None or case.find("error") is not None:
            path = case.get("classname", "").replace(".", "/")
            ids.append(f"{path}.py::{case.get('name')}")
    return dict(passed=total - failed - skipped, failed=failed, skipped=skipped, ids=ids)


def run(config: dict, tests: list[str], pytest_args: list[str], logs: Path) -> bool:
    env = {k: v for k, v in os.environ.items() if k not in _PINS}
    env.update(config["env"])
    cache = None
    if config.get("numba_generic"):
        cache = Path(tempfile.mkdtemp(prefix="numba-generic-"))
        env["NUMBA_CACHE_DIR"] = str(cache)
    tag = "".join(c if c.isalnum() else "_" for c in config["name"]).strip("_")
    log, junit = logs / f"{tag}.log", logs / f"{tag}.xml"
    arch = subprocess.run([sys.executable, "-c", _BLAS_PROBE], env=env, cwd=REPO,
                          capture_output=True, text=True).stdout.strip() or "none found"
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        rc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             f"--junitxml={junit}", *tests, *pytest_args],
                            env=env, cwd=REPO, stdout=fh, stderr=subprocess.STDOUT).returncode
    seconds = time.perf_counter() - t0
    counts = (_counts(junit) if junit.exists()
              else dict(passed=0, failed=0, skipped=0, ids=[]))
    shown = arch.replace("Katmai", "Katmai = Prescott's kernels")
    notes = [f"OpenBLAS runs {shown}"]
    ok = rc == 0 and counts["failed"] == 0 and counts["passed"] > 0
    if config["expect"] is not None and not (arch.split() and
                                             set(arch.split()) <= set(config["expect"])):
        notes.append(f"NOT the pinned {config['expect'][0]}")
        ok = False
    if cache is not None:
        compiled = len(list(cache.rglob("*.nbi")))
        notes.append(f"{compiled} numba functions compiled for the generic CPU" if compiled
                     else "NO numba function compiled: the compiled kernels were not tested")
        ok = ok and compiled > 0
        shutil.rmtree(cache, ignore_errors=True)
    print(f"portability: {'PASS' if ok else 'FAIL'}  {config['name']:<44} "
          f"{counts['passed']} passed, {counts['failed']} failed, {counts['skipped']} skipped "
          f"in {seconds:.0f} s  [{'; '.join(notes)}]", flush=True)
    if not ok:
        for test_id in counts["ids"]:
            print(f"portability:     failed: {test_id}")
        print(f"portability:     pytest exit status {rc}; log: {log}", flush=True)
    return ok


def parse_args(argv: list[str]):
    """``(only, tests, pytest_args)`` from the command line (see the module docstring)."""
    import argparse

    cut = argv.index("--") if "--" in argv else len(argv)
    parser = argparse.ArgumentParser(
        prog="portability.py", description="Run the tests under each BLAS kernel set and with "
        "generic compiled kernels; arguments after -- go to pytest.")
    parser.add_argument("--only", type=lambda v: [k for k in v.split(",") if k],
                        metavar="KEYS", help="comma-separated keys: run the configurations whose "
                        "name contains one of them")
    parser.add_argument("tests", nargs="*", metavar="TEST_PATH",
                        help=f"test paths (default: {' '.join(TESTS)})")
    args = parser.parse_args(argv[:cut])
    return args.only, args.tests, argv[cut + 1:]


def main(argv: list[str]) -> int:
    only, tests, pytest_args = parse_args(argv)
    if only is not None and not only:
        print("portability: error: --only needs a comma-separated list of keys")
        return 2
    tests = tests or TESTS
    logs = Path(tempfile.mkdtemp(prefix="portability-"))
    configs = configurations(cpu_flags())
    if only is not None:
        configs = [c for c in configs if any(k and k in c["name"] for k in only)]
        if not configs:
            print(f"portability: error: no configuration matches --only {','.join(only)}")
            return 2
    print(f"portability: {' '.join(tests)} under {len(configs)} configuration(s); "
          f"logs in {logs}", flush=True)
    results = [run(c, tests, pytest_args, logs) for c in configs]
    n_bad = results.count(False)
    print(f"portability: {len(results) - n_bad} of {len(results)} configurations passed",
          flush=True)
    if n_bad == 0:
        shutil.rmtree(logs, ignore_errors=True)
    return 1 if n_bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
