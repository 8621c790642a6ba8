"""The package's modules import each other without a cycle, the catalog loads alone, and
every import keeps ARCHITECTURE.md's layer rules."""

from __future__ import annotations

import ast
import functools
import graphlib
import re
import subprocess
import sys
from importlib.util import resolve_name
from pathlib import Path

import pytest
from helpers import WINDOWS

PACKAGE = Path(__file__).resolve().parents[2] / "tango_aio"
PAGE = PACKAGE.parent / "ARCHITECTURE.md"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, modules: set[str], typing_too: bool = False) -> set[str]:
    """The package modules ``path`` imports anywhere in its text (function-level imports
    included: they make cycles too, only later; imports under ``if TYPE_CHECKING:`` left
    out unless ``typing_too``)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only = {id(node) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and ast.unparse(block.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
                   for statement in block.body for node in ast.walk(statement)}
    found: set[str] = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Import | ast.ImportFrom) or (
                id(node) in typing_only and not typing_too):
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
            continue
        base = resolve_name("." * node.level + (node.module or ""), package)
        found.update([base, *(f"{base}.{alias.name}" for alias in node.names)])
    # A module's own package (its __init__) runs before it anyway: not an edge.
    return {m for m in found if m in modules and not name.startswith(m + ".") and m != name}


@functools.cache  # read once per process: each test only reads it
def _graph(typing_too: bool = False) -> dict[str, set[str]]:
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {_module_name(path) for path in paths}
    return {_module_name(path): _imports(path, modules, typing_too) for path in paths}


def test_the_import_graph_has_no_cycle() -> None:
    graph = _graph()
    assert "tango_aio._catalog" in graph and "tango_aio.schema" in graph
    order = list(graphlib.TopologicalSorter(graph).static_order())  # CycleError if any
    assert len(order) == len(graph)


def test_the_import_graph_has_no_cycle_counting_typing_imports() -> None:
    """Imports under ``if TYPE_CHECKING:`` count too: a module that names another only for
    its types still cannot be read (or type-checked) without it, so the two would be one
    knot. The emulator's handlers see the model through ``sim/port.py``'s protocol."""
    graph = _graph(typing_too=True)
    # sim/__init__.py imports its modules only for their types: they count here.
    assert "tango_aio.sim.model" in graph["tango_aio.sim"] - _graph()["tango_aio.sim"]
    order = list(graphlib.TopologicalSorter(graph).static_order())  # CycleError if any
    assert len(order) == len(graph)


def test_schema_and_catalog_import_only_downwards() -> None:
    graph = _graph()
    assert graph["tango_aio.schema"] == set()
    assert graph["tango_aio.replyrules"] == {"tango_aio.schema"}
    assert graph["tango_aio._catalog"] == {"tango_aio.schema", "tango_aio.replyrules"}


def _fresh(code: str) -> None:
    subprocess.run([sys.executable, "-c", code], check=True, cwd=PACKAGE.parent,
                   capture_output=True, text=True)


@pytest.mark.parametrize("module", ["tango_aio.schema", "tango_aio.replyrules",
                                    "tango_aio._catalog", "tango_aio.instructions"])
def test_module_imports_first_in_a_fresh_interpreter(module: str) -> None:
    _fresh(f"import {module}")


def test_every_module_imports_in_dependency_order() -> None:
    order = [m for m in graphlib.TopologicalSorter(_graph()).static_order()
             if m != "tango_aio.__main__"  # __main__ runs the command line
             and not (WINDOWS and m == "tango_aio.sim.ptyserve")]  # POSIX only
    _fresh(f"import importlib\nfor name in {order!r}:\n    importlib.import_module(name)")


# ------------------------------------------------------------------ the layer rules -------
# The layers are read from ARCHITECTURE.md's diagram (its first code block), so the page and
# this test cannot drift apart: one line per layer, top first; ``epics/`` names a package.

PACKAGE_FACADE = "tango_aio"  # __init__.py: re-exports from every layer, lazily
EMULATOR = "emulator"
# The emulator shares the catalog (but not patterns.py, the driver's reading of a reply) and
# the error table with the stack, and nothing else (ARCHITECTURE.md, "Rules of the layers").
EMULATOR_MAY_IMPORT = {"tango_aio.schema", "tango_aio._catalog", "tango_aio.instructions",
                       "tango_aio.replyrules", "tango_aio.errors"}
# The documented exceptions, each named in ARCHITECTURE.md.
EMULATOR_EXCEPTIONS = {("tango_aio.sim.motion", "tango_aio.units")}
STARTS_THE_EMULATOR = {"tango_aio.connection", "tango_aio.testing", "tango_aio.cli",
                       "tango_aio._argtypes"}


def _layers() -> list[tuple[str, list[str]]]:
    """(layer, the files and packages it names) for each line of the page's diagram."""
    block = PAGE.read_text(encoding="utf-8").split("```")[1]
    layers = []
    for line in block.splitlines()[1:]:
        if not line.strip() or line.strip() == "↓":
            continue
        name, _, rest = line.partition("  ")
        layers.append((name.strip(), re.findall(r"[\w/]*\w\.py|\w+/",
                                                   re.sub(r"\([^)]*\)", "", rest))))
    return layers


