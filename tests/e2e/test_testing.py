"""tango_aio.testing (issue 15 item 7): the pytest plugin and the fault-injection handle."""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import textwrap
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from helpers import make_model, serve_pty, wait_until

import tango_aio
from tango_aio.testing import Emulated, EmulatedSync, emulator_url, faults

#: What a request whose reply ``drop()`` loses may raise: the request's own reply lost
#: (``ControllerTimeoutError`` at its timeout), or the reply of the separator line the
#: driver wrote before it (the request's reply then arrives where the separator's was
#: expected: the driver cannot tell it from a stray line, resyncs and aborts the request).
LOST_REPLY = (tango_aio.ControllerTimeoutError, tango_aio.RequestAbortedError)


def test_the_plugin_is_registered_by_its_entry_point(request: pytest.FixtureRequest) -> None:
    assert request.config.pluginmanager.hasplugin("tango_aio")


async def test_default_emulator(tango_emulator: Emulated) -> None:
    assert tango_emulator.tango.identity.axes == 3
    assert "profile=manual" in tango_emulator.url and "baud=0" in tango_emulator.url
    assert (await tango_emulator.tango.get("vel"))["x"] == 100.0  # speed "fast"


@pytest.mark.tango_emulator(axes=1, speed="instant-line")
async def test_marker_options(tango_emulator: Emulated) -> None:
    assert tango_emulator.tango.identity.axes == 1
    assert (await tango_emulator.tango.get("vel"))["x"] != 100.0


async def test_factory(tango_emulator_factory: Callable[..., Awaitable[Emulated]]) -> None:
    one = await tango_emulator_factory(axes=2)
    two = await tango_emulator_factory(axes=4, speed="real")
    assert (one.tango.identity.axes, two.tango.identity.axes) == (2, 4)
    assert "baud=57600" in two.url


def test_sync_fixture(tango_emulator_sync: EmulatedSync) -> None:
    tango = tango_emulator_sync.tango
    # The resync marker after the lost reply shares its 0.3 s: late on a loaded machine, it
    # is written again rather than the link declared dead.
    tango.aio.protocol.session.dead_after = 10
    assert tango.move_to(x=3) == {"x": "@", "y": "@", "z": "@"}
    tango_emulator_sync.faults.drop()
    with pytest.raises(LOST_REPLY):
        tango.get("pos", timeout=0.3)
    assert tango.position()["x"] == 3.0


async def test_drop_garble_noise_stall_delay_disconnect(tango_emulator: Emulated) -> None:
    tango, handle = tango_emulator.tango, tango_emulator.faults
    tango.protocol.session.dead_after = 10  # a late marker is written again (as above)
    handle.drop()
    with pytest.raises(LOST_REPLY):
        await tango.get("pos", timeout=0.3)
    assert handle.wire.dropped_replies == 1
    handle.garble(2)
    for _ in range(2):  # each garbled reply is consumed: a value, or a typed error
        with contextlib.suppress(tango_aio.TangoError):
            await tango.get("vel", timeout=0.5)
    assert handle.wire.faults.garble_replies == 0
    # A garbled reply that no longer fits its request starts a resync, and the second
    # garbled reply may then be the resync marker's: unrecognisable, so the resync waits
    # for its deadline and drops every line meanwhile. A fresh marker ends it at once.
    await tango.protocol.resync()
    events = tango.events()
    handle.noise(b"junk that nobody asked for\r")  # while idle: an unsolicited line
    event = await anext(events)
    assert isinstance(event, tango_aio.UnsolicitedLine)
    assert event.line == "junk that nobody asked for"
    assert (await tango.get("vel"))["y"] == 100.0  # the stream stays in step
    handle.stall(0.2)
    assert (await tango.get("vel"))["z"] == 100.0  # answered after the stall
    handle.delay(0.1)
    assert await tango.status() == {"x": "@", "y": "@", "z": "@"}
    assert handle.model.axes == 3
    handle.disconnect()
    with pytest.raises(tango_aio.ConnectionLostError):
        await tango.get("pos")
    for bad in (0, -1, True):
        with pytest.raises(ValueError):
            handle.drop(bad)


async def test_faults_of_a_real_link_is_refused() -> None:
    async with tango_aio.connect("sim://?baud=0") as tango:
        assert faults(tango).wire.lines_processed > 0
    async with await serve_pty(make_model) as server, tango_aio.connect(server.path) as tango:
        with pytest.raises(TypeError, match="not an emulated"):
            faults(tango)  # a serial port: no emulated wire in this process


def test_emulator_url_checks_its_options() -> None:
    assert emulator_url(axes=2, speed="real", echo="after").startswith("sim://?profile=manual")
    with pytest.raises(ValueError, match="speed"):
        emulator_url(speed="warp")
    with pytest.raises(ValueError, match="axes"):
        emulator_url(axes=5)


#: pytest in a user's project. Sardana's plugin (an extra of this environment, not of the
#: user's) would import taurus and sardana for nothing, as pyproject's addopts says.
PYTEST = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
          "-p", "no:sardana_pool_plugins"]


def test_command_line_options(tmp_path: Path) -> None:
    test_file = tmp_path / "test_cli_options.py"
    test_file.write_text(textwrap.dedent('''
        import pytest

        @pytest.mark.asyncio
        async def test_axes(tango_emulator):
            assert tango_emulator.tango.identity.axes == 2
            assert "baud=57600" in tango_emulator.url
    '''))
    result = subprocess.run(
        [*PYTEST, "--tango-axes", "2",
         "--tango-speed", "real", str(test_file)],
        capture_output=True, text=True, timeout=120, check=False, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout


@pytest.mark.tango_emulator(speed="instant-line")
async def test_axes_tell_where_the_emulated_axes_really_are(tango_emulator: Emulated) -> None:
    tango, handle = tango_emulator.tango, tango_emulator.faults
    move = asyncio.create_task(tango.move_to(z=5.0))  # about 0.5 s at 10 rev/s
    await wait_until(lambda: handle.axes()["z"][1] != 0.0 or move.done())  # it started
    position, velocity = handle.axes()["z"]
    assert velocity > 0.0 and 0.0 <= position < 5.0
    await move
    assert handle.axes()["z"] == (5.0, 0.0)
    assert handle.axes()["x"] == (0.0, 0.0)


def test_the_readme_example_passes(tmp_path: Path) -> None:
    """The README's "The emulator in your own tests" block, run as a user's test module."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    section = readme.split("### The emulator in your own tests", 1)[1]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    test_file = tmp_path / "test_readme_example.py"
    test_file.write_text(code)
    result = subprocess.run(
        [*PYTEST, str(test_file)],
        capture_output=True, text=True, timeout=120, check=False, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout
