"""The IOC in one process, ophyd-async's stock ``epics.motor.Motor`` in another.

The IOC is ``tango-aio ioc sim://?baud=0`` (the command line), the client uses
ophyd-async with aioca (EPICS base's libca), both on loopback with free ports.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from importlib.util import find_spec
from pathlib import Path

import pytest

# Both sides run in subprocesses: look the packages up without importing them here (aioca
# and ophyd-async's EPICS side take about a second to import, in every xdist worker).
_MISSING = [name for name in ("caproto", "ophyd_async", "aioca") if find_spec(name) is None]
if _MISSING:
    pytest.skip(f"not installed: {', '.join(_MISSING)}", allow_module_level=True)

from test_epics import free_port, loopback_environment  # noqa: E402

pytestmark = pytest.mark.timeout(90)

CLIENT = """
import asyncio, json, sys
from ophyd_async.epics.motor import Motor

async def main(prefix):
    x = Motor(prefix + "X", name="x")
    await x.connect(timeout=20)
    out = {"egu": await x.motor_egu.get_value()}
    scan = []
    for target in (0.5, 1.0, 1.5, 2.0):
        await x.set(target)
        scan.append(await x.user_readback.get_value())
    out["scan"] = scan
    out["dmov"] = await x.motor_done_move.get_value()
    status = x.set(30.0)
    await asyncio.sleep(0.5)
    await x.stop(success=False)
    try:
        await status
        out["stopped_move"] = "completed"
    except Exception as exc:
        out["stopped_move"] = type(exc).__name__
    out["after_stop"] = await x.user_readback.get_value()
    print(json.dumps(out), flush=True)

asyncio.run(main(sys.argv[1]))
"""


@pytest.fixture
def environment() -> Iterator[dict[str, str]]:
    """The loopback CA environment of both processes; a UDP socket takes the beacons."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.bind(("127.0.0.1", 0))
        env = dict(os.environ, **loopback_environment(free_port()))
        env["EPICS_CAS_BEACON_PORT"] = env["EPICS_CA_REPEATER_PORT"] = \
            str(sink.getsockname()[1])
        yield env


def test_ophyd_async_motor_scans_and_stops_a_tango_axis(environment: dict[str, str],
                                                        tmp_path: Path) -> None:
    command = [sys.executable, "-m", "tango_aio", "ioc", "sim://?baud=0", "--prefix", "OPH:"]
    log = tmp_path / "ioc.log"
    with log.open("w") as errors, subprocess.Popen(
            command, env=environment, stdout=subprocess.PIPE, stderr=errors,
            text=True) as ioc:
        try:
            assert ioc.stdout is not None
            banner = ioc.stdout.readline()
            assert "OPH:X" in banner, log.read_text()
            client = subprocess.run([sys.executable, "-c", CLIENT, "OPH:"],
                                    env=environment, capture_output=True, text=True,
                                    timeout=60)
            assert client.returncode == 0, client.stderr + log.read_text()
            result = json.loads(client.stdout.strip().splitlines()[-1])
        finally:
            ioc.terminate()
            ioc.wait(timeout=10)
    assert result["egu"] == "mm"
    assert result["scan"] == pytest.approx([0.5, 1.0, 1.5, 2.0])
    assert result["dmov"] == 1
    assert result["stopped_move"] != "completed"
    assert 2.0 < result["after_stop"] < 30.0


def test_sigterm_ends_the_ioc_cleanly(environment: dict[str, str], tmp_path: Path) -> None:
    command = [sys.executable, "-m", "tango_aio", "ioc", "sim://?baud=0", "--prefix", "TRM:"]
    log = tmp_path / "ioc.log"
    with log.open("w") as errors, subprocess.Popen(
            command, env=environment, stdout=subprocess.PIPE, stderr=errors,
            text=True) as ioc:
        assert ioc.stdout is not None
        assert "TRM:X" in ioc.stdout.readline(), log.read_text()
        ioc.send_signal(signal.SIGTERM)
        assert ioc.wait(timeout=20) == 0, log.read_text()
    assert "Traceback" not in log.read_text()
