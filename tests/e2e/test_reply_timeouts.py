"""Reply timeouts: a controller that stops answering, stalls, drops or delays a reply;
keepalive on an idle link."""

from __future__ import annotations

import asyncio

import pytest
from helpers import (
    FAST,
    TICKS,
    VEL_TEXT,
    VELS,
    EmulatorFactory,
    next_event,
    true_within_ticks,
    wait_until,
)

from tango_aio.errors import (
    ConnectionLostError,
    ControllerTimeoutError,
    RequestAbortedError,
)
from tango_aio.events import ConnectionLost, Reconnected

pytestmark = [pytest.mark.timeout(30), pytest.mark.virtual_clock]


async def test_default_reply_timeout_is_five_seconds(emulator: EmulatorFactory) -> None:
    assert (await emulator()).tango.reply_timeout == 5.0


async def test_a_controller_that_stops_answering_times_out_then_the_link_is_lost(
        emulator: EmulatorFactory) -> None:
    """#14 item 5: a link that stays open but forwards nothing (an adapter that stopped,
    a controller power-cycled behind one). The first request fails with its own timeout,
    its resync marker goes unanswered too, and the link is declared lost: every later
    call fails at once with ConnectionLostError whose cause says why."""
    emu = await emulator()  # the set-up's replies come: the default timeout
    tango = emu.tango
    async with tango.events() as events:
        emu.wire.stall(60.0)
        # Short: this reply and its resync marker's never come.
        with pytest.raises(ControllerTimeoutError, match=r"no reply to '\?vel'"):
            await tango.query("?vel", timeout=0.2)
        lost = await next_event(events, timeout=30.0)
        assert isinstance(lost, ConnectionLost)
        assert isinstance(lost.cause, ConnectionAbortedError)
    assert not tango.connected
    for call in (lambda: tango.query("?vel"), tango.position,
                 lambda: tango.set("vel", x=5)):
        with pytest.raises(ConnectionLostError) as caught:
            await call()
        assert isinstance(caught.value.__cause__, ConnectionAbortedError)


async def test_a_dead_link_reconnects_when_enabled(emulator: EmulatorFactory) -> None:
    # The set-up's and the reconnect's replies come: the default timeout for them.
    emu = await emulator(autostatus=2, **FAST)
    tango = emu.tango
    async with tango.events() as events:
        emu.wire.faults.drop_replies = 1_000_000  # forwards nothing back, stays open
        with pytest.raises(ControllerTimeoutError):
            await tango.query("?vel", timeout=0.2)  # neither it nor its marker answered
        assert isinstance(await next_event(events, timeout=30.0), ConnectionLost)
        assert isinstance(await next_event(events, timeout=30.0), Reconnected)
    assert tango.connected and tango.autostatus == 2
    await tango.set("vel", **VELS)
    assert await tango.query("?vel") == VEL_TEXT


async def test_keepalive_notices_a_dead_idle_link(emulator: EmulatorFactory) -> None:
    emu = await emulator(keepalive=0.05)  # the set-up's replies come: the default timeout
    tango = emu.tango
    tango.protocol.reply_timeout = 0.1  # the keepalive reads' from now on: never answered
    async with tango.events() as events:
        emu.wire.stall(60.0)  # no call of ours: only the keepalive can notice
        lost = await next_event(events, timeout=30.0)
        assert isinstance(lost, ConnectionLost)
    assert not tango.connected


async def test_keepalive_restores_the_mode_after_a_restart_behind_the_adapter(
        emulator: EmulatorFactory) -> None:
    """The controller restarts (power-on mode 1) while the link stays open: the keepalive
    reads a mode other than the one in force and restores it."""
    emu = await emulator(autostatus=2, keepalive=0.02)
    emu.model.reboot()
    await wait_until(lambda: emu.model.autostatus == 2 == emu.tango.autostatus, timeout=30.0)
    await emu.tango.set("vel", **VELS)
    assert await emu.tango.query("?vel") == VEL_TEXT


async def test_a_stalled_controller_answers_again_in_sync(emulator: EmulatorFactory) -> None:
    # A stall, not a dead link: its markers (one per 0.2 s) may all go unanswered.
    emu = await emulator(dead_after=100)
    tango = emu.tango
    await tango.set("vel", **VELS)
    # The stall outlasts the 0.2 s timeout by far more than a loaded machine delays a timer.
    emu.wire.stall(2.0)
    with pytest.raises(ControllerTimeoutError):
        await tango.query("?vel", timeout=0.2)
    assert emu.wire.busy  # the reply timeout ended the wait, not the end of the stall
    await wait_until(lambda: not emu.wire.busy and not emu.wire.tx_pending, timeout=30.0)
    for _ in range(TICKS):  # the late reply reaches the driver
        await asyncio.sleep(0)
    # The late ?vel reply was dropped: it is not taken for the reply to ?pos.
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
    assert await tango.query("?vel") == VEL_TEXT


async def test_a_dropped_reply_times_out_and_the_stream_stays_in_sync(
        emulator: EmulatorFactory) -> None:
    # Its marker shares the 0.2 s: late on a loaded machine, it is written again, and the
    # link is not declared dead.
    emu = await emulator(dead_after=10)
    tango = emu.tango
    await tango.set("vel", **VELS)
    emu.wire.faults.drop_replies = 1
    # The dropped reply is the separator's before '?vel' (the last request of the set-up
    # also answered numbers): '?vel' then fails as the resync aborts it.
    with pytest.raises((ControllerTimeoutError, RequestAbortedError)):
        await tango.query("?vel", timeout=0.2)
    # The resync marker is answered at once: the next request needs no timeout of its own.
    await true_within_ticks(lambda: not tango.protocol.core.resyncing)
    assert emu.wire.dropped_replies == 1
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
    assert await tango.query("?vel") == VEL_TEXT


async def test_a_late_reply_is_dropped(emulator: EmulatorFactory) -> None:
    emu = await emulator(dead_after=100)  # the markers behind the late reply wait with it
    tango = emu.tango
    await tango.set("vel", **VELS)
    emu.wire.faults.delay_replies = 1
    # Late by far more than a loaded machine delays the 0.2 s timer.
    emu.wire.faults.reply_delay = 2.0
    with pytest.raises(ControllerTimeoutError):
        await tango.query("?vel", timeout=0.2)
    # The late reply and the marker's arrive: waited for, not a time (a loaded machine).
    await wait_until(lambda: not emu.wire.rx_pending and not emu.wire.busy
                     and not emu.wire.tx_pending, timeout=30)
    for _ in range(TICKS):  # the replies reach the driver
        await asyncio.sleep(0)
    assert await tango.get("vel", axis="x") == 11.5
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
