"""Tests of the real-time serving layers: pty (with pyserial), TCP and in-process."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import math
import os
import socket
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import pytest
import serial
from helpers import serve_pty
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.cli._main import _parser
from tango_aio.cli._main import main as cli_main
from tango_aio.cli._simcmd import _sim_url, _tcp_address
from tango_aio.sim.clock import EmulatorClock, ScaledHandler
from tango_aio.sim.inprocess import configs_from_url, open_sim, speed_from_url
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import PROFILES, Firmware
from tango_aio.sim.serve import (
    CONNECTION_BACKLOG,
    INPUT_QUEUE_LIMIT,
    INPUT_QUEUE_RESUME,
    SharedController,
    SimTransport,
    TcpServer,
    WireRunner,
    create_sim_connection,
    serve_tcp,
)
from tango_aio.sim.state import FORMAT, MAX_SIZE, VERSION, StateFileError, save_state
from tango_aio.sim.wire import Emit, HandlerFactory, Wire, WireConfig

from .test_wire import BT, PingHandler

# A hang's bound, not a speed: generous enough for a machine under load (subprocess
# starts take seconds there).
pytestmark = pytest.mark.timeout(60)

SLOW = WireConfig(processing_time_per_line=0.005)
"""Processing slower than the line rate of ``?ping`` lines (6 bytes = 1.15 ms)."""
STREAM = b"?ping\r" * 200


def handler_of(wire: Wire) -> PingHandler:
    handler = wire.handler
    assert isinstance(handler, PingHandler)
    return handler


def assert_conserved(wire: Wire, sent: int) -> None:
    """Every byte sent was lost, executed as part of a line, or is still buffered."""
    assert wire.rx_pending == 0
    handled = sum(len(line) + 1 for line in handler_of(wire).texts)
    assert wire.lost_bytes + handled + wire.buffered == sent


def recv_line(sock: socket.socket) -> bytes:
    """Read from ``sock`` up to and including a CR (replies may arrive in pieces)."""
    reply = b""
    while not reply.endswith(b"\r"):
        chunk = sock.recv(100)
        if not chunk:
            break
        reply += chunk
    return reply


def read_until_settled(read: Callable[[], bytes], settled: Callable[[], bool]) -> bytes:
    """Collect bytes from ``read()`` (a blocking call with a short timeout) until the
    emulator is done (``settled()``, its own state, asked before the read) and a read then
    returns none: a read that times out ends nothing while the emulator is still at work,
    so a loaded machine cannot cut the output short. 30 s bound a hang."""
    out = b""
    deadline = time.monotonic() + 30.0
    while True:
        done = settled()  # what it had sent by then is in the OS buffer: read below
        chunk = read()
        out += chunk
        if done and not chunk:
            return out
        assert time.monotonic() < deadline, out


def asked_in_loop(predicate: Callable[[], bool]) -> Callable[[], bool]:
    """``predicate`` evaluated in the running event loop (the emulator's), for a thread."""
    loop = asyncio.get_running_loop()

    async def ask() -> bool:
        return predicate()

    return lambda: asyncio.run_coroutine_threadsafe(ask(), loop).result(timeout=30.0)


def idle(wire: Wire) -> bool:
    """The emulated link took every byte it got and sent every reply it made."""
    return not wire.busy and wire.rx_pending == 0 and wire.tx_pending == 0


def overflow_done(wires: Callable[[], list[Wire]], sent: int) -> bool:
    """Every byte of ``sent`` reached the (only) wire, which is idle: nothing more comes."""
    found = wires()
    if not found:
        return False
    wire = found[0]
    handled = sum(len(line) + 1 for line in handler_of(wire).texts)
    return idle(wire) and wire.lost_bytes + handled + wire.buffered == sent


def ctrl_c_done(wires: Callable[[], list[Wire]]) -> bool:
    """The (only) wire got its Ctrl+C and is idle: nothing more comes."""
    found = wires()
    return bool(found) and found[0].ctrl_c_count == 1 and idle(found[0])


# ---------------------------------------------------------------------------------- pty


async def test_pty_round_trip_with_pyserial() -> None:
    async with await serve_pty(PingHandler) as server:

        def host() -> tuple[bytes, float]:
            with serial.Serial(server.path, 57600, timeout=1) as port:
                start = time.monotonic()
                port.write(b"?ping\r")
                reply = port.read_until(b"\r")
                return reply, time.monotonic() - start

        reply, elapsed = await asyncio.to_thread(host)
    assert reply == b"pong\r"
    assert elapsed >= 11 * BT  # 6 bytes in, 5 bytes out at 57600 Bd
    assert handler_of(server.wire).texts == [b"?ping"]


async def test_pty_overflow_loses_bytes() -> None:
    async with await serve_pty(PingHandler, SLOW) as server:
        settled = asked_in_loop(lambda: overflow_done(lambda: [server.wire], len(STREAM)))

        def host() -> bytes:
            with serial.Serial(server.path, 57600, timeout=0.3) as port:
                port.write(STREAM)
                return read_until_settled(lambda: port.read(4096), settled)

        replies = await asyncio.to_thread(host)
        wire = server.wire
        assert wire.lost_bytes > 0
        assert_conserved(wire, len(STREAM))
        assert replies == b"pong\r" * handler_of(wire).texts.count(b"?ping")
        assert replies.count(b"pong\r") < 200


async def test_pty_ctrl_c_clears_input() -> None:
    config = WireConfig(processing_time_per_line=0.1)
    async with await serve_pty(PingHandler, config) as server:
        settled = asked_in_loop(lambda: ctrl_c_done(lambda: [server.wire]))

        def host() -> tuple[bytes, bytes]:
            with serial.Serial(server.path, 57600, timeout=0.3) as port:
                port.write(b"?ping\r?ping\r?ping\r\x03")
                first = read_until_settled(lambda: port.read(100), settled)
                port.timeout = 30.0  # this reply comes: a bound on a hang only
                port.write(b"?ping\r")
                return first, port.read_until(b"\r")

        first, second = await asyncio.to_thread(host)
        handler = handler_of(server.wire)
    assert first == b"pong\r"  # only the line already being processed
    assert second == b"pong\r"
    assert handler.texts == [b"?ping", b"?ping"]
    assert len(handler.ctrl_cs) == 1


async def test_pty_disconnect_is_seen_by_host() -> None:
    server = await serve_pty(PingHandler)
    opened = asyncio.Event()
    loop = asyncio.get_running_loop()

    def host() -> bytes:
        with serial.Serial(server.path, 57600, timeout=2) as port:
            port.write(b"?ping\r")
            reply = port.read_until(b"\r")
            loop.call_soon_threadsafe(opened.set)
            with pytest.raises(serial.SerialException):
                port.read(1)
            return reply

    task = asyncio.create_task(asyncio.to_thread(host))
    await opened.wait()
    server.wire.disconnect()
    await server.wait_closed()
    assert await task == b"pong\r"  # the host's read failed: it noticed the disconnect


async def test_pty_disconnect_mid_reply() -> None:
    server = await serve_pty(PingHandler)
    server.wire.disconnect(mid_reply=True)

    def host() -> bytes:
        got = b""
        with serial.Serial(server.path, 57600, timeout=2) as port:
            port.write(b"echo 0123456789\r")
            with pytest.raises(serial.SerialException):
                while chunk := port.read(1):
                    got += chunk
        return got

    assert await asyncio.to_thread(host) == b"01234"
    await server.wait_closed()


# ---------------------------------------------------------------------------------- tcp


async def test_tcp_binds_loopback_and_round_trips_with_a_socket() -> None:
    async with await serve_tcp(PingHandler) as server:
        assert server.host == "127.0.0.1"
        assert server.port > 0

        def host() -> bytes:
            with socket.create_connection(("127.0.0.1", server.port), timeout=1) as sock:
                sock.sendall(b"?ping\r")
                reply = b""
                while not reply.endswith(b"\r"):
                    reply += sock.recv(100)
                return reply

        assert await asyncio.to_thread(host) == b"pong\r"


async def test_tcp_round_trip_with_pyserial_url() -> None:
    async with await serve_tcp(PingHandler) as server:

        def host() -> bytes:
            port = serial.serial_for_url(f"socket://127.0.0.1:{server.port}", timeout=1)
            try:
                port.write(b"?PING\r")
                return bytes(port.read_until(b"\r"))
            finally:
                port.close()

        assert await asyncio.to_thread(host) == b"pong\r"


async def test_tcp_per_connection_gives_each_connection_a_fresh_controller() -> None:
    async with await serve_tcp(PingHandler, config=WireConfig(baud=None),
                               shared=False) as server:

        def host(text: bytes) -> bytes:
            with socket.create_connection(("127.0.0.1", server.port), timeout=1) as sock:
                sock.sendall(b"echo " + text + b"\r")
                return recv_line(sock)

        assert await asyncio.to_thread(host, b"one") == b"one\r"
        first = await server.next_connection()
        assert await asyncio.to_thread(host, b"two") == b"two\r"
        second = await server.next_connection()
    assert first is not second
    assert handler_of(first).texts == [b"echo one"]
    assert handler_of(second).texts == [b"echo two"]


async def test_tcp_overflow_loses_bytes() -> None:
    async with await serve_tcp(PingHandler, config=SLOW) as server:
        settled = asked_in_loop(lambda: overflow_done(lambda: server.wires, len(STREAM)))

        def host() -> bytes:
            with socket.create_connection(("127.0.0.1", server.port), timeout=0.3) as sock:
                sock.sendall(STREAM)

                def recv() -> bytes:
                    try:
                        return sock.recv(4096)
                    except TimeoutError:
                        return b""

                return read_until_settled(recv, settled)

        replies = await asyncio.to_thread(host)
        wire = server.wires[0] if server.wires else await server.next_connection()
    assert wire.lost_bytes > 0
    assert_conserved(wire, len(STREAM))
    assert replies == b"pong\r" * handler_of(wire).texts.count(b"?ping")


async def test_tcp_ctrl_c_clears_input() -> None:
    async with await serve_tcp(PingHandler, config=WireConfig(processing_time_per_line=0.1)) \
            as server:
        settled = asked_in_loop(lambda: ctrl_c_done(lambda: server.wires))

        def host() -> bytes:
            port = serial.serial_for_url(f"socket://127.0.0.1:{server.port}", timeout=0.3)
            try:
                port.write(b"?ping\r?ping\r?ping\r\x03")
                return read_until_settled(lambda: port.read(100), settled)
            finally:
                port.close()

        assert await asyncio.to_thread(host) == b"pong\r"
        wire = await server.next_connection()
    assert handler_of(wire).texts == [b"?ping"]
    assert wire.ctrl_c_count == 1


async def test_tcp_disconnect_is_seen_by_socket_and_pyserial() -> None:
    async with await serve_tcp(PingHandler) as server:

        def socket_host() -> tuple[bytes, bytes]:
            with socket.create_connection(("127.0.0.1", server.port), timeout=1) as sock:
                sock.sendall(b"echo 0123456789\r")
                got = b""
                while chunk := sock.recv(100):
                    got += chunk
                return got, chunk

        task = asyncio.create_task(asyncio.to_thread(socket_host))
        wire = await server.next_connection()
        wire.disconnect(mid_reply=True)
        assert await task == (b"01234", b"")  # partial reply, then EOF

        def serial_host() -> None:
            port = serial.serial_for_url(f"socket://127.0.0.1:{server.port}", timeout=1)
            try:
                with pytest.raises(serial.SerialException):
                    port.read(1)
            finally:
                port.close()

        task2 = asyncio.create_task(asyncio.to_thread(serial_host))
        (await server.next_connection()).disconnect()
        await task2


async def test_tcp_stall_delays_the_reply_in_real_time() -> None:
    async with await serve_tcp(PingHandler) as server:
        sock = await asyncio.to_thread(socket.create_connection, ("127.0.0.1", server.port), 1)
        with sock:
            wire = await server.next_connection()
            await asyncio.sleep(0.2)  # the runner is idle: its wire's time is stale
            wire.stall(0.3)
            start = time.monotonic()
            await asyncio.to_thread(sock.sendall, b"?ping\r")
            assert await asyncio.to_thread(recv_line, sock) == b"pong\r"
            assert time.monotonic() - start >= 0.29


async def test_tcp_close_ends_open_connections() -> None:
    server = await serve_tcp(PingHandler)
    sock = await asyncio.to_thread(socket.create_connection, ("127.0.0.1", server.port), 1)
    with sock:
        await server.next_connection()
        server.close()
        await server.wait_closed()
        assert await asyncio.to_thread(sock.recv, 100) == b""
    assert server.wires == []


# ---------------------------------------------------------------------------- in-process


class Collector(asyncio.Protocol):
    """Records what an in-process transport delivers."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.made: list[asyncio.BaseTransport] = []
        self.lost: asyncio.Future[Exception | None] = asyncio.get_running_loop().create_future()
        self._got = asyncio.Event()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.made.append(transport)

    def data_received(self, data: bytes) -> None:
        self.chunks.append(data)
        self._got.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.set_result(exc)

    async def read_until(self, end: bytes = b"\r") -> bytes:
        while not b"".join(self.chunks).endswith(end):
            self._got.clear()
            await asyncio.wait_for(self._got.wait(), 1.0)
        return b"".join(self.chunks)


async def test_sim_connection_round_trip_with_fragmentation() -> None:
    config = WireConfig(fragment_probability=1.0, seed=3, baud=None, fragment_gap=0.002)
    transport, protocol = await create_sim_connection(Collector, PingHandler, config)
    assert isinstance(transport, SimTransport)
    assert protocol.made == [transport]
    transport.write(b"echo hello world\r")
    assert await protocol.read_until() == b"hello world\r"
    assert len(protocol.chunks) > 1  # delivered in pieces
    assert transport.get_extra_info("wire") is transport.wire
    transport.close()
    assert await protocol.lost is None
    assert transport.is_closing()
    transport.write(b"?ping\r")  # ignored after close
    await transport.wait_closed()


async def test_sim_connection_is_paced() -> None:
    transport, protocol = await create_sim_connection(Collector, PingHandler)
    loop = asyncio.get_running_loop()
    start = loop.time()
    transport.write(b"?ping\r")
    assert await protocol.read_until() == b"pong\r"
    assert loop.time() - start >= 11 * BT
    transport.close()


async def test_sim_connection_disconnect_fault() -> None:
    transport, protocol = await create_sim_connection(Collector, PingHandler)
    transport.wire.disconnect(mid_reply=True)
    transport.write(b"echo 0123456789\r")
    exc = await asyncio.wait_for(protocol.lost, 1.0)
    assert isinstance(exc, ConnectionResetError)
    assert b"".join(protocol.chunks) == b"01234"
    assert transport.is_closing()


async def test_sim_connection_pause_reading_holds_output() -> None:
    transport, protocol = await create_sim_connection(
        Collector, PingHandler, WireConfig(baud=None))
    transport.pause_reading()
    assert not transport.is_reading()
    transport.write(b"?ping\r")
    await asyncio.sleep(0.02)
    assert protocol.chunks == []
    transport.resume_reading()
    assert protocol.chunks == [b"pong\r"]
    transport.close()


async def test_sim_connection_overflow_and_ctrl_c() -> None:
    transport, protocol = await create_sim_connection(
        Collector, PingHandler, WireConfig(baud=None, processing_time_per_line=0.05))
    transport.write(b"?ping\r" * 50)
    transport.write(b"\x03")
    assert await protocol.read_until() == b"pong\r"
    await asyncio.sleep(0.1)
    assert protocol.chunks == [b"pong\r"]
    wire = transport.wire
    assert wire.lost_bytes == 300 - 256
    assert handler_of(wire).texts == [b"?ping"]
    transport.close()


# ------------------------------------------------------------------------- time scale


def scaled_model_wire(speed: float, config: WireConfig | None = None) -> Wire:
    """A wire to a ControllerModel on emulator time, both clocks starting at 0."""

    def model(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, SimConfig(), now=0.0)

    return Wire(lambda emit: ScaledHandler(model, emit, speed, origin=0.0),
                config or WireConfig(baud=None))


def reply_times(wire: Wire, line: bytes, count: int, at: float = 0.0
                ) -> list[tuple[float, bytes]]:
    """Feed ``line`` at ``at`` and step the wire deadline by deadline (virtual time) until
    ``count`` reply lines arrived; each with the wire time its CR arrived."""
    wire.feed(line, at)
    replies: list[tuple[float, bytes]] = []
    pending = b""
    while len(replies) < count:
        deadline = wire.next_deadline()
        assert deadline is not None, replies
        pending += wire.poll(deadline)
        while b"\r" in pending:
            text, _, pending = pending.partition(b"\r")
            replies.append((deadline, text))
    return replies


@pytest.mark.parametrize("line", [b"!moa 10 -5 2\r", b"!cal\r", b"!pause 1000\r!moa 1\r",
                                  b"!delay 1000\r!moa 1\r"])
def test_speed_runs_moves_calibration_and_pauses_faster_in_emulator_time(line: bytes) -> None:
    [(normal, report)] = reply_times(scaled_model_wire(1.0), line, 1)
    [(fast, fast_report)] = reply_times(scaled_model_wire(20.0), line, 1)
    assert fast_report == report and report.endswith(b".")
    assert normal > 1.0  # a real move, not an instant one
    assert fast == pytest.approx(normal / 20, rel=1e-9)


def test_speed_leaves_the_wire_at_its_baud_rate() -> None:
    line = b"!mor 1\r"
    [(normal, report)] = reply_times(scaled_model_wire(1.0, WireConfig()), line, 1)
    [(fast, _)] = reply_times(scaled_model_wire(20.0, WireConfig()), line, 1)
    wire_time = (len(line) + len(report) + 1) * BT  # the line in, the report out
    assert fast - wire_time == pytest.approx((normal - wire_time) / 20, rel=1e-6)
    # A read involves no controller time: byte for byte the same at any speed.
    assert reply_times(scaled_model_wire(20.0, WireConfig()), b"?pos\r", 1) == \
        reply_times(scaled_model_wire(1.0, WireConfig()), b"?pos\r", 1)


def test_speed_scales_the_controllers_own_processing_time() -> None:
    wire = scaled_model_wire(20.0)
    handler = wire.handler
    assert isinstance(handler, ScaledHandler)
    model = handler.handler
    assert isinstance(model, ControllerModel)
    assert handler.processing_time(b"reset") == model.processing_time(b"reset") / 20 > 0


def test_speed_positions_follow_emulator_time() -> None:
    [(done, _)] = reply_times(scaled_model_wire(10.0), b"!moa 20\r", 1)
    wire = scaled_model_wire(10.0)
    [(_, start)] = reply_times(wire, b"!moa 20\r?pos x\r", 1)
    [(_, middle)] = reply_times(wire, b"?pos x\r", 1, at=done / 2)
    [(_, report), (_, end)] = reply_times(wire, b"?pos x\r", 2, at=done)
    assert (start, report, end) == (b"0.0000", b"@@@-.", b"20.0000")
    assert 0.0 < float(middle) < 20.0


@settings(max_examples=300, deadline=None)
@given(origin=st.floats(0, 1e7), speed=st.floats(1e-3, 1e4), ahead=st.floats(0, 1e5))
def test_emulator_clock_deadlines_round_up(origin: float, speed: float, ahead: float) -> None:
    clock = EmulatorClock(speed, origin)
    deadline = origin + ahead
    host = clock.to_host(deadline)
    assert clock.to_emulator(host) >= deadline  # polling then finds the deadline passed
    assert host == pytest.approx(origin + ahead / speed, rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("speed", ["0", "-1", "nan", "inf", "fast"])
def test_a_bad_speed_is_refused(speed: str) -> None:
    with pytest.raises(ValueError, match="speed must be a finite number > 0"):
        speed_from_url(f"sim://?speed={speed}")


async def test_sim_url_speed_reaches_the_emulator() -> None:
    protocol, close = await open_sim("sim://?baud=0&speed=20&profile=legacy", Collector)
    try:
        transport = protocol.made[0]
        assert isinstance(transport, SimTransport)
        handler = transport.wire.handler
        assert isinstance(handler, ScaledHandler) and handler.clock.speed == 20
        transport.write(b"?pos\r")
        assert await protocol.read_until() == b"0.0000 0.0000 0.0000\r"
    finally:
        await close()
    protocol, close = await open_sim("sim://?baud=0", Collector)
    await close()
    assert isinstance(protocol.made[0].get_extra_info("wire").handler, ControllerModel)


# ---------------------------------------------------------------------------- imports


def test_the_readme_imports_work() -> None:
    import tango_aio.sim as package
    from tango_aio.sim import (  # the emulator reference page's promise
        ControllerModel,
        SimConfig,
        Wire,
        WireConfig,
        create_sim_connection,
        model,
        serve,
        serve_tcp,
        wire,
    )

    assert (ControllerModel, SimConfig) == (model.ControllerModel, model.SimConfig)
    assert (Wire, WireConfig) == (wire.Wire, wire.WireConfig)
    assert (create_sim_connection, serve_tcp) == (
        serve.create_sim_connection, serve.serve_tcp)
    assert set(package.__all__) <= set(dir(package))
    with pytest.raises(AttributeError):
        package.no_such_name  # noqa: B018


def test_importing_the_package_loads_none_of_its_modules() -> None:
    code = ("import sys, tango_aio.sim, tango_aio.sim.wire; "
            "print(sorted(m for m in sys.modules if m.startswith('tango_aio.sim.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "['tango_aio.sim.wire']"


# ------------------------------------------------------- one controller for a server's life


async def ask(port: int, *lines: bytes, replies: int | None = None) -> list[bytes]:
    """Connect, send ``lines``, read ``replies`` lines (default one per line), close."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(b"".join(lines))
        count = len(lines) if replies is None else replies
        return [(await reader.readuntil(b"\r"))[:-1] for _ in range(count)]
    finally:
        writer.close()
        await writer.wait_closed()


def model_factory(**config: Any) -> HandlerFactory:
    def make(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, SimConfig(**config))

    return make


async def test_tcp_state_survives_a_reconnect() -> None:
    async with await serve_tcp(model_factory(), config=WireConfig(baud=None),
                               speed=50) as server:
        assert await ask(server.port, b"!cal\r") == [b"AAA-."]
        assert (await ask(server.port, b"?statusaxis\r"))[0].startswith(b"AAA")
        assert await ask(server.port, b"!moa 2 1\r") == [b"@@@-."]
        assert await ask(server.port, b"!vel x 3\r?vel x\r", replies=1) == [b"3.000"]
        assert await ask(server.port, b"?pos\r", b"?vel x\r") == [
            b"2.0000 1.0000 0.0000", b"3.000"]
        assert server.shared is not None
        assert isinstance(server.shared.handler, ScaledHandler)


async def test_tcp_per_connection_starts_each_connection_at_power_on() -> None:
    async with await serve_tcp(model_factory(), config=WireConfig(baud=None),
                               shared=False) as server:
        assert server.shared is None
        assert await ask(server.port, b"!moa 0.1\r") == [b"@@@-."]
        assert await ask(server.port, b"?pos\r") == [b"0.0000 0.0000 0.0000"]


async def test_tcp_a_new_connection_starts_with_an_empty_input_buffer() -> None:
    async with await serve_tcp(model_factory(), config=WireConfig(baud=None)) as server:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(b"!moa 1\r?po")  # a half-sent line, then the client goes away
        assert await reader.readuntil(b"\r") == b"@@@-.\r"
        wire = await server.next_connection()
        assert wire.buffered == 3
        writer.close()
        await writer.wait_closed()
        assert await ask(server.port, b"?pos\r", b"?err\r") == [b"1.0000 0.0000 0.0000", b"0"]


async def test_tcp_a_new_connection_takes_over_from_the_open_one() -> None:
    async with await serve_tcp(model_factory(), config=WireConfig(baud=None)) as server:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(b"!moa 1\r")
        assert await reader.readuntil(b"\r") == b"@@@-.\r"
        assert await ask(server.port, b"?pos\r") == [b"1.0000 0.0000 0.0000"]
        assert await reader.read() == b""  # the first connection was closed
        writer.close()
        await writer.wait_closed()


def test_a_detached_controller_runs_on_and_its_output_is_lost() -> None:
    made: list[ControllerModel] = []

    def make(emit: Emit) -> ControllerModel:
        made.append(ControllerModel(emit, SimConfig(), now=0.0))
        return made[-1]

    shared = SharedController(make)
    first = Wire(lambda emit: shared.attach(emit, 0.0), WireConfig(baud=None))
    first.feed(b"!moa 10\r", 0.0)
    shared.detach(first.emit)
    second = Wire(lambda emit: shared.attach(emit, 100.0), WireConfig(baud=None))
    assert second.handler is first.handler is made[0] and len(made) == 1
    assert second.poll(100.0) == b""  # the move's report went to no one
    assert first.poll(100.0) == b""
    second.feed(b"?pos x\r", 100.0)
    assert second.poll(100.0) == b"10.0000\r"
    shared.detach(first.emit)  # a stale wire does not detach the attached one
    second.feed(b"?pos y\r", 100.0)
    assert second.poll(100.0) == b"0.0000\r"


async def test_tcp_a_factory_that_fails_closes_the_connection_at_once() -> None:
    errors: list[dict[str, Any]] = []
    loop = asyncio.get_running_loop()
    loop.set_exception_handler(lambda _, context: errors.append(context))

    def broken(emit: Emit) -> PingHandler:
        raise RuntimeError("no controller today")

    try:
        async with await serve_tcp(broken, shared=False) as server:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(b"?ping\r")
            with contextlib.suppress(ConnectionResetError):
                assert await reader.read() == b""
            writer.close()
            with contextlib.suppress(ConnectionResetError):
                await writer.wait_closed()
            assert server.wires == []
    finally:
        loop.set_exception_handler(None)
    assert [str(context["exception"]) for context in errors] == ["no controller today"]


# ------------------------------------------------------------- bounded, for days of service


async def settle(server: TcpServer) -> None:
    """Wait until every closed connection's bookkeeping is gone (events, not time)."""
    if server._tasks:  # a connection ends with its task (the server saw the close)
        await asyncio.wait(list(server._tasks))
    await asyncio.sleep(0)  # the tasks' done callbacks
    assert not server._tasks and not server.wires
    gc.collect()


async def churn(server: TcpServer, count: int, line: bytes, reply: bytes) -> None:
    for _ in range(count):
        assert await ask(server.port, line) == [reply]


@pytest.mark.slow
@pytest.mark.parametrize(("factory", "shared"), [(model_factory(), True),
                                                 (PingHandler, False)])
async def test_tcp_memory_stays_flat_over_1000_connections(
        factory: HandlerFactory, shared: bool) -> None:
    line, reply = (b"?pos\r", b"0.0000 0.0000 0.0000") if shared else (b"?ping\r", b"pong")
    async with await serve_tcp(factory, config=WireConfig(baud=None), shared=shared) as server:
        tracemalloc.start()
        try:
            await churn(server, 100, line, reply)  # fills the backlog and every cache
            await settle(server)
            before, tasks = tracemalloc.get_traced_memory()[0], len(asyncio.all_tasks())
            await churn(server, 1000, line, reply)
            await settle(server)
            grown = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        assert len(asyncio.all_tasks()) == tasks
        assert len(server._new) == CONNECTION_BACKLOG
        assert grown < 100_000  # < 100 bytes a connection (it was about 47 kB each)


@pytest.mark.slow
@pytest.mark.timeout(120)
async def test_tcp_memory_stays_flat_over_1000_connections_with_a_model_each() -> None:
    async with await serve_tcp(model_factory(), config=WireConfig(baud=None),
                               shared=False) as server:
        tracemalloc.start()
        try:
            await churn(server, 100, b"?pos\r", b"0.0000 0.0000 0.0000")
            await settle(server)
            before = tracemalloc.get_traced_memory()[0]
            await churn(server, 1000, b"?pos\r", b"0.0000 0.0000 0.0000")
            await settle(server)
            grown = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        assert grown < 100_000


# On the virtual clock the two feeds come at the same instant, as the test means: on the
# real clock a slow machine let the line carry bytes away between them.
@pytest.mark.virtual_clock
async def test_runner_stops_and_resumes_reading_input_beyond_its_limit() -> None:
    calls: list[bool] = []
    resumed = asyncio.Event()
    pending_at_resume: list[int] = []

    def throttle(paused: bool) -> None:
        calls.append(paused)
        if not paused:
            # Read here: by the time the test wakes up, the line has carried more away.
            pending_at_resume.append(runner.wire.rx_pending)
            resumed.set()

    out = bytearray()
    runner = WireRunner(Wire(PingHandler), out.extend, throttle=throttle)
    stream = b"?ping\r" * 700  # 4200 bytes: more than INPUT_QUEUE_LIMIT
    runner.feed(stream[:3000])
    assert calls == []
    runner.feed(stream[3000:])
    assert calls == [True] and runner.input_paused
    task = asyncio.create_task(runner.run())
    await resumed.wait()  # the line carried the excess away at the baud rate
    assert calls == [True, False]
    # At the resume level, or below it by what the line took while the loop woke the
    # runner late (the wire takes bytes at their exact times; under load, a few lines).
    assert 0 < pending_at_resume[0] <= INPUT_QUEUE_RESUME
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


def push(port: int, data: bytes, chunk: int = 65536, held: float = 0.5) -> int:
    """Send ``data`` until done or the server stops taking it for ``held`` s; bytes sent."""
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=held) as sock:
        try:
            while sent < len(data):
                sent += sock.send(data[sent:sent + chunk])
        except TimeoutError:
            pass
    return sent


