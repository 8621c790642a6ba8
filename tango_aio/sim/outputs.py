"""The trigger outputs' rules (manual chapters 21 and 22), without state or I/O: which
outputs one trigger event drives and for how long, the clocks of the periodic mode and of
the secondary output's own frequency, and the frequency ``?trigf`` reads back.

Choices where the manual is silent are switches of :mod:`tango_aio.sim.profiles`
(``trigf_round``, ``periodic_first``, ``trigcomp_read``; ``bidirectional_next`` in
:mod:`tango_aio.sim.trigtrack`); the others are named with their lines below.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .devices import TAKT_OUT, TRIGGER_OUT, Pulse

__all__ = ["TICK", "Clock", "OutputSettings", "compensation_step", "event_pulses", "precise",
           "true_frequency"]

#: The trigger signals are processed in a 40 µs interval (L12525), the resolution of
#: ``trigs`` (L12959-12967) and of ``trigf``'s period (L13234, L13240-13250).
TICK = 40e-6

#: The secondary output's precise timings resolve 1/132 µs (L13290, L13329; "7.6ns
#: steps", L14343, L14386).
PRECISE_STEP = 1e-6 / 132


def precise(microseconds: float) -> float:
    """A precise delay or width (``trigbdelay``, ``trigbwidth``) in seconds, on its
    1/132 µs step."""
    return round(microseconds * 132) * PRECISE_STEP


def compensation_step(microseconds: int) -> int:
    """``trigcomp`` on its "smallest step is 10µs" (L13060): the nearest, halves up."""
    return math.floor(microseconds / 10 + 0.5) * 10


def true_frequency(hz: float, rounding: str) -> float:
    """The frequency ``trigf`` runs at: its period a whole number of 40 µs ticks
    ("the resulting frequency might not always match", "?trigf ... the true value",
    L13240-13250, L13278). Whether the tick count is rounded to the nearest or down the
    manual does not say (switch ``trigf_round``: ``nearest``, ``down``)."""
    ticks = 1.0 / (hz * TICK)
    count = round(ticks) if rounding == "nearest" else math.floor(ticks + 1e-9)
    return 1.0 / (max(1, count) * TICK)


@dataclass(frozen=True, slots=True)
class OutputSettings:
    """What shapes a trigger event's pulses: ``trigo``, ``trigs`` and the precise
    timings of the secondary output."""

    #: ``trigo`` 0-15 (L12860-12949): bit 0 TRIGGER_OUT (OUT1), bit 1 TAKT_OUT (OUT2);
    #: ``outputs // 4`` the secondary output's function: 0 standard 1:1, 1 precise width,
    #: 2 precise delay, 3 precise frequency.
    outputs: int
    #: OUT1's width in seconds (``trigs``; 0 still sends a short spike, L14259-14261).
    width: float
    #: ``!trigs w d w2``'s delay and width of OUT2 in the 1:1 mode, seconds; ``None``:
    #: OUT2 the same as OUT1 (L12973-13001, L14271-14300).
    out2: tuple[float, float] | None = None
    #: ``trigbwidth`` in seconds (trigo 4-7, L13318-13350).
    precise_width: float = 40e-6
    #: ``trigbdelay`` in seconds (trigo 8-11, L13279-13316).
    precise_delay: float = 0.0

    @property
    def function(self) -> int:
        """The secondary output's function: 0 1:1, 1 width, 2 delay, 3 frequency."""
        return self.outputs // 4


def event_pulses(time: float, high: bool, settings: OutputSettings,
                 position: float | None = None) -> list[Pulse]:
    """The pulses one trigger event sends at ``time``: OUT1 for ``trigs``, OUT2 as its
    function says. Both share the polarity (L14251); trigo 12-15 drive OUT2 from its own
    clock (:class:`Clock`), not from the events (L14444-14476)."""
    pulses: list[Pulse] = []
    if settings.outputs & 1:
        pulses.append(Pulse(time, TRIGGER_OUT, settings.width, high, position))
    if not settings.outputs & 2 or settings.function == 3:
        return pulses
    start, width = time, settings.width
    if settings.function == 0 and settings.out2 is not None:
        # Delay and width of its own, but inactive latest when OUT1 ends: OUT2 "must be
        # within the active range of OUT1" (L12987-12990, L14282-14284). Choice: a delay
        # at or beyond OUT1's width leaves OUT2 without a pulse.
        delay, own = settings.out2
        if delay >= settings.width:
            return pulses
        start, width = time + delay, min(own, settings.width - delay)
    elif settings.function == 1:
        width = settings.precise_width  # starts with OUT1, may outlast it (L14337-14345)
    elif settings.function == 2:
        # A precise edge delay; the pulse is reset at the next 40 µs tick (counted from
        # OUT1's edge): "Pulses of 100ns up to 39µs may occur" (L14377-14394).
        start = time + settings.precise_delay
        width = TICK - math.fmod(settings.precise_delay, TICK)
    pulses.append(Pulse(start, TAKT_OUT, width, high, position))
    return pulses


@dataclass(slots=True)
class Clock:
    """A periodic source: ticks at ``start + k * period``; :meth:`due` hands out those not
    handed out yet."""

    start: float
    period: float
    #: How many ticks were handed out.
    done: int = 0

    def due(self, now: float) -> tuple[int, int]:
        """The first index and the count of the ticks at or before ``now`` not handed out
        yet (they count as handed out from here on)."""
        if now < self.start:
            return self.done, 0
        last = math.floor((now - self.start) / self.period * (1 + 1e-12) + 1e-9)
        first, count = self.done, max(0, last + 1 - self.done)
        self.done += count
        return first, count

    def time(self, index: int) -> float:
        """When tick ``index`` (from 0) comes."""
        return self.start + index * self.period
