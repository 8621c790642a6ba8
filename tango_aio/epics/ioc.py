"""The Channel Access IOC: TANGO axes as motor records, served by caproto.

For each controller (prefix ``P:``, or ``P:name:`` with several controllers):

* ``P:X`` ... ``P:A``: a motor record per present axis (see :mod:`.record` for units).
  A put to VAL starts the move (through a :class:`~tango_aio.coalesce.MoveCoalescer`,
  so puts to different axes that arrive together become one ``!moa`` line); a put with
  callback completes when the move has ended, after RBV and DMOV were published. A move
  that fails (status E, S or T, a controller error, a lost link) fails the put and puts
  the record in a WRITE/MAJOR alarm until the next successful move.
* ``P:CONNECTED`` (0/1), ``P:ERROR`` (number of the last error: the controller's error
  number, -1 for a failure without one, 0 none), ``P:ERROR:TEXT``, ``P:AUTOSTATUS``,
  ``P:TRIGCOUNT``.

One poller per controller reads ``?pos`` and ``?statusaxis`` every ``poll`` seconds and
``?readsw``, ``?statuslimit`` and ``?trigcount`` every fifth time. While the link is down
every PV but CONNECTED is in an INVALID/COMM alarm; when the driver has reconnected
(``connect(url, reconnect=True)``) the settings are read again and the alarms clear.

Choices (the motor record documentation leaves room, the TANGO has no such concepts):

* STOP, and SPMG set to Stop or Pause, send ``!a <axis>`` (L6785: abort one axis). The
  stopped move's put then fails: the target was not reached. While SPMG is Stop or Pause
  a put to VAL is refused (Pause does not hold the move for a later Go).
* HOMR runs ``cal`` (reverse, to the lower limit switch, sets the origin, L5259), HOMF
  runs ``rm`` (forward, to the upper limit switch, sets the upper limit, L5343).
* SET=Set: a put to VAL redefines the position instead of moving; with FOFF=Variable the
  user offset OFF changes, with FOFF=Frozen the controller's position is set (``!pos``,
  L6900).
* HLM/LLM and DHLM/DLLM are the controller's soft limits (``!lim``, L4522); a VAL outside
  them is refused before anything is sent (LVIO=1).
* VELO sets ``vel``; ACCL sets ``accel`` so that VELO is reached in ACCL seconds; a new
  VELO keeps ``accel`` (ACCL is recomputed).
* CNEN Enable/Disable sends ``!axis <axis> 1`` / ``0`` (L3919: a disabled axis keeps its
  motor current, so a vertical axis does not drop; ``-1``, power off, is never sent).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

from caproto import AccessRights, AlarmSeverity, AlarmStatus, CAStatus, Forbidden
from caproto.asyncio.server import Context
from caproto.server import PVGroup, pvproperty
from caproto.server.menus import motorSPMG, motorTORQ
from caproto.server.records import MotorFields, register_record
from caproto.server.server import (
    PvpropertyDouble,
    PvpropertyEnum,
    PvpropertyShort,
)

from ..coalesce import MoveCoalescer
from ..controller import Controller
from ..errors import ConnectionLostError, ControllerError, MoveError, TangoError
from ..instructions import AXES, lookup
from ..motion import FAILED_LETTERS
from .access import AccessPolicy
from .record import AxisUnits, LimitSwitches, calibrated, limit_switches, msta

__all__ = ["MotorRefusedError", "TangoIoc", "build_ioc"]

log = logging.getLogger("tango_aio.epics")

#: The fields that show the link's INVALID alarm with the record.
READBACK_FIELDS = ("RBV", "DRBV", "DMOV", "MOVN", "MSTA", "HLS", "LLS")

#: How many polls of ``?pos``/``?statusaxis`` per read of switches and counters.
SLOW_EVERY = 5


class MotorRefusedError(TangoError, ValueError):
    """A motor-record request that was refused before anything was sent (a target
    outside the limits, SPMG in Stop or Pause, the link down)."""


class MoveStoppedError(TangoError):
    """The move was stopped (STOP or SPMG) before it reached its target."""


# ---------------------------------------------------------------------------- the record


def _axis_of(fields: Any) -> AxisServer:
    """The :class:`AxisServer` behind a record's field group."""
    axis: AxisServer = fields.parent.group.axis
    return axis


