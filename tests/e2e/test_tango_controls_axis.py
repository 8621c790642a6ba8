"""The Tango Controls device server's asyncio side (``tango_aio.tango_controls._axis``),
without pytango: what an axis device shows (``State``, ``Status``, ``Position``) and in
which order it publishes it, for every way a motion can end, against the in-process
emulator."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from typing import Any

import pytest
from helpers import (
    FAST,
    INSTANT,
    Emulated,
    EmulatorFactory,
    abort_from_outside,
    emulated_position,
    wait_moving,
    wait_until,
)

from tango_aio import TangoError
from tango_aio.tango_controls import Shown
from tango_aio.tango_controls._axis import AxisBusyError, AxisCore, LimitError, StageLink
from tango_aio.testing import faults

pytestmark = pytest.mark.timeout(60)


class Recorder:
    """What an axis published, in order; each ``State`` with the position shown then."""

    def __init__(self, axis: AxisCore, emu: Emulated) -> None:
        self.axis, self.emu = axis, emu
        self.log: list[tuple[str, Any]] = []
        #: (state, Position shown, where the emulated axis really was) at each State.
        self.states: list[tuple[Shown, float, float]] = []
        axis.publish = self.publish

    def publish(self, name: str, value: Any) -> None:
        self.log.append((name, value))
        if name == "State":
            self.states.append((value[0], self.axis.position,
                                emulated_position(self.emu, self.axis.letter)))

    def last_state(self) -> Shown:
        return self.axis.state[0]


@contextlib.asynccontextmanager
async def served(emu: Emulated) -> AsyncIterator[tuple[StageLink, Recorder]]:
    link = StageLink(emu.tango, interval=0.02)
    recorder = Recorder(link.axes["x"], emu)
    task = asyncio.create_task(link.run())
    try:
        await wait_until(lambda: recorder.last_state() is Shown.ON)
        yield link, recorder
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await link.aclose()


async def ended(recorder: Recorder) -> Shown:
    await wait_until(lambda: recorder.last_state() is not Shown.MOVING)
    return recorder.last_state()


async def test_a_move_shows_moving_then_on_with_the_final_position(
        emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    await emu.make_fast()
    async with served(emu) as (_, recorder):
        axis = recorder.axis
        for target in (3.0, -2.5, 7.25):
            start = len(recorder.log)
            await axis.move_to(target)
            assert axis.state[0] is Shown.MOVING  # at once, before any reply came
            assert await ended(recorder) is Shown.ON
            assert axis.position == pytest.approx(target)
            published = recorder.log[start:]
            final = max(i for i, (name, _) in enumerate(published) if name == "Position")
            on = max(i for i, (name, _) in enumerate(published) if name == "State")
            assert final < on and published[final][1] == pytest.approx(target)
        # Never ON while the position shown is not where the axis stands.
        for state, shown_at, really in recorder.states:
            if state is Shown.ON:
                assert shown_at == pytest.approx(really, abs=1e-3)


async def test_a_read_under_way_at_the_verdict_is_dropped(emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    await emu.make_fast()
    async with served(emu) as (_, recorder):
        axis = recorder.axis
        before = axis.verdicts
        await axis.move_to(4.0)
        assert await ended(recorder) is Shown.ON
        # A read written before the verdict, answered after it: mid-move news.
        axis.read(before, "M", 1.5)
        assert axis.position == pytest.approx(4.0) and axis.state[0] is Shown.ON
        axis.read(axis.verdicts, "@", 4.0)  # a fresh one applies
        assert axis.state[0] is Shown.ON


async def test_a_move_beyond_a_limit_switch_shows_alarm(emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT, travel=10)  # switches at -5 and +5 mm
    await emu.make_fast()
    async with served(emu) as (_, recorder):
        await recorder.axis.move_to(8.0)
        assert await ended(recorder) is Shown.ALARM
        _, status = recorder.axis.state
        assert "move to 8 ended short" in status and "limit switch" in status.lower()
        assert recorder.axis.position == pytest.approx(emulated_position(emu, "x"), abs=1e-3)
        await recorder.axis.move_to(0.0)  # a move that arrives clears the alarm
        assert await ended(recorder) is Shown.ON


async def test_stop_and_an_abort_from_elsewhere_end_in_alarm(
        emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    async with served(emu) as (_, recorder):
        axis = recorder.axis
        await axis.move_to(40.0)  # 10 mm/s: seconds
        await wait_moving(emu, "x")
        await axis.stop()
        assert await ended(recorder) is Shown.ALARM
        assert axis.position == pytest.approx(emulated_position(emu, "x"), abs=1e-3)
        await axis.move_to(-40.0)
        await wait_moving(emu, "x")
        abort_from_outside(emu)
        assert await ended(recorder) is Shown.ALARM
        assert "move to -40 ended short" in axis.state[1]


@pytest.mark.parametrize(("policy", "end"), [("stop", Shown.ALARM), ("continue", Shown.ALARM)])
async def test_an_axis_disabled_mid_move(emulator: EmulatorFactory, policy: str,
                                         end: Shown) -> None:
    """The manual does not say what disabling a moving axis does (L3919-3960): the move
    stops short, or goes on to its target; either way the axis ends disabled (``-``),
    which the driver's verdict counts as no arrival (ALARM), with the position read."""
    emu = await emulator(f"{INSTANT}&disable_during_move={policy}")
    async with served(emu) as (_, recorder):
        await recorder.axis.move_to(20.0)
        await wait_moving(emu, "x")
        emu.model.handle_line(b"!axis x 0", asyncio.get_running_loop().time())
        assert await ended(recorder) is end
        assert recorder.axis.position == pytest.approx(emulated_position(emu, "x"), abs=1e-3)


