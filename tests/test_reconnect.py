"""Reliability: disconnect detection, automatic reconnect, reply timeouts, line injection.

Links are the in-process emulator (``sim://``), a pty (a serial port that can be
"unplugged" by closing the server) and TCP (a server that is closed and started again on
the same port, and a proxy that resets the connection).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import itertools
import logging
import os
import pickle
import socket
import struct
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
import serial
from conftest import (
    INSTANT,
    VEL_TEXT,
    VELS,
    EmulatorFactory,
    FakeTransport,
    make_model,
    wire_of,
)

from tango_aio.cli import Shell
from tango_aio.connection import connect
from tango_aio.controller import Controller
from tango_aio.errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    InvalidCommandError,
    MoveError,
    RequestAbortedError,
)
from tango_aio.events import ConnectionLost, Reconnected, Subscription, TangoEvent
from tango_aio.instructions import Command, build, build_axes, encode, parse
from tango_aio.protocol import TangoProtocol
from tango_aio.reconnect import IdentityMismatchError, ReconnectPolicy
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.serve import serve_pty, serve_tcp
from tango_aio.sim.wire import Emit, Wire, WireConfig

pytestmark = pytest.mark.timeout(30)

#: Fast backoff for the tests: 0.05, 0.1, 0.2, 0.2, ... s.
FAST = {"reconnect": True, "reconnect_initial": 0.05, "reconnect_max": 0.2}


def make_other_firmware(emit: Emit) -> ControllerModel:
    """The same model with another firmware: not the controller the driver knew."""
    return ControllerModel(emit, SimConfig(firmware="1.69"))


async def next_event(events: Subscription, timeout: float = 3.0) -> TangoEvent:
    async with asyncio.timeout(timeout):
        return await anext(events)


async def remaining(events: Subscription, timeout: float = 2.0) -> list[TangoEvent]:
    """Every event up to the end of the stream (fails if it does not end)."""
    async with asyncio.timeout(timeout):
        return [event async for event in events]


async def start_slow_move(tango: Controller, **target: float) -> asyncio.Task[Any]:
    """Start a move that takes seconds (default vel 10 mm/s) and wait until it runs."""
    task = asyncio.create_task(tango.move_to(**target))
    for _ in range(400):
        if "M" in (await tango.status()).values():
            return task
        await asyncio.sleep(0.005)
    raise AssertionError("the move did not start")


async def assert_fails_fast(call: Callable[[], Awaitable[object]],
                            cause: type[BaseException] = BaseException) -> None:
    """``call()`` raises ConnectionLostError at once, with a cause of class ``cause``."""
    begin = time.monotonic()
    with pytest.raises(ConnectionLostError) as info:
        await call()
    assert time.monotonic() - begin < 0.05
    assert isinstance(info.value.__cause__, cause)


async def wait_until(predicate: Callable[[], bool], timeout: float = 2.0) -> None:
    async with asyncio.timeout(timeout):
        while True:  # polled: the conditions are states of other objects, not events
            if predicate():
                return
            await asyncio.sleep(0.005)


async def opened(url: str, **options: Any) -> Controller:
    """``connect()`` as a coroutine (for a task)."""
    return await connect(url, **options)


def sim_transport_tasks() -> list[asyncio.Task[Any]]:
    """Emulator tasks of in-process ``sim://`` links that are still running."""
    return [t for t in asyncio.all_tasks()
            if getattr(t.get_coro(), "__qualname__", "") == "SimTransport._serve"
            and not t.done()]


# --------------------------------------------------------------------------------------
# 1. Disconnect detection on every transport


@contextlib.asynccontextmanager
async def linked(kind: str) -> AsyncIterator[tuple[Controller, Wire]]:
    """A controller at the real baud rate over ``kind`` (sim, pty, tcp) and its wire."""
    if kind == "sim":
        async with connect("sim://") as tango:
            yield tango, wire_of(tango)
    elif kind == "pty":
        async with await serve_pty(make_model) as server, connect(server.path) as tango:
            yield tango, server.wire
    else:
        async with await serve_tcp(make_model) as server, \
                connect(f"socket://127.0.0.1:{server.port}") as tango:
            yield tango, server.wires[0]


