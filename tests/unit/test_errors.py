"""The exception hierarchy and the error-number table (manual chapter 5)."""

from __future__ import annotations

import json
import pickle
from pathlib import Path
from typing import Any

import pytest

from tango_aio import errors
from tango_aio.errors import (
    CATEGORIES,
    ERROR_DESCRIPTIONS,
    AmplifiersDisabledError,
    CommandRejectedError,
    ControllerError,
    HardwareFaultError,
    InternalControllerError,
    InvalidCommandError,
    LimitSwitchActiveError,
    OutOfRangeError,
    ProtocolError,
    StateError,
    TangoError,
    UnknownControllerError,
    controller_error,
    error_class,
    parse_error_reply,
)

REFERENCE = Path(__file__).resolve().parents[2] / "reference" / "errors.json"
DOCUMENTED: list[dict[str, Any]] = json.loads(REFERENCE.read_text(encoding="utf-8"))["errors"]


@pytest.mark.parametrize("error", DOCUMENTED, ids=[str(e["number"]) for e in DOCUMENTED])
def test_one_class_per_documented_number(error: dict[str, Any]) -> None:
    number = error["number"]
    cls = error_class(number)
    assert cls is not UnknownControllerError
    assert issubclass(cls, ControllerError)
    assert cls.number == number
    assert cls.text == error["description"]
    assert ERROR_DESCRIPTIONS[number] == error["description"]
    instance = controller_error(number, "!vel 10")
    assert type(instance) is cls
    assert instance.number == number
    assert instance.text == error["description"]
    assert instance.command == "!vel 10"
    assert str(number) in str(instance) and error["description"] in str(instance)
    # Exported under its own name.
    assert getattr(errors, cls.__name__) is cls
    assert cls.__name__ in errors.__all__


def test_no_undocumented_numbers() -> None:
    assert set(ERROR_DESCRIPTIONS) == {e["number"] for e in DOCUMENTED}
    classes = {error_class(e["number"]) for e in DOCUMENTED}
    assert len(classes) == len(DOCUMENTED)


def test_limit_switch_error() -> None:
    error = controller_error(12)
    assert isinstance(error, LimitSwitchActiveError)
    assert error.number == 12
    assert error.text == "limit switch active"
    assert error.command is None
    with pytest.raises(LimitSwitchActiveError):
        raise error


@pytest.mark.parametrize("number", [14, 20, 28, 69, 87, 999, -3])
def test_unknown_numbers(number: int) -> None:
    error = controller_error(number, "?pos")
    assert type(error) is UnknownControllerError
    assert error.number == number
    assert error.text == "unknown error"
    assert not isinstance(error, CATEGORIES)
    assert str(number) in str(error)
    assert isinstance(error, ControllerError) and isinstance(error, TangoError)


def test_controller_errors_pickle() -> None:
    for error in (controller_error(12, "!moa 1"), controller_error(4242)):
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error)
        assert copy.number == error.number and copy.command == error.command
        assert copy.text == error.text and str(copy) == str(error)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("ERR 5", (5, None)),
        ("ERR", (None, None)),
        ("ERR 29", (29, None)),
        ("OK...", (0, None)),
        ("OK... ", (0, None)),
        ("5", (5, None)),
        ("0", (0, None)),
        ("  29\r", (29, None)),
        ("ERROR 29,servo amplifier off", (29, "servo amplifier off")),
        ("ERROR 5,number outside range", (5, "number outside range")),
        ("ERROR 0,no error", (0, "no error")),
        ("ERROR 4,unknown keyword", (4, "unknown keyword")),
    ],
)
def test_parse_error_reply(line: str, expected: tuple[int | None, str | None]) -> None:
    assert parse_error_reply(line) == expected


@pytest.mark.parametrize("line", ["", "hello", "10.000", "@@@-.", "ERR x", "1 2"])
def test_parse_error_reply_rejects_other_lines(line: str) -> None:
    with pytest.raises(ProtocolError):
        parse_error_reply(line)


def test_invalid_command_error_is_a_value_error() -> None:
    error = InvalidCommandError("bad", instruction="vel", parameter="velocity", number=5)
    assert isinstance(error, ValueError) and isinstance(error, TangoError)
    assert not isinstance(error, ControllerError)
    assert (error.instruction, error.parameter, error.number) == ("vel", "velocity", 5)
    assert InvalidCommandError("bad").number == 4
    with pytest.raises(ValueError):
        raise error


def test_hierarchy() -> None:
    for cls in (ProtocolError, ControllerError, errors.MoveError, errors.ConnectionLostError,
                errors.RequestAbortedError, errors.ControllerTimeoutError):
        assert issubclass(cls, TangoError)
    assert issubclass(errors.ControllerTimeoutError, TimeoutError)
    move = errors.MoveError("stopped", {"x": "S", "y": "@"})
    assert move.statuses == {"x": "S", "y": "@"}


def _category(number: int) -> type[ControllerError] | None:
    """The category a number belongs to, by the ranges of issue 18 (not by the code)."""
    if 1 <= number <= 7:
        return CommandRejectedError
    if 8 <= number <= 30:
        return StateError
    if 70 <= number <= 86:
        return HardwareFaultError
    return None


