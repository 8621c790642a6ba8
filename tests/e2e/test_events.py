"""Events: the :class:`EventHub` on its own, and :meth:`Controller.events` end to end."""

from __future__ import annotations

import asyncio

import pytest
from helpers import EmulatorFactory, wait_until

from tango_aio.errors import MoveError
from tango_aio.events import (
    ConnectionLost,
    EventHub,
    MoveAborted,
    MoveFinished,
    PositionUpdate,
    StatusReport,
    Subscription,
    TangoEvent,
    UnsolicitedLine,
)

pytestmark = [pytest.mark.timeout(30), pytest.mark.virtual_clock]


def line(text: str) -> UnsolicitedLine:
    return UnsolicitedLine(text, time=0.0)


async def collect(subscription: Subscription) -> list[TangoEvent]:
    """Every event until the iteration ends."""
    return [event async for event in subscription]


def buffered(subscription: Subscription) -> list[TangoEvent]:
    """Every event buffered right now, without waiting."""
    out: list[TangoEvent] = []
    while (event := subscription.get_nowait()) is not None:
        out.append(event)
    return out


# --------------------------------------------------------------------------------------
# EventHub


async def test_every_subscriber_sees_every_event_in_order() -> None:
    hub = EventHub()
    first, second = hub.subscribe(), hub.subscribe()
    events = [line(str(n)) for n in range(5)]
    for event in events:
        hub.publish(event)
    hub.close()
    assert await collect(first) == events
    assert await collect(second) == events


async def test_a_subscriber_sees_only_events_after_it_subscribed() -> None:
    hub = EventHub()
    hub.publish(line("before"))
    subscription = hub.subscribe()
    hub.publish(line("after"))
    hub.close()
    assert await collect(subscription) == [line("after")]


async def test_full_buffer_drops_the_oldest_and_counts() -> None:
    hub = EventHub()
    slow, fast = hub.subscribe(maxsize=3), hub.subscribe(maxsize=100)
    for n in range(10):
        hub.publish(line(str(n)))
    assert slow.dropped == 7 and fast.dropped == 0
    assert slow.pending == 3
    assert buffered(slow) == [line("7"), line("8"), line("9")]
    assert len(buffered(fast)) == 10


async def test_iteration_waits_for_events_and_ends_on_close() -> None:
    hub = EventHub()
    subscription = hub.subscribe()
    reader = asyncio.create_task(collect(subscription))
    await asyncio.sleep(0.01)
    assert not reader.done()
    hub.publish(line("a"))
    await asyncio.sleep(0)
    hub.publish(line("b"))
    hub.close()
    assert await asyncio.wait_for(reader, 10.0) == [line("a"), line("b")]


async def test_closed_subscription_ends_and_receives_nothing() -> None:
    hub = EventHub()
    async with hub.subscribe() as subscription:
        hub.publish(line("kept?"))
    hub.publish(line("after close"))
    assert await collect(subscription) == []
    late = hub.subscribe()
    hub.close()
    after_close = hub.subscribe()
    assert await collect(late) == [] and await collect(after_close) == []


def test_maxsize_must_be_positive() -> None:
    with pytest.raises(ValueError, match="maxsize"):
        EventHub().subscribe(maxsize=0)


# --------------------------------------------------------------------------------------
# Controller events


@pytest.mark.parametrize("mode", [1, 2, 4])
async def test_subscribers_get_move_finished_with_letters(emulator: EmulatorFactory,
                                                          mode: int) -> None:
    emu = await emulator(autostatus=mode, travel=10.0)
    await emu.make_fast()
    first, second = emu.tango.events(), emu.tango.events()
    await emu.tango.move_to(x=1)
    await emu.tango.calibrate("y")
    await emu.tango.measure_range("y")
    with pytest.raises(MoveError):
        await emu.tango.move_to(z=-6)  # into the E0 switch at -5 mm
    expected = [
        ("move", {"x": "@", "y": "@", "z": "@"}, True),
        ("cal", {"x": "@", "y": "A", "z": "@"}, True),
        ("rm", {"x": "@", "y": "D", "z": "@"}, True),
        ("move", {"x": "@", "y": "@", "z": "S"}, False),
    ]
    for subscription in (first, second):
        got = [(e.kind, dict(e.statuses), e.ok) for e in buffered(subscription)
               if isinstance(e, MoveFinished)]
        assert got == expected
        await subscription.aclose()