async def _put_stop(fields: Any, instance: Any, value: int) -> int:
    if value:
        await _axis_of(fields).stop()
    return 0


async def _put_spmg(fields: Any, instance: Any, value: str) -> str:
    if value in ("Stop", "Pause"):
        await _axis_of(fields).stop()
    return value


async def _put_velo(fields: Any, instance: Any, value: float) -> float:
    return await _axis_of(fields).set_velocity(float(value))


async def _put_accl(fields: Any, instance: Any, value: float) -> float:
    return await _axis_of(fields).set_acceleration_time(float(value))


async def _put_hlm(fields: Any, instance: Any, value: float) -> float:
    dial = float(value) - fields.user_offset.value
    return await _axis_of(fields).set_limit(high=True, dial=dial)


async def _put_llm(fields: Any, instance: Any, value: float) -> float:
    dial = float(value) - fields.user_offset.value
    return await _axis_of(fields).set_limit(high=False, dial=dial)


async def _put_dhlm(fields: Any, instance: Any, value: float) -> float:
    await _axis_of(fields).set_limit(high=True, dial=float(value))
    return value


async def _put_dllm(fields: Any, instance: Any, value: float) -> float:
    await _axis_of(fields).set_limit(high=False, dial=float(value))
    return value


async def _put_twf(fields: Any, instance: Any, value: int) -> int:
    if value:
        await _axis_of(fields).tweak(+1)
    return 0


async def _put_twr(fields: Any, instance: Any, value: int) -> int:
    if value:
        await _axis_of(fields).tweak(-1)
    return 0


async def _put_homf(fields: Any, instance: Any, value: int) -> int:
    if value:
        await _axis_of(fields).home(forward=True)
    return 0


async def _put_homr(fields: Any, instance: Any, value: int) -> int:
    if value:
        await _axis_of(fields).home(forward=False)
    return 0


async def _put_off(fields: Any, instance: Any, value: float) -> float:
    await _axis_of(fields).offset_changed(float(value))
    return value


async def _put_cnen(fields: Any, instance: Any, value: str) -> str:
    await _axis_of(fields).set_enabled(value == "Enable")
    return value


@register_record
class TangoMotorFields(MotorFields):  # type: ignore[misc]
    """The motor record's fields, with handlers that drive a TANGO axis.

    Registered under its own record type name, so caproto's plain ``motor`` record is left
    alone; RTYP still reads ``motor``. (A field's handler can only be replaced by declaring
    the field again in a subclass.)
    """

    _record_type = "tango_motor"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.record_type._data["value"] = "motor"
        self.parent.reported_record_type = "motor"

    stop = pvproperty(name="STOP", dtype=PvpropertyShort, doc="Stop", put=_put_stop)
    stop_pause_move_go = pvproperty(name="SPMG", dtype=PvpropertyEnum, value=3,
                                    enum_strings=motorSPMG.get_string_tuple(),
                                    doc="Stop/Pause/Move/Go", put=_put_spmg)
    velocity = pvproperty(name="VELO", dtype=PvpropertyDouble, doc="Velocity (EGU/s)",
                          put=_put_velo)
    seconds_to_velocity = pvproperty(name="ACCL", dtype=PvpropertyDouble, value=0.2,
                                     doc="Seconds to Velocity", put=_put_accl)
    user_high_limit = pvproperty(name="HLM", dtype=PvpropertyDouble, doc="User High Limit",
                                 put=_put_hlm)
    user_low_limit = pvproperty(name="LLM", dtype=PvpropertyDouble, doc="User Low Limit",
                                put=_put_llm)
    dial_high_limit = pvproperty(name="DHLM", dtype=PvpropertyDouble, doc="Dial High Limit",
                                 put=_put_dhlm)
    dial_low_limit = pvproperty(name="DLLM", dtype=PvpropertyDouble, doc="Dial Low Limit",
                                put=_put_dllm)
    tweak_motor_forward = pvproperty(name="TWF", dtype=PvpropertyShort,
                                     doc="Tweak motor Forward", put=_put_twf)
    tweak_motor_reverse = pvproperty(name="TWR", dtype=PvpropertyShort,
                                     doc="Tweak motor Reverse", put=_put_twr)
    home_forward = pvproperty(name="HOMF", dtype=PvpropertyShort, doc="Home Forward",
                              put=_put_homf)
    home_reverse = pvproperty(name="HOMR", dtype=PvpropertyShort, doc="Home Reverse",
                              put=_put_homr)
    user_offset = pvproperty(name="OFF", dtype=PvpropertyDouble, doc="User Offset (EGU)",
                             put=_put_off)
    enable_control = pvproperty(name="CNEN", dtype=PvpropertyEnum, value=1,
                                enum_strings=motorTORQ.get_string_tuple(),
                                doc="Enable control", put=_put_cnen)


