"""Every public function and method of the package documents its parameters and its result
in numpydoc sections (``Parameters``, ``Returns``, ``Yields``), which the API reference
shows as fields. ruff's pydocstyle and pydoclint rules (pyproject.toml) check the sections'
form and the ``Raises``/``Returns`` a body calls for; no ruff rule asks for a
``Parameters`` section to exist, so this test does.

Read from the source (ast), so that a module needing an optional extra is checked too."""

from __future__ import annotations

import ast
import collections
import copy
import functools
import inspect
import re
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "tango_aio"

#: Generated from the reference data (tools/), not written by hand.
GENERATED = {"catalog/_table.py", "families/_generated.py"}
#: The emulator's instruction handlers: each ``i_<instruction>`` method takes the parsed
#: line and returns the reply lines (``None``: no reply), as these modules' docstrings say
#: once for all of them; the sections would repeat that on every handler.
HANDLER_MODULES = {"sim/handlers.py", "sim/peripherals.py"}
#: A Sardana controller: its methods (``StateOne``, ``StartAll``, ...) and constructor are
#: the pool's interface, documented once by Sardana; the class docstring says what ours do.
FRAMEWORK_OVERRIDES = {"sardana/_controller.py", "sardana/_trigger.py"}
#: ``raise _fail(...)``: a helper builds the error, and the Raises sections name the class
#: it builds (InvalidCommandError), not the helper.
RAISES_ELSEWHERE = {"catalog/_instructions.py", "catalog/_encode.py"}

_HEADER = re.compile(r"^(?P<indent> *)(?P<name>[A-Z][a-z]+(?: [A-Z][a-z]+)?)\n(?P=indent)-{3,}$",
                     re.MULTILINE)
_DECORATORS_WITHOUT_SECTIONS = {"property", "cached_property", "overload", "setter", "deleter",
                                "pymm_property"}


def _relative(path: Path) -> str:
    return path.relative_to(PACKAGE).as_posix()


