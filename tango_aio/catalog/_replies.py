"""Replies to the catalog's instructions: how many lines a read owes (:func:`reply_rule`)
and their values (:func:`parse_reply`), per the reply shape the catalog names."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final

from ..errors import ProtocolError, parse_error_reply
from ._schema import AXES, DEFAULT_CONTEXT, Command, Context, LineRule, Shape

__all__ = [
    "DET_FLAGS",
    "DetInfo",
    "VersionInfo",
    "parse_reply",
    "reply_group",
    "reply_rule",
]


def reply_rule(command: Command, context: Context | None = None) -> LineRule:
    """How many lines the read ``command`` replies with (``count=0``: no data reply).

    Parameters
    ----------
    command
        The command written.
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    LineRule
        The rule of its reply.
    """
    entry = command.instruction
    if not command.is_read:
        return LineRule(count=1 if entry.exec_reply is not Shape.NONE else 0)
    if entry.reply is Shape.NONE:
        return LineRule(count=0)
    if entry.lines is not None:
        return entry.lines(command, context or DEFAULT_CONTEXT)
    return LineRule()


@dataclass(frozen=True, slots=True)
class VersionInfo:
    """The parsed ``?version`` reply."""

    model: str
    firmware: str
    build_date: str = ""
    build_time: str = ""

    @property
    def firmware_tuple(self) -> tuple[int, ...]:
        """The firmware version as numbers (``"1.71"`` → ``(1, 71)``)."""
        return tuple(int(part) for part in re.findall(r"\d+", self.firmware))


#: The ``?det`` option bits (manual L1119-1185).
DET_FLAGS: Final[dict[str, int]] = {
    "encoder_1vpp": 0x1,
    "encoder_mr": 0x2,
    "encoder_ttl": 0x4,
    "encoder_universal": 0x8,
    "display": 0x100,
    "speedpoti": 0x200,
    "handwheel": 0x400,
    "snapshot": 0x800,
    "tvr_in": 0x1000,
    "trigger_out": 0x2000,
    "tvr_out": 0x8000,
    "io_extension": 0x10000,
    "multi_io": 0x20000,
    "trackball": 0x40000,
    "ets": 0x80000,
    "xpos": 0x100000,
}


@dataclass(frozen=True, slots=True)
class DetInfo:
    """The decoded ``?det`` configuration bit field."""

    value: int

    @property
    def axes(self) -> int:
        """Number of configured axes (bits 4-7)."""
        return (self.value >> 4) & 0xF

    @property
    def options(self) -> frozenset[str]:
        """Names of the configured options (see :data:`DET_FLAGS`)."""
        return frozenset(name for name, bit in DET_FLAGS.items() if self.value & bit)

    def has(self, option: str) -> bool:
        """Whether ``option`` (a :data:`DET_FLAGS` name) is configured.

        Parameters
        ----------
        option
            A :data:`DET_FLAGS` name.

        Returns
        -------
        bool
            Whether it is configured.
        """
        return bool(self.value & DET_FLAGS[option])


def _number(token: str) -> float:
    try:
        return float(token)
    except ValueError:
        raise ProtocolError(f"expected a number, got {token!r}") from None


def _integer(token: str) -> int:
    try:
        return int(token)
    except ValueError:
        raise ProtocolError(f"expected an integer, got {token!r}") from None


def _per_axis(
    command: Command, items: list[str | float | int], group: int
) -> object:
    """Map reply values to axes: a scalar (or tuple) with an axis letter, else a dict."""
    if len(items) % group:
        raise ProtocolError(f"{command.name}: {len(items)} values do not form groups of "
                            f"{group}: {items}")
    grouped: list[object] = (
        [tuple(items[i : i + group]) for i in range(0, len(items), group)]
        if group > 1
        else list(items)
    )
    if command.axis is not None:
        if len(grouped) != 1:
            raise ProtocolError(f"{command.name}: expected one axis value, got {items}")
        return grouped[0]
    if len(grouped) > len(AXES):
        raise ProtocolError(f"{command.name}: more than {len(AXES)} axis values: {items}")
    return dict(zip(AXES, grouped, strict=False))


def _parse_version(text: str) -> VersionInfo:
    parts = [p.strip() for p in text.split(",")]
    match = re.search(r"Version\s+([^\s,]+)", text)
    if match is None:
        if re.fullmatch(r"\d+\.\d+\w*", text.strip()):
            return VersionInfo(model="", firmware=text.strip())
        raise ProtocolError(f"not a version reply: {text!r}")
    date = parts[2] if len(parts) > 2 else ""
    time = parts[3] if len(parts) > 3 else ""
    return VersionInfo(model=parts[0], firmware=match.group(1), build_date=date, build_time=time)


def _parse_status(command: Command, text: str) -> object:
    body = text.strip()
    if command.axis is not None:
        if len(body) != 1:
            raise ProtocolError(f"statusaxis: expected one letter, got {text!r}")
        return body
    letters = body.split(".")[0]
    return {axis: letter for axis, letter in zip(AXES, letters, strict=False) if letter != "-"}


def _split_numbers(text: str) -> list[str]:
    # ?lim in extmode 0 adds stray commas after values (manual L4559-4619); a comma
    # inside a token ("0,0000") stays, so the token is no number.
    return [token.removesuffix(",") for token in text.split()]


def parse_reply(command: Command, lines: Sequence[str]) -> object:
    """Parse the reply lines of the read ``command`` into Python values.

    Per-axis replies give ``{"x": 1.0, "y": 2.0}`` (only the axes present) or a scalar when
    the command named an axis; groups (``?lim``) give tuples. ``?statusaxis`` gives letters,
    ``?version`` a :class:`VersionInfo`, ``?det`` a :class:`DetInfo`, ``?err`` an int,
    ``help`` an ``(int, text)`` pair, acknowledgements ``(code, None)``.

    Parameters
    ----------
    command
        The command written.
    lines
        Its reply lines, CR removed.

    Returns
    -------
    object
        The values, as above.

    Raises
    ------
    ProtocolError
        A reply came to a command that owes none.
    """
    entry = command.instruction
    shape = entry.reply if command.is_read else entry.exec_reply
    if shape is Shape.LINES:
        return list(lines)
    text = " ".join(line.strip() for line in lines)
    parser = _SCALAR_PARSERS.get(shape)
    if parser is not None:
        return parser(text)
    if shape is Shape.STATUS:
        return _parse_status(command, text)
    if shape in (Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT):
        convert = _AXIS_CONVERTERS[shape]
        tokens = _split_numbers(text)
        if entry.digit_values:
            tokens = [digit for token in tokens for digit in _digits(token)]
        return _per_axis(command, [convert(t) for t in tokens], reply_group(command))
    if shape is Shape.NUMBERS:
        return [_number(t) for t in _split_numbers(text)]
    if shape is Shape.INTS:
        return [_integer(t) for t in _split_numbers(text)]
    raise ProtocolError(f"{entry.name}: no reply expected, got {list(lines)}")


def reply_group(command: Command) -> int:
    """Values per axis in the reply to the read ``command`` (``?lim``: 2).

    Parameters
    ----------
    command
        The read.

    Returns
    -------
    int
        Values per axis.
    """
    entry = command.instruction
    for value, group in entry.option_groups:
        if command.values and command.values[0] == value:
            return group
    return entry.reply_group


def _digits(token: str) -> list[str]:
    # '1 1 11 1 11 1 1' is three groups '1 1 1' printed without the separating space.
    return list(token) if token.isdigit() else [token]


def _parse_help(text: str) -> tuple[int | None, str | None]:
    return parse_error_reply(text)


def _parse_ack(text: str) -> tuple[int | None, str | None]:
    return parse_error_reply(text)


_SCALAR_PARSERS: Final[dict[Shape, Callable[[str], object]]] = {
    Shape.INT: lambda text: _integer(text.strip()),
    Shape.FLOAT: lambda text: _number(text.strip()),
    Shape.TEXT: lambda text: text.strip(),
    Shape.FLAGS: lambda text: text.strip(),
    Shape.ERROR_NUMBER: lambda text: _integer(text.strip()),
    Shape.HELP: _parse_help,
    Shape.ACK: _parse_ack,
    Shape.VERSION: _parse_version,
    Shape.DET: lambda text: DetInfo(_integer(text.strip())),
}

_AXIS_CONVERTERS: Final[dict[Shape, Callable[[str], str | float | int]]] = {
    Shape.AXES_FLOAT: _number,
    Shape.AXES_INT: _integer,
    Shape.AXES_TEXT: str,
}
