"""Shared helpers of the tests (importable as ``helpers`` from every tier: pyproject's
pytest ``pythonpath`` and mypy's ``mypy_path`` both name ``tests``). Fixtures stay in
``conftest.py``; plain names, classes and functions that tests import live here."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol, TypedDict, Unpack, cast

import pytest

from tango_aio._platform import WINDOWS as WINDOWS
from tango_aio.controller._connection import connect
from tango_aio.controller._controller import Controller
from tango_aio.errors import ConnectionLostError
from tango_aio.events import Subscription, TangoEvent
from tango_aio.link._protocol import Submission, TangoProtocol
from tango_aio.sansio._core import Event
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.motion import AxisConfig, MotionConfig
from tango_aio.sim.wire import Emit, Wire
from tango_aio.testing import Faults, faults

if TYPE_CHECKING:
    from tango_aio.sim.ptyserve import PtyServer
    from tango_aio.sim.wire import HandlerFactory, WireConfig

# --------------------------------------------------------------------------------------
# POSIX-only tests (issue #27): on Windows, and "as if on Windows"
# (TANGO_AIO_TEST_AS_WINDOWS=1, tests/as_windows.py), they skip, naming what they need.

#: What the pty emulator needs, for skip reasons.
PTY_EMULATOR = "the pty emulator (os.openpty, termios, tty: tango_aio.sim.ptyserve)"


def load_tool(name: str) -> ModuleType:
    """The script ``tools/<name>.py`` loaded as a module (tools are not a package)."""
    path = Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def posix_only(what: str) -> None:
    """Skip the running test on Windows: it needs ``what``, which only POSIX has."""
    if WINDOWS:
        pytest.skip(f"POSIX only: needs {what}")


async def serve_pty(factory: HandlerFactory, config: WireConfig | None = None, *,
                    speed: float = 1.0) -> PtyServer:
    """:func:`tango_aio.sim.ptyserve.serve_pty`, or a skip where there are no ptys."""
    posix_only(PTY_EMULATOR)
    from tango_aio.sim.ptyserve import serve_pty as serve

    return await serve(factory, config, speed=speed)


# --------------------------------------------------------------------------------------
# Emulator URLs, models and values

#: The in-process emulator without line pacing (motion still runs in real time).
INSTANT = "sim://?baud=0"
class Axes(TypedDict, total=False):
    """Per-axis values passed as ``**axes`` (``tango.set("vel", **VELS)``): typed, so that
    mypy tells them from the keyword-only options beside them (``check``, ``unit``...)."""

    x: float
    y: float
    z: float
    a: float


class ConnectOptions(TypedDict, total=False):
    """The keyword options of :func:`tango_aio.connect`, for tests that pass them on."""

    baudrate: int
    rtscts: bool
    autostatus: int | None
    identify: bool
    reply_timeout: float
    credit_limit: int
    marker_chunk: int
    reconnect: bool
    reconnect_initial: float
    reconnect_max: float
    reconnect_attempts: int | None
    units: str | None
    dead_after: int
    keepalive: float | None


def as_axes(values: Mapping[str, float]) -> Axes:
    """Per-axis values built at run time, typed as :class:`Axes` (checked)."""
    assert set(values) <= set(Axes.__annotations__), values
    return cast(Axes, dict(values))


def one_axis(axis: str, value: float) -> Axes:
    """``{axis: value}`` typed as :class:`Axes` (``move_to(**one_axis("y", 1.0))``)."""
    return as_axes({axis: value})


class ReconnectOptions(TypedDict):
    """:data:`FAST`: the reconnect options of :func:`tango_aio.connect`."""

    reconnect: bool
    reconnect_initial: float
    reconnect_max: float


#: Distinctive per-axis velocities: a reply routed to the wrong request cannot match.
VELS: Axes = {"x": 11.5, "y": 12.25, "z": 13.125}
VEL_TEXT = "11.500 12.250 13.125"


def make_model(emit: Emit) -> ControllerModel:
    """Handler factory of the pty and TCP servers: a default 3-axis controller (TANGO-DT,
    firmware 1.71)."""
    return ControllerModel(emit, SimConfig())


def wire_of(tango: Controller) -> Wire:
    """The emulated link behind a ``sim://`` controller's current transport."""
    return faults(tango).wire


class FakeTransport(asyncio.Transport):
    """A transport that records every write; the test feeds the replies by hand."""

    def __init__(self, protocol: asyncio.Protocol) -> None:
        super().__init__()
        self.protocol = protocol
        self.writes: list[bytes] = []
        self.closed = False
        self.written = asyncio.Event()

    def write(self, data: bytes | bytearray | memoryview) -> None:
        self.writes.append(bytes(data))
        self.written.set()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            asyncio.get_running_loop().call_soon(self.protocol.connection_lost, None)

    def is_closing(self) -> bool:
        return self.closed

    @property
    def sent(self) -> bytes:
        """Everything written so far."""
        return b"".join(self.writes)


