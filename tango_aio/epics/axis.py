"""One axis behind its motor record: the puts, the motions and their completion, the alarms."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import Any, Protocol

from caproto import AlarmSeverity, AlarmStatus

from ..catalog import lookup, upper_bound
from ..controller import Controller
from ..errors import MotorRefusedError, MoveError, MoveStoppedError, TangoError
from ..group import MoveCoalescer
from ..status import ARRIVED_LETTERS, MOVING, AxisStatus
from .autosave import SAVED, Autosave
from .fields import (
    ALARM_FIELDS,
    AUTOSAVED,
    MAX_MAGNITUDE,
    REFUSED,
    AxisGroup,
    _finite,
    _log_failure,
    _number,
    _start_motion,
)
from .record import (
    NO_ALARM,
    AxisUnits,
    Ending,
    LimitSwitches,
    Mip,
    calibrated,
    derived_fields,
    fault_after,
    limit_switches,
    limit_violation,
    msta,
    revolution_speeds,
    shown_alarm,
)

log = logging.getLogger("tango_aio.epics")

def _fields(record: Any) -> Any:
    return record.field_inst


class AxisHost(Protocol):
    """What an axis uses of its controller's server (:class:`~.server.ControllerServer`)."""

    controller: Controller
    prefix: str
    autosave: Autosave | None
    coalescer: MoveCoalescer
    link_up: bool

    async def flush(self) -> None: ...

    async def link_lost(self) -> None: ...

    async def read_units(self) -> tuple[dict[str, AxisUnits], int]: ...


