"""The TANGO instruction catalog: every instruction of the manual as data."""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping
from decimal import Decimal
from fractions import Fraction
from typing import Final

from ..errors import InvalidCommandError
from ..units import DIM_MM_VEL
from ._schema import (
    AXES,
    DEFAULT_CONTEXT,
    AxisRule,
    Bare,
    Command,
    Completion,
    Context,
    Form,
    Instruction,
    Kind,
    LineFn,
    LineRule,
    ModeEffect,
    Param,
    Precision,
    Shape,
    Signature,
)
from ._table import CATALOG

__all__ = [
    "AXES",
    "INSTRUCTIONS",
    "MAX_SNAPSHOTS",
    "MAX_TRIGGERS",
    "AxisRule",
    "Bare",
    "Command",
    "Completion",
    "Context",
    "Form",
    "Instruction",
    "Kind",
    "LineFn",
    "LineRule",
    "ModeEffect",
    "Param",
    "Precision",
    "Shape",
    "Signature",
    "encode",
    "format_number",
    "lookup",
    "parse",
    "upper_bound",
]

#: Longest command line the controller accepts, CR included (manual L129-131).
MAX_LINE_BYTES: Final = 255


# --------------------------------------------------------------------------------------
# Number formatting and token parsing

_NUMBER_RE: Final = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)$")
_INT_RE: Final = re.compile(r"^[+-]?\d+$")


def format_number(value: float | int | Decimal | Fraction) -> str:
    """Format a number for the wire: decimal point, never exponent notation."""
    number = wire_number(value)
    if isinstance(number, int):
        return str(number)
    if isinstance(number, Decimal):
        if not number.is_finite():
            raise ValueError(f"not a finite number: {value!r}")
        return format(number, "f")
    if not math.isfinite(number):
        raise ValueError(f"not a finite number: {value!r}")
    text = repr(number)
    if "e" not in text:
        # Already plain decimal notation with a point ("0.0123", "-10.0"): what the
        # Decimal round trip below would give, at a fraction of the cost.
        return text
    text = format(Decimal(text), "f")
    return text if "." in text else text + ".0"


def wire_number(value: object) -> int | float | Decimal:
    """``value`` as the Python number whose text goes on the wire, or ``TypeError``.

    Labs pass numbers of many types (bluesky always passes numpy): integers of any kind
    (``int``, ``numpy.int64``: anything registered as :class:`numbers.Integral`) become
    ``int``; :class:`Decimal` stays exact; other reals (``float``, ``numpy.float64``,
    ``numpy.float32``, :class:`Fraction`) become ``float``. A ``numpy.float32`` is taken
    at its own shortest text (``float32(0.1)`` is written ``0.1``, not
    ``0.10000000149011612``). Booleans, strings, sequences and complex numbers are not
    numbers here: ``True`` where a velocity goes is a bug, not ``1``.

    Parameters
    ----------
    value
        What the caller passed.

    Returns
    -------
    int, float or Decimal
        The number.

    Raises
    ------
    TypeError
        ``value`` is not a number.
    """
    if isinstance(value, bool) or type(value).__name__ == "bool_":  # numpy.bool_ too
        raise TypeError(f"a boolean is not a number on the wire: {value!r}")
    if type(value) is float or type(value) is int:
        return value  # the common case, checked first
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, Decimal):
        return value
    if isinstance(value, numbers.Real):
        if isinstance(value, float | Fraction):
            return float(value)
        # Other reals (numpy.float32/float16...): their str() is the shortest text that
        # round trips in their own precision.
        return float(str(value))
    raise TypeError(f"not a number: {value!r} ({type(value).__name__})")


def _fail(
    message: str, instruction: str | None, parameter: str | None = None, code: int = 4
) -> InvalidCommandError:
    return InvalidCommandError(message, instruction=instruction, parameter=parameter, number=code)


def _check_range(param: Param, value: float, name: str, hi: float | None) -> None:
    if param.lo is not None and value < param.lo:
        raise _fail(f"{name}: {param.name}={value} is below {param.lo}", name, param.name, 5)
    if hi is not None and value > hi:
        raise _fail(f"{name}: {param.name}={value} is above {hi}", name, param.name, 5)
    if param.min_abs is not None and abs(value) < param.min_abs:
        raise _fail(f"{name}: {param.name}={value} is closer to 0 than ±{param.min_abs}",
                    name, param.name, 5)