async def _put_val(group: AxisGroup, instance: Any, value: float) -> float:
    await group.axis.move(float(value))
    return value


class AxisGroup(PVGroup):  # type: ignore[misc]
    """One motor record (the PV is the group's prefix, e.g. ``P:X``)."""

    motor = pvproperty(name="", value=0.0, record="tango_motor", precision=4,
                       doc="TANGO axis", put=_put_val)

    def __init__(self, prefix: str, *, axis: AxisServer) -> None:
        self.axis = axis
        super().__init__(prefix)


class ControllerGroup(PVGroup):  # type: ignore[misc]
    """The PVs of one controller (``P:CONNECTED`` ...)."""

    connected = pvproperty(name="CONNECTED", value=0, read_only=True,
                           doc="1 while the link to the controller is up")
    error = pvproperty(name="ERROR", value=0, read_only=True,
                       doc="last error: controller error number, -1 other, 0 none")
    error_text = pvproperty(name="ERROR:TEXT", value="", max_length=256,
                            report_as_string=True, read_only=True,
                            doc="text of the last error")
    autostatus = pvproperty(name="AUTOSTATUS", value=0, read_only=True,
                            doc="autostatus mode in force")
    trigcount = pvproperty(name="TRIGCOUNT", value=0, read_only=True,
                           doc="trigger events generated (?trigcount)")


# ------------------------------------------------------------------------------ the axes


def _fields(record: Any) -> Any:
    return record.field_inst


