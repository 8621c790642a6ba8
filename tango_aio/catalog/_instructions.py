"""The TANGO instruction catalog: every instruction of the manual as data.

One table (:data:`INSTRUCTIONS`, the data of the generated :mod:`tango_aio.catalog._table`, made
of the types of :mod:`tango_aio.catalog._schema`, which this module re-exports) drives the whole
package: validation and encoding of command lines (:func:`encode`, :func:`build`), the
parsing of replies (:func:`parse_reply`), what the protocol core expects back
(:attr:`Instruction.completion`, :func:`reply_rule`), the typed API and the emulator's
command parser (:func:`parse`).

The grammar of a command line (manual chapter 2 and 4)::

    [!|?]name[ axis][ value ...]CR

``!`` executes/sets, ``?`` reads; some instructions also have a *bare* form without a
prefix, which either executes (``moa``, ``cal``) or reads (``version``, ``sa``). An axis is
one of ``x y z a``. Without an axis letter, per-axis values are given in X Y Z A order and a
single value goes to X (``moa 10.2`` == ``moa x 10.2``), except for the "all axes" group
(``swtyp``, ``calbspeed``, ...), where one value group without a letter applies to every axis.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from decimal import Decimal
from fractions import Fraction
from typing import Final, TypeVar

from ..errors import InvalidCommandError, ProtocolError, parse_error_reply
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
    "DetInfo",
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
    "Value",
    "VersionInfo",
    "build",
    "build_axes",
    "build_rows",
    "check_framing",
    "check_rows",
    "check_rows_framing",
    "encode",
    "encode_rows",
    "format_number",
    "lookup",
    "parse",
    "parse_reply",
    "reply_group",
    "reply_rule",
    "upper_bound",
]

#: Longest command line the controller accepts, CR included (manual L129-131).
MAX_LINE_BYTES: Final = 255


# --------------------------------------------------------------------------------------
# Number formatting and token parsing

_NUMBER_RE: Final = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)$")
_INT_RE: Final = re.compile(r"^[+-]?\d+$")


def format_number(value: float | int | Decimal | Fraction) -> str:
    """Format a number for the wire: decimal point, never exponent notation.

    Integers are written without a fraction; floats use the shortest decimal that round
    trips (``1e-06`` → ``0.000001``, ``10.0`` → ``10.0``). Any real number type is
    accepted as labs have them (:func:`wire_number`): numpy scalars, :class:`Decimal`
    (written exactly), :class:`Fraction`. ``TypeError`` for a non-number (``bool``
    included), ``ValueError`` for NaN and infinities.

    Parameters
    ----------
    value
        A real number of any type (:func:`wire_number`).

    Returns
    -------
    str
        Its text on the wire.

    Raises
    ------
    TypeError
        ``value`` is not a number (a bool is not one).
    ValueError
        ``value`` is NaN or infinite.
    """
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
    upper bound of the index (first lead parameter) of its write form.

    Parameters
    ----------
    name
        The instruction of the list (``"trigp"``, ``"snsa"``).

    Returns
    -------
    int
        The number of entries.
    """
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


def check_framing(command: Command) -> None:
    """Refuse a line that would frame more than one line, or Ctrl+C, on the wire.

    :func:`parse` already rejects these; this guards :class:`Command` objects built by
    hand (defence in depth: CR would end the line early and smuggle in a second command,
    0x03 would abort every axis).

    Parameters
    ----------
    command
        The line about to be written.

    Raises
    ------
    InvalidCommandError
        The line holds a control or non-ASCII character.
    """
    line = command.line
    # Printable ASCII: CR, LF and 0x03 are not printable, so one test covers all three.
    if not (line.isascii() and line.isprintable()):
        raise _fail(f"control or non-ASCII character inside the command line {line!r}",
                    command.name)


