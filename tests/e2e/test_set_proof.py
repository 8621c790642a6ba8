"""Every set is proven (issue 37, failure 2): a set line lost on the way raises instead of
returning, in every autostatus mode, whatever the path (``set``, the typed setters,
``command``, the blocking API); a set that arrives returns with the emulator holding the
value; the rounding the manual documents is what the controller holds."""

from __future__ import annotations

from collections.abc import Awaitable, Callable

import pytest
from helpers import INSTANT, EmulatorFactory

import tango_aio.sync
from tango_aio import SettingNotAppliedError
from tango_aio.controller._controller import Controller
from tango_aio.errors import ControllerError, ControllerTimeoutError
from tango_aio.testing import Faults, faults

pytestmark = pytest.mark.virtual_clock

Setter = Callable[[Controller], Awaitable[None]]

#: Each path that sets ``vel`` of X to 55.5 rev/s.
PATHS: dict[str, Setter] = {
    "set": lambda tango: tango.set("vel", 55.5, axis="x"),
    "set by keyword": lambda tango: tango.set("vel", x=55.5),
    "set_velocity": lambda tango: tango.set_velocity(x=55.5),
    "command": lambda tango: tango.command("!vel x 55.5"),
}


def _vel_x(fault: Faults) -> float:
    return fault.model.params.number("vel", 0)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_a_lost_set_line_raises_in_modes_without_an_answer(
        emulator: EmulatorFactory, mode: int, path: str) -> None:
    tango = (await emulator(INSTANT, autostatus=mode)).tango
    fault = faults(tango)
    before = _vel_x(fault)
    fault.lose_line("!vel")
    with pytest.raises(SettingNotAppliedError) as info:
        await PATHS[path](tango)
    assert _vel_x(fault) == before != 55.5  # the controller never had it
    error = info.value
    assert (error.instruction, error.sent) == ("vel", "55.5")
    assert error.read.startswith("?vel") and error.held.split()[0] == f"{before:.3f}"
    assert "may not have been applied" in str(error)
    # The stream is in step: the next set is proven and held.
    await tango.set("vel", 44.25, axis="x")
    assert _vel_x(fault) == 44.25


@pytest.mark.parametrize("mode", [2, 4])
async def test_a_lost_set_line_still_times_out_where_the_line_owes_an_answer(
        emulator: EmulatorFactory, mode: int) -> None:
    tango = (await emulator(INSTANT, autostatus=mode)).tango
    tango.reply_timeout = 1.0  # the answer never comes: any timeout ends the same way
    fault = faults(tango)
    before = _vel_x(fault)
    fault.lose_line("!vel")
    with pytest.raises(ControllerTimeoutError):
        await tango.set("vel", 55.5, axis="x")
    assert _vel_x(fault) == before


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_sets_that_arrive_return_and_are_held(emulator: EmulatorFactory,
                                                    mode: int) -> None:
    tango = (await emulator(INSTANT, autostatus=mode)).tango
    fault = faults(tango)
    model = fault.model
    await tango.set("vel", 55.5, axis="x")
    await tango.set_acceleration(x=0.5, y=0.75)
    await tango.command("!lim y -10 20.5")
    await tango.set("swtyp", 1, 0, 1)
    await tango.set("delay", 15)
    await tango.set("triga", "y")
    await tango.command("!lock 3 1")
    assert _vel_x(fault) == 55.5
    assert [model.params.number("accel", i) for i in (0, 1)] == [0.5, 0.75]
    assert model.motion.limits(1) == (-10.0, 20.5)  # dim 2: mm, as written
    assert all(model.params.axis("swtyp", i) == (1, 0, 1) for i in range(3))
    assert model.params.first("delay") == 15
    assert model.params.first("triga") == "y"
    assert str(model.params.first("lock"))[3] == "1"


async def test_a_value_the_controller_rounds_as_documented_is_held_so(
        emulator: EmulatorFactory) -> None:
    """``!trigs`` rounds to 40 µs steps and reads the corrected value back (L12965-12967):
    the set returns, and the controller holds the rounded value."""
    tango = (await emulator(INSTANT)).tango
    await tango.set("trigs", 90)
    model = faults(tango).model
    assert model.params.first("trigs") == 80
    await tango.set("trigs", 100, 0, 60)
    assert model.params.global_values["trigs"] == (120, 0, 80)


async def test_a_value_the_controller_changes_otherwise_raises(
        emulator: EmulatorFactory) -> None:
    """A controller that holds another value than the one written, without an error
    (here the emulator's interpreter changes it as the line runs), fails the set with
    both values named."""
    tango = (await emulator(INSTANT)).tango
    model = faults(tango).model
    handle = model.handle_line

    def clamp(line: bytes, now: float) -> None:
        handle(line, now)
        if line.startswith(b"!vel"):
            model.params.put_axis("vel", 0, (40.0,))
    model.handle_line = clamp  # type: ignore[method-assign]
    with pytest.raises(SettingNotAppliedError) as info:
        await tango.set("vel", 55.5, axis="x")
    assert (info.value.sent, info.value.held) == ("55.5", "40.000")


async def test_an_unchecked_set_reads_nothing_back(emulator: EmulatorFactory) -> None:
    tango = (await emulator(INSTANT)).tango
    fault = faults(tango)
    fault.lose_line("!vel")
    processed = fault.wire.lines_processed
    await tango.set("vel", 55.5, axis="x", check=False)  # what the caller asked for
    await tango.get("vel", axis="x")
    assert fault.wire.lines_processed - processed == 1  # the read alone arrived


def test_the_blocking_api_raises_too() -> None:
    with tango_aio.sync.connect(INSTANT) as tango:
        async def lose() -> None:
            faults(tango.aio).lose_line("!vel")
        tango.portal.call(lose)
        with pytest.raises(SettingNotAppliedError):
            tango.set_velocity(x=55.5)
        tango.set_velocity(x=33.5)
        assert tango.velocity()["x"] == 33.5


@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_a_standing_internal_error_does_not_stand_in_for_the_proof(
        emulator: EmulatorFactory, mode: int) -> None:
    """With an internal error standing (29: amplifier off, L2824-2881), ``?err`` answers
    it behind every line that was fine (L2853-2867), and the driver takes it for the
    controller's state, not the line's: the read-back still decides."""
    tango = (await emulator(INSTANT, autostatus=mode)).tango
    fault = faults(tango)
    fault.model.inject_internal_error(29, permanent=True)
    await tango.set("vel", 44.25, axis="x")  # held: accepted, the fault published
    assert _vel_x(fault) == 44.25
    fault.lose_line("!vel")
    with pytest.raises(SettingNotAppliedError) as info:
        await tango.set("vel", 55.5, axis="x")
    assert isinstance(info.value.__cause__, ControllerError)
    assert info.value.__cause__.number == 29
    assert _vel_x(fault) == 44.25
