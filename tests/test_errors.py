"""The exception hierarchy and the error-number table (manual chapter 5)."""

from __future__ import annotations

import json
import pickle
from pathlib import Path
from typing import Any

import pytest

from tango_aio import errors
from tango_aio.errors import (
    ERROR_DESCRIPTIONS,
    ControllerError,
    InvalidCommandError,
    LimitSwitchActiveError,
    ProtocolError,
    TangoError,
    UnknownControllerError,
    controller_error,
    error_class,
    parse_error_reply,
)

REFERENCE = Path(__file__).resolve().parents[1] / "reference" / "errors.json"
DOCUMENTED: list[dict[str, Any]] = json.loads(REFERENCE.read_text(encoding="utf-8"))["errors"]


@pytest.mark.parametrize("error", DOCUMENTED, ids=[str(e["number"]) for e in DOCUMENTED])
def test_one_class_per_documented_number(error: dict[str, Any]) -> None:
    number = error["number"]
    cls = error_class(number)
    assert cls is not UnknownControllerError
    assert issubclass(cls, ControllerError)
    assert cls.code == number
    assert cls.description == error["description"]
    assert ERROR_DESCRIPTIONS[number] == error["description"]
    instance = controller_error(number, "!vel 10")
    assert type(instance) is cls
    assert instance.error_code == instance.code == number
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
    assert error.code == error.error_code == 12
    assert error.text == "limit switch active"
    assert error.command is None
    with pytest.raises(LimitSwitchActiveError):
        raise error


@pytest.mark.parametrize("number", [14, 20, 28, 69, 87, 999, -3])
def test_unknown_numbers(number: int) -> None:
    error = controller_error(number, "?pos")
    assert type(error) is UnknownControllerError
    assert error.error_code == number
    assert str(number) in str(error)
    assert isinstance(error, ControllerError) and isinstance(error, TangoError)


def test_controller_errors_pickle() -> None:
    for error in (controller_error(12, "!moa 1"), controller_error(4242)):
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error)
        assert copy.error_code == error.error_code and copy.command == error.command


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
    error = InvalidCommandError("bad", instruction="vel", parameter="velocity", code=5)
    assert isinstance(error, ValueError) and isinstance(error, TangoError)
    assert not isinstance(error, ControllerError)
    assert (error.instruction, error.parameter, error.code) == ("vel", "velocity", 5)
    assert InvalidCommandError("bad").code == 4
    with pytest.raises(ValueError):
        raise error


def test_hierarchy() -> None:
    for cls in (ProtocolError, ControllerError, errors.MoveError, errors.ConnectionLostError,
                errors.RequestAbortedError, errors.ControllerTimeoutError):
        assert issubclass(cls, TangoError)
    assert issubclass(errors.ControllerTimeoutError, TimeoutError)
    move = errors.MoveError("stopped", {"x": "S", "y": "@"})
    assert move.statuses == {"x": "S", "y": "@"}