@pytest.mark.parametrize("error", DOCUMENTED, ids=[str(e["number"]) for e in DOCUMENTED])
def test_every_number_is_in_exactly_its_category(error: dict[str, Any]) -> None:
    number = error["number"]
    cls = error_class(number)
    expected = _category(number)
    inside = [category for category in CATEGORIES if issubclass(cls, category)]
    assert inside == ([] if expected is None else [expected])
    if expected is not None:
        assert cls.__bases__ == (expected,)


def test_categories_are_caught_by_except() -> None:
    with pytest.raises(CommandRejectedError) as info:
        raise controller_error(5, "!vel 1e9")
    assert type(info.value) is OutOfRangeError
    with pytest.raises(StateError):
        raise controller_error(12)
    with pytest.raises(HardwareFaultError):
        raise controller_error(73)
    # The categories are ControllerErrors and do not stand for a number themselves.
    for category in CATEGORIES:
        assert issubclass(category, ControllerError)
        assert category.number == -1
        assert category not in {error_class(e["number"]) for e in DOCUMENTED}
        assert category.__name__ in errors.__all__


@pytest.mark.parametrize("number", sorted(n for n in ERROR_DESCRIPTIONS if n >= 20))
def test_internal_error_is_also_its_numbers_class(number: int) -> None:
    error = InternalControllerError(number)
    own = error_class(number)
    assert isinstance(error, InternalControllerError) and isinstance(error, own)
    assert isinstance(error, _category(number) or ControllerError)
    assert error.number == number and error.command is None
    assert error.text == ERROR_DESCRIPTIONS[number]
    assert "not caused by a command" in str(error)
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error) and str(copy) == str(error)
    assert copy.number == number
    # The internal variant does not take the number's place in the table.
    assert error_class(number) is own


def test_internal_error_of_an_undocumented_number() -> None:
    error = InternalControllerError(55)
    assert type(error) is InternalControllerError
    assert error.number == 55 and error.text == "unknown error"
    assert type(pickle.loads(pickle.dumps(error))) is InternalControllerError


def test_amplifiers_off_caught_as_state_error() -> None:
    with pytest.raises(StateError) as info:
        raise InternalControllerError(29)
    assert isinstance(info.value, AmplifiersDisabledError)


def test_every_error_pickles() -> None:
    for number in ERROR_DESCRIPTIONS:
        error = controller_error(number, f"!cmd {number}")
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error)
        assert (copy.number, copy.text, copy.command) == (error.number, error.text,
                                                          error.command)
    invalid = pickle.loads(pickle.dumps(InvalidCommandError("bad", number=6)))
    assert invalid.number == 6


def test_package_exports_every_error_class() -> None:
    import tango_aio

    for name in errors.__all__:
        value = getattr(errors, name)
        if isinstance(value, type) and issubclass(value, TangoError):
            assert getattr(tango_aio, name) is value, name
            assert name in tango_aio.__all__, name

def test_move_error_pickles_with_its_statuses() -> None:
    error = errors.MoveError("'!moa 1' ended with status {'x': 'S'}", {"x": "S", "y": "@"})
    error.add_note("while scanning")
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is errors.MoveError
    assert str(again) == str(error) and again.statuses == {"x": "S", "y": "@"}
    assert again.__notes__ == ["while scanning"]


def _every_tango_error() -> set[type[TangoError]]:
    import importlib
    import pkgutil

    import tango_aio
    from tango_aio._platform import WINDOWS

    for module in pkgutil.walk_packages(tango_aio.__path__, "tango_aio."):
        if module.name != "tango_aio.__main__" and not (
                module.name == "tango_aio.sim.ptyserve" and WINDOWS):  # POSIX only
            importlib.import_module(module.name)
    found: set[type[TangoError]] = set()
    todo: list[type[TangoError]] = [TangoError]
    while todo:
        cls = todo.pop()
        found.add(cls)
        todo.extend(sub for sub in cls.__subclasses__() if sub not in found)
    return found


def test_every_tango_error_is_defined_in_errors() -> None:
    elsewhere = {f"{cls.__module__}.{cls.__qualname__}" for cls in _every_tango_error()
                 if cls.__module__ != "tango_aio.errors"}
    assert elsewhere == set()


def test_the_surfaces_errors_keep_their_old_import_paths() -> None:
    from tango_aio import bluesky
    from tango_aio import fieldkit as probe
    from tango_aio.epics import ioc
    from tango_aio.families import _bulk as bulk
    from tango_aio.link import _protocol as protocol
    from tango_aio.link import _reconnect as reconnect

    assert protocol.WrongEventLoopError is errors.WrongEventLoopError
    assert bulk.UploadError is errors.UploadError
    assert reconnect.IdentityMismatchError is errors.IdentityMismatchError
    assert probe.ProbeError is errors.ProbeError
    assert (ioc.MotorRefusedError, ioc.MoveStoppedError) == (errors.MotorRefusedError,
                                                              errors.MoveStoppedError)
    assert (bluesky.StageLimitsError, bluesky.MissingAxisError) == (
        errors.StageLimitsError, errors.MissingAxisError)
    assert issubclass(errors.StageLimitsError, errors.InvalidCommandError)
