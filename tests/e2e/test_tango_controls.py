"""``tango-aio tango-server`` end to end: the Tango Controls device server in a subprocess
(``--nodb`` on 127.0.0.1) over the emulator on TCP (served by this test, which injects the
faults), driven by ``tango.DeviceProxy`` clients in processes of their own
(``tango_controls_client.py``).

What a client sees: ``MOVING`` from the write of ``Position`` to the driver's verdict, then
``ON`` with the final position, never ``ON`` beside a position from the middle of the move;
``ALARM`` with the reason in ``Status`` for a move that ended short; ``FAULT`` while the
link is lost; change events pushed without polling, the final ``Position`` before the final
``State``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import socket
import sys
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from helpers import make_model, wait_until

from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.motion import AxisConfig, MotionConfig
from tango_aio.sim.profiles import Firmware
from tango_aio.sim.serve import TcpServer, serve_tcp
from tango_aio.sim.wire import Emit

pytest.importorskip("tango", reason="the tango-controls extra (pytango) is not installed")

pytestmark = pytest.mark.timeout(180)

CLIENT = Path(__file__).with_name("tango_controls_client.py")
#: Generous: a bound that only catches a hang.
HANG = 60.0


@dataclass
class Client:
    """A client process: ``await client.ask(op=..., ...)``."""

    process: asyncio.subprocess.Process

    async def ask(self, **request: Any) -> dict[str, Any]:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write((json.dumps(request) + "\n").encode())
        await self.process.stdin.drain()
        async with asyncio.timeout(HANG):
            line = await self.process.stdout.readline()
        assert line, f"the client ended: {request}"
        answer: dict[str, Any] = json.loads(line)
        return answer

    async def events(self, until: str | None = None) -> list[list[Any]]:
        """The change events so far, once X's latest State event is ``until``."""
        events: list[list[Any]] = (await self.ask(op="events", until=until))["events"]
        return events


@dataclass
class Served:
    """The emulator (this process), the server (a subprocess) and the clients' base."""

    emulator: TcpServer
    port: int
    base: str
    server: asyncio.subprocess.Process | None = None
    _model: ControllerModel | None = None
    _model_of: TcpServer | None = None

    @property
    def model(self) -> ControllerModel:
        """The emulated controller (the same for every connection: the server's)."""
        if self._model is None or self._model_of is not self.emulator:
            handler = self.emulator.wires[0].handler
            assert isinstance(handler, ControllerModel)
            self._model, self._model_of = handler, self.emulator
        return self._model

    def moving(self) -> bool:
        return bool(self.emulator.wires) and self.model.motion.is_moving("x")

    def line(self, text: bytes) -> None:
        """A line reaching the controller from another host or its keypad."""
        self.model.handle_line(text, asyncio.get_running_loop().time())


@contextlib.asynccontextmanager
async def client_of(served: Served, suffix: str = "#dbase=no") -> AsyncIterator[Client]:
    process = await asyncio.create_subprocess_exec(
        sys.executable, str(CLIENT), served.base, suffix, stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE, limit=1 << 24)  # a line holds every sample read
    try:
        yield Client(process)
    finally:
        assert process.stdin is not None
        process.stdin.close()
        await ended(process)


async def ended(process: asyncio.subprocess.Process) -> None:
    """Wait until ``process`` has ended (killed if it hangs)."""
    try:
        async with asyncio.timeout(HANG):
            await process.wait()
    except TimeoutError:
        process.kill()
        await process.wait()


