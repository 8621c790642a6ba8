"""What a standard client reads from the IOC is what a motor record would answer.

Soft limits, alarms, VAL after a stop, metadata, and the clients' own pitfalls; each client
(pyepics, classic ophyd, ophyd-async, caproto's own client) in a process of its own, on
the loopback CA environment of :mod:`test_epics`, every client call bounded by a timeout.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import AsyncIterator
from importlib.util import find_spec
from typing import Any

import pytest

_MISSING = [name for name in ("caproto", "epics", "ophyd", "ophyd_async", "bluesky")
            if find_spec(name) is None]
if _MISSING:
    pytest.skip(f"not installed: {', '.join(_MISSING)}", allow_module_level=True)

from caproto import AlarmSeverity, AlarmStatus  # noqa: E402
from caproto.asyncio.client import Context as ClientContext  # noqa: E402
from helpers import INSTANT  # noqa: E402
from test_epics import Client, PutFailed, ca_env, one_stage  # noqa: E402, F401 - a fixture
from test_epics import serving as serving_in_process  # noqa: E402
from test_epics_clients import _spy_moves, _stage, run_client, serving  # noqa: E402

from tango_aio.bluesky import MarzhauserAxis, MarzhauserStage  # noqa: E402
from tango_aio.controller._connection import connect  # noqa: E402
from tango_aio.controller._controller import Controller  # noqa: E402
from tango_aio.epics.ioc import build_ioc  # noqa: E402
from tango_aio.epics.record import Msta  # noqa: E402
from tango_aio.sim.profiles import SWITCHES  # noqa: E402

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.usefixtures("ca_env"),
    pytest.mark.skipif(os.environ.get("TANGO_AIO_TEST_LOOP") == "uvloop",
                       reason="caproto IOC in a uvloop loop: see test_epics"),
]

# ----------------------------------------------------------------------- soft limits

#: A move of X to ``target`` beyond the high soft limit, by ``client``: what the client
#: reads as VAL's control limits, how the move ended (an exception's name, or
#: "completed"), and for pyepics the DMOV values its monitor saw and the record after.
BEYOND = """
import asyncio, json, sys, threading, time, warnings
warnings.simplefilter("ignore")
prefix, client, target = sys.argv[1], sys.argv[2], float(sys.argv[3])
x = prefix + "X"
out = {}
if client == "pyepics":
    import epics
    seen, lock = [], threading.Lock()
    def record(value=None, **kw):
        with lock:
            seen.append(int(value))
    dmov = epics.PV(x + ".DMOV", auto_monitor=True, callback=record)
    val = epics.PV(x, form="ctrl")
    assert dmov.wait_for_connection(30) and val.wait_for_connection(30)
    ctrl = val.get_ctrlvars(timeout=10)
    out["limits"] = [ctrl["lower_ctrl_limit"], ctrl["upper_ctrl_limit"]]
    end = time.monotonic() + 10
    while time.monotonic() < end and not seen:
        time.sleep(0.01)
    with lock:
        seen.clear()
    epics.caput(x, target, wait=True, timeout=30)
    end = time.monotonic() + 10
    while time.monotonic() < end and len(seen) < 2:
        time.sleep(0.01)
    with lock:
        out["dmov"] = list(seen)
    out["lvio"] = epics.caget(x + ".LVIO", timeout=10, use_monitor=False)
    out["val"] = epics.caget(x, timeout=10, use_monitor=False)
    rbv = epics.PV(x + ".RBV", form="time")
    out["position"] = rbv.get(timeout=10, use_monitor=False)
    out["severity"] = rbv.severity
elif client == "ophyd":
    from ophyd import EpicsMotor
    motor = EpicsMotor(x, name="x")
    motor.wait_for_connection(timeout=30)
    out["limits"] = list(motor.limits)
    try:
        motor.move(target, wait=True, timeout=30)
        out["checked"] = "completed"
    except Exception as exc:
        out["checked"] = type(exc).__name__
    # Past ophyd's own check (as when the limits changed after it read them): the IOC
    # refuses the put, and DMOV's blink with RBV in alarm ends the move as a failure.
    motor.check_value = motor.user_setpoint.check_value = lambda position: None
    try:
        motor.move(target, wait=True, timeout=30)
        out["refused"] = "completed"
    except Exception as exc:
        out["refused"] = type(exc).__name__
    out["position"] = motor.position