async def _closed_at(wire: Wire) -> float:
    """The loop time at which ``wire`` was cut (polled every millisecond)."""
    while True:
        if wire.closed:
            return asyncio.get_running_loop().time()
        await asyncio.sleep(0.001)


@pytest.mark.parametrize("kind", ["sim", "pty", "tcp"])
async def test_disconnect_in_the_middle_of_a_line_fails_everything_fast(kind: str) -> None:
    async with linked(kind) as (tango, wire):
        await tango.set("vel", **VELS)
        events = tango.events()
        cut = asyncio.create_task(_closed_at(wire))
        wire.disconnect(mid_reply=True)  # half of the ?vel reply, then the link is gone
        with pytest.raises(ConnectionLostError) as info:
            await asyncio.wait_for(tango.query("?vel"), 1.0)
        failed = asyncio.get_running_loop().time()
        assert info.value.__cause__ is not None
        assert failed - await cut < 0.1
        # The half line never became a line: no reply, no unsolicited event.
        assert [type(e) for e in await remaining(events)] == [ConnectionLost]
        assert not tango.connected
        for call in (tango.position, lambda: tango.move_to(x=1), lambda: tango.query("?err")):
            await assert_fails_fast(call)
        with pytest.raises(ConnectionLostError):
            await tango.wait_connected(timeout=1.0)


class ResetProxy:
    """A TCP proxy in front of a server; :meth:`reset` aborts the client side with RST."""

    def __init__(self, upstream: int) -> None:
        self.upstream = upstream
        self.port = 0
        self._server: asyncio.Server | None = None
        self._writers: list[asyncio.StreamWriter] = []
        self._clients: list[asyncio.StreamWriter] = []
        self._tasks: list[asyncio.Task[None]] = []

    async def __aenter__(self) -> ResetProxy:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        assert self._server is not None
        self._server.close()
        for task in self._tasks:
            task.cancel()
        for writer in self._writers:
            writer.close()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        for writer in self._writers:
            with contextlib.suppress(OSError):
                await writer.wait_closed()
        await self._server.wait_closed()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream)
        self._writers += [writer, up_writer]
        self._clients.append(writer)
        self._tasks += [asyncio.create_task(self._pump(reader, up_writer)),
                        asyncio.create_task(self._pump(up_reader, writer))]

    @staticmethod
    async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(OSError):
            while data := await reader.read(4096):
                writer.write(data)

    def reset(self) -> None:
        """Close every client connection with a TCP reset (SO_LINGER 0)."""
        for writer in self._clients:
            sock = writer.get_extra_info("socket")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            writer.transport.abort()


async def test_tcp_reset_fails_pending_awaits_with_the_reset_as_cause() -> None:
    async with await serve_tcp(make_model) as server, ResetProxy(server.port) as proxy, \
            connect(f"socket://127.0.0.1:{proxy.port}") as tango:
        events = tango.events()
        move = await start_slow_move(tango, x=40)
        server.wires[0].stall(10.0)  # the query stays unanswered
        query = asyncio.create_task(tango.query("?vel"))
        await asyncio.sleep(0.02)
        start = asyncio.get_running_loop().time()
        proxy.reset()
        for task in (query, move):
            with pytest.raises(ConnectionLostError) as info:
                await asyncio.wait_for(task, 0.5)
            assert isinstance(info.value.__cause__, ConnectionResetError)
        assert asyncio.get_running_loop().time() - start < 0.1
        lost = await remaining(events)
        assert isinstance(lost[-1], ConnectionLost)
        assert isinstance(lost[-1].cause, ConnectionResetError)
        assert lost[-1].cause.errno == errno.ECONNRESET  # a real RST, not a FIN
        await assert_fails_fast(tango.position, ConnectionResetError)


# --------------------------------------------------------------------------------------
# 2. Automatic reconnect


def test_backoff_doubles_up_to_the_maximum() -> None:
    policy = ReconnectPolicy(initial=0.1, maximum=1.0, attempts=7)
    assert list(policy.delays()) == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0])
    endless = ReconnectPolicy(initial=2.0, maximum=5.0).delays()
    assert [next(endless) for _ in range(100)][-3:] == [5.0, 5.0, 5.0]


