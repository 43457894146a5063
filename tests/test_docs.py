"""The documentation site builds with warnings as errors (``make docs``), and shows what it must.

The build is Sphinx's own (``python -m sphinx -W --keep-going``, as ``make docs`` runs it) into a
temporary folder, so a broken cross-reference, a docstring that does not render or a page left
out of every toctree fails the suite.
"""

from __future__ import annotations

import html
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    for name in ("sphinx", "numpydoc", "myst_parser", "sphinxarg"):
        pytest.importorskip(name, reason="the docs extra is not installed (pip install -e .[docs])")
    out = tmp_path_factory.mktemp("site")
    proc = subprocess.run(
        [sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q",
         "-d", str(out / "doctrees"), str(REPO / "docs"), str(out / "html")],
        capture_output=True, text=True, cwd=REPO, timeout=600)
    assert proc.returncode == 0, f"make docs failed:\n{proc.stderr[-4000:]}"
    return out / "html"


def _text(source: str) -> str:
    """The words of an HTML page, tags dropped and white space collapsed."""
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", source)))


@pytest.mark.parametrize("module, name, parameters", [
    ("dlsr.coding", "lasso", ["X", "D", "lam"]),
    ("graspsim.eval.trials", "run_trials", ["detector", "objects", "n", "seed", "out"]),
    ("graspsim.detectors.base", "GraspDetector", ["obs"]),
])
def test_api_pages_show_the_public_names_with_their_parameters(site, module, name, parameters):
    page = site / "api" / f"{module}.html"
    source = page.read_text(encoding="utf-8")
    assert f'id="{module}.{name}"' in source
    # the entry runs to the next name of the module that is not one of its members
    start = source.index(f'id="{module}.{name}"')
    ends = [m.start() for m in re.finditer(rf'id="{re.escape(module)}\.([\w.]+)"', source)
            if m.start() > start and not m.group(1).startswith(f"{name}.")]
    text = _text(source[start:min(ends, default=len(source))])
    assert "Parameters" in text
    for p in parameters:
        assert re.search(rf"\b{re.escape(p)}\b", text), f"{module}.{name}: no parameter {p}"


def test_every_module_has_an_api_page(site):
    spec = importlib.util.spec_from_file_location("docs_conf", REPO / "docs" / "conf.py")
    conf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conf)
    names = conf.public_modules()
    assert {"dlsr.coding", "dlsr.detection.registry", "graspsim.eval.trials"} <= set(names)
    assert not [n for n in names if not (site / "api" / f"{n}.html").exists()]


def test_the_command_line_page_shows_every_subcommand(site):
    from graspsim.cli import COMMANDS, build_parser

    text = _text((site / "cli.html").read_text(encoding="utf-8"))
    for name in COMMANDS:
        assert f"graspsim {name}" in text, f"graspsim {name} missing from cli.html"
    # the options too, straight from the parsers: every flag of `graspsim trials`
    trials = next(a for a in build_parser()._subparsers._group_actions[0].choices.items()
                  if a[0] == "trials")[1]
    usage = text.replace(" ", "")  # the usage lines set "--n" as "-- n"
    for action in trials._actions:
        for flag in action.option_strings:
            if flag == "--help":  # the usage line shows -h only
                continue
            assert f"[{flag}" in usage or f"{flag}{action.metavar or action.dest.upper()}" \
                in usage, f"graspsim trials {flag} missing from cli.html"


def test_guides_and_experiments_are_listed(site):
    index = (site / "index.html").read_text(encoding="utf-8")
    for folder in ("guides", "experiments"):
        pages = sorted((REPO / "docs" / folder).glob("*.md"))
        assert pages, folder
        for page in pages:
            assert f'href="{folder}/{page.stem}.html' in index, f"{folder}/{page.name}"
