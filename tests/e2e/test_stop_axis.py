"""One-axis stop (#26 item 3): ``Controller.stop("x")`` writes the manual's ``a x``
(L6785-6844), fails only the moves that involve X and leaves the others to succeed."""

from __future__ import annotations

import asyncio

import pytest
from helpers import Emulated, EmulatorFactory, emulated_position, wait_moving

import tango_aio.sync
from tango_aio.errors import InvalidCommandError, MoveError
from tango_aio.events import MoveAborted
from tango_aio.group._group import ControllerGroup

pytestmark = pytest.mark.virtual_clock


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
    assert "'!moa 5.0' was aborted: X was stopped by this program (a stop, abort or " \
        "cancel), at " in str(raised.value)
    assert str(raised.value).endswith(", target 5")
    # Stopped short, by `a x` (possibly before it had left 0, on a fast loop).
    assert 0.0 <= emulated_position(emu, "x") < 5.0
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
    assert 0.0 <= emulated_position(emu, "x") < 5.0
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


async def test_a_group_stops_one_axis_of_its_members() -> None:
    specs = {"stage": "sim://?baud=0", "focus": "sim://?baud=0"}
    async with ControllerGroup(specs) as group:
        stage, focus = group["stage"], group["focus"]
        x_move = asyncio.create_task(stage.move_to(x=5.0))
        y_move = asyncio.create_task(focus.move_to(y=1.0))
        await wait_moving(Emulated(stage), "x")
        await wait_moving(Emulated(focus), "y")
        await group.stop("x")
        with pytest.raises(MoveError):
            await x_move
        assert (await y_move)["y"] == "@"  # Y was not stopped
        assert emulated_position(Emulated(focus), "y") == pytest.approx(1.0)


def test_the_blocking_stop_stops_one_axis() -> None:
    with tango_aio.sync.connect("sim://?baud=0") as tango:
        x_move = tango.start_move_to(x=5.0)
        while tango.status()["x"] != "M":
            pass
        tango.stop("x")
        assert "M" not in tango.status().values()
        with pytest.raises(MoveError):
            x_move.result(timeout=10)
        assert 0 < tango.position()["x"] < 5.0


async def test_older_firmware_stops_every_axis(emulator: EmulatorFactory) -> None:
    """The older edition's ``a`` takes no axis (old L1907-1919): stop("x") stops all, and
    the Y move it cut short fails rather than passing for a success."""
    emu = await emulator("sim://?baud=0&profile=legacy")
    tango = emu.tango
    assert tango.identity.family == "older"
    move = asyncio.create_task(tango.move_to(y=5.0))
    await wait_moving(emu, "y")
    await tango.stop("x")
    assert not emu.model.motion.is_moving("y")
    with pytest.raises(MoveError):
        await move
    assert emulated_position(emu, "y") < 5.0
