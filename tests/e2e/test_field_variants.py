"""#32 item 4: firmware and link variants the driver refuses at connect, and calls that
fail while they have axes moving (they stop them, or say that they still move).

The variants the driver serves run in the firmware matrix (``tests/e2e/test_matrix.py``,
among them ``test_traffic_during_a_move``); the core's rules for them are tested in
``tests/unit/test_core.py``.
"""

from __future__ import annotations

import asyncio

import pytest
from helpers import EmulatorFactory, wait_moving

from tango_aio.connection import connect
from tango_aio.errors import ConnectError, ControllerError, TangoError
from tango_aio.testing import faults

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_local_echo_is_refused_at_connect_in_words(mode: int) -> None:
    # An adapter that echoes every byte sent: the copies would interleave with the
    # controller's replies, so connect fails, naming it (not "not a version reply").
    with pytest.raises(ConnectError, match="local echo"):
        async with asyncio.timeout(30):
            await connect("sim://?baud=0&local_echo=yes", autostatus=mode,
                          reply_timeout=1.0)


async def test_a_lost_state_read_stops_the_move_or_says_it_still_runs(
        emulator: EmulatorFactory) -> None:
    # Autostatus 0 polls the state during the move; every poll's reply is lost, so the
    # move cannot be followed. It must not leave X running without a word.
    emu = await emulator("sim://?baud=0", autostatus=0, reply_timeout=0.3, dead_after=100)
    tango = emu.tango
    await tango.set("vel", 1.0, axis="x")
    move = asyncio.create_task(tango.move_to(x=4.0))
    await wait_moving(emu, "x")
    faults(tango).drop(6)  # three state reads (statusaxis and pos) in a row
    with pytest.raises(TangoError) as info:
        async with asyncio.timeout(30):
            await move
    message = str(info.value)
    assert message.endswith(("; axes stopped", "; axes X may still move")), message
    if message.endswith("axes stopped"):
        position, velocity = faults(tango).axes()["x"]
        assert velocity == 0.0 and position < 4.0
    await tango.set("vel", 50.0, axis="x")
    await tango.move_to(x=0.5)  # the next call works


@pytest.mark.parametrize("mode", [1, 2])
async def test_speed_whose_answer_is_lost_stops_its_axes(emulator: EmulatorFactory,
                                                         mode: int) -> None:
    emu = await emulator("sim://?baud=0", autostatus=mode, reply_timeout=0.3,
                         dead_after=100)
    tango = emu.tango
    faults(tango).drop(1)  # the speed line's check: ?err, or its OK... in mode 2
    with pytest.raises(TangoError) as info:
        await tango.speed(z=1.0)
    assert not isinstance(info.value, ControllerError)
    assert str(info.value).endswith("; axes Z stopped"), info.value
    assert faults(tango).axes()["z"][1] == 0.0
    await tango.speed(y=0.5)  # the next call works
    await tango.speed(y=0.0)
