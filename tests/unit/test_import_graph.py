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
    package = _package_of(path)
    found: set[str] = set()
    for node, typing_only in _import_statements(path):
        if typing_only and not typing_too:
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
            continue
        base = resolve_name("." * node.level + (node.module or ""), package)
        found.update([base, *(f"{base}.{alias.name}" for alias in node.names)])
    # A module's own package (its __init__) runs before it anyway: not an edge.
    return {m for m in found if m in modules and not name.startswith(m + ".") and m != name}


def _package_of(path: Path) -> str:
    """The package a relative import in ``path`` starts from."""
    name = _module_name(path)
    return name if path.name == "__init__.py" else name.rpartition(".")[0]


@functools.cache  # parsed once per process: several tests read the same imports
def _import_statements(path: Path) -> list[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Each import statement anywhere in ``path``, and whether it is under
    ``if TYPE_CHECKING:``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only = {id(node) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and ast.unparse(block.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
                   for statement in block.body for node in ast.walk(statement)}
    return [(node, id(node) in typing_only) for node in ast.walk(tree)
            if isinstance(node, ast.Import | ast.ImportFrom)]


@functools.cache  # read once per process: each test only reads it
def _graph(typing_too: bool = False) -> dict[str, set[str]]:
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {_module_name(path) for path in paths}
    return {_module_name(path): _imports(path, modules, typing_too) for path in paths}


def test_the_import_graph_has_no_cycle() -> None:
    graph = _graph()
    assert "tango_aio.catalog._table" in graph and "tango_aio.catalog._schema" in graph
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
    assert graph["tango_aio.catalog._schema"] == set()
    assert graph["tango_aio.catalog._replyrules"] == {"tango_aio.catalog._schema"}
    assert graph["tango_aio.catalog._table"] == {"tango_aio.catalog._schema",
                                                 "tango_aio.catalog._replyrules"}


def _fresh(code: str) -> None:
    subprocess.run([sys.executable, "-c", code], check=True, cwd=PACKAGE.parent,
                   capture_output=True, text=True)


@pytest.mark.parametrize("module", ["tango_aio.catalog._schema",
                                    "tango_aio.catalog._replyrules",
                                    "tango_aio.catalog._table",
                                    "tango_aio.catalog._instructions",
                                    "tango_aio.catalog._encode",
                                    "tango_aio.catalog._replies"])
def test_module_imports_first_in_a_fresh_interpreter(module: str) -> None:
    _fresh(f"import {module}")


def test_every_module_imports_in_dependency_order() -> None:
    order = [m for m in graphlib.TopologicalSorter(_graph()).static_order()
             if m != "tango_aio.__main__"  # __main__ runs the command line
             and not (WINDOWS and m == "tango_aio.sim.ptyserve")]  # POSIX only
    _fresh(f"import importlib\nfor name in {order!r}:\n    importlib.import_module(name)")


# ------------------------------------------------------------------ the layer rules -------
# The layers are read from ARCHITECTURE.md's diagram (its first code block), so the page and
# this test cannot drift apart: one line per layer, top first, each naming top-level modules
# (``errors.py``) and packages (``sansio/``). A module's home is its top-level package, or
# itself when it is a top-level module. A module imports its own home, or a home of a layer
# above its own; never another home of its own layer (no same-layer imports), never one
# below, and never a private module (``_name``) of another home: only what that package's
# ``__init__`` exports.

PACKAGE_FACADE = "tango_aio"  # __init__.py: re-exports from every layer, lazily
EMULATOR = "emulator"
# The emulator shares the catalog and the error table with the stack, and nothing else
# (ARCHITECTURE.md, "Rules of the layers"); its one documented exception, the motion
# model's units:
EMULATOR_MAY_IMPORT = {"catalog/", "errors.py"}
EMULATOR_EXCEPTIONS = {("tango_aio.sim.motion", "tango_aio.units"),
                       ("tango_aio.sim.engine", "tango_aio.units")}
STARTS_THE_EMULATOR = {"controller/", "testing.py", "cli/", "_argtypes.py"}
#: Layers whose code is sans-IO: no event loop, no clock, no thread, no port or socket.
SANS_IO = ("catalog/", "sansio/", "moves/")
NOT_SANS_IO = {"asyncio", "time", "threading", "socket", "select", "selectors", "serial",
               "os", "subprocess", "concurrent"}


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


def _home(module: str) -> str:
    """``sansio/`` for tango_aio.sansio._core, ``errors.py`` for tango_aio.errors."""
    parts = module.split(".")[1:]
    if (PACKAGE / parts[0]).is_dir():
        return parts[0] + "/"
    return parts[0] + ".py"


def _rank_of() -> dict[str, tuple[int, str]]:
    """Each home's (rank, layer): rank 0 is the top layer; the emulator has no rank."""
    ranked = [layer for layer in _layers() if layer[0] != EMULATOR]
    placed = {home: (rank, name) for rank, (name, homes) in enumerate(ranked)
              for home in homes}
    placed.update({home: (-1, EMULATOR) for name, homes in _layers()
                   if name == EMULATOR for home in homes})
    return placed


def _violations(graph: dict[str, set[str]], rank: dict[str, tuple[int, str]]) -> list[str]:
    found = []
    for module, imported in sorted(graph.items()):
        if module == PACKAGE_FACADE:
            continue
        home = _home(module)
        (my_rank, layer) = rank[home]
        for target in sorted(imported):
            if target == PACKAGE_FACADE:
                continue  # the package's own __version__: checked below
            there = _home(target)
            (target_rank, target_layer) = rank[there]
            if there == home:
                continue
            if any(part.startswith("_") for part in target.split(".")[2:]):
                found.append(f"{module} reaches into {target}, private to {there}")
                continue
            if layer == EMULATOR:
                ok = (there in EMULATOR_MAY_IMPORT
                      or (module, target) in EMULATOR_EXCEPTIONS)
            elif target_layer == EMULATOR:
                ok = home in STARTS_THE_EMULATOR
            else:
                ok = target_rank < my_rank
            if not ok:
                found.append(f"{module} ({layer}) imports {target} ({target_layer})")
    return found


def test_every_module_has_a_layer_in_the_page() -> None:
    rank = _rank_of()
    homes = {_home(module) for module in _graph() if module != PACKAGE_FACADE}
    unplaced = sorted(homes - set(rank))
    assert not unplaced, f"ARCHITECTURE.md's diagram places no layer for {unplaced}"
    assert rank["epics/"][1] == "integrations"
    assert rank["sim/"][1] == EMULATOR


def test_every_import_keeps_the_layer_rules() -> None:
    """A module imports only its own home or the layers above its own, counting
    function-level and ``TYPE_CHECKING`` imports; the emulator imports only the catalog and
    the errors."""
    violations = _violations(_graph(typing_too=True), _rank_of())
    assert not violations, "\n".join(violations)


@pytest.mark.parametrize(("module", "target"), [
    ("tango_aio.fieldkit._trace", "tango_aio.bluesky"),  # an integration, below
    ("tango_aio.link._reconnect", "tango_aio.families"),  # bulk transfers, below
    ("tango_aio.transports._portlink", "tango_aio.group"),  # coalescing, below
    ("tango_aio.bluesky._flyer", "tango_aio.epics"),  # another integration, same layer
    ("tango_aio.moves._timing", "tango_aio.sansio"),  # the sans-IO link, below
    ("tango_aio.controller._controller", "tango_aio.link._protocol"),  # a private module
    ("tango_aio.sim.model", "tango_aio.sansio"),  # the driver's rules, in the emulator
    ("tango_aio.bluesky._axis", "tango_aio.sim.wire"),  # the emulator, from the stack
])
def test_the_layer_check_sees_a_violation(module: str, target: str) -> None:
    imported = _graph(typing_too=True)[module]
    assert not _violations({module: imported}, _rank_of())
    assert _violations({module: imported | {target}}, _rank_of())


def test_sans_io_layers_import_no_loop_clock_or_port() -> None:
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "__init__.py" or _home(_module_name(path)) not in SANS_IO:
            continue
        for node, _ in _import_statements(path):
            names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom)
                     and node.level == 0 else [])
            bad = [name for name in names if name.split(".")[0] in NOT_SANS_IO]
            assert not bad, f"{path.relative_to(PACKAGE)} imports {bad}"


def test_the_package_is_imported_only_for_its_version() -> None:
    for path in sorted(PACKAGE.rglob("*.py")):
        package = _package_of(path)
        for node, _ in _import_statements(path):
            if isinstance(node, ast.ImportFrom) and node.module is None and node.level \
                    and resolve_name("." * node.level, package) == PACKAGE_FACADE:
                names = [alias.name for alias in node.names]
                assert all(name == "__version__" or (PACKAGE / f"{name}.py").exists()
                           or (PACKAGE / name).is_dir() for name in names), (path, names)
