"""Connect on any link (issue 32 item 5): a link lost during connect's first exchange
fails at once with ConnectionLostError, and a cancelled connect releases its port."""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Any

import pytest
import serial
from helpers import make_model, opened, serve_pty

import tango_aio
from tango_aio import ConnectionLostError, Controller
from tango_aio.sim.serve import serve_tcp

pytestmark = pytest.mark.timeout(30)

#: Far longer than the test's own timeout: a connect that waited for it never returns.
NEVER = 3600.0


async def _close_after_first_bytes(reader: asyncio.StreamReader,
                                   writer: asyncio.StreamWriter) -> None:
    await reader.read(1)  # connect's first exchange is under way
    writer.close()


async def test_a_link_lost_in_the_first_exchange_is_connection_lost_at_once() -> None:
    server = await asyncio.start_server(_close_after_first_bytes, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        with pytest.raises(ConnectionLostError):
            await tango_aio.connect(f"socket://127.0.0.1:{port}", reply_timeout=NEVER)
    finally:
        server.close()
        await server.wait_closed()


async def _connect_many(count: int) -> None:
    """``count`` clients connect at once to the shared TCP emulator, which serves one
    connection at a time (a new one takes over): each either connects or fails with
    ConnectionLostError at once, none waits out its reply timeout."""
    async with await serve_tcp(make_model) as server:
        url = f"socket://127.0.0.1:{server.port}"
        results = await asyncio.gather(
            *(tango_aio.connect(url, reply_timeout=NEVER) for _ in range(count)),
            return_exceptions=True)
        for result in results:
            if isinstance(result, Controller):
                await result.aclose()
    unexpected = [r for r in results
                  if not isinstance(r, Controller | ConnectionLostError)]
    assert not unexpected, unexpected
    assert any(isinstance(r, Controller) for r in results)


async def test_clients_connecting_at_once_fail_fast_or_connect() -> None:
    await _connect_many(10)


@pytest.mark.slow
async def test_a_hundred_clients_connecting_at_once_fail_fast_or_connect() -> None:
    await _connect_many(100)


async def test_a_connect_cancelled_while_the_port_opens_has_closed_it_when_it_returns(
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
        assert len(ports) == 1 and not ports[0].is_open  # closed before connect returned


async def _cancel_and_reopen(path: str, ticks: int) -> None:
    """Cancel a connect to ``path`` after ``ticks`` loop iterations (opening, connecting,
    setting up); the port then opens again at once: no "Could not exclusively lock
    port"."""
    task = asyncio.create_task(opened(path))
    for _ in range(ticks):
        await asyncio.sleep(0)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await (await task).aclose()  # it finished before the cancellation came
    async with tango_aio.connect(path) as tango:
        assert tango.connected


@pytest.mark.parametrize("ticks", [0, 1, 2, 3, 5, 8, 13, 21, 34, 55, 89, 144])
async def test_a_cancelled_pty_connect_releases_the_port_before_it_returns(
        ticks: int) -> None:
    async with await serve_pty(make_model) as server:
        await _cancel_and_reopen(server.path, ticks)


@pytest.mark.slow
async def test_sixty_cancelled_pty_connects_in_a_row_each_release_the_port() -> None:
    async with await serve_pty(make_model) as server:
        for attempt in range(60):
            await _cancel_and_reopen(server.path, attempt * 3)
