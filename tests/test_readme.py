"""Every command block of the README works on a clean clone.

Each shell line of the README is classified: ``graspsim`` commands are parsed by the real
argument parser (a renamed option or subcommand fails here) and the files they read from the
repository must exist; ``make`` targets must exist in the Makefile; ``python scripts/X.py``
must exist and answer ``--help``; ``pip``/``ray`` lines (a cluster, the network) are only checked
for the extras they name. The plug-in example, which finishes in well under a minute, runs for
real. A line of another kind fails the test, so a new block gets classified here.
"""

from __future__ import annotations

import ast
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
# A hook refuses commit hashes in the README (an abbreviated or full hexadecimal id).
HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")


def blocks(text: str, lang: str) -> list[str]:
    """The bodies of the fenced code blocks of language ``lang``, in order."""
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.M | re.S)


def commands(block: str) -> list[str]:
    """The shell commands of a block: continuation lines joined, comments and prompts dropped."""
    out = []
    for line in block.replace("\\\n", " ").splitlines():
        line = re.sub(r"\s+#.*$", "", line).strip()
        if line and not line.startswith("#"):
            out.append(line.removeprefix("$ "))
    return out


def readme_commands() -> list[str]:
    return [c for b in blocks(README.read_text(encoding="utf-8"), "sh") for c in commands(b)]


def makefile_targets() -> set[str]:
    text = (REPO / "Makefile").read_text(encoding="utf-8")
    return set(re.findall(r"^([A-Za-z][\w.-]*):", text, flags=re.M))


def test_readme_is_short_and_opens_with_the_two_commands():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    first = blocks(text, "sh")[0]
    assert commands(first) == ["make run", "make test"]
    assert text.index("```sh") < text.index("\n## ")  # before any section
    assert not HASH.findall(text), HASH.findall(text)


def test_readme_links_exist():
    text = README.read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert links
    missing = [link for link in links
               if not link.startswith(("http://", "https://")) and not (REPO / link).exists()]
    assert not missing


def test_every_readme_command_is_known():
    from graspsim.cli import build_parser

    parser = build_parser()
    targets = makefile_targets()
    seen = set()
    for cmd in readme_commands():
        argv = shlex.split(cmd)
        tool = argv[0].removeprefix(".venv/bin/")
        seen.add(tool)
        if tool == "make":
            assert argv[1] in targets, cmd
        elif tool == "graspsim":
            args = parser.parse_args(argv[1:])  # SystemExit on an unknown option
            config = getattr(args, "config", None)
            if config is not None:
                assert (REPO / config).exists(), cmd
        elif tool == "python":
            assert (REPO / argv[1]).exists(), cmd
            proc = subprocess.run([sys.executable, argv[1], "--help"], cwd=REPO,
                                  capture_output=True, text=True, timeout=120)
            assert proc.returncode == 0, proc.stderr
        elif tool == "pip":  # the extras it names exist
            extras = re.findall(r'\.\[([\w,]+)\]', cmd)
            pyproject = (REPO / "pyproject.toml").read_text(encoding="utf-8")
            for extra in ",".join(extras).split(","):
                assert re.search(rf"^{extra} = \[", pyproject, flags=re.M), cmd
        elif tool == "ray":  # needs a cluster: only the form
            assert argv[1] == "start", cmd
        else:
            raise AssertionError(f"README command of an unknown kind: {cmd}")
    assert {"make", "graspsim"} <= seen


def test_readme_python_blocks_compile():
    for block in blocks(README.read_text(encoding="utf-8"), "python"):
        ast.parse(block)


@pytest.mark.slow
@pytest.mark.sim
def test_the_plugin_example_runs(tmp_path):
    text = README.read_text(encoding="utf-8")
    plugin = next(b for b in blocks(text, "python") if b.startswith("# topgrasp.py"))
    (tmp_path / "topgrasp.py").write_text(plugin)
    cmd = next(c for c in readme_commands() if "topgrasp:TopGrasp" in c)
    argv = shlex.split(cmd)
    proc = subprocess.run(
        [sys.executable, "-c", "import sys; from graspsim.cli import main; sys.exit(main())",
         *argv[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = tmp_path / argv[argv.index("--out") + 1]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n"] == int(argv[argv.index("--n") + 1])
    assert 0 <= summary["successes"] <= summary["n"]
