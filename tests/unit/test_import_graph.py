"""The package's modules import each other without a cycle, and the catalog loads alone."""

from __future__ import annotations

import ast
import graphlib
import subprocess
import sys
from importlib.util import resolve_name
from pathlib import Path

import pytest
from helpers import WINDOWS

PACKAGE = Path(__file__).resolve().parents[2] / "tango_aio"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The package modules ``path`` imports at run time anywhere in its text
    (function-level imports included: they make cycles too, only later; imports under
    ``if TYPE_CHECKING:`` left out)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only = {id(node) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and ast.unparse(block.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
                   for statement in block.body for node in ast.walk(statement)}
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in typing_only or not isinstance(node, ast.Import | ast.ImportFrom):
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
            continue
        base = resolve_name("." * node.level + (node.module or ""), package)
        found.update([base, *(f"{base}.{alias.name}" for alias in node.names)])
    # A module's own package (its __init__) runs before it anyway: not an edge.
    return {m for m in found if m in modules and not name.startswith(m + ".") and m != name}


def _graph() -> dict[str, set[str]]:
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {_module_name(path) for path in paths}
    return {_module_name(path): _imports(path, modules) for path in paths}


def test_the_import_graph_has_no_cycle() -> None:
    graph = _graph()
    assert "tango_aio._catalog" in graph and "tango_aio.schema" in graph
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
