"""#32 item 4: firmware and link variants the driver refuses at connect, and calls that
fail while they have axes moving (they stop them, or say that they still move).

The variants the driver serves run in the firmware matrix (``tests/e2e/test_matrix.py``,
among them ``test_traffic_during_a_move``); the core's rules for them are tested in
``tests/unit/test_core.py``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
from helpers import EmulatorFactory, serve_pty, wait_moving, wait_until

from tango_aio.controller._connection import connect
from tango_aio.errors import ConnectError, ControllerError, TangoError
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import Firmware
from tango_aio.sim.wire import Emit, WireConfig
from tango_aio.testing import faults

pytestmark = [pytest.mark.timeout(60), pytest.mark.virtual_clock]


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_local_echo_is_refused_at_connect_in_words(mode: int) -> None:
    # An adapter that echoes every byte sent: the copies would interleave with the
    # controller's replies, so connect fails, naming it (not "not a version reply").
    with pytest.raises(ConnectError, match="local echo"):
        async with asyncio.timeout(30):
            await connect("sim://?baud=0&local_echo=yes", autostatus=mode,
                          reply_timeout=5.0)  # replies come: a bound on a hang


def left_in(mode: int, profile: str, local_echo: str) -> Callable[[Emit], ControllerModel]:
    """Handler factory of a controller that an earlier program left in autostatus
    ``mode``, behind a link with local echo or without."""
    firmware = Firmware.from_options(profile, local_echo=local_echo)

    def factory(emit: Emit) -> ControllerModel:
        model = ControllerModel(emit, SimConfig(firmware=firmware))
        model.set_autostatus(mode)
        return model
    return factory


async def connect_through_pty(factory: Callable[[Emit], ControllerModel],
                              wanted: int | None) -> int:
    """Connect through the pty emulator selecting ``wanted``; return the mode in force
    once connected (on the driver's side and the emulator's)."""
    server = await serve_pty(factory, WireConfig(baud=0))
    try:
        async with asyncio.timeout(30), \
                connect(server.path, autostatus=wanted, reply_timeout=5.0) as tango:
            handler = server.wire.handler
            assert isinstance(handler, ControllerModel)
            assert handler.autostatus == tango.autostatus
            return tango.autostatus
    finally:
        server.close()
        await server.wait_closed()


@pytest.mark.parametrize("profile", ["manual", "legacy"])
@pytest.mark.parametrize("left", [0, 1, 2, 3, 4])
async def test_local_echo_is_refused_whatever_mode_the_unit_was_left_in(
        profile: str, left: int) -> None:
    # A unit left in mode 4 used to connect behind a local-echo adapter: mode 4 may echo
    # reads itself (legacy: echo_all, old L723), or not (1.71, L2117), so the adapter's
    # copy of a read passed for the controller's echo (and in mode 2 under
    # ack_reads=before for an acknowledgement). Selecting mode 0 or 3 is like 1
    # (test_local_echo_is_refused_at_connect_in_words); None keeps the unit's mode. The
    # TCP emulator, under every variant: tests/e2e/test_matrix.py,
    # test_local_echo_is_refused_at_connect_in_every_mode.
    for wanted in (None, 1, 2, 4):
        with pytest.raises(ConnectError, match="local echo"):
            await connect_through_pty(left_in(left, profile, "yes"), wanted)
    # Without local echo the same unit connects, in the mode it was left in.
    assert await connect_through_pty(left_in(left, profile, "no"), None) == left


@pytest.mark.parametrize("profile", ["manual", "legacy"])
@pytest.mark.parametrize("echo", ["before", "after", "completion"])
async def test_a_unit_left_in_mode_4_connects_whatever_its_echo_order(
        profile: str, echo: str) -> None:
    # Connect detects how ``?help N`` answers while the unit may still be in mode 4; with
    # the echo of a read after its reply (echo=after; legacy echoes reads, old L723) the
    # ``?err`` behind ``?help N`` ends with its own echo, and the ``?err`` number once
    # passed for help's text: every later marker then waited for that number.
    firmware = Firmware.from_options(profile, echo=echo)

    def factory(emit: Emit) -> ControllerModel:
        model = ControllerModel(emit, SimConfig(firmware=firmware))
        model.set_autostatus(4)
        return model

    for wanted in (None, 1, 4):
        assert await connect_through_pty(factory, wanted) == (4 if wanted is None
                                                              else wanted)


# Slow tier: the drops leave a resync of many markers behind (about 6 s).
@pytest.mark.slow
async def test_a_lost_state_read_stops_the_move_or_says_it_still_runs(
        emulator: EmulatorFactory) -> None:
    # Autostatus 0 polls the state during the move; every poll's reply is lost, so the
    # move cannot be followed. It must not leave X running without a word.
    emu = await emulator("sim://?baud=0", autostatus=0, dead_after=100)
    tango = emu.tango
    await tango.set("vel", 1.0, axis="x")
    tango.reply_timeout = 0.3  # short for the lost replies: the move's polls from now on
    move = asyncio.create_task(tango.move_to(x=4.0))
    await wait_moving(emu, "x")
    # The next 20 replies are lost, the resyncs' markers among them: the state reads
    # (statusaxis and pos) fail three times in a row whatever the loop's timing (with six,
    # under uvloop the markers once took enough that the third read came back). Lines
    # queued behind that resync go out at its end, and the next call must still work.
    faults(tango).drop(20)
    with pytest.raises(TangoError) as info:
        async with asyncio.timeout(30):
            await move
    message = str(info.value)
    assert message.endswith(("; axes stopped", "; axes X may still move")), message
    if message.endswith("axes stopped"):
        position, velocity = faults(tango).axes()["x"]
        assert velocity == 0.0 and position < 4.0
    await wait_until(lambda: faults(tango).wire.faults.drop_replies == 0, timeout=30.0)
    tango.reply_timeout = 5.0  # the replies from here on come
    await tango.set("vel", 50.0, axis="x")
    await tango.move_to(x=0.5)  # the next call works


@pytest.mark.parametrize("mode", [1, 2])
async def test_speed_whose_answer_is_lost_stops_its_axes(emulator: EmulatorFactory,
                                                         mode: int) -> None:
    emu = await emulator("sim://?baud=0", autostatus=mode, dead_after=100)
    tango = emu.tango
    faults(tango).drop(1)  # the speed line's check: ?err, or its OK... in mode 2
    tango.reply_timeout = 0.3  # short for the lost reply only
    with pytest.raises(TangoError) as info:
        await tango.speed(z=1.0)
    tango.reply_timeout = 5.0  # the replies from here on come
    assert not isinstance(info.value, ControllerError)
    assert str(info.value).endswith("; axes Z stopped"), info.value
    assert faults(tango).axes()["z"][1] == 0.0
    await tango.speed(y=0.5)  # the next call works
    await tango.speed(y=0.0)