class AxisServer:
    """Drives one axis for its motor record and publishes what the poller reads."""

    def __init__(self, server: ControllerServer, letter: str) -> None:
        self.server = server
        self.letter = letter
        self.units = AxisUnits()
        self.group = AxisGroup(f"{server.prefix}{letter.upper()}", axis=self)
        self.record: Any = self.group.motor
        self._busy = 0
        self._stop_requested = False
        self._problem = False
        self._switches = LimitSwitches()
        self._homed = False
        self._dial = 0.0
        self._positive = True
        self._motion: asyncio.Future[Any] | None = None

    async def _set_alarm(self, status: AlarmStatus, severity: AlarmSeverity) -> None:
        """Set the record's alarm and that of its readback fields (RBV shows INVALID too).

        The fields keep alarms of their own: caproto re-applies a channel's own alarm
        state when it is written, so a shared alarm would be reset by the next RBV.
        """
        fields = self.record.fields
        channels = [self.record, *(fields[name] for name in READBACK_FIELDS)]
        for channel in channels:
            await channel.alarm.write(status=status, severity=severity)

    @property
    def controller(self) -> Controller:
        """The axis's controller."""
        return self.server.controller

    @property
    def _f(self) -> Any:
        return _fields(self.record)

    # -- motion --------------------------------------------------------------------------

    async def move(self, target: float) -> None:
        """VAL was put: move there (or redefine the position with SET=Set)."""
        self._require_link()
        f = self._f
        if f.stop_pause_move_go.value in ("Stop", "Pause"):
            raise MotorRefusedError(f"{self.record.pvname}: SPMG is "
                                    f"{f.stop_pause_move_go.value}; set it to Go to move")
        if not math.isfinite(target):
            raise MotorRefusedError(f"{self.record.pvname}: target {target!r} is not finite")
        if f.set_use_switch.value == "Set":
            await self._redefine(target)
            return
        dial = target - f.user_offset.value
        await self._check_limits(dial)
        self._positive = dial >= self._dial
        await f.dial_desired_value.write(dial)
        await self._run(lambda: self.server.coalescer.move_to(self.letter, dial))

    async def _check_limits(self, dial: float) -> None:
        f = self._f
        low, high = f.dial_low_limit.value, f.dial_high_limit.value
        inside = (low == high == 0.0) or low <= dial <= high
        await f.limit_violation.write(0 if inside else 1)
        if not inside:
            raise MotorRefusedError(f"{self.record.pvname}: dial target {dial} outside the "
                                    f"limits [{low}, {high}]")

    async def _run(self, motion: Callable[[], Awaitable[Any]]) -> None:
        """Run ``motion`` with DMOV=0; publish RBV, then DMOV=1, before returning.

        The motion runs in a task of its own, which :meth:`stop` cancels: a move not yet
        sent is withdrawn, a running one is stopped (by the coalescer or the controller).
        """
        f = self._f
        self._busy += 1
        self._stop_requested = False
        await f.done_moving_to_value.write(0)
        await f.motor_is_moving.write(1)
        task = self._motion = asyncio.ensure_future(motion())
        try:
            try:
                await asyncio.wait([task])
            except asyncio.CancelledError:  # the IOC shuts down: stop the move
                task.cancel()
                await asyncio.wait([task])
                raise
            if task.cancelled() or self._stop_requested:
                raise MoveStoppedError(f"{self.record.pvname}: stopped before the target")
            try:
                task.result()
            except MoveError as exc:
                # A merged move reports every axis: this one may have arrived anyway.
                if exc.statuses.get(self.letter, "E") in FAILED_LETTERS:
                    raise
        except TangoError:
            self._problem = True
            raise
        else:
            self._problem = False
            if self.server.link_up:
                await self.record.alarm.write(status=AlarmStatus.NO_ALARM,
                                              severity=AlarmSeverity.NO_ALARM)
        finally:
            self._busy -= 1
            with contextlib.suppress(TangoError):
                await self._publish_dial(await self.controller.get("pos", axis=self.letter))
            if not self._busy:
                await f.motor_is_moving.write(0)
                await f.done_moving_to_value.write(1)
                await self._publish_status()

    async def stop(self) -> None:
        """STOP, or SPMG Stop/Pause: stop this axis and return once it stands still.

        A move this IOC started is cancelled (a merged move then stops as a whole, its
        other axes' puts fail too); otherwise ``!a <axis>`` (L6785) is sent.
        """
        self._require_link()
        task = self._motion
        if task is not None and not task.done():
            self._stop_requested = True
            task.cancel()
            await asyncio.wait([task])
        else:
            await self.controller.command(f"!a {self.letter}")

    async def tweak(self, sign: int) -> None:
        """TWF/TWR: move VAL by TWV."""
        f = self._f
        target = self.record.value + sign * abs(f.tweak_step_size.value)
        await self.record.write(target)

    async def home(self, *, forward: bool) -> None:
        """HOMF: ``rm`` (upper switch); HOMR: ``cal`` (lower switch)."""
        self._require_link()
        if self._f.stop_pause_move_go.value in ("Stop", "Pause"):
            raise MotorRefusedError(f"{self.record.pvname}: SPMG is not Go")
        run = self.controller.measure_range if forward else self.controller.calibrate
        try:
            await self._run(lambda: run(self.letter))
        finally:
            with contextlib.suppress(TangoError):
                await self._read_limits()
            await self.record.write(self.record.fields["RBV"].value, verify_value=False)

    async def _redefine(self, target: float) -> None:
        f = self._f
        if f.offset_freeze_switch.value == "Frozen":
            await self.controller.command(f"!pos {self.letter} {target - f.user_offset.value}")
            await self._publish_dial(await self.controller.get("pos", axis=self.letter))
        else:
            await f.user_offset.write(target - self._dial)

    # -- settings ------------------------------------------------------------------------

    async def set_velocity(self, velo: float) -> float:
        """VELO was put: set ``vel``; returns the VELO the controller took."""
        self._require_link()
        await self.controller.set("vel", round(self.units.vel_from_velo(velo), 6),
                                  axis=self.letter)
        await self._read_speed()
        value: float = self._f.velocity.value
        return value

    async def set_acceleration_time(self, accl: float) -> float:
        """ACCL was put: set ``accel`` so VELO is reached in ``accl`` seconds."""
        self._require_link()
        try:
            accel = self.units.accel_from_accl(self._f.velocity.value, accl)
        except ValueError as exc:
            raise MotorRefusedError(str(exc)) from None
        await self.controller.set("accel", round(accel, 6), axis=self.letter)
        await self._read_speed()
        value: float = self._f.seconds_to_velocity.value
        return value

    async def set_limit(self, *, high: bool, dial: float) -> float:
        """HLM/LLM/DHLM/DLLM was put: set the controller's soft limits (``!lim``)."""
        self._require_link()
        f = self._f
        low, up = f.dial_low_limit.value, f.dial_high_limit.value
        low, up = (low, dial) if high else (dial, up)
        await self.controller.command(f"!lim {self.letter} {low} {up}")
        await self._read_limits()
        limit: float = (f.user_high_limit if high else f.user_low_limit).value
        return limit

    async def offset_changed(self, offset: float) -> None:
        """OFF changed: republish every user value (user = dial + OFF)."""
        f = self._f
        await f.user_readback_value.write(self._dial + offset)
        await f.user_high_limit.write(f.dial_high_limit.value + offset, verify_value=False)
        await f.user_low_limit.write(f.dial_low_limit.value + offset, verify_value=False)
        await self._publish_drive_limits(offset)

    async def set_enabled(self, enabled: bool) -> None:
        """CNEN was put: ``!axis x 1`` or ``!axis x 0`` (L3919)."""
        self._require_link()
        await self.controller.command(f"!axis {self.letter} {1 if enabled else 0}")

    def _require_link(self) -> None:
        if not self.server.link_up:
            raise MotorRefusedError(f"{self.record.pvname}: the controller is not connected")

    # -- reading -------------------------------------------------------------------------

    async def read_settings(self) -> None:
        """Read units, speeds, limits, enable state and position (at start, reconnect)."""
        c, axis = self.controller, self.letter
        self.units = AxisUnits(int(await c.get("dim", axis=axis)),
                               float(await c.get("pitch", axis=axis)),
                               float(await self._optional("gear", 1.0, axis=axis)),
                               int(await self._optional("usteps", 40000)))
        f = self._f
        precision = int(await self._optional("resolution", 4))
        await self.record.write_metadata(units=self.units.egu, precision=precision)
        await f.engineering_units.write(self.units.egu)
        for field in ("RBV", "DRBV", "DVAL", "HLM", "LLM", "DHLM", "DLLM"):
            await self.record.fields[field].write_metadata(precision=precision,
                                                           units=self.units.egu)
        await self._read_speed()
        await self._read_limits()
        enabled = int(await c.get("axis", axis=axis)) == 1
        await f.enable_control.write("Enable" if enabled else "Disable", verify_value=False)
        await self._publish_dial(await c.get("pos", axis=axis))
        await self.record.write(self.record.fields["RBV"].value, verify_value=False)

    async def _optional(self, name: str, default: float, axis: str | None = None) -> Any:
        """Read ``name``; a controller that refuses it (older firmware may lack gear,
        usteps or resolution) gives ``default``, with a warning."""
        try:
            return await self.controller.get(name, axis=axis)
        except ControllerError as exc:
            log.warning("%s: ?%s refused (%s); assuming %s", self.record.pvname, name, exc,
                        default)
            return default

    async def _read_speed(self) -> None:
        c, axis, f = self.controller, self.letter, self._f
        velo = self.units.velo_from_vel(float(await c.get("vel", axis=axis)))
        accel = float(await c.get("accel", axis=axis))
        spec = lookup("vel").write[0].per_axis[0]
        top = spec.hi_dim9 if self.units.dim == 9 and spec.hi_dim9 else spec.hi
        await f.velocity.write(velo, verify_value=False)
        await f.max_velocity.write(self.units.velo_from_vel(float(top or 0.0)))
        await f.seconds_to_velocity.write(self.units.accl_from_accel(velo, accel),
                                          verify_value=False)

    async def _read_limits(self) -> None:
        low, high = await self.controller.get("lim", axis=self.letter)
        f = self._f
        offset = f.user_offset.value
        await f.dial_low_limit.write(float(low), verify_value=False)
        await f.dial_high_limit.write(float(high), verify_value=False)
        await f.user_low_limit.write(float(low) + offset, verify_value=False)
        await f.user_high_limit.write(float(high) + offset, verify_value=False)
        await self._publish_drive_limits(offset)

    async def _publish_drive_limits(self, offset: float) -> None:
        f = self._f
        await self.record.write_metadata(
            lower_ctrl_limit=f.dial_low_limit.value + offset,
            upper_ctrl_limit=f.dial_high_limit.value + offset)

    async def _publish_dial(self, dial: float) -> None:
        self._dial = float(dial)
        f = self._f
        await f.dial_readback_value.write(self._dial)
        await f.user_readback_value.write(self._dial + f.user_offset.value)

    async def poll_update(self, dial: float, letter: str) -> None:
        """Publish a polled position and status letter."""
        if not self._busy:
            await self._publish_dial(dial)
            moving = letter == "M"
            f = self._f
            if f.motor_is_moving.value != int(moving):
                await f.motor_is_moving.write(int(moving))
                await f.done_moving_to_value.write(int(not moving))
        else:
            await self._publish_dial(dial)
        await self._publish_status(moving=letter == "M")

    async def slow_update(self, readsw: str, statuslimit: str) -> None:
        """Publish the limit switches and the homed state."""
        self._switches = limit_switches(readsw, self.letter)
        self._homed = calibrated(statuslimit, self.letter)
        f = self._f
        await f.user_high_limit_switch.write(int(self._switches.high))
        await f.user_low_limit_switch.write(int(self._switches.low))
        await self._publish_status()

    async def _publish_status(self, moving: bool | None = None) -> None:
        f = self._f
        if moving is None:
            moving = bool(f.motor_is_moving.value)
        word = msta(moving=moving or bool(self._busy), switches=self._switches,
                    problem=self._problem, comm_error=not self.server.link_up,
                    homed=self._homed, positive=self._positive)
        if f.motor_status.value != word:
            await f.motor_status.write(word)

    async def link_changed(self, up: bool) -> None:
        """The link went down (INVALID/COMM alarm) or came back (settings re-read)."""
        if up:
            await self.read_settings()
            await self._set_alarm(AlarmStatus.NO_ALARM, AlarmSeverity.NO_ALARM)
        else:
            await self._set_alarm(AlarmStatus.COMM, AlarmSeverity.INVALID_ALARM)
        await self._publish_status()

    async def assert_invalid(self) -> None:
        """Keep the INVALID alarm while the link is down (a failed put overwrites it)."""
        if self.record.alarm.severity != AlarmSeverity.INVALID_ALARM:
            await self.link_changed(False)


