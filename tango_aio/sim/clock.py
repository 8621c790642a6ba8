"""Time between the serving layers and the controller logic.

The wire and the serving layers run on the *host's clock*: the running event loop's
(``loop.time()``; under uvloop this is not ``time.monotonic()``). :func:`host_now` reads
it, and the emulator's clock starts from it.

The controller logic may run faster than the host: with ``speed`` 20 (``sim://?speed=20``,
``tango-aio sim --speed 20``) :class:`ScaledHandler` hands it *emulator time*, which runs
20 times as fast from a common origin. Everything timed inside the controller (motion,
``!pause`` and ``!delay``, calibration and range-measure timeouts, the second a ``reset``
takes) then takes 1/20 of the time, while the wire keeps its timing: baud rate, reply
latency, processing time per line and stalls are link properties in host seconds.
Emulator time equals host time at the origin, so timestamps stay comparable.
"""

from __future__ import annotations

import asyncio
import math
import time

from .wire import Emit, HandlerFactory, LineHandler

__all__ = ["EmulatorClock", "ScaledHandler", "check_speed", "host_now", "scaled_factory"]


def host_now() -> float:
    """The host's clock: the running event loop's time, else ``time.monotonic()``."""
    try:
        return asyncio.get_running_loop().time()
    except RuntimeError:
        return time.monotonic()


def check_speed(speed: float) -> float:
    """``speed`` as a float if it is a finite number > 0, else a ValueError saying so."""
    value = float(speed)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"speed must be a finite number > 0, got {speed!r}")
    return value


class EmulatorClock:
    """Converts host time to emulator time and back: ``speed`` times as fast from ``origin``."""

    def __init__(self, speed: float, origin: float) -> None:
        self.speed = check_speed(speed)
        """Emulator seconds per host second."""
        self.origin = origin
        """The instant (both clocks) where they agree."""

    def to_emulator(self, host: float) -> float:
        """The emulator time at host time ``host``."""
        return self.origin + (host - self.origin) * self.speed

    def to_host(self, emulator: float) -> float:
        """The earliest host time whose emulator time is not before ``emulator``."""
        host = self.origin + (emulator - self.origin) / self.speed
        while self.to_emulator(host) < emulator:
            host = math.nextafter(host, math.inf)
        return host


class ScaledHandler:
    """A :class:`~tango_aio.sim.wire.LineHandler` that runs the controller logic built by
    ``make_handler`` on emulator time (see the module docstring)."""

    def __init__(self, make_handler: HandlerFactory, emit: Emit, speed: float,
                 origin: float | None = None) -> None:
        self.handler: LineHandler = make_handler(emit)
        """The controller logic (e.g. the :class:`~tango_aio.sim.model.ControllerModel`)."""
        self.clock = EmulatorClock(speed, host_now() if origin is None else origin)
        """The conversion between the wire's time and the logic's."""
        # What the wire asks its handler, passed on from the logic (the wire reads these
        # once, with getattr: without them a scaled emulator ignored ctrl_c=ignore).
        self.ctrl_c_stops: bool = getattr(self.handler, "ctrl_c_stops", True)
        """Whether Ctrl+C bypasses the parser (the logic's answer)."""
        self.local_echo: bool = getattr(self.handler, "local_echo", False)
        """Whether the link echoes every byte sent (the logic's answer)."""

    def reboots(self, line: bytes) -> bool:
        """Whether ``line`` restarts the controller (the logic's answer, if it has one)."""
        ask = getattr(self.handler, "reboots", None)
        return bool(ask(line)) if ask is not None else False

    def reboot(self, now: float) -> None:
        """Restart the logic as at power-on (if it can), at emulator time."""
        restart = getattr(self.handler, "reboot", None)
        if restart is not None:
            restart(self.clock.to_emulator(now))

    def handle_line(self, line: bytes, now: float) -> None:
        """Execute one line at emulator time."""
        self.handler.handle_line(line, self.clock.to_emulator(now))

    def line_too_long(self, head: bytes, now: float) -> None:
        """Report an over-long line at emulator time."""
        self.handler.line_too_long(head, self.clock.to_emulator(now))

    def ctrl_c(self, now: float) -> None:
        """Ctrl+C at emulator time."""
        self.handler.ctrl_c(self.clock.to_emulator(now))

    def processing_time(self, line: bytes) -> float:
        """The logic's extra interpreter time (e.g. a reset), in host seconds."""
        return self.handler.processing_time(line) / self.clock.speed

    def poll(self, now: float) -> None:
        """Advance the logic to emulator time."""
        self.handler.poll(self.clock.to_emulator(now))

    def next_deadline(self) -> float | None:
        """The logic's next deadline, in host time."""
        deadline = self.handler.next_deadline()
        return None if deadline is None else self.clock.to_host(deadline)


def scaled_factory(make_handler: HandlerFactory, speed: float) -> HandlerFactory:
    """``make_handler`` with its logic on emulator time; unchanged at speed 1."""
    speed = check_speed(speed)
    if speed == 1.0:
        return make_handler

    def make(emit: Emit) -> LineHandler:
        return ScaledHandler(make_handler, emit, speed)

    return make
