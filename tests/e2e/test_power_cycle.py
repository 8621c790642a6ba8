"""A controller power-cycled behind a live link, in every autostatus mode (issue 32 item
5): the driver notices (the mode it set is gone), selects its mode again, reads its
settings again and publishes ControllerRestarted; and no move that ran is reported failed
without saying that it may have run (MoveOutcomeUnknown)."""

from __future__ import annotations

import asyncio

import pytest
from helpers import settled_position

import tango_aio
from tango_aio import Controller, ControllerRestarted, MoveOutcomeUnknown, TangoError
from tango_aio.events import Subscription
from tango_aio.testing import Faults, faults

pytestmark = pytest.mark.timeout(600)

#: Moves tried after each power cycle: the first may fail (its answer cannot come), the
#: next one works (#37 item 4: in modes 2 and 4 it was written in the power-on mode).
MOVES = 2
STEP = 0.5




async def _move_after_cycle(tango: Controller, fault: Faults) -> list[str]:
    """Power-cycle, then ``move_by`` until one succeeds; the outcomes, checked."""
    fault.power_cycle(0.05)
    outcomes: list[str] = []
    for _ in range(MOVES):
        before = await settled_position(fault)
        try:
            await tango.move_by(x=STEP)
        except TangoError as exc:
            moved = abs(await settled_position(fault) - before) > 1e-6
            # A failed move that ran must say so; one that says so may not have run.
            assert not moved or isinstance(exc, MoveOutcomeUnknown), (before, exc)
            outcomes.append(type(exc).__name__)
            continue
        assert await settled_position(fault) == pytest.approx(before + STEP, abs=1e-3)
        outcomes.append("ok")
        return outcomes
    raise AssertionError(f"the driver did not recover within {MOVES} moves: {outcomes}")


async def _restarted(events: Subscription) -> ControllerRestarted:
    async with asyncio.timeout(30.0):
        async for event in events:
            if isinstance(event, ControllerRestarted):
                return event
    raise AssertionError("the event stream ended")


async def _power_cycles(mode: int, count: int) -> None:
    url = "sim://?baud=0"
    async with tango_aio.connect(url, autostatus=mode, reply_timeout=0.5) as tango:
        fault = faults(tango)
        await tango.set("vel", x=20)  # not saved: the restart loses it
        events = tango.events()
        for _ in range(count):
            await _move_after_cycle(tango, fault)
            if mode != 1:  # the power-on mode: nothing to notice there (module restart)
                event = await _restarted(events)
                assert (event.found, event.autostatus) == (1, mode)
                assert tango.autostatus == mode
            assert fault.model.autostatus == tango.autostatus
        if mode != 1:
            assert (await tango.get("vel"))["x"] == 10.0  # read again: the power-on value


@pytest.mark.parametrize("mode", range(5))
async def test_the_driver_recovers_from_a_power_cycle(mode: int) -> None:
    await _power_cycles(mode, 2)


@pytest.mark.slow
@pytest.mark.parametrize("mode", range(5))
async def test_the_driver_recovers_from_twenty_power_cycles(mode: int) -> None:
    await _power_cycles(mode, 20)


@pytest.mark.parametrize("mode", [2, 4])
async def test_a_raw_move_line_that_ran_is_never_reported_failed_without_saying_so(
        mode: int) -> None:
    """``command("!mor ...")`` right after a restart: it returns (the line was seen
    accepted, and the stage moved) or raises a MoveOutcomeUnknown error (it may have
    run; on the stock loop it always does, as the line arrives after the power-on)."""
    async with tango_aio.connect("sim://?baud=0", autostatus=mode,
                                 reply_timeout=0.5) as tango:
        fault = faults(tango)
        fault.power_cycle(0.0)
        try:
            await tango.command("!mor 0.5")
        except TangoError as exc:
            # Whether it ran or not (a line that arrives while the unit is still off is
            # lost: under uvloop it may), a failure must not deny that it may have run.
            assert isinstance(exc, MoveOutcomeUnknown), exc
        else:  # returned: it was accepted, so it ran
            assert await settled_position(fault) == pytest.approx(0.5, abs=1e-3)


@pytest.mark.parametrize("mode", [2, 4])
async def test_a_set_line_unanswered_after_a_restart_claims_no_move(mode: int) -> None:
    async with tango_aio.connect("sim://?baud=0", autostatus=mode,
                                 reply_timeout=0.5) as tango:
        faults(tango).power_cycle(0.0)
        with pytest.raises(tango_aio.ControllerTimeoutError) as info:
            await tango.command("!vel x 5")
        assert not isinstance(info.value, MoveOutcomeUnknown)


async def test_a_power_cycle_ends_the_move_by_start_rule() -> None:
    """After a restart the HDI is on again: a ``!joy 0`` sent before it no longer holds,
    so a move_by reads its start again and honours a hand on the joystick."""
    async with tango_aio.connect("sim://?baud=0", autostatus=2, reply_timeout=0.5) as tango:
        fault = faults(tango)
        events = tango.events()
        await tango.set("joy", 0)
        await tango.move_by(x=STEP)
        await _move_after_cycle(tango, fault)
        await _restarted(events)
        await tango.move_by(x=STEP)  # confirmed where it stands, with the HDI on
        assert fault.model.hdi_deflect(0, 0.25)  # the power-on HDI is on: honoured
        nudged = await settled_position(fault)
        await tango.move_by(x=STEP)
        assert await settled_position(fault) == pytest.approx(nudged + STEP, abs=1e-3)
        assert (await tango.position())["x"] == pytest.approx(nudged + STEP, abs=1e-3)