elif client == "pyepics-motor":
    import epics
    motor = epics.Motor(x, timeout=30)
    out["limits"] = [motor.LLM, motor.HLM]
    out["checked"] = motor.move(target, wait=True, timeout=30)  # its own check first
    out["refused"] = motor.move(target, wait=True, timeout=30, ignore_limits=True)
    out["position"] = motor.get_position(readback=True)
    out["steps"] = motor.get_position(readback=True, raw=True)
elif client == "caproto":
    from caproto import ChannelType
    from caproto.threading.client import Context
    val, lvio, rbv = Context().get_pvs(x, x + ".LVIO", x + ".RBV", timeout=30)
    for pv in (val, lvio, rbv):
        pv.wait_for_connection(timeout=30)
    ctrl = val.read(data_type=ChannelType.CTRL_DOUBLE, timeout=10).metadata
    out["limits"] = [ctrl.lower_ctrl_limit, ctrl.upper_ctrl_limit]
    out["put"] = val.write([target], wait=True, notify=True, timeout=30).status.name
    out["lvio"] = int(lvio.read(timeout=10).data[0])
    out["val"] = float(val.read(timeout=10).data[0])
    reading = rbv.read(data_type=ChannelType.TIME_DOUBLE, timeout=10)
    out["position"] = float(reading.data[0])
    out["severity"] = int(reading.metadata.severity)
else:
    from ophyd_async.epics.motor import Motor

    async def main():
        motor = Motor(x, name="x")
        await motor.connect(timeout=30)
        try:
            await asyncio.wait_for(motor.set(target), 30)
            out["checked"] = "completed"
        except Exception as exc:
            out["checked"] = type(exc).__name__
        out["position"] = await motor.user_readback.get_value()
    asyncio.run(main())
print(json.dumps(out))
"""


@pytest.mark.parametrize("client", [
    "ophyd", pytest.param("pyepics", marks=pytest.mark.slow),
    pytest.param("ophyd-async", marks=pytest.mark.slow),
    pytest.param("caproto", marks=pytest.mark.slow),
    pytest.param("pyepics-motor", marks=pytest.mark.slow)])
async def test_a_move_beyond_the_soft_limits_fails_at_once(client: str) -> None:
    # Classic ophyd hung here: VAL served no control limits, so its own check let
    # the move through, the IOC refused the put, and DMOV never moved.
    async with connect(INSTANT) as tango, serving({"": tango}, "LIM:") as ioc:
        await ioc.servers[0].axes[0].put_field("LLM", -5.0)
        result = await run_client(BEYOND, "LIM:", client, 5000.0, timeout=120)
        assert (await tango.position())["x"] == 0.0
    assert result["position"] == 0.0
    if client == "ophyd-async":
        assert result["checked"] == "MotorLimitsError"  # its own check of HLM/LLM
        return
    # VAL's control limits are the soft limits: the clients check before they put.
    assert result["limits"] == pytest.approx([-5.0, 2600.0])
    if client == "pyepics-motor":  # pyepics' epics.Motor: codes, not exceptions
        assert result["checked"] == -12  # outside the soft limits: not attempted
        assert result["refused"] == -4  # put anyway: finished, soft limit violation seen
        assert result["steps"] == 0
        return
    if client == "ophyd":
        assert result["checked"] == "LimitError"
        # Past its check the IOC refuses, DMOV blinks with RBV in alarm: a failure.
        assert result["refused"] == "UnknownStatusFailure", result  # success=False
        return
    if client == "caproto":  # the put with completion ends at once, failed
        assert result["put"] == "ECA_PUTFAIL", result
    else:  # LVIO, VAL kept, no motion, DMOV blinks, the axis in alarm
        assert result["dmov"][-2:] == [0, 1], result  # (the first monitor may come late)
    assert result["lvio"] == 1
    assert result["val"] == 0.0
    assert result["severity"] == 2  # MAJOR


# ---------------------------------------------------- alarms and VAL (in-process client)


async def _alarms(client: Client) -> dict[str, Any]:
    """The alarm of every PV a client judges a move by, SEVR, and MSTA's problem bit."""
    seen: dict[str, Any] = {name: await client.alarm(name)
                            for name in ("X", "X.RBV", "X.DMOV", "X.DVAL", "X.MSTA")}
    seen["SEVR"] = await client.get("X.SEVR")
    seen["problem"] = bool(await client.get("X.MSTA") & Msta.PROBLEM)
    return seen


