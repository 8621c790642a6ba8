"""The types of the instruction catalog: what an instruction, its parameters, its
signatures and its reply look like, as plain data.
"""

from __future__ import annotations

import enum
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Final

__all__ = [
    "AXES",
    "DEFAULT_CONTEXT",
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
    "SettingValue",
    "Shape",
    "Signature",
]

#: One stored value of a setting (a number or a word such as ``triga``'s axis letter).
SettingValue = float | int | str

#: Axis letters in wire order.
AXES: Final = ("x", "y", "z", "a")



class Form(enum.Enum):
    """How an instruction is prefixed on the wire."""

    # Hashed by identity, in C: Enum's own __hash__ is a Python function, and these
    # members are dict keys and set members on the per-line path. Members are
    # singletons compared by identity, so the two agree.
    __hash__ = object.__hash__

    SET = "!"
    READ = "?"
    BARE = ""


class Bare(enum.Enum):
    """What the prefix-less form of an instruction does."""

    NONE = "none"  #: not allowed
    READ = "read"  #: reads, like ``?`` (``version``, ``sa``, ``err``)
    EXECUTE = "execute"  #: executes, like ``!`` (``moa``, ``cal``, ``save``)


class AxisRule(enum.Enum):
    """How an axis letter and per-axis values are handled."""

    NONE = "none"  #: no axis letter accepted
    OPTIONAL = "optional"  #: optional letter; without it values go to X Y Z A in order
    ALL = "all"  #: optional letter; without it one value group applies to all axes
    REQUIRED = "required"  #: an axis letter is mandatory


class Kind(enum.Enum):
    """Type of a parameter value."""

    FLOAT = "float"
    INT = "int"
    CHOICE = "choice"  #: one of :attr:`Param.choices` (numbers or words)
    BITS = "bits"  #: a string of ``0``/``1`` characters, LSB first


class Shape(enum.Enum):
    """Shape of a reply, which selects the reply parser."""

    # Hashed by identity, in C: Enum's own __hash__ is a Python function, and these
    # members are dict keys and set members on the per-line path. Members are
    # singletons compared by identity, so the two agree.
    __hash__ = object.__hash__

    NONE = "none"  #: no reply
    INT = "int"  #: one integer
    FLOAT = "float"  #: one number
    TEXT = "text"  #: one line of text, returned as is
    FLAGS = "flags"  #: a string of flag characters (``000100``), returned as str
    AXES_FLOAT = "axes_float"  #: numbers per axis, X Y Z A order
    AXES_INT = "axes_int"  #: integers per axis
    AXES_TEXT = "axes_text"  #: words per axis (``0 0 e``)
    NUMBERS = "numbers"  #: a list of numbers that is not per axis
    INTS = "ints"  #: a list of integers that is not per axis (``key`` → ``0 1 0 0``)
    STATUS = "status"  #: statusaxis letters (``@@@-.-`` or one letter)
    ACK = "ack"  #: ``OK...`` or ``ERR n``
    ERROR_NUMBER = "error_number"  #: ``?err``
    HELP = "help"  #: ``ERROR n,text``
    VERSION = "version"  #: ``TANGO-DT, Version 1.71, ...``
    DET = "det"  #: the ``?det`` bit field
    LINES = "lines"  #: several lines of text


class ModeEffect(enum.Enum):
    """How executing an instruction changes the autostatus mode (a catalog fact)."""

    NONE = "none"  #: the mode stays
    #: ``!autostatus n``: the mode becomes n (L2060-2168).
    VALUE = "value"
    #: ``reset``: a restart, in the power-on mode 1 (L1837-1857, L2062; never saved, L2071).
    RESTART = "restart"
    #: ``restore -1``: a factory reset and restart, in mode 1 (L1805-1813); plain
    #: ``restore`` reloads the saved set and keeps the mode (L1791-1800).
    RESTART_IF_MINUS_ONE = "restart_if_minus_one"

    def mode_after(self, command: Command, mode: int) -> int:
        """The autostatus mode in force after ``command`` (of an instruction with this
        effect) ran in ``mode``.

        Parameters
        ----------
        command
            The command that ran.
        mode
            The mode it ran in.

        Returns
        -------
        int
            The mode after it.
        """
        if self is ModeEffect.VALUE:
            if command.form is Form.SET and command.values:
                return int(command.values[0])
        elif self is ModeEffect.RESTART or (
                self is ModeEffect.RESTART_IF_MINUS_ONE and command.values == (-1,)):
            return 1  # power-on default (manual L2062); autostatus is never saved (L2071)
        return mode

    def owes_nothing(self, command: Command) -> bool:
        """Whether ``command`` sets the mode itself (``!autostatus n``): its echo and
        acknowledgement depend on the firmware, so it owes no mandatory line.

        Parameters
        ----------
        command
            The command.

        Returns
        -------
        bool
            Whether it owes no mandatory line.
        """
        return self is ModeEffect.VALUE and command.form is Form.SET


