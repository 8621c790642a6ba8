"""Disconnect detection on every transport (in-process emulator, pty, TCP, a proxy that
resets the connection): pending and later awaits fail fast with the cause kept."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
import struct
from collections.abc import AsyncIterator

import pytest
from helpers import (
    VELS,
    assert_fails_fast,
    done_within_ticks,
    make_model,
    remaining,
    serve_pty,
    start_slow_move,
    wait_lost,
    wire_of,
)

from tango_aio.controller._connection import connect
from tango_aio.controller._controller import Controller
from tango_aio.errors import (
    ConnectionLostError,
)
from tango_aio.events import ConnectionLost
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import Wire

pytestmark = pytest.mark.timeout(30)


@contextlib.asynccontextmanager
async def linked(kind: str) -> AsyncIterator[tuple[Controller, Wire]]:
    """A controller at the real baud rate over ``kind`` (sim, pty, tcp) and its wire."""
    if kind == "sim":
        async with connect("sim://") as tango:
            yield tango, wire_of(tango)
    elif kind == "pty":
        async with await serve_pty(make_model) as pty, connect(pty.path) as tango:
            yield tango, pty.wire
    else:
        async with await serve_tcp(make_model) as tcp, \
                connect(f"socket://127.0.0.1:{tcp.port}") as tango:
            yield tango, tcp.wires[0]


@pytest.mark.parametrize("kind", ["sim", "pty", "tcp"])
async def test_disconnect_in_the_middle_of_a_line_fails_everything_fast(kind: str) -> None:
    async with linked(kind) as (tango, wire):
        await tango.set("vel", **VELS)
        events = tango.events()
        wire.disconnect(mid_reply=True)  # half of the ?vel reply, then the link is gone
        query = asyncio.create_task(tango.query("?vel"))
        await wait_lost(tango)  # the driver noticed the loss
        await done_within_ticks(query)  # ... and failed the query with it
        with pytest.raises(ConnectionLostError) as info:
            await query
        assert info.value.__cause__ is not None
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
        proxy.reset()
        await done_within_ticks(query, move)  # the reset fails them at once
        for task in (query, move):
            with pytest.raises(ConnectionLostError) as info:
                await task
            assert isinstance(info.value.__cause__, ConnectionResetError)
        lost = await remaining(events)
        assert isinstance(lost[-1], ConnectionLost)
        assert isinstance(lost[-1].cause, ConnectionResetError)
        assert lost[-1].cause.errno == errno.ECONNRESET  # a real RST, not a FIN
        await assert_fails_fast(tango.position, ConnectionResetError)