def _all(alarm: tuple[AlarmStatus, AlarmSeverity], sevr: AlarmSeverity,
         problem: bool) -> dict[str, Any]:
    return {"X": alarm, "X.RBV": alarm, "X.DMOV": alarm, "X.DVAL": alarm, "X.MSTA": alarm,
            "SEVR": sevr, "problem": problem}


FAULT = (AlarmStatus.STATE, AlarmSeverity.MAJOR_ALARM)
CLEAR = (AlarmStatus.NO_ALARM, AlarmSeverity.NO_ALARM)


async def test_one_alarm_rule_on_every_pv_failed_move_stop_good_move() -> None:
    async with one_stage() as (tango, ioc, client):
        await tango.command("!axis x 0")  # disabled: the move ends short (a fault)
        with pytest.raises(PutFailed):
            await client.put("X", 5.0)
        assert await _alarms(client) == _all(FAULT, AlarmSeverity.MAJOR_ALARM, True)
        await client.put("X.STOP", 1)  # a stop neither raises nor clears
        assert await _alarms(client) == _all(FAULT, AlarmSeverity.MAJOR_ALARM, True)
        await client.put("X.SPMG", "Stop")
        await client.put("X.SPMG", "Go")
        assert await _alarms(client) == _all(FAULT, AlarmSeverity.MAJOR_ALARM, True)
        await tango.command("!axis x 1")
        await client.put("X", 1.0)  # a move that arrives clears every PV
        assert await _alarms(client) == _all(CLEAR, AlarmSeverity.NO_ALARM, False)
        # A stop of a clean axis raises nothing either.
        move = asyncio.create_task(client.put("X", 40.0))
        await client.until("X.DMOV", 0)
        await client.put("X.STOP", 1)
        with pytest.raises(PutFailed):
            await move
        assert await _alarms(client) == _all(CLEAR, AlarmSeverity.NO_ALARM, False)
        # A refused setting is no failed move: the put fails, the alarm stays as it was.
        with pytest.raises(PutFailed):
            await client.put("X.VELO", -1.0)
        assert await _alarms(client) == _all(CLEAR, AlarmSeverity.NO_ALARM, False)
        # Beyond the soft limits: refused, in alarm on its side, until a good move.
        with pytest.raises(PutFailed):
            await client.put("X", 1e5)
        assert await _alarms(client) == _all((AlarmStatus.HIGH, AlarmSeverity.MAJOR_ALARM),
                                             AlarmSeverity.MAJOR_ALARM, True)
        await client.put("X", 2.0)
        assert await _alarms(client) == _all(CLEAR, AlarmSeverity.NO_ALARM, False)
        assert ioc.servers[0].axes[0].record.alarm.severity == AlarmSeverity.NO_ALARM


async def _stopped_mid_move(tango: Controller, client: Client, how: str) -> float:
    """Move X toward 40, stop it by ``how`` mid-move; where it stands."""
    move = asyncio.create_task(client.put("X", 40.0))
    await client.until("X.DMOV", 0)
    async with asyncio.timeout(30):
        while (await tango.position())["x"] < 0.5:  # noqa: ASYNC110 - polls the stage
            await asyncio.sleep(0.01)
    if how == "STOP":
        await client.put("X.STOP", 1)
    elif how == "CNEN":
        await client.put("X.CNEN", "Disable")
    else:
        await client.put("X.SPMG", how)
    with pytest.raises(PutFailed):
        await move
    await client.until("X.DMOV", 1)
    return float((await tango.position())["x"])


@pytest.mark.parametrize("how", ["STOP", "Stop", "Pause"])
async def test_val_after_a_stop_is_where_the_axis_stopped(how: str) -> None:
    async with one_stage() as (tango, _, client):
        await client.put("X.OFF", 1.5)
        stood = await _stopped_mid_move(tango, client, how)
        assert 0.5 <= stood < 40.0 - 1.5
        assert await client.get("X.DRBV") == pytest.approx(stood, abs=1e-3)
        if how == "Pause":  # the motor record keeps the target: Go resumes toward it
            assert await client.get("X") == pytest.approx(40.0)
            assert await client.get("X.DVAL") == pytest.approx(38.5)
        else:
            assert await client.get("X") == pytest.approx(stood + 1.5, abs=1e-3)
            assert await client.get("X.DVAL") == pytest.approx(stood, abs=1e-3)