@contextlib.asynccontextmanager
async def serving(factory: Callable[[Emit], ControllerModel] = make_model, *,
                  database: int | None = None) -> AsyncIterator[Served]:
    """The emulator and the server (``database``: the port of a Tango database, else
    ``--nodb``)."""
    served = Served(await serve_tcp(factory), 0, "")
    port = served.port = served.emulator.port
    where = ["--nodb"] if database is None else ["--prefix", "lab/stage1"]
    environment = {**os.environ, "TANGO_HOST": f"127.0.0.1:{database}"} \
        if database is not None else None
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tango_aio", "tango-server", f"socket://127.0.0.1:{port}",
        *where, "--poll", "0.05", stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL, env=environment)
    served.server = process
    try:
        assert process.stdout is not None
        async with asyncio.timeout(HANG):
            line = (await process.stdout.readline()).decode()
        if database is None:
            found = re.search(r"tango://127\.0\.0\.1:(\d+)/NAME#dbase=no", line)
            assert found, line
            base = f"tango://127.0.0.1:{found[1]}/marzhauser/stage/"
        else:
            assert "as TangoAio/stage1" in line, line
            base = f"tango://127.0.0.1:{database}/lab/stage1/"
        served.base = base
        yield served
    finally:
        if process.returncode is None:
            process.terminate()
        await ended(process)
        served.emulator.close()  # the one serving now (a test may start a fresh one)
        await served.emulator.wait_closed()


def states(events: list[list[Any]], device: str = "x") -> list[str]:
    return [e[2] for e in events if e[0] == device and e[1] == "state"]


def final_position_before_final_state(events: list[list[Any]], position: float) -> None:
    mine = [e for e in events if e[0] == "x" and e[1] in ("state", "position")]
    last_state = max(i for i, e in enumerate(mine) if e[1] == "state")
    before = [e[2] for e in mine[:last_state] if e[1] == "position"]
    assert before and before[-1] == pytest.approx(position, abs=1e-3), mine
    assert all(e[1] != "position" for e in mine[last_state + 1:]), mine


def never_on_mid_move(rounds: list[dict[str, Any]], targets: list[float]) -> None:
    for target, result in zip(targets, rounds, strict=True):
        assert result["samples"][0][0] == "MOVING"  # the write returned with MOVING shown
        assert result["state"] == "ON" and result["position"] == pytest.approx(target)
        for state, position in result["samples"]:
            if state == "ON":
                assert position == pytest.approx(target), result["samples"]


async def moves_read_moving_then_on(rounds: int) -> None:
    async with serving() as served, client_of(served) as client:
        # No polling: the events are the server's own (a subscription needs one or the
        # other, API_AttributePollingNotStarted otherwise).
        assert (await client.ask(op="polled", attr="Position")) == {"polled": False}
        await client.ask(op="write", attr="Velocity", value=100.0)
        await client.ask(op="subscribe", attrs=["State", "Position"])
        targets = [float(2 * (i % 2) + 0.5 + i / 1000) for i in range(rounds)]
        answer = await client.ask(op="moves", targets=targets)
        never_on_mid_move(answer["rounds"], targets)
        events = await client.events(until="ON")
        assert states(events)[-1] == "ON"
        final_position_before_final_state(events, targets[-1])


async def test_a_move_reads_moving_then_on_with_the_final_position() -> None:
    await moves_read_moving_then_on(3)


@pytest.mark.slow
async def test_a_move_never_reads_on_with_an_intermediate_position_100_rounds() -> None:
    await moves_read_moving_then_on(100)


@pytest.mark.slow
async def test_change_events_arrive_without_polling() -> None:
    async with serving() as served, client_of(served) as client:
        assert (await client.ask(op="polled", attr="Position")) == {"polled": False}
        assert (await client.ask(op="polled", attr="State")) == {"polled": False}
        await client.ask(op="subscribe", attrs=["State", "Position", "Status"])
        await client.ask(op="write", attr="Position", value=3.0)  # 10 mm/s: 0.3 s
        result = await client.ask(op="until", leave=["MOVING"])
        assert result["state"] == "ON"
        events = await client.events(until="ON")
        assert states(events)[-2:] == ["MOVING", "ON"]
        positions = [e[2] for e in events if e[1] == "position"]
        # Some from mid-move; the final one is pushed again at the confirmation, also when
        # a poll read it already (under load the axis may stand before that).
        assert len(positions) >= 3 and any(0 < p < 3.0 for p in positions)
        final_position_before_final_state(events, 3.0)
        assert any(e[1] == "status" and "arrived" in e[2] for e in events)


