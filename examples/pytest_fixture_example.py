"""Use the emulator in your own pytest tests: the ``tango_emulator`` fixture.

Installing tango-aio registers the pytest plugin :mod:`tango_aio.testing`, so nothing needs
copying into your ``conftest.py``: ask for ``tango_emulator`` and every test gets a fresh
emulated controller (``.tango``) with a fault-injection handle (``.faults``), closed after
the test. Options come from a marker (``@pytest.mark.tango_emulator(axes=2)``), the command
line (``--tango-profile legacy --tango-axes 2 --tango-speed real``) or the ini file. The
async fixtures use pytest-asyncio (explicit markers here, so this also works without
``asyncio_mode = "auto"``); ``tango_emulator_sync`` gives a blocking controller instead.

This file is both a test module and a script; run it either way:

    python -m pytest examples/pytest_fixture_example.py
    python examples/pytest_fixture_example.py
"""

from __future__ import annotations

import sys

import pytest

import tango_aio
from tango_aio.testing import Emulated, EmulatedSync


@pytest.mark.asyncio
@pytest.mark.tango_emulator(axes=2)
async def test_moves_and_settings(tango_emulator: Emulated) -> None:
    tango = tango_emulator.tango
    assert tango.identity.model == "TANGO-DT"
    assert tango.identity.axes == 2
    assert await tango.move_to(x=1.5, y=-0.5, unit="mm") == {"x": "@", "y": "@"}
    assert await tango.position() == pytest.approx({"x": 1.5, "y": -0.5})
    await tango.set("vel", 12.5, axis="y")
    assert await tango.get("vel", axis="y") == 12.5
    with pytest.raises(tango_aio.ControllerError) as caught:  # refused by the controller
        await tango.command("!moa x 1000000")
    assert caught.value.number == 5
    with pytest.raises(tango_aio.InvalidCommandError):  # refused before sending
        await tango.set("vel", -1, axis="x")


@pytest.mark.asyncio
async def test_a_lost_reply_fails_one_request_only(tango_emulator: Emulated) -> None:
    tango = tango_emulator.tango
    tango_emulator.faults.drop()  # the next reply never arrives
    # The lost reply may be the request's own (ControllerTimeoutError after 0.3 s) or the
    # one of a separator line the driver wrote before it (RequestAbortedError, at once).
    with pytest.raises((tango_aio.ControllerTimeoutError, tango_aio.RequestAbortedError)):
        await tango.get("pos", timeout=0.3)
    assert await tango.status() == {"x": "@", "y": "@", "z": "@"}  # the next call works
    tango_emulator.faults.disconnect()
    with pytest.raises(tango_aio.ConnectionLostError):
        await tango.get("pos")


def test_blocking_controller(tango_emulator_sync: EmulatedSync) -> None:
    tango = tango_emulator_sync.tango
    future = tango.start_move_to(x=2.0)  # returns at once
    tango.wait_idle()
    assert future.result() == {"x": "@", "y": "@", "z": "@"}
    assert tango.position(unit="um")["x"] == pytest.approx(2000.0)


if __name__ == "__main__":
    # Run as a script, this file has imported pytest_asyncio before pytest starts, so pytest
    # cannot assertion-rewrite that plugin and warns (an error under this repository's
    # ``filterwarnings = error``); that warning is harmless here.
    sys.exit(pytest.main([__file__, "-q", "-p", "no:cacheprovider",
                          "-W", "ignore::pytest.PytestAssertRewriteWarning"]))