async def test_val_after_a_failed_move_is_where_the_axis_stands() -> None:
    async with one_stage() as (tango, _, client):
        await client.put("X", 2.0)
        await tango.command("!axis x 0")
        with pytest.raises(PutFailed):
            await client.put("X", 5.0)
        stood = (await tango.position())["x"]
        assert stood != pytest.approx(5.0)
        assert await client.get("X") == pytest.approx(stood, abs=1e-3)
        assert await client.get("X.DVAL") == pytest.approx(stood, abs=1e-3)


# ------------------------------------------------------------------ switches and SET


@contextlib.asynccontextmanager
async def _unpolled(tango: Controller) -> AsyncIterator[Client]:
    """The IOC polling once, at its start: only a request's own end reads the switches."""
    ioc = await build_ioc({"": tango}, "T:", poll=3600)
    task = asyncio.create_task(ioc.run(["127.0.0.1"]))
    context = ClientContext()
    try:
        client = Client(context, "T:")
        assert await client.get("X.DMOV") == 1
        yield client
    finally:
        await context.disconnect()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def test_the_switches_are_read_before_dmov_returns_to_one() -> None:
    # Classic ophyd reads HLS or LLS (by TDIR) when DMOV returns to 1, pyepics' Motor
    # both: a move that ended on a switch shows it, a home that left it shows it free.
    async with connect("sim://?baud=0&speed=20") as tango:  # the emulator's clock 20x
        await tango.command("!lim x -1000 1000")  # soft limits beyond the switches
        async with _unpolled(tango) as client:
            with pytest.raises(PutFailed):
                await client.put("X", 500.0)  # stops on the upper switch
            assert (await client.get("X.HLS"), await client.get("X.TDIR")) == (1, 1)
            assert await client.get("X.MSTA") & Msta.PLUS_LS
            await client.put("X.HOMR", 1)  # cal: to the lower switch, then out of it
            assert (await client.get("X.HLS"), await client.get("X.LLS")) == (0, 0)
            assert await client.get("X.MSTA") & Msta.HOMED


#: Classic ophyd: ``set_current_position`` (SET, VAL, SET) and what it reads right after,
#: then ``home`` forward and reverse: whether each raised, and where the axis stood.
OPHYD_HOME = """
import json, sys, warnings
warnings.simplefilter("ignore")
from ophyd import EpicsMotor
motor = EpicsMotor(sys.argv[1] + "X", name="x")
motor.wait_for_connection(timeout=30)
out = {}
motor.set_current_position(5.0)
out["redefined"] = [motor.position, motor.user_setpoint.get(), motor.user_offset.get()]
for direction in ("forward", "reverse"):
    try:
        motor.home(direction, wait=True, timeout=60)
        out[direction] = ["done", motor.high_limit_switch.get(), motor.low_limit_switch.get()]
    except Exception as exc:
        out[direction] = [type(exc).__name__]
print(json.dumps(out))
"""


@pytest.mark.slow
async def test_classic_ophyd_redefines_and_homes() -> None:
    # Each home ends out of its switch (the manual's cal and rm travel out of it, L5292,
    # L5376): ophyd, reading the switch TDIR points to as DMOV returns to 1, must see it
    # free; and after set_current_position its monitors already hold the new position.
    async with connect("sim://?baud=0&speed=20") as tango, serving({"": tango}, "OH:"):
        result = await run_client(OPHYD_HOME, "OH:", timeout=120)
    assert result["redefined"] == [5.0, 5.0, 5.0], result
    assert result["forward"] == ["done", 0, 0], result
    assert result["reverse"] == ["done", 0, 0], result


# ------------------------------------------------------------------------ metadata

#: Names asked for that no motor record has (motorRecord.dbd of motor R7 lists none of
#: them; POSM was deleted from the record in motor R4): a motor record IOC answers no
#: search for them, and neither does this one.
NOT_MOTOR_RECORD_FIELDS = ("RDBK", "HOMS", "POSM")


def _served(fields: Any) -> set[str]:
    return {prop.pvspec.name for prop in fields._pvs_.values()}


