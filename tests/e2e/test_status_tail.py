"""A unit whose ``?statusaxis`` ends with ``.`` alone (switch ``status_tail=dot``): the
reply reads like a completion report (L2087-2089) instead of ending with the ``.-`` the
manual adds (L2668-2670). Found at connect from the raw lines of the mode read, and
served in every autostatus mode by reading the letters axis by axis (``sa x``, L2725)
(#37: every move raised ProtocolError there)."""

from __future__ import annotations

import pytest
from helpers import EmulatorFactory, emulated_position

from tango_aio.errors import MoveError

pytestmark = pytest.mark.virtual_clock

DOT = "sim://?baud=0&status_tail=dot"


@pytest.mark.parametrize("autostatus", [0, 1, 2, 3, 4])
async def test_a_unit_whose_statusaxis_ends_with_a_dot_is_served(
        emulator: EmulatorFactory, autostatus: int) -> None:
    emu = await emulator(DOT, travel=4.0, autostatus=autostatus)  # switches at +-2 mm
    tango, motion = emu.tango, emu.model.motion
    assert tango.identity.detected["status_tail"] == "dot"
    assert await tango.status() == dict(zip("xyz", motion.status_letters(), strict=False))
    assert await tango.move_to(x=1.0, y=-0.5) == {"x": "@", "y": "@", "z": "@"}
    assert (emulated_position(emu, "x"), emulated_position(emu, "y")) == pytest.approx(
        (1.0, -0.5), abs=1e-3)
    assert (await tango.move_by(y=0.25))["y"] == "@"
    assert emulated_position(emu, "y") == pytest.approx(-0.25, abs=1e-3)
    # A stop is read too: X at its switch ends the move of both axes at once.
    with pytest.raises(MoveError, match=r"X stopped at its upper limit switch") as raised:
        await tango.move_to(x=60.0, y=0.0)
    assert raised.value.statuses["x"] == "S"
    assert not any(motion.is_moving(a) for a in "xyz")
    assert (await tango.status())["x"] == motion.status_letters()[0] == "S"


@pytest.mark.parametrize(("url", "tail"), [("sim://?baud=0", "yes"),
                                           ("sim://?baud=0&status_tail=no", "no")])
async def test_the_other_tails_are_recorded_and_read_in_one_line(
        emulator: EmulatorFactory, url: str, tail: str) -> None:
    emu = await emulator(url)
    assert emu.tango.identity.detected["status_tail"] == tail
    assert not emu.tango._letters_by_axis
    assert await emu.tango.status() == {"x": "@", "y": "@", "z": "@"}
