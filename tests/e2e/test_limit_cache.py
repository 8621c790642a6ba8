"""The software limits known without a read (#28 target 3): ``Controller.axis_limits``.

A Bluesky step point checks its target against the limits; they change only through
lines the driver writes (``!lim``, ``cal``/``rm``/``vrm``, ``restore``/``reset``, and
``dim`` changes their unit: L4522-4580, L1296) or a power cycle, so the limits read once
serve every later check until one of those went out, ended, or the link was set up again.
A limit changed behind the driver's back still fails the move with a typed error.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable

import pytest
from helpers import Emulated, EmulatorFactory, emulated_position

from tango_aio import Controller
from tango_aio.errors import ControllerError, MoveError

pytestmark = pytest.mark.virtual_clock


def _lim_reads(caplog: pytest.LogCaptureFixture) -> int:
    return sum(1 for r in caplog.records if r.name == "tango_aio.wire"
               and " -> " in r.getMessage() and "?lim" in r.getMessage())


@pytest.fixture
async def emu(emulator: EmulatorFactory) -> Emulated:
    emulated = await emulator(travel=20.0)
    await emulated.make_fast()
    return emulated


async def test_limits_read_once_serve_every_later_move(
        emu: Emulated, caplog: pytest.LogCaptureFixture) -> None:
    tango = emu.tango
    await tango.set_limits(x=(-4.0, 4.0))
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        assert await tango.axis_limits("x") == (-4.0, 4.0)
        for target in (1.0, -1.0, 2.0):
            await tango.move_to(x=target)
            await tango.move_by(x=0.5)
            assert await tango.axis_limits("x") == (-4.0, 4.0)
        assert _lim_reads(caplog) == 1
        assert await tango.axis_limits("x", cached=False) == (-4.0, 4.0)
        assert _lim_reads(caplog) == 2


async def _set_limits(tango: Controller) -> None:
    await tango.set_limits(x=(-3.0, 3.0))


async def _command_lim(tango: Controller) -> None:
    await tango.command("!lim x -3 3")


async def _set_lim(tango: Controller) -> None:
    await tango.set("lim", -3, 3, axis="x")


async def _calibrate(tango: Controller) -> None:
    await tango.calibrate("x")


async def _measure_range(tango: Controller) -> None:
    await tango.measure_range("x")


async def _raw_cal(tango: Controller) -> None:
    """A cal written raw: the limits it sets come at its end, after the line's ack; a
    read while it runs sees the old ones and must not be kept."""
    await tango.command("!cal x")
    await tango.axis_limits("x")
    await tango.wait_idle()


async def _setup(tango: Controller) -> None:
    await tango.setup()


PATHS: dict[str, Callable[[Controller], Awaitable[None]]] = {
    "set_limits": _set_limits, "command !lim": _command_lim, "set lim": _set_lim,
    "calibrate": _calibrate, "measure_range": _measure_range, "command !cal": _raw_cal,
    "setup": _setup}


@pytest.mark.parametrize("path", PATHS)
async def test_every_line_that_may_change_the_limits_is_seen(emu: Emulated,
                                                             path: str) -> None:
    tango = emu.tango
    await tango.set_limits(x=(-4.5, 4.5))
    await tango.move_to(x=0.5)
    assert await tango.axis_limits("x") == (-4.5, 4.5)
    if path == "setup":
        emu.model.motion.set_limits("x", -2.5, 2.5)  # as a power cycle may bring
    await PATHS[path](tango)
    known = await tango.axis_limits("x")  # read again, or the cache of before
    assert known != (-4.5, 4.5)
    assert known == pytest.approx(emu.model.motion.limits("x"))
    assert await tango.axis_limits("x", cached=False) == known


async def test_a_read_overtaken_by_a_limit_change_is_not_kept(emu: Emulated) -> None:
    tango = emu.tango
    await tango.set_limits(x=(-4.0, 4.0))
    await tango.axis_limits("x", cached=False)
    await tango.command("!dim x 1")  # the unit changes: limits now in µm (L4555)
    read = asyncio.ensure_future(tango.axis_limits("x"))
    await asyncio.sleep(0)  # its ?lim is on its way
    await tango.command("!dim x 2")
    await read
    assert await tango.axis_limits("x") == (-4.0, 4.0)


async def test_limits_changed_behind_the_drivers_back_still_fail_the_move(
        emu: Emulated) -> None:
    tango = emu.tango
    await tango.set_limits(x=(-4.0, 4.0))
    assert await tango.axis_limits("x") == (-4.0, 4.0)
    emu.model.motion.set_limits("x", -1.0, 1.0)  # not through the driver
    assert await tango.axis_limits("x") == (-4.0, 4.0)  # the cache cannot know
    with pytest.raises((ControllerError, MoveError)):
        await tango.move_to(x=3.0)
    assert emulated_position(emu, "x") <= 1.0
    await tango.move_to(x=0.5)  # the next call works
    assert emulated_position(emu, "x") == pytest.approx(0.5)


async def test_a_calibration_without_reports_is_seen_at_its_end(
        emulator: EmulatorFactory) -> None:
    # Autostatus 0 sends no report at the end of a cal (L2131-2134): calibrate() itself
    # forgets the limits when it returns, so a read made while it ran is not kept.
    emu = await emulator(travel=20.0, autostatus=0)
    await emu.make_fast()
    tango = emu.tango
    await tango.set_limits(x=(-4.5, 4.5))
    await tango.move_to(x=0.5)
    calibrating = asyncio.ensure_future(tango.calibrate("x"))
    for _ in range(1000):  # each read goes behind the lines written before it
        if (await tango.status())["x"] == "M":
            break
    assert not calibrating.done()
    assert await tango.axis_limits("x") == (-4.5, 4.5)  # read while it runs
    await calibrating
    known = await tango.axis_limits("x")
    assert known != (-4.5, 4.5)
    assert known == pytest.approx(emu.model.motion.limits("x"))