def test_every_field_served_is_a_motor_record_field_but_the_drive_limits() -> None:
    from caproto.server.records import MotorFields

    from tango_aio.epics.fields import TangoMotorFields
    served = _served(TangoMotorFields)
    # caproto's copy of the record predates ACCS/ACCU (motor R6-10); DRVH/DRVL, which
    # the record serves as VAL's control limits only, are also served as fields.
    assert served - _served(MotorFields) == {"ACCS", "ACCU", "DRVH", "DRVL"}
    assert not served & set(NOT_MOTOR_RECORD_FIELDS)


async def test_a_search_for_a_field_no_motor_record_has_finds_no_channel() -> None:
    async with one_stage() as (_, _, client):
        assert await client.get("X.ATHM") == 0  # a motor record field: found
        for name in NOT_MOTOR_RECORD_FIELDS:
            (pv,) = await client.context.get_pvs(f"T:X.{name}", timeout=1)
            with pytest.raises(TimeoutError):
                await pv.wait_for_connection(timeout=1)



async def _bluesky_facts(axis: MarzhauserAxis) -> dict[str, float]:
    return {"MRES": await axis.motor_resolution.get_value(),
            "SREV": await axis.steps_per_revolution.get_value(),
            "UREV": await axis.units_per_revolution.get_value()}


async def _ioc_facts(client: Client) -> dict[str, float]:
    return {name: await client.get(f"X.{name}") for name in ("MRES", "SREV", "UREV")}


async def test_derived_fields_follow_a_move_as_the_motor_record_derives_them() -> None:
    # Classic ophyd reads TDIR when DMOV returns to 1 (which switch to check);
    # ophyd-async reads PREC and ERES; RRBV, RVAL, DIFF and the rest are the record's own.
    async with one_stage() as (_, _, client):
        mres, urev = await client.get("X.MRES"), await client.get("X.UREV")
        assert await client.get("X.PREC") == 4  # the decimals the controller prints
        assert await client.get("X.ERES") == mres  # no encoder: the record's rule
        assert await client.get("X.S") == pytest.approx(await client.get("X.VELO") / urev)
        assert await client.get("X.SMAX") == pytest.approx(await client.get("X.VMAX") / urev)
        move = asyncio.create_task(client.put("X", 3.0))
        await client.until("X.MIP", 0x20)  # a move (not a jog or home) in progress
        await move
        steps = round(3.0 / mres)
        assert [await client.get(f"X.{name}") for name in (
            "RVAL", "RRBV", "RMP", "RDIF", "LRVL", "TDIR", "CDIR", "MIP")] == [
            steps, steps, steps, 0, steps, 1, 1, 0]
        assert [await client.get(f"X.{name}") for name in ("DIFF", "LVAL", "LDVL")] == [
            0.0, 3.0, 3.0]
        await client.put("X", 1.0)
        assert (await client.get("X.TDIR"), await client.get("X.RRBV")) == (
            0, round(1.0 / mres))
        # OFF (FOFF Variable) moves VAL with RBV; the dial target stays.
        await client.put("X.OFF", 0.5)
        assert (await client.get("X"), await client.get("X.DVAL")) == (1.5, 1.0)
        assert await client.get("X.LVAL") == 1.5


async def test_resolution_fields_match_the_bluesky_device_and_follow_a_pitch_change() -> None:
    stage = MarzhauserStage("sim://?baud=0", axes="x")
    await stage.connect()
    try:
        tango = stage.controller
        async with serving_in_process({"": tango}) as (_, client):
            facts = await _bluesky_facts(stage.x)
            assert facts == {"MRES": pytest.approx(2.5e-5), "SREV": 40000,
                             "UREV": pytest.approx(1.0)}
            assert await _ioc_facts(client) == facts
            assert await client.get("X.RDBD") == pytest.approx(1.5e-4)  # 4 decimals
            assert await client.get("X.ACCS") == pytest.approx(
                1000.0 * await tango.get("accel", axis="x"))
            assert await client.get("X.ACCU") == 2  # Accs: the acceleration is held
            assert await client.get("X.DRVH") == await client.get("X.DHLM")
            assert await client.get("X.DRVL") == await client.get("X.DLLM")
            velo = await client.get("X.VELO")
            # Through the driver, not the IOC: the IOC follows.
            await tango.set("pitch", 2.0, axis="x")
            await stage.refresh_settings()
            facts = await _bluesky_facts(stage.x)
            assert facts["UREV"] == pytest.approx(2.0)
            await client.until("X.UREV", facts["UREV"])
            assert await _ioc_facts(client) == facts
            assert await client.get("X.VELO") == pytest.approx(2 * velo)  # same rev/s
            await tango.command("!lim x -3 7")
            await client.until("X.DRVH", 7.0)
            assert await client.get("X.HLM") == 7.0 and await client.get("X.DRVL") == -3.0
    finally:
        await stage.aclose()


