"""#14 items 8 and 9: the wrong event loop, and memory that stays flat for days
(abandoned subscriptions, wire-log records, multi-line replies)."""

from __future__ import annotations

import asyncio
import gc
import logging
from collections.abc import Callable
from typing import Unpack

import pytest
from helpers import INSTANT, ConnectOptions, FakeLink

from tango_aio import connect
from tango_aio.catalog._instructions import parse
from tango_aio.controller._controller import Controller
from tango_aio.errors import ProtocolError, WrongEventLoopError
from tango_aio.events import EventHub, StatusReport
from tango_aio.link._router import TRACE_LINE
from tango_aio.sansio._core import Mismatched, ProtocolCore

pytestmark = pytest.mark.timeout(30)


async def _connect(url: str, **options: Unpack[ConnectOptions]) -> Controller:
    return await connect(url, **options)


def test_a_controller_used_from_another_event_loop_fails_at_once() -> None:
    with asyncio.Runner() as home:
        tango = home.run(_connect(INSTANT, reply_timeout=30.0))
        try:
            with asyncio.Runner() as other:
                for call in (lambda: tango.query("?vel"), tango.position,
                             lambda: tango.set("vel", x=5), lambda: tango.move_to(x=0.1)):
                    with pytest.raises(WrongEventLoopError, match="another event loop"):
                        # Without the check this waited the 30 s reply timeout.
                        other.run(asyncio.wait_for(call(), 5.0))
            # The home loop still works.
            assert home.run(tango.query("?vel x"))
        finally:
            home.run(tango.aclose())


async def test_abandoned_subscriptions_are_unregistered() -> None:
    hub = EventHub()

    async def first_event() -> None:
        async for _ in hub.subscribe():
            return

    for _ in range(200):
        task = asyncio.create_task(first_event())
        await asyncio.sleep(0)
        hub.publish(StatusReport({"x": "@"}, "@."))
        await task
    gc.collect()
    assert hub.subscribers == 0
    kept = hub.subscribe()
    hub.subscribe()  # dropped at once
    gc.collect()
    assert hub.subscribers == 1
    kept.close()
    assert hub.subscribers == 0


async def test_abandoned_controller_subscriptions_do_not_pile_up() -> None:
    async with connect(INSTANT) as tango:
        for _ in range(50):
            async with asyncio.timeout(2):
                task = asyncio.ensure_future(tango.move_by(x=0.001))
                async for _event in tango.events():
                    break  # abandoned, not closed
                await task
        gc.collect()
        assert tango._hub.subscribers == 0


async def test_wire_log_records_are_capped(fake_link: Callable[..., FakeLink],
                                           caplog: pytest.LogCaptureFixture) -> None:
    link = fake_link()
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    link.feed(b"A" * 100_000 + b"\r")  # over-long: the core drops it, the log cuts it
    link.feed(b"B" * 10_000)  # no CR yet
    sizes = [len(record.getMessage()) for record in caplog.records]
    assert sizes and max(sizes) < TRACE_LINE + 100
    assert "(100000 bytes)" in caplog.records[0].getMessage()


def test_a_multi_line_reply_is_capped_in_lines_and_bytes() -> None:
    for lines, size in ((10, 1 << 20), (1 << 20, 500)):
        core = ProtocolCore(max_reply_lines=lines, max_reply_bytes=size)
        core.send(parse("?service"), "service")
        events = core.events(b"line of the service print\r" * 40)
        mismatched = [e for e in events if isinstance(e, Mismatched)]
        assert len(mismatched) == 1 and "exceeds" in mismatched[0].reason
        assert mismatched[0].tag == "service"
        # Everything after is dropped until the resync.
        assert all(type(e).__name__ == "Dropped" for e in events[1:])


async def test_an_endless_reply_fails_its_request_typed(fake_link: Callable[..., FakeLink]) -> None:
    link = fake_link()
    link.protocol.core._max_reply = (20, 1 << 20)
    task = asyncio.create_task(link.protocol.request(parse("?service"), timeout=2.0))
    await link.wait_written(b"?service\r")
    link.feed(b"more\r" * 30)
    with pytest.raises(ProtocolError, match="exceeds 20 lines"):
        await task
    link.answer_marker()
    assert not link.protocol.core.resyncing
