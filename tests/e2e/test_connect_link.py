"""Connect on any link (issue 32 item 5): a link lost during connect's first exchange
fails at once with ConnectionLostError, and a cancelled connect releases its port."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import random
import threading
from typing import Any

import pytest
import serial
from helpers import make_model, opened, serve_pty

import tango_aio
from tango_aio import ConnectionLostError, Controller
from tango_aio.sansio._session import LinkSession
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import WireConfig

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
    entered, release = threading.Event(), threading.Event()

    def slow_open(*args: Any, **kwargs: Any) -> Any:
        entered.set()  # runs in the opening thread
        assert release.wait(30.0)
        ports.append(real(*args, **kwargs))
        return ports[-1]

    async with await serve_pty(make_model) as server:
        monkeypatch.setattr(serial, "serial_for_url", slow_open)
        task = asyncio.create_task(opened(server.path))
        assert await asyncio.to_thread(entered.wait, 30.0)  # the port is being opened
        task.cancel()
        release.set()  # the open ends after the cancellation
        with pytest.raises(asyncio.CancelledError):
            await task
        assert len(ports) == 1 and not ports[0].is_open  # closed before connect returned
        monkeypatch.setattr(serial, "serial_for_url", real)
        async with tango_aio.connect(server.path) as tango:  # the lock was released
            assert tango.connected


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


# -- a controller still busy with an earlier program's queries

#: Queries of every reply shape connect reads, as an earlier program may have left them.
EARLIER = b"".join(line + b"\r" for line in [
    b"?version", b"?det", b"?autostatus", b"?pos", b"?vel", b"?err", b"help", b"?help 5",
    b"?dim", b"?pitch", b"?accel", b"?secvel", b"?delay", b"?pause", b"?ctrt"] * 3)


async def _connect_and_check(path: str) -> None:
    async with tango_aio.connect(path, autostatus=2) as tango:
        assert tango.identity.model == "TANGO-DT" and tango.identity.axes == 3
        assert await tango.get("autostatus") == 2
        assert set(await tango.position()) == {"x", "y", "z"}
        assert (await tango.get("vel"))["x"] == 10.0


@pytest.mark.parametrize("baud", [4800, 57600])
async def test_connect_comes_into_step_behind_an_earlier_programs_queries(
        baud: int) -> None:
    """An earlier program wrote its queries and went away; the controller still answers
    them, slowly, to whoever opens the port next."""
    async with await serve_pty(make_model, WireConfig(baud=baud)) as server:
        port = serial.Serial(server.path, timeout=0)
        port.write(EARLIER)
        port.close()
        await _connect_and_check(server.path)


@pytest.mark.parametrize("ticks", [5, 20, 60])
async def test_connect_comes_into_step_behind_its_own_abandoned_attempt(ticks: int) -> None:
    """A first attempt is cancelled while its exchanges are answered (at 4800 Bd); the
    next one, started at once, reads none of its replies."""
    async with await serve_pty(make_model, WireConfig(baud=4800)) as server:
        first = asyncio.create_task(opened(server.path, autostatus=4))
        for _ in range(ticks):
            await asyncio.sleep(0)
        first.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await (await first).aclose()
        await _connect_and_check(server.path)


@pytest.mark.parametrize("lacks", ["ctrt", "pause", "extmode", "delay,pause,ctrt"])
@pytest.mark.parametrize("profile", ["manual", "legacy"])
async def test_a_unit_lacking_a_setting_connects_at_once_and_times_moves_without_it(
        lacks: str, profile: str) -> None:
    """A read the unit does not know is answered by nothing (error 4): connect does not
    wait a reply timeout for it (NEVER), and the setting counts as absent (0)."""
    url = f"sim://?baud=0&profile={profile}&lacks={lacks}"
    async with tango_aio.connect(url, reply_timeout=NEVER, autostatus=2) as tango:
        timing = tango._settings
        for name in lacks.split(","):
            field = {"delay": "delay_ms", "pause": "pause_ms", "ctrt": "settle_ms"}.get(
                name, name)
            assert getattr(timing, field) == 0, name
        await tango.move_to(x=0.2)
        assert (await tango.position())["x"] == pytest.approx(0.2)


async def test_a_connect_right_after_one_abandoned_in_its_first_exchange_is_in_step(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The first attempt is cancelled right after it wrote detect's step 0, whose replies
    are still on their way (4800 Bd); every session starts with the same marker number
    here, so the next attempt's step 0 would take those replies for its own and hand its
    own late ones to the next requests (``not a version reply: '1'``, seen once in 60
    cancelled connects) unless it uses another number."""
    monkeypatch.setattr(random, "randrange", lambda n: 0)  # the core's first number
    started = asyncio.Event()
    real = LinkSession.begin_detect

    def spy(self: LinkSession, recent: collections.deque[int] | None = None) -> int:
        started.set()  # step 0's lines are written next
        return real(self, recent)

    monkeypatch.setattr(LinkSession, "begin_detect", spy)
    async with await serve_pty(make_model, WireConfig(baud=4800)) as server:
        first = asyncio.create_task(opened(server.path))
        await started.wait()
        for _ in range(3):
            await asyncio.sleep(0)  # its lines are written
        first.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await (await first).aclose()
        await _connect_and_check(server.path)
