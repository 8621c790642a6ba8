"""Automatic reconnect: backoff, restoring the mode, giving up, another firmware
answering, aclose while reconnecting."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any

import pytest
from helpers import (
    FAST,
    VEL_TEXT,
    VELS,
    EmulatorFactory,
    assert_fails_fast,
    make_model,
    next_event,
    remaining,
    serve_pty,
    start_slow_move,
    wait_until,
)

from tango_aio.controller._connection import connect
from tango_aio.errors import (
    ConnectError,
    ConnectionLostError,
)
from tango_aio.events import ConnectionLost, Reconnected
from tango_aio.link._reconnect import IdentityMismatchError, ReconnectPolicy
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import Emit, WireConfig

pytestmark = pytest.mark.timeout(30)


def make_other_firmware(emit: Emit) -> ControllerModel:
    """The same model with another firmware: not the controller the driver knew."""
    return ControllerModel(emit, SimConfig(version="1.69"))



def test_backoff_doubles_up_to_the_maximum() -> None:
    policy = ReconnectPolicy(initial=0.1, maximum=1.0, attempts=7)
    assert list(policy.delays()) == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0])
    endless = ReconnectPolicy(initial=2.0, maximum=5.0).delays()
    assert [next(endless) for _ in range(100)][-3:] == [5.0, 5.0, 5.0]


@pytest.mark.parametrize("options", [
    {"reconnect_initial": 0}, {"reconnect_initial": float("nan")},
    {"reconnect_initial": 1.0, "reconnect_max": 0.5}, {"reconnect_attempts": 0}])
async def test_bad_reconnect_options_are_refused_before_opening(options: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="reconnect"):
        await connect("/dev/nonexistent-tango", reconnect=True, **options)


async def test_sim_reconnects_and_restores_the_autostatus_mode(
        emulator: EmulatorFactory) -> None:
    emu = await emulator(autostatus=4, reconnect=True, reconnect_initial=0.01)
    tango = emu.tango
    first = tango.protocol
    async with tango.events() as events:
        emu.wire.disconnect()
        assert isinstance(await next_event(events), ConnectionLost)
        reconnected = await next_event(events)
        assert isinstance(reconnected, Reconnected) and reconnected.attempt == 1
    assert tango.connected and tango.protocol is not first
    assert emu.model.autostatus == 4 == tango.autostatus  # a fresh emulator: re-applied
    await tango.set("vel", **VELS)
    assert await tango.query("?vel") == VEL_TEXT
    await tango.wait_connected(timeout=0)


@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_a_move_in_flight_fails_even_when_the_link_is_back_at_once(
        emulator: EmulatorFactory, mode: int) -> None:
    emu = await emulator(autostatus=mode, reconnect=True, reconnect_initial=0.001)
    tango = emu.tango
    async with tango.events() as events:
        for _ in range(3):  # the loss may fall between two statusaxis polls (mode 0)
            move = await start_slow_move(tango, x=40)
            await asyncio.sleep(0.01)
            emu.wire.disconnect()
            with pytest.raises(ConnectionLostError):
                await asyncio.wait_for(move, 30)  # a bound, not a speed
            assert isinstance(await next_event(events), ConnectionLost)
            assert isinstance(await next_event(events), Reconnected)
            assert tango.autostatus == mode


async def test_tcp_server_restart_on_the_same_port_reconnects() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", autostatus=2, **FAST)
    try:
        events = tango.events()
        identity = tango.identity
        move = await start_slow_move(tango, x=40)
        server.close()
        await server.wait_closed()
        with pytest.raises(ConnectionLostError) as info:  # reported, never retried
            await asyncio.wait_for(move, 30)  # a bound, not a speed
        assert info.value.__cause__ is not None
        assert isinstance(await next_event(events), ConnectionLost)
        assert tango.reconnecting and not tango.connected
        await assert_fails_fast(tango.position)  # no waiting while the link is down
        # Attempts (at ~0.05, 0.15 and 0.35 s) are refused: waited for, not timed.
        await wait_until(lambda: tango.reconnect_attempt >= 3, timeout=30)
        server = await serve_tcp(make_model, port=port)
        await tango.wait_connected(timeout=30.0)
        reconnected = await next_event(events)
        assert isinstance(reconnected, Reconnected)
        assert reconnected.attempt == tango.reconnect_attempt >= 4
        assert tango.identity == identity
        handler = server.wires[0].handler
        assert isinstance(handler, ControllerModel)
        assert handler.autostatus == 2 == tango.autostatus
        # The interrupted move was not sent again to the (fresh) controller.
        assert await tango.status() == {"x": "@", "y": "@", "z": "@"}
        assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}
        await tango.set("vel", **VELS)
        assert await tango.query("?vel") == VEL_TEXT
        assert events.get_nowait() is None
    finally:
        await tango.aclose()
        server.close()
        await server.wait_closed()
    assert not tango.reconnecting
    assert all(not isinstance(e, Reconnected) for e in await remaining(events))


async def test_another_firmware_answering_stops_reconnecting() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", **FAST)
    other = None
    try:
        events = tango.events()
        server.close()
        await server.wait_closed()
        assert isinstance(await next_event(events), ConnectionLost)
        other = await serve_tcp(make_other_firmware, port=port)
        with pytest.raises(ConnectionLostError) as info:
            await tango.wait_connected(timeout=30.0)
        assert isinstance(info.value.__cause__, IdentityMismatchError)
        assert "1.69" in str(info.value.__cause__)
        assert not tango.reconnecting
        assert await remaining(events) == []  # ended, no Reconnected
        await assert_fails_fast(tango.position, IdentityMismatchError)
        await wait_until(lambda: other is not None and not other.wires)  # link closed
    finally:
        await tango.aclose()
        if other is not None:
            other.close()
            await other.wait_closed()


async def test_reconnect_gives_up_after_the_attempts() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", reconnect=True,
                          reconnect_initial=0.02, reconnect_max=0.05, reconnect_attempts=3)
    try:
        events = tango.events()
        server.close()
        await server.wait_closed()
        assert isinstance(await next_event(events), ConnectionLost)
        with pytest.raises(ConnectionLostError) as info:
            await tango.wait_connected(timeout=30.0)  # the attempts run out first
        assert tango.reconnect_attempt == 3 and not tango.reconnecting
        assert isinstance(info.value.__cause__, ConnectError)  # cannot connect
        assert isinstance(info.value.__cause__.__cause__, OSError)
        assert await remaining(events) == []
    finally:
        await tango.aclose()


async def test_unplugged_serial_port_backs_off_until_aclose(
        caplog: pytest.LogCaptureFixture, tmp_path: Path) -> None:
    caplog.set_level(logging.WARNING, logger="tango_aio")
    server = await serve_pty(make_model)
    # Through a link of its own, as /dev/serial/by-id/... names an adapter: once removed
    # it stays absent, whereas the pty's own number is soon reused by another test.
    port = tmp_path / "usb-adapter"
    port.symlink_to(server.path)
    tango = await connect(str(port), **FAST)
    try:
        events = tango.events()
        server.close()  # the pty disappears: like a USB adapter pulled out
        await server.wait_closed()
        port.unlink()
        assert isinstance(await next_event(events), ConnectionLost)
        await wait_until(lambda: tango.reconnect_attempt >= 4, timeout=30.0)
        assert tango.reconnecting
    finally:
        await tango.aclose()
    records = [r for r in caplog.records if "reconnect attempt" in r.getMessage()]
    numbers = [int(r.getMessage().split()[2]) for r in records]
    # One attempt after the other, backing off (the schedule itself: test_backoff_*).
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) >= 3
    assert not tango.reconnecting
    await asyncio.sleep(0.3)
    assert len([r for r in caplog.records if "reconnect attempt" in r.getMessage()]) == len(
        records)  # aclose stopped it
    assert await remaining(events) == []
    with pytest.raises(ConnectionLostError):
        await tango.wait_connected(timeout=1.0)


async def test_aclose_while_reconnecting_closes_the_half_set_up_link() -> None:
    server = await serve_tcp(make_model)
    port = server.port
    tango = await connect(f"socket://127.0.0.1:{port}", **FAST)
    server.close()
    await server.wait_closed()
    # The new controller takes 10 s per line: the reconnect's set-up hangs in its resync.
    slow = await serve_tcp(make_model, port=port, config=WireConfig(
        baud=None, processing_time_per_line=10.0))
    try:
        await asyncio.wait_for(slow.next_connection(), 30.0)
        assert tango.reconnecting and not tango.connected
        await assert_fails_fast(tango.position)  # not routed to the half-set-up link
        with pytest.raises(TimeoutError):
            await tango.wait_connected(timeout=0.05)
        await tango.aclose()
        assert not tango.reconnecting
        await wait_until(lambda: not slow.wires)
    finally:
        slow.close()
        await slow.wait_closed()


async def test_wait_connected_without_reconnect(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    await emu.tango.wait_connected(timeout=0)
    assert emu.tango.connected and not emu.tango.reconnecting
    events = emu.tango.events()
    emu.wire.disconnect()
    assert [type(e) for e in await remaining(events)] == [ConnectionLost]
    with pytest.raises(ConnectionLostError) as info:
        await emu.tango.wait_connected(timeout=1.0)
    assert isinstance(info.value.__cause__, ConnectionResetError)
