"""A ``speed`` or ``go`` line whose line is lost on the way is not reported as done.

In autostatus 0, 1 and 3 neither line owes an answer of its own, and the ``?err`` 0
behind a lost line is what the line before it left (L2853-2867). The state read behind
the line proves it (:func:`tango_aio.moves._timing.acceptance`); else the call raises a
:class:`~tango_aio.errors.MoveOutcomeUnknown` saying that the line may not have been
applied and what still moves. Every outcome is checked against the emulator's state.
"""

from __future__ import annotations

import pytest

import tango_aio
from tango_aio import Controller, MoveOutcomeUnknown
from tango_aio.testing import Faults, faults

pytestmark = pytest.mark.virtual_clock

#: The modes whose speed and go lines owe no answer of their own.
UNANSWERED = [0, 1, 3]


async def opened(mode: int) -> Controller:
    return await tango_aio.connect("sim://?baud=0", autostatus=mode, reply_timeout=2.0)


def sample(modes: list[int], default: int) -> list[object]:
    """``modes``, all but ``default`` in the slow tier only (each waits out a bound)."""
    return [mode if mode == default else pytest.param(mode, marks=pytest.mark.slow)
            for mode in modes]


def moving(fault: Faults, axis: str) -> bool:
    return fault.model.motion.is_moving(axis) or fault.axes()[axis][1] != 0.0


def lose(fault: Faults, prefix: bytes) -> None:
    fault.wire.faults.lose_line = prefix


@pytest.mark.parametrize("call", ["speed", "command"])
@pytest.mark.parametrize("mode", [*UNANSWERED, *sample([2, 4], 2)])
async def test_a_lost_speed_line_raises(mode: int, call: str) -> None:
    async with await opened(mode) as tango:
        fault = faults(tango)
        lose(fault, b"!speed")
        with pytest.raises(tango_aio.TangoError) as raised:
            if call == "speed":
                await tango.speed(z=2.0)
            else:
                await tango.command("!speed z 2")
        assert fault.wire.lost_lines == 1
        assert not moving(fault, "z")
        if mode in UNANSWERED:
            assert isinstance(raised.value, MoveOutcomeUnknown), raised.value
            assert "may not have been applied" in str(raised.value)
            assert "Z standing" in str(raised.value)
        # The call after it works.
        await tango.speed(z=2.0)
        assert moving(fault, "z")
        await tango.speed(z=0.0)
        await tango.wait_idle(timeout=30.0)
        assert not moving(fault, "z")


@pytest.mark.parametrize(("new", "says"), [
    (0.0, "Z still moving.*axes Z stopped"),  # a lost stop: Z runs on
    (4.0, "Z moving as before the line.*axes Z stopped"),  # M proves nothing, ?speed does
])
@pytest.mark.parametrize("mode", sample(UNANSWERED, 1))
async def test_a_lost_line_to_a_running_axis_stops_it_and_says_so(mode: int, new: float,
                                                                  says: str) -> None:
    async with await opened(mode) as tango:
        fault = faults(tango)
        await tango.speed(z=2.0)
        await tango.speed(z=3.0)  # not lost: the speed in force shows it
        assert moving(fault, "z")
        assert await tango.get("speed", axis="z") == pytest.approx(3.0)
        lose(fault, b"!speed")
        with pytest.raises(MoveOutcomeUnknown, match=says):
            await tango.speed(z=new)
        assert fault.wire.lost_lines == 1
        assert not moving(fault, "z")


@pytest.mark.parametrize("mode", UNANSWERED)
async def test_a_lost_go_raises_and_a_go_that_ended_is_proven(mode: int) -> None:
    async with await opened(mode) as tango:
        fault = faults(tango)
        lose(fault, b"!go")
        with pytest.raises(MoveOutcomeUnknown, match="may not have been applied"):
            await tango.go(x=0.5)
        assert fault.wire.lost_lines == 1
        assert fault.axes()["x"] == (0.0, 0.0)
        await tango.go(x=0.0)  # where X stands: nothing moves, the position shows it
        await tango.go(x=0.5)
        await tango.wait_idle(timeout=30.0)
        assert fault.axes()["x"][0] == pytest.approx(0.5, abs=1e-3)
