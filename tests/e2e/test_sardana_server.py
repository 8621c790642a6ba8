"""The Sardana controller in a real Sardana server (Pool, MacroServer and Door in one
process) on pytango's Python database server (SQLite), everything on 127.0.0.1: ``mv``
and ``ascan`` through the Door, and a Tango Controls client that polls the motor during
a move never reads it ON short of its target. Slow: the server takes seconds to start."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tango_aio.sardana import POOL_PATH

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parents[2]
#: Generous bound that only catches a hang (starting the server takes seconds).
HANG = 180.0


@dataclass
class Server:
    """The running Sardana server and the names of its devices."""

    port: int
    tango: Any

    def proxy(self, name: str) -> Any:
        return self.tango.DeviceProxy(f"tango://127.0.0.1:{self.port}/{name}")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _until(check: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + HANG
    while not check():
        assert time.monotonic() < deadline, f"{what}: not within {HANG:.0f} s"
        time.sleep(0.1)


def _answers(call: Callable[[], Any], failure: type[BaseException]) -> bool:
    try:
        call()
    except failure:
        return False
    return True


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    pytest.importorskip("sardana", reason="Sardana is not installed (the sardana extra)")
    tango = pytest.importorskip("tango", reason="pytango is not installed")
    folder = tmp_path_factory.mktemp("sardana_server")
    port = _free_port()
    env = {**os.environ, "TANGO_HOST": f"127.0.0.1:{port}",
           "PYTANGO_DATABASE_NAME": str(folder / "tango.db"),
           "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [
               os.environ.get("PYTHONPATH")])])}
    started: list[subprocess.Popen[bytes]] = []

    def start(args: list[str], log: str) -> None:
        with (folder / log).open("wb") as out:
            started.append(subprocess.Popen(args, env=env, cwd=folder, stdout=out,
                                            stderr=subprocess.STDOUT))

    try:
        start([sys.executable, "-m", "tango.databaseds.database", "--host", "127.0.0.1",
               "--port", str(port), "2"], "database.log")
        _until(lambda: _answers(lambda: tango.Database("127.0.0.1", port).get_info(),
                                tango.DevFailed), "the database server")
        database = tango.Database("127.0.0.1", port)
        for device, klass in (("pool/t/1", "Pool"), ("macroserver/t/1", "MacroServer"),
                              ("door/t/1", "Door")):
            info = tango.DbDevInfo()
            info.name, info._class, info.server = device, klass, "Sardana/t"
            database.add_device(info)
        database.put_device_property("pool/t/1", {"PoolPath": [POOL_PATH]})
        database.put_device_property("macroserver/t/1", {
            "PoolNames": ["pool/t/1"], "EnvironmentDb": [str(folder / "environment")]})
        database.put_device_property("door/t/1", {"MacroServerName": ["macroserver/t/1"]})
        sardana_command = Path(sys.executable).with_name("Sardana")
        start([str(sardana_command), "t", "-ORBendPoint", "giop:tcp:127.0.0.1:0"],
              "sardana.log")
        running = Server(port, tango)
        _until(lambda: _answers(lambda: running.proxy("door/t/1").state(), tango.DevFailed),
               "the Sardana server")
        pool = running.proxy("pool/t/1")
        pool.CreateController(["Motor", "MarzhauserMotorCtrl.py", "MarzhauserMotorController",
                               "stage", "URL", "sim://?baud=0"])
        pool.CreateElement(["Motor", "stage", "1", "stx"])
        pool.CreateController(["CTExpChannel", "DummyCounterTimerController.py",
                               "DummyCounterTimerController", "counters"])
        pool.CreateElement(["CTExpChannel", "counters", "1", "ct01"])
        pool.CreateMeasurementGroup(["mntgrp", "ct01"])
        yield running
    finally:
        for process in reversed(started):
            process.terminate()
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def run_macro(server: Server, *macro: str, done: Callable[[], bool]) -> tuple[str, ...]:
    """Run a macro on the Door; return its output once ``done()`` and the Door is ON
    (the Door starts the macro in a thread of its own: its state alone may still read
    ON a moment after ``RunMacro``)."""
    door = server.proxy("door/t/1")
    door.RunMacro(list(macro))
    on = server.tango.DevState.ON
    _until(lambda: done() and door.state() == on, f"the macro {' '.join(macro)}")
    errors = door.read_attribute("Error").value
    assert not errors, errors
    return tuple(door.read_attribute("Output").value or ())


def test_mv_through_the_door_never_reads_on_short_of_the_target(server: Server) -> None:
    motor = server.proxy("stx")
    on = server.tango.DevState.ON
    motor.write_attribute("Velocity", 2.0)  # a move of seconds, for the client to watch
    assert motor.read_attribute("Velocity").value == pytest.approx(2.0)
    door = server.proxy("door/t/1")
    door.RunMacro(["mv", "stx", "5"])
    readings = []

    def finished() -> bool:
        state = motor.state()
        position = motor.read_attribute("Position").value
        readings.append((state, position))
        return bool(state == on and position == pytest.approx(5.0, abs=1e-3)
                    and door.state() == on)

    _until(finished, "mv stx 5")
    assert any(state != on for state, _ in readings), "never seen moving"
    for state, position in readings:
        if state == on:  # ON: at the start or at the target, never in between
            assert position == pytest.approx(0.0, abs=1e-3) or \
                position == pytest.approx(5.0, abs=1e-3), readings
    motor.write_attribute("Velocity", 100.0)


def test_ascan_through_the_door(server: Server) -> None:
    door = server.proxy("door/t/1")
    motor = server.proxy("stx")
    run_macro(server, "senv", "ActiveMntGrp", "mntgrp",
              done=lambda: bool(door.read_attribute("Output").value))
    output = run_macro(server, "ascan", "stx", "0", "2", "4", "0.01",
                       done=lambda: len(door.read_attribute("Output").value or ()) >= 6)
    header, *rows = output
    assert header.split()[:4] == ["#Pt", "No", "stx", "ct01"]
    assert [float(row.split()[1]) for row in rows] == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert motor.state() == server.tango.DevState.ON
    assert motor.read_attribute("Position").value == pytest.approx(2.0, abs=1e-3)
