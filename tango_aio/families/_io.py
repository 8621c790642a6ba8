"""Digital and analogue I/O, the shutter line, the LED strobe, and a
polling watch of the inputs and of the joystick's moves."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncGenerator, Mapping

from .._checks import check_timeout
from ..catalog import Form, build, wire_number
from ..errors import InvalidCommandError, SettingNotAppliedError
from ..events import InputsChanged, JoystickMoved, PositionUpdate
from ._generated import IOAccess
from ._reach import DevicePort

__all__ = ["IO"]

#: ``!flash``: 0.00001 ms (10 ns) to 32500 ms, either sign (L9861-9913).
FLASH_MS = (0.00001, 32500.0)
#: ``anaout`` channels and level in percent (L9453-9568).
ANALOG_OUT_CHANNELS = range(3)
#: ``anain`` channels (L9340-9452).
ANALOG_IN_CHANNELS = range(32)
#: ``digout`` outputs (L8579-8626).
DIGITAL_OUTPUTS = range(16)


def _flag(value: object, name: str) -> bool:
    if not isinstance(value, bool):
        raise InvalidCommandError(f"{name}: the level must be True or False, got {value!r}",
                                  instruction=name, parameter="level", number=5)
    return value


def _index(value: object, allowed: range, name: str, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value not in allowed:
        raise InvalidCommandError(
            f"{name}: {what} must be an integer {allowed.start}..{allowed.stop - 1}, "
            f"got {value!r}", instruction=name, parameter=what, number=5)
    return value


def _number(value: object, low: float, high: float, name: str, what: str) -> float:
    try:
        number = float(wire_number(value))
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    if not low <= number <= high:
        raise InvalidCommandError(f"{name}: {what} must be {low:g}..{high:g}, got {value!r}",
                                  instruction=name, parameter=what, number=5)
    return number


class IO(IOAccess):
    """Digital and analogue I/O (``tango.io``; manual chapter 17): the typed access of
    every I/O instruction (:class:`IOAccess`: input types and polarities, the stop input,
    brakes, the dispenser, ...) and the lines a microscope uses, with their checks.

    Every set is proven like any set of the driver (its error state, and a read-back
    where the controller can show the value); bad values raise
    :class:`~tango_aio.InvalidCommandError` before any byte is written.
    """

    _port: DevicePort

    # -- the shutter line and the LED strobe ------------------------------------------

    async def set_shutter(self, level: bool) -> None:
        """Set the AUX I/O shutter output (``!shutter``, L9837-9860): ``True`` TTL high.

        Parameters
        ----------
        level
            The level.

        Raises
        ------
        InvalidCommandError
            ``level`` is not a bool.
        SettingNotAppliedError
            The read-back shows another level.
        """
        await self._port.set("shutter", int(_flag(level, "shutter")))

    async def shutter(self) -> bool:
        """The shutter output's level (``?shutter``).

        Returns
        -------
        bool
            ``True``: TTL high.
        """
        return int(await self._port.get("shutter")) == 1

    async def flash(self, ms: float) -> None:
        """Send one pulse on the AUX I/O TAKT_OUT pin, e.g. to an LED strobe (``!flash``,
        L9861-9913): ``ms`` milliseconds long, 0.00001 (10 ns) to 32500; a positive value
        is an active-high pulse, a negative one active low. Nothing reads a pulse back:
        the controller's error state proves the line.

        Parameters
        ----------
        ms
            The pulse length in ms, its sign the polarity.

        Raises
        ------
        InvalidCommandError
            The length is out of range, before anything is written.
        """
        try:
            value = float(wire_number(ms))
        except (TypeError, ValueError, OverflowError):
            value = math.nan
        _number(abs(value), *FLASH_MS, "flash", "duration")
        await self._port.command(build("flash", value).line)

    # -- analogue ------------------------------------------------------------------------

    async def set_analog_out(self, channel: int, percent: float) -> None:
        """Set analogue output ``channel`` (0..2) to ``percent`` of its range
        (``!anaout c channel level``, L9453-9568), then read it back (``?anaout c
        channel``) at the two decimals the controller prints.

        Parameters
        ----------
        channel
            The output, 0..2.
        percent
            The level, 0..100 %.

        Raises
        ------
        InvalidCommandError
            A value out of range, before anything is written.
        SettingNotAppliedError
            The read-back shows another level.
        """
        index = _index(channel, ANALOG_OUT_CHANNELS, "anaout", "channel")
        level = _number(percent, 0.0, 100.0, "anaout", "level")
        line = build("anaout", "c", index, level)
        await self._port.command(line.line)
        held = await self.analog_out(index)
        if abs(held - level) > 0.0051:
            raise SettingNotAppliedError(line.line, instruction="anaout", axis=None,
                                         sent=f"{level:g}", read=f"?anaout c {index}",
                                         held=f"{held:.2f}")

    async def analog_out(self, channel: int) -> float:
        """The level of analogue output ``channel`` in percent (``?anaout c channel``).

        Parameters
        ----------
        channel
            The output, 0..2.

        Returns
        -------
        float
            Its level, 0..100 %.
        """
        index = _index(channel, ANALOG_OUT_CHANNELS, "anaout", "channel")
        reply = await self._port.query(build("anaout", "c", index, form=Form.READ).line)
        return float(reply.split()[0])

    async def analog_in(self, channel: int) -> float:
        """Analogue input ``channel`` in converter counts, 0..1023, at the converter's
        resolution (``?anain v channel``, L9340-9452; channel 15 is the 2.5 V reference).

        Parameters
        ----------
        channel
            The input, 0..31.

        Returns
        -------
        float
            Its counts.
        """
        index = _index(channel, ANALOG_IN_CHANNELS, "anain", "channel")
        return float(await self._port.get("anain", "v", index))

    # -- digital -------------------------------------------------------------------------

    async def digital_in(self) -> tuple[bool, ...]:
        """The level of every digital input of the I/O connector (``?digin``,
        L8538-8578), input 0 first.

        Returns
        -------
        tuple[bool, ...]
            One level per input.
        """
        reply = await self._port.query("?digin")
        return tuple(char == "1" for char in reply.strip())

    async def set_digital_out(self, output: int, level: bool) -> None:
        """Set one digital output (``!digout output state``, L8579-8626), proven by the
        read of every output.

        Parameters
        ----------
        output
            The output, 0..15.
        level
            Its level.

        Raises
        ------
        InvalidCommandError
            A value out of range, before anything is written.
        SettingNotAppliedError
            The outputs read back show another level.
        """
        index = _index(output, DIGITAL_OUTPUTS, "digout", "output")
        state = _flag(level, "digout")
        line = build("digout", index, int(state))
        await self._port.command(line.line)
        held = await self.digital_out()
        if len(held) <= index or held[index] != state:
            raise SettingNotAppliedError(line.line, instruction="digout", axis=None,
                                         sent=str(int(state)), read="?digout",
                                         held="".join(str(int(h)) for h in held))

    async def digital_out(self) -> tuple[bool, ...]:
        """The level of every digital output (``?digout``), output 0 first.

        Returns
        -------
        tuple[bool, ...]
            One level per output.
        """
        reply = await self._port.query("?digout")
        return tuple(char == "1" for char in reply.strip())

    # -- a watch of the inputs and the joystick -----------------------------------------------

    async def watch_inputs(self, interval: float = 0.1
                           ) -> AsyncGenerator[InputsChanged | JoystickMoved, None]:
        """Poll the digital inputs and the stage every ``interval`` seconds until the
        caller stops iterating; yield (and publish to ``events()``)
        :class:`~tango_aio.events.InputsChanged` when an input changed, and
        :class:`~tango_aio.events.JoystickMoved` (with a
        :class:`~tango_aio.events.PositionUpdate`) when the stage moved while no move of
        this driver ran, the joystick's doing. The controller reports neither by itself.
        Each read of the stage also becomes ``last_positions()``.

        Parameters
        ----------
        interval
            Seconds between two reads.

        Yields
        ------
        InputsChanged or JoystickMoved
            What changed.
        """
        check_timeout(interval, "interval")
        levels: tuple[bool, ...] | None = None
        texts: Mapping[str, str] | None = None
        while True:
            now = await self.digital_in()
            if levels is not None and now != levels:
                changed = tuple(i for i, (a, b) in enumerate(zip(levels, now, strict=False))
                                if a != b)
                event: InputsChanged | JoystickMoved = InputsChanged(now, changed)
                self._port._publish_event(event)
                yield event
            levels = now
            driven = self._port._in_motion()
            _, positions = await self._port._status_and_positions()
            driven = driven or self._port._in_motion()
            if texts is not None and positions != texts and not driven:
                values = await self._port._user_positions(positions)
                self._port._publish_event(PositionUpdate(values))
                event = JoystickMoved(values)
                self._port._publish_event(event)
                yield event
            # A move of this driver is not the joystick's: compare from after its end.
            texts = None if driven else positions
            await asyncio.sleep(interval)