# ------------------------------------------------------------------------ the controller


class ControllerServer:
    """The PVs of one controller: its axes and controller PVs, and the poller."""

    def __init__(self, controller: Controller, prefix: str, *, poll: float = 0.1,
                 window: float = 0.02) -> None:
        self.controller = controller
        self.prefix = prefix
        self.poll = poll
        self.coalescer = MoveCoalescer(controller, window=window)
        self.group = ControllerGroup(prefix)
        self.link_up = controller.connected
        count = controller.identity.axes if controller.identity else controller.context.axes
        self.axes = [AxisServer(self, letter) for letter in AXES[:count]]

    @property
    def pvdb(self) -> dict[str, Any]:
        """Every PV of this controller, by name."""
        pvdb: dict[str, Any] = dict(self.group.pvdb)
        for axis in self.axes:
            pvdb.update(axis.group.pvdb)
        return pvdb

    async def start(self) -> None:
        """Read the settings and publish the first values (raises if it cannot)."""
        await self._set_link(self.controller.connected, force=True)

    async def report_error(self, exc: BaseException) -> None:
        """Publish ``exc`` as the last error (``P:ERROR``, ``P:ERROR:TEXT``)."""
        number = exc.number if isinstance(exc, ControllerError) else -1
        await self.group.error.write(number)
        await self.group.error_text.write(str(exc)[:255])
        if not self.link_up:  # the failed put's WRITE alarm must not hide the link state
            for axis in self.axes:
                await axis.assert_invalid()

    async def _set_link(self, up: bool, *, force: bool = False) -> None:
        if up == self.link_up and not force:
            return
        group = self.group
        if not up:
            self.link_up = False
            log.warning("%s: link to %s lost", self.prefix, self.controller.url)
            await self.report_error(ConnectionLostError(f"link to {self.controller.url} lost"))
        for axis in self.axes:
            await axis.link_changed(up)
        severity = AlarmSeverity.NO_ALARM if up else AlarmSeverity.INVALID_ALARM
        status = AlarmStatus.NO_ALARM if up else AlarmStatus.COMM
        for pv in (group.autostatus, group.trigcount, group.error, group.error_text):
            await pv.alarm.write(status=status, severity=severity)
        await group.connected.write(int(up))
        if up:
            await group.autostatus.write(self.controller.autostatus)
            log.info("%s: connected to %s", self.prefix, self.controller.url)
        # Up only once every setting was read: a failed read is tried again next poll.
        self.link_up = up

    async def run(self) -> None:
        """Poll until cancelled; follows the link down and up again."""
        count = 0
        while True:
            try:
                await self._poll_once(slow=count % SLOW_EVERY == 0)
            except ConnectionLostError:
                pass  # seen as link down by the next round
            except TangoError as exc:  # a timeout, a garbled reply: try again later
                log.warning("%s: poll failed: %s", self.prefix, exc)
            count += 1
            await asyncio.sleep(self.poll)

    async def _poll_once(self, *, slow: bool) -> None:
        c = self.controller
        if not c.connected:
            await self._set_link(False)
            for axis in self.axes:
                await axis.assert_invalid()
            return
        await self._set_link(True)
        positions = await c.position()
        letters = await c.status()
        for axis in self.axes:
            await axis.poll_update(positions.get(axis.letter, 0.0),
                                   letters.get(axis.letter, "@"))
        if slow:
            readsw = await c.query("?readsw")
            statuslimit = await c.query("?statuslimit")
            for axis in self.axes:
                await axis.slow_update(readsw, statuslimit)
            await self.group.trigcount.write(int(await c.get("trigcount")))
            await self.group.autostatus.write(c.autostatus)

    async def aclose(self) -> None:
        """Stop what the coalescer is moving."""
        await self.coalescer.aclose()


