"""The Channel Access IOC: TANGO axes as motor records, served by caproto.

For each controller (prefix ``P:``, or ``P:name:`` with several controllers):

* ``P:X`` ... ``P:A``: a motor record per present axis (see :mod:`.record` for units).
  A put to VAL starts the move (through a :class:`~tango_aio.group._coalesce.MoveCoalescer`,
  so puts to different axes that arrive together become one ``!moa`` line); a put with
  callback completes when the move has ended and the final RBV, MOVN=0 and DMOV=1 are on
  the wire to every client (:mod:`.flush`). A move that ends anywhere but at its target
  (any status letter but @/A/D, a controller error, a lost link, a refused line) fails
  the put, sets the MSTA problem bit and puts the record and its fields in a MAJOR alarm
  until a move ends at its target (one rule for every PV of the axis,
  :func:`~.record.fault_after`: STOP and SPMG neither raise nor clear it); VAL and DVAL
  are then where the axis stands, as after STOP or SPMG=Stop (the motor record's rule;
  SPMG=Pause keeps them, Go resumes toward VAL).
* ``P:CONNECTED`` (0/1), ``P:ERROR`` (number of the last error: the controller's error
  number, -1 for a failure without one, 0 none), ``P:ERROR:TEXT``, ``P:AUTOSTATUS``,
  ``P:TRIGCOUNT``.

One poller per controller reads ``?pos`` and ``?statusaxis`` every ``poll`` seconds and
``?readsw``, ``?statuslimit`` and ``?trigcount`` every fifth time. While the link is down
every PV but CONNECTED is in an INVALID/COMM alarm; when the driver has reconnected
(``connect(url, reconnect=True)``) the settings are read again and the alarms go back to
the axis's own (a move that failed with the link still shows its fault). Every fifth poll
also publishes the soft limits the driver knows (read again after any line that may
change them), and every 25th reads the unit settings (``dim``, ``pitch``, ``gear``,
``usteps``, ``resolution``), so the limits, EGU, PREC, MRES, UREV, SREV, RDBD and the
speeds follow a change made through any path.

Choices (the motor record documentation leaves room, the TANGO has no such concepts):

* Motion requests run one at a time per axis (:class:`AxisServer`): a VAL put during a
  move retargets (the one-axis stop ``a x``, L6785-6844, then the new move), and a newer
  request replaces a waiting one. STOP, and SPMG set to Stop or Pause, stop the axis the
  same way and drop every waiting request; the stopped put fails (the target was not
  reached), its alarm left as it was. While SPMG is Stop or Pause every motion request is refused
  (the flag is set before the stop is awaited, so a VAL right behind it is refused too);
  Pause then Go resumes the move toward VAL.
* HOMR runs ``cal`` (reverse, to the lower limit switch, sets the origin, L5259), HOMF
  runs ``rm`` (forward, to the upper limit switch, sets the upper limit, L5343).
* SET=Set: a put to VAL redefines the position instead of moving; with FOFF=Variable the
  user offset OFF changes, with FOFF=Frozen the controller's position is set (``!pos``,
  L6900).
* HLM/LLM and DHLM/DLLM are the controller's soft limits (``!lim``, L4522), served as
  VAL's (user) and DVAL's, DRVH's and DRVL's (dial) control limits, which clients check
  before they put; a target outside them sets LVIO=1, keeps VAL, blinks DMOV (0, then 1)
  and fails the put, with the axis in a HIGH or LOW/MAJOR alarm, before anything is sent
  (the motor record's rule, limits 0 and 0 meaning none).
* VELO sets ``vel`` (at most VMAX, which starts at the controller's own speed); ACCL sets
  ``accel`` so that VELO is reached in ACCL seconds; a new VELO keeps ``accel`` (ACCL is
  recomputed: ACCU is Accs, ACCS the acceleration in EGU/s²). DVAL and RLV move through
  VAL, SSET/SUSE switch SET; DIR (but Pos), VBAS (but 0), JOGF/JOGR/JVEL, RVAL and MRES
  refuse writes (:data:`REFUSED`), and every field not in :data:`WRITABLE` is read-only.
* CNEN Enable/Disable sends ``!axis <axis> 1`` / ``0`` (L3919: a disabled axis keeps its
  motor current, so a vertical axis does not drop; ``-1``, power off, is never sent). A
  moving axis is stopped first, as by STOP: the manual does not say what disabling does
  to a move (L3919-3960).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
from collections.abc import Awaitable, Callable, Mapping, Sequence
from contextvars import ContextVar
from typing import Any

from caproto import AccessRights, AlarmSeverity, AlarmStatus, CAStatus, Forbidden, SkipWrite
from caproto.server import PVGroup, pvproperty
from caproto.server.menus import motorDIR, motorSPMG, motorTORQ
from caproto.server.records import MotorFields, register_record
from caproto.server.server import (
    PvpropertyDouble,
    PvpropertyEnum,
    PvpropertyInteger,
    PvpropertyShort,
)

from ..catalog import AXES, lookup, upper_bound
from ..controller import Controller
from ..errors import (
    ConnectionLostError,
    ControllerError,
    MotorRefusedError,
    MoveError,
    MoveStoppedError,
    TangoError,
)
from ..group import MoveCoalescer
from ..status import ARRIVED_LETTERS, MOVING, AxisStatus
from ..units import DEFAULT_USTEPS
from .access import AccessPolicy
from .autosave import SAVED, Autosave
from .flush import FlushingContext
from .record import (
    NO_ALARM,
    AxisUnits,
    Ending,
    LimitSwitches,
    calibrated,
    fault_after,
    limit_switches,
    limit_violation,
    msta,
    shown_alarm,
)

__all__ = ["MotorRefusedError", "MoveStoppedError", "TangoIoc", "build_ioc"]

log = logging.getLogger("tango_aio.epics")

#: The fields that show the link's INVALID alarm with the record.
ALARM_FIELDS = ("RBV", "DRBV", "DMOV", "MOVN", "MSTA", "HLS", "LLS", "LVIO", "VELO",
                "VMAX", "ACCL", "HLM", "LLM", "DHLM", "DLLM", "OFF", "CNEN", "DVAL")

#: The fields whose put rewrites the autosave file (user limits are saved as dial ones).
AUTOSAVED = frozenset({"OFF", "HLM", "LLM", "DHLM", "DLLM", "VELO", "VMAX"})

#: The largest magnitude a float field takes (positions are at most a few metres in any
#: unit; this refuses 1e308 and friends, which would overflow user = dial + OFF).
MAX_MAGNITUDE = 1e9

#: Why each field this IOC serves but does not carry out refuses a write.
REFUSED = {
    "DIR": "only Pos is supported (user and dial directions are the same)",
    "VBAS": "a TANGO axis has no base velocity; only 0 is accepted",
    "RVAL": "raw steps are not exposed; put VAL or DVAL",
    "MRES": "the resolution follows the controller's dim, pitch and usteps",
    "JOGF": "jogging is not supported; use TWF/TWR or VAL",
    "JOGR": "jogging is not supported; use TWF/TWR or VAL",
    "JVEL": "jogging is not supported",
}

#: How many polls of ``?pos``/``?statusaxis`` per read of switches and counters.
SLOW_EVERY = 5

#: How many polls per read of the unit settings (five reads, pipelined).
UNITS_EVERY = 5 * SLOW_EVERY


def _finite(pvname: str, field: str, value: float) -> None:
    """Refuse NaN, infinities and absurd magnitudes before anything is done."""
    if not math.isfinite(value) or abs(value) > MAX_MAGNITUDE:
        raise MotorRefusedError(f"{pvname}.{field}: {value!r} is not a usable number")


def _number(text: str | None) -> float | None:
    """``text`` as a finite number, or ``None`` (not given, or not a number)."""
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _start_motion(motion: Callable[[], Awaitable[Any]]
                 ) -> tuple[asyncio.Task[Any], asyncio.Future[None]]:
    """Run ``motion`` in a task; return it and a future set once it has ended.

    The future is set in the motion's own last step, so whoever awaits it resumes one loop
    turn after the motion ended (awaiting the task through ``asyncio.wait`` takes two: the
    done-callback's turn, then the waiter's), and finds the task done. A task cancelled
    before its first step never runs the motion; its done-callback sets the future then.
    Cancelling the future's waiter leaves the task alone.

    Parameters
    ----------
    motion
        Makes the coroutine to run.

    Returns
    -------
    tuple[asyncio.Task[Any], asyncio.Future[None]]
        The task, and the future set once it has ended.
    """
    ended: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def settle(_: object = None) -> None:
        if not ended.done():
            ended.set_result(None)

    async def run() -> Any:
        try:
            return await motion()
        finally:
            settle()

    task = asyncio.ensure_future(run())
    task.add_done_callback(settle)
    return task, ended


def _log_failure(task: asyncio.Future[Any]) -> None:
    """Done-callback of a background move (Pause, then Go): log how it failed."""
    if not task.cancelled() and task.exception() is not None:
        log.warning("resumed move failed: %s", task.exception())


# ---------------------------------------------------------------------------- the record


def _axis_of(fields: Any) -> AxisServer:
    """The :class:`AxisServer` behind a record's field group."""
    axis: AxisServer = fields.parent.group.axis
    return axis