@pytest.mark.parametrize("options", [
    {"reconnect_initial": 0}, {"reconnect_initial": float("nan")},
    {"reconnect_initial": 1.0, "reconnect_max": 0.5}, {"reconnect_attempts": 0}])
async def test_bad_reconnect_options_are_refused_before_opening(options: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="reconnect"):
        await connect("/dev/nonexistent-tango", reconnect=True, **options)


async def test_sim_reconnects_and_restores_the_autostatus_mode(
        emulator: EmulatorFactory) -> None:
    emu = await emulator(autostatus=4, reconnect=True, reconnect_initial=0.01)
    tango = emu.tango
    first = tango.protocol
    async with tango.events() as events:
        emu.wire.disconnect()
        assert isinstance(await next_event(events), ConnectionLost)
        reconnected = await next_event(events)
        assert isinstance(reconnected, Reconnected) and reconnected.attempt == 1
    assert tango.connected and tango.protocol is not first
    assert emu.model.autostatus == 4 == tango.autostatus  # a fresh emulator: re-applied
    await tango.set("vel", **VELS)
    assert await tango.query("?vel") == VEL_TEXT
    await tango.wait_connected(timeout=0)


@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_a_move_in_flight_fails_even_when_the_link_is_back_at_once(
        emulator: EmulatorFactory, mode: int) -> None:
    emu = await emulator(autostatus=mode, reconnect=True, reconnect_initial=0.001)
    tango = emu.tango
    async with tango.events() as events:
        for _ in range(3):  # the loss may fall between two statusaxis polls (mode 0)
            move = await start_slow_move(tango, x=40)
            await asyncio.sleep(0.01)
            emu.wire.disconnect()
            with pytest.raises(ConnectionLostError):
                await asyncio.wait_for(move, 2.0)
            assert isinstance(await next_event(events), ConnectionLost)
            assert isinstance(await next_event(events), Reconnected)
            assert tango.autostatus == mode


async def test_tcp_server_restart_on_the_same_port_reconnects() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", autostatus=2, **FAST)
    try:
        events = tango.events()
        identity = tango.identity
        move = await start_slow_move(tango, x=40)
        server.close()
        await server.wait_closed()
        with pytest.raises(ConnectionLostError) as info:  # reported, never retried
            await asyncio.wait_for(move, 0.5)
        assert info.value.__cause__ is not None
        assert isinstance(await next_event(events), ConnectionLost)
        assert tango.reconnecting and not tango.connected
        await assert_fails_fast(tango.position)  # no waiting while the link is down
        await asyncio.sleep(0.45)  # attempts at ~0.05, 0.15 and 0.35 s are refused
        assert tango.reconnect_attempt >= 3
        server = await serve_tcp(make_model, port=port)
        await tango.wait_connected(timeout=5.0)
        reconnected = await next_event(events)
        assert isinstance(reconnected, Reconnected)
        assert reconnected.attempt == tango.reconnect_attempt >= 4
        assert tango.identity == identity
        assert server.wires[0].handler.autostatus == 2 == tango.autostatus
        # The interrupted move was not sent again to the (fresh) controller.
        assert await tango.status() == {"x": "@", "y": "@", "z": "@"}
        assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
        await tango.set("vel", **VELS)
        assert await tango.query("?vel") == VEL_TEXT
        assert events.get_nowait() is None
    finally:
        await tango.aclose()
        server.close()
        await server.wait_closed()
    assert not tango.reconnecting
    assert all(not isinstance(e, Reconnected) for e in await remaining(events))


async def test_another_firmware_answering_stops_reconnecting() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", **FAST)
    other = None
    try:
        events = tango.events()
        server.close()
        await server.wait_closed()
        assert isinstance(await next_event(events), ConnectionLost)
        other = await serve_tcp(make_other_firmware, port=port)
        with pytest.raises(ConnectionLostError) as info:
            await tango.wait_connected(timeout=5.0)
        assert isinstance(info.value.__cause__, IdentityMismatchError)
        assert "1.69" in str(info.value.__cause__)
        assert not tango.reconnecting
        assert await remaining(events) == []  # ended, no Reconnected
        await assert_fails_fast(tango.position, IdentityMismatchError)
        await wait_until(lambda: other is not None and not other.wires)  # link closed
    finally:
        await tango.aclose()
        if other is not None:
            other.close()
            await other.wait_closed()