def _public_api() -> list[str]:
    """docs/conf.py's ``PUBLIC_API``: the one list of the modules a program imports."""
    tree = ast.parse((PACKAGE.parent / "docs" / "conf.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and ast.unparse(node.targets[0]) == "PUBLIC_API":
            return list(ast.literal_eval(node.value))
    raise AssertionError("docs/conf.py has no PUBLIC_API")


def _file_of(module: str) -> Path:
    path = PACKAGE.parent.joinpath(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _defined_in(path: Path, name: str) -> Path | None:
    """The file that defines ``name``, following ``path``'s relative imports of it."""
    found = _definitions(path).get(name)
    if found is None or isinstance(found, Path):
        return found
    source, original = found
    return _defined_in(source, original) if source.is_file() else None


@functools.cache  # each worker collects this module: read each file once
def _definitions(path: Path) -> dict[str, Path | tuple[Path, str]]:
    """Each name ``path`` defines at its top level (to ``path``) or imports relatively (to
    the file it imports it from and its name there), the first one in ``ast.walk``'s order."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(node) for node in tree.body}
    found: dict[str, Path | tuple[Path, str]] = {}
    for node in _statements(tree):
        if isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) \
                and id(node) in top:
            found.setdefault(node.name, path)
        elif isinstance(node, ast.ImportFrom) and node.level:
            base = path.parent
            for _ in range(node.level - 1):
                base = base.parent
            target = base.joinpath(*(node.module or "").split(".")) if node.module else base
            source = target / "__init__.py" if target.is_dir() else target.with_suffix(".py")
            for alias in node.names:
                found.setdefault(alias.asname or alias.name, (source, alias.name))
    return found


def _statements(tree: ast.Module) -> Iterator[ast.AST]:
    """``ast.walk(tree)`` without the expressions (no statement is inside one)."""
    todo: collections.deque[ast.AST] = collections.deque([tree])
    while todo:
        node = todo.popleft()
        todo.extend(child for child in ast.iter_child_nodes(node)
                    if isinstance(child, ast.stmt | ast.excepthandler | ast.match_case))
        yield node


def _exported_names(module: str) -> list[str]:
    tree = ast.parse(_file_of(module).read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and ast.unparse(node.targets[0]) == "__all__":
            return list(ast.literal_eval(node.value))
    return []


@functools.cache
def _public_modules() -> dict[Path, set[str] | None]:
    """Each file that holds public API: a public module's own file (all its public names:
    ``None``) and, for the names a public package exports from its private modules, those
    modules' files (only those names)."""
    found: dict[Path, set[str] | None] = {}
    for module in _public_api():
        found[_file_of(module)] = None
        for name in _exported_names(module):
            home = _defined_in(_file_of(module), name)
            if home is not None and home != _file_of(module):
                names = found.setdefault(home, set())
                if names is not None:
                    names.add(name)
    return found


def _decorator_names(node: ast.FunctionDef | ast.AsyncFunctionDef) -> set[str]:
    names = set()
    for decorator in node.decorator_list:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        names.add(ast.unparse(target).rpartition(".")[2])
    return names


def _top_level(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """The statements of a module or class body, looking into ``if`` and ``try`` blocks
    (a definition that depends on the platform or on an optional import)."""
    for node in body:
        if isinstance(node, ast.If):
            yield from _top_level(node.body)
            yield from _top_level(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (node.body, node.orelse, node.finalbody):
                yield from _top_level(block)
            for handler in node.handlers:
                yield from _top_level(handler.body)
        else:
            yield node


def _public_functions(
        tree: ast.Module) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef, bool]]:
    """(qualified name, node, is a method) of each public function and public method of a
    public class; a class's ``__init__`` as the class itself (numpydoc documents the
    constructor's parameters in the class docstring)."""
    for node in _top_level(tree.body):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            if not node.name.startswith("_"):
                yield node.name, node, False
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for member in _top_level(node.body):
                if isinstance(member, ast.FunctionDef | ast.AsyncFunctionDef) \
                        and not member.name.startswith("_"):
                    yield f"{node.name}.{member.name}", member, True
                elif isinstance(member, ast.FunctionDef) and member.name == "__init__":
                    yield node.name, _constructor(node, member), True


def _constructor(cls: ast.ClassDef, init: ast.FunctionDef) -> ast.FunctionDef:
    """``init`` with the class's docstring, and no result to document."""
    constructor = copy.copy(init)
    constructor.body = [*cls.body[:1], *init.body]
    constructor.decorator_list = []
    constructor.returns = None
    return constructor


def _yields(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """Whether the function itself (not a function nested in it) yields."""
    stack: list[ast.AST] = list(node.body)
    while stack:
        child = stack.pop()
        if isinstance(child, ast.Yield | ast.YieldFrom):
            return True
        if not isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda
                          | ast.ClassDef):
            stack.extend(ast.iter_child_nodes(child))
    return False


def _raised(node: ast.FunctionDef | ast.AsyncFunctionDef) -> set[str]:
    """The exception classes the function itself raises by name (``raise X(...)``)."""
    found: set[str] = set()
    stack: list[ast.AST] = list(node.body)
    while stack:
        child = stack.pop()
        if isinstance(child, ast.Raise) and child.exc is not None:
            target = child.exc.func if isinstance(child.exc, ast.Call) else child.exc
            name = ast.unparse(target).rpartition(".")[2]
            if name[:1].isupper():
                found.add(name)
        if not isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda
                          | ast.ClassDef):
            stack.extend(ast.iter_child_nodes(child))
    return found


def sections(docstring: str) -> dict[str, list[str]]:
    """The numpydoc sections of a docstring: header to the names its entries list (an
    entry is a line at the header's indent, ``name : type`` or ``a, b : type``)."""
    found: dict[str, list[str]] = {}
    headers = list(_HEADER.finditer(docstring))
    ends = [header.start() for header in headers[1:]] + [len(docstring)] * bool(headers)
    for header, end in zip(headers, ends, strict=True):
        indent = header.group("indent")
        body = docstring[header.end():end]
        names: list[str] = []
        for line in body.splitlines():
            if line.strip() and line.startswith(indent) and not line[len(indent)].isspace():
                names.extend(name.strip() for name in line.split(" : ")[0].split(","))
        found[header.group("name")] = names
    return found


def _help_texts(tree: ast.Module) -> set[str]:
    """The functions whose docstring the module shows as a command's ``--help`` text
    (``description=run_ioc.__doc__``): plain prose, without sections."""
    return {node.value.id for node in ast.walk(tree)
            if isinstance(node, ast.Attribute) and node.attr == "__doc__"
            and isinstance(node.value, ast.Name)}


def problems(source: str, *, handlers: bool = False, only: set[str] | None = None,
             raises_elsewhere: bool = False, overrides: bool = False) -> list[str]:
    """What each public function and method of a module's source lacks (``handlers``:
    instruction handler methods, ``i_<instruction>``, are left out; ``only``: just these
    top-level names and their methods)."""
    found = []
    tree = ast.parse(source)
    help_texts = _help_texts(tree)
    for name, node, method in _public_functions(tree):
        if only is not None and name.partition(".")[0] not in only:
            continue
        decorators = _decorator_names(node)
        if decorators & _DECORATORS_WITHOUT_SECTIONS or name in help_texts:
            continue
        if handlers and method and node.name.startswith("i_"):
            continue
        if overrides and method and (node.name[:1].isupper() or node.name == "__init__"):
            continue
        docstring = ast.get_docstring(node) or ""
        documented = sections(docstring)
        arguments = node.args
        parameters = [*arguments.posonlyargs, *arguments.args]
        if method and "staticmethod" not in decorators:
            parameters = parameters[1:]  # self or cls
        names = [parameter.arg for parameter in [*parameters, *arguments.kwonlyargs]]
        if arguments.vararg:
            names.append(f"*{arguments.vararg.arg}")
        if arguments.kwarg:
            names.append(f"**{arguments.kwarg.arg}")
        listed = {entry.lstrip("*") for entry in documented.get("Parameters", [])}
        missing = [parameter for parameter in names if parameter.lstrip("*") not in listed]
        if missing:
            found.append(f"{name}: Parameters lacks {', '.join(missing)}")
        returns = ast.unparse(node.returns) if node.returns else "None"
        if _yields(node):
            if "Yields" not in documented:
                found.append(f"{name}: no Yields section")
        elif returns not in {"None", "NoReturn", "Never"} and "Returns" not in documented:
            found.append(f"{name}: no Returns section (returns {returns})")
        unlisted = sorted(_raised(node) - {entry.rpartition(".")[2]
                                           for entry in documented.get("Raises", [])})
        if unlisted and not raises_elsewhere:
            found.append(f"{name}: Raises lacks {', '.join(unlisted)}")
    return found


def _checked() -> list[Path]:
    return [path for path in _public_modules() if _relative(path) not in GENERATED]


@pytest.mark.parametrize("path", _checked(), ids=_relative)
def test_public_functions_document_parameters_and_results(path: Path) -> None:
    handlers = _relative(path) in HANDLER_MODULES
    only = _public_modules()[path]
    assert problems(path.read_text(encoding="utf-8"), handlers=handlers, only=only,
                    raises_elsewhere=_relative(path) in RAISES_ELSEWHERE,
                    overrides=_relative(path) in FRAMEWORK_OVERRIDES) == []


def test_the_public_api_includes_what_packages_export_from_private_modules() -> None:
    files = _public_modules()
    assert files[PACKAGE / "controller" / "_controller.py"] == {"Controller"}
    assert files[PACKAGE / "controller" / "_reads.py"] == {"Identity"}
    assert "MarzhauserStage" in (files[PACKAGE / "bluesky" / "_stage.py"] or ())
    assert files[PACKAGE / "errors.py"] is None


def test_the_ruff_exceptions_are_the_same_modules() -> None:
    """pyproject.toml lets exactly the modules this test skips go without the pydoclint
    rules: the generated ones."""
    config = tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text(encoding="utf-8"))
    ignores = config["tool"]["ruff"]["lint"]["per-file-ignores"]
    without = {key.removeprefix("tango_aio/") for key, rules in ignores.items()
               if key.startswith("tango_aio/") and "DOC" in rules}
    assert without == GENERATED