# ------------------------------------------------------------------- CNEN mid-move


@pytest.mark.parametrize("policy", SWITCHES["disable_during_move"].values)
async def test_cnen_disable_during_a_move_stops_then_disables(policy: str) -> None:
    # The manual is silent on what a disable does to a move (L3919-3960): the IOC stops
    # the axis first, so the outcome is the same under every behaviour of the emulator.
    async with connect(f"{INSTANT}&disable_during_move={policy}") as tango, \
            serving_in_process({"": tango}) as (_, client):
        stood = await _stopped_mid_move(tango, client, "CNEN")
        assert stood < 40.0
        assert await tango.get("axis", axis="x") == 0
        assert await client.get("X.CNEN") == 0  # Disable
        assert await client.get("X") == pytest.approx(stood, abs=1e-3)
        assert await _alarms(client) == _all(CLEAR, AlarmSeverity.NO_ALARM, False)
        with pytest.raises(PutFailed):  # a disabled axis does not move: a fault
            await client.put("X", 1.0)
        assert (await tango.position())["x"] == pytest.approx(stood)
        await client.put("X.CNEN", "Enable")
        await client.put("X", 1.0)
        assert await _alarms(client) == _all(CLEAR, AlarmSeverity.NO_ALARM, False)


# ------------------------------------------------------- puts from two client threads

#: pyepics: two threads put X and Y (with callback) at once, ``pairs`` times.
THREADS = """
import json, sys, threading, warnings
warnings.simplefilter("ignore")
import epics
prefix, pairs = sys.argv[1], int(sys.argv[2])
pvs = {axis: epics.PV(prefix + axis) for axis in "XY"}
assert all(pv.wait_for_connection(30) for pv in pvs.values())
done = []
for i in range(pairs):
    barrier = threading.Barrier(2)
    def put(axis, target):
        barrier.wait(timeout=30)
        done.append(pvs[axis].put(target, wait=True, timeout=60))
    threads = [threading.Thread(target=put, args=(axis, 1.0 + i + (axis == "Y")))
               for axis in "XY"]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(90)
print(json.dumps({"done": done}))
"""


@pytest.mark.slow
async def test_puts_from_two_threads_within_the_merge_window_are_merged() -> None:
    # merge="window": every put waits the window for puts to other axes, whatever thread
    # (or client) sent them; with the default "turn" only puts that reach the IOC
    # together merge, which two threads' puts may or may not do (see the how-to).
    async with connect(INSTANT) as tango, \
            serving_in_process({"": tango}, merge="window", window=0.5) as (_, client):
        assert await client.get("X.DMOV") == 1  # served (and the in-process client used)
        moves = _spy_moves(tango)
        result = await run_client(THREADS, "T:", 2, timeout=120)
    assert len(result["done"]) == 4
    assert moves == ["!moa 1.0 2.0", "!moa 2.0 3.0"], moves


# ------------------------------------------------------------------ client pitfalls
# Each test states what a client should do and fails because the client does otherwise
# (strict xfail: should a fixed release come, the test passes and the mark must go).