async def test_reconnect_gives_up_after_the_attempts() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", reconnect=True,
                          reconnect_initial=0.02, reconnect_max=0.05, reconnect_attempts=3)
    try:
        events = tango.events()
        server.close()
        await server.wait_closed()
        assert isinstance(await next_event(events), ConnectionLost)
        with pytest.raises(ConnectionLostError) as info:
            await tango.wait_connected(timeout=2.0)
        assert tango.reconnect_attempt == 3 and not tango.reconnecting
        assert isinstance(info.value.__cause__, ConnectionLostError)  # cannot connect
        assert isinstance(info.value.__cause__.__cause__, OSError)
        assert await remaining(events) == []
    finally:
        await tango.aclose()


async def test_unplugged_serial_port_backs_off_until_aclose(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="tango_aio")
    server = await serve_pty(make_model)
    tango = await connect(server.path, **FAST)
    try:
        events = tango.events()
        server.close()  # the pty disappears: like a USB adapter pulled out
        await server.wait_closed()
        assert isinstance(await next_event(events), ConnectionLost)
        await asyncio.sleep(1.0)
        assert tango.reconnecting
    finally:
        await tango.aclose()
    records = [r for r in caplog.records if "reconnect attempt" in r.getMessage()]
    numbers = [int(r.getMessage().split()[2]) for r in records]
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) >= 4
    gaps = [b.created - a.created for a, b in itertools.pairwise(records)]
    assert 0.08 <= gaps[0] <= 0.2  # 0.1 s
    assert all(0.18 <= gap <= 0.35 for gap in gaps[1:])  # 0.2 s, then capped at 0.2 s
    assert not tango.reconnecting
    await asyncio.sleep(0.3)
    assert len([r for r in caplog.records if "reconnect attempt" in r.getMessage()]) == len(
        records)  # aclose stopped it
    assert await remaining(events) == []
    with pytest.raises(ConnectionLostError):
        await tango.wait_connected(timeout=1.0)


async def test_aclose_while_reconnecting_closes_the_half_set_up_link() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", **FAST)
    server.close()
    await server.wait_closed()
    # The new controller takes 10 s per line: the reconnect's set-up hangs in its resync.
    slow = await serve_tcp(make_model, port=port, config=WireConfig(
        baud=None, processing_time_per_line=10.0))
    try:
        await asyncio.wait_for(slow.next_connection(), 2.0)
        assert tango.reconnecting and not tango.connected
        await assert_fails_fast(tango.position)  # not routed to the half-set-up link
        with pytest.raises(TimeoutError):
            await tango.wait_connected(timeout=0.05)
        await tango.aclose()
        assert not tango.reconnecting
        await wait_until(lambda: not slow.wires)
    finally:
        slow.close()
        await slow.wait_closed()