def check_rows_framing(template: Command, blob: bytes, count: int) -> None:
    """Refuse list entries given as bytes (:func:`encode_rows`) unless they are ``count``
    lines of printable ASCII, each ended by CR (the same defence as
    :func:`check_framing`, on the whole blob).

    Parameters
    ----------
    template
        A line of the entries' instruction and form.
    blob
        The entries' bytes.
    count
        How many lines they are.

    Raises
    ------
    InvalidCommandError
        A line holds a control or non-ASCII character, or the blob is not ``count``
        CR-ended lines.
    """
    text = blob.decode("latin-1")
    lines = text.replace("\r", "")
    if text.count("\r") != count or not text.endswith("\r") \
            or not (lines.isascii() and lines.isprintable()):
        raise _fail("control or non-ASCII character inside a list line", template.name)


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
    ``7``). Floats keep their text: its digits are the precision the caller chose.

    Returns
    -------
    str
        The token's wire text.
    """
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


#: A number as callers have them (numpy scalars are accepted too, see wire_number).
Number = float | int | Decimal | Fraction
Value = Number | str
AxisValues = Value | Sequence[Value]


def build(
    name: str,
    *args: Value,
    form: Form | str = Form.SET,
    axis: str | None = None,
    context: Context | None = None,
    **axes: AxisValues,
) -> Command:
    """Build a validated command from Python values.

    Numbers are written by :func:`format_number`: Python ints as integers, floats with a
    decimal point, never in exponent notation. ``build("vel", x=10, y=5.5)`` gives
    ``!vel 10 5.5``. The wire has no way to skip an axis, so per-axis keywords must be
    given without gaps from X, or as a single axis (``build("vel", y=5)`` → ``!vel y 5``).
    Positional ``args`` are the lead values (``build("trigp", -1, 2.5)``), ``form`` is
    ``"!"``, ``"?"`` or ``""``.

    Parameters
    ----------
    name
        The instruction's name or alias.
    *args
        The lead values.
    form
        ``"!"``, ``"?"`` or ``""`` (or a :class:`Form`).
    axis
        A single axis letter to address, for a form that takes one.
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.
    **axes
        The values of each axis, by axis letter (a sequence where an axis takes several).

    Returns
    -------
    Command
        The validated command.

    Raises
    ------
    InvalidCommandError
        A value, an axis or the combination is not valid.
    """
    return _build(name, args, form, axis, context, axes)


def _build(
    name: str,
    args: Sequence[Value],
    form: Form | str,
    axis: str | None,
    context: Context | None,
    axes: Mapping[str, AxisValues],
) -> Command:
    entry = lookup(name)
    the_form = form if isinstance(form, Form) else Form(form)
    if axis is not None:
        check_axis_word(axis, entry.name)
    parts: list[str] = [the_form.value + entry.name]
    if axes:
        _check_lead_count(entry, the_form, args)
        letter, per_axis = _axis_part(entry, the_form, axis, axes)
    else:  # what _axis_part gives without per-axis keywords
        letter, per_axis = (axis.lower() if axis else None), []
    if letter:
        parts.append(letter)
    given = [*args, *per_axis]
    textual = False
    for value in given:
        textual = textual or isinstance(value, str)
        parts.append(_format_value(value, entry.name))
    if (not letter or letter in AXES) and _BY_ALIAS.get(entry.name) is entry and not textual:
        # Fast path, same result as parsing the joined line: the parts are the canonical
        # name, an axis letter and formatted numbers, so the text checks and the split
        # that parse() does cannot fail and would give back these very tokens.
        _check_form(entry, the_form)
        return _parse_tokens(entry, the_form, parts[1:], context or DEFAULT_CONTEXT)
    command = parse(" ".join(parts), context)
    _check_words(command, given)
    return command


def check_axis_word(axis: object, name: str) -> None:
    """Refuse an ``axis=`` argument that is not one axis letter (``x``, ``y``, ``z``,
    ``a``, either case): ``""`` would address every axis, ``"y 5"`` smuggle in a value,
    ``1`` is no letter at all.

    Parameters
    ----------
    axis
        The ``axis=`` argument.
    name
        The instruction's name, for the error.

    Raises
    ------
    InvalidCommandError
        ``axis`` is not one axis letter.
    """
    if not isinstance(axis, str) or axis.lower() not in AXES:
        raise _fail(f"{name}: axis must be one of x, y, z, a, got {axis!r}", name, "axis", 1)


def _check_lead_count(entry: Instruction, form: Form, args: Sequence[Value]) -> None:
    """Positional values are the lead (global) parameters only: with per-axis keywords,
    ``set("vel", 5, x=3)`` would otherwise send ``!vel 5 3`` and set Y to 3.

    Raises
    ------
    InvalidCommandError
        Positional values are mixed with per-axis keywords.
    """
    most = max((len(sig.lead) for sig in entry.signatures(form)), default=0)
    if len(args) > most:
        raise _fail(f"{entry.name}: positional values {list(args)} cannot be mixed with "
                    "per-axis keywords (give every axis as a keyword)", entry.name, None, 6)


def _check_words(command: Command, given: Sequence[Value]) -> None:
    """A string value must be one whole token of a word or bit-pattern parameter: where
    a number goes, ``"5"`` is a caller's bug and ``"1 2"`` would smuggle in a second
    value (``move_to(x="1 2")`` sending ``!moa 1 2`` moves Y).

    Raises
    ------
    InvalidCommandError
        A string stands where a number goes.
    """
    for value, parsed in zip(given, command.values, strict=False):
        if isinstance(value, str) and not isinstance(parsed, str):
            raise _fail(f"{command.name}: {value!r} is a string where a number goes",
                        command.name, None, 5)


def build_rows(
    name: str,
    lead: Sequence[Value],
    rows: Iterable[Sequence[float | int]],
    *,
    form: Form | str = Form.SET,
    context: Context | None = None,
) -> Iterator[Command]:
    """``build(name, *lead, *row)`` for each row, about twice as fast: list entries such
    as ``!trigp -1 pos`` differ only in their trailing numbers.

    The first row of each length is built in full; the grammar alternative it matched then
    checks the numbers of later rows of that length directly (kind and range, no text
    round trip). A row that does not pass is built in full, so the result and every error
    are exactly those of :func:`build`.

    Parameters
    ----------
    name
        The instruction's name (``"trigp"``, ``"snsa"``...).
    lead
        The lead values, the same for every row.
    rows
        The trailing values of each row.
    form
        ``"!"``, ``"?"`` or ``""`` (or a :class:`Form`).
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    Iterator[Command]
        The command of each row, built as it is asked for.

    Raises
    ------
    InvalidCommandError
        A row is not valid (raised when it is built).
    """
    return _rows(name, lead, rows, form, context, _RowPlan.build, _same_command)


def encode_rows(
    name: str,
    lead: Sequence[Value],
    rows: Iterable[Sequence[float | int]],
    *,
    form: Form | str = Form.SET,
    context: Context | None = None,
) -> Iterator[bytes]:
    """``build(name, *lead, *row).to_bytes()`` for each row, as :func:`build_rows` checks
    them, but without a :class:`Command` per row that passes its plan's checks: a list
    upload keeps its lines as bytes (building was a third of a 64-link upload's
    CPU). Same bytes and errors as :func:`build` (``tests/unit/test_build_rows.py``).

    Parameters
    ----------
    name
        The instruction's name (``"trigp"``, ``"snsa"``...).
    lead
        The lead values, the same for every row.
    rows
        The trailing values of each row.
    form
        ``"!"``, ``"?"`` or ``""`` (or a :class:`Form`).
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    Iterator[bytes]
        The line of each row (CR included), made as it is asked for.

    Raises
    ------
    InvalidCommandError
        A row is not valid (raised when it is made).
    """
    return _rows(name, lead, rows, form, context, _RowPlan.encode, Command.to_bytes)


def check_rows(
    name: str,
    lead: Sequence[Value],
    rows: Iterable[Sequence[float | int]],
    *,
    form: Form | str = Form.SET,
    context: Context | None = None,
) -> Iterator[bool]:
    """``True`` for each row of ``rows``; raise what :func:`build_rows` raises for the
    first bad one, without making the lines. A list upload validates every entry before
    it clears the list, and then makes each chunk's lines (:func:`encode_rows`, which
    cannot fail on rows checked here) while the chunks before it are on the wire (so
    that 64 uploads do not start one list-build apart). A row of plain in-range floats written
    without an exponent is checked by its numbers alone (its line cannot be too long:
    :attr:`_RowPlan.short`); any other row is built in full.

    Parameters
    ----------
    name
        The instruction's name (``"trigp"``, ``"snsa"``...).
    lead
        The lead values, the same for every row.
    rows
        The trailing values of each row.
    form
        ``"!"``, ``"?"`` or ``""`` (or a :class:`Form`).
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    Iterator[bool]
        ``True`` per row checked.

    Raises
    ------
    InvalidCommandError
        A row is not valid (raised when it is checked).
    """
    return _rows(name, lead, rows, form, context, _RowPlan.passes, _accepted)


_Made = TypeVar("_Made")


def _accepted(command: Command) -> bool:
    return True


def _same_command(command: Command) -> Command:
    return command


def _rows(name: str, lead: Sequence[Value], rows: Iterable[Sequence[float | int]],
          form: Form | str, context: Context | None,
          fast: Callable[[_RowPlan, Sequence[float | int]], _Made | None],
          full: Callable[[Command], _Made]) -> Iterator[_Made]:
    """What :func:`build_rows`, :func:`encode_rows` and :func:`check_rows` share:
    ``fast`` makes a row from
    the plan of the first row of its length, ``full`` from a command built in full.

    Yields
    ------
    _Made
        What ``fast`` or ``full`` made of each row.
    """
    ctx = context or DEFAULT_CONTEXT
    plans: dict[int, _RowPlan | None] = {}
    for row in rows:
        size = len(row)
        if size not in plans:
            command = _build(name, (*lead, *row), form, None, context, {})
            plans[size] = _RowPlan.of(command, len(lead), ctx)
            yield full(command)
            continue
        plan = plans[size]
        made = fast(plan, row) if plan is not None else None
        yield made if made is not None else full(
            _build(name, (*lead, *row), form, None, context, {}))


#: Magnitudes whose ``repr()`` has no exponent (Python writes ``1e-05`` and ``1e+16``),
#: and the longest such text (17 digits, sign, point, ``0.000``).
_PLAIN_FLOATS: Final = (1e-4, 1e16)
_PLAIN_FLOAT_TEXT: Final = 24


@dataclass(frozen=True, slots=True)
class _RowPlan:
    """How :func:`build_rows` checks and builds rows like the one that made it."""

    template: Command
    params: tuple[tuple[Param, float | None], ...]  # per row value: its param and upper bound
    #: The line's text before the row's numbers (form, name and lead tokens).
    head: str
    #: Whether every row value is a FLOAT parameter (:meth:`encode`'s shortcut).
    floats: bool
    #: Whether a row of floats written without an exponent (at most 24 characters each)
    #: always makes a line short enough (:meth:`passes`).
    short: bool
    #: Per row value: its parameter's range as ``(lowest, highest, least magnitude)``,
    #: unbounded ends as infinities (:func:`_plain_row`).
    bounds: tuple[tuple[float, float, float], ...]

    @staticmethod
    def of(command: Command, lead: int, ctx: Context) -> _RowPlan | None:
        entry, form = command.instruction, command.form
        if command.axis is not None:
            return None
        for sig in entry.signatures(form) or (Signature(),):
            try:
                _values(entry, sig, None, list(command.tokens), ctx)
            except InvalidCommandError:
                continue  # what _parse_tokens did too: the first alternative that fits
            if sig.precision is not None:
                return None
            count = len(command.values)
            params = [_param_at(sig, index, ctx) for index in range(lead, count)]
            kept = command.tokens[: len(command.tokens) - (count - lead)]
            head = " ".join((form.value + entry.name, *kept))
            floats = all(param.kind is Kind.FLOAT for param, _ in params)
            short = len(head) + (1 + _PLAIN_FLOAT_TEXT) * len(params) + 1 <= MAX_LINE_BYTES
            bounds = tuple((-math.inf if param.lo is None else param.lo,
                            math.inf if hi is None else hi, param.min_abs or 0.0)
                           for param, hi in params)
            return _RowPlan(command, tuple(params), head, floats, floats and short, bounds)
        return None

    def _checked(self, row: Sequence[float | int]) -> list[float | int] | None:
        """The row's values typed as :func:`build` types them, or ``None`` when the row
        needs the full path.

        Returns
        -------
        list[float | int] or None
            The typed values, or ``None``.
        """
        name = self.template.instruction.name
        try:
            return [_checked_number(param, value, name, hi)
                    for (param, hi), value in zip(self.params, row, strict=True)]
        except (InvalidCommandError, OverflowError):
            return None

    def build(self, row: Sequence[float | int]) -> Command | None:
        """The command for ``row``, or ``None`` when it needs the full path."""
        values = self._checked(row)
        if values is None:
            return None
        template = self.template
        tokens = (*template.tokens[: len(template.tokens) - len(row)],
                  *(format_number(value) for value in row))
        command = Command(template.instruction, template.form, None,
                          (*template.values[: len(template.values) - len(row)], *values),
                          tokens)
        return command if len(command.to_bytes()) <= MAX_LINE_BYTES else None

    def encode(self, row: Sequence[float | int]) -> bytes | None:
        """The bytes of the command for ``row`` (CR included), or ``None`` when it needs
        the full path.

        Returns
        -------
        bytes or None
            The bytes, or ``None``.
        """
        if self.floats and _plain_row(self.bounds, row):
            # What _checked and format_number give for such a row, a third of the time.
            texts = [self.head, *map(repr, row)]
        else:
            if self._checked(row) is None:
                return None
            texts = [self.head, *map(format_number, row)]
        data = " ".join(texts).encode("ascii") + b"\r"
        return data if len(data) <= MAX_LINE_BYTES else None

    def passes(self, row: Sequence[float | int]) -> bool | None:
        """``True`` when ``row`` passes :meth:`encode`'s shortcut with a line that cannot
        be too long (:func:`check_rows`), without making its words; ``None`` when it
        needs the full check.

        Returns
        -------
        bool or None
            ``True``, or ``None``.
        """
        return True if self.short and _plain_row(self.bounds, row) else None


def _plain_row(bounds: Sequence[tuple[float, float, float]],
               row: Sequence[float | int]) -> bool:
    """Whether every value of ``row`` is a finite ``float`` within its ``bounds`` (what
    :func:`_check_range` allows) whose ``repr()`` has no exponent, so that
    :func:`format_number` writes exactly that ``repr()``: what an upload passes. One call
    per row, not per value (the hot path of a list upload).

    Returns
    -------
    bool
        Whether the row is plain.
    """
    low_plain, high_plain = _PLAIN_FLOATS
    for (lowest, highest, least), value in zip(bounds, row, strict=True):
        # NaN fails the first comparison; an infinity the magnitude test.
        if type(value) is not float or not lowest <= value <= highest:
            return False
        size = abs(value)
        if size < least or not (size == 0.0 or low_plain <= size < high_plain):
            return False
    return True


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


def _param_at(sig: Signature, index: int, ctx: Context) -> tuple[Param, float | None]:
    """The parameter of the ``index``-th value (no axis letter) and its upper bound."""
    if index < len(sig.lead):
        param, dim = sig.lead[index], ctx.dims[0]
    else:
        offset = index - len(sig.lead)
        param = sig.per_axis[offset % len(sig.per_axis)]
        dim = ctx.dims[offset // len(sig.per_axis)]
    return param, upper_bound(param, dim)


def _checked_number(param: Param, value: float | int, name: str,
                    hi: float | None) -> float | int:
    """``value`` typed as :func:`_parse_value` would type its text, or InvalidCommandError."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(f"{name}: not a number", name, param.name, 5)
    if param.kind is Kind.FLOAT and math.isfinite(value):
        number: float | int = float(value)
    elif param.kind in (Kind.INT, Kind.CHOICE) and isinstance(value, int):
        if param.kind is Kind.CHOICE and value not in param.choices:
            raise _fail(f"{name}: not a choice", name, param.name, 5)
        number = value
    else:
        raise _fail(f"{name}: needs the full check", name, param.name, 5)
    _check_range(param, number, name, hi)
    return number


