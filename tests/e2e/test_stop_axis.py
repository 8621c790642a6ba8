"""One-axis stop (#26 item 3): ``Controller.stop("x")`` writes the manual's ``a x``
(L6785-6844), fails only the moves that involve X and leaves the others to succeed."""

from __future__ import annotations

import asyncio

import pytest
from helpers import Emulated, EmulatorFactory, emulated_position, wait_moving

from tango_aio.errors import InvalidCommandError, MoveError
from tango_aio.events import MoveAborted


@pytest.fixture
async def emu(emulator: EmulatorFactory) -> Emulated:
    """The default emulator, moving at 10 mm/s."""
    return await emulator()


async def test_stopping_x_leaves_a_running_y_move_to_succeed(emu: Emulated) -> None:
    tango = emu.tango
    move = asyncio.create_task(tango.move_to(y=2.0))
    await wait_moving(emu, "y")
    await tango.stop("x")  # X stands: nothing to do, and Y goes on
    assert emu.model.motion.is_moving("y")
    assert (await move)["y"] == "@"
    assert emulated_position(emu, "y") == pytest.approx(2.0)
    assert (await tango.position())["y"] == 2.0


async def test_stopping_x_fails_the_x_move_and_the_queued_y_move_succeeds(
        emu: Emulated) -> None:
    tango = emu.tango
    x_move = asyncio.create_task(tango.move_to(x=5.0))
    await wait_moving(emu, "x")
    y_move = asyncio.create_task(tango.move_to(y=1.0))  # waits behind the X move
    await tango.stop("x")
    with pytest.raises(MoveError) as raised:
        await x_move
    assert raised.value.statuses["x"] == "E"
    assert 0.0 < emulated_position(emu, "x") < 5.0  # stopped on the way, by `a x`
    assert (await y_move)["y"] == "@"
    assert emulated_position(emu, "y") == pytest.approx(1.0)
    positions = await tango.position()
    assert positions["y"] == 1.0
    assert positions["x"] == pytest.approx(emulated_position(emu, "x"), abs=1e-3)


async def test_stopping_one_axis_of_a_merged_move_stops_that_axis_only(
        emu: Emulated) -> None:
    tango = emu.tango
    events = tango.events()
    move = asyncio.create_task(tango.move_to(x=5.0, y=1.0))  # one line: !moa 5 1
    await wait_moving(emu, "x")
    await tango.stop("X")
    assert not emu.model.motion.is_moving("x")
    with pytest.raises(MoveError):  # the line moved X, which was stopped
        await move
    # `a x` stopped X only: Y went on to its target (the emulator's own state).
    assert 0.0 < emulated_position(emu, "x") < 5.0
    assert emulated_position(emu, "y") == pytest.approx(1.0)
    seen = []
    while (event := events.get_nowait()) is not None:
        seen.append(event)
    assert [(e.ctrl_c, e.axes) for e in seen if isinstance(e, MoveAborted)] == [
        (False, ("x",))]


async def test_stop_refuses_an_absent_axis_before_writing(emu: Emulated) -> None:
    tango = emu.tango
    move = asyncio.create_task(tango.move_to(x=1.0))
    await wait_moving(emu, "x")
    with pytest.raises(InvalidCommandError, match="no A axis") as raised:
        await tango.stop("x", "a")  # a 3-axis controller
    assert isinstance(raised.value, ValueError)
    assert (await move)["x"] == "@"  # nothing was written: X was not stopped


async def test_stop_without_axes_stops_every_axis(emu: Emulated) -> None:
    tango = emu.tango
    move = asyncio.create_task(tango.move_to(x=5.0, y=5.0))
    await wait_moving(emu, "x")
    await tango.stop()
    with pytest.raises(MoveError):
        await move
    assert emulated_position(emu, "x") < 5.0 and emulated_position(emu, "y") < 5.0
