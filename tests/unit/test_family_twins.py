"""Every family of the controller has a typed blocking twin in :mod:`tango_aio.sync`, and
every public method of an async family has its blocking twin there, declared on the
twin's class (not made up when looked up), with the same signature and docstring."""

from __future__ import annotations

import functools
import inspect
import re
import typing
from typing import Any

import pytest

import tango_aio.sync
from tango_aio import families
from tango_aio.controller import Controller as AsyncController
from tango_aio.sync._blocking import _Blocking, _Wrapper

#: The controller's families, by attribute (``tango.settings``...).
FAMILIES = ("settings", "info", "joystick", "io", "encoders", "closed_loop", "triggers",
            "snapshots")


def _twin_of(name: str) -> type[_Wrapper[Any]]:
    """The blocking twin class ``tango_aio.sync.Controller.<name>`` says it returns."""
    prop = getattr(tango_aio.sync.Controller, name)
    assert isinstance(prop, functools.cached_property), name
    twin = typing.get_type_hints(prop.func, vars(tango_aio.sync))["return"]
    assert isinstance(twin, type) and issubclass(twin, _Wrapper), (name, twin)
    return twin


def _wrapped(twin: type[_Wrapper[Any]]) -> type[families.Family]:
    """The async family class a twin wraps (``Joystick(JoystickAccess[AsyncJoystick])``)."""
    wrapped = {arg for base in twin.__orig_bases__  # type: ignore[attr-defined]
               for arg in typing.get_args(base)}
    assert len(wrapped) == 1, (twin, wrapped)
    (cls,) = wrapped
    assert issubclass(cls, families.Family)
    return typing.cast(type[families.Family], cls)


def _declared(twin: type, name: str) -> Any:
    """``name`` as a class of the twin's MRO declares it, or None."""
    for klass in twin.__mro__:
        if name in vars(klass):
            return vars(klass)[name]
    return None


def _public_methods(cls: type) -> dict[str, Any]:
    return {name: member for name, member in inspect.getmembers(cls, inspect.isfunction)
            if not name.startswith("_")}


def _same_overloads(twin: Any, method: Any) -> bool:
    def shapes(func: Any) -> list[inspect.Signature]:
        return [inspect.signature(item) for item in typing.get_overloads(func)]

    # An async overload's signature as a blocking one: the same parameters and return.
    return shapes(twin) == shapes(method)


def missing_twins(cls: type, twin: type) -> list[str]:
    """The public methods of the async family ``cls`` without a matching blocking twin on
    ``twin``, each with what is wrong."""
    problems = []
    for name, method in _public_methods(cls).items():
        declared = _declared(twin, name)
        if declared is None:
            problems.append(f"{name}: no twin")
        elif isinstance(declared, _Blocking):
            # The descriptor calls the async method by name: it must be made from the
            # very method the family has (not a base class's it overrides).
            if declared.__wrapped__ is not method:
                problems.append(f"{name}: made from {declared.__wrapped__.__qualname__}")
            elif not inspect.iscoroutinefunction(method):
                problems.append(f"{name}: a blocking descriptor of a plain method")
            elif typing.get_overloads(method):
                problems.append(f"{name}: overloads a descriptor loses")
        elif not inspect.isfunction(declared):
            problems.append(f"{name}: twin is {type(declared).__name__}")
        elif _blocking_signature(method) != inspect.signature(declared):
            problems.append(f"{name}: signature {inspect.signature(declared)} differs "
                            f"from {_blocking_signature(method)}")
        elif not _same_overloads(declared, method):
            problems.append(f"{name}: overloads differ")
        elif inspect.iscoroutinefunction(declared) or inspect.isasyncgenfunction(declared):
            problems.append(f"{name}: twin is not blocking")
    return problems


def _blocking_signature(method: Any) -> inspect.Signature:
    """The signature of ``method``'s blocking twin: the same, an async iterator's items
    given by a blocking iterator."""
    signature = inspect.signature(method)
    if not inspect.isasyncgenfunction(method):
        return signature
    items = re.fullmatch(r"AsyncGenerator\[(.*), None\]|AsyncIterator\[(.*)\]",
                         str(signature.return_annotation))
    assert items is not None, signature
    return signature.replace(return_annotation=f"Iterator[{items[1] or items[2]}]")


@pytest.mark.parametrize("name", FAMILIES)
def test_every_method_of_a_family_has_a_typed_blocking_twin(name: str) -> None:
    twin = _twin_of(name)
    cls = _wrapped(twin)
    assert not hasattr(twin, "__getattr__"), "twins are declared, not looked up"
    assert not missing_twins(cls, twin), missing_twins(cls, twin)


def test_every_family_of_the_controller_is_listed() -> None:
    """The controller's families are the attributes its ``__init__`` sets to a family
    object: each has a twin above (a new family without one fails here)."""
    source = inspect.getsource(AsyncController.__init__)
    made = {name for name in dir(families)
            if isinstance(getattr(families, name), type)
            and issubclass(getattr(families, name), families.Family)
            and f"= {name}(" in source}
    twins = {_wrapped(_twin_of(name)).__name__ for name in FAMILIES}
    assert made == twins


def test_twins_are_exported() -> None:
    for name in FAMILIES:
        twin = _twin_of(name)
        assert getattr(tango_aio.sync, twin.__name__) is twin
        assert twin.__name__ in tango_aio.sync.__all__


def test_a_method_added_without_a_twin_is_found() -> None:
    class Grown(families.Joystick):
        async def recentre(self, *, axis: str = "x") -> None:
            """Added without a blocking twin."""

        async def joydir(self) -> dict[str, int]:  # type: ignore[override]
            """An override the generated twin does not follow."""
            return {}

    class GrownTwin(tango_aio.sync.Joystick):
        pass

    assert missing_twins(Grown, GrownTwin) == [
        "joydir: signature (self, *, axis: 'str | None' = None) -> 'dict[str, JoydirMode] | "
        "JoydirMode' differs from (self) -> 'dict[str, int]'",
        "recentre: no twin"]

    class Retyped(families.Snapshots):
        async def count(self, *, limit: int = 0) -> int:
            """An override the hand-written twin does not follow."""
            return limit

    assert missing_twins(Retyped, tango_aio.sync.Snapshots) == [
        "count: made from Snapshots.count"]


def test_per_axis_reads_keep_their_overloads() -> None:
    twin = tango_aio.sync.Settings
    assert [str(inspect.signature(item)) for item in typing.get_overloads(twin.vel)] == [
        "(self) -> 'dict[str, float]'", "(self, *, axis: 'str') -> 'float'"]
    assert twin.vel.__doc__ == families.Settings.vel.__doc__
    assert twin.velocity.__doc__ == families.Settings.velocity.__doc__
