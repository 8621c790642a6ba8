"""What a Sardana synchronisation description asks of the trigger output, and how the
trigger-gate axis stands (sans-IO)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from ._state import State

__all__ = ["Group", "TriggerPlan", "plan", "trigger_state"]


@dataclass(frozen=True)
class Group:
    """One group of a description in the position domain (dial positions, in the unit
    the motor controller reads)."""

    #: Where the first pulse goes.
    initial: float
    #: The distance from one pulse to the next (negative: travelling backwards).
    total: float
    #: How many pulses.
    repeats: int
    #: The active part of each interval in seconds (the pulse width), if given.
    active_time: float | None = None


@dataclass(frozen=True)
class TriggerPlan:
    """The trigger positions to load, as a range when equidistant (``!trigr``), else as a
    list, and the pulse width."""

    positions: tuple[float, ...]
    #: ``(start, end, count)`` when one equidistant run covers every position.
    range: tuple[float, float, int] | None
    #: The pulse width in µs (``None``: keep the controller's).
    width_us: int | None


def plan(groups: list[Group]) -> TriggerPlan:
    """The trigger positions of ``groups``, in order; ValueError for an empty
    description, a group without pulses, an interval of zero or not finite, or positions
    that do not run one way (the list must be strictly monotonic)."""
    if not groups:
        raise ValueError("the synchronisation description has no group")
    positions: list[float] = []
    widths = {round(g.active_time * 1e6) for g in groups if g.active_time is not None}
    if len(widths) > 1:
        raise ValueError("the trigger output has one pulse width; the groups' active "
                         f"times differ ({sorted(widths)} µs)")
    for group in groups:
        if isinstance(group.repeats, bool) or not isinstance(group.repeats, int) \
                or group.repeats < 1:
            raise ValueError(f"a group needs at least one repeat, got {group.repeats!r}")
        if not (math.isfinite(group.initial) and math.isfinite(group.total)) \
                or group.total == 0:
            raise ValueError(f"a group needs a finite initial position and a non-zero "
                             f"interval, got {group.initial!r} and {group.total!r}")
        positions += [group.initial + i * group.total for i in range(group.repeats)]
    steps = [b - a for a, b in itertools.pairwise(positions)]
    if not (all(s > 0 for s in steps) or all(s < 0 for s in steps)):
        raise ValueError("the trigger positions must run one way (strictly monotonic)")
    one_run = len(groups) == 1 and len(positions) >= 2
    return TriggerPlan(tuple(positions),
                       (positions[0], positions[-1], len(positions)) if one_run else None,
                       widths.pop() if widths else None)


def trigger_state(*, loaded: bool, started: bool, stopped: bool, enabled: bool, count: int,
                  expected: int) -> tuple[State, str]:
    """The trigger-gate axis' state from the controller's trigger counter against the
    pulses the loaded description expects."""
    if not started:
        return State.ON, "ready: " + (f"{expected} pulses loaded" if loaded else
                                      "no synchronisation loaded")
    if count > expected:
        return State.ALARM, f"{count} pulses were sent, {expected} expected"
    if count == expected:
        return State.ON, f"all {expected} pulses sent"
    if stopped:
        return State.ON, f"stopped on request after {count} of {expected} pulses"
    if not enabled:
        return State.ALARM, (f"the trigger output was switched off elsewhere after {count} "
                             f"of {expected} pulses")
    return State.MOVING, f"{count} of {expected} pulses sent"
