"""The few moves every generated accessor is made of: read through the port and convert,
write one value group per axis, and name the manual's values.
"""

from __future__ import annotations

import contextlib
import enum
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, TypeVar

from ..catalog import AXES, INSTRUCTIONS, Form, Value, build
from ..errors import (
    InvalidCommandError,
    InvalidInstructionError,
    NotSupportedByFirmwareError,
    ProtocolError,
)
from ._base import FamilyPort

__all__ = ["ManualEnum", "read", "read_axes", "supported", "to_bool", "write", "write_axes"]

T = TypeVar("T")


class ManualEnum(enum.IntEnum):
    """The values the manual lists for a setting; a value it does not list (a newer
    firmware's) reads as a pseudo-member ``UNDOCUMENTED_<n>`` instead of failing."""

    @classmethod
    def _missing_(cls, value: object) -> ManualEnum | None:
        if not isinstance(value, int) or isinstance(value, bool):
            return None
        member = int.__new__(cls, value)
        member._name_ = f"UNDOCUMENTED_{value}".replace("-", "MINUS_")
        member._value_ = value
        return member


def to_bool(value: object) -> bool:
    """A ``0``/``1`` reply as a bool; anything else is a protocol error."""
    if value in (0, 1) and not isinstance(value, float | str):
        return bool(value)
    raise ProtocolError(f"expected 0 or 1, got {value!r:.40}")


def _convert(convert: Callable[[Any], T], value: Any) -> T:
    if isinstance(value, tuple):
        return tuple(convert(item) for item in value)  # type: ignore[return-value]
    return convert(value)


def _older(port: FamilyPort) -> bool:
    try:
        return port.identity.family == "older"
    except RuntimeError:  # not identified: the firmware answers for itself
        return False


@contextlib.contextmanager
def supported(port: FamilyPort, name: str) -> Iterator[None]:
    """Refuse ``name`` where the firmware lacks it, or answers error 4 (L970) to it."""
    # The older edition does not document it; or error 4 to a line the catalog found
    # valid: this firmware does not know the instruction.
    entry = INSTRUCTIONS[name]
    if not entry.in_older_manual and _older(port):
        raise NotSupportedByFirmwareError(entry.name)
    try:
        yield
    except NotSupportedByFirmwareError:
        raise
    except InvalidInstructionError as error:
        raise NotSupportedByFirmwareError(entry.name, error.command) from error


async def read(port: FamilyPort, name: str, convert: Callable[[Any], T],
               *args: Value | None, axis: str | None = None) -> T:
    """Read ``name`` (trailing ``None`` arguments left out) and convert its reply."""
    present = _present(args)
    with supported(port, name):
        value = await port.get(name, *present, axis=axis)
    return _convert(convert, value)


async def read_axes(port: FamilyPort, name: str, convert: Callable[[Any], T],
                    *args: Value | None, axis: str | None = None) -> Any:
    """Read a per-axis ``name``: one converted value for ``axis``, else a dict by axis."""
    present = _present(args)
    with supported(port, name):
        value = await port.get(name, *present, axis=axis)
    if axis is not None:
        return _convert(convert, value)
    if not isinstance(value, Mapping):
        raise ProtocolError(f"{name}: expected a value per axis, got {value!r:.60}")
    return {letter: _convert(convert, item) for letter, item in value.items()}


def _wire(value: Value) -> Value:
    """A typed value as the catalog takes it: a bool or an enum member as a plain int."""
    return int(value) if isinstance(value, int) and type(value) is not int else value


def _present(args: Sequence[Value | None]) -> tuple[Value, ...]:
    """``args`` without their trailing ``None`` (optional arguments not given)."""
    values = list(args)
    while values and values[-1] is None:
        values.pop()
    if any(value is None for value in values):
        raise InvalidCommandError("an optional argument is missing before a given one",
                                  number=5)
    return tuple(_wire(value) for value in values if value is not None)


def _group(value: object) -> Value | tuple[Value, ...]:
    if isinstance(value, Sequence) and not isinstance(value, str):
        return tuple(_present(list(value)))
    return _wire(value)  # type: ignore[arg-type]


async def write(port: FamilyPort, name: str, *args: Value | None,
                axis: str | None = None) -> None:
    """Write ``name`` with its lead values (trailing ``None`` left out), proven."""
    present = _present(args)
    with supported(port, name):
        await port.set(name, *present, axis=axis)


async def write_axes(port: FamilyPort, name: str, lead: Sequence[Value | None],
                     values: Mapping[str, object]) -> None:
    """Write one value group per given axis (``None``: not given), all checked first."""
    # Axes that run from X, or a single axis, go in one line; any other set (the wire
    # cannot skip an axis) goes axis by axis.
    given: dict[str, Any] = {axis: _group(value) for axis, value in values.items()
                             if value is not None}
    if not given:
        raise InvalidCommandError(f"{name}: no axis value given", instruction=name, number=5)
    head = _present(lead)
    letters = list(given)
    if len(letters) > 1 and letters != list(AXES[: len(letters)]):
        for letter in letters:  # every line proven valid before anything is written
            build(name, *head, *_flat(given[letter]), form=Form.SET, axis=letter,
                  context=port.context)
    with supported(port, name):
        if len(letters) == 1:
            await port.set(name, *head, *_flat(given[letters[0]]), axis=letters[0])
        elif letters == list(AXES[: len(letters)]):
            await port.set(name, *head, **given)
        else:
            for letter in letters:
                await port.set(name, *head, *_flat(given[letter]), axis=letter)


def _flat(value: Value | tuple[Value, ...]) -> tuple[Value, ...]:
    return value if isinstance(value, tuple) else (value,)
