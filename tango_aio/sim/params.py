"""Generic settings store of the emulated controller, driven by the instruction catalog.

Every instruction that can be both set and read keeps its value here without any code of
its own: per-axis instructions keep one value group per axis, global ones one tuple. Reads
are formatted the way the manual prints them (digit counts from its examples, positions
with ``resolution`` digits). Instructions with behaviour (moves, lists, identity) are
handled by :mod:`tango_aio.sim.model` and only use this store for their plain settings.

The facts come from the manual's catalog (power-on values, reply digits, position-valued
replies: :class:`~tango_aio.catalog._schema.Instruction`); the emulator reads the catalog, never
the driver's rules.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from ..catalog import AXES, INSTRUCTIONS, AxisRule, Command, Kind, Param, Signature

__all__ = ["INDEXED", "ParamStore", "format_value"]

Value = float | int | str

#: Settings written as ``index value`` (``!joyspeed 2 25``): their power-on value per
#: index, from the catalog (:attr:`~tango_aio.catalog._schema.Instruction.indexed`).
INDEXED: Final[dict[str, tuple[Value, ...]]] = {
    name: entry.indexed for name, entry in INSTRUCTIONS.items() if entry.indexed
}


def format_value(value: Value, digits: int) -> str:
    """Format one reply value: ints as ints, floats with ``digits`` fractional digits."""
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
    default = INSTRUCTIONS[name].default
    values: list[Value] = []
    for index, param in enumerate(params):
        if index < len(default):
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
                self.global_values[name] = entry.indexed or _initial(sig, name)

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
            entry = INSTRUCTIONS[name]
            if entry.position_valued:
                digits = position_digits(int(self.first("resolution")),
                                         int(self.first("dim", axis)))
            else:
                digits = 3 if entry.digits is None else entry.digits  # 3: not stated
        return format_value(value, digits)
