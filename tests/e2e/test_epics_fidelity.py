"""What a standard client reads from the IOC is what a motor record would answer.

Soft limits, alarms, VAL after a stop, metadata, and the clients' own pitfalls; each client
(pyepics, classic ophyd, ophyd-async) in a process of its own, on the loopback CA
environment of :mod:`test_epics`, every client call bounded by a timeout.
"""

from __future__ import annotations

import asyncio
import os
from importlib.util import find_spec

import pytest

_MISSING = [name for name in ("caproto", "epics", "ophyd", "ophyd_async", "bluesky")
            if find_spec(name) is None]
if _MISSING:
    pytest.skip(f"not installed: {', '.join(_MISSING)}", allow_module_level=True)

from helpers import INSTANT  # noqa: E402
from test_epics import ca_env  # noqa: E402, F401 - ca_env is a fixture
from test_epics_clients import run_client, serving  # noqa: E402

from tango_aio.connection import connect  # noqa: E402

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
    motor.check_value = lambda position: None
    try:
        motor.move(target, wait=True, timeout=30)
        out["refused"] = "completed"
    except Exception as exc:
        out["refused"] = type(exc).__name__
    out["position"] = motor.position
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


async def test_a_move_beyond_the_soft_limits_fails_at_once_for_every_client() -> None:
    async with connect(INSTANT) as tango, serving({"": tango}, "LIM:") as ioc:
        await ioc.servers[0].axes[0].put_field("LLM", -5.0)
        pyepics, ophyd, ophyd_async = await asyncio.gather(
            run_client(BEYOND, "LIM:", "pyepics", 5000.0, timeout=120),
            run_client(BEYOND, "LIM:", "ophyd", 5000.0, timeout=120),
            run_client(BEYOND, "LIM:", "ophyd-async", 5000.0, timeout=120))
        assert (await tango.position())["x"] == 0.0
    # VAL's control limits are the soft limits: the clients check before they put.
    assert pyepics["limits"] == pytest.approx([-5.0, 2600.0])
    assert ophyd["limits"] == pytest.approx([-5.0, 2600.0])
    assert ophyd["checked"] == "LimitError"
    assert ophyd_async["checked"] == "MotorLimitsError"
    # A put beyond them: LVIO, VAL kept, no motion, DMOV blinks, the axis in alarm.
    assert pyepics["dmov"][-2:] == [0, 1], pyepics  # (the first monitor may come late)
    assert pyepics["lvio"] == 1
    assert pyepics["val"] == 0.0
    assert pyepics["position"] == 0.0
    assert pyepics["severity"] == 2  # MAJOR
    assert ophyd["refused"] not in ("completed", "WaitTimeoutError"), ophyd
    assert ophyd["position"] == 0.0
