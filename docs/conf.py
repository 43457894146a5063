"""Sphinx configuration of the dlsr-graspsim documentation (``make docs``).

The API pages are written at build time from the package tree (one page per public module,
:func:`write_api_pages`), so a new module appears without editing anything here; the
command-line page is generated from ``graspsim.cli.build_parser`` by sphinx-argparse. User guides
(``guides/*.md``) and the experiment log (``experiments/*.md``) are MyST Markdown pages picked
up by glob toctrees.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
sys.path.insert(0, str(REPO))
# Headless builds: the report and picture modules import matplotlib.
os.environ.setdefault("MPLBACKEND", "Agg")

project = "dlsr-graspsim"
author = "the dlsr-graspsim developers"
copyright = "2026, the dlsr-graspsim developers"  # noqa: A001 (Sphinx's name)

extensions = [
    "myst_parser",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinxarg.ext",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path = []
# Keep "--option" as typed in help texts and docstrings (no en dashes, no curly quotes).
smartquotes = False

# MyST: GitHub-flavoured tables and headings with anchors, so links like guide.md#section work.
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 3

# autodoc + numpydoc: parameters, returns and shapes from the numpydoc docstrings.
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc sections carry the types
# Only this project's docstrings: a method without one (GraspEnv.step) does not show
# gymnasium's or scikit-learn's, whose references point into their own sites.
autodoc_inherit_docstrings = False
autosummary_generate = False
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "alabaster"
html_title = "dlsr-graspsim"
html_static_path = []

# Modules that are not public API: private helpers (a leading underscore), the CLI's subcommand
# modules (documented on the command-line page), the object set (package data) and the old
# home of the CNN peers (a shim for the entry point of earlier installs).
SKIP_PREFIXES = ("graspsim.commands", "graspsim.assets", "graspsim.ggcnn")
# graspsim's wings, lowest first (CONTRIBUTING.md, tests/test_import_graph.py): the API index
# shows the package a wing at a time, in this order, the faces last.
WINGS = ("runtime", "sim", "labels", "data", "detectors", "eval", "pipeline")


def public_modules(packages=("dlsr", "graspsim")) -> list[str]:
    """Dotted names of the public modules and packages under ``packages``, sorted."""
    names = []
    for pkg in packages:
        for path in sorted((REPO / pkg).rglob("*.py")):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join(parts)
            if any(p.startswith("_") for p in parts) or name.startswith(SKIP_PREFIXES):
                continue
            names.append(name)
    return sorted(names)


def write_api_pages(app=None) -> None:
    """Write ``api/<module>.rst`` for every public module and the ``api/index.rst`` toctree.

    A package page shows its docstring and the names it defines itself; names it re-exports
    from its modules (``dlsr.detection``) are documented on those modules' pages.
    """
    out = DOCS / "api"
    out.mkdir(exist_ok=True)
    modules = public_modules()
    wanted = set()
    for name in modules:
        is_package = (REPO / name.replace(".", "/") / "__init__.py").exists()
        options = "   :ignore-module-all:\n" if is_package else ""
        text = f"{name}\n{'=' * len(name)}\n\n.. automodule:: {name}\n{options}"
        page = out / f"{name}.rst"
        wanted.add(page.name)
        if not page.exists() or page.read_text() != text:
            page.write_text(text)
    index = api_index(modules)
    wanted.add("index.rst")
    if not (out / "index.rst").exists() or (out / "index.rst").read_text() != index:
        (out / "index.rst").write_text(index)
    for stale in out.glob("*.rst"):
        if stale.name not in wanted:
            stale.unlink()


def _first_line(module: str) -> str:
    """The first sentence of a package's docstring (read from the source, not imported)."""
    import ast

    path = REPO / module.replace(".", "/") / "__init__.py"
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    return " ".join(doc.split(":")[0].replace("``", "").split()) if doc else module


def api_index(modules: list[str]) -> str:
    """``api/index.rst``: ``dlsr``, then ``graspsim`` one wing at a time (lowest first, each
    captioned by its package's docstring), then graspsim's faces."""

    def toctree(caption: str, names: list[str]) -> str:
        return (f".. toctree::\n   :caption: {caption}\n   :maxdepth: 1\n\n"
                + "".join(f"   {m}\n" for m in names) + "\n")

    text = ("API reference\n=============\n\nGenerated from the numpydoc docstrings of every "
            "public module of ``dlsr`` (the method; never imports pybullet) and ``graspsim`` "
            "(the simulator and harness). ``graspsim`` is shown a wing at a time, in its import "
            "order: each wing imports only the wings above it on this page.\n\n")
    text += toctree("dlsr", [m for m in modules if m.split(".")[0] == "dlsr"])
    placed = set()
    for wing in WINGS:
        names = [m for m in modules if m.startswith(f"graspsim.{wing}")
                 and m.split(".")[1] == wing]
        placed.update(names)
        text += toctree(f"graspsim.{wing}: {_first_line(f'graspsim.{wing}')}", names)
    faces = [m for m in modules if m.split(".")[0] == "graspsim" and m not in placed]
    return text + toctree("graspsim: the environment and the command line", faces)


def skip_member(app, what, name, obj, skip, options):
    """Leave out scikit-learn's generated metadata-routing methods (``set_fit_request``...)."""
    if name.startswith("set_") and name.endswith("_request"):
        return True
    return None


def setup(app):
    write_api_pages()
    app.connect("autodoc-skip-member", skip_member)
    return {"parallel_read_safe": True}
