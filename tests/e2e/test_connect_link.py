"""Connect on any link (issue 32 item 5): a link lost during connect's first exchange
fails at once with ConnectionLostError, and a cancelled connect releases its port."""

from __future__ import annotations

import asyncio

import pytest
from helpers import make_model

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