def _format_value(value: object, name: str | None = None) -> str:
    """The wire text of one value given by the caller (a word, or a number of any real
    type, see :func:`wire_number`); InvalidCommandError for anything else.

    Returns
    -------
    str
        The wire text.

    Raises
    ------
    InvalidCommandError
        ``value`` is not one word or number.
    """
    if isinstance(value, str):
        if not value or value.split() != [value]:
            raise _fail(f"{name}: {value!r} is not one value", name, None, 5)
        return value
    try:
        return format_number(value)  # type: ignore[arg-type]  # checked by wire_number
    except TypeError as exc:
        raise _fail(f"{name}: {exc}", name, None, 5) from None
    except ValueError:
        raise _fail(f"{name}: not a finite number: {value!r}", name, None, 5) from None


def _axis_part(
    entry: Instruction, form: Form, axis: str | None, axes: Mapping[str, AxisValues]
) -> tuple[str | None, list[Value]]:
    unknown = set(axes) - set(AXES)
    if unknown:
        raise _fail(f"{entry.name}: unknown axis keyword(s) {sorted(unknown)}",
                    entry.name, "axis", 1)
    given = [a for a in AXES if a in axes]
    if not given:
        return (axis.lower() if axis else None), []
    if axis is not None:
        raise _fail(f"{entry.name}: give either axis= or per-axis keywords", entry.name, "axis", 1)
    group = max((len(sig.per_axis) for sig in entry.signatures(form)), default=0)
    if len(given) == 1 and given[0] != "x":
        return given[0], _as_list(entry, group, axes[given[0]])
    if given != list(AXES[: len(given)]):
        raise _fail(f"{entry.name}: per-axis values must start at x without gaps, got "
                    f"{given}", entry.name, "axis", 1)
    return None, [v for a in given for v in _as_list(entry, group, axes[a])]