def _put(field: str) -> Callable[[Any, Any, Any], Awaitable[Any]]:
    """The put handler of ``field``: :meth:`AxisServer.put_field` does the work."""

    async def put(fields: Any, instance: Any, value: Any) -> Any:
        return await _failure_is_ours(_axis_of(fields).put_field(field, value))

    put.__name__ = f"_put_{field.lower()}"
    return put


def _field(name: str, dtype: Any, doc: str, **kwargs: Any) -> Any:
    return pvproperty(name=name, dtype=dtype, doc=doc, put=_put(name), **kwargs)


class _Handled:
    """A numeric channel whose put only its handler judges. caproto's own check of a
    numeric put refuses a value beyond the control limits and re-applies the alarm its
    value limits give (none here), which would clear the axis's alarm on every field
    sharing it (a STOP put clearing RBV's alarm). So VAL and DVAL serve control limits,
    which clients check before they put (classic ophyd's ``check_value``), while a put
    beyond them still reaches the handler, which refuses it as the motor record does
    (LVIO=1, no motion); and a field's put leaves the axis's alarm to its own rule.
    """

    putter: Any

    async def verify_value(self, value: Any) -> Any:
        """Hand the value to the put handler without caproto's checks.

        Parameters
        ----------
        value
            The value put.

        Returns
        -------
        Any
            What the handler returns.
        """
        if self.putter is not None:
            return await self.putter(self, value)
        return value


class HandledDouble(_Handled, PvpropertyDouble):  # type: ignore[misc]
    """A double field judged by its put handler only (:class:`_Handled`)."""


class HandledShort(_Handled, PvpropertyShort):  # type: ignore[misc]
    """A short field judged by its put handler only (:class:`_Handled`)."""


class HandledInteger(_Handled, PvpropertyInteger):  # type: ignore[misc]
    """An integer field judged by its put handler only (:class:`_Handled`)."""