# --------------------------------------------------------------------------------- the IOC


def _guard(pv: Any, policy: AccessPolicy,
           on_error: Callable[[BaseException], Awaitable[None]]) -> None:
    """Make ``pv`` refuse writes to clients the policy does not allow (status
    ECA_NOWTACCESS), and answer a put whose handler failed with the status ECA_PUTFAIL.

    caproto answers a failed put with an error message, which clients waiting for the
    put's callback do not all match to their put (caproto's own client then times out);
    EPICS base's server answers with the put-callback's status, as done here.
    """
    own_check, own_write = pv.check_access, pv.auth_write

    def check_access(hostname: str, username: str) -> AccessRights:
        rights = own_check(hostname, username)
        if not policy.may_write(hostname, username):
            rights &= ~AccessRights.WRITE
        return rights

    async def auth_write(hostname: str, username: str, *args: Any, **kwargs: Any) -> Any:
        try:
            return await own_write(hostname, username, *args, **kwargs)
        except Forbidden:
            log.warning("%s: write refused to %s@%s", pv.pvname, username, hostname)
            return CAStatus.ECA_NOWTACCESS
        except Exception as exc:
            log.warning("%s: put by %s@%s failed: %s", pv.pvname, username, hostname, exc)
            await on_error(exc)
            return CAStatus.ECA_PUTFAIL

    pv.check_access = check_access
    pv.auth_write = auth_write