def _as_list(entry: Instruction, group: int, value: AxisValues) -> list[Value]:
    """The values of one axis: one value, or a sequence of at most ``group`` values for
    instructions that take several per axis. A list where one number goes is refused
    (``move_to(x=[1, 2])`` would send ``!moa 1 2``).

    Returns
    -------
    list[Value]
        The axis's values.

    Raises
    ------
    InvalidCommandError
        A sequence where one value goes, or too many values.
    """
    if isinstance(value, str) or not isinstance(value, Sequence):
        return [value]
    if group < 2 or len(value) > group:
        raise _fail(f"{entry.name}: {value!r} is not a single value per axis"
                    if group < 2 else f"{entry.name}: at most {group} values per axis, got "
                    f"{len(value)}", entry.name, None, 6)
    return list(value)


# --------------------------------------------------------------------------------------
# Replies


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


def build_axes(
    name: str,
    axes: Mapping[str, AxisValues],
    *,
    form: Form | str = Form.SET,
    context: Context | None = None,
) -> Command:
    """:func:`build` with the per-axis values given as a mapping (``{"x": 1, "y": 2}``).

    Parameters
    ----------
    name
        The instruction's name or alias.
    axes
        The values of each axis, by axis letter.
    form
        ``"!"``, ``"?"`` or ``""`` (or a :class:`Form`).
    context
        What the driver knows of the controller (dims, axes, extmode); ``None`` for the
        default context.

    Returns
    -------
    Command
        The validated command.
    """
    return _build(name, (), form, None, context, axes)
