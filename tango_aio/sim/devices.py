"""The emulated controller's I/O lines, encoders and trigger outputs: what a test sets
(input levels, encoders fitted, a joystick deflection) and what it reads back (the pulses
the trigger and TAKT outputs sent).

The model keeps one :class:`Devices`, cleared by a restart like the rest of its state.
The handlers change it through the model (:mod:`tango_aio.sim.port`); a test reaches it
as ``model.devices``. The record of pulses is bounded (:attr:`Devices.limit`): a periodic
output runs for hours at up to 66 MHz (L13353-13386), so the oldest pulses are dropped and
counted (:attr:`Devices.dropped`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

__all__ = ["TAKT_OUT", "TRIGGER_OUT", "Devices", "Drift", "Pulse"]

#: The primary trigger output (TRIGGER_OUT, L12860-12949).
TRIGGER_OUT = "trigger"
#: The AUX I/O TAKT_OUT pin: the secondary trigger output and ``!flash`` (L9861-9913).
TAKT_OUT = "takt"


@dataclass(frozen=True, slots=True)
class Pulse:
    """One pulse an output sent."""

    #: When it began (the emulator's clock, seconds).
    time: float
    #: Which output: :data:`TRIGGER_OUT` or :data:`TAKT_OUT`.
    output: str
    #: Its length in seconds.
    width: float
    #: ``True``: an active-high pulse; ``False``: active low.
    active_high: bool
    #: The trigger axis' motor position where it fired (user frame); ``None``: not by
    #: position.
    position: float | None = None


@dataclass(frozen=True, slots=True)
class Drift:
    """How an axis' encoder deviates from its motor position (user frame, the axis' dim
    unit): ``encoder = motor * (1 - slip) + offset``."""

    #: The fraction of the motor's travel the encoder does not see (0.01: 1 % less).
    slip: float = 0.0
    #: A constant deviation, in revolutions of the motor (set through
    #: ``ControllerModel.set_encoder_drift`` in the dim unit).
    offset: float = 0.0


@dataclass(slots=True)
class Devices:
    """The levels and records of the emulated I/O, encoders and trigger outputs."""

    #: Input levels by input group (``digin`` 24, ``edigin`` 12, ``adigin`` 4: L8573,
    #: L8825, L9120), 0 or 1 per input.
    inputs: dict[str, list[int]] = field(default_factory=lambda: {
        "digin": [0] * 24, "edigin": [0] * 12, "adigin": [0] * 4})
    #: ``anain`` counts (0..1023) by channel; channel 15 is the 2.5 V reference
    #: (L9340-9380). A channel not listed reads 0.
    analog: dict[int, int] = field(default_factory=lambda: {15: 512})
    #: Axes (indices) with an encoder fitted: ``encmask`` activates only these.
    encoders: set[int] = field(default_factory=set)
    #: Closed-loop position difference (motor minus encoder) by axis, in user units.
    position_error: dict[int, float] = field(default_factory=dict)
    #: The pulses sent, in the order they were recorded: the last :attr:`limit` (up to
    #: an eighth more between two trims).
    pulses: list[Pulse] = field(default_factory=list)
    #: How many pulses the record keeps; older ones are dropped.
    limit: int = 50_000
    #: How many pulses were dropped from the record, or never recorded beyond the limit.
    dropped: int = 0
    #: Each axis' encoder drift (index: :class:`Drift`); an axis not listed has none.
    drift: dict[int, Drift] = field(default_factory=dict)
    #: The joystick's deflection per axis (-1..1), while held.
    deflection: dict[int, float] = field(default_factory=dict)

    def set_input(self, group: str, index: int, level: bool) -> None:
        """Set input ``index`` (from 0) of ``group`` (``digin``, ``edigin``, ``adigin``):
        the level only; ``ControllerModel.set_input`` also acts on a snapshot input's edge."""
        self.inputs[group][index] = int(level)

    def record(self, pulses: Iterable[Pulse]) -> None:
        """Append ``pulses`` to the record, dropping the oldest beyond :attr:`limit`."""
        self.pulses.extend(pulses)
        excess = len(self.pulses) - self.limit
        if excess > self.limit // 8:
            del self.pulses[:excess]
            self.dropped += excess

    def pulses_of(self, output: str) -> list[Pulse]:
        """The pulses ``output`` (:data:`TRIGGER_OUT`, :data:`TAKT_OUT`) sent, in order."""
        return [pulse for pulse in self.pulses if pulse.output == output]