@register_record
class TangoMotorFields(MotorFields):  # type: ignore[misc]
    """The motor record's fields, with handlers that drive a TANGO axis.

    Registered under its own record type name, so caproto's plain ``motor`` record is left
    alone; RTYP still reads ``motor``. (A field's handler can only be replaced by declaring
    the field again in a subclass.) Fields not in :data:`WRITABLE` refuse writes.

    Parameters
    ----------
    *args, **kwargs
        caproto's arguments of a record's fields.
    """

    _record_type = "tango_motor"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # RTYP must read "motor" from the first client read on, before any await. caproto
        # (1.3) has no public synchronous setter for a read-only field: ChannelData.write
        # is a coroutine, a pvproperty's ``value=`` is overwritten by
        # records.RecordFieldGroup.__init__ with ``_record_type`` (which must stay
        # "tango_motor", the registry key), and that __init__ itself sets RTYP and NAME
        # by writing ``_data["value"]``. So this does what caproto does.
        self.record_type._data["value"] = "motor"
        self.parent.reported_record_type = "motor"

    stop = _field("STOP", HandledShort, "Stop")
    stop_pause_move_go = _field("SPMG", PvpropertyEnum, "Stop/Pause/Move/Go", value=3,
                                enum_strings=motorSPMG.get_string_tuple())
    velocity = _field("VELO", HandledDouble, "Velocity (EGU/s)")
    max_velocity = _field("VMAX", HandledDouble, "Max. Velocity (EGU/s)")
    base_velocity = _field("VBAS", HandledDouble, "Base Velocity (EGU/s)")
    seconds_to_velocity = _field("ACCL", HandledDouble, "Seconds to Velocity",
                                 value=0.2)
    user_high_limit = _field("HLM", HandledDouble, "User High Limit")
    user_low_limit = _field("LLM", HandledDouble, "User Low Limit")
    dial_high_limit = _field("DHLM", HandledDouble, "Dial High Limit")
    dial_low_limit = _field("DLLM", HandledDouble, "Dial Low Limit")
    tweak_motor_forward = _field("TWF", HandledShort, "Tweak motor Forward")
    tweak_motor_reverse = _field("TWR", HandledShort, "Tweak motor Reverse")
    tweak_step_size = _field("TWV", HandledDouble, "Tweak Step Size (EGU)")
    home_forward = _field("HOMF", HandledShort, "Home Forward")
    home_reverse = _field("HOMR", HandledShort, "Home Reverse")
    user_offset = _field("OFF", HandledDouble, "User Offset (EGU)")
    enable_control = _field("CNEN", PvpropertyEnum, "Enable control", value=1,
                            enum_strings=motorTORQ.get_string_tuple())
    user_direction = _field("DIR", PvpropertyEnum, "User Direction", value=0,
                            enum_strings=motorDIR.get_string_tuple())
    relative_value = _field("RLV", HandledDouble, "Relative Value")
    dial_desired_value = _field("DVAL", HandledDouble, "Dial Desired Value (EGU)")
    raw_desired_value = _field("RVAL", HandledInteger, "Raw Desired Value")
    set_set_mode = _field("SSET", HandledShort, "Set SET Mode")
    set_use_mode = _field("SUSE", HandledShort, "Set USE Mode")
    motor_step_size = _field("MRES", HandledDouble, "Motor Step Size (EGU)")
    jog_motor_forward = _field("JOGF", HandledShort, "Jog motor Forward")
    jog_motor_reverse = _field("JOGR", HandledShort, "Jog motor Reverse")
    jog_velocity = _field("JVEL", HandledDouble, "Jog Velocity (EGU/s)")
    monitor_deadband = _field("MDEL", HandledDouble, "Monitor Deadband")
    move_acceleration = pvproperty(name="ACCS", dtype=PvpropertyDouble, read_only=True,
                                   doc="Move Accel. (EGU/s^2)")
    acceleration_used = pvproperty(name="ACCU", dtype=PvpropertyEnum, read_only=True,
                                   value="Accs", enum_strings=("Undef", "Accl", "Accs"),
                                   doc="ACCS used")
    drive_high_limit = pvproperty(name="DRVH", dtype=PvpropertyDouble, read_only=True,
                                  doc="Drive High Limit (dial EGU)")
    drive_low_limit = pvproperty(name="DRVL", dtype=PvpropertyDouble, read_only=True,
                                 doc="Drive Low Limit (dial EGU)")
    archive_deadband = _field("ADEL", HandledDouble, "Archive Deadband")


#: The fields a client may write (besides VAL); every other field refuses writes.
WRITABLE = frozenset({
    "STOP", "SPMG", "VELO", "VMAX", "VBAS", "ACCL", "HLM", "LLM", "DHLM", "DLLM", "TWF",
    "TWR", "TWV", "HOMF", "HOMR", "OFF", "CNEN", "DIR", "RLV", "DVAL", "RVAL", "SSET",
    "SUSE", "MRES", "JOGF", "JOGR", "JVEL", "SET", "FOFF", "MDEL", "ADEL", "DESC",
})


#: What failed the current put (set by the handler, read by :func:`_guard`).
_FAILED: ContextVar[Exception | None] = ContextVar("_FAILED", default=None)


async def _failure_is_ours(put: Awaitable[Any]) -> Any:
    """Await a put handler; a failure skips caproto's WRITE/MAJOR alarm, as the axis's
    alarm follows its own rule (:func:`~.record.fault_after`); the put still fails:
    :func:`_guard` answers ECA_PUTFAIL.

    Returns
    -------
    Any
        What the handler returned.

    Raises
    ------
    SkipWrite
        The handler raised.
    """
    try:
        return await put
    except Exception as exc:
        _FAILED.set(exc)
        raise SkipWrite from exc


