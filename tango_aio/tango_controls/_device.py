"""The Tango Controls device classes (pytango, asyncio green mode): ``MarzhauserAxis``, one
device per axis of the Märzhäuser TANGO controller, and ``MarzhauserController``, one for
the controller itself. They show what the :class:`~._axis.AxisCore` and
:class:`~._axis.StageLink` of the running server know; :data:`SERVING` hands each device
its part by device name before the server starts.
"""

from __future__ import annotations

import json
import logging
import signal
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import tango
from tango import AttrWriteType, DevState, GreenMode
from tango.server import Device, attribute, command

from ..controller import Controller
from ..errors import TangoError
from ._axis import AxisCore, StageLink
from ._controller_info import info_field, trigger_config_json, updated_trigger_config
from ._state import Shown

__all__ = ["SERVING", "MarzhauserAxis", "MarzhauserController", "Serving"]

log = logging.getLogger("tango_aio.tango_controls")


@dataclass
class Serving:
    """What the running server serves, by device name (lower case), and the thread that
    pushes its change events."""

    axes: dict[str, AxisCore] = field(default_factory=dict)
    controllers: dict[str, StageLink] = field(default_factory=dict)
    #: Set when Ctrl+C (SIGINT) ended the server: the command then exits with 130.
    interrupted: bool = False
    pusher: ThreadPoolExecutor = field(
        default_factory=lambda: ThreadPoolExecutor(1, thread_name_prefix="tango-events"))

    def push(self, device: Device, name: str, value: Any) -> None:
        """Push a change event of ``device``'s attribute ``name`` (in order)."""
        self.pusher.submit(_push, device, name, value)


def _push(device: Device, name: str, value: Any) -> None:
    try:
        # Tango sends the device's own state and status in their events: both are set
        # under the device's lock, with no request between them and the push.
        with tango.AutoTangoMonitor(device):
            if name == "State":
                device.set_state(value)
                device.push_change_event(name)
            elif name == "Status":
                device.set_status(value)
                device.push_change_event(name)
            else:
                device.push_change_event(name, value)
    except Exception:  # a deleted device, a server shutting down: nobody to tell
        log.debug("%s: %s event not pushed", device.get_name(), name, exc_info=True)


#: The one server this process runs.
SERVING = Serving()

#: The attributes whose change events the server pushes itself (no polling).
PUSHED = ("State", "Status", "Position", "DialPosition", "LimitSwitches", "Calibrated")


def _refuse(exc: Exception) -> None:
    """Fail the client's call with ``exc``'s class and message (a DevFailed)."""
    tango.Except.throw_exception(f"TangoAio_{type(exc).__name__}", str(exc),
                                 "tango_aio.tango_controls")