def test_the_check_finds_what_is_missing() -> None:
    source = '''
def move(axis: str, target: float, *, wait: bool = True) -> float:
    """Move.

    Parameters
    ----------
    axis : str
        The axis.
    target
        Where to.
    """


class Stage:
    def read(self, *names: str) -> Iterator[float]:
        """Read.

        Parameters
        ----------
        *names
            Which.
        """
        yield 1.0

    @property
    def position(self) -> float:
        """The position."""

    def command(self, x: int) -> int:
        """A command."""

    def _private(self, x: int) -> int:
        """Not checked."""


class Axis:
    """An axis.

    Parameters
    ----------
    letter
        Its letter.
    """

    def __init__(self, letter: str, speed: float) -> None:
        """Not where numpydoc looks."""
'''
    assert problems(source) == [
        "move: Parameters lacks wait",
        "move: no Returns section (returns float)",
        "Stage.read: no Yields section",
        "Stage.command: Parameters lacks x",
        "Stage.command: no Returns section (returns int)",
        "Axis: Parameters lacks speed",
    ]
    assert problems(source + "\nHELP = move.__doc__\n") == problems(source)[2:]
    handler = "class Handlers:\n    def i_pos(self, c: Command) -> Reply:\n        ...\n"
    assert problems(handler, handlers=True) == []
    assert problems(handler) == ["Handlers.i_pos: Parameters lacks c",
                                 "Handlers.i_pos: no Returns section (returns Reply)"]
    assert sections("Summary.\n\nReturns\n-------\nfloat\n    The value.\n") \
        == {"Returns": ["float"]}
    raising = ('def stop() -> None:\n    """Stop.\n\n    Raises\n    ------\n    MoveError\n'
               '        Still moving.\n    """\n    raise errors.MoveError("x")\n'
               '    raise TimeoutError\n')
    assert problems(raising) == ["stop: Raises lacks TimeoutError"]
    assert problems(raising, raises_elsewhere=True) == []


def test_a_start_method_keeps_the_sections_but_not_the_result() -> None:
    """``tango_aio.sync``'s ``start_*`` docstrings reuse the async method's: dedented, so
    that its sections still parse after the line put before them, and without Returns
    (a ``start_*`` call returns a future at once)."""
    import tango_aio.sync

    assert "Returns" in sections(inspect.getdoc(tango_aio.ControllerGroup.move_to) or "")
    doc = tango_aio.sync.ControllerGroup.start_move_to.__doc__ or ""
    found = sections(doc)
    assert set(found) == {"Parameters", "Raises"}
    assert found["Parameters"] == ["targets", "timeout", "stop_on_cancel", "fail_fast"]