async def _put_val(group: AxisGroup, instance: Any, value: float) -> Any:
    published = await _failure_is_ours(group.axis.move(float(value)))
    # A move published VAL as it started; writing it again now would post the same value
    # to every VAL monitor once more, on the put's own path (its response waits for it).
    return SkipWrite if published else value


class AxisGroup(PVGroup):  # type: ignore[misc]
    """One motor record (the PV is the group's prefix, e.g. ``P:X``).

    Parameters
    ----------
    prefix
        The record's PV name.
    axis
        The axis it drives.
    """

    motor = pvproperty(name="", value=0.0, dtype=HandledDouble, record="tango_motor",
                       precision=4, doc="TANGO axis", put=_put_val)

    def __init__(self, prefix: str, *, axis: AxisServer) -> None:
        self.axis = axis
        super().__init__(prefix)


class ControllerPVs(PVGroup):  # type: ignore[misc]
    """The PVs of one controller (``P:CONNECTED`` ...)."""

    # CONNECTED has an alarm of its own: it stays NO_ALARM while the others go INVALID.
    connected = pvproperty(name="CONNECTED", value=0, read_only=True,
                           alarm_group="connected",
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
    """Drives one axis for its motor record and publishes what the poller reads.

    Motion requests (VAL and the fields that move: DVAL, RLV, TWF/TWR, HOMF/HOMR) run one
    at a time. A new request first stops the running one (VAL during a move retargets)
    and replaces a request still waiting (the record has one VAL, so nothing piles up).
    STOP and SPMG Stop/Pause stop the running request and drop the waiting one. Every
    request carries a number (:attr:`_request`); one that is no longer the newest when
    its turn comes fails without moving.

    Parameters
    ----------
    server
        The controller's server.
    letter
        The axis letter.
    """

    def __init__(self, server: ControllerServer, letter: str) -> None:
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
        """Set the record's alarm and that of its fields (RBV shows INVALID too).

        caproto gives the record one alarm and its fields another, shared by all of them;
        each is written once. A numeric channel written *with* verification re-applies
        the alarm its own value limits give (none here), which would clear this one: the
        readbacks are therefore written with ``verify_value=False``.
        """
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
        """A client put ``value`` to ``field``: act on it, return the value to store.

        Raises (the put fails, ECA_PUTFAIL) for a value this IOC does not carry out.

        Parameters
        ----------
        field
            The motor record field (``"VAL"``, ``"VELO"``...).
        value
            The value put.

        Returns
        -------
        Any
            The value the field stores.

        Raises
        ------
        TangoError
            The IOC does not carry the value out (the put fails, ECA_PUTFAIL).
        """
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
        """Put back the autosaved fields (at start, once the controller is connected).

        Parameters
        ----------
        saved
            The autosaved value of each field, by field name.
        """
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
        return vmax

    # -- motion --------------------------------------------------------------------------

    async def move(self, target: float) -> bool:
        """VAL was put: move there (or redefine the position with SET=Set).

        The put announces itself to the coalescer as it starts, so a merged move being
        collected waits for it (puts to other axes that arrive together join one line)
        and a lone put waits for no time at all (see :mod:`tango_aio.group._coalesce`).

        Parameters
        ----------
        target
            The new VAL (user units).

        Returns
        -------
        bool
            Whether VAL was published (a move, as it started); False for SET=Set.
        """
        arrived = self.server.coalescer.announce()
        try:
            self._require_link()
            f = self._f
            self._require_go()
            _finite(self.record.pvname, "VAL", target)
            if f.set_use_switch.value == "Set":
                await self._redefine(target)
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
        DMOV's end sees one), and the put fails with the axis's alarm raised.

        Raises
        ------
        MotorRefusedError
            The target is beyond the soft limits.
        """
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
                   positive: bool = True, confirmed: Mapping[str, str] | None = None
                   ) -> None:
        """Run ``motion`` once it is this request's turn, with DMOV=0; before returning,
        publish RBV, MOVN=0 and DMOV=1 (unless another request follows) and wait until
        those updates are on the wire to every client.

        ``confirmed``: where ``motion`` leaves the positions its move's confirmation read
        behind the report (the axis read stopped, then its position, nothing written in
        between); after a successful move RBV comes from there instead of another ``?pos``
        (a round trip, about 4 ms at 57600 Bd, on the path of every put).

        The motion runs in a task of its own, which :meth:`stop` cancels: a move not yet
        sent is withdrawn, a running one is stopped (by the coalescer or the controller).

        Raises
        ------
        MoveStoppedError
            The request was replaced or stopped before it started, or the move was stopped.
        TangoError
            The motion failed (the record shows the alarm).
        """
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
                await self._motion_of(motion, request)
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
                await self._finish(arrived_at, settle=settle)

    def _ended(self, request: int) -> None:
        self._busy -= 1
        ended = self._ongoing.pop(request, None)
        if ended is not None:
            ended.set()

    async def _motion_of(self, motion: Callable[[], Awaitable[Any]], request: int) -> None:
        """Run ``motion`` in a task :meth:`stop` can cancel; raise what ended it short."""
        f = self._f
        if f.motor_is_moving.value != 1:
            await f.motor_is_moving.write(1, verify_value=False)
        await self._publish_status()
        task, ended = _start_motion(motion)
        self._motion = task
        try:
            await ended  # set in the motion's last step: one loop turn, not two
        except asyncio.CancelledError:  # the IOC shuts down: stop the move
            task.cancel()
            await asyncio.wait([task])
            raise
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

    async def _finish(self, confirmed: str | None = None, *, settle: bool = False) -> None:
        """A request ended: publish the position (``confirmed``, as printed by the read
        that confirmed its move's arrival, else read now), with ``settle`` VAL and DVAL
        too (where the axis stopped); unless another request follows, publish MOVN=0 and
        DMOV=1 (only while the link is up: a move that lost its link has not been seen to
        stand); then wait until every client has those updates."""
        f = self._f
        self.finished += 1  # a poll in flight read the axis before this request ended
        dial = _number(confirmed)
        with contextlib.suppress(TangoError):
            await self._publish_dial(dial if dial is not None
                                     else await self.controller.get("pos", axis=self.letter))
            if settle:
                await self._settle_target()
        if not self.controller.connected:
            self._standing_unknown = True
            await self.server.link_lost()
        elif not self._busy:
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

    async def stop(self, *, keep_target: bool = False) -> None:
        """STOP, or SPMG Stop/Pause: stop this axis, drop every waiting request, and
        return once it stands still.

        A move this IOC started and not yet sent is withdrawn; otherwise the axis gets the
        one-axis stop ``a x`` (L6785-6844): the other axes of a merged line go on. VAL and
        DVAL are then set to where the axis stands, but with ``keep_target`` (SPMG=Pause,
        which the motor record resumes toward VAL on Go).

        Parameters
        ----------
        keep_target
            Leave VAL and DVAL at the stopped target.
        """
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
        """TWF/TWR: move VAL by TWV.

        Parameters
        ----------
        sign
            +1 for TWF, -1 for TWR.
        """
        f = self._f
        await self.move(self.record.value + sign * abs(f.tweak_step_size.value))

    async def home(self, *, forward: bool) -> None:
        """HOMF: ``rm`` (upper switch); HOMR: ``cal`` (lower switch).

        Parameters
        ----------
        forward
            True for HOMF, False for HOMR.
        """
        self._require_link()
        self._require_go()
        run = self.controller.measure_range if forward else self.controller.calibrate
        try:
            await self._run(lambda: run(self.letter), positive=forward)
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
            await f.user_offset.write(target - self._dial)  # through OFF's handler

    # -- settings ------------------------------------------------------------------------

    async def set_velocity(self, velo: float, *, vmax: float | None = None) -> float:
        """VELO was put: set ``vel`` (a VELO above VMAX is VMAX, as in the motor record);
        returns the VELO the controller took.

        Parameters
        ----------
        velo
            The VELO put (EGU/s).
        vmax
            The VMAX in force; ``None`` for the field's current value.

        Returns
        -------
        float
            The VELO the controller took.

        Raises
        ------
        MotorRefusedError
            ``velo`` is not positive.
        """
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
        """ACCL was put: set ``accel`` so VELO is reached in ``accl`` seconds.

        Parameters
        ----------
        accl
            The ACCL put (seconds).

        Returns
        -------
        float
            The ACCL the controller took.

        Raises
        ------
        MotorRefusedError
            ``accl`` is not a positive number of seconds.
        """
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
        """HLM/LLM/DHLM/DLLM was put: set the controller's soft limits (``!lim``).

        Parameters
        ----------
        high
            True for the high limit, False for the low one.
        dial
            The new limit, in dial units.

        Returns
        -------
        float
            The user limit the controller took.
        """
        self._require_link()
        f = self._f
        low, up = f.dial_low_limit.value, f.dial_high_limit.value
        low, up = (low, dial) if high else (dial, up)
        await self.controller.command(f"!lim {self.letter} {low} {up}")
        await self._read_limits()
        limit: float = (f.user_high_limit if high else f.user_low_limit).value
        return limit

    async def offset_changed(self, offset: float) -> None:
        """OFF changed: republish every user value (user = dial + OFF).

        Parameters
        ----------
        offset
            The new OFF.

        Raises
        ------
        MotorRefusedError
            ``offset`` is out of range.
        """
        f = self._f
        if abs(offset) > MAX_MAGNITUDE:
            raise MotorRefusedError(f"{self.record.pvname}.OFF {offset!r} is out of range")
        await f.user_readback_value.write(self._dial + offset, verify_value=False)
        await f.user_high_limit.write(f.dial_high_limit.value + offset, verify_value=False)
        await f.user_low_limit.write(f.dial_low_limit.value + offset, verify_value=False)
        await self._publish_drive_limits(offset)

    async def set_enabled(self, enabled: bool) -> None:
        """CNEN was put: ``!axis x 1`` or ``!axis x 0`` (L3919-3960).

        The manual does not say what disabling a moving axis does to its move (it may go
        on, stop, or the line be refused: the emulator's ``disable_during_move``), so a
        moving axis is first stopped as by STOP (its put fails, VAL is where it stood,
        no alarm), then disabled: the same outcome whatever the controller does.

        Parameters
        ----------
        enabled
            The CNEN put.
        """
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
        RDBD, and the speeds in EGU/s) if they changed since last read (or ``force``).

        Parameters
        ----------
        units
            The axis's unit settings, as just read.
        decimals
            The decimals the controller prints positions with (PREC).
        force
            Publish even if nothing changed.
        """
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
        its link is seen to stand).

        Parameters
        ----------
        dial
            The position read, in dial units.
        letter
            The axis's status letter.
        """
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
        """Publish the limit switches and the homed state.

        Parameters
        ----------
        readsw
            The ``?readsw`` reply.
        statuslimit
            The ``?statuslimit`` reply.
        """
        self._switches = limit_switches(readsw, self.letter)
        self._homed = calibrated(statuslimit, self.letter)
        f = self._f
        if f.user_high_limit_switch.value != int(self._switches.high):
            await f.user_high_limit_switch.write(int(self._switches.high), verify_value=False)
        if f.user_low_limit_switch.value != int(self._switches.low):
            await f.user_low_limit_switch.write(int(self._switches.low), verify_value=False)
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
        """The link went down (INVALID/COMM alarm) or came back (settings re-read).

        Parameters
        ----------
        up
            Whether the link is up.
        """
        if up:
            await self.read_settings()
        await self._show_alarm(up)  # the fault of a failed move outlives the link's loss
        await self._publish_status()

    async def assert_invalid(self) -> None:
        """Keep the INVALID alarm while the link is down (a failed put overwrites it)."""
        if self.record.alarm.severity != AlarmSeverity.INVALID_ALARM:
            await self.link_changed(False)


# ------------------------------------------------------------------------ the controller


class ControllerServer:
    """The PVs of one controller: its axes and controller PVs, and the poller.

    Parameters
    ----------
    controller
        The connected controller.
    prefix
        The PV prefix of its PVs.
    poll, window, merge, autosave
        As for :func:`build_ioc`.
    group
        The controller PVs, if already served (a waiting controller's); ``None`` for new
        ones.
    """

    def __init__(self, controller: Controller, prefix: str, *, poll: float = 0.1,
                 window: float = 0.02, merge: str = "turn",
                 autosave: Autosave | None = None,
                 group: ControllerPVs | None = None) -> None:
        self.controller = controller
        self.autosave = autosave
        self._restored = autosave is None
        self.prefix = prefix
        self.poll = poll
        # merge="turn": no fixed wait. VAL puts announce themselves as they start, and a
        # merged move waits only for the puts already on their way (those that arrived
        # together, e.g. in one TCP read), ``window`` bounding that wait; a lone put
        # waits for nothing. merge="window": every move waits ``window`` seconds for
        # puts to other axes (a client that writes them one by one, each flushed).
        if merge not in ("turn", "window"):
            raise ValueError(f"merge must be 'turn' or 'window', got {merge!r}")
        self.coalescer = MoveCoalescer(controller, window=window,
                                       collect="announced" if merge == "turn" else "window")
        self.group = group if group is not None else ControllerPVs(prefix)
        self.link_up = controller.connected
        self._lacking: set[str] = set()  # settings this controller refused
        self.context: FlushingContext | None = None
        # The context's axis count: set by identification, or the connect() default when
        # the controller was connected with identify=False (the identity is not read).
        count = controller.context.axes
        self.axes = [AxisServer(self, letter) for letter in AXES[:count]]

    @property
    def pvdb(self) -> dict[str, Any]:
        """Every PV of this controller, by name."""
        pvdb: dict[str, Any] = dict(self.group.pvdb)
        for axis in self.axes:
            pvdb.update(axis.group.pvdb)
        return pvdb

    async def start(self) -> None:
        """Read the settings and publish the first values (with the controller down, the
        PVs start INVALID and the poller connects them when it comes)."""
        try:
            await self._set_link(self.controller.connected, force=True)
        except ConnectionLostError:
            await self._set_link(False, force=True)

    async def read_units(self) -> tuple[dict[str, AxisUnits], int]:
        """Read every axis's unit settings (``dim``, ``pitch``, ``gear``, ``usteps``) and
        the decimals of printed positions (``resolution``), pipelined.

        Returns
        -------
        tuple[dict[str, AxisUnits], int]
            The unit settings by axis letter, and the decimals.
        """
        c = self.controller
        dims, pitch, gear, usteps, decimals = await asyncio.gather(
            c.get("dim"), c.get("pitch"), self._optional("gear", None),
            self._optional("usteps", DEFAULT_USTEPS), self._optional("resolution", 4))
        units = {axis.letter: AxisUnits(
            int(dims[axis.letter]), float(pitch[axis.letter]),
            float(gear[axis.letter]) if isinstance(gear, Mapping) else 1.0, int(usteps))
            for axis in self.axes}
        return units, int(decimals)

    async def _optional(self, name: str, default: Any) -> Any:
        """Read ``name``; a controller that refuses it (older firmware may lack gear,
        usteps or resolution) gives ``default``, with one warning, and is not asked again.

        Returns
        -------
        Any
            The value read, or ``default``.
        """
        if name in self._lacking:
            return default
        try:
            return await self.controller.get(name)
        except ControllerError as exc:
            self._lacking.add(name)
            log.warning("%s: ?%s refused (%s); assuming %s", self.prefix, name, exc,
                        default)
            return default

    async def flush(self) -> None:
        """Wait until the monitor updates published so far are on the wire to every
        client (no-op before the server runs)."""
        if self.context is not None:
            await self.context.flush()

    async def link_lost(self) -> None:
        """A request saw the link down: every PV but CONNECTED goes INVALID now."""
        await self._set_link(False)

    async def report_error(self, exc: BaseException) -> None:
        """Publish ``exc`` as the last error (``P:ERROR``, ``P:ERROR:TEXT``).

        Parameters
        ----------
        exc
            The error.
        """
        number = exc.number if isinstance(exc, ControllerError) else -1
        await self.group.error.write(number, verify_value=False)
        await self.group.error_text.write(str(exc)[:255], verify_value=False)
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
        await group.connected.write(int(up), verify_value=False)
        if up:
            await group.autostatus.write(self.controller.autostatus, verify_value=False)
            log.info("%s: connected to %s", self.prefix, self.controller.url)
            if not self._restored and self.autosave is not None:
                for axis in self.axes:
                    saved = self.autosave.values.get(axis.record.pvname)
                    if saved:
                        await axis.restore(saved)
                self._restored = True
        # Up only once every setting was read: a failed read is tried again next poll.
        self.link_up = up

    async def run(self) -> None:
        """Poll until cancelled; follows the link down and up again."""
        count = 0
        while True:
            try:
                await self._poll_once(slow=count % SLOW_EVERY == 0,
                                      units=count % UNITS_EVERY == 0)
            except ConnectionLostError:
                pass  # seen as link down by the next round
            except TangoError as exc:  # a timeout, a garbled reply: try again later
                log.warning("%s: poll failed: %s", self.prefix, exc)
            count += 1
            await asyncio.sleep(self.poll)

    async def _poll_once(self, *, slow: bool, units: bool = False) -> None:
        c = self.controller
        if not c.connected:
            await self._set_link(False)
            for axis in self.axes:
                await axis.assert_invalid()
            return
        await self._set_link(True)
        seen = [axis.finished for axis in self.axes]
        positions = await c.position()
        letters = await c.status()
        for axis, finished in zip(self.axes, seen, strict=True):
            if axis.finished != finished:
                # A request of this axis ended while the poll read: what it published
                # (its RBV, MOVN=0, DMOV=1, maybe already sent as a put's completion) is
                # newer than this poll's letters and position, which may show it moving.
                continue
            await axis.poll_update(positions.get(axis.letter, 0.0),
                                   letters.get(axis.letter, AxisStatus.READY.value))
        if slow:
            readsw = await c.query("?readsw")
            statuslimit = await c.query("?statuslimit")
            settings = await self.read_units() if units else None
            for axis in self.axes:
                await axis.slow_update(readsw, statuslimit)
                # Settings changed through another path (the driver, another program on
                # this link, the IOC's own puts) show here.
                if settings is not None:
                    await axis.units_read(settings[0][axis.letter], settings[1])
                await axis.follow_limits()
            await self.group.trigcount.write(int(await c.get("trigcount")), verify_value=False)
            await self.group.autostatus.write(c.autostatus, verify_value=False)

    async def aclose(self) -> None:
        """Stop what the coalescer is moving."""
        await self.coalescer.aclose()


# --------------------------------------------------------------------------------- the IOC


def _guard(pv: Any, policy: AccessPolicy,
           on_error: Callable[[BaseException], Awaitable[None]], *,
           writable: bool = True) -> None:
    """Make ``pv`` refuse writes to clients the policy does not allow (status
    ECA_NOWTACCESS), and answer a put whose handler failed with the status ECA_PUTFAIL.

    caproto answers a failed put with an error message, which clients waiting for the
    put's callback do not all match to their put (caproto's own client then times out);
    EPICS base's server answers with the put-callback's status, as done here.
    """
    own_check, own_write = pv.check_access, pv.auth_write

    def check_access(hostname: str, username: str) -> AccessRights:
        rights = own_check(hostname, username)
        if not writable or not policy.may_write(hostname, username):
            rights &= ~AccessRights.WRITE
        return rights

    async def auth_write(hostname: str, username: str, *args: Any, **kwargs: Any) -> Any:
        _FAILED.set(None)
        try:
            status = await own_write(hostname, username, *args, **kwargs)
            failed = _FAILED.get()
            if isinstance(failed, MoveStoppedError):
                log.info("%s: put by %s@%s ended short: %s", pv.pvname, username,
                         hostname, failed)
                return CAStatus.ECA_PUTFAIL
            if failed is not None:
                raise failed
            return status
        except Forbidden:
            log.warning("%s: write refused to %s@%s", pv.pvname, username, hostname)
            return CAStatus.ECA_NOWTACCESS
        except Exception as exc:
            log.warning("%s: put by %s@%s failed: %s", pv.pvname, username, hostname, exc)
            await on_error(exc)
            return CAStatus.ECA_PUTFAIL

    pv.check_access = check_access
    pv.auth_write = auth_write


class WaitingServer:
    """A controller that could not be reached when the IOC started.

    Its controller PVs are served at once (``CONNECTED`` 0, the others INVALID); ``open``
    is tried again every ``retry`` seconds, and once it gives a controller the axes'
    motor records are added and served like those of the others.

    Parameters
    ----------
    open_controller
        Opens the controller.
    prefix
        The PV prefix of its PVs.
    poll, window, merge, autosave
        As for :class:`ControllerServer`.
    retry
        Seconds between two tries.
    """

    def __init__(self, open_controller: Callable[[], Awaitable[Controller]], prefix: str,
                 *, poll: float, window: float, autosave: Autosave | None,
                 retry: float = 2.0, merge: str = "turn") -> None:
        self.open_controller = open_controller
        self.prefix = prefix
        self.retry = retry
        self.group = ControllerPVs(prefix)
        self._options = {"poll": poll, "window": window, "merge": merge,
                         "autosave": autosave}
        self.server: ControllerServer | None = None

    @property
    def pvdb(self) -> dict[str, Any]:
        """The controller PVs, served while waiting."""
        return dict(self.group.pvdb)

    async def start(self) -> None:
        """Publish the waiting state: CONNECTED=0, every other PV INVALID."""
        for pv in (self.group.autostatus, self.group.trigcount, self.group.error,
                   self.group.error_text):
            await pv.alarm.write(status=AlarmStatus.COMM,
                                 severity=AlarmSeverity.INVALID_ALARM)
        await self.group.error_text.write(f"waiting for the controller at {self.prefix}",
                                          verify_value=False)

    async def connect(self) -> ControllerServer:
        """Try until the controller answers; return its server (started).

        Returns
        -------
        ControllerServer
            The server of the connected controller.
        """
        while True:
            try:
                controller = await self.open_controller()
            except (TangoError, OSError) as exc:
                log.info("%s: controller not reachable yet: %s", self.prefix, exc)
                await asyncio.sleep(self.retry)
                continue
            if _unidentified(controller):
                await controller.identify()
            server = ControllerServer(controller, self.prefix, group=self.group,
                                      **self._options)  # type: ignore[arg-type]
            await server.start()
            self.server = server
            return server


class TangoIoc:
    """An IOC serving one or more controllers. Build it with :func:`build_ioc`.

    Parameters
    ----------
    servers
        The servers of the connected controllers.
    policy
        Who may write.
    waiting
        The controllers not reachable yet.
    """

    def __init__(self, servers: Sequence[ControllerServer], policy: AccessPolicy,
                 waiting: Sequence[WaitingServer] = ()) -> None:
        self.servers = list(servers)
        self.waiting = list(waiting)
        self.policy = policy
        self.pvdb: dict[str, Any] = {}
        self._context: FlushingContext | None = None
        for server in self.servers:
            self._add(server.pvdb, server.report_error)
        for pending in self.waiting:  # read-only controller PVs: nothing to report
            self._add(pending.pvdb, _ignore)

    def _add(self, pvdb: Mapping[str, Any],
             on_error: Callable[[BaseException], Awaitable[None]]) -> None:
        """Serve ``pvdb`` too, each PV guarded by the access policy."""
        overlap = set(self.pvdb) & set(pvdb)
        if overlap:
            raise ValueError(f"PV names used twice: {sorted(overlap)[:3]}")
        for pv in pvdb.values():
            _guard(pv, self.policy, on_error)
            for name, field in getattr(pv, "fields", {}).items():  # "P:X.VELO"
                _guard(field, self.policy, on_error, writable=name in WRITABLE)
        self.pvdb.update(pvdb)

    async def start(self) -> None:
        """Read every controller's settings and publish the first values."""
        for server in self.servers:
            await server.start()
        for waiting in self.waiting:
            await waiting.start()

    async def _serve_when_connected(self, waiting: WaitingServer) -> None:
        server = await waiting.connect()
        server.context = self._context
        self.servers.append(server)
        self._add({name: pv for name, pv in server.pvdb.items()
                   if name not in self.pvdb}, server.report_error)
        log.info("%s: controller connected; serving its axes", waiting.prefix)
        await server.run()

    async def run(self, interfaces: Sequence[str] = ("127.0.0.1",)) -> None:
        """Serve on ``interfaces`` until cancelled; stops the moves this IOC started.

        Parameters
        ----------
        interfaces
            The addresses to serve Channel Access on.

        Raises
        ------
        RuntimeError
            The Channel Access server stopped.
        """
        context = self._context = FlushingContext(self.pvdb, list(interfaces))
        for server in self.servers:
            server.context = context
        tasks = [asyncio.ensure_future(server.run()) for server in self.servers]
        tasks += [asyncio.ensure_future(self._serve_when_connected(waiting))
                  for waiting in self.waiting]
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
            for waiting in self.waiting:
                if waiting.server is not None:
                    await waiting.server.controller.aclose()


async def _ignore(exc: BaseException) -> None:
    """No controller to report a failed put to yet."""


def _unidentified(controller: Controller) -> bool:
    """Whether ``controller`` was connected without reading its identity."""
    try:
        _ = controller.identity
    except RuntimeError:
        return True
    return False


async def build_ioc(controllers: Mapping[str, Controller], prefix: str, *,
                    policy: AccessPolicy | None = None, poll: float = 0.1,
                    window: float = 0.02, merge: str = "turn",
                    autosave: str | os.PathLike[str] | None = None,
                    waiting: Mapping[str, Callable[[], Awaitable[Controller]]] | None = None,
                    retry: float = 2.0) -> TangoIoc:
    """Build (and :meth:`~TangoIoc.start`) an IOC for ``controllers``.

    ``controllers`` maps a name to a connected controller; the name ``""`` gives PVs
    ``<prefix>X``, any other name ``<prefix><name>:X``. ``poll`` is the seconds between
    position reads.
    ``autosave``: a file that keeps OFF, the soft limits, VELO and VMAX across restarts
    (:mod:`.autosave`); its values are put back once each controller is connected.
    ``waiting`` maps names (as ``controllers``) to functions that open a controller not
    reachable yet: its controller PVs are served at once with ``CONNECTED`` 0, the
    function is tried every ``retry`` seconds, and its axes are served once it works.

    Parameters
    ----------
    controllers
        Connected controllers, by name.
    prefix
        The PV prefix.
    policy
        Who may write; ``None`` lets every client write.
    poll
        Seconds between position reads.
    window
        The longest wait of a merged move for puts to other axes, in seconds
        (``merge="window"``: the wait every move pays).
    merge
        How puts to different axes become one ``!moa`` line: ``"turn"`` merges
        the puts that arrive together (announced as they start, no fixed wait),
        ``"window"`` makes every put wait ``window`` seconds for others
        (:class:`~tango_aio.group._coalesce.MoveCoalescer`'s ``collect``).
    autosave
        The autosave file; ``None`` for none.
    waiting
        Functions that open controllers not reachable yet, by name.
    retry
        Seconds between two tries of a ``waiting`` function.

    Returns
    -------
    TangoIoc
        The started IOC; serve it with :meth:`~TangoIoc.run`.
    """
    saved = Autosave(autosave) if autosave is not None else None
    if saved is not None:
        saved.load()
    for controller in controllers.values():
        if controller.connected and controller.context.axes and _unidentified(controller):
            await controller.identify()  # connected with identify=False: axes unknown
    servers = [ControllerServer(controller, f"{prefix}{name}:" if name else prefix,
                                poll=poll, window=window, merge=merge, autosave=saved)
               for name, controller in controllers.items()]
    pending = [WaitingServer(opener, f"{prefix}{name}:" if name else prefix, poll=poll,
                             window=window, merge=merge, autosave=saved, retry=retry)
               for name, opener in (waiting or {}).items()]
    ioc = TangoIoc(servers, policy or AccessPolicy(), pending)
    await ioc.start()
    return ioc