class MarzhauserAxis(Device):  # type: ignore[misc]
    """One axis of a Märzhäuser TANGO stepper-motor controller."""

    green_mode = GreenMode.Asyncio

    async def init_device(self) -> None:
        await super().init_device()
        self._axis = SERVING.axes[self.get_name().lower()]
        self._moment = self._now()
        for name in PUSHED:
            self.set_change_event(name, True, False)
        self._axis.publish = self._publish
        self.set_state(getattr(DevState, self._moment[2][0].value))

    async def delete_device(self) -> None:
        self._axis.publish = _forget
        await super().delete_device()

    def _now(self) -> tuple[float, float, tuple[Shown, str]]:
        return self._axis.position, self._axis.dial, self._axis.state

    async def always_executed_hook(self) -> None:
        self._moment = self._now()

    async def dev_state(self) -> DevState:
        return getattr(DevState, self._moment[2][0].value)

    async def dev_status(self) -> str:
        return self._moment[2][1]

    def _publish(self, name: str, value: Any) -> None:
        if name == "State":
            shown, status = value
            SERVING.push(self, "Status", status)
            SERVING.push(self, "State", getattr(DevState, shown.value))
        else:
            SERVING.push(self, name, value)

    # -- attributes ----------------------------------------------------------------------

    @attribute(dtype=float, access=AttrWriteType.READ_WRITE,
               doc="the confirmed position (user units); write: start a move there")
    async def Position(self) -> float:
        return self._moment[0]

    @Position.write  # type: ignore[no-redef]
    async def Position(self, value: float) -> None:
        try:
            await self._axis.move_to(value)
        except (TangoError, ValueError) as exc:
            _refuse(exc)

    @attribute(dtype=float, doc="the position in the controller's own terms (no Offset)")
    async def DialPosition(self) -> float:
        return self._moment[1]

    @attribute(dtype=float, access=AttrWriteType.READ_WRITE, memorized=True,
               hw_memorized=True, doc="Position = DialPosition + Offset")
    async def Offset(self) -> float:
        return self._axis.offset

    @Offset.write  # type: ignore[no-redef]
    async def Offset(self, value: float) -> None:
        self._axis.offset = value
        SERVING.push(self, "Position", self._axis.position)

    @attribute(dtype=str, doc="the unit of the positions (the axis's dim)")
    async def Unit(self) -> str:
        return self._axis.unit

    @attribute(dtype=float, access=AttrWriteType.READ_WRITE,
               doc="the velocity, in Unit per second")
    async def Velocity(self) -> float:
        return await self._read_setting(self._axis.controller.settings.velocity, "/s")

    @Velocity.write  # type: ignore[no-redef]
    async def Velocity(self, value: float) -> None:
        await self._write_setting(self._axis.controller.settings.set_velocity, "/s", value)

    @attribute(dtype=float, access=AttrWriteType.READ_WRITE,
               doc="the acceleration, in Unit per second squared")
    async def Acceleration(self) -> float:
        return await self._read_setting(self._axis.controller.settings.acceleration, "/s2")

    @Acceleration.write  # type: ignore[no-redef]
    async def Acceleration(self, value: float) -> None:
        await self._write_setting(self._axis.controller.settings.set_acceleration, "/s2", value)

    @attribute(dtype=float, access=AttrWriteType.READ_WRITE,
               doc="the lower soft limit (user units)")
    async def LowerLimit(self) -> float:
        return (await self._limits())[0] + self._axis.offset

    @LowerLimit.write  # type: ignore[no-redef]
    async def LowerLimit(self, value: float) -> None:
        await self._set_limits(value - self._axis.offset, None)

    @attribute(dtype=float, access=AttrWriteType.READ_WRITE,
               doc="the upper soft limit (user units)")
    async def UpperLimit(self) -> float:
        return (await self._limits())[1] + self._axis.offset

    @UpperLimit.write  # type: ignore[no-redef]
    async def UpperLimit(self, value: float) -> None:
        await self._set_limits(None, value - self._axis.offset)

    @attribute(dtype=(bool,), max_dim_x=3,
               doc="the lower, upper and reference switch (?readsw), actuated or not")
    async def LimitSwitches(self) -> list[bool]:
        return list(self._axis.switches)

    @attribute(dtype=bool, doc="calibrated since the controller was switched on")
    async def Calibrated(self) -> bool:
        return self._axis.calibrated

    # -- commands ------------------------------------------------------------------------

    @command
    async def Stop(self) -> None:
        """Stop this axis (the others go on)."""
        await self._do(self._axis.stop())

    @command
    async def Abort(self) -> None:
        """Stop every axis of the controller."""
        await self._do(self._axis.controller.abort(soft=True))

    @command
    async def Calibrate(self) -> None:
        """Start a calibration (to the lower limit switch; the origin is set there)."""
        try:
            self._axis.calibrate()
        except (TangoError, ValueError) as exc:
            _refuse(exc)

    @command
    async def MeasureRange(self) -> None:
        """Start a range measurement (to the upper limit switch)."""
        try:
            self._axis.measure_range()
        except (TangoError, ValueError) as exc:
            _refuse(exc)

    @command(dtype_in=float, doc_in="the distance, in Unit")
    async def MoveRelative(self, distance: float) -> None:
        """Start a move by ``distance`` from where the axis stands."""
        await self._do(self._axis.move_by(distance))

    # -- helpers -------------------------------------------------------------------------

    async def _do(self, action: Any) -> Any:
        try:
            return await action
        except (TangoError, ValueError) as exc:
            _refuse(exc)

    async def _read_setting(self, read: Any, per: str) -> float:
        values = await self._do(read(unit=self._axis.unit + per))
        return float(values[self._axis.letter])

    async def _write_setting(self, write: Any, per: str, value: float) -> None:
        await self._do(write(unit=self._axis.unit + per, **{self._axis.letter: value}))

    async def _limits(self) -> tuple[float, float]:
        limits: tuple[float, float] = await self._do(
            self._axis.controller.axis_limits(self._axis.letter))
        return limits

    async def _set_limits(self, low: float | None, high: float | None) -> None:
        old_low, old_high = await self._limits()
        pair = (old_low if low is None else low, old_high if high is None else high)
        limits: dict[str, Any] = {self._axis.letter: pair}
        await self._do(self._axis.controller.settings.set_limits(**limits))


def _forget(name: str, value: Any) -> None:
    """A publisher for a deleted device."""


