"""The layer contract of docs/architecture.md, checked on every production module.

- calib_core (the science) imports only the standard library's non-I/O modules,
  numpy, scipy, numba (the compiled loops of calib_core.second_differences) and itself:
  no storage, pipelines, database, workflow, file-format or file-system module, and none
  that decides how to run (threads, executors, memory maps, the C library): the
  pipelines pass that in (`calib_core.streamed.Execution`);
- storage (the archive) imports no pipelines;
- pipelines.commands never imports pipelines.cli (cli -> commands, one way);
- no production module imports calib_core.simulate or the support package
  calib_testing (tests, benchmarks, scripts and the sample-data generator may; the
  ground-truth benchmark's simulated cases are in calib_testing.benchmark_cases).
"""

from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calib_core", "storage", "pipelines")
SCIENCE_THIRD_PARTY = {"numpy", "scipy", "numba"}
# Standard-library modules that touch files, processes, the network or a database.
IO_STDLIB = {
    "os", "io", "pathlib", "shutil", "glob", "tempfile", "subprocess", "socket", "sqlite3",
    "pickle", "shelve", "dbm", "urllib", "http", "ftplib", "smtplib", "mmap", "fileinput",
    "multiprocessing", "concurrent", "asyncio", "logging", "zipfile", "tarfile", "csv",
}  # fmt: skip
# How to run: the caller's choice (calib_core.streamed.Execution), never the science's.
EXECUTION = {"threading", "queue", "concurrent", "mmap", "ctypes", "_thread"}
MAX_PRIVATE_IMPORTS = 8  # private names (`_x`) imported across production modules


@functools.cache
def parsed(source: str) -> ast.Module:
    """The syntax tree of a source text, parsed once for all the tests of this module (each
    walks every production file; the trees are only read)."""
    return ast.parse(source)