async def test_mode3_move_finished_has_the_confirmed_letters(emulator: EmulatorFactory
                                                             ) -> None:
    # The bare CR of autostatus 3 carries no letters; the move is confirmed with
    # ?statusaxis (tango_aio.controller._motion), whose letters MoveFinished carries.
    emu = await emulator(autostatus=3)
    async with emu.tango.events() as events:
        await emu.tango.move_to(x=0.01)
        finished = [e for e in buffered(events) if isinstance(e, MoveFinished)]
    assert [(e.kind, dict(e.statuses), e.ok) for e in finished] == [
        ("move", {"x": "@", "y": "@", "z": "@"}, True)]


async def test_unsolicited_lines_and_status_reports(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    async with emu.tango.events() as events:
        emu.wire.emit(b"hello\r")
        unsolicited = await asyncio.wait_for(anext(events), 10.0)
        assert isinstance(unsolicited, UnsolicitedLine) and unsolicited.line == "hello"
        await emu.tango.command("!joy 1")
        await emu.tango.command("!joy 0")  # disabling the joystick reports @@@-.
        report = await asyncio.wait_for(anext(events), 10.0)
    assert isinstance(report, StatusReport)
    assert dict(report.statuses) == {"x": "@", "y": "@", "z": "@"}
    assert report.line == "@@@-."


async def test_slow_subscriber_drops_the_oldest_moves(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    await emu.make_fast()
    async with emu.tango.events(maxsize=2) as events:
        for target in (0.1, 0.2, 0.3, 0.4):
            await emu.tango.move_to(x=target)
        assert events.dropped == 2
        assert [type(e) for e in buffered(events)] == [MoveFinished, MoveFinished]


async def test_abort_publishes_move_aborted(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    async with emu.tango.events() as events:
        move = asyncio.create_task(emu.tango.move_to(x=40))
        await wait_until(lambda: emu.model.motion.is_moving("x"), timeout=30.0)  # under way
        await emu.tango.abort()
        with pytest.raises(MoveError):
            await move
        got = buffered(events)
    aborted = [e for e in got if isinstance(e, MoveAborted)]
    finished = [e for e in got if isinstance(e, MoveFinished)]
    assert len(aborted) == 1 and aborted[0].ctrl_c
    assert len(finished) == 1 and finished[0].statuses["x"] == "E" and not finished[0].ok


async def test_connection_loss_ends_every_subscription(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    readers = [asyncio.create_task(collect(emu.tango.events())) for _ in range(2)]
    await asyncio.sleep(0.01)
    emu.wire.disconnect()
    for reader in readers:
        events = await asyncio.wait_for(reader, 10.0)
        assert isinstance(events[-1], ConnectionLost)
        assert isinstance(events[-1].cause, ConnectionResetError)
    assert await collect(emu.tango.events()) == []  # a late subscriber ends at once


async def test_watch_position_follows_a_move_and_stops_when_idle(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()
    events = emu.tango.events()
    move = asyncio.create_task(emu.tango.move_to(x=3))
    await wait_until(lambda: emu.model.motion.is_moving("x"), timeout=30.0)  # under way
    updates = [update async for update in emu.tango.watch_position(interval=0.02)]
    assert not move.done() or move.result()
    xs = [update.positions["x"] for update in updates]
    assert xs == sorted(xs) and xs[-1] == 3.0  # the last update comes once idle
    assert len([x for x in xs if 0.0 < x < 3.0]) >= 2  # updates came while moving
    await move
    published = [e for e in buffered(events) if isinstance(e, PositionUpdate)]
    assert published == updates
    await events.aclose()
