"""The blocking twins of the controller's families (``tango.settings``, ``tango.info``,
``tango.joystick``, ``tango.io``, ...), each built on the twins of its accessor classes."""

from __future__ import annotations

from collections.abc import (
    Iterator,
)

from ..events import InputsChanged, JoystickMoved
from ..families import IO as AsyncIO
from ..families import ClosedLoop as AsyncClosedLoop
from ..families import Encoders as AsyncEncoders
from ..families import Info as AsyncInfo
from ..families import Joystick as AsyncJoystick
from ..families import Settings as AsyncSettings
from ..families import SettingsSnapshot
from ..families import Snapshots as AsyncSnapshots
from ..families import Triggers as AsyncTriggers
from ._blocking import _Blocking
from ._generated import (
    AdjustmentsAccess,
    CalibrationAccess,
    ClosedLoopAccess,
    CommunicationAccess,
    ControllerInfoAccess,
    EncoderAccess,
    IOAccess,
    JoystickAccess,
    LimitSwitchAccess,
    MREncoderAccess,
    OperatingModesAccess,
    SnapshotAccess,
    SystemAccess,
    TriggerAccess,
)


class Settings(CommunicationAccess[AsyncSettings], SystemAccess[AsyncSettings],
               OperatingModesAccess[AsyncSettings], AdjustmentsAccess[AsyncSettings],
               LimitSwitchAccess[AsyncSettings], CalibrationAccess[AsyncSettings]):
    """The blocking twin of :class:`tango_aio.families.Settings` (``tango.settings``)."""

    unit_scales = _Blocking(AsyncSettings.unit_scales)
    velocity = _Blocking(AsyncSettings.velocity)
    set_velocity = _Blocking(AsyncSettings.set_velocity)
    acceleration = _Blocking(AsyncSettings.acceleration)
    set_acceleration = _Blocking(AsyncSettings.set_acceleration)
    limits = _Blocking(AsyncSettings.limits)
    set_limits = _Blocking(AsyncSettings.set_limits)
    snapshot = _Blocking(AsyncSettings.snapshot)
    diff = _Blocking(AsyncSettings.diff)
    restore = _Blocking(AsyncSettings.restore)
    save = _Blocking(AsyncSettings.save)
    reload = _Blocking(AsyncSettings.reload)
    factory_reset = _Blocking(AsyncSettings.factory_reset)
    reset = _Blocking(AsyncSettings.reset)

    def check(self, snapshot: SettingsSnapshot) -> None:
        """:meth:`tango_aio.families.Settings.check`, in the caller's thread (it reads only
        the identity and the context the driver holds, no line is written).

        Parameters
        ----------
        snapshot
            The snapshot to check against this controller.

        Raises
        ------
        SnapshotMismatchError
            The snapshot is of another model, or has axes this controller lacks.
        """
        self.aio.check(snapshot)


class Info(ControllerInfoAccess[AsyncInfo]):
    """The blocking twin of :class:`tango_aio.families.Info` (``tango.info``)."""

    read = _Blocking(AsyncInfo.read)


class Joystick(JoystickAccess[AsyncJoystick]):
    """The blocking twin of :class:`tango_aio.families.Joystick` (``tango.joystick``)."""

    enable = _Blocking(AsyncJoystick.enable)
    disable = _Blocking(AsyncJoystick.disable)
    is_enabled = _Blocking(AsyncJoystick.is_enabled)


class IO(IOAccess[AsyncIO]):
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


class Encoders(EncoderAccess[AsyncEncoders], MREncoderAccess[AsyncEncoders]):
    """The blocking twin of :class:`tango_aio.families.Encoders` (``tango.encoders``)."""

    mask = _Blocking(AsyncEncoders.mask)
    set_mask = _Blocking(AsyncEncoders.set_mask)
    active = _Blocking(AsyncEncoders.active)
    set_position_source = _Blocking(AsyncEncoders.set_position_source)
    position_error = _Blocking(AsyncEncoders.position_error)


class ClosedLoop(ClosedLoopAccess[AsyncClosedLoop]):
    """The blocking twin of :class:`tango_aio.families.ClosedLoop` (``tango.closed_loop``)."""

    enable = _Blocking(AsyncClosedLoop.enable)
    mode = _Blocking(AsyncClosedLoop.mode)
    settle = _Blocking(AsyncClosedLoop.settle)


class Triggers(TriggerAccess[AsyncTriggers]):
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


class Snapshots(SnapshotAccess[AsyncSnapshots]):
    """The blocking twin of :class:`tango_aio.families.Snapshots` (``tango.snapshots``)."""

    read_config = _Blocking(AsyncSnapshots.read_config)
    write_config = _Blocking(AsyncSnapshots.write_config)
    count = _Blocking(AsyncSnapshots.count)
    upload_positions = _Blocking(AsyncSnapshots.upload_positions)
    read_positions = _Blocking(AsyncSnapshots.read_positions)