def imported_modules(source: str, module: str) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every import in `source` (relative ones resolved)."""
    found: list[tuple[int, str]] = []
    package = module.rsplit(".", 1)[0]
    for node in ast.walk(parsed(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            found.append((node.lineno, base))
            # `from calib_core import simulate` names a module too
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return found


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def violations(module: str, source: str) -> list[str]:
    """What `module` (dotted name, a production module) imports against the contract,
    one line per offending import statement."""
    bad: dict[int, str] = {}
    for line, name in imported_modules(source, module):
        if line in bad:
            continue
        top = name.split(".")[0]
        why = None
        if top == "calib_testing":
            why = "production code imports the test support package calib_testing"
        elif _within(name, "calib_core.simulate"):
            if not _within(module, "calib_core.simulate"):
                why = "production code imports the simulator"
        elif _within(module, "calib_core"):
            if top in ("storage", "pipelines"):
                why = "calib_core imports a higher layer"
            elif top in EXECUTION:
                why = "calib_core imports an execution module (threads, memory maps)"
            elif top in IO_STDLIB:
                why = "calib_core imports an I/O module"
            elif top not in sys.stdlib_module_names and top not in SCIENCE_THIRD_PARTY | {
                "calib_core",
                "__future__",
            }:
                why = "calib_core imports a library other than numpy, scipy and numba"
        elif _within(module, "storage") and top == "pipelines":
            why = "storage imports pipelines"
        elif _within(module, "pipelines.commands") and _within(name, "pipelines.cli"):
            why = "a command module imports pipelines.cli (cli -> commands only)"
        if why:
            bad[line] = f"{module} line {line}: imports {name}: {why}"
    return list(bad.values())


def production_modules() -> dict[str, Path]:
    mods: dict[str, Path] = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            if "migrations" in parts:
                continue  # Alembic scripts: data definitions run by Alembic itself
            mods[".".join(parts)] = path
    return mods


def test_every_production_module_keeps_the_layer_contract() -> None:
    mods = production_modules()
    assert len(mods) > 60, sorted(mods)  # the walk found the packages
    bad = [v for mod, path in mods.items() for v in violations(mod, path.read_text("utf-8"))]
    assert bad == [], "\n".join(bad)


def test_the_checker_reports_each_kind_of_forbidden_import() -> None:
    cases = {
        ("calib_core.noise", "import sqlalchemy"): "library other than numpy",
        ("calib_core.noise", "from pathlib import Path"): "I/O module",
        ("calib_core.streamed", "import threading"): "execution module",
        ("calib_core.streamed", "from concurrent.futures import Future"): "execution module",
        ("calib_core.solvers.static_bias", "import queue"): "execution module",
        ("calib_core.streamed", "import mmap"): "execution module",
        ("calib_core.streamed", "import ctypes"): "execution module",
        ("calib_core.noise", "from storage import queries"): "higher layer",
        ("calib_core.solvers.integral", "from ..simulate import noise"): "simulator",
        ("storage.archive", "from pipelines.process import run_outcome"): "storage imports",
        ("pipelines.commands.query", "from pipelines.cli import app"): "cli -> commands",
        ("pipelines.process", "from calib_core import simulate"): "simulator",
        ("pipelines.process", "import calib_core.simulate.table"): "simulator",
        ("storage.backup", "from calib_testing.pgserver import private_server"): "support",
        ("pipelines.cli", "from calib_testing import run_writers"): "support",
    }
    for (module, source), reason in cases.items():
        found = violations(module, source)
        assert len(found) == 1 and reason in found[0], (module, source, found)
    # allowed: the science's own libraries, the simulator inside itself, glue importing all
    assert violations("calib_core.noise", "import numpy as np\nfrom scipy import signal") == []
    assert violations("calib_core.simulate.table", "from calib_core.simulate import noise") == []
    assert violations("pipelines.process", "from storage import rawstore\nimport pyarrow") == []
    # the ground-truth benchmark's product side neither: its cases come from calib_testing
    assert violations("pipelines.validation.benchmark", "import calib_core.simulate") != []
    assert violations("pipelines.validation.benchmark", "from calib_testing import x") != []


def _import_edges(
    source: str, module: str, known: set[str], deferred: bool, is_package: bool = False
) -> set[str]:
    """The production modules `module` imports: at import time only, or also inside
    functions (`deferred`); never those under ``if TYPE_CHECKING``. ``from pkg import mod``
    is an edge to pkg.mod, not to the package that holds it."""
    package = module if is_package else module.rsplit(".", 1)[0]
    edges: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            return
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not deferred:
            return
        if isinstance(node, ast.Import):
            edges.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known]
            edges.update(subs or [base])
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(parsed(source))
    return {e for e in edges if e in known and e != module}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of `graph` (module -> modules it imports): its strongly connected
    components of more than one module, each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def walk(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in graph.get(node, ()):
            if nxt not in index:
                walk(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in list(graph):
        if node not in index:
            walk(node)
    return cycles


def _graph(deferred: bool, within: str = "") -> dict[str, set[str]]:
    mods = {m: p for m, p in production_modules().items() if _within(m, within or m)}
    known = set(mods)
    return {
        m: _import_edges(p.read_text("utf-8"), m, known, deferred, p.name == "__init__.py")
        for m, p in mods.items()
    }


def test_no_import_cycle() -> None:
    """No cycle among production modules at import time; and none in the web app even
    through deferred imports (its pages import the app's helpers, never the app)."""
    assert import_cycles(_graph(deferred=False)) == []
    assert import_cycles(_graph(deferred=True, within="pipelines.web")) == []


def test_no_deferred_import_loop() -> None:
    """No loop among production modules even through imports inside functions."""
    assert import_cycles(_graph(deferred=True)) == []


def test_the_cycle_finder_finds_a_deferred_loop() -> None:
    app = "from pipelines.web import runs\n"
    runs = "def page():\n    from pipelines.web.app import render\n"
    known = {"pipelines.web.app", "pipelines.web.runs"}
    graph = {
        "pipelines.web.app": _import_edges(app, "pipelines.web.app", known, deferred=True),
        "pipelines.web.runs": _import_edges(runs, "pipelines.web.runs", known, deferred=True),
    }
    assert import_cycles(graph) == [["pipelines.web.app", "pipelines.web.runs"]]
    graph["pipelines.web.runs"] = _import_edges(runs, "pipelines.web.runs", known, False)
    assert import_cycles(graph) == []


def test_one_class_name_per_concept() -> None:
    """No two production modules define a class of the same name: a name that means two
    things (a manifest record and a Type B spec, a measured plateau and a planned step, a
    segment's stretch of samples and a recalibration interval) is a reader's trap."""
    where: dict[str, list[str]] = {}
    for module, path in production_modules().items():
        for node in parsed(path.read_text("utf-8")).body:
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(module)
    assert {name: mods for name, mods in where.items() if len(mods) > 1} == {}


def private_imports(module: str, source: str, modules: set[str] = frozenset()) -> list[str]:
    """The private names (`_x`, not dunders) `module` imports from another production
    module, as ``module: from <module> import <name>`` (a package's private module, one of
    `modules`, is not a name: it is imported whole)."""
    found = []
    for _, name in imported_modules(source, module):
        base, _, last = name.rpartition(".")
        private = last.startswith("_") and not last.startswith("__")
        if base.split(".")[0] in PACKAGES and private and name not in modules:
            found.append(f"{module}: from {base} import {last}")
    return found


def test_few_private_names_cross_a_module_boundary() -> None:
    """A name a module keeps private is not another's to import: at most
    MAX_PRIVATE_IMPORTS such imports in all production code (a public name or one module)."""
    assert private_imports("pipelines.x", "from pipelines.ingest.csv_reader import _a, b") == [
        "pipelines.x: from pipelines.ingest.csv_reader import _a"
    ]
    assert private_imports("pipelines.x", "from numpy import _x\nfrom .y import __all__") == []
    mods = production_modules()
    found = [
        hit
        for mod, path in mods.items()
        for hit in private_imports(mod, path.read_text(), set(mods))
    ]
    assert len(found) <= MAX_PRIVATE_IMPORTS, "\n".join(found)
