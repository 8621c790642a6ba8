"""The blocking twins of the device families (``tango.joystick``, ``tango.io``, ...)."""

from __future__ import annotations

from collections.abc import (
    Iterator,
)

from ..events import InputsChanged, JoystickMoved
from ..families import IO as AsyncIO
from ..families import ClosedLoop as AsyncClosedLoop
from ..families import Encoders as AsyncEncoders
from ..families import Joystick as AsyncJoystick
from ..families import Snapshots as AsyncSnapshots
from ..families import Triggers as AsyncTriggers
from ._blocking import _Blocking, _Family


class Joystick(_Family[AsyncJoystick]):
    """The blocking twin of :class:`tango_aio.families.Joystick` (``tango.joystick``)."""

    enable = _Blocking(AsyncJoystick.enable)
    disable = _Blocking(AsyncJoystick.disable)
    is_enabled = _Blocking(AsyncJoystick.is_enabled)


class IO(_Family[AsyncIO]):
    """The blocking twin of :class:`tango_aio.families.IO` (``tango.io``)."""

    set_shutter = _Blocking(AsyncIO.set_shutter)
    shutter = _Blocking(AsyncIO.shutter)
    flash = _Blocking(AsyncIO.flash)
    set_analog_out = _Blocking(AsyncIO.set_analog_out)
    analog_out = _Blocking(AsyncIO.analog_out)
    analog_in = _Blocking(AsyncIO.analog_in)
    digital_in = _Blocking(AsyncIO.digital_in)
    set_digital_out = _Blocking(AsyncIO.set_digital_out)
    digital_out = _Blocking(AsyncIO.digital_out)

    def watch_inputs(self, interval: float = 0.1) -> Iterator[InputsChanged | JoystickMoved]:
        """Blocking iterator over :meth:`tango_aio.families.IO.watch_inputs`.

        Parameters
        ----------
        interval
            Seconds between two reads.

        Returns
        -------
        Iterator[InputsChanged | JoystickMoved]
            What changed, read in the driver's thread.
        """
        return self._portal.iterate(self.aio.watch_inputs(interval))


class Encoders(_Family[AsyncEncoders]):
    """The blocking twin of :class:`tango_aio.families.Encoders` (``tango.encoders``)."""

    mask = _Blocking(AsyncEncoders.mask)
    set_mask = _Blocking(AsyncEncoders.set_mask)
    active = _Blocking(AsyncEncoders.active)
    set_position_source = _Blocking(AsyncEncoders.set_position_source)
    position_error = _Blocking(AsyncEncoders.position_error)


class ClosedLoop(_Family[AsyncClosedLoop]):
    """The blocking twin of :class:`tango_aio.families.ClosedLoop` (``tango.closed_loop``)."""

    enable = _Blocking(AsyncClosedLoop.enable)
    mode = _Blocking(AsyncClosedLoop.mode)
    settle = _Blocking(AsyncClosedLoop.settle)


class Triggers(_Family[AsyncTriggers]):
    """The blocking twin of :class:`tango_aio.families.Triggers` (``tango.triggers``)."""

    read_config = _Blocking(AsyncTriggers.read_config)
    write_config = _Blocking(AsyncTriggers.write_config)
    enabled = _Blocking(AsyncTriggers.enabled)
    set_enabled = _Blocking(AsyncTriggers.set_enabled)
    count = _Blocking(AsyncTriggers.count)
    set_count = _Blocking(AsyncTriggers.set_count)
    fire = _Blocking(AsyncTriggers.fire)
    upload_positions = _Blocking(AsyncTriggers.upload_positions)
    read_positions = _Blocking(AsyncTriggers.read_positions)
    set_range = _Blocking(AsyncTriggers.set_range)


class Snapshots(_Family[AsyncSnapshots]):
    """The blocking twin of :class:`tango_aio.families.Snapshots` (``tango.snapshots``)."""

    read_config = _Blocking(AsyncSnapshots.read_config)
    write_config = _Blocking(AsyncSnapshots.write_config)
    count = _Blocking(AsyncSnapshots.count)
    upload_positions = _Blocking(AsyncSnapshots.upload_positions)
    read_positions = _Blocking(AsyncSnapshots.read_positions)
