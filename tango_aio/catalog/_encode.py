"""Command lines built from Python values against the catalog (:func:`build`,
:func:`build_axes`), list entries built, encoded or checked row by row (:func:`build_rows`,
:func:`encode_rows`, :func:`check_rows`), and the framing check of a line about to be
written (:func:`check_framing`, :func:`check_rows_framing`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from decimal import Decimal
from fractions import Fraction
from typing import Final, TypeVar

from ..errors import InvalidCommandError
from ._instructions import (
    _BY_ALIAS,
    MAX_LINE_BYTES,
    _check_form,
    _check_range,
    _fail,
    _parse_tokens,
    _values,
    format_number,
    lookup,
    parse,
    upper_bound,
)
from ._schema import (
    AXES,
    DEFAULT_CONTEXT,
    Command,
    Context,
    Form,
    Instruction,
    Kind,
    Param,
    Signature,
)

__all__ = [
    "AxisValues",
    "Number",
    "Value",
    "build",
    "build_axes",
    "build_rows",
    "check_axis_word",
    "check_framing",
    "check_rows",
    "check_rows_framing",
    "encode_rows",
]


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
    ``set("vel", 5, x=3)`` would otherwise send ``!vel 5 3`` and set Y to 3."""
    most = max((len(sig.lead) for sig in entry.signatures(form)), default=0)
    if len(args) > most:
        raise _fail(f"{entry.name}: positional values {list(args)} cannot be mixed with "
                    "per-axis keywords (give every axis as a keyword)", entry.name, None, 6)


def _check_words(command: Command, given: Sequence[Value]) -> None:
    """A string value must be one whole token of a word or bit-pattern parameter: where
    a number goes, ``"5"`` is a caller's bug and ``"1 2"`` would smuggle in a second
    value (``move_to(x="1 2")`` sending ``!moa 1 2`` moves Y)."""
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
    the plan of the first row of its length, ``full`` from a command built in full."""
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
        needs the full path."""
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
        the full path."""
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
        needs the full check."""
        return True if self.short and _plain_row(self.bounds, row) else None


def _plain_row(bounds: Sequence[tuple[float, float, float]],
               row: Sequence[float | int]) -> bool:
    """Whether every value of ``row`` is a finite ``float`` within its ``bounds`` (what
    :func:`_check_range` allows) whose ``repr()`` has no exponent, so that
    :func:`format_number` writes exactly that ``repr()``: what an upload passes. One call
    per row, not per value (the hot path of a list upload)."""
    low_plain, high_plain = _PLAIN_FLOATS
    for (lowest, highest, least), value in zip(bounds, row, strict=True):
        # NaN fails the first comparison; an infinity the magnitude test.
        if type(value) is not float or not lowest <= value <= highest:
            return False
        size = abs(value)
        if size < least or not (size == 0.0 or low_plain <= size < high_plain):
            return False
    return True


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
    type, see :func:`wire_number`); InvalidCommandError for anything else."""
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
    (``move_to(x=[1, 2])`` would send ``!moa 1 2``)."""
    if isinstance(value, str) or not isinstance(value, Sequence):
        return [value]
    if group < 2 or len(value) > group:
        raise _fail(f"{entry.name}: {value!r} is not a single value per axis"
                    if group < 2 else f"{entry.name}: at most {group} values per axis, got "
                    f"{len(value)}", entry.name, None, 6)
    return list(value)


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