class AxisServer:
    """Drives one axis for its motor record and publishes what the poller reads."""

    def __init__(self, server: AxisHost, letter: str) -> None:
        self.server = server
        self.letter = letter
        self.units = AxisUnits()
        self.group = AxisGroup(f"{server.prefix}{letter.upper()}", axis=self)
        self.record: Any = self.group.motor
        self._busy = 0
        #: The requests in progress (counted in ``_busy``), by number: set once ended.
        self._ongoing: dict[int, asyncio.Event] = {}
        #: Requests ended so far: a poll during which one ended carries older news.
        self.finished = 0
        self._request = 0
        self._turn = asyncio.Lock()
        self._halted = False  # SPMG is Stop or Pause (set before any await)
        self._resume: float | None = None  # Pause interrupted a move to this user value
        self._fault = NO_ALARM  # raised by a failed move, cleared by one that arrived
        self._settle = False  # a STOP ends the running request: VAL goes where it stood
        self._standing_unknown = False  # a move ended with the link down
        self._switches = LimitSwitches()
        self._homed = False
        self._dial = 0.0
        self._decimals = 4
        self._positive = True
        self._motion: asyncio.Future[Any] | None = None
        self._saving: set[asyncio.Future[None]] = set()

    async def _end(self, ending: Ending) -> None:
        """A motion request ended as ``ending``: the axis's alarm follows
        (:func:`~.record.fault_after`) on every PV, unless the link is down."""
        self._fault = fault_after(self._fault, ending)
        if self.server.link_up and self.controller.connected:
            await self._show_alarm()

    async def _show_alarm(self, link_up: bool | None = None) -> None:
        """Show the axis's alarm (:func:`~.record.shown_alarm`) on every PV (``link_up``:
        the link's state, if not yet the server's)."""
        up = self.server.link_up if link_up is None else link_up
        alarm = shown_alarm(self._fault, link_up=up)
        await self._set_alarm(AlarmStatus[alarm.status], AlarmSeverity[alarm.severity])

    @property
    def _problem(self) -> bool:
        return self._fault != NO_ALARM

    async def _set_alarm(self, status: AlarmStatus, severity: AlarmSeverity) -> None:
        """Set the record's alarm and that of its fields (RBV shows INVALID too)."""
        fields = self.record.fields
        alarms = {id(c.alarm): c.alarm for c in (self.record, *(fields[name] for name in
                                                                  ALARM_FIELDS))}
        for alarm in alarms.values():
            # Each write posts a monitor on every channel that shares the alarm: clearing
            # an alarm that is not set (the end of every good move) is skipped, about
            # 0.3 ms of each put; an alarm is posted again each time it is set (a link
            # loss re-asserts INVALID to every client, after CONNECTED=0 too).
            if severity != AlarmSeverity.NO_ALARM or alarm.severity != severity \
                    or alarm.status != status:
                await alarm.write(status=status, severity=severity)

    @property
    def controller(self) -> Controller:
        """The axis's controller."""
        return self.server.controller

    @property
    def _f(self) -> Any:
        return _fields(self.record)

    # -- field puts ----------------------------------------------------------------------

    async def put_field(self, field: str, value: Any) -> Any:
        """A client put ``value`` to ``field``: act on it, return the value to store."""
        stored = await self._put_field(field, value)
        if field in AUTOSAVED:
            self._save_soon()
        return stored

    def _save_soon(self) -> None:
        """Write the autosave file once caproto has stored the value being put (the
        put's own task stores it before it next waits)."""
        if self.server.autosave is not None:
            task = asyncio.ensure_future(self._save())
            self._saving.add(task)
            task.add_done_callback(self._saving.discard)

    async def _save(self) -> None:
        autosave = self.server.autosave
        if autosave is None:
            return
        fields = self.record.fields
        try:
            autosave.store(self.record.pvname, {name: fields[name].value for name in SAVED})
        except OSError as exc:
            log.error("%s: autosave to %s failed: %s", self.record.pvname, autosave.path,
                      exc)

    async def restore(self, saved: Mapping[str, float]) -> None:
        """Put back the autosaved fields (at start, once the controller is connected)."""
        f = self._f
        if "DLLM" in saved or "DHLM" in saved:
            low = saved.get("DLLM", f.dial_low_limit.value)
            high = saved.get("DHLM", f.dial_high_limit.value)
            await self.controller.command(f"!lim {self.letter} {low} {high}")
            await self._read_limits()
        if "OFF" in saved:
            await f.user_offset.write(saved["OFF"], verify_value=False)
            await self.offset_changed(saved["OFF"])
            await self.record.write(self.record.fields["RBV"].value, verify_value=False)
            await self._publish_derived()
        if "VMAX" in saved:
            await f.max_velocity.write(saved["VMAX"], verify_value=False)
        if "VELO" in saved:
            await self.set_velocity(saved["VELO"])

    async def _put_field(self, field: str, value: Any) -> Any:
        f = self._f
        if isinstance(value, float) and field not in ("DESC",):
            _finite(self.record.pvname, field, value)
        if field == "STOP":
            if value:
                await self.stop()
            return 0
        if field == "SPMG":
            return await self._put_spmg(value)
        if field in ("TWF", "TWR"):
            if value:
                await self.tweak(+1 if field == "TWF" else -1)
            return 0
        if field in ("HOMF", "HOMR"):
            if value:
                await self.home(forward=field == "HOMF")
            return 0
        if field == "VELO":
            return await self.set_velocity(float(value))
        if field == "VMAX":
            return await self._put_vmax(float(value))
        if field == "ACCL":
            return await self.set_acceleration_time(float(value))
        if field in ("HLM", "LLM"):
            dial = float(value) - f.user_offset.value
            return await self.set_limit(high=field == "HLM", dial=dial)
        if field in ("DHLM", "DLLM"):
            await self.set_limit(high=field == "DHLM", dial=float(value))
            return value
        if field == "OFF":
            await self.offset_changed(float(value))
            return value
        if field == "CNEN":
            await self.set_enabled(value == "Enable")
            return value
        if field == "RLV":
            if value:
                await self.move(self.record.value + float(value))
            return 0.0
        if field == "DVAL":
            await self.move(float(value) + f.user_offset.value)
            return value
        if field in ("SSET", "SUSE"):
            if value:
                await f.set_use_switch.write("Set" if field == "SSET" else "Use")
            return 0
        if field in ("TWV", "MDEL", "ADEL"):
            if float(value) < 0:
                raise MotorRefusedError(f"{self.record.pvname}.{field} must be >= 0")
            return value
        if field == "DIR" and value in ("Pos", 0):
            return value
        if field == "VBAS" and float(value) == 0.0:
            return value
        raise MotorRefusedError(f"{self.record.pvname}.{field}: {REFUSED[field]}")

    async def _put_spmg(self, value: str) -> str:
        if value in ("Stop", "Pause"):
            # The flag is set before the first await: a VAL put right behind is refused.
            self._halted = True
            resume = self.record.value if value == "Pause" and self._busy else None
            await self.stop(keep_target=value == "Pause")
            self._resume = resume
            return value
        self._halted = False
        resume, self._resume = self._resume, None
        if value == "Go" and resume is not None:  # Pause, then Go: on toward VAL
            task = asyncio.ensure_future(self.move(resume))
            task.add_done_callback(_log_failure)
        return value

    async def _put_vmax(self, vmax: float) -> float:
        if vmax <= 0 or vmax > self._vmax_ceiling():
            raise MotorRefusedError(f"{self.record.pvname}.VMAX must be in (0, "
                                    f"{self._vmax_ceiling():g}] {self.units.egu}/s")
        if self._f.velocity.value > vmax:
            await self.set_velocity(vmax, vmax=vmax)
        await self._publish_speeds(vmax)
        return vmax

    # -- motion --------------------------------------------------------------------------

    async def move(self, target: float) -> bool:
        """VAL was put: move there (or redefine the position with SET=Set)."""
        arrived = self.server.coalescer.announce()
        try:
            self._require_link()
            f = self._f
            self._require_go()
            _finite(self.record.pvname, "VAL", target)
            if f.set_use_switch.value == "Set":
                await self._redefine(target)
                await self.server.flush()  # the new RBV and OFF before the put's reply
                return False
            dial = target - f.user_offset.value
            await self._check_limits(dial)
            await self.record.write(target, verify_value=False)  # VAL: the newest target
            await f.dial_desired_value.write(dial, verify_value=False)
            confirmed: dict[str, str] = {}
            await self._run(lambda: self.server.coalescer.move_to(
                self.letter, dial, arrived, positions=confirmed),
                positive=dial >= self._dial, confirmed=confirmed)
            return True
        finally:
            arrived()  # refused, replaced or failed before it joined: nobody waits for it

    def _require_go(self) -> None:
        if self._halted:
            raise MotorRefusedError(f"{self.record.pvname}: SPMG is "
                                    f"{self._f.stop_pause_move_go.value}; set it to Go to "
                                    "move")

    async def _check_limits(self, dial: float) -> None:
        """Refuse a target beyond the soft limits as the motor record does: LVIO=1, VAL
        and DVAL kept, no motion, DMOV blinks (0, then 1 at once: a client waiting for
        DMOV's end sees one), and the put fails with the axis's alarm raised."""
        f = self._f
        low, high = f.dial_low_limit.value, f.dial_high_limit.value
        violation = limit_violation(dial, low, high)
        if f.limit_violation.value != int(violation is not None):
            await f.limit_violation.write(int(violation is not None), verify_value=False)
        if violation is None:
            return
        await self._end(violation)
        if not self._busy:
            await f.done_moving_to_value.write(0, verify_value=False)
            await f.done_moving_to_value.write(1, verify_value=False)
        await self._publish_status()
        await self.server.flush()
        raise MotorRefusedError(f"{self.record.pvname}: dial target {dial} outside the "
                                f"limits [{low}, {high}] (LVIO)")

    async def _run(self, motion: Callable[[], Awaitable[Any]], *,
                   positive: bool = True, confirmed: Mapping[str, str] | None = None,
                   mip: int = Mip.MOVE) -> None:
        """Run ``motion`` once it is this request's turn, with DMOV=0; before returning,
        publish RBV, MOVN=0 and DMOV=1 (unless another request follows) and wait until
        those updates are on the wire to every client."""
        f = self._f
        self._request += 1
        request = self._request
        self._busy += 1
        self._ongoing[request] = asyncio.Event()
        self._settle = False  # replaced, not stopped: this request sets VAL itself
        try:
            if f.done_moving_to_value.value != 0:
                await f.done_moving_to_value.write(0, verify_value=False)
            await self._cancel_running()
        except BaseException:
            self._ended(request)
            await self._finish()
            raise
        # The turn covers the final publishing too: the next request (or a STOP that
        # waits for its turn) starts after this one's RBV/DMOV are out.
        arrived_at: str | None = None  # the confirmed position, after a success only
        settle = moving = False
        async with self._turn:
            try:
                if request != self._request:
                    raise MoveStoppedError(f"{self.record.pvname}: replaced or stopped "
                                           "before it started")
                self._require_link()
                self._require_go()
                self._positive = positive
                moving = True
                await self._motion_of(motion, request, {
                    "TDIR": int(positive), "CDIR": int(positive), "MIP": mip,
                    **self._derived()})
            except MoveStoppedError:
                settle = self._settle  # a STOP's; a newer request sets VAL itself
                raise
            except TangoError:
                # The record's alarm shows on its fields too, as a motor record's SEVR
                # does: classic ophyd's EpicsMotor fails a move when RBV is in alarm.
                # VAL and DVAL go where the axis stopped, as the motor record's do. A
                # request refused before it moved (SPMG, the link) changes neither.
                if moving:
                    settle = True
                    await self._end(Ending.FAILED)
                raise
            else:
                settle = False
                await self._end(Ending.ARRIVED)
                arrived_at = (confirmed or {}).get(self.letter)
            finally:
                self._ended(request)
                # A client reads the switches when DMOV returns to 1 (classic ophyd the
                # one TDIR points to): read them first unless the move arrived with none
                # shown actuated (the poll reads them every fifth time).
                await self._finish(arrived_at, settle=settle, switches=arrived_at is None
                                   or self._switches.low or self._switches.high)

    def _ended(self, request: int) -> None:
        self._busy -= 1
        ended = self._ongoing.pop(request, None)
        if ended is not None:
            ended.set()

    async def _motion_of(self, motion: Callable[[], Awaitable[Any]], request: int,
                         start: Mapping[str, float]) -> None:
        """Run ``motion`` in a task :meth:`stop` can cancel, publishing the ``start``
        fields while its line goes out; raise what ended it short."""
        f = self._f
        if f.motor_is_moving.value != 1:
            await f.motor_is_moving.write(1, verify_value=False)
        await self._publish_status()
        task, ended = _start_motion(motion)
        self._motion = task
        published = asyncio.ensure_future(self._publish_fields(start))  # after its step
        try:
            await ended  # set in the motion's last step: one loop turn, not two
        except asyncio.CancelledError:  # the IOC shuts down: stop the move
            task.cancel()
            await asyncio.wait([task, published])
            raise
        await published
        if task.cancelled() or request != self._request:
            if not task.cancelled():
                task.exception()  # retrieved: the stop is what is reported
            raise MoveStoppedError(f"{self.record.pvname}: stopped before the target")
        try:
            task.result()
        except MoveError as exc:
            # A merged move reports every axis: this one may have arrived anyway
            # (@ arrived, A calibrated, D range measured; anything else ended short).
            if exc.statuses.get(self.letter, AxisStatus.ERROR) not in ARRIVED_LETTERS:
                raise

    async def _cancel_running(self) -> None:
        """Stop the running request's motion (its put fails) and wait until it ended.

        A move not yet sent is withdrawn; a sent one is stopped with the one-axis stop
        (``a x``, L6785-6844), so the other axes of a merged line go on to their targets.
        """
        task = self._motion
        if task is None or task.done():
            return
        if self.server.coalescer.pending(self.letter) or not self.controller.connected:
            task.cancel()
        else:
            await self.controller.stop(self.letter)
        await asyncio.wait([task])

    async def _finish(self, confirmed: str | None = None, *, settle: bool = False,
                      switches: bool = True) -> None:
        """A request ended: publish the position (``confirmed``, as printed by the read
        that confirmed its move's arrival, else read now), with ``settle`` VAL and DVAL
        too (where the axis stopped); unless another request follows, publish MOVN=0 and
        DMOV=1 (only while the link is up: a move that lost its link has not been seen to
        stand); with ``switches`` the limit switches are read first; then wait until every
        client has those updates."""
        f = self._f
        self.finished += 1  # a poll in flight read the axis before this request ended
        dial = _number(confirmed)
        with contextlib.suppress(TangoError):
            await self._publish_dial(dial if dial is not None
                                     else await self.controller.get("pos", axis=self.letter))
            if settle:
                await self._settle_target()
            if switches:
                c = self.controller
                await self.slow_update(await c.query("?readsw"),
                                       await c.query("?statuslimit"))
        if not self.controller.connected:
            self._standing_unknown = True
            await self.server.link_lost()
        elif not self._busy:
            await self._publish_fields({"MIP": Mip.DONE})
            if f.motor_is_moving.value != 0:
                await f.motor_is_moving.write(0, verify_value=False)
            if f.done_moving_to_value.value != 1:
                await f.done_moving_to_value.write(1, verify_value=False)
        await self._publish_status()
        await self.server.flush()

    async def _settle_target(self) -> None:
        """VAL and DVAL where the axis stands (DRBV as last published), as the motor
        record sets them after a STOP, SPMG=Stop or a move that ended short."""
        f = self._f
        if f.dial_desired_value.value != self._dial:
            await f.dial_desired_value.write(self._dial, verify_value=False)
        user = self._dial + f.user_offset.value
        if self.record.value != user:
            await self.record.write(user, verify_value=False)
        await self._publish_derived()

    async def stop(self, *, keep_target: bool = False) -> None:
        """STOP, or SPMG Stop/Pause: stop this axis, drop every waiting request, and
        return once it stands still.

        A move this IOC started and not yet sent is withdrawn; otherwise the axis gets the
        one-axis stop ``a x`` (L6785-6844): the other axes of a merged line go on. VAL and
        DVAL are then set to where the axis stands, but with ``keep_target`` (SPMG=Pause,
        which the motor record resumes toward VAL on Go)."""
        self._request += 1  # every waiting request is now stale
        stopped = self._request
        self._settle = not keep_target
        if not keep_target:
            self._resume = None
        self._require_link()
        await self._cancel_running()
        # Whatever moves this axis now (a move sent as it was withdrawn, another
        # program's) gets the one-axis stop too; stop() returns once it stands.
        if (await self.controller.status()).get(self.letter) == MOVING:
            await self.controller.stop(self.letter)
        # Requests made before this stop end without moving; one may still be stopping
        # the move before it and not yet waiting for its turn. This stop publishes
        # MOVN=0/DMOV=1 only after all of them (a later request is a new move).
        for number, ended in list(self._ongoing.items()):
            if number < stopped:
                await ended.wait()
        async with self._turn:  # the stopped and the stale requests have ended
            # A request made after this stop is a new move and sets VAL itself.
            await self._finish(settle=not keep_target and self._request == stopped)

    async def tweak(self, sign: int) -> None:
        """TWF/TWR: move VAL by TWV."""
        f = self._f
        await self.move(self.record.value + sign * abs(f.tweak_step_size.value))

    async def home(self, *, forward: bool) -> None:
        """HOMF: ``rm`` (upper switch); HOMR: ``cal`` (lower switch)."""
        self._require_link()
        self._require_go()
        run = self.controller.measure_range if forward else self.controller.calibrate
        try:
            await self._run(lambda: run(self.letter), positive=forward,
                            mip=Mip.HOMF if forward else Mip.HOMR)
        finally:
            with contextlib.suppress(TangoError):
                await self._read_limits()
            await self.record.write(self.record.fields["RBV"].value, verify_value=False)
            await self._publish_derived()

    async def _redefine(self, target: float) -> None:
        f = self._f
        if f.offset_freeze_switch.value == "Frozen":
            await self.controller.command(f"!pos {self.letter} {target - f.user_offset.value}")
            await self._publish_dial(await self.controller.get("pos", axis=self.letter))
        else:
            await f.user_offset.write(target - self._dial)  # through OFF's handler

    # -- settings ------------------------------------------------------------------------

    async def set_velocity(self, velo: float, *, vmax: float | None = None) -> float:
        """VELO was put: set ``vel`` (a VELO above VMAX is VMAX, as in the motor record);
        returns the VELO the controller took."""
        self._require_link()
        await self._units_now()
        top = self._f.max_velocity.value if vmax is None else vmax
        if velo <= 0:
            raise MotorRefusedError(f"{self.record.pvname}.VELO must be > 0")
        velo = min(velo, top) if top > 0 else velo
        await self.controller.set("vel", round(self.units.vel_from_velo(velo), 6),
                                  axis=self.letter)
        await self._read_speed()
        value: float = self._f.velocity.value
        return value

    async def set_acceleration_time(self, accl: float) -> float:
        """ACCL was put: set ``accel`` so VELO is reached in ``accl`` seconds."""
        self._require_link()
        await self._units_now()
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
        if abs(offset) > MAX_MAGNITUDE:
            raise MotorRefusedError(f"{self.record.pvname}.OFF {offset!r} is out of range")
        await f.user_readback_value.write(self._dial + offset, verify_value=False)
        # VAL follows too (the dial target is kept), as in the motor record.
        await self.record.write(f.dial_desired_value.value + offset, verify_value=False)
        await f.user_high_limit.write(f.dial_high_limit.value + offset, verify_value=False)
        await f.user_low_limit.write(f.dial_low_limit.value + offset, verify_value=False)
        await self._publish_drive_limits(offset)
        await self._publish_derived()

    async def set_enabled(self, enabled: bool) -> None:
        """CNEN was put: ``!axis x 1`` or ``!axis x 0`` (L3919-3960)."""
        self._require_link()
        if not enabled and (self._busy or
                            (await self.controller.status()).get(self.letter) == MOVING):
            await self.stop()
        await self.controller.command(f"!axis {self.letter} {1 if enabled else 0}")

    def _vmax_ceiling(self) -> float:
        """The largest VMAX: the `vel` instruction's ceiling (L3452) in EGU/s."""
        spec = lookup("vel").write[0].per_axis[0]
        top = upper_bound(spec, self.units.dim)
        return self.units.velo_from_vel(float(top or 0.0))

    def _require_link(self) -> None:
        if not self.server.link_up:
            raise MotorRefusedError(f"{self.record.pvname}: the controller is not connected")

    # -- reading -------------------------------------------------------------------------

    async def _units_now(self) -> None:
        """Read the unit settings before a conversion: ``pitch`` or ``dim`` may have
        changed through any path since the last poll read them."""
        units, decimals = await self.server.read_units()
        await self.units_read(units[self.letter], decimals)

    async def read_settings(self) -> None:
        """Read units, speeds, limits, enable state and position (at start, reconnect)."""
        c, axis, f = self.controller, self.letter, self._f
        units, decimals = await self.server.read_units()
        await self.units_read(units[axis], decimals, force=True)
        await self._read_limits()
        enabled = int(await c.get("axis", axis=axis)) == 1
        await f.enable_control.write("Enable" if enabled else "Disable", verify_value=False)
        await self._publish_dial(await c.get("pos", axis=axis))
        await self._settle_target()
        # LVIO says whether the position (VAL at start) is inside the limits: caproto's
        # record starts with LVIO=1.
        violation = limit_violation(self._dial, f.dial_low_limit.value,
                                    f.dial_high_limit.value)
        await f.limit_violation.write(int(violation is not None), verify_value=False)

    async def units_read(self, units: AxisUnits, decimals: int, *,
                         force: bool = False) -> None:
        """Publish what follows from the unit settings (EGU, PREC, MRES, UREV, SREV,
        RDBD, and the speeds in EGU/s) if they changed since last read (or ``force``)."""
        f = self._f
        if not force and units == self.units and decimals == self._decimals:
            return
        self.units, self._decimals = units, decimals
        egu = units.egu
        await self.record.write_metadata(units=egu, precision=decimals)
        if f.engineering_units.value != egu:
            await f.engineering_units.write(egu)
        for field in ("RBV", "DRBV", "DVAL", "HLM", "LLM", "DHLM", "DLLM", "DRVH", "DRVL",
                      "RDBD", "MRES", "UREV"):
            await self.record.fields[field].write_metadata(precision=decimals, units=egu)
        for field, value in ((f.motor_step_size, units.mres),
                             (f.encoder_step_size, units.mres),  # no encoder: ERES=MRES
                             (f.display_precision, decimals),
                             (f.egu_s_per_revolution, units.urev),
                             (f.steps_per_revolution, units.srev),
                             (f.retry_deadband, units.rdbd(decimals))):
            if field.value != value:
                await field.write(value, verify_value=False)
        await self._read_speed()

    async def follow_limits(self) -> None:
        """Publish the soft limits if they changed through another path (the driver's
        cached limits: read again only after a line that may have changed them)."""
        f = self._f
        low, high = await self.controller.axis_limits(self.letter)
        if (low, high) != (f.dial_low_limit.value, f.dial_high_limit.value):
            await self._publish_limits(low, high)

    async def _read_speed(self) -> None:
        c, axis, f = self.controller, self.letter, self._f
        velo = self.units.velo_from_vel(float(await c.get("vel", axis=axis)))
        accel = float(await c.get("accel", axis=axis))
        await f.velocity.write(velo, verify_value=False)
        if f.max_velocity.value <= 0:
            # VMAX starts at the speed the controller is set to (its saved `vel`, the one
            # speed known to suit the stage), not the `vel` ceiling of 200 rev/s (L3452);
            # a client raises it with a VMAX put, and it stays where it is put.
            await f.max_velocity.write(velo, verify_value=False)
        await f.seconds_to_velocity.write(self.units.accl_from_accel(velo, accel),
                                          verify_value=False)
        accs = self.units.accs_from_accel(accel)
        if f.move_acceleration.value != accs:
            await f.move_acceleration.write(accs, verify_value=False)
        await self._publish_speeds(f.max_velocity.value)

    async def _read_limits(self) -> None:
        await self._publish_limits(*await self.controller.axis_limits(self.letter,
                                                                      cached=False))

    async def _publish_limits(self, low: float, high: float) -> None:
        f = self._f
        offset = f.user_offset.value
        await f.dial_low_limit.write(float(low), verify_value=False)
        await f.dial_high_limit.write(float(high), verify_value=False)
        await f.user_low_limit.write(float(low) + offset, verify_value=False)
        await f.user_high_limit.write(float(high) + offset, verify_value=False)
        await self._publish_drive_limits(offset)

    async def _publish_drive_limits(self, offset: float) -> None:
        """VAL's control and display limits are the user soft limits, DVAL's and
        DRVH/DRVL the dial ones, as the motor record serves them (clients check a
        target against them before they put; :class:`HandledDouble`)."""
        f = self._f
        low, high = f.dial_low_limit.value, f.dial_high_limit.value
        await self.record.write_metadata(
            lower_disp_limit=low + offset, upper_disp_limit=high + offset,
            lower_ctrl_limit=low + offset, upper_ctrl_limit=high + offset)
        await f.dial_desired_value.write_metadata(
            lower_disp_limit=low, upper_disp_limit=high, lower_ctrl_limit=low,
            upper_ctrl_limit=high)
        for field, value in ((f.drive_high_limit, high), (f.drive_low_limit, low)):
            if field.value != value:
                await field.write(value, verify_value=False)

    async def _publish_dial(self, dial: float) -> None:
        self._dial = float(dial)
        f = self._f
        await self._publish_changed(f.dial_readback_value, self._dial)
        await self._publish_changed(f.user_readback_value, self._dial + f.user_offset.value)
        await self._publish_derived()

    def _derived(self) -> dict[str, float]:
        """The raw, difference and last-value fields (:func:`~.record.derived_fields`)."""
        f = self._f
        return derived_fields(val=self.record.value, dval=f.dial_desired_value.value,
                              drbv=f.dial_readback_value.value, mres=self.units.mres)

    async def _publish_derived(self) -> None:
        await self._publish_fields(self._derived())

    async def _publish_speeds(self, vmax: float) -> None:
        await self._publish_fields(revolution_speeds(velo=self._f.velocity.value,
                                                     vmax=vmax, urev=self.units.urev))

    async def _publish_fields(self, values: Mapping[str, float]) -> None:
        """Write each field whose value changed."""
        fields = self.record.fields
        for name, value in values.items():
            if fields[name].value != value:
                await fields[name].write(value, verify_value=False)

    async def _publish_changed(self, channel: Any, value: float) -> None:
        """Write ``value`` to a readback only if it moved by more than MDEL from the value
        last sent (any change with MDEL=0), as the motor record posts its monitors."""
        f = self._f
        deadband = max(f.monitor_deadband.value, 0.0)
        last = channel.value
        if value == last or (abs(value - last) <= deadband and deadband > 0):
            return
        await channel.write(value, verify_value=False)  # keeps the record's alarm

    async def poll_update(self, dial: float, letter: str) -> None:
        """Publish a polled position and status letter (DMOV=1 once a move that lost
        its link is seen to stand)."""
        await self._publish_dial(dial)
        if not self._busy:
            moving = letter == MOVING
            self._standing_unknown = False
            f = self._f
            if f.motor_is_moving.value != int(moving):
                await f.motor_is_moving.write(int(moving), verify_value=False)
            if f.done_moving_to_value.value != int(not moving):
                await f.done_moving_to_value.write(int(not moving), verify_value=False)
        await self._publish_status(moving=letter == MOVING)

    async def slow_update(self, readsw: str, statuslimit: str) -> None:
        """Publish the limit switches and the homed state."""
        self._switches = limit_switches(readsw, self.letter)
        self._homed = calibrated(statuslimit, self.letter)
        f = self._f
        if f.user_high_limit_switch.value != int(self._switches.high):
            await f.user_high_limit_switch.write(int(self._switches.high), verify_value=False)
        if f.user_low_limit_switch.value != int(self._switches.low):
            await f.user_low_limit_switch.write(int(self._switches.low), verify_value=False)
        # DIR is always Pos: the raw switches are the user ones.
        await self._publish_fields({"RHLS": int(self._switches.high),
                                    "RLLS": int(self._switches.low)})
        await self._publish_status()

    async def _publish_status(self, moving: bool | None = None) -> None:
        f = self._f
        if moving is None:
            moving = bool(f.motor_is_moving.value)
        word = msta(moving=moving or bool(self._busy) or self._standing_unknown,
                    switches=self._switches,
                    problem=self._problem, comm_error=not self.server.link_up,
                    homed=self._homed, positive=self._positive)
        if f.motor_status.value != word:
            await f.motor_status.write(word, verify_value=False)

    async def link_changed(self, up: bool) -> None:
        """The link went down (INVALID/COMM alarm) or came back (settings re-read)."""
        if up:
            await self.read_settings()
        await self._show_alarm(up)  # the fault of a failed move outlives the link's loss
        await self._publish_status()

    async def assert_invalid(self) -> None:
        """Keep the INVALID alarm while the link is down (a failed put overwrites it)."""
        if self.record.alarm.severity != AlarmSeverity.INVALID_ALARM:
            await self.link_changed(False)
