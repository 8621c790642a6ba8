"""Tier 3: the whole driver against the emulator.

``connect("sim://...")`` runs the emulator in-process; the pty and TCP tests open it the
way a real controller is opened (a serial device path, ``socket://host:port``).
``sim://?baud=0`` (instant mode: no line pacing) is used wherever timing does not matter;
motion always runs in real time, so the stage is made fast first.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from helpers import (
    INSTANT,
    VEL_TEXT,
    VELS,
    Emulated,
    EmulatorFactory,
    as_axes,
    assert_fails_fast,
    done_within_ticks,
    make_model,
    serve_pty,
    start_slow_move,
    wait_lost,
    wait_until,
)

from tango_aio.controller._connection import connect
from tango_aio.controller._controller import Controller
from tango_aio.errors import (
    ConnectionLostError,
    InvalidCommandError,
    MoveError,
    NotExecutableError,
    OutOfRangeError,
    RequestAbortedError,
)
from tango_aio.sim.model import ControllerModel
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import Wire
from tango_aio.transports._fdlink import FdTransport

pytestmark = [pytest.mark.timeout(60), pytest.mark.virtual_clock]

#: Travel between the limit switches of the shortened emulated axes (mm).
TRAVEL = 10.0


# --------------------------------------------------------------------------------------
# Identity and typed access


async def test_identify_position_status_get_set(emulator: EmulatorFactory) -> None:
    emu = await emulator("sim://?baud=0&axes=2&model=TANGO-DTe&firmware=1.69")
    tango = emu.tango
    identity = await tango.identify()
    assert (identity.model, identity.firmware, identity.axes) == ("TANGO-DTe", "1.69", 2)
    assert tango.identity == identity
    assert await tango.position() == {"x": 0.0, "y": 0.0}
    assert await tango.status() == {"x": "@", "y": "@"}
    assert await tango.get("vel") == {"x": 10.0, "y": 10.0}
    await tango.set("vel", x=10, y=5)
    assert await tango.get("vel") == {"x": 10.0, "y": 5.0}
    assert await tango.get("vel", axis="y") == 5.0
    await tango.set("vel", 3, axis="y")
    assert await tango.query("?vel") == "10.000 3.000"


async def test_connect_as_context_manager() -> None:
    async with connect(INSTANT) as tango:
        assert tango.identity is not None and tango.identity.axes == 3
        assert await tango.query("?err") == "0"
    with pytest.raises(ConnectionLostError):
        await tango.position()


# --------------------------------------------------------------------------------------
# Every autostatus mode


# Mode 0 polls (6-7 s here): under ``slow``.
@pytest.mark.parametrize("mode", [pytest.param(0, marks=pytest.mark.slow), 1, 2, 3, 4])
async def test_every_autostatus_mode_moves_cal_rm(emulator: EmulatorFactory, mode: int) -> None:
    emu = await emulator(autostatus=mode, travel=TRAVEL)
    tango = emu.tango
    assert tango.autostatus == mode and emu.model.autostatus == mode
    await emu.make_fast()
    assert set((await tango.move_to(x=1, y=2, z=-3)).values()) == {"@"}
    assert await tango.position() == {"x": 1.0, "y": 2.0, "z": -3.0}
    assert set((await tango.move_by(y=0.5)).values()) <= {"@"}
    assert await tango.position() == {"x": 1.0, "y": 2.5, "z": -3.0}
    assert await tango.calibrate() == {"x": "A", "y": "A", "z": "A"}
    assert await tango.measure_range() == {"x": "D", "y": "D", "z": "D"}
    letters = await tango.move_to_center()
    assert not set(letters.values()) & set("EST")
    assert await tango.status() == {"x": "@", "y": "@", "z": "@"}
    assert (await tango.calibrate("y"))["y"] == "A"
    assert await tango.query("?err") == "0"
    assert tango.protocol.core.awaiting_completion == []


async def test_switching_autostatus_mid_session(emulator: EmulatorFactory) -> None:
    emu = await emulator(travel=TRAVEL)
    tango = emu.tango
    await emu.make_fast()
    for step, mode in enumerate([3, 0, 2, 4, 1]):
        await tango.command(f"!autostatus {mode}")
        assert emu.model.autostatus == mode and tango.autostatus == mode
        assert (await tango.calibrate("x"))["x"] == "A"
        assert (await tango.measure_range("y"))["y"] == "D"
        await tango.move_to(x=step + 1.0)
        assert (await tango.position())["x"] == step + 1.0
        await tango.set("vel", **VELS)
        assert await tango.query("?vel") == VEL_TEXT
        await tango.set("vel", x=100, y=100, z=100)
    assert tango.protocol.core.pending_tags == []


# --------------------------------------------------------------------------------------
# Errors


@pytest.mark.parametrize("mode", [1, 2, 4])
async def test_bad_set_raises_typed_controller_error(emulator: EmulatorFactory,
                                                     mode: int) -> None:
    tango = (await emulator(autostatus=mode)).tango
    with pytest.raises(OutOfRangeError) as info:
        await tango.set("lim", 10, 5, axis="x")
    assert info.value.number == 5 and info.value.command == "!lim x 10 5"
    await tango.set("vel", **VELS)  # the stream is still in step
    assert await tango.query("?vel") == VEL_TEXT


async def test_invalid_input_is_refused_before_sending(emulator: EmulatorFactory,
                                                       caplog: pytest.LogCaptureFixture) -> None:
    tango = (await emulator()).tango
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        with pytest.raises(InvalidCommandError):
            await tango.set("vel", x=500)
        with pytest.raises(InvalidCommandError):
            await tango.move_to(a=1.0)  # a 3-axis controller has no A axis
        with pytest.raises(InvalidCommandError):
            await tango.move_to(x=1.0, y=1.0, z=1.0, a=1.0)
        with pytest.raises(InvalidCommandError):
            await tango.calibrate("a")
        with pytest.raises(InvalidCommandError):
            await tango.get("vel", axis="a")
        with pytest.raises(InvalidCommandError):
            await tango.set("vel", x=1, y=1, z=1, a=1)
    assert not [r for r in caplog.records if r.name == "tango_aio.wire"]


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_move_beyond_soft_limits_raises_without_hanging(emulator: EmulatorFactory,
                                                              mode: int) -> None:
    tango = (await emulator(autostatus=mode)).tango
    await tango.set("lim", -5, 5, axis="x")
    async with asyncio.timeout(30.0):  # a bound on a hang only
        with pytest.raises(OutOfRangeError) as info:
            await tango.move_to(x=10)
    assert info.value.command == "!moa 10"
    assert tango.protocol.core.awaiting_completion == []
    await tango.move_to(x=0.01)
    assert (await tango.position())["x"] == 0.01


@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_move_into_limit_switch_raises_move_error_s(emulator: EmulatorFactory,
                                                          mode: int) -> None:
    emu = await emulator(autostatus=mode, travel=TRAVEL)
    await emu.make_fast()
    with pytest.raises(MoveError) as info:
        await emu.tango.move_to(x=-TRAVEL)  # E0 is at -TRAVEL/2
    assert info.value.statuses["x"] == "S"


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_soft_abort_raises_move_error_e(emulator: EmulatorFactory, mode: int) -> None:
    tango = (await emulator(autostatus=mode)).tango
    move = await start_slow_move(tango, x=40)
    await tango.abort(soft=True)
    with pytest.raises(MoveError) as info:
        await move
    assert info.value.statuses["x"] == "E"
    assert "M" not in (await tango.status()).values()


# --------------------------------------------------------------------------------------
# Ctrl+C


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_ctrl_c_abort_with_queued_queries(emulator: EmulatorFactory, mode: int) -> None:
    # Paced link and a slow interpreter, so the queries really are queued in the
    # controller's input buffer when Ctrl+C arrives.
    emu = await emulator("sim://?processing=0.004", autostatus=mode)
    tango = emu.tango
    await tango.set("vel", **VELS)
    move = await start_slow_move(tango, x=40)
    queued = [asyncio.create_task(tango.query(line))
              for line in ("?vel x", "?vel y", "?pos", "?err", "?vel z")]
    await asyncio.sleep(0)  # every query is written
    async with asyncio.timeout(5.0):
        await tango.abort()
        for task in queued:
            with pytest.raises(RequestAbortedError):
                await task
        with pytest.raises(MoveError) as info:
            await move
    assert info.value.statuses["x"] == "E"
    assert emu.wire.ctrl_c_count == 1
    assert await tango.query("?vel y") == "12.250"
    assert await tango.query("?vel") == VEL_TEXT
    assert tango.protocol.core.awaiting_completion == []
    await tango.move_to(x=1)  # the next move completes normally


# --------------------------------------------------------------------------------------
# Cancellation


async def _cancel_at_random(rng: random.Random, op: Awaitable[Any], horizon: float) -> bool:
    """Run ``op`` and cancel it at a random moment; True if it was cancelled."""
    if rng.random() < 0.5:
        try:
            await asyncio.wait_for(op, timeout=rng.uniform(0.0, horizon))
        except TimeoutError:
            return True
        return False
    task = asyncio.ensure_future(op)
    if rng.random() < 0.5:
        for _ in range(rng.randint(0, 12)):
            await asyncio.sleep(0)
    else:
        await asyncio.sleep(rng.uniform(0.0, horizon))
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task
    return task.cancelled()


async def _check_in_step(tango: Controller, position: float | None) -> None:
    assert await tango.query("?vel") == VEL_TEXT
    assert await tango.get("vel", axis="z") == 13.125
    assert await tango.query("?err") == "0"
    if position is not None:
        assert (await tango.position())["x"] == position
    assert "M" not in (await tango.status()).values()


async def _cancellation_fuzz(tango: Controller, rng: random.Random, rounds: int,
                             horizon: float) -> int:
    ops: list[Callable[[], Awaitable[Any]]] = [
        lambda: tango.query("?vel y"),
        lambda: tango.get("pos"),
        lambda: tango.status(),
        lambda: tango.set("vel", y=12.25),  # same value: exercises the ?err probe
    ]
    position: float | None = 0.0
    cancelled = 0
    for _ in range(rounds):
        if rng.random() < 0.4:
            target = round(rng.uniform(-0.2, 0.2), 3)
            if await _cancel_at_random(rng, tango.move_to(x=target), horizon * 4):
                position = None
                cancelled += 1
            else:
                position = target
        else:
            cancelled += await _cancel_at_random(rng, rng.choice(ops)(), horizon)
        await _check_in_step(tango, position)
    assert tango.protocol.core.pending_tags == []
    assert tango.protocol.core.awaiting_completion == []
    return cancelled


async def _fuzz_setup(emu: Emulated) -> None:
    await emu.make_fast()
    await emu.tango.set("vel", **VELS)


@pytest.mark.parametrize("rounds", [pytest.param(100, id="quick"),
                                    pytest.param(1000, id="full", marks=pytest.mark.slow)])
async def test_random_cancellation_instant_mode(emulator: EmulatorFactory, rounds: int) -> None:
    emu = await emulator()
    await _fuzz_setup(emu)
    cancelled = await _cancellation_fuzz(emu.tango, random.Random(2024), rounds, 0.002)
    assert cancelled > 0.3 * rounds


#: A quick sample by default, the longer run under slow.
ROUNDS = [pytest.param(60, id="quick"), pytest.param(300, id="full", marks=pytest.mark.slow)]


@pytest.mark.parametrize("rounds", ROUNDS)
@pytest.mark.parametrize("mode", [0, 2, 3, 4])
async def test_random_cancellation_in_other_modes(emulator: EmulatorFactory, mode: int,
                                                  rounds: int) -> None:
    emu = await emulator(autostatus=mode)
    await _fuzz_setup(emu)
    cancelled = await _cancellation_fuzz(emu.tango, random.Random(mode), rounds, 0.002)
    assert cancelled > 0.2 * rounds


@pytest.mark.parametrize("rounds", ROUNDS)
async def test_random_cancellation_at_57600_baud(emulator: EmulatorFactory, rounds: int) -> None:
    emu = await emulator("sim://?baud=57600")
    await _fuzz_setup(emu)
    cancelled = await _cancellation_fuzz(emu.tango, random.Random(57600), rounds, 0.006)
    assert cancelled > 0.2 * rounds


@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_cancelled_move_stops_the_axes(emulator: EmulatorFactory, mode: int,
                                             caplog: pytest.LogCaptureFixture) -> None:
    tango = (await emulator(autostatus=mode)).tango
    move = await start_slow_move(tango, x=40)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        move.cancel()
        with pytest.raises(asyncio.CancelledError):
            await move
    assert any("-> b'!a'" in r.getMessage() for r in caplog.records)
    assert "M" not in (await tango.status()).values()
    stopped = (await tango.position())["x"]
    await asyncio.sleep(0.05)
    assert (await tango.position())["x"] == stopped < 40


async def test_cancelled_move_keeps_going_without_stop_on_cancel(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()
    await emu.tango.set("accel", x=20)
    task = asyncio.create_task(emu.tango.move_to(x=2, stop_on_cancel=False))
    await wait_until(lambda: emu.model.motion.is_moving("x"), timeout=30.0)  # under way
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert (await emu.tango.status())["x"] == "M"
    # The next move waits until the detached one has reached its target.
    assert await emu.tango.move_to(y=1) == {"x": "@", "y": "@", "z": "@"}
    assert await emu.tango.position() == {"x": 2.0, "y": 1.0, "z": 0.0}


async def test_second_concurrent_move_waits_for_the_first(
        emulator: EmulatorFactory, caplog: pytest.LogCaptureFixture) -> None:
    emu = await emulator()
    await emu.make_fast()
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        first, second = await asyncio.gather(emu.tango.move_to(x=3), emu.tango.move_to(y=4))
    assert first == second == {"x": "@", "y": "@", "z": "@"}
    wire = [r.getMessage().split(" ", 1)[1] for r in caplog.records
            if r.name == "tango_aio.wire"]
    moves = [i for i, m in enumerate(wire) if m.startswith("-> b'!moa")]
    reports = [i for i, m in enumerate(wire) if m == "<- b'@@@-.'"]
    assert len(moves) == 2 and len(reports) == 2
    assert moves[0] < reports[0] < moves[1] < reports[1]
    assert await emu.tango.position() == {"x": 3.0, "y": 4.0, "z": 0.0}


# --------------------------------------------------------------------------------------
# Wire tracing


async def test_wire_logger_traces_lines_both_ways(emulator: EmulatorFactory,
                                                  caplog: pytest.LogCaptureFixture) -> None:
    tango = (await emulator()).tango
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.get("vel")
        await tango.set("vel", x=10, y=5)
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records
             if r.name == "tango_aio.wire"]
    # Separators between look-alike requests (?help N, ERROR N,...) left out.
    lines = [line for line in lines if "help" not in line and "ERROR" not in line]
    # The set's read-back (tango_aio.sansio._readback) follows its ?err in the same write.
    assert lines == ["-> b'?vel'", "<- b'10.000 10.000 10.000'",
                     "-> b'!vel 10 5'", "-> b'?err'", "-> b'?vel'", "<- b'0'",
                     "<- b'10.000 5.000 10.000'"]


# --------------------------------------------------------------------------------------
# Connection loss


async def _assert_loss_fails_pending(tango: Controller, wire: Wire,
                                     cut: Callable[[], object]) -> None:
    """With a move running and a query waiting, ``cut()`` the link: both fail fast."""
    move = await start_slow_move(tango, x=40)
    wire.stall(10.0)  # the query stays unanswered
    query = asyncio.create_task(tango.query("?vel"))
    await asyncio.sleep(0.02)
    assert not query.done()
    cut()
    await wait_lost(tango)  # the driver noticed the loss
    await done_within_ticks(query, move)  # ... and failed every waiter with it
    for task in (query, move):
        with pytest.raises(ConnectionLostError) as info:
            await task
        assert info.value.__cause__ is not None
    for call in (tango.position, lambda: tango.move_to(x=1), lambda: tango.query("?err")):
        await assert_fails_fast(call)


async def test_sim_disconnect_fails_pending_awaits(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    wire = emu.wire

    def cut() -> None:
        wire.disconnect()

    await _assert_loss_fails_pending(emu.tango, wire, cut)


async def test_pty_server_close_fails_pending_awaits() -> None:
    server = await serve_pty(make_model)
    try:
        tango = await connect(server.path)
        try:
            # A plain POSIX port: its descriptor is read and written directly (#19).
            assert isinstance(tango.protocol.transport, FdTransport)
            assert tango.identity is not None and tango.identity.axes == 3
            assert await tango.get("vel") == {"x": 10.0, "y": 10.0, "z": 10.0}
            await _assert_loss_fails_pending(tango, server.wire, server.close)
        finally:
            await tango.aclose()
    finally:
        server.close()
        await server.wait_closed()


async def test_tcp_server_close_fails_pending_awaits() -> None:
    async with await serve_tcp(make_model) as server:
        tango = await connect(f"socket://127.0.0.1:{server.port}")
        try:
            assert await tango.get("vel") == {"x": 10.0, "y": 10.0, "z": 10.0}
            await _assert_loss_fails_pending(tango, server.wires[0], server.close)
        finally:
            await tango.aclose()


async def test_refused_move_on_busy_axis_raises_and_keeps_sync(
        emulator: EmulatorFactory) -> None:
    tango = (await emulator()).tango
    await tango.set("vel", **VELS)
    move = await start_slow_move(tango, x=5)
    with pytest.raises(NotExecutableError):
        await tango.command("!moa x 1")  # refused: x is still moving
    await tango.abort(soft=True)
    with pytest.raises(MoveError):
        await move
    assert await tango.query("?vel") == VEL_TEXT


# --------------------------------------------------------------------------------------
# Set-up whatever mode the controller was left in


@pytest.mark.parametrize("left", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("wanted", [1, 4])
async def test_setup_from_any_mode_left_behind(emulator: EmulatorFactory, left: int,
                                               wanted: int) -> None:
    emu = await emulator(autostatus=wanted)
    emu.model.set_autostatus(left)  # e.g. the controller was reset, or another program
    await emu.tango.setup(autostatus=wanted)
    assert emu.model.autostatus == wanted == emu.tango.autostatus
    await emu.tango.set("vel", **VELS)
    assert await emu.tango.query("?vel") == VEL_TEXT


async def test_pty_reconnect_finds_the_mode_the_last_session_left() -> None:
    server = await serve_pty(make_model)
    try:
        async with connect(server.path, autostatus=4) as tango:
            await tango.set("vel", **VELS)
        async with connect(server.path) as tango:  # default: autostatus 1
            handler = server.wire.handler
            assert isinstance(handler, ControllerModel)
            assert tango.autostatus == 1 and handler.autostatus == 1
            assert await tango.query("?vel") == VEL_TEXT
    finally:
        server.close()
        await server.wait_closed()


@pytest.mark.parametrize("axes", [1, 2, 4])
async def test_moves_on_controllers_with_other_axis_counts(emulator: EmulatorFactory,
                                                           axes: int) -> None:
    emu = await emulator(f"sim://?baud=0&axes={axes}", travel=TRAVEL)
    await emu.make_fast()
    present = "xyza"[:axes]
    assert emu.tango.identity is not None and emu.tango.identity.axes == axes
    letters = await emu.tango.move_to(**as_axes(dict.fromkeys(present, 0.5)))
    assert letters == {a: "@" for a in present}
    assert await emu.tango.calibrate() == {a: "A" for a in present}
    assert await emu.tango.position() == {a: 0.0 for a in present}


async def test_ctrl_c_discarding_an_autostatus_line_keeps_the_mode_right(
        emulator: EmulatorFactory) -> None:
    emu = await emulator("sim://?processing=0.01")
    tango = emu.tango
    await tango.set("vel", **VELS)
    queued = [asyncio.create_task(tango.query("?vel")),
              asyncio.create_task(tango.command("!autostatus 4"))]
    await asyncio.sleep(0)
    # The mode change is a barrier: it waits for ?vel's reply, and Ctrl+C discards it.
    await tango.abort()
    results = await asyncio.gather(*queued, return_exceptions=True)
    assert all(isinstance(r, RequestAbortedError) for r in results)
    assert emu.model.autostatus == 1 == tango.autostatus  # the line never ran
    await tango.set("vel", x=11.5)
    assert await tango.query("?vel") == VEL_TEXT