class MarzhauserController(Device):  # type: ignore[misc]
    """A Märzhäuser TANGO stepper-motor controller: its identity and link, what it says
    about itself (``Info`` and its fields), its settings (``Settings``) and its trigger
    output (``TriggerConfig``, ``TriggerEnabled``, ``TriggerCount``)."""

    green_mode = GreenMode.Asyncio

    async def init_device(self) -> None:
        await super().init_device()
        self._link = SERVING.controllers[self.get_name().lower()]
        self.set_state(DevState.ON)
        # Tango's own signal thread ends the server on Ctrl+C; this says it was one. Where
        # Tango will not register it, the server still ends; only the exit code is 0.
        try:
            self.register_signal(signal.SIGINT)
        except tango.DevFailed:
            log.debug("SIGINT not registered: Ctrl+C will end the server with 0")

    def signal_handler(self, signo: int) -> None:
        """Note a Ctrl+C (the server then shuts down as Tango does on it)."""
        if signo == signal.SIGINT:
            SERVING.interrupted = True

    @property
    def _controller(self) -> Controller:
        return self._link.controller

    async def dev_state(self) -> DevState:
        return DevState.ON if self._controller.connected else DevState.FAULT

    async def dev_status(self) -> str:
        c = self._controller
        return f"connected to {c.url}" if c.connected else \
            f"the link to {c.url} is lost; reconnecting"

    @attribute(dtype=str, doc="the controller's model (?version)")
    async def Model(self) -> str:
        return self._controller.identity.model

    @attribute(dtype=str, doc="the firmware version (?version)")
    async def Firmware(self) -> str:
        return self._controller.identity.firmware

    @attribute(dtype=int, doc="the number of axes (?det)")
    async def Axes(self) -> int:
        return self._controller.identity.axes

    @attribute(dtype=str, doc="the URL the server opened")
    async def Url(self) -> str:
        return self._controller.url

    @attribute(dtype=bool, doc="the link to the controller is up")
    async def Connected(self) -> bool:
        return self._controller.connected

    @attribute(dtype=int, doc="the autostatus mode the driver runs the controller in")
    async def Autostatus(self) -> int:
        return self._controller.autostatus

    @command
    async def Abort(self) -> None:
        """Stop every axis."""
        try:
            await self._link.abort()
        except TangoError as exc:
            _refuse(exc)

    # -- what the controller says about itself -------------------------------------------

    async def _ask(self, action: Any) -> Any:
        try:
            return await action
        except (TangoError, ValueError) as exc:
            _refuse(exc)

    async def _info(self, name: str) -> Any:
        try:
            return info_field(await self._ask(self._controller.read_info()), name)
        except LookupError as exc:
            _refuse(exc)

    @attribute(dtype=str, doc="everything read_info() reads, as a JSON object (null: a "
                              "field this controller does not answer)")
    async def Info(self) -> str:
        info = await self._ask(self._controller.read_info())
        return json.dumps(info.as_dict(), sort_keys=True)

    @attribute(dtype=str, doc="the serial number (?readsn)")
    async def SerialNumber(self) -> str:
        return str(await self._info("serial_number"))

    @attribute(dtype=str, doc="the version string (?ver)")
    async def Version(self) -> str:
        return str(await self._info("version"))

    @attribute(dtype=str, doc="the internal version (?iver)")
    async def InternalVersion(self) -> str:
        return str(await self._info("internal_version"))

    @attribute(dtype=int, unit="s", doc="seconds since power-on or reset (?uptime)")
    async def Uptime(self) -> int:
        return int(await self._info("uptime"))

    @attribute(dtype=float, unit="degC", doc="the case temperature (?temp)")
    async def Temperature(self) -> float:
        return float(await self._info("temperature"))

    @attribute(dtype=str, doc="every setting the controller holds, as the JSON of a "
                              "settings snapshot (tango_aio's SettingsSnapshot.to_json)")
    async def Settings(self) -> str:
        snapshot = await self._ask(self._controller.settings.snapshot())
        return str(snapshot.to_json())

    # -- the trigger output --------------------------------------------------------------

    @attribute(dtype=str, access=AttrWriteType.READ_WRITE,
               doc="the trigger configuration as a JSON object (mode, axis, width_us, "
                   "distance, frequency_hz, output, compensation_us, encoder, "
                   "list_active_high); write: the fields to change, the others kept")
    async def TriggerConfig(self) -> str:
        return trigger_config_json(await self._ask(self._controller.triggers.read_config()))

    @TriggerConfig.write  # type: ignore[no-redef]
    async def TriggerConfig(self, value: str) -> None:
        triggers = self._controller.triggers
        try:
            config = updated_trigger_config(await triggers.read_config(), value)
            await triggers.write_config(config)
        except (TangoError, ValueError) as exc:
            _refuse(exc)

    @attribute(dtype=bool, access=AttrWriteType.READ_WRITE,
               doc="the trigger output is switched on (?trig, !trig)")
    async def TriggerEnabled(self) -> bool:
        return bool(await self._ask(self._controller.triggers.enabled()))

    @TriggerEnabled.write  # type: ignore[no-redef]
    async def TriggerEnabled(self, value: bool) -> None:
        await self._ask(self._controller.triggers.set_enabled(bool(value)))

    @attribute(dtype=int, access=AttrWriteType.READ_WRITE,
               doc="the trigger events so far (?trigcount); write: set the counter")
    async def TriggerCount(self) -> int:
        return int(await self._ask(self._controller.triggers.count()))

    @TriggerCount.write  # type: ignore[no-redef]
    async def TriggerCount(self, value: int) -> None:
        await self._ask(self._controller.triggers.set_count(int(value)))
