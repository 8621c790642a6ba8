"""Tests of the real-time serving layers: pty (with pyserial), TCP and in-process."""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable

import pytest
import serial

from tango_aio.sim.serve import SimTransport, create_sim_connection, serve_pty, serve_tcp
from tango_aio.sim.wire import Wire, WireConfig

from .test_wire import BT, PingHandler

pytestmark = pytest.mark.timeout(10)

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


def read_until_quiet(read: Callable[[], bytes]) -> bytes:
    """Collect bytes from ``read()`` (a blocking call with a timeout) until it returns none."""
    out = b""
    while chunk := read():
        out += chunk
    return out


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

        def host() -> bytes:
            with serial.Serial(server.path, 57600, timeout=0.3) as port:
                port.write(STREAM)
                return read_until_quiet(lambda: port.read(4096))

        replies = await asyncio.to_thread(host)
        wire = server.wire
        assert wire.lost_bytes > 0
        assert_conserved(wire, len(STREAM))
        assert replies == b"pong\r" * handler_of(wire).texts.count(b"?ping")
        assert replies.count(b"pong\r") < 200


async def test_pty_ctrl_c_clears_input() -> None:
    config = WireConfig(processing_time_per_line=0.1)
    async with await serve_pty(PingHandler, config) as server:

        def host() -> tuple[bytes, bytes]:
            with serial.Serial(server.path, 57600, timeout=0.3) as port:
                port.write(b"?ping\r?ping\r?ping\r\x03")
                first = read_until_quiet(lambda: port.read(100))
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
    start = loop.time()
    server.wire.disconnect()
    await server.wait_closed()
    assert await task == b"pong\r"
    assert loop.time() - start < 1.0


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

        def host() -> bytes:
            with socket.create_connection(("127.0.0.1", server.port), timeout=0.3) as sock:
                sock.sendall(STREAM)

                def recv() -> bytes:
                    try:
                        return sock.recv(4096)
                    except TimeoutError:
                        return b""

                return read_until_quiet(recv)

        replies = await asyncio.to_thread(host)
        wire = server.wires[0] if server.wires else await server.next_connection()
    assert wire.lost_bytes > 0
    assert_conserved(wire, len(STREAM))
    assert replies == b"pong\r" * handler_of(wire).texts.count(b"?ping")


async def test_tcp_ctrl_c_clears_input() -> None:
    async with await serve_tcp(PingHandler, config=WireConfig(processing_time_per_line=0.1)) \
            as server:

        def host() -> bytes:
            port = serial.serial_for_url(f"socket://127.0.0.1:{server.port}", timeout=0.3)
            try:
                port.write(b"?ping\r?ping\r?ping\r\x03")
                return read_until_quiet(lambda: port.read(100))
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