#: A number in exponent notation (``1e3``), which the wire format refuses.
_EXPONENT_RE: Final = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)[eE][+-]?\d+")


def _parse_value(param: Param, token: str, name: str, dim: int) -> float | int | str:
    """Validate one token against ``param`` and return its typed value."""
    if param.kind is Kind.BITS:
        if not re.fullmatch(r"[01]+", token) or (param.width and len(token) > param.width):
            raise _fail(f"{name}: {param.name} must be up to {param.width} 0/1 characters, "
                        f"got {token!r}", name, param.name, 5)
        return token
    if param.kind is Kind.CHOICE and any(isinstance(c, str) for c in param.choices):
        if token.lower() not in param.choices:
            raise _fail(f"{name}: {param.name} must be one of {param.choices}, got {token!r}",
                        name, param.name, 5)
        return token.lower()
    if not _NUMBER_RE.match(token):
        if _EXPONENT_RE.fullmatch(token):
            raise _fail(f"{name}: {param.name} {token!r} is in exponent notation, which is "
                        f"refused: write the number out (e.g. 1000, 0.001)", name,
                        param.name, 5)
        raise _fail(f"{name}: {param.name} must be a number, got {token!r}", name, param.name, 5)
    if param.kind is Kind.FLOAT:
        value = float(token)
        _check_range(param, value, name, upper_bound(param, dim))
        return value
    if not _INT_RE.match(token):
        raise _fail(f"{name}: {param.name} must be an integer, got {token!r}", name, param.name, 5)
    number = int(token)
    if param.kind is Kind.CHOICE and number not in param.choices:
        raise _fail(f"{name}: {param.name} must be one of {param.choices}, got {number}",
                    name, param.name, 5)
    _check_range(param, number, name, param.hi)
    return number


# --------------------------------------------------------------------------------------
# Catalog access


#: Every instruction of the manual, by canonical name.
INSTRUCTIONS: Final[Mapping[str, Instruction]] = {entry.name: entry for entry in CATALOG}

_BY_ALIAS: Final[dict[str, Instruction]] = {
    alias: entry for entry in INSTRUCTIONS.values() for alias in (entry.name, *entry.aliases)
}


def list_capacity(name: str) -> int:
    """How many entries the controller list indexed by instruction ``name`` holds: the
    upper bound of the index (first lead parameter) of its write form."""
    index = INSTRUCTIONS[name].write[0].lead[0]
    assert index.name == "index" and index.hi is not None, index
    return int(index.hi)


#: Entries of the trigger position list: '!trigp index' goes up to 10000 (L13767-13802).
MAX_TRIGGERS: Final = list_capacity("trigp")
#: Rows of the snapshot position array: '!snsa index' goes up to 1024 (L15324-15389).
MAX_SNAPSHOTS: Final = list_capacity("snsa")


def lookup(name: str) -> Instruction:
    """Return the instruction called ``name`` or one of its aliases (case-insensitive).

    Raises :class:`InvalidCommandError` for an unknown name, with the closest names
    (``unknown instruction 'mao' (did you mean moa?)``).

    Parameters
    ----------
    name
        An instruction name or alias, in any case.

    Returns
    -------
    Instruction
        The instruction.

    Raises
    ------
    InvalidCommandError
        The name is not known.
    """
    entry = _BY_ALIAS.get(name.lower())
    if entry is None:
        close = similar_names(name)
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        raise _fail(f"unknown instruction {name!r}{hint}", name, None, 4)
    return entry


def similar_names(name: str) -> list[str]:
    """Up to three instruction names (or aliases) spelt like ``name``: at most one typing
    mistake away (two for long names; a swap of neighbours counts as one), closest
    first, then those with the same letters (``mao`` → ``moa``), then alphabetically.

    Parameters
    ----------
    name
        A name that is not known.

    Returns
    -------
    list[str]
        At most three known names.
    """
    typed = name.lower()
    most = 1 if len(typed) <= 4 else 2
    scored = [(distance, sorted(alias) != sorted(typed), alias) for alias in _BY_ALIAS
              if (distance := _typing_distance(typed, alias)) <= most]
    return [alias for *_, alias in sorted(scored)[:3]]