#: ``pyepics-motor``: pyepics' ``epics.Motor.move(wait=True)`` of a move that fails (a
#: disabled axis): the status code it returned.
#: ``ophyd-async``: ``Motor.set`` of a move that fails (a disabled axis): did it raise?
#: ``ophyd-stop``: ``EpicsMotor.move`` that another client stops: did it raise?
#: ``ophyd-after-caput``: pyepics ``caput(wait=True)``, then ``EpicsMotor.move`` on the
#: same PV in the same process, ``rounds`` times: the rounds where ``move`` returned with
#: the axis short of its target.
PITFALLS = """
import asyncio, json, sys, time, warnings
warnings.simplefilter("ignore")
prefix, case, rounds = sys.argv[1], sys.argv[2], int(sys.argv[3])
x = prefix + "X"
out = {}
if case == "pyepics-motor":
    import epics
    motor = epics.Motor(x, timeout=30)
    out["status"] = motor.move(15.0, wait=True, timeout=60)  # 0: "finished OK"
    out["position"] = motor.get_position(readback=True)
elif case == "ophyd-async":
    from ophyd_async.epics.motor import Motor

    async def main():
        motor = Motor(x, name="x")
        await motor.connect(timeout=30)
        try:
            await asyncio.wait_for(motor.set(15.0), 60)
            out["raised"] = False
        except Exception as exc:
            out["raised"], out["error"] = True, repr(exc)
        out["position"] = await motor.user_readback.get_value()
    asyncio.run(main())
else:
    import epics
    from ophyd import EpicsMotor
    motor = EpicsMotor(x, name="x")
    motor.wait_for_connection(timeout=30)
    if case == "ophyd-stop":
        try:
            motor.move(40.0, wait=True, timeout=60)
            out["raised"] = False
        except Exception as exc:
            out["raised"], out["error"] = True, repr(exc)
        out["position"] = motor.position
    else:
        early = []
        for i in range(rounds):
            start = 1.0 + i % 2
            epics.caput(x, start, wait=True, timeout=30)
            motor.move(start + 3.0, wait=True, timeout=30)
            position = epics.caget(x + ".RBV", use_monitor=False, timeout=10)
            if abs(position - (start + 3.0)) > 1e-3:
                early.append([start + 3.0, position])
        out["early"] = early
print(json.dumps(out))
"""


async def _failed_move_by(case: str, prefix: str) -> Any:
    """What the PITFALLS ``case`` reports of a move that fails (X disabled)."""
    async with connect(INSTANT) as tango, serving({"": tango}, prefix):
        await tango.command("!axis x 0")
        result = await run_client(PITFALLS, prefix, case, 0, timeout=120)
        assert (await tango.position())["x"] == 0.0  # the move failed
    return result


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="pyepics' epics.Motor.move(wait=True) returns 0 "
                   "(finished OK) whenever the put's callback came, LVIO is 0 and no limit "
                   "switch is on: it reads neither the put's status nor the alarm")
async def test_pitfall_pyepics_motor_move_reports_a_failed_move() -> None:
    result = await _failed_move_by("pyepics-motor", "PFM:")
    assert result["status"] != 0, result


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="ophyd-async 0.21's Motor.set returns normally when "
                   "the put fails: its retry loop (stamina over tenacity) takes aioca's "
                   "CANothing, falsy for a failure, for a success")
async def test_pitfall_ophyd_async_set_raises_when_the_move_fails() -> None:
    result = await _failed_move_by("ophyd-async", "PFA:")
    assert result["raised"], result


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="classic ophyd judges a move by RBV's alarm when DMOV "
                   "returns to 1, and a STOP raises no alarm (as the motor record's does "
                   "not): a move stopped by another client is taken for a success")
async def test_pitfall_ophyd_move_stopped_by_another_client_raises() -> None:
    async with connect(INSTANT) as tango, serving({"": tango}, "PFS:") as ioc:
        await _stage(tango)
        mover = asyncio.create_task(run_client(PITFALLS, "PFS:", "ophyd-stop", 0,
                                               timeout=120))
        async with asyncio.timeout(60):
            while (await tango.position())["x"] < 1.0:  # noqa: ASYNC110 - polls the stage
                await asyncio.sleep(0.02)
        await ioc.servers[0].axes[0].put_field("STOP", 1)  # another client's STOP
        result = await mover
        assert (await tango.position())["x"] < 40.0  # stopped short
    assert result["raised"], result


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="classic ophyd's move() right after a pyepics "
                   "caput(wait=True) on the same PV in the same process: the caput's DMOV "
                   "0 and 1 reach ophyd's callback thread late and end the new move at once")
async def test_pitfall_ophyd_move_after_a_pyepics_caput_ends_at_its_target() -> None:
    async with connect(INSTANT) as tango, serving({"": tango}, "PFC:"):
        await _stage(tango)
        result = await run_client(PITFALLS, "PFC:", "ophyd-after-caput", 8, timeout=200)
    assert result["early"] == [], result


# ------------------------------------------------------- the same, by clients in other processes