async def stream_to(server: TcpServer, data: bytes, held: float = 0.5
                    ) -> tuple[Wire, int, int]:
    """:func:`push` ``data`` to ``server``: the connection's wire, the bytes sent and the
    peak of memory allocated meanwhile (tracemalloc). ``held``: how long the server may
    stop taking bytes before the client counts itself held back (short only where the
    server holds it back for good)."""
    tracemalloc.start()
    try:
        task = asyncio.create_task(asyncio.to_thread(push, server.port, data, 65536, held))
        wire = await server.next_connection()
        sent = await task
        return wire, sent, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


async def test_tcp_a_client_streaming_10_mb_is_held_back_not_buffered() -> None:
    garbage = bytes(range(4, 256)) * (10_000_000 // 252)  # no CR, no Ctrl+C
    async with await serve_tcp(PingHandler) as server:
        wire, sent, peak = await stream_to(server, garbage)
        assert sent < len(garbage)  # the client was held back, as by a real port
        assert wire.rx_pending <= INPUT_QUEUE_LIMIT + 4096  # plus one socket read
        assert wire.buffered <= 256
        assert peak < 1_000_000


class Pong(PingHandler):
    """Answers every line with ``pong`` and records nothing (memory tests)."""

    def handle_line(self, line: bytes, now: float) -> None:
        self.emit(b"pong\r")


async def test_tcp_a_client_that_never_reads_is_not_read_from_either() -> None:
    lines = b"\r" * 10**7  # empty lines: the most replies per byte
    async with await serve_tcp(Pong, config=WireConfig(baud=None)) as server:
        wire, sent, peak = await stream_to(server, lines)
    assert sent < len(lines)  # the client was held back
    assert wire.lines_processed < sent
    assert peak < 1_000_000  # replies held: the transport's limit, plus one read's worth


async def test_pty_a_host_writing_faster_than_the_line_is_held_back() -> None:
    async with await serve_pty(PingHandler) as server:
        fd = os.open(server.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            sent, refused = 0, 0
            while refused < 20 and sent < 10_000_000:
                try:
                    sent += os.write(fd, b"x" * 4096)
                    refused = 0
                except BlockingIOError:
                    refused += 1
                await asyncio.sleep(0.005)
        finally:
            os.close(fd)
        assert sent < 1_000_000  # the kernel's pty buffer, then the host waits
        assert server.wire.rx_pending <= INPUT_QUEUE_LIMIT + 4096


@pytest.mark.slow
@pytest.mark.timeout(400)  # 22 s of CPU alone; the slow tier runs 6 workers on 2 cores
async def test_tcp_10_mb_of_garbage_pass_through_in_bounded_memory() -> None:
    garbage = (b"x" * 99 + b"\r") * 100_000
    async with await serve_tcp(model_factory(), config=WireConfig(baud=None)) as server:
        wire, sent, peak = await stream_to(server, garbage, held=30.0)  # it takes them all
        await settle(server)
    assert sent == len(garbage)
    assert wire.lines_processed == 100_000
    assert peak < 2_000_000


# ------------------------------------------------------------------------- state file


def saved_model(path: Path) -> ControllerModel:
    return ControllerModel(lambda data: None, SimConfig(state_file=path), now=0.0)


def valid_state(**changes: Any) -> dict[str, Any]:
    data: dict[str, Any] = {"format": FORMAT, "version": VERSION,
                            "axes": {"vel": [[3.0], [4.0], [5.0], [6.0]]},
                            "global": {"usteps": [40000]}}
    data.update(changes)
    return data


@pytest.mark.parametrize(("text", "reason"), [
    ("[]", "not a JSON object"),
    ('"tango"', "not a JSON object"),
    ('{"foo": 1}', "no 'tango_aio.sim state' marker"),
    ('{"format": "other", "version": 1}', "format 'other'"),
    ('{"format": "tango_aio.sim state", "version": 2}', "unsupported version 2"),
    ('{"axes": []}', "axes: expected an object of parameters"),
    ('{"axes": {"vel": [[1.0]]}}', "axes.vel: expected 4 value groups"),
    ('{"axes": {"vel": [1, 2, 3, 4]}}', "axes.vel[0]: expected a non-empty list"),
    ('{"axes": {"vel": [[], [1], [1], [1]]}}', "axes.vel[0]: expected a non-empty list"),
    ('{"axes": {"nosuch": [[1], [1], [1], [1]]}}', "'nosuch' is not a per-axis parameter"),
    ('{"axes": {"usteps": [[1], [1], [1], [1]]}}', "'usteps' is not a per-axis parameter"),
    ('{"global": {"vel": [1]}}', "'vel' is not a global parameter"),
    ('{"global": {"usteps": ["many"]}}', "global.usteps[0]: expected a number"),
    ('{"global": {"triga": [1]}}', "global.triga[0]: expected a text"),
    ('{"global": {"usteps": [true]}}', "global.usteps[0]: True is not a text or a number"),
    ('{"global": {"usteps": [null]}}', "is not a text or a number"),
    ('{"global": {"usteps": [[1]]}}', "is not a text or a number"),
    ('{"global": {"usteps": 40000}}', "global.usteps: expected a non-empty list"),
    ('{"axes": {}, "global": {}, "extra": 1}', "no 'tango_aio.sim state' marker"),
    ('{"format": "tango_aio.sim state", "version": 1, "extra": 1}', "unknown key(s) ['extra']"),
    ('{"global": {"usteps": [NaN]}}', "NaN is not a valid value"),
    ('{"global": {"usteps": [Infinity]}}', "Infinity is not a valid value"),
    ('{"global": {"usteps": [-Infinity]}}', "-Infinity is not a valid value"),
    ('{"global": {"usteps": [1e999]}}', "1e999 is not a finite number"),
    ('{"global": {"usteps": [-1e999]}}', "-1e999 is not a finite number"),
    ('{"global": {"usteps": [1' + "0" * 400 + ']}}', "is not a finite number"),
    ('{"axes": {"vel": [[1', "not a tango_aio emulator state file"),
    ("\udcff", "not a tango_aio emulator state file"),
])
def test_a_state_file_of_the_wrong_shape_is_refused_with_the_reason(
        tmp_path: Path, text: str, reason: str) -> None:
    path = tmp_path / "state.json"
    path.write_bytes(text.encode("utf-8", "surrogateescape"))
    with pytest.raises(StateFileError) as info:
        saved_model(path)
    assert reason in str(info.value)
    assert str(path) in str(info.value)
    assert path.read_bytes() == text.encode("utf-8", "surrogateescape")


def test_a_large_file_is_not_ours(tmp_path: Path) -> None:
    path = tmp_path / "big.json"
    path.write_bytes(b" " * (MAX_SIZE + 1))
    with pytest.raises(StateFileError, match="not a tango_aio emulator state file"):
        saved_model(path)


def test_a_valid_state_file_loads_and_a_legacy_one_too(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    path.write_text(json.dumps(valid_state()), encoding="utf-8")
    assert saved_model(path).params.axis_values["vel"][:3] == [(3.0,), (4.0,), (5.0,)]
    legacy = valid_state()
    del legacy["format"], legacy["version"]  # written before the marker existed
    path.write_text(json.dumps(legacy), encoding="utf-8")
    model = saved_model(path)
    assert model.params.axis_values["vel"][1] == (4.0,)
    model.save()
    assert json.loads(path.read_text(encoding="utf-8"))["format"] == FORMAT


@pytest.mark.parametrize("content", [b"", b"  \n"])
def test_an_empty_file_counts_as_nothing_saved_and_is_written(
        tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "state.json"
    path.write_bytes(content)
    model = saved_model(path)
    assert model.params.axis_values["vel"][0] == (10.0,)
    model.save()
    data = json.loads(path.read_text(encoding="utf-8"))
    assert (data["format"], data["version"]) == (FORMAT, VERSION)
    assert data["axes"]["vel"][0] == [10.0]


@pytest.mark.parametrize("foreign", [b"my notes\n", b'{"foo": 1}', b"[1, 2]",
                                     b'{"global": {"usteps": [NaN]}}'])
def test_save_never_overwrites_a_file_that_is_not_ours(tmp_path: Path, foreign: bytes) -> None:
    path = tmp_path / "state.json"
    wire = Wire(lambda emit: ControllerModel(emit, SimConfig(state_file=path), now=0.0),
                WireConfig(baud=None))
    wire.feed(b"!vel x 3\rsave\r", 0.0)
    assert wire.poll(0.0) == b"OK...\r"
    path.write_bytes(foreign)  # someone put another file there meanwhile
    wire.feed(b"save\r?err\r", 0.0)
    assert wire.poll(0.0) == b"ERR 73\r73\r"
    assert path.read_bytes() == foreign
    assert list(tmp_path.iterdir()) == [path]


def test_save_refuses_a_value_that_is_not_finite(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    model = saved_model(path)
    model.params.put_axis("vel", 0, (math.inf,))
    with pytest.raises(StateFileError, match="not finite"):
        save_state(path, model.params, ["vel"])
    assert not path.exists()


async def test_tcp_a_bad_state_file_fails_at_start_once(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    path.write_text('{"axes": {"vel": 3}}', encoding="utf-8")
    with pytest.raises(StateFileError, match=r"axes\.vel: expected 4 value groups"):
        await serve_tcp(model_factory(state_file=path))
    with pytest.raises(StateFileError):
        await serve_pty(model_factory(state_file=path))


def test_cli_a_bad_state_file_is_one_line_at_start(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    path.write_text("1e999", encoding="utf-8")
    for extra in ([], ["--per-connection"]):
        result = subprocess.run(
            [sys.executable, "-m", "tango_aio", "sim", "--tcp", "127.0.0.1:0", "--state",
             str(path), *extra], capture_output=True, text=True, timeout=60, check=False)
        assert result.returncode == 1 and result.stdout == ""
        assert result.stderr.splitlines() == [
            f"error: state file {path}: 1e999 is not a finite number"]


# --------------------------------------------------------------------------------- uvloop


def run_under_uvloop(main: Callable[[], Coroutine[Any, Any, None]]) -> None:
    uvloop = pytest.importorskip("uvloop")
    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        runner.run(main())


class OffsetClockLoop(asyncio.SelectorEventLoop):
    """An event loop whose clock is 1000 s behind ``time.monotonic()``."""

    def time(self) -> float:
        return super().time() - 1000.0


def test_the_emulators_clock_starts_from_the_loops_clock() -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        before = loop.time()
        model = ControllerModel(lambda data: None)
        assert before <= model.motion.now <= loop.time()
        model.handle_line(b"!moa 1", loop.time())  # not "time must not go backwards"
        assert model.error == 0
        async with await serve_tcp(model_factory(), shared=False) as server:
            assert await ask(server.port, b"!moa 1\r") == [b"@@@-."]

    with asyncio.Runner(loop_factory=OffsetClockLoop) as runner:
        runner.run(main())
    run_under_uvloop(main)


def test_served_emulators_run_under_uvloop() -> None:
    async def main() -> None:
        async with await serve_tcp(model_factory()) as server:
            assert await ask(server.port, b"!moa 1\r") == [b"@@@-."]
            assert await ask(server.port, b"?pos\r") == [b"1.0000 0.0000 0.0000"]
        async with await serve_tcp(model_factory(), shared=False, speed=20) as server:
            position, report = await ask(server.port, b"!moa 1\r?pos x\r", replies=2)
            assert 0.0 < float(position) < 1.0 and report == b"@@@-."
        async with await serve_pty(model_factory()) as pty:

            def host() -> bytes:
                with serial.Serial(pty.path, 57600, timeout=2) as port:
                    port.write(b"?pos\r")
                    return bytes(port.read_until(b"\r"))

            assert await asyncio.to_thread(host) == b"0.0000 0.0000 0.0000\r"
        transport, protocol = await create_sim_connection(Collector, model_factory())
        transport.write(b"?pos\r")
        assert await protocol.read_until() == b"0.0000 0.0000 0.0000\r"
        transport.close()
        await transport.wait_closed()

    run_under_uvloop(main)


# ---------------------------------------------------------------------------- command line


@pytest.mark.parametrize(("text", "address"), [
    ("127.0.0.1:4001", ("127.0.0.1", 4001)), (":4001", ("127.0.0.1", 4001)),
    ("[::1]:4001", ("::1", 4001)), ("localhost:0", ("localhost", 0)),
    ("0.0.0.0:65535", ("0.0.0.0", 65535)), ("4001", ("127.0.0.1", 4001))])
def test_cli_tcp_addresses(text: str, address: tuple[str, int]) -> None:
    assert _tcp_address(text) == address


@pytest.mark.parametrize(("args", "message"), [
    (["--tcp", "127.0.0.1:99999"], "the port a number 0-65535"),
    (["--tcp", ":abc"], "the port a number 0-65535"),
    (["--tcp", "127.0.0.1:-1"], "the port a number 0-65535"),
    (["--tcp", "::1:4001"], "write an IPv6 address in brackets"),
    (["--tcp", "abc"], "expected [HOST:]PORT"),
    (["--speed", "0"], "--speed '0': expected a finite number > 0"),
    (["--speed", "nan"], "--speed 'nan': expected a finite number > 0"),
    (["--switch", "echo"], "expected NAME=VALUE"),
    (["--switch", "baud=0"], "unknown firmware switch 'baud'"),
    (["--switch", "echo=sideways"], "echo='sideways' is not allowed; allowed: before, after"),
    (["--profile", "newest"], "unknown firmware profile 'newest'; allowed: manual, legacy"),
    (["--per-connection"], "--per-connection needs --tcp"),
])
def test_cli_sim_bad_values_are_one_line_errors(
        args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["sim", *args]) == 2  # usage errors, as argparse's (issue 30 item 7)
    captured = capsys.readouterr()
    out = captured.err
    assert len(out.splitlines()) == 1 and out.startswith("error: ") and message in out
    assert captured.out == ""


def test_cli_sim_options_make_the_emulators_configuration() -> None:
    args = _parser().parse_args(["sim", "--profile", "legacy", "--switch", "echo=after",
                                 "--switch", "line_end=crlf", "--speed", "20", "--axes", "2"])
    url = _sim_url(args)
    sim, _ = configs_from_url(url)
    assert sim.firmware == Firmware.from_options("legacy", echo="after", line_end="crlf")
    assert sim.axes == 2
    assert speed_from_url(url) == 20.0
    defaults = _sim_url(_parser().parse_args(["sim"]))
    assert configs_from_url(defaults)[0].firmware == PROFILES["manual"]
    assert speed_from_url(defaults) == 1.0


@pytest.mark.parametrize(("extra", "position"), [([], b"2.0000"),
                                                 (["--per-connection"], b"0.0000")])
def test_cli_sim_tcp_keeps_one_controller_unless_per_connection(
        extra: list[str], position: bytes) -> None:
    command = [sys.executable, "-m", "tango_aio", "sim", "--tcp", "127.0.0.1:0", "--baud", "0",
               "--axes", "1", "--switch", "line_end=crlf", "--speed", "50", *extra]
    with subprocess.Popen(command, stdout=subprocess.PIPE, text=True) as proc:
        try:
            assert proc.stdout is not None
            url = proc.stdout.readline().strip()
            for lines, reply in ((b"!moa 2\r", b"@---.\r\n"), (b"?pos\r", position + b"\r\n")):
                port = serial.serial_for_url(url, timeout=5)
                try:
                    port.write(lines)
                    assert port.read_until(b"\n") == reply
                finally:
                    port.close()
        finally:
            proc.terminate()
            proc.wait(timeout=10)
