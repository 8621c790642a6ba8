"""Use the emulator in your own pytest tests, as a fixture.

Copy the ``tango`` fixture into your ``conftest.py``: every test gets a fresh emulated
controller in its own event loop (``sim://?baud=0`` skips the wire pacing so tests are
fast; moves still run in real time at the configured speeds). The fixture and tests use
pytest-asyncio (``pip install pytest-asyncio``) with explicit markers, so they also work
without ``asyncio_mode = "auto"``.

This file is both a test module and a script; run it either way:

    python -m pytest examples/pytest_fixture_example.py
    python examples/pytest_fixture_example.py
"""

from __future__ import annotations

import sys
from collections.abc import AsyncIterator

import pytest
import pytest_asyncio

import tango_aio


@pytest_asyncio.fixture
async def tango() -> AsyncIterator[tango_aio.Controller]:
    """A controller connected to a fresh in-process emulator, closed after the test."""
    controller = await tango_aio.connect("sim://?baud=0")
    try:
        yield controller
    finally:
        await controller.aclose()


@pytest.mark.asyncio
async def test_identifies_as_a_tango(tango: tango_aio.Controller) -> None:
    assert tango.identity is not None
    assert tango.identity.model == "TANGO-DT"
    assert tango.identity.axes == 3


@pytest.mark.asyncio
async def test_move_reaches_the_target(tango: tango_aio.Controller) -> None:
    letters = await tango.move_to(x=1.5, y=-0.5)
    assert letters == {"x": "@", "y": "@", "z": "@"}
    position = await tango.position()
    assert position["x"] == pytest.approx(1.5)
    assert position["y"] == pytest.approx(-0.5)


@pytest.mark.asyncio
async def test_settings_round_trip_and_errors(tango: tango_aio.Controller) -> None:
    await tango.set("vel", 12.5, axis="y")
    assert await tango.get("vel", axis="y") == 12.5
    with pytest.raises(tango_aio.ControllerError) as caught:  # refused by the controller
        await tango.command("!moa x 1000000")
    assert caught.value.error_code == 5
    with pytest.raises(tango_aio.InvalidCommandError):  # refused before sending
        await tango.set("vel", -1, axis="x")


if __name__ == "__main__":
    # Run as a script, this file has imported pytest_asyncio before pytest starts, so pytest
    # cannot assertion-rewrite that plugin and warns (an error under this repository's
    # ``filterwarnings = error``); that warning is harmless here.
    sys.exit(pytest.main([__file__, "-q", "-p", "no:cacheprovider",
                          "-W", "ignore::pytest.PytestAssertRewriteWarning"]))
