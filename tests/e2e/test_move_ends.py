"""A move that ends at a limit switch, a disabled axis or an abort ends the call at once,
with a :class:`MoveError` that says what happened in words (#26 items 2 and 6)."""

from __future__ import annotations

import asyncio

import pytest
from helpers import (
    Emulated,
    EmulatorFactory,
    abort_from_outside,
    emulated_position,
    wait_moving,
)

from tango_aio.errors import MoveError

pytestmark = pytest.mark.virtual_clock


@pytest.fixture
async def emu(emulator: EmulatorFactory) -> Emulated:
    """Limit switches at -2 and +2 mm; the axes travel at 10 mm/s."""
    return await emulator(travel=4.0)


async def test_a_move_into_a_limit_switch_fails_when_the_switch_is_reached(
        emu: Emulated) -> None:
    tango = emu.tango
    motion = emu.model.motion
    errors: list[tuple[MoveError, float, bool]] = []

    async def move() -> None:
        try:
            await tango.move_to(x=60.0)
        except MoveError as error:
            # The emulator's own clock and state at the moment the error arrives.
            errors.append((error, motion.now, motion.is_moving("x")))

    start = motion.now
    await move()
    [(error, ended, moving)] = errors
    assert error.statuses["x"] == "S" and not moving
    assert emulated_position(emu, "x") < 3.0  # stopped at the switch, far from 60
    # The driver's own plan for this move: 60 mm at the speed it knows.
    planned = tango._settings.travel("x", 60.0)
    reach_switch = tango._settings.travel("x", 2.0)
    # Ended near when the switch was reached, not at the planned end (the old driver
    # waited out the whole planned travel, then read the state).
    assert ended - start < reach_switch + (planned - reach_switch) / 2
    assert "X stopped at its upper limit switch (EE) (status S)" in str(error)
    assert "target 60" in str(error)
    assert (await tango.position())["x"] == pytest.approx(emulated_position(emu, "x"),
                                                          abs=1e-3)
    # The next move works: back inside the range.
    assert (await tango.move_to(x=0.0))["x"] == "@"


async def test_a_move_towards_the_lower_switch_says_so(emu: Emulated) -> None:
    with pytest.raises(MoveError, match=r"X stopped at its lower limit switch \(E0\)"):
        await emu.tango.move_by(x=-60.0)


async def test_a_move_of_a_disabled_axis_fails_at_once_in_words(emu: Emulated) -> None:
    tango = emu.tango
    await tango.set("axis", 0, axis="y")
    start = emu.model.motion.now
    planned = tango._settings.travel("y", 5.0)
    with pytest.raises(MoveError, match=r"Y is disabled or absent \(status -\) and did "
                       r"not move, at 0.0000, target 5") as raised:
        await tango.move_to(y=5.0)
    assert emu.model.motion.now - start < planned / 2
    assert raised.value.statuses.get("y", "-") in ("-", "@")
    assert emulated_position(emu, "y") == 0.0


async def test_an_abort_by_someone_else_fails_the_move_at_once(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()  # switches at +-50 mm: a 40 mm move takes 4 s
    tango = emu.tango
    motion = emu.model.motion
    move = asyncio.create_task(tango.move_to(x=40.0))
    await wait_moving(emu, "x")
    abort_from_outside(emu)
    aborted = motion.now
    with pytest.raises(MoveError, match=r"X stopped: its move was aborted or not executed "
                       r"\(status E\), at \d+\.\d+, target 40"):
        await move
    # Ended at the report of the abort (the emulator's clock when the driver read the
    # state that ended it), not at the planned end of the move.
    assert motion.now - aborted < tango._settings.travel("x", 40.0) / 2
    assert not emu.model.motion.is_moving("x")
    # Short of the target; it may not have left 0 yet when the abort came (seen under uvloop).
    assert 0.0 <= emulated_position(emu, "x") < 40.0
    assert (await tango.position())["x"] == pytest.approx(emulated_position(emu, "x"),
                                                          abs=1e-3)


async def test_without_reports_a_limit_switch_is_seen_by_polling_during_the_move(
        emulator: EmulatorFactory) -> None:
    """Autostatus 0 sends no report: the driver polls during the move, so the stop at
    the switch ends the call long before the planned end."""
    emu = await emulator(travel=4.0, autostatus=0)
    tango = emu.tango
    motion = emu.model.motion
    start = motion.now
    with pytest.raises(MoveError, match="upper limit switch"):
        await tango.move_to(x=60.0)
    assert not motion.is_moving("x")
    planned = tango._settings.travel("x", 60.0)
    assert motion.now - start < planned / 2


# -- a move of several axes, one of which stops early (#37 item 5) ---------------------------

#: Where each move starts and goes: the stopped axis runs into its upper switch at +2 mm
#: while the other has a quarter of a millimetre to go over the whole vector move.
_SPLIT = {"x": ((1.5, -0.25), (60.0, 0.0)), "y": ((-0.25, 1.5), (0.0, 60.0))}


@pytest.mark.parametrize("stopped", ["x", "y"])
@pytest.mark.parametrize("autostatus", [0, 1, 2, 3, 4])
async def test_an_axis_stopped_by_its_switch_ends_a_move_of_several_axes_at_once(
        emulator: EmulatorFactory, autostatus: int, stopped: str) -> None:
    """The other axis of the vector move goes on (the emulator's reading: a switch stops
    its own axis) and the report waits for it; the call ends once the stop is read,
    with the other axis stopped, not at the planned end of the move."""
    emu = await emulator(travel=4.0, autostatus=autostatus)
    tango, motion = emu.tango, emu.model.motion
    other = "y" if stopped == "x" else "x"
    (x0, y0), (x1, y1) = _SPLIT[stopped]
    await tango.move_to(x=x0, y=y0)
    planned = tango._settings.travel(stopped, 58.5)  # the line's own plan
    start = motion.now
    errors: list[tuple[MoveError, float, list[str]]] = []
    try:
        await tango.move_to(x=x1, y=y1)
    except MoveError as raised:
        # The emulator's own clock and state when the error arrives.
        errors.append((raised, motion.now, [a for a in "xyz" if motion.is_moving(a)]))
    [(error, ended, moving)] = errors
    assert ended - start < planned / 2  # not the planned end of the move
    assert moving == []  # the other axis was stopped: nothing moves
    assert emulated_position(emu, stopped) < 3.0
    assert abs(emulated_position(emu, other)) < 0.25  # stopped short of its target
    assert error.statuses[stopped] == "S"
    assert error.statuses[other] != "M"
    name = stopped.upper()
    assert f"{name} stopped at its upper limit switch (EE) (status S)" in str(error)
    assert f"{other.upper()} was stopped by this program when {name} stopped" in str(error)
    # The link is in step: the next move works.
    assert (await tango.move_to(x=0.0, y=0.0))["x"] == "@"
    assert emulated_position(emu, "x") == pytest.approx(0.0, abs=1e-3)