async def test_a_move_of_a_disabled_axis_ends_in_alarm(emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    await emu.make_fast()
    async with served(emu) as (_, recorder):
        emu.model.handle_line(b"!axis x 0", asyncio.get_running_loop().time())
        await recorder.axis.move_to(2.0)
        assert await ended(recorder) is Shown.ALARM
        assert recorder.axis.position == pytest.approx(0.0)


async def test_a_refused_line_ends_in_alarm(emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    await emu.make_fast()
    async with served(emu) as (_, recorder):
        # The limits change behind the server's back: its check passes, the controller
        # refuses the line (manual L4526-4540).
        emu.model.handle_line(b"!lim x -1 1", asyncio.get_running_loop().time())
        await recorder.axis.move_to(3.0)
        assert await ended(recorder) is Shown.ALARM
        assert recorder.axis.position == pytest.approx(emulated_position(emu, "x"), abs=1e-3)


async def test_a_second_motion_or_a_target_beyond_the_limits_is_refused_at_once(
        emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    async with served(emu) as (_, recorder):
        axis = recorder.axis
        _, high = await emu.tango.axis_limits("x")
        with pytest.raises(LimitError):
            await axis.move_to(high + 1)
        assert axis.state[0] is Shown.ON
        await axis.move_to(30.0)
        with pytest.raises(AxisBusyError):
            await axis.move_to(1.0)
        with pytest.raises(AxisBusyError):
            axis.calibrate()
        await wait_moving(emu, "x")
        await axis.stop()
        assert await ended(recorder) is Shown.ALARM


async def test_no_motion_before_the_settings_are_read(emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT)
    axis = StageLink(emu.tango).axes["x"]  # not running: nothing read yet
    assert axis.state[0] is Shown.INIT
    with pytest.raises(TangoError, match="settings are being read"):
        await axis.move_to(1.0)
    assert axis.state[0] is Shown.INIT and not emu.model.motion.is_moving("x")


async def test_a_lost_link_shows_fault_then_the_move_as_unknown(
        emulator: EmulatorFactory) -> None:
    emu = await emulator(INSTANT, **FAST)
    async with served(emu) as (_, recorder):
        axis = recorder.axis
        await axis.move_to(40.0)
        await wait_moving(emu, "x")
        faults(emu.tango).disconnect()
        await wait_until(lambda: axis.state[0] is Shown.FAULT)
        await wait_until(lambda: axis.state[0] is Shown.ALARM)  # back, the move unproven
        assert "ended short" in axis.state[1]
        states = [state for state, _, _ in recorder.states]
        assert Shown.ON not in states[states.index(Shown.FAULT):]
