"""Generic settings store of the emulated controller, driven by the instruction catalog.

Every instruction that can be both set and read keeps its value here without any code of
its own: per-axis instructions keep one value group per axis, global ones one tuple. Reads
are formatted the way the manual prints them (digit counts from its examples, positions
with ``resolution`` digits). Instructions with behaviour (moves, lists, identity) are
handled by :mod:`tango_aio.sim.model` and only use this store for their plain settings.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from ..instructions import AXES, INSTRUCTIONS, AxisRule, Command, Kind, Param, Signature

__all__ = ["DEFAULTS", "DIGITS", "INDEXED", "POSITION_VALUED", "ParamStore", "format_value"]

Value = float | int | str

#: Power-on / factory defaults where the manual states them; everything else starts at the
#: first allowed value or 0.
DEFAULTS: Final[dict[str, tuple[Value, ...]]] = {
    "baud": (57600,), "cts": (0,), "ipreter": (1,), "autostatus": (1,), "extmode": (0,),
    "scanmode": (0,), "scanvel": (10.0,), "dim": (2,), "pitch": (1.0,), "gear": (1.0,),
    "motorsteps": (200,), "accel": (1.0,), "stopaccel": (1.0,), "vel": (10.0,),
    "velfac": (1.0,), "secvel": (10.0,), "cur": (1.0,), "reduction": (1.0,),
    "curdelay": (1000,), "axis": (1,), "usteps": (40000,), "resolution": (4,),
    "swtyp": (1, 1, 1), "swpol": (0, 0, 0), "swact": (1, 0, 1), "limctr": (1,),
    "caltimeout": (40,), "calbspeed": (32.0,), "calrefspeed": (32.0,),
    "calvel": (10.0, 0.5), "rmvel": (10.0, 0.5), "joy": (2,), "joydir": (1,),
    "joywindow": (14,), "joyvel": (10.0,), "joyspeed": (1.0,), "keyspeed": (1.0, 10.0),
    "hwfilter": (1,), "tbfactor": (1.0,), "zwaxis": ("z",), "zwfactor": (1,),
    "zwtravel": (1.0,), "tvrjoyf": (1.0,), "hwfactor": (1.0,), "hwfactorb": (1.0,),
    "pa": (1,), "encvel": (0.5,), "encperiod": (0.02,), "encrefvel": (1.0,), "ctr": (2,),
    "ctrf": (2.0,), "ctrff": (2.0, 2.0), "ctrd": (10,), "ctrt": (1000,), "ctrc": (1,),
    "twi": (0.001,), "ctrs": (0.5,), "mra": (1.0,), "trigf": (1000.0,), "trigbf": (1000.0,),
    "trigbwidth": (40.0,), "trigs": (40,), "trigo": (1,), "triga": ("x",), "trigl": (1,),
    "sns": (1,), "snsf": (10,), "anaout": (0.0,), "trigd": (1.0,), "noled": (0,),
}

#: Settings written as ``index value`` (``!joyspeed 2 25``, ``!anaout c 1 25.3``): the store
#: keeps one value per index, not the written pair. Defaults where the manual gives them:
#: adiginfunc "SnapShot is assigned to the SnapShot input (3) and stop ... to the not
#: available input 2" (L9195); zwtravel presets 0.1 / 0.01 / 1.0 mm/rev (L7863); anaout
#: channels 0-2 at 0 %. The joyspeed presets are not documented: chosen.
INDEXED: Final[dict[str, tuple[Value, ...]]] = {
    "adiginfunc": (0, 0, 1, 2),
    "zwtravel": (0.1, 0.01, 1.0),
    "joyspeed": (1.0, 10.0, 30.0),
    "anaout": (0.0, 0.0, 0.0),
}

#: Fractional digits of float replies, from the manual's examples (protocol_notes §3).
DIGITS: Final[dict[str, int]] = {
    "vel": 3, "secvel": 2, "accel": 2, "stopaccel": 2, "cur": 2, "iscur": 2, "pitch": 4,
    "gear": 3, "keyspeed": 2, "calvel": 3, "rmvel": 3, "ctrff": 1, "anaout": 2,
    "scanvel": 6, "trigbf": 3, "trigbdelay": 2, "trigbwidth": 2, "isvel": 3,
    "encperiod": 4, "velfac": 2, "reduction": 2, "joyvel": 3, "encrefvel": 3, "encvel": 3,
    "speed": 3, "calbspeed": 1, "calrefspeed": 1, "mra": 4, "trigf": 2, "joyspeed": 3,
    "zwtravel": 3, "tvrjoyf": 3, "hwfactor": 3, "hwfactorb": 3, "tbfactor": 3,
    "backlash": 1, "temp": 1, "flash": 3, "encamp": 0, "ctrf": 0,
}

#: Replies in position units, printed with ``resolution`` digits (manual L4144).
POSITION_VALUED: Final = frozenset({
    "pos", "lim", "maxpos", "posclr", "distance", "twi", "ctrs", "ctrdiff", "caliboffset",
    "rmoffset", "calpos", "calzeropos", "trigd", "snsa", "snsp", "snsj", "prehome", "home",
    "lockpos", "trigp", "trigr", "clim", "vrm",
})


def format_value(value: Value, digits: int) -> str:
    """Format one reply value: ints as ints, floats with ``digits`` fractional digits.

    A float that rounds to zero from below prints ``-0.0000`` here; the model prints it
    as ``0.0000`` unless the firmware switch ``numbers`` is ``negzero``.
    """
    if isinstance(value, str):
        return value
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}f}"


def position_digits(resolution: int, dim: int) -> int:
    """Digits of a position reply: ``resolution``, but at most 2 in dim 1 and none in
    dim 0 (manual L4109-4162, L3120-3126)."""
    if dim == 0:
        return 0
    if dim == 1:
        return 1 if resolution <= 4 else resolution - 3
    return resolution


def _initial(sig: Signature, name: str) -> tuple[Value, ...]:
    params = sig.per_axis or sig.lead
    default = DEFAULTS.get(name)
    values: list[Value] = []
    for index, param in enumerate(params):
        if default is not None and index < len(default):
            values.append(default[index])
        else:
            values.append(_zero(param))
    return tuple(values)


def _zero(param: Param) -> Value:
    if param.kind is Kind.CHOICE and param.choices:
        return 0 if 0 in param.choices else param.choices[0]
    if param.kind is Kind.BITS:
        return "0" * param.width
    if param.kind is Kind.FLOAT:
        return 0.0
    return 0


class ParamStore:
    """Values of every settable instruction, per axis or global."""

    def __init__(self) -> None:
        self.axis_values: dict[str, list[tuple[Value, ...]]] = {}
        self.global_values: dict[str, tuple[Value, ...]] = {}
        for name, entry in INSTRUCTIONS.items():
            if not entry.write or not entry.read:
                continue
            sig = entry.write[0]
            if sig.per_axis:
                self.axis_values[name] = [_initial(sig, name)] * len(AXES)
            else:
                self.global_values[name] = INDEXED.get(name) or _initial(sig, name)

    # -- access ---------------------------------------------------------------------------

    def axis(self, name: str, axis: int) -> tuple[Value, ...]:
        """The value group of ``name`` for axis index ``axis``."""
        return self.axis_values[name][axis]

    def first(self, name: str, axis: int = 0) -> Value:
        """The first value of ``name`` (of axis ``axis`` for per-axis instructions)."""
        if name in self.axis_values:
            return self.axis_values[name][axis][0]
        return self.global_values[name][0]

    def number(self, name: str, axis: int = 0) -> float:
        """:meth:`first` as a float."""
        return float(self.first(name, axis))

    def put_axis(self, name: str, axis: int, values: Sequence[Value]) -> None:
        """Replace the leading values of the group of ``name`` on axis ``axis``."""
        old = self.axis_values[name][axis]
        self.axis_values[name][axis] = tuple(values) + old[len(values):]

    def put_global(self, name: str, values: Sequence[Value]) -> None:
        """Replace the leading values of global ``name``."""
        old = self.global_values[name]
        self.global_values[name] = tuple(values) + old[len(values):]

    # -- commands -------------------------------------------------------------------------

    def apply(self, command: Command, axes: int) -> None:
        """Store the values of a set command (generic semantics of chapter 2)."""
        name = command.name
        if name in self.axis_values:
            self._apply_axes(command, axes)
        elif name in self.global_values and command.values:
            self.put_global(name, command.values)

    def _apply_axes(self, command: Command, axes: int) -> None:
        name = command.name
        sig = command.instruction.write[0]
        size = len(sig.per_axis)
        values = command.values[len(sig.lead):]
        if command.axis is not None:
            self.put_axis(name, AXES.index(command.axis), values)
        elif sig.axis is AxisRule.ALL:
            for index in range(len(AXES)):
                self.put_axis(name, index, values)
        else:
            for index in range(min(axes, (len(values) + size - 1) // size)):
                self.put_axis(name, index, values[index * size:(index + 1) * size])

    def read(self, command: Command, axes: int, digits: int | None = None) -> str:
        """Format the stored value(s) for a read command."""
        name = command.name
        if name in self.axis_values:
            indices = [AXES.index(command.axis)] if command.axis else range(axes)
            groups = [self.axis_values[name][i] for i in indices]
            return " ".join(self._format(name, value, i, digits)
                            for i, group in zip(indices, groups, strict=True)
                            for value in group)
        values = self.global_values[name]
        return " ".join(self._format(name, value, 0, digits) for value in values)

    def _format(self, name: str, value: Value, axis: int, digits: int | None) -> str:
        if digits is None:
            if name in POSITION_VALUED:
                digits = position_digits(int(self.first("resolution")),
                                         int(self.first("dim", axis)))
            else:
                digits = DIGITS.get(name, 3)
        return format_value(value, digits)