@dataclass
class FakeLink:
    """A :class:`TangoProtocol` connected to a :class:`FakeTransport`."""

    protocol: TangoProtocol
    transport: FakeTransport
    events: list[tuple[Event, Submission | None]] = field(default_factory=list)
    lost: list[BaseException | None] = field(default_factory=list)

    def feed(self, data: bytes) -> None:
        """The controller sent ``data`` (one chunk)."""
        self.protocol.data_received(data)

    async def feed_bytewise(self, data: bytes, delay: float = 0.0) -> None:
        """The controller sent ``data`` one byte per chunk, yielding in between."""
        for index in range(len(data)):
            self.protocol.data_received(data[index : index + 1])
            await asyncio.sleep(delay)

    def sent_lines(self) -> list[bytes]:
        """Command lines written so far (without CR)."""
        return self.transport.sent.split(b"\r")[:-1]

    def marker_codes(self) -> list[int]:
        """Numbers of the ``?help N`` resync markers written so far."""
        return [int(n) for n in re.findall(rb"\?help (\d+)\r", self.transport.sent)]

    async def wait_written(self, needle: bytes, count: int = 1, timeout: float = 10.0) -> None:
        """Wait until ``needle`` occurs ``count`` times in what was written."""
        async with asyncio.timeout(timeout):
            while self.transport.sent.count(needle) < count:
                self.transport.written.clear()
                await self.transport.written.wait()

    def answer_marker(self, index: int = -1) -> None:
        """Feed the reply of a resync marker (by default the latest)."""
        code = self.marker_codes()[index]
        self.feed(f"ERROR {code},marker\r".encode())


@dataclass
class Emulated:
    """A controller connected to an in-process emulator, with handles on the emulator."""

    tango: Controller

    @property
    def wire(self) -> Wire:
        """The emulated link (fault injection)."""
        return wire_of(self.tango)

    @property
    def model(self) -> ControllerModel:
        """The emulated controller's interpreter."""
        return faults(self.tango).model

    async def shorten(self, travel: float, autostatus: int | None) -> None:
        """Power the emulator up again with limit switches at ±``travel``/2 mm (quick
        cal/rm), and set the driver up again."""
        model = self.model
        axis = AxisConfig(e0_position=-travel / 2, ee_position=travel / 2)
        motion = MotionConfig(n_axes=model.axes, axes=(axis,) * 4)
        model.config = replace(model.config, motion=motion)
        model.reboot()
        await self.tango.setup(autostatus=autostatus)

    async def make_fast(self) -> None:
        """Fast motion on every axis: 100 mm/s, 20 m/s², quick cal/rm release."""
        present = "xyza"[: self.tango.context.axes]
        for name, value in (("secvel", 100), ("vel", 100), ("accel", 20), ("stopaccel", 20)):
            await self.tango.set(name, axis=None, check=True, **dict.fromkeys(present, value))
        await self.tango.set("calbspeed", 8000)


def emulated_position(emu: Emulated, axis: str) -> float:
    """Where the emulator's axis really is, in its dim unit (its own state, not a reply)."""
    motion = emu.model.motion
    return motion.to_user(axis, motion.position(axis))


async def wait_moving(emu: Emulated, axis: str) -> None:
    """Poll the emulator until ``axis`` moves."""
    for _ in range(400):
        if (await emu.tango.status())[axis] == "M":
            return
        await asyncio.sleep(0.005)
    raise AssertionError(f"{axis} did not start moving")


def abort_from_outside(emu: Emulated) -> None:
    """Stop every axis of the emulator as a second host or the keypad would: ``a`` reaches
    the controller's interpreter without passing the driver's link (L6785-6844); its
    report goes out on the link."""
    emu.model.handle_line(b"a", asyncio.get_running_loop().time())
    notify = emu.wire.notify  # the served link's wake-up: the stop ends earlier now
    assert notify is not None
    notify()


@contextlib.contextmanager
def ctrl_c_when(ready: Callable[[], bool]) -> Iterator[None]:
    """Press Ctrl+C (a real SIGINT to this process) once ``ready()`` holds, from a helper
    thread, while the body blocks in the main thread."""
    entered = threading.Event()

    def press() -> None:
        entered.wait()
        while not ready():
            time.sleep(0.001)
        time.sleep(0.02)  # the main thread is in the body's blocking call by now
        os.kill(os.getpid(), signal.SIGINT)

    helper = threading.Thread(target=press)
    helper.start()
    try:
        entered.set()
        yield
    finally:
        helper.join()


