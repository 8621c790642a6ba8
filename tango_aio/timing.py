"""Move timing without I/O: how long a move may take and what counts as its target.

Theory of operation
===================
The driver never waits for a move without a bound (no false success, and every failure
in bounded time). That bound is computed here, from the settings the driver caches
(:class:`MoveTiming`, which :class:`~tango_aio.state.DriverState` extends and keeps in
step with every accepted set) and from the geometry of the move:

* :meth:`MoveTiming.travel` converts a distance in the axis's user unit (``dim``,
  ``pitch``) to motor revolutions and times a trapezoid profile (:func:`travel_time`) at
  the slowest plausible speed: ``vel`` capped by the security speed ``secvel``, with the
  acceleration ``accel``. The waits around a move, ``delay`` before it (L6845-6868),
  ``pause`` after it (L6873-6899) and the closed-loop settling ``ctrt`` (L11616-11631),
  are cached with it; the controller adds them to the travel to size a move's budget.
* :func:`moved_axes` says which axes a motion line moves, so that only those are
  confirmed.
* :func:`position_tolerance` says how far a printed position may stand from its target
  and still be "at" it: the controller prints positions rounded (L4080-4100), so the
  tolerance follows the printed digits.

Everything here is a pure function of its arguments, tested synchronously
(``tests/unit/test_timing.py``); :mod:`tango_aio.motion` asks it and does the waiting.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from .instructions import AXES, Command
from .units import UnitScale

__all__ = ["UNKNOWN_TRAVEL", "MoveTiming", "moved_axes", "position_tolerance", "travel_time"]

#: Seconds :func:`travel_time` gives a move whose speed or acceleration is unknown.
UNKNOWN_TRAVEL = 60.0


@dataclass(slots=True)
class MoveTiming:
    """Per-axis and global settings the driver caches to time moves."""

    dims: list[int] = field(default_factory=lambda: [2, 2, 2, 2])
    pitch: list[float] = field(default_factory=lambda: [1.0] * 4)
    vel: list[float] = field(default_factory=lambda: [10.0] * 4)
    accel: list[float] = field(default_factory=lambda: [1.0] * 4)
    secvel: list[float] = field(default_factory=lambda: [10.0] * 4)
    extmode: int = 0
    #: ``!delay`` (ms) before a moa/mor/m/moc starts (L6845-6868).
    delay_ms: float = 0.0
    #: ``!pause`` (ms) after the axes reached their target, before the report (L6873-6899).
    pause_ms: float = 0.0
    #: ``!ctrt`` (ms): longest closed-loop settling before the report (L11616-11631).
    settle_ms: float = 0.0

    def travel(self, axis: str, distance: float) -> float:
        """Seconds a single-axis trapezoid move of ``distance`` takes at the slowest
        plausible speed (vel capped by secvel)."""
        index = AXES.index(axis)
        scale = UnitScale(dim=self.dims[index], pitch=self.pitch[index])
        return travel_time(abs(scale.pos_from_user(distance)),
                           min(scale.vel_from_user(self.vel[index]),
                               scale.mm_to_rev(self.secvel[index])),
                           scale.accel_to_rev(self.accel[index]))


def travel_time(revs: float, speed: float, accel: float) -> float:
    """Seconds to travel ``revs`` revolutions with a trapezoid profile
    (:data:`UNKNOWN_TRAVEL` when the speed or acceleration is unknown)."""
    if speed <= 0 or accel <= 0 or not math.isfinite(speed + accel):
        return UNKNOWN_TRAVEL
    ramp = speed / accel
    if revs < speed * ramp:
        return 2.0 * math.sqrt(revs / accel)
    return revs / speed + ramp


def moved_axes(command: Command, present: Sequence[str]) -> tuple[str, ...]:
    """The axes a motion line moves: its axis, the leading axes it has values for, or every
    present axis (``cal``, ``rm``, ``moc`` without an axis)."""
    if command.axis is not None:
        return (command.axis,)
    if command.values:
        return tuple(AXES[: len(command.values)])
    return tuple(present)


def position_tolerance(text: str) -> float:
    """How far a position read as ``text`` may be from its target: one and a half units of
    its last printed digit (the controller prints positions rounded to its ``resolution``,
    L4080-4100; a ``move_by`` target carries the rounding of the start position too)."""
    digits = len(text.rsplit(".", 1)[1]) if "." in text else 0
    return 1.5 * 10.0 ** -digits