def _typing_distance(a: str, b: str) -> int:
    """Edits (insert, delete, replace, swap two neighbours) that turn ``a`` into ``b``."""
    if abs(len(a) - len(b)) > 2:
        return 3
    rows = [list(range(len(b) + 1))]
    for i in range(1, len(a) + 1):
        row = [i] + [0] * len(b)
        for j in range(1, len(b) + 1):
            row[j] = min(rows[-1][j] + 1, row[j - 1] + 1,
                         rows[-1][j - 1] + (a[i - 1] != b[j - 1]))
            if i > 1 and j > 1 and a[i - 1] == b[j - 2] and a[i - 2] == b[j - 1]:
                row[j] = min(row[j], rows[-2][j - 2] + 1)
        rows.append(row)
    return rows[-1][-1]


# --------------------------------------------------------------------------------------
# Parsing and encoding command lines

_LINE_RE: Final = re.compile(r"^([!?]?)([A-Za-z]+)(?:\s+(.*))?$")


def _check_line_text(line: str) -> None:
    for char in ("\r", "\n", "\x03"):
        if char in line:
            raise _fail(f"control character {char!r} inside the command line", None, None, 4)
    if not line.isascii():
        raise _fail("the command line contains non-ASCII characters", None, None, 4)
    if not line.isprintable():
        raise _fail("the command line contains control characters", None, None, 4)


def _split_form(line: str) -> tuple[Form, Instruction, list[str]]:
    match = _LINE_RE.match(line.strip())
    if match is None:
        raise _fail(f"not a command line: {line!r}", None, None, 4)
    prefix, name, rest = match.groups()
    entry = lookup(name)
    form = Form(prefix)
    _check_form(entry, form)
    return form, entry, (rest or "").split()


_FORM_WORDS = {Form.SET: "with '!' (set or run)", Form.READ: "with '?' (read)",
               Form.BARE: "without a prefix"}


def _check_form(entry: Instruction, form: Form) -> None:
    if not entry.allows(form):
        code = 7 if form is Form.BARE else 4
        allowed = " or ".join(repr(f.value + entry.name) for f in sorted(entry.forms, key=str))
        raise _fail(f"{entry.name}: cannot be written {_FORM_WORDS[form]}; write {allowed}",
                    entry.name, None, code)


def _take_axis(entry: Instruction, sig: Signature, tokens: list[str]) -> str | None:
    if not tokens or not tokens[0].isalpha():
        if sig.axis is AxisRule.REQUIRED:
            raise _fail(f"{entry.name}: an axis letter is required", entry.name, "axis", 1)
        return None
    letter = tokens[0].lower()
    if sig.axis is AxisRule.NONE:
        # A word where the grammar has none is a parameter (zwaxis z, anain c 3).
        return None
    if letter not in AXES:
        raise _fail(f"{entry.name}: {tokens[0]!r} is not an axis (x, y, z, a)",
                    entry.name, "axis", 1)
    del tokens[0]
    return letter


def _values(
    entry: Instruction, sig: Signature, axis: str | None, tokens: list[str], ctx: Context
) -> tuple[float | int | str, ...]:
    rest = list(tokens)
    values: list[float | int | str] = []
    dim = ctx.dims[AXES.index(axis) if axis else 0]
    for param in sig.lead:
        if not rest:
            if not param.optional:
                raise _fail(f"{entry.name}: missing {param.name}", entry.name, param.name, 6)
            break
        values.append(_parse_value(param, rest.pop(0), entry.name, dim))
    if sig.per_axis:
        values.extend(_axis_values(entry, sig, axis, rest, ctx))
    elif sig.precision is not None and rest:
        digits = Param("digits", Kind.INT, sig.precision.lo, sig.precision.hi)
        values.append(_parse_value(digits, rest.pop(0), entry.name, 2))
    if rest:
        raise _fail(f"{entry.name}: too many values ({' '.join(tokens)})", entry.name, None, 6)
    return tuple(values)