class Completion(enum.Enum):
    """The autostatus completion an executing instruction produces."""

    MOVE = "@"  #: moa, mor, m, moc, mol
    CAL = "A"  #: cal
    RM = "D"  #: rm


@dataclass(frozen=True, slots=True)
class Param:
    """One parameter value with its documented range."""

    name: str
    kind: Kind
    lo: float | None = None
    hi: float | None = None
    choices: tuple[int | str, ...] = ()
    optional: bool = False
    unit: str = ""
    #: The upper bound when the axis is in dim 9 (velocities in mm/s), if it differs.
    hi_dim9: float | None = None
    #: For :attr:`Kind.BITS`: the maximum number of characters.
    width: int = 0
    #: The smallest magnitude allowed, for ranges such as ``±0.00001 .. ±32500`` that
    #: exclude values around zero (``!flash``).
    min_abs: float | None = None


@dataclass(frozen=True, slots=True)
class Precision:
    """The optional trailing digit-count argument of some reads (``?vel y 4``)."""

    lo: int = 0
    hi: int = 16
    default: int | None = None


@dataclass(frozen=True, slots=True)
class Signature:
    """The argument grammar of one form of an instruction.

    ``lead`` parameters come first and are global; then ``per_axis`` groups follow, one
    group per axis, as many as the axis rule allows. ``arities`` restricts the total number
    of values where the manual does (``!clim r`` or ``!clim x y r``).
    """

    axis: AxisRule = AxisRule.NONE
    lead: tuple[Param, ...] = ()
    per_axis: tuple[Param, ...] = ()
    min_groups: int = 1
    precision: Precision | None = None

    @property
    def max_values(self) -> int:
        """The largest number of values the signature accepts (without an axis letter)."""
        groups = 1 if self.axis is AxisRule.ALL else len(AXES)
        return len(self.lead) + groups * len(self.per_axis) + (1 if self.precision else 0)


@dataclass(frozen=True, slots=True)
class LineRule:
    """How many reply lines a read produces.

    ``count`` lines always; then, if ``terminator`` is set, lines up to and including the
    terminator line; or, if ``continuation`` is set, every following line that matches it
    (the protocol follows such a request with a marker query so the end is seen).
    """

    count: int = 1
    terminator: str | None = None
    continuation: re.Pattern[str] | None = None


@dataclass(frozen=True)
class Instruction:
    """One instruction of the manual, as data."""

    name: str
    summary: str
    forms: frozenset[Form]
    bare: Bare = Bare.NONE
    aliases: tuple[str, ...] = ()
    #: Grammar of the executing forms (``!`` and an executing bare form); alternatives in
    #: order. Empty when the instruction has no executing form.
    write: tuple[Signature, ...] = ()
    #: Grammar of the reading forms (``?`` and a reading bare form).
    read: tuple[Signature, ...] = ()
    #: Shape of the reply to a read.
    reply: Shape = Shape.NONE
    #: Values per axis in a per-axis reply (``?lim`` has 2, ``?swtyp`` 3).
    reply_group: int = 1
    #: ``(value, group)`` pairs: a read whose first value is ``value`` replies with
    #: ``group`` values per axis instead (``?ctrstatus 0`` → ``2 7 2 7 0 0``).
    option_groups: tuple[tuple[int | str, int], ...] = ()
    #: Every per-axis reply value is a single digit; the controller may leave out the
    #: space between axis groups (``?swtyp`` in extmode 0 → ``1 1 11 1 11 1 1``).
    digit_values: bool = False
    #: Shape of the reply to an executing form (``save`` always answers ``OK...``).
    exec_reply: Shape = Shape.NONE
    completion: Completion | None = None
    #: Stored by ``save`` (the manual's "Save" column).
    saved: bool = False
    #: How executing it changes the autostatus mode.
    mode_effect: ModeEffect = ModeEffect.NONE
    #: Documented by the older edition of the manual (``old L<n>``).
    in_older_manual: bool = True
    #: The older edition documents it without values (``help``, ``version``: old L414,
    #: old L805-819), so a firmware of that edition refuses values.
    older_without_values: bool = False
    #: The attribute of the driver's cached settings (:class:`tango_aio.sansio._state.DriverState`)
    #: that mirrors this setting; empty: the driver does not cache it.
    cached: str = ""
    #: Power-on / factory values where the manual states them (one value group; per
    #: axis for per-axis settings). Empty: not stated.
    default: tuple[SettingValue, ...] = ()
    #: Settings written as ``index value`` (``!joyspeed 2 25``): the power-on value of
    #: each index. Empty: not an indexed setting.
    indexed: tuple[SettingValue, ...] = ()
    #: Fractional digits of float replies, from the manual's examples; ``None``: not
    #: stated.
    digits: int | None = None
    #: The reply is in position units, printed with ``resolution`` digits (L4144).
    position_valued: bool = False
    section: str = ""
    line: int = 0
    #: Reply-line rule for reads; see :func:`reply_rule`.
    lines: LineFn | None = field(default=None, repr=False)

    @property
    def per_axis(self) -> bool:
        """Whether its set form takes one value group per axis (``!vel 5 6``)."""
        return bool(self.write and self.write[0].per_axis)

    def allows(self, form: Form) -> bool:
        """Whether the instruction accepts ``form``.

        Parameters
        ----------
        form
            The form.

        Returns
        -------
        bool
            Whether it is accepted.
        """
        return form in self.forms

    def signatures(self, form: Form) -> tuple[Signature, ...]:
        """The grammar alternatives of ``form``; the bare form uses the read or write one.

        Parameters
        ----------
        form
            The form.

        Returns
        -------
        tuple[Signature, ...]
            The alternatives, in order.
        """
        return self.read if self.is_read(form) else self.write

    def is_read(self, form: Form) -> bool:
        """Whether ``form`` reads (``?`` or a reading bare form).

        Parameters
        ----------
        form
            The form.

        Returns
        -------
        bool
            Whether it reads.
        """
        return form is Form.READ or (form is Form.BARE and self.bare is Bare.READ)