def _layer_of() -> dict[str, tuple[int, str]]:
    """Each module's (rank, layer): rank 0 is the top layer; the emulator has no rank."""
    placed: dict[str, tuple[int, str]] = {}
    ranked = [layer for layer in _layers() if layer[0] != EMULATOR]
    files = [(f, (rank, name)) for rank, (name, fs) in enumerate(ranked) for f in fs]
    files += [(f, (-1, EMULATOR)) for name, fs in _layers() if name == EMULATOR for f in fs]
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if module == PACKAGE_FACADE:
            continue
        relative = path.relative_to(PACKAGE).as_posix()
        exact = dict(files)  # a file named on its own line before the package holding it
        packages = [where for entry, where in files
                    if entry.endswith("/") and relative.startswith(entry)]
        if relative in exact or packages:
            placed[module] = exact.get(relative) or packages[0]
    return placed


def _violations(graph: dict[str, set[str]], layer: dict[str, tuple[int, str]]) -> list[str]:
    found = []
    for module, imported in sorted(graph.items()):
        if module == PACKAGE_FACADE:
            continue
        (rank, name) = layer[module]
        for target in sorted(imported):
            if target == PACKAGE_FACADE:
                continue  # the package's own __version__: checked below
            (target_rank, target_name) = layer[target]
            if name == EMULATOR:
                ok = (target_name == EMULATOR or target in EMULATOR_MAY_IMPORT
                      or (module, target) in EMULATOR_EXCEPTIONS)
            elif target_name == EMULATOR:
                ok = module in STARTS_THE_EMULATOR
            else:
                ok = target_rank <= rank
            if not ok:
                found.append(f"{module} ({name}) imports {target} ({target_name})")
    return found


def test_every_module_has_a_layer_in_the_page() -> None:
    layer = _layer_of()
    unplaced = sorted(set(_graph()) - set(layer) - {PACKAGE_FACADE})
    assert not unplaced, f"ARCHITECTURE.md's diagram places no layer for {unplaced}"
    assert layer["tango_aio.epics.flush"][1] == "integrations"
    assert layer["tango_aio.sim.wire"][1] == EMULATOR


def test_every_import_keeps_the_layer_rules() -> None:
    """A module imports only its own layer or the layers above it, counting function-level
    and ``TYPE_CHECKING`` imports; the emulator imports only the catalog and the errors."""
    violations = _violations(_graph(typing_too=True), _layer_of())
    assert not violations, "\n".join(violations)


def test_the_layer_check_sees_a_violation() -> None:
    layer = _layer_of()
    graph = {"tango_aio.state": {"tango_aio.controller"},
             "tango_aio.sim.model": {"tango_aio.core", "tango_aio.errors"},
             "tango_aio.bluesky": {"tango_aio.sim.wire"}}
    assert _violations(graph, layer) == [
        "tango_aio.bluesky (integrations) imports tango_aio.sim.wire (emulator)",
        "tango_aio.sim.model (emulator) imports tango_aio.core (core)",
        "tango_aio.state (core) imports tango_aio.controller (controller)"]


def test_the_package_is_imported_only_for_its_version() -> None:
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module is None and node.level == 1 \
                    and path.parent == PACKAGE:
                names = [alias.name for alias in node.names]
                assert all(name == "__version__" or (PACKAGE / f"{name}.py").exists()
                           or (PACKAGE / name).is_dir() for name in names), (path, names)
