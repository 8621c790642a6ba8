"""A cancelled connect() leaves nothing open: no emulator task, no transport, no serial
port (serial ports are opened exclusively)."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

import pytest
import serial
from helpers import (
    INSTANT,
    FakeTransport,
    make_model,
    opened,
    serve_pty,
    wait_until,
)

from tango_aio.controller._connection import connect
from tango_aio.errors import (
    ConnectionLostError,
    PortBusyError,
)
from tango_aio.link._protocol import TangoProtocol

pytestmark = pytest.mark.timeout(30)


def sim_transport_tasks() -> list[asyncio.Task[Any]]:
    """Emulator tasks of in-process ``sim://`` links that are still running."""
    return [t for t in asyncio.all_tasks()
            if getattr(t.get_coro(), "__qualname__", "") == "SimTransport._serve"
            and not t.done()]



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
        with pytest.raises(PortBusyError, match="busy") as info:
            await connect(server.path)
        assert isinstance(info.value.__cause__, serial.SerialException)


async def test_a_connect_cancelled_before_connection_made_closes_the_serial_port(
        monkeypatch: pytest.MonkeyPatch) -> None:
    hang, reached = asyncio.Event(), asyncio.Event()

    async def never(self: TangoProtocol) -> None:
        reached.set()
        await hang.wait()

    async with await serve_pty(make_model) as server:
        with monkeypatch.context() as patch:
            patch.setattr(TangoProtocol, "wait_connected", never)
            task = asyncio.create_task(opened(server.path))
            await asyncio.wait_for(reached.wait(), 30.0)  # it waits there now
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
        await asyncio.sleep(0.01)
        async with connect(server.path) as tango:  # the exclusive lock was released
            assert tango.connected
