"""What a Sardana motor's state is, decided from the driver's verdicts (sans-IO)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from tango_aio.status import ABSENT, AxisStatus

#: Sardana's limit-switch bits (``MotorController.HomeLimitSwitch`` and the others).
HOME, UPPER, LOWER = 1, 2, 4


class State(enum.Enum):
    """The Sardana state an axis is reported in (mapped to ``sardana.State``)."""

    ON = "On"
    MOVING = "Moving"
    ALARM = "Alarm"
    FAULT = "Fault"


@dataclass(frozen=True)
class Outcome:
    """How this controller's latest move of an axis stands."""

    #: The move's verdict is not in yet (its line may not even be written).
    running: bool
    #: Why it did not arrive (``None``: it arrived, or is still running).
    error: str | None = None
    #: The pool stopped or aborted this axis during the move.
    stopped_on_request: bool = False


@dataclass(frozen=True)
class AxisState:
    """An axis' state, its status text and its limit switches (Sardana's bits)."""

    state: State
    status: str
    switches: int = 0


def switch_bits(states: tuple[bool, bool, bool]) -> int:
    """Sardana's bits of (lower, reference, upper); reference (always 0) maps to home."""
    lower, reference, upper = states
    return (LOWER if lower else 0) | (HOME if reference else 0) | (UPPER if upper else 0)


def describe_switches(bits: int) -> str:
    """The actuated switches in words (``""`` for none)."""
    names = [name for bit, name in ((LOWER, "lower"), (UPPER, "upper"), (HOME, "home"))
             if bits & bit]
    return " and ".join(names) + (" limit switch" if len(names) == 1 else " limit switches") \
        if names else ""


def axis_state(outcome: Outcome | None, *, letter: str | None = None, switches: int = 0,
               unreadable: str | None = None) -> AxisState:
    """Decide an axis' state. A move of this controller reads MOVING until the driver's
    verdict is in (its final position is then what ``?pos`` reads); only the verdict
    makes an axis stopped. Without a move in flight, the link, the status letter and the
    switches decide; a failed move keeps ALARM, with its reason, until the next move."""
    if outcome is not None and outcome.running:
        return AxisState(State.MOVING, "moving: the move's verdict is not in yet", switches)
    if unreadable is not None:
        return AxisState(State.FAULT, unreadable, switches)
    if letter == AxisStatus.MOVING:
        return AxisState(State.MOVING, "moving (not started by this pool: another client, "
                         "or a manual control)", switches)
    touching = describe_switches(switches)
    if outcome is not None and outcome.error is not None and not outcome.stopped_on_request:
        text = f"the last move failed: {outcome.error}"
        return AxisState(State.ALARM, f"{text}; on the {touching}" if touching else text,
                         switches)
    if switches & (LOWER | UPPER):
        return AxisState(State.ALARM, f"on the {touching}", switches)
    stopped = outcome is not None and outcome.stopped_on_request
    if letter == ABSENT:
        return AxisState(State.ALARM, "status -: the axis is not enabled or not present "
                         "(manual L2711)", switches)
    if letter is not None and not stopped:
        try:
            member = AxisStatus.of(letter)
        except ValueError:
            return AxisState(State.ALARM, f"status {letter!r}, a letter the manual does not "
                             "document", switches)
        if member.is_failure:
            return AxisState(State.ALARM, f"status {letter}: {member.meaning}", switches)
    if stopped:
        return AxisState(State.ON, "stopped on request", switches)
    return AxisState(State.ON, "", switches)
