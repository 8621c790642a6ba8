"""The protocol stamps writes and arrivals with the loop's clock, and a line that started
before its request could have been answered fails that request and resyncs (the core's
timing rule, :func:`tango_aio.sansio._linktiming.earliest_reply`). The loop's clock is set by hand
here: the stamps are what the test controls, not the machine's speed."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
from helpers import FakeLink

from tango_aio.catalog._instructions import parse
from tango_aio.errors import ProtocolError
from tango_aio.link._protocol import Submission

LinkFactory = Callable[..., FakeLink]


class _Clock:
    """The loop's ``time()``, moved by the test (from the real time, so that the loop's
    timers keep their meaning)."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.now = loop.time()

    def __call__(self) -> float:
        return self.now


@pytest.fixture
async def clock(monkeypatch: pytest.MonkeyPatch) -> _Clock:
    loop = asyncio.get_running_loop()
    if not isinstance(loop, asyncio.BaseEventLoop):
        pytest.skip("sets the stock loop's clock")
    hand = _Clock(loop)
    monkeypatch.setattr(loop, "time", hand)
    return hand


async def _fails_then_in_step(link: FakeLink, read: Submission, clock: _Clock,
                              answer_after: float) -> None:
    """``read`` fails with the timing's ProtocolError, the stream resyncs as for any
    unfitting line, and a read whose reply comes ``answer_after`` s after its write gets
    it."""
    assert read.reply is not None
    with pytest.raises(ProtocolError, match="started before the request could have been"):
        await read.reply
    await link.wait_written(b"?help ")
    link.answer_marker()
    clock.now += 0.100
    again = link.protocol.submit(parse("?pos x"))
    clock.now += answer_after
    link.feed(b"91.125\r")
    assert again.reply is not None
    assert (await again.reply).lines == ("91.125",)


async def test_noise_read_before_a_read_was_written_fails_it(
        fake_link: LinkFactory, clock: _Clock) -> None:
    link = fake_link()
    link.feed(b"1")  # a stray byte, no CR, while idle
    clock.now += 0.010
    read = link.protocol.submit(parse("?pos x"))
    assert link.sent_lines()[-1] == b"?pos x"
    clock.now += 0.005
    link.feed(b"91.125\r")  # the reply, glued behind the stray byte: '191.125'
    await _fails_then_in_step(link, read, clock, 0.005)


async def test_a_reply_that_starts_after_the_write_is_taken(
        fake_link: LinkFactory, clock: _Clock) -> None:
    link = fake_link()
    read = link.protocol.submit(parse("?pos x"))
    link.feed(b"9")  # same instant as the write: not provably early
    clock.now += 0.001
    link.feed(b"1.125\r")
    assert read.reply is not None
    assert (await read.reply).lines == ("91.125",)


async def test_on_a_paced_wire_a_line_started_while_the_read_passes_fails_it(
        fake_link: LinkFactory, clock: _Clock) -> None:
    link = fake_link()
    link.protocol.wire_paced(0.001)  # 1 ms per byte: '?pos x\r' passes in 7 ms
    read = link.protocol.submit(parse("?pos x"))
    clock.now += 0.003
    link.feed(b"1")  # while the request is still on the wire
    clock.now += 0.010
    link.feed(b"91.125\r")
    # Then a reply in time (7 ms + 1 byte time - the 2 ms margin) is taken.
    await _fails_then_in_step(link, read, clock, 0.0065)
