"""The package's lazy exports: every public name resolves, the type checkers' imports and
``__all__`` agree, and importing the package alone loads none of the driver."""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
from pathlib import Path

import tango_aio
import tango_aio.errors
import tango_aio.events


def _type_checking_imports() -> set[str]:
    tree = ast.parse(Path(inspect.getfile(tango_aio)).read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
            for statement in node.body:
                assert isinstance(statement, ast.ImportFrom)
                names.update(alias.asname or alias.name for alias in statement.names)
    return names


def test_every_exported_name_resolves_from_its_home() -> None:
    for name in tango_aio.__all__:
        value = getattr(tango_aio, name)
        module = getattr(value, "__module__", "")
        if module.startswith("tango_aio."):  # not a type alias such as TangoEvent
            assert module.split(".")[1] in tango_aio._HOMES, (name, module)


def test_type_checkers_see_exactly_the_exported_names() -> None:
    assert _type_checking_imports() == set(tango_aio.__all__)


def test_every_error_and_event_class_is_exported() -> None:
    public = {name for module in (tango_aio.errors, tango_aio.events)
              for name in module.__all__
              if isinstance(getattr(module, name), type) and name != "EventHub"}
    assert public <= set(tango_aio.__all__), public - set(tango_aio.__all__)


def test_unknown_names_raise_attribute_error() -> None:
    try:
        tango_aio.NoSuchThing  # noqa: B018
    except AttributeError as error:
        assert "NoSuchThing" in str(error)
    else:
        raise AssertionError("an unknown name resolved")


def test_importing_the_package_loads_none_of_the_driver() -> None:
    probe = ("import sys, tango_aio; "
             "print(sorted(m for m in sys.modules if m.startswith('tango_aio.') "
             "or m == 'asyncio'))")
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                            check=True).stdout.strip()
    assert loaded == "[]", loaded