async def test_wait_connected_without_reconnect(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    await emu.tango.wait_connected(timeout=0)
    assert emu.tango.connected and not emu.tango.reconnecting
    events = emu.tango.events()
    emu.wire.disconnect()
    assert [type(e) for e in await remaining(events)] == [ConnectionLost]
    with pytest.raises(ConnectionLostError) as info:
        await emu.tango.wait_connected(timeout=1.0)
    assert isinstance(info.value.__cause__, ConnectionResetError)


# --------------------------------------------------------------------------------------
# 2. Fixes: cancelled connect(), exclusive serial ports, picklable MoveError


@pytest.mark.parametrize("ticks", range(0, 12))
async def test_a_cancelled_sim_connect_leaves_no_emulator_running(ticks: int) -> None:
    task = asyncio.create_task(opened(INSTANT))
    for _ in range(ticks):
        await asyncio.sleep(0)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        tango = await task
        await tango.aclose()  # it finished before the cancellation reached it
    await wait_until(lambda: not sim_transport_tasks())


async def test_connect_cancelled_before_connection_made_closes_the_transport(
        monkeypatch: pytest.MonkeyPatch) -> None:
    protocols: list[TangoProtocol] = []
    hang = asyncio.Event()

    async def never(self: TangoProtocol) -> None:
        protocols.append(self)
        await hang.wait()

    monkeypatch.setattr(TangoProtocol, "wait_connected", never)
    task = asyncio.create_task(opened(INSTANT))
    await wait_until(lambda: bool(protocols))
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert protocols[0].transport is not None and protocols[0].transport.is_closing()
    await wait_until(lambda: not sim_transport_tasks())


async def test_a_protocol_closed_before_connection_made_closes_its_transport() -> None:
    protocol = TangoProtocol()
    transport = FakeTransport(protocol)
    protocol.close()  # e.g. connect() cancelled while a serial transport was being made
    protocol.connection_made(transport)
    assert transport.closed
    await asyncio.sleep(0)
    with pytest.raises(ConnectionLostError):
        protocol.check()


async def test_serial_ports_are_opened_exclusively() -> None:
    async with await serve_pty(make_model) as server, connect(server.path):
        with pytest.raises(ConnectionLostError, match="exclusive") as info:
            await connect(server.path)
        assert isinstance(info.value.__cause__, serial.SerialException)


async def test_a_connect_cancelled_while_the_port_opens_closes_the_port(
        monkeypatch: pytest.MonkeyPatch) -> None:
    real = serial.serial_for_url
    ports: list[Any] = []

    def slow_open(*args: Any, **kwargs: Any) -> Any:
        time.sleep(0.2)  # runs in the opening thread
        ports.append(real(*args, **kwargs))
        return ports[-1]

    async with await serve_pty(make_model) as server:
        monkeypatch.setattr(serial, "serial_for_url", slow_open)
        task = asyncio.create_task(opened(server.path))
        await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await wait_until(lambda: bool(ports) and not ports[0].is_open)
        monkeypatch.setattr(serial, "serial_for_url", real)
        async with connect(server.path) as tango:  # the lock was released
            assert tango.connected


async def test_a_connect_cancelled_before_connection_made_closes_the_serial_port(
        monkeypatch: pytest.MonkeyPatch) -> None:
    hang = asyncio.Event()

    async def never(self: TangoProtocol) -> None:
        await hang.wait()

    async with await serve_pty(make_model) as server:
        with monkeypatch.context() as patch:
            patch.setattr(TangoProtocol, "wait_connected", never)
            task = asyncio.create_task(opened(server.path))
            await asyncio.sleep(0.1)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
        await asyncio.sleep(0.01)
        async with connect(server.path) as tango:  # the exclusive lock was released
            assert tango.connected


def test_move_error_pickles_with_its_statuses() -> None:
    error = MoveError("'!moa 1' ended with status {'x': 'S'}", {"x": "S", "y": "@"})
    error.add_note("while scanning")
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is MoveError
    assert str(again) == str(error) and again.statuses == {"x": "S", "y": "@"}
    assert again.__notes__ == ["while scanning"]


# --------------------------------------------------------------------------------------
# 3. Reply timeouts


async def test_default_reply_timeout_is_five_seconds(emulator: EmulatorFactory) -> None:
    assert (await emulator()).tango.reply_timeout == 5.0


async def test_a_controller_that_stops_answering_times_out_then_the_link_is_lost(
        emulator: EmulatorFactory) -> None:
    """#14 item 5: a link that stays open but forwards nothing (an adapter that stopped,
    a controller power-cycled behind one). The first request fails with its own timeout,
    its resync marker goes unanswered too, and the link is declared lost: every later
    call fails at once with ConnectionLostError whose cause says why."""
    emu = await emulator(reply_timeout=0.2)
    tango = emu.tango
    async with tango.events() as events:
        emu.wire.stall(60.0)
        with pytest.raises(ControllerTimeoutError, match=r"no reply to '\?vel'"):
            await tango.query("?vel")
        lost = await next_event(events)
        assert isinstance(lost, ConnectionLost)
        assert isinstance(lost.cause, ConnectionAbortedError)
    assert not tango.connected
    for call in (lambda: tango.query("?vel"), tango.position,
                 lambda: tango.set("vel", x=5)):
        with pytest.raises(ConnectionLostError) as caught:
            await call()
        assert isinstance(caught.value.__cause__, ConnectionAbortedError)


async def test_a_dead_link_reconnects_when_enabled(emulator: EmulatorFactory) -> None:
    emu = await emulator(reply_timeout=0.2, autostatus=2, **FAST)
    tango = emu.tango
    async with tango.events() as events:
        emu.wire.faults.drop_replies = 1_000_000  # forwards nothing back, stays open
        with pytest.raises(ControllerTimeoutError):
            await tango.query("?vel")
        assert isinstance(await next_event(events), ConnectionLost)
        assert isinstance(await next_event(events), Reconnected)
    assert tango.connected and tango.autostatus == 2
    await tango.set("vel", **VELS)
    assert await tango.query("?vel") == VEL_TEXT


async def test_keepalive_notices_a_dead_idle_link(emulator: EmulatorFactory) -> None:
    emu = await emulator(reply_timeout=0.1, keepalive=0.05)
    tango = emu.tango
    async with tango.events() as events:
        emu.wire.stall(60.0)  # no call of ours: only the keepalive can notice
        lost = await next_event(events)
        assert isinstance(lost, ConnectionLost)
    assert not tango.connected


async def test_keepalive_restores_the_mode_after_a_restart_behind_the_adapter(
        emulator: EmulatorFactory) -> None:
    """The controller restarts (power-on mode 1) while the link stays open: the keepalive
    reads a mode other than the one in force and restores it."""
    emu = await emulator(autostatus=2, keepalive=0.02)
    emu.model.reboot()
    for _ in range(200):
        if emu.model.autostatus == 2 == emu.tango.autostatus:
            break
        await asyncio.sleep(0.01)
    assert emu.model.autostatus == 2 == emu.tango.autostatus
    await emu.tango.set("vel", **VELS)
    assert await emu.tango.query("?vel") == VEL_TEXT


async def test_a_stalled_controller_answers_again_in_sync(emulator: EmulatorFactory) -> None:
    emu = await emulator(reply_timeout=0.2, dead_after=10)  # a stall, not a dead link
    tango = emu.tango
    await tango.set("vel", **VELS)
    loop = asyncio.get_running_loop()
    start = loop.time()
    emu.wire.stall(0.8)
    with pytest.raises(ControllerTimeoutError):
        await tango.query("?vel")
    assert loop.time() - start < 0.55
    await asyncio.sleep(0.8 - (loop.time() - start) + 0.05)
    # The late ?vel reply was dropped: it is not taken for the reply to ?pos.
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
    assert await tango.query("?vel") == VEL_TEXT


async def test_a_dropped_reply_times_out_and_the_stream_stays_in_sync(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()
    tango = emu.tango
    await tango.set("vel", **VELS)
    emu.wire.faults.drop_replies = 1
    loop = asyncio.get_running_loop()
    start = loop.time()
    # The dropped reply is the separator's before '?vel' (the last request of the set-up
    # also answered numbers): '?vel' then fails as the resync aborts it.
    with pytest.raises((ControllerTimeoutError, RequestAbortedError)):
        await tango.query("?vel", timeout=0.2)
    assert loop.time() - start < 0.2 + 0.15  # the resync marker is answered at once
    assert emu.wire.dropped_replies == 1
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
    assert await tango.query("?vel") == VEL_TEXT


async def test_a_late_reply_is_dropped(emulator: EmulatorFactory) -> None:
    emu = await emulator(dead_after=10)
    tango = emu.tango
    await tango.set("vel", **VELS)
    emu.wire.faults.delay_replies = 1
    emu.wire.faults.reply_delay = 0.6
    with pytest.raises(ControllerTimeoutError):
        await tango.query("?vel", timeout=0.2)
    await asyncio.sleep(0.5)  # the late reply and the marker's arrive meanwhile
    assert await tango.get("vel", axis="x") == 11.5
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}


# --------------------------------------------------------------------------------------
# 7. Security: no CR, LF or Ctrl+C reaches the wire; loopback; atomic state file


class _NoInput:
    async def read(self) -> str:
        raise EOFError


def _hand_built(tango: Controller, char: str) -> Awaitable[object]:
    command = parse("!vel x 5")
    forged = Command(command.instruction, command.form, "x", (5,), (f"5{char}!moa 9",))

    async def submit() -> object:
        return tango.protocol.submit(forged)

    return submit()


#: Every public entry point that takes a string, with ``char`` smuggled into it.
ENTRY_POINTS: dict[str, Callable[[Controller, str], Awaitable[object]]] = {
    "query": lambda t, c: t.query(f"?pos{c}!moa 9 9"),
    "query-trailing": lambda t, c: t.query(f"?pos{c}"),
    "command": lambda t, c: t.command(f"!vel 5{c}!moa 9"),
    "command-unchecked": lambda t, c: t.command(f"!vel 5{c}", check=False),
    "get-name": lambda t, c: t.get(f"vel{c}"),
    "get-arg": lambda t, c: t.get("trigp", f"1{c}"),
    "get-axis": lambda t, c: t.get("vel", axis=f"x{c}"),
    "set-arg": lambda t, c: t.set("vel", f"5{c}!moa 9", axis="x"),
    "set-axis": lambda t, c: t.set("vel", 5, axis=f"y{c}"),
    "set-keyword": lambda t, c: t.set("vel", x=f"5{c}!moa 9"),
    "move_to": lambda t, c: t.move_to(x=f"1{c}!moa 9"),  # type: ignore[arg-type]
    "move_by": lambda t, c: t.move_by(y=f"1{c}"),  # type: ignore[arg-type]
    "go": lambda t, c: t.go(x=f"1{c}"),  # type: ignore[arg-type]
    "speed": lambda t, c: t.speed(x=f"1{c}"),  # type: ignore[arg-type]
    "calibrate": lambda t, c: t.calibrate(f"x{c}"),
    "measure_range": lambda t, c: t.measure_range(f"y{c}"),
    "move_to_center": lambda t, c: t.move_to_center(f"z{c}"),
    "set_trigger_range": lambda t, c: t.set_trigger_range(0, 1, 2, axis=f"x{c}"),
    "upload_trigger_positions": lambda t, c: t.upload_trigger_positions([1.0], axis=f"x{c}"),
    "shell": lambda t, c: Shell(t, _NoInput()).execute(f"?pos{c}!moa 9 9"),
    "protocol-submit": _hand_built,
}


@pytest.mark.parametrize("char", ["\r", "\n", "\x03"], ids=["CR", "LF", "ETX"])
@pytest.mark.parametrize("entry", sorted(ENTRY_POINTS))
async def test_control_characters_are_refused_before_writing(
        emulator: EmulatorFactory, monkeypatch: pytest.MonkeyPatch, entry: str,
        char: str) -> None:
    tango = (await emulator()).tango
    transport = tango.protocol.transport
    written: list[bytes] = []
    monkeypatch.setattr(transport, "write", written.append)
    with pytest.raises(InvalidCommandError):
        await ENTRY_POINTS[entry](tango, char)
    assert written == []


@pytest.mark.parametrize("char", ["\r", "\n", "\x03"], ids=["CR", "LF", "ETX"])
@pytest.mark.parametrize("call", [
    lambda c: encode(f"!vel 5{c}!moa 9"),
    lambda c: parse(f"?pos{c}"),
    lambda c: build("vel", f"5{c}", axis="x"),
    lambda c: build(f"vel{c}", 5),
    lambda c: build("vel", 5, axis=f"x{c}"),
    lambda c: build_axes("moa", {"x": f"1{c}!moa 9"}),
], ids=["encode", "parse", "build-value", "build-name", "build-axis", "build_axes"])
def test_the_catalog_refuses_control_characters(call: Callable[[str], object],
                                                char: str) -> None:
    with pytest.raises(InvalidCommandError):
        call(char)


async def test_tcp_emulator_binds_to_loopback_by_default() -> None:
    async with await serve_tcp(make_model) as server:
        assert server.host == "127.0.0.1"


async def test_the_state_file_is_replaced_atomically(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, emulator: EmulatorFactory) -> None:
    state = tmp_path / "tango.json"
    tango = (await emulator(f"sim://?baud=0&state={state}")).tango
    await tango.set("vel", 3, axis="x")
    await tango.command("save")
    old = state.read_bytes()

    def crash(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        raise OSError("power failure")

    monkeypatch.setattr(os, "replace", crash)
    await tango.set("vel", 7, axis="x")
    with pytest.raises(ControllerError) as info:
        await tango.command("save")
    assert info.value.error_code == 73
    assert state.read_bytes() == old  # the old file, whole
    assert os.listdir(tmp_path) == [state.name]  # no temp file left behind