LineFn = Callable[["Command", "Context"], LineRule]


@dataclass(frozen=True, slots=True)
class Context:
    """Controller state that changes how lines validate and replies look.

    ``dims`` holds the ``dim`` of X Y Z A (velocity limits depend on dim 9), ``axes`` the
    number of configured axes, ``extmode`` the extended mode (``?lim`` formatting).
    """

    dims: tuple[int, int, int, int] = (2, 2, 2, 2)
    axes: int = 4
    extmode: int = 0

    @classmethod
    def of(cls, dims: Sequence[int], axes: int = 4, extmode: int = 0) -> Context:
        """The context for the ``dim`` of X Y Z A given as any sequence of four.

        Parameters
        ----------
        dims
            The ``dim`` of X, Y, Z and A.
        axes
            The number of configured axes.
        extmode
            The extended mode.

        Returns
        -------
        Context
            The context.
        """
        x, y, z, a = dims
        return cls((int(x), int(y), int(z), int(a)), axes, extmode)


DEFAULT_CONTEXT: Final = Context()


@dataclass(frozen=True, slots=True)
class Command:
    """A validated command line."""

    instruction: Instruction
    form: Form
    axis: str | None
    values: tuple[float | int | str, ...]
    tokens: tuple[str, ...]
    # The line text and its bytes, computed once on first use: the protocol asks for them
    # several times per line (size, credit, framing check, write), which showed in the
    # scaling benchmark (benchmarks/scaling.py).
    _line: str | None = field(default=None, init=False, repr=False, compare=False)
    _bytes: bytes | None = field(default=None, init=False, repr=False, compare=False)
    #: The instruction's canonical name.
    name: str = field(init=False, repr=False, compare=False)
    #: Whether this command reads (and so expects a data reply). Both are fields, set once
    #: here, not properties: every layer asks for them several times per line.
    is_read: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        instruction = self.instruction
        object.__setattr__(self, "name", instruction.name)
        object.__setattr__(self, "is_read", instruction.is_read(self.form))

    @property
    def executes(self) -> bool:
        """Whether this command sets or executes something."""
        return not self.is_read

    @property
    def line(self) -> str:
        """The canonical text of the line, without CR."""
        line = self._line
        if line is None:
            head = self.form._value_ + self.instruction.name  # _value_: .value, cheaper
            line = " ".join([head, *([self.axis] if self.axis else []), *self.tokens])
            object.__setattr__(self, "_line", line)
        return line

    def to_bytes(self) -> bytes:
        """The exact bytes to write, CR included.

        Returns
        -------
        bytes
            The line, CR included.
        """
        data = self._bytes
        if data is None:
            data = self.line.encode("ascii") + b"\r"  # a non-ASCII token raises here
            object.__setattr__(self, "_bytes", data)
        return data

