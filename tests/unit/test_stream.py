"""The one bounded drop-oldest stream (tango_aio.stream) and the subscriptions built on it."""

from __future__ import annotations

import asyncio

import pytest

from tango_aio.events import Subscription
from tango_aio.group._group import GroupSubscription
from tango_aio.stream import BoundedStream, check_maxsize

pytestmark = pytest.mark.timeout(10)


async def drain(stream: BoundedStream[int]) -> list[int]:
    return [item async for item in stream]


async def test_overflow_drops_the_oldest_and_counts() -> None:
    stream: BoundedStream[int] = BoundedStream(3)
    for n in range(10):
        stream.offer(n)
    assert stream.dropped == 7 and stream.pending == 3
    stream.end()
    assert await drain(stream) == [7, 8, 9]


async def test_end_lets_the_consumer_drain_then_stops() -> None:
    stream: BoundedStream[int] = BoundedStream(10)
    stream.offer(1)
    stream.end()
    stream.offer(2)  # ignored once ended
    assert stream.ended
    assert await drain(stream) == [1]
    assert stream.get_nowait() is None


async def test_close_discards_the_buffer() -> None:
    stream: BoundedStream[int] = BoundedStream(10)
    stream.offer(1)
    stream.close()
    assert stream.pending == 0 and await drain(stream) == []


async def test_iteration_waits_for_the_next_item() -> None:
    stream: BoundedStream[int] = BoundedStream(2)
    waiting = asyncio.ensure_future(stream.__anext__())
    await asyncio.sleep(0)
    assert not waiting.done()
    stream.offer(5)
    assert await waiting == 5
    waiting = asyncio.ensure_future(stream.__anext__())
    await asyncio.sleep(0)
    stream.end()
    with pytest.raises(StopAsyncIteration):
        await waiting


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "3", None])
def test_maxsize_must_be_a_positive_integer(bad: object) -> None:
    with pytest.raises(ValueError, match="maxsize"):
        check_maxsize(bad)
    with pytest.raises(ValueError, match="maxsize"):
        BoundedStream(bad)  # type: ignore[arg-type]


def test_both_subscriptions_are_the_one_stream() -> None:
    assert issubclass(Subscription, BoundedStream)
    assert issubclass(GroupSubscription, BoundedStream)


async def test_group_subscription_counts_its_own_and_its_members_losses() -> None:
    from tango_aio.events import EventHub, UnsolicitedLine

    hub = EventHub()
    member = hub.subscribe(maxsize=2)
    merged = GroupSubscription({"a": member}, maxsize=1)
    for n in range(5):
        hub.publish(UnsolicitedLine(str(n), time=0.0))
    assert member.dropped == 3  # the member's buffer overflowed before forwarding ran
    hub.close()
    received = [event async for event in merged]
    assert [item.event.line for item in received] == ["4"]  # type: ignore[union-attr]
    assert merged.dropped == 3 + 1  # the merged buffer held one of the member's two
