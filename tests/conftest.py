"""Shared test settings and fixtures."""

from __future__ import annotations

import asyncio
import re
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field, replace
from typing import Any

import pytest
from hypothesis import settings

from tango_aio.connection import connect
from tango_aio.controller import Controller
from tango_aio.core import Event
from tango_aio.protocol import Submission, TangoProtocol
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.motion import AxisConfig, MotionConfig
from tango_aio.sim.wire import Emit, Wire

# No per-example deadline: the first examples pay for imports and would flake on a busy CI.
settings.register_profile("tango_aio", deadline=None)
settings.load_profile("tango_aio")


# --------------------------------------------------------------------------------------
# Shared fixtures of the driver tests (tiers 2 and 3)

#: The in-process emulator without line pacing (motion still runs in real time).
INSTANT = "sim://?baud=0"
#: Distinctive per-axis velocities: a reply routed to the wrong request cannot match.
VELS = {"x": 11.5, "y": 12.25, "z": 13.125}
VEL_TEXT = "11.500 12.250 13.125"


def make_model(emit: Emit) -> ControllerModel:
    """Handler factory of the pty and TCP servers: a default 3-axis controller (TANGO-DT,
    firmware 1.71)."""
    return ControllerModel(emit, SimConfig())


def wire_of(tango: Controller) -> Wire:
    """The emulated link behind a ``sim://`` controller's current transport."""
    transport = tango.protocol.transport
    assert transport is not None
    wire = transport.get_extra_info("wire")
    assert isinstance(wire, Wire)
    return wire


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

    async def wait_written(self, needle: bytes, count: int = 1, timeout: float = 2.0) -> None:
        """Wait until ``needle`` occurs ``count`` times in what was written."""
        async with asyncio.timeout(timeout):
            while self.transport.sent.count(needle) < count:
                self.transport.written.clear()
                await self.transport.written.wait()

    def answer_marker(self, index: int = -1) -> None:
        """Feed the reply of a resync marker (by default the latest)."""
        code = self.marker_codes()[index]
        self.feed(f"ERROR {code},marker\r".encode())


@pytest.fixture
def fake_link() -> Callable[..., FakeLink]:
    """Factory: ``fake_link(autostatus=1)`` (call it inside the test's event loop)."""

    def make(**options: Any) -> FakeLink:
        # Hand-fed tests answer each line themselves: separators between look-alike
        # requests (answered like markers) only where a test asks for them.
        options.setdefault("separators", False)
        protocol = TangoProtocol(**options)
        link = FakeLink(protocol, FakeTransport(protocol))
        protocol.set_callbacks(lambda event, sub: link.events.append((event, sub)),
                               link.lost.append)
        protocol.connection_made(link.transport)
        return link

    return make


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
        handler = self.wire.handler
        assert isinstance(handler, ControllerModel)
        return handler

    async def shorten(self, travel: float, autostatus: int) -> None:
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
            await self.tango.set(name, **{a: value for a in present})
        await self.tango.set("calbspeed", 8000)


EmulatorFactory = Callable[..., Awaitable[Emulated]]


@pytest.fixture
async def emulator() -> AsyncIterator[EmulatorFactory]:
    """Factory: ``await emulator(url=INSTANT, travel=None, **connect_options)``; closed at
    teardown. ``travel`` (mm) shortens the axes so that cal/rm take a fraction of a second.
    """
    opened: list[Controller] = []

    async def open_one(url: str = INSTANT, *, travel: float | None = None,
                       **options: Any) -> Emulated:
        tango = await connect(url, **options)
        opened.append(tango)
        emulated = Emulated(tango)
        if travel is not None:
            await emulated.shorten(travel, options.get("autostatus", 1))
        return emulated

    yield open_one
    for tango in opened:
        await tango.aclose()
