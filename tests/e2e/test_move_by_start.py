"""A ``move_by``'s start (#28 target 2): remembered only while nothing else can move the
stage, read otherwise.

With the HDI (joystick) on, a hand on it moves the axes (L6318-6323) without any line on
the link, so every ``move_by`` reads its start (``?pos`` in the write of its line); once
``!joy 0`` was accepted on the link (L7101-7144), and the snapshot and pulse/direction
inputs were read idle (``?snsm`` 0, ``?tvr`` 0), the position a move's confirmation read
is the next ``move_by``'s start: no ``?pos`` before the line. Any other ``!`` line (it
may move or redefine the stage) makes the next one read again.
"""

from __future__ import annotations

import logging

import pytest
from helpers import Emulated, EmulatorFactory, emulated_position

pytestmark = pytest.mark.virtual_clock


def _written(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage().split(" ", 2)[2] for r in caplog.records
            if r.name == "tango_aio.wire" and " -> " in r.getMessage()]


def _reads_before_moves(lines: list[str]) -> list[bool]:
    """For each ``!mor`` line: whether a ``?pos`` (of every axis) went out right before."""
    return [index > 0 and lines[index - 1] == "b'?pos'"
            for index, line in enumerate(lines) if line.startswith("b'!mor")]


@pytest.fixture
async def emu(emulator: EmulatorFactory) -> Emulated:
    emulated = await emulator()
    await emulated.make_fast()
    return emulated


async def test_with_the_joystick_on_every_move_by_reads_its_start(
        emu: Emulated, caplog: pytest.LogCaptureFixture) -> None:
    tango = emu.tango
    await tango.move_to(x=1.0)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.move_by(x=0.5)
        assert emu.model.hdi_deflect(0, 0.25)  # a hand on the joystick: X at 1.75
        await tango.move_by(x=0.5)
    assert _reads_before_moves(_written(caplog)) == [True, True]
    # The nudge was honoured: the start was read, not remembered (1.5 + 0.5).
    assert (await tango.position())["x"] == pytest.approx(2.25)
    assert emulated_position(emu, "x") == pytest.approx(2.25)


async def test_with_the_joystick_off_a_move_by_starts_where_the_last_move_ended(
        emu: Emulated, caplog: pytest.LogCaptureFixture) -> None:
    tango = emu.tango
    await tango.set("joy", 0)
    assert not emu.model.hdi_deflect(0, 0.25)  # the HDI is off: a deflection does nothing
    await tango.move_to(x=1.0, y=2.0)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.move_by(x=0.5)
        await tango.move_by(x=-0.25, y=0.5)
        await tango.move_by(y=0.5)
    assert _reads_before_moves(_written(caplog)) == [False, False, False]
    assert (await tango.position())["x"] == pytest.approx(1.25)
    assert emulated_position(emu, "y") == pytest.approx(3.0)


async def test_any_other_line_makes_the_next_move_by_read_again(
        emu: Emulated, caplog: pytest.LogCaptureFixture) -> None:
    tango = emu.tango
    await tango.set("joy", 0)
    await tango.move_to(x=1.0)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.command("!pos x 5")  # redefines what ?pos prints
        await tango.move_by(x=0.5)
        await tango.move_by(x=0.5)
        await tango.set("joy", 2)  # the joystick on again
        await tango.move_by(x=0.5)
        await tango.move_by(x=0.5)
    assert _reads_before_moves(_written(caplog)) == [True, False, True, True]
    assert (await tango.position())["x"] == pytest.approx(7.0)


async def test_a_snapshot_mode_that_moves_keeps_the_read(
        emu: Emulated, caplog: pytest.LogCaptureFixture) -> None:
    tango = emu.tango
    await tango.set("snsm", 1)  # a snapshot event moves the stage (L14520-14530)
    await tango.set("joy", 0)
    await tango.move_to(x=1.0)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.move_by(x=0.5)
        await tango.move_by(x=0.5)
    assert _reads_before_moves(_written(caplog)) == [True, True]