def _axis_values(
    entry: Instruction, sig: Signature, axis: str | None, rest: list[str], ctx: Context
) -> list[float | int | str]:
    """Consume every token of ``rest`` as per-axis groups and return their typed values."""
    group = sig.per_axis
    groups = 1 if axis is not None or sig.axis is AxisRule.ALL else len(AXES)
    if len(rest) > groups * len(group):
        raise _fail(f"{entry.name}: too many values, at most {groups * len(group)}",
                    entry.name, None, 6)
    if groups == len(AXES) and len(rest) > ctx.axes * len(group):
        # A value for an axis the controller does not have: the emulator answers error 1
        # (no valid axis name), as a line naming that axis would get.
        present = " ".join(AXES[: ctx.axes]).upper()
        raise _fail(f"{entry.name}: {-(-len(rest) // len(group))} axis values, but the "
                    f"controller has {ctx.axes} (axes {present})", entry.name, None, 1)
    taken = rest[:]
    rest.clear()
    required = sum(1 for p in group if not p.optional)
    if len(taken) < sig.min_groups * required:
        name = group[len(taken) % len(group)].name
        raise _fail(f"{entry.name}: missing {name}", entry.name, name, 6)
    if sig.axis is AxisRule.ALL and axis is None and taken and len(taken) < required:
        raise _fail(f"{entry.name}: without an axis letter give {required} value(s) for all "
                    "axes", entry.name, None, 6)
    tail = len(taken) % len(group)
    if tail and not group[tail].optional:
        raise _fail(f"{entry.name}: missing {group[tail].name}", entry.name, group[tail].name, 6)
    out: list[float | int | str] = []
    for index, token in enumerate(taken):
        axis_index = AXES.index(axis) if axis else index // len(group)
        out.append(_parse_value(group[index % len(group)], token, entry.name,
                                ctx.dims[axis_index]))
    return out


def parse(line: str, context: Context | None = None) -> Command:
    """Validate a command line (without CR) and return the parsed :class:`Command`.

    This is the parser of both :func:`encode` and the emulator. It raises
    :class:`InvalidCommandError` whose ``code`` is the error number a controller would set.

    Parameters
    ----------
    line
        The command line, without CR.
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    Command
        The parsed command.

    Raises
    ------
    InvalidCommandError
        The line is not valid.
    """
    ctx = context or DEFAULT_CONTEXT
    _check_line_text(line)
    form, entry, tokens = _split_form(line)
    return _parse_tokens(entry, form, tokens, ctx)


def _parse_tokens(entry: Instruction, form: Form, tokens: list[str], ctx: Context) -> Command:
    """The part of :func:`parse` after the line was split into form, name and tokens."""
    errors: list[InvalidCommandError] = []
    for sig in entry.signatures(form) or (Signature(),):
        rest = list(tokens)
        try:
            axis = _take_axis(entry, sig, rest)
            values = _values(entry, sig, axis, rest, ctx)
        except InvalidCommandError as exc:
            errors.append(exc)
            continue
        canonical = tuple(_canonical(token, value) for token, value in zip(rest, values,
                                                                             strict=True))
        return _checked_length(Command(entry, form, axis, values, canonical))
    # Prefer an error about a value over one about the number of values: it is more
    # specific when one alternative matched the count.
    raise min(errors, key=lambda exc: exc.number == 6)


def _checked_length(command: Command) -> Command:
    if len(command.to_bytes()) > MAX_LINE_BYTES:
        raise _fail(f"{command.name}: line is longer than {MAX_LINE_BYTES} bytes with its CR",
                    command.name, None, 3)
    return command


def _canonical(token: str, value: float | int | str) -> str:
    """The token as it goes on the wire: words in lower case, integers (counts, modes,
    enumerated choices) in their plain form (``-0`` → ``0``, ``+1`` → ``1``, ``007`` →
    ``7``). Floats keep their text: its digits are the precision the caller chose."""
    if isinstance(value, int):
        return str(value)
    return token.lower() if token.isalpha() else token


def encode(line: str, context: Context | None = None) -> bytes:
    """Validate a raw command line such as ``"!vel y 12.5"`` (without CR) and return its
    canonical bytes, CR included. Raises :class:`InvalidCommandError` (a
    :class:`ValueError`) for bad input, including any CR, LF or Ctrl+C inside ``line``.

    Parameters
    ----------
    line
        The command line, without CR.
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    bytes
        The canonical line, CR included.

    Raises
    ------
    InvalidCommandError
        The line is not valid.
    """
    # The length limit applies to the canonical bytes that are sent (parse checks it):
    # redundant spaces in ``line`` are collapsed and do not count.
    return parse(line, context).to_bytes()


def upper_bound(param: Param, dim: int) -> float | None:
    """The upper bound of ``param`` for an axis in ``dim``.

    Parameters
    ----------
    param
        A parameter of the catalog.
    dim
        The axis's ``dim``.

    Returns
    -------
    float | None
        Its ``hi_dim9`` in dim 9 (velocities in mm/s, L3452), if it has one, else its
        ``hi`` (``None``: no upper bound).
    """
    return param.hi_dim9 if dim == DIM_MM_VEL and param.hi_dim9 else param.hi