@pytest.mark.slow
async def test_a_write_with_a_3_s_timeout_returns_on_a_30_s_move() -> None:
    async with serving() as served, client_of(served) as client:
        answer = await client.ask(op="write", attr="Position", value=300.0, timeout_ms=3000)
        assert answer == {"ok": True}  # no API_DeviceTimedOut
        assert (await client.ask(op="read", attrs=["State"]))["values"] == {"State": "MOVING"}
        await client.ask(op="command", name="Stop")
        result = await client.ask(op="until", leave=["MOVING"])
        assert result["state"] == "ALARM" and "ended short" in result["status"]


def shortened(emit: Emit) -> ControllerModel:
    """Limit switches at -5 and +5 mm."""
    axis = AxisConfig(e0_position=-5, ee_position=5)
    return ControllerModel(emit, SimConfig(motion=MotionConfig(n_axes=3, axes=(axis,) * 4)))


def stops_when_disabled(emit: Emit) -> ControllerModel:
    """An axis disabled while it moves stops (L3919-3960 leave it open)."""
    return ControllerModel(emit, SimConfig(
        firmware=Firmware.from_options("manual", disable_during_move="stop")))


async def injected(served: Served, other: Client, how: str) -> None:
    """End the running move of X the way ``how`` says."""
    if how == "stop":
        await other.ask(op="command", name="Stop")
    elif how == "abort by another client":
        await other.ask(device="controller", op="command", name="Abort")
    elif how == "disabled axis":
        served.line(b"!axis x 0")


