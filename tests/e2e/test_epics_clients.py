"""The IOC driven by the standard EPICS clients, each in a process of its own.

The IOC runs in the test's event loop against the emulator (so a test can watch the
controller itself); the clients are pyepics, classic ophyd's ``EpicsMotor`` (both on
pyepics' libca) and ophyd-async's ``epics.motor.Motor`` in a bluesky RunEngine (aioca),
started as subprocesses on the loopback CA environment of :mod:`test_epics`.

What they check is what a scan relies on: when a put with callback has completed, the
client's monitored RBV and DMOV already show the end of the move.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
from importlib.util import find_spec
from collections.abc import AsyncIterator, Mapping
from typing import Any

import pytest

_MISSING = [name for name in ("caproto", "epics", "ophyd", "ophyd_async", "bluesky")
            if find_spec(name) is None]
if _MISSING:
    pytest.skip(f"not installed: {', '.join(_MISSING)}", allow_module_level=True)

from helpers import INSTANT  # noqa: E402
from test_epics import ca_env  # noqa: E402, F401 - ca_env is a fixture

from tango_aio.connection import connect  # noqa: E402
from tango_aio.controller import Controller  # noqa: E402
from tango_aio.epics.ioc import TangoIoc, build_ioc  # noqa: E402

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.skipif(os.environ.get("TANGO_AIO_TEST_LOOP") == "uvloop",
                       reason="caproto IOC in a uvloop loop: see test_epics"),
]

#: pyepics ``caput(wait=True)`` then the monitored RBV/DMOV and a fresh ``caget``; and
#: classic ophyd ``EpicsMotor.move(wait=True)`` then its ``position`` (monitored RBV).
PYEPICS = """
import json, sys, warnings
warnings.simplefilter("ignore")
import epics
from ophyd import EpicsMotor

prefix, rounds = sys.argv[1], int(sys.argv[2])
rbv = epics.PV(prefix + "X.RBV", auto_monitor=True)
dmov = epics.PV(prefix + "X.DMOV", auto_monitor=True)
assert rbv.wait_for_connection(10) and dmov.wait_for_connection(10)
wrong = []
for i in range(rounds):
    target = 1.0 if i % 2 == 0 else 0.0
    epics.caput(prefix + "X", target, wait=True, timeout=30)
    seen = [rbv.get(use_monitor=True), dmov.get(use_monitor=True),
            epics.caget(prefix + "X.RBV", use_monitor=False)]
    if abs(seen[0] - target) > 1e-3 or seen[1] != 1 or abs(seen[2] - target) > 1e-3:
        wrong.append(["pyepics", target, seen])
motor = EpicsMotor(prefix + "Y", name="y")
motor.wait_for_connection(timeout=10)
for i in range(rounds):
    target = 1.0 if i % 2 == 0 else 0.0
    motor.move(target, wait=True, timeout=30)
    seen = [motor.position, motor.motor_done_move.get()]
    if abs(seen[0] - target) > 1e-3 or seen[1] != 1:
        wrong.append(["ophyd", target, seen])
print(json.dumps({"wrong": wrong}))
"""

#: ophyd-async ``Motor`` in a RunEngine: ``bp.scan`` and ``bp.grid_scan``; every event's
#: readbacks must be the plan's positions.
OPHYD_ASYNC = """
import itertools, json, sys, warnings
warnings.simplefilter("ignore")
import numpy as np
import bluesky.plans as bp
from bluesky import RunEngine
from ophyd_async.core import init_devices
from ophyd_async.epics.motor import Motor

prefix, points, side, runs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
RE = RunEngine({})
with init_devices():
    x = Motor(prefix + "X")
    y = Motor(prefix + "Y")
    z = Motor(prefix + "Z")
events = []
RE.subscribe(lambda name, doc: events.append(doc["data"]) if name == "event" else None)
wrong = []
for run in range(runs):
    events.clear()
    RE(bp.scan([x], x, 0.0, 2.0, points))
    for data, target in zip(events, np.linspace(0.0, 2.0, points), strict=True):
        if abs(data["x"] - target) > 1e-3:
            wrong.append(["scan", run, float(target), data["x"]])
    events.clear()
    line = np.linspace(0.0, 1.0, side)
    RE(bp.grid_scan([x, y, z], x, 0.0, 1.0, side, y, 0.0, 1.0, side, z, 0.0, 1.0, side,
                    snake_axes=False))
    grid = list(itertools.product(line, line, line))
    for data, target in zip(events, grid, strict=True):
        seen = (data["x"], data["y"], data["z"])
        if any(abs(a - b) > 1e-3 for a, b in zip(seen, target)):
            wrong.append(["grid", run, [float(t) for t in target], seen])
print(json.dumps({"wrong": wrong, "events": len(events)}))
"""


async def run_client(script: str, *args: object, timeout: float = 240) -> Any:
    """Run a client script in a subprocess; return the JSON of its last line."""
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-c", script, *map(str, args), stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    try:
        out, err = await asyncio.wait_for(process.communicate(), timeout)
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
    assert process.returncode == 0, err.decode()[-3000:]
    return json.loads(out.decode().strip().splitlines()[-1])


@contextlib.asynccontextmanager
async def serving(controllers: Mapping[str, Controller],
                  prefix: str) -> AsyncIterator[TangoIoc]:
    """The IOC, served on loopback in this event loop, until the block ends."""
    ioc = await build_ioc(controllers, prefix, poll=0.05)
    task = asyncio.create_task(ioc.run(["127.0.0.1"]))
    try:
        yield ioc
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def _stage(tango: Controller) -> None:
    """Fast enough that a round is short, slow enough that a move takes a few polls."""
    for axis in "xyz":
        await tango.set("vel", 20.0, axis=axis)


# ------------------------------------------------------------------------ put ordering


async def _ordering(rounds: int, points: int, side: int, runs: int) -> None:
    async with connect(INSTANT) as tango:
        await _stage(tango)
        async with serving({"": tango}, "ORD:"):
            pyepics, ophyd_async = await asyncio.gather(
                run_client(PYEPICS, "ORD:", rounds),
                run_client(OPHYD_ASYNC, "ORD:", points, side, runs))
    assert pyepics["wrong"] == []
    assert ophyd_async["wrong"] == []
    assert ophyd_async["events"] == side ** 3


async def test_a_completed_put_shows_the_final_readback_to_every_client(
        ca_env: dict[str, str]) -> None:
    await _ordering(rounds=4, points=5, side=2, runs=1)


@pytest.mark.slow
async def test_a_completed_put_shows_the_final_readback_over_many_rounds(
        ca_env: dict[str, str]) -> None:
    await _ordering(rounds=100, points=33, side=3, runs=3)