class PtySim:
    """``tango-aio sim --pty`` in a subprocess: an emulator that outlives the program
    under test, so that we can see whether its axes still move after it ended. On
    Windows (no ptys) ``sim --tcp``, and :attr:`path` is its ``socket://`` URL."""

    def __init__(self) -> None:
        where = ["--tcp", "127.0.0.1:0"] if WINDOWS else ["--pty"]
        self.proc = subprocess.Popen([sys.executable, "-m", "tango_aio", "sim", *where,
                                      "--baud", "0"], stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()

    def __enter__(self) -> PtySim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=10)
        assert self.proc.stdout is not None
        self.proc.stdout.close()

    def moving_axes(self) -> list[str]:
        """The axes that move now; asks twice for the position, 0.2 s apart."""
        async def ask() -> list[str]:
            async with connect(self.path) as tango:
                before = await tango.position()
                await asyncio.sleep(0.2)
                after = await tango.position()
                status = await tango.status()
            return [a for a in status if status[a] == "M" or before[a] != after[a]]
        return asyncio.run(ask())


class EmulatorFactory(Protocol):
    """The ``emulator`` fixture: ``await emulator(url=INSTANT, travel=None, **options)``."""

    def __call__(self, url: str = ..., *, travel: float | None = None,
                 **options: Unpack[ConnectOptions]) -> Awaitable[Emulated]: ...



# --------------------------------------------------------------------------------------
# Waiting for events (link loss, reconnect, states of other objects)

#: Fast reconnect backoff for the tests: 0.05, 0.1, 0.2, 0.2, ... s.
FAST: ReconnectOptions = {"reconnect": True, "reconnect_initial": 0.05, "reconnect_max": 0.2}


async def next_event(events: Subscription, timeout: float = 10.0) -> TangoEvent:
    async with asyncio.timeout(timeout):
        return await anext(events)


async def remaining(events: Subscription, timeout: float = 10.0) -> list[TangoEvent]:
    """Every event up to the end of the stream (fails if it does not end)."""
    async with asyncio.timeout(timeout):
        return [event async for event in events]


async def start_slow_move(tango: Controller, **target: Unpack[Axes]) -> asyncio.Task[Any]:
    """Start a move that takes seconds (default vel 10 mm/s) and wait until it runs."""
    task = asyncio.create_task(tango.move_to(**target))
    for _ in range(400):
        if "M" in (await tango.status()).values():
            return task
        await asyncio.sleep(0.005)
    raise AssertionError("the move did not start")


#: Turns of the event loop within which something that waits for no timer has ended.
TICKS = 50


async def true_within_ticks(predicate: Callable[[], bool], ticks: int = TICKS) -> None:
    """``predicate()`` becomes true within ``ticks`` turns of the event loop: at once,
    waiting for no timer. A count of loop turns, not a wall-clock time (no timer of a
    few milliseconds expires within them, and a slow machine cannot make it fail)."""
    for _ in range(ticks):
        if predicate():
            return
        await asyncio.sleep(0)
    assert predicate(), f"still false after {ticks} loop turns"


async def done_within_ticks(*awaited: asyncio.Future[Any], ticks: int = TICKS) -> None:
    """Every one of ``awaited`` ends within ``ticks`` loop turns (:func:`true_within_ticks`)."""
    await true_within_ticks(lambda: all(future.done() for future in awaited), ticks)


async def wait_lost(tango: Controller) -> None:
    """Wait until the driver has noticed that its link is gone (bounded: a hang fails)."""
    await wait_until(lambda: not tango.connected)


async def assert_fails_fast(call: Callable[[], Awaitable[object]],
                            cause: type[BaseException] = BaseException) -> None:
    """``call()`` raises ConnectionLostError at once (within :data:`TICKS` loop turns),
    with a cause of class ``cause``."""
    task = asyncio.ensure_future(call())
    await done_within_ticks(task)
    with pytest.raises(ConnectionLostError) as info:
        await task
    assert isinstance(info.value.__cause__, cause)


async def wait_until(predicate: Callable[[], bool], timeout: float = 10.0) -> None:
    """Poll until ``predicate()`` holds; ``timeout`` only bounds a hang (not a speed)."""
    async with asyncio.timeout(timeout):
        while True:  # polled: the conditions are states of other objects, not events
            if predicate():
                return
            await asyncio.sleep(0.005)


async def settled_position(fault: Faults, axis: str = "x") -> float:
    """Where the emulated ``axis`` stands once it stopped (read from the emulator). Its
    velocity alone is no test: it is 0.0 too at the instant a move starts (uvloop's clock
    ticks in milliseconds), so the motion model must say that no move is under way."""
    await wait_until(lambda: not fault.model.motion.is_moving(axis)
                     and fault.axes()[axis][1] == 0.0, timeout=30.0)
    return fault.axes()[axis][0]


async def opened(url: str, **options: Unpack[ConnectOptions]) -> Controller:
    """``connect()`` as a coroutine (for a task)."""
    return await connect(url, **options)