ENDINGS: list[tuple[str, Callable[[Emit], ControllerModel], float, str, str]] = [
    # (how, emulator, target, final state, in Status)
    ("target", make_model, 4.0, "ON", "arrived"),
    ("limit switch", shortened, 8.0, "ALARM", "limit switch"),
    ("disabled axis", stops_when_disabled, 30.0, "ALARM", "ended short"),
    ("stop", make_model, 30.0, "ALARM", "ended short"),
    ("abort by another client", make_model, 30.0, "ALARM", "ended short"),
    ("refused line", make_model, 3.0, "ALARM", "ended short"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("how", "factory", "target", "state", "status"), ENDINGS,
                         ids=[ending[0] for ending in ENDINGS])
async def test_each_way_a_move_ends(how: str, factory: Callable[[Emit], ControllerModel],
                                    target: float, state: str, status: str) -> None:
    async with serving(factory) as served, client_of(served) as client, \
            client_of(served) as other:
        await client.ask(op="subscribe", attrs=["State", "Position"])
        if how == "refused line":
            served.line(b"!lim x -1 1")  # behind the server's back: the controller refuses
        await client.ask(op="write", attr="Position", value=target)
        if how in ("stop", "abort by another client", "disabled axis"):
            await wait_until(served.moving, timeout=HANG)
            await injected(served, other, how)
        result = await client.ask(op="until", leave=["MOVING"])
        assert result["state"] == state, result["status"]
        assert status in result["status"].lower()
        for seen, position in result["samples"]:
            if seen == "ON":
                assert position == pytest.approx(target)
        events = await client.events(until=state)
        assert states(events)[-2:] == ["MOVING", state]
        final_position_before_final_state(events, result["position"])


@pytest.mark.slow
async def test_a_lost_link_shows_fault_then_the_move_unproven() -> None:
    async with serving() as served, client_of(served) as client:
        await client.ask(op="subscribe", attrs=["State"])
        await client.ask(op="write", attr="Position", value=30.0)
        await wait_until(served.moving, timeout=HANG)
        served.emulator.close()
        await served.emulator.wait_closed()
        result = await client.ask(op="until", leave=["MOVING"])
        assert result["state"] == "FAULT" and "link" in result["status"]
        served.emulator = await serve_tcp(make_model, port=served.port)  # a fresh controller
        result = await client.ask(op="until", leave=["FAULT", "INIT"])
        assert result["state"] == "ALARM" and "ended short" in result["status"]
        seen = states(await client.events(until="ALARM"))
        assert seen[seen.index("FAULT"):][-1] == "ALARM" and "ON" not in seen[seen.index("FAULT"):]


@pytest.mark.slow
async def test_an_ophyd_async_tango_scan_reads_no_position_from_mid_move() -> None:
    pytest.importorskip("ophyd_async.tango")
    pytest.importorskip("bluesky")
    async with serving() as served:
        process = await asyncio.create_subprocess_exec(
            sys.executable, str(CLIENT.with_name("tango_controls_bluesky.py")),
            f"{served.base}x#dbase=no", stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.DEVNULL)
        async with asyncio.timeout(HANG * 2):
            out, _ = await process.communicate()
        assert process.returncode == 0
        scan = json.loads(out.decode().strip().splitlines()[-1])
        assert scan["readings"] == pytest.approx(scan["targets"])  # 0 mid-move readings


@contextlib.asynccontextmanager
async def tango_database(folder: Path) -> AsyncIterator[int]:
    """pytango's own database server (SQLite, in ``folder``) on a free loopback port."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tango.databaseds.database", "--port", str(port), "2",
        cwd=folder, env={**os.environ, "TANGO_HOST": f"127.0.0.1:{port}"},
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL)
    try:
        assert process.stdout is not None
        async with asyncio.timeout(HANG):
            while b"Ready to accept request" not in await process.stdout.readline():
                pass
        yield port
    finally:
        process.terminate()
        await ended(process)


@pytest.mark.slow
async def test_with_a_tango_database_the_devices_are_found_by_name(tmp_path: Path) -> None:
    async with tango_database(tmp_path) as port, serving(database=port) as served, \
            client_of(served, suffix="") as client:
        await client.ask(op="write", attr="Position", value=1.5)
        result = await client.ask(op="until", leave=["MOVING"])
        assert result["state"] == "ON" and result["position"] == pytest.approx(1.5)
        answer = await client.ask(device="controller", op="read", attrs=["Model"])
        assert answer["values"] == {"Model": "TANGO-DT"}


@pytest.mark.slow
async def test_a_terminated_server_stops_the_moves_it_started() -> None:
    async with serving() as served, client_of(served) as client:
        await client.ask(op="write", attr="Position", value=30.0)  # 10 mm/s: 3 s
        await wait_until(served.moving, timeout=HANG)
        assert served.server is not None
        served.server.terminate()
        await ended(served.server)
        assert served.server.returncode == 0
        await wait_until(lambda: not served.model.motion.is_moving("x"), timeout=HANG)
        motion = served.model.motion
        assert motion.to_user("x", motion.position("x")) < 29.0  # stopped on its way


@pytest.mark.skipif(sys.platform == "win32", reason="a console's Ctrl+C is no POSIX signal")
async def test_ctrl_c_ends_the_server_with_130_after_stopping_its_moves() -> None:
    # Tango's own signal thread takes SIGINT and shuts the server down; the controller
    # device notes it, so the command exits as every tango-aio command does after Ctrl+C.
    async with serving() as served, client_of(served) as client:
        await client.ask(op="write", attr="Position", value=30.0)  # 10 mm/s: 3 s
        await wait_until(served.moving, timeout=HANG)
        assert served.server is not None
        served.server.send_signal(signal.SIGINT)
        await ended(served.server)
        assert served.server.returncode == 130
        await wait_until(lambda: not served.model.motion.is_moving("x"), timeout=HANG)
