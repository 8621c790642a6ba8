"""The motor record's fields for caproto: the put handlers, the record class, the PV groups."""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Awaitable, Callable
from contextvars import ContextVar
from typing import Any, Protocol

from caproto import SkipWrite
from caproto.server import PVGroup, pvproperty
from caproto.server.menus import motorDIR, motorSPMG, motorTORQ
from caproto.server.records import MotorFields, register_record
from caproto.server.server import (
    PvpropertyDouble,
    PvpropertyEnum,
    PvpropertyInteger,
    PvpropertyShort,
)

from ..errors import MotorRefusedError

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
    """Run ``motion`` in a task; return it and a future set once it has ended."""
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


class RecordAxis(Protocol):
    """What a record's put handlers call on its axis (:class:`~.axis.AxisServer`)."""

    async def put_field(self, field: str, value: Any) -> Any: ...

    async def move(self, target: float) -> bool: ...


def _axis_of(fields: Any) -> RecordAxis:
    """The :class:`~.axis.AxisServer` behind a record's field group."""
    axis: RecordAxis = fields.parent.group.axis
    return axis


def _put(field: str) -> Callable[[Any, Any, Any], Awaitable[Any]]:
    """The put handler of ``field``: :meth:`~.axis.AxisServer.put_field` does the work."""

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
        """Hand the value to the put handler without caproto's checks."""
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
    """The motor record's fields, with handlers that drive a TANGO axis."""

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
    :func:`_guard` answers ECA_PUTFAIL."""
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
    """One motor record (the PV is the group's prefix, e.g. ``P:X``)."""

    motor = pvproperty(name="", value=0.0, dtype=HandledDouble, record="tango_motor",
                       precision=4, doc="TANGO axis", put=_put_val)

    def __init__(self, prefix: str, *, axis: RecordAxis) -> None:
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
