"""The driver's cached view of the controller's settings, without I/O."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from ..catalog import AXES, INSTRUCTIONS, Command, Context, Instruction
from ..moves import MoveTiming

__all__ = ["CACHED_SETTINGS", "DriverState"]

#: The instructions whose settings the driver caches, in catalog (manual) order.
CACHED_SETTINGS: Final = tuple(entry for entry in INSTRUCTIONS.values() if entry.cached)
#: The cached settings :class:`~tango_aio.catalog._schema.Context` is made of (besides the axes).
_CONTEXT_SETTINGS: Final = frozenset({"dim", "extmode"})


@dataclass(slots=True)
class DriverState(MoveTiming):
    """The settings the driver caches (the :class:`~tango_aio.moves._timing.MoveTiming` fields)
    and the number of configured axes: everything the validation context and move
    timing depend on. Pure: no I/O, no event loop."""

    #: Configured axes (``?det``, read by ``identify``).
    axes: int = 4

    @property
    def context(self) -> Context:
        """The validation context these settings make (dims, axes, extmode)."""
        return Context.of(self.dims, self.axes, self.extmode)

    def observe(self, command: Command) -> bool:
        """Take in a set or executing ``command`` the controller accepted. Returns whether
        it changed a setting the validation context is made of (:attr:`context`: ``dim``
        or ``extmode``), so that the caller builds the context again only then."""
        entry = command.instruction
        if not entry.cached or not command.values or command.is_read:
            return False
        if not entry.per_axis:
            self._put(entry, command.values[0])
        else:
            # '!vel y 5' sets Y; '!vel 5 6' sets X and Y (values in X Y Z A order).
            start = AXES.index(command.axis) if command.axis else 0
            self._put_axes(entry, dict(zip(AXES[start:], command.values, strict=False)))
        return entry.name in _CONTEXT_SETTINGS

    def load(self, entry: Instruction, value: object) -> None:
        """Store the value of the cached setting ``entry`` read back from the controller:
        ``{axis: value}`` for a per-axis setting (axes left out keep their value), one
        number for a global one."""
        if not entry.cached:
            raise ValueError(f"{entry.name} is not a cached setting")
        if not entry.per_axis:
            self._put(entry, value)
        elif isinstance(value, Mapping):
            self._put_axes(entry, value)
        else:
            raise TypeError(f"{entry.name}: expected {{axis: value}}, got {value!r}")

    def _put(self, entry: Instruction, value: object) -> None:
        current = getattr(self, entry.cached)
        setattr(self, entry.cached, type(current)(value))

    def _put_axes(self, entry: Instruction, values: Mapping[str, object]) -> None:
        target = getattr(self, entry.cached)
        for index, axis in enumerate(AXES):
            if axis in values:
                target[index] = type(target[index])(values[axis])