#: pyepics: a move that fails (the test disabled X), STOP, CNEN=Enable and a good move,
#: then a move stopped mid-way; after each step the severity of VAL, RBV and DMOV, SEVR
#: and MSTA's problem bit, and at the end VAL, DVAL and RBV.
RULE = """
import json, sys, time, warnings
warnings.simplefilter("ignore")
import epics
x = sys.argv[1] + "X"
pvs = {name: epics.PV(x + name, form="time") for name in ("", ".RBV", ".DMOV")}
assert all(pv.wait_for_connection(30) for pv in pvs.values())
def alarms():
    for pv in pvs.values():
        pv.get(timeout=10, use_monitor=False)
    return [[pv.severity for pv in pvs.values()],
            epics.caget(x + ".SEVR", timeout=10, use_monitor=False),
            bool(int(epics.caget(x + ".MSTA", timeout=10, use_monitor=False)) & 512)]
out = {}
epics.caput(x, 5.0, wait=True, timeout=30)
out["failed"] = alarms()
epics.caput(x + ".STOP", 1, wait=True, timeout=30)
out["stop"] = alarms()
epics.caput(x + ".CNEN", 1, wait=True, timeout=30)
epics.caput(x, 1.0, wait=True, timeout=30)
out["good"] = alarms()
epics.caput(x, 40.0, wait=False)
end = time.monotonic() + 30
while time.monotonic() < end and epics.caget(x + ".RBV", use_monitor=False) < 2.0:
    time.sleep(0.01)
epics.caput(x + ".STOP", 1, wait=True, timeout=30)
end = time.monotonic() + 30
while time.monotonic() < end and epics.caget(x + ".DMOV", use_monitor=False) != 1:
    time.sleep(0.01)
out["stopped"] = alarms()
out["val"], out["dval"], out["rbv"] = (epics.caget(x + name, timeout=10, use_monitor=False)
                                       for name in ("", ".DVAL", ".RBV"))
print(json.dumps(out))
"""


@pytest.mark.slow
async def test_pyepics_sees_the_alarm_rule_and_val_after_stop() -> None:
    async with connect(INSTANT) as tango, serving({"": tango}, "RUL:"):
        await _stage(tango)
        await tango.command("!axis x 0")
        result = await run_client(RULE, "RUL:", timeout=120)
        stood = (await tango.position())["x"]
    fault, clear = [[2, 2, 2], 2, True], [[0, 0, 0], 0, False]
    assert result["failed"] == fault, result
    assert result["stop"] == fault, result  # a STOP neither raises nor clears
    assert result["good"] == clear, result
    assert result["stopped"] == clear, result
    assert 2.0 <= stood < 40.0
    for name in ("val", "dval", "rbv"):
        assert result[name] == pytest.approx(stood, abs=1e-3), result


#: ophyd-async's Motor: the resolution fields it records as configuration.
RESOLUTION = """
import asyncio, json, sys
from ophyd_async.epics.motor import Motor

async def main():
    motor = Motor(sys.argv[1] + "X", name="x")
    await motor.connect(timeout=30)
    print(json.dumps({"MRES": await motor.motor_resolution.get_value(),
                      "SREV": await motor.steps_per_revolution.get_value(),
                      "UREV": await motor.units_per_revolution.get_value()}))
asyncio.run(main())
"""


@pytest.mark.slow
async def test_ophyd_async_records_the_bluesky_devices_resolution() -> None:
    stage = MarzhauserStage(INSTANT, axes="x")
    await stage.connect()
    try:
        async with serving({"": stage.controller}, "RES:") as ioc:
            assert await run_client(RESOLUTION, "RES:", timeout=120) == \
                pytest.approx(await _bluesky_facts(stage.x))
            await stage.controller.set("pitch", 4.0, axis="x")
            await stage.refresh_settings()
            wanted = await _bluesky_facts(stage.x)
            assert wanted["UREV"] == pytest.approx(4.0)
            urev = ioc.servers[0].axes[0].record.fields["UREV"]
            async with asyncio.timeout(60):
                while urev.value != pytest.approx(4.0):  # noqa: ASYNC110 - the IOC's poll
                    await asyncio.sleep(0.05)
            assert await run_client(RESOLUTION, "RES:", timeout=120) == \
                pytest.approx(wanted)
    finally:
        await stage.aclose()