class TangoIoc:
    """An IOC serving one or more controllers. Build it with :func:`build_ioc`."""

    def __init__(self, servers: Sequence[ControllerServer], policy: AccessPolicy) -> None:
        self.servers = list(servers)
        self.policy = policy
        self.pvdb: dict[str, Any] = {}
        for server in self.servers:
            overlap = set(self.pvdb) & set(server.pvdb)
            if overlap:
                raise ValueError(f"PV names used twice: {sorted(overlap)[:3]}")
            self.pvdb.update(server.pvdb)
            for pv in server.pvdb.values():
                _guard(pv, policy, server.report_error)
                for field in getattr(pv, "fields", {}).values():  # served as "P:X.VELO"
                    _guard(field, policy, server.report_error)

    async def start(self) -> None:
        """Read every controller's settings and publish the first values."""
        for server in self.servers:
            await server.start()

    async def run(self, interfaces: Sequence[str] = ("127.0.0.1",)) -> None:
        """Serve on ``interfaces`` until cancelled; stops the moves this IOC started."""
        context = Context(self.pvdb, list(interfaces))
        tasks = [asyncio.ensure_future(server.run()) for server in self.servers]
        tasks.append(asyncio.ensure_future(context.run()))
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                task.result()  # a poller or the server died: report why
            raise RuntimeError("the Channel Access server stopped")
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for server in self.servers:
                await server.aclose()


async def build_ioc(controllers: Mapping[str, Controller], prefix: str, *,
                    policy: AccessPolicy | None = None, poll: float = 0.1,
                    window: float = 0.02) -> TangoIoc:
    """Build (and :meth:`~TangoIoc.start`) an IOC for ``controllers``.

    ``controllers`` maps a name to a connected controller; the name ``""`` gives PVs
    ``<prefix>X``, any other name ``<prefix><name>:X``. ``poll`` is the seconds between
    position reads, ``window`` the :class:`~tango_aio.coalesce.MoveCoalescer` window.
    """
    servers = [ControllerServer(controller, f"{prefix}{name}:" if name else prefix,
                                poll=poll, window=window)
               for name, controller in controllers.items()]
    ioc = TangoIoc(servers, policy or AccessPolicy())
    await ioc.start()
    return ioc
