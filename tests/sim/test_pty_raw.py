"""The emulator over a real pty (and TCP), spoken to with raw pyserial, without our driver.

A host program such as the Micro-Manager TANGO adapter opens the port at 57600 8N2 and
exchanges plain lines; these tests do the same in a worker thread while the emulator runs
on the event loop in real time (57600 Bd pacing, 256-byte input buffer).
"""

from __future__ import annotations

import asyncio
import re
import time
from collections.abc import Callable

import pytest
import serial
from helpers import serve_pty

from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import PROFILES
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import Emit, Wire, WireConfig

from .test_serve import asked_in_loop, ctrl_c_done, read_until_settled

pytestmark = pytest.mark.timeout(30)


def controller(axes: int = 3, profile: str = "manual") -> Callable[[Emit], ControllerModel]:
    """A handler factory: a fresh emulated controller per wire."""
    sim = SimConfig(axes=axes, firmware=PROFILES[profile])

    def make(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, sim)

    return make


def model_of(wire: Wire) -> ControllerModel:
    handler = wire.handler
    assert isinstance(handler, ControllerModel)
    return handler


class Host:
    """A raw line-based host on a pyserial port."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port

    def line(self) -> str:
        """One reply line; fails instead of hanging when none comes."""
        data = self.port.read_until(b"\r")
        assert data.endswith(b"\r"), f"no complete reply line, got {data!r}"
        return data[:-1].decode("ascii")

    def ask(self, text: str) -> str:
        self.port.write(text.encode("ascii") + b"\r")
        return self.line()

    def tell(self, text: str) -> None:
        """A line that owes no reply (autostatus 0/1 set instructions)."""
        self.port.write(text.encode("ascii") + b"\r")

    def quiet(self, seconds: float = 0.3) -> bytes:
        """Everything that arrives until the port stays silent for ``seconds``."""
        timeout = self.port.timeout
        self.port.timeout = seconds
        try:
            out = b""
            while chunk := self.port.read(4096):
                out += chunk
            return out
        finally:
            self.port.timeout = timeout

    def wait_idle(self, limit: float = 10.0, poll: str = "?statusaxis") -> list[str]:
        """Poll ``?statusaxis`` (or ``poll``: ``sa``) until no axis shows ``M``; returns
        the polled replies."""
        seen: list[str] = []
        deadline = time.monotonic() + limit
        while time.monotonic() < deadline:
            status = self.ask(poll)
            assert re.fullmatch(r"[@MJSADET-]{4}\.-", status), status
            seen.append(status)
            if "M" not in status:
                return seen
            time.sleep(0.02)
        raise AssertionError(f"axes still moving after {limit} s: {seen[-3:]}")



def open_port(path: str) -> serial.Serial:
    return serial.Serial(path, 57600, stopbits=serial.STOPBITS_TWO, timeout=2)


async def test_micro_manager_style_session() -> None:
    async with await serve_pty(controller()) as server:

        def host() -> dict[str, object]:
            with open_port(server.path) as port:
                tango = Host(port)
                out: dict[str, object] = {"version": tango.ask("?version")}
                tango.tell("!autostatus 0")
                out["det"] = tango.ask("?det")
                out["pitch"] = tango.ask("?pitch x")
                tango.tell("!dim 1 1")
                tango.tell("!moa 10 5")
                out["err"] = tango.ask("?err")
                out["polls"] = tango.wait_idle()
                out["pos"] = tango.ask("?pos")
                tango.tell("MOA Z 10")
                out["err2"] = tango.ask("?err")
                out["polls2"] = tango.wait_idle()
                out["pos2"] = tango.ask("?POS Z")
                out["stray"] = tango.quiet()
                return out

        out = await asyncio.to_thread(host)
        model = model_of(server.wire)
    assert out["version"] == "TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00"
    assert out["det"] == "10288"
    assert out["pitch"] == "1.0000"
    assert out["err"] == "0"
    assert out["err2"] == "0"
    polls = out["polls"]
    assert isinstance(polls, list) and polls[-1] == "@@@-.-"
    assert out["pos"] == "10.0 5.0 0.0000"  # dim 1: 0.1 µm with resolution 4 (L4160)
    polls2 = out["polls2"]
    assert isinstance(polls2, list) and "@@M-.-" in polls2 and polls2[-1] == "@@@-.-"
    assert out["pos2"] == "10.0000"
    assert out["stray"] == b""  # autostatus 0: no completion string ever came
    assert model.internal_errors == []
    assert server.wire.lost_bytes == 0


async def test_default_autostatus_reports_over_the_pty() -> None:
    async with await serve_pty(controller()) as server:

        def host() -> list[str]:
            with open_port(server.path) as port:
                tango = Host(port)
                start = time.monotonic()
                tango.tell("!moa 2 1")
                report = tango.line()
                elapsed = time.monotonic() - start
                tango.tell("!autostatus 2")
                ack = tango.line()
                tango.tell("!vel -1")
                nack = tango.line()
                return [report, f"{elapsed:.3f}", ack, nack, tango.ask("?err")]

        report, elapsed, ack, nack, err = await asyncio.to_thread(host)
    assert report == "@@@-."
    assert float(elapsed) >= 0.2  # 2 mm at 10 mm/s
    assert (ack, nack, err) == ("OK...", "ERR 5", "5")


async def test_overflow_loses_bytes_of_a_blasted_trigp_list() -> None:
    entries = 300
    blast = b"".join(f"!trigp -1 {i / 100:.2f}\r".encode() for i in range(1, entries + 1))
    config = WireConfig(processing_time_per_line=0.005)  # slower than the line rate
    async with await serve_pty(controller(), config) as server:
        wire = server.wire
        port = await asyncio.to_thread(open_port, server.path)
        try:
            await asyncio.to_thread(port.write, blast)
            idle = 0
            for _ in range(500):  # until the controller has taken in everything
                idle = idle + 1 if wire.rx_pending == 0 and not wire.busy else 0
                if idle >= 10:
                    break
                await asyncio.sleep(0.01)
            tango = Host(port)
            # A lost CR may leave a partial line in the buffer: end it first, as a host
            # recovering from an overrun must (it sets an error, answers nothing).
            await asyncio.to_thread(tango.tell, "")
            count = await asyncio.to_thread(tango.ask, "?trigc")
            err = await asyncio.to_thread(tango.ask, "?err")
        finally:
            await asyncio.to_thread(port.close)
        model = model_of(wire)
    assert wire.lost_bytes > 0
    assert 0 < int(count) < entries
    assert re.fullmatch(r"\d+", err)
    assert model.triggers.count() == int(count)
    assert model.internal_errors == []


async def test_paced_trigp_upload_loses_nothing() -> None:
    """The manual's advice: read back ?trigc after each !trigp (L14091-14097)."""
    config = WireConfig(processing_time_per_line=0.005)
    async with await serve_pty(controller(), config) as server:

        def host() -> list[str]:
            with open_port(server.path) as port:
                tango = Host(port)
                return [tango.ask(f"!trigp -1 {i}\r?trigc") for i in range(1, 21)]

        counts = await asyncio.to_thread(host)
        assert server.wire.lost_bytes == 0
    assert counts == [str(i) for i in range(1, 21)]


async def test_ctrl_c_stops_and_discards_queued_input() -> None:
    config = WireConfig(processing_time_per_line=0.05)
    async with await serve_pty(controller(), config) as server:
        # The emulator's own state, asked from the host's thread (no time is assumed).
        moving = asked_in_loop(lambda: model_of(server.wire).motion.is_moving("x")
                               and not server.wire.busy)  # and its line done
        stopped_all = asked_in_loop(lambda: ctrl_c_done(lambda: [server.wire])
                                    and not model_of(server.wire).motion.is_moving("x"))

        def host() -> tuple[bytes, str, str]:
            with open_port(server.path) as port:
                tango = Host(port)
                tango.tell("!moa 30")
                deadline = time.monotonic() + 30.0  # a bound on a hang only
                while not moving():  # under way (a 3 s move), the interpreter free
                    assert time.monotonic() < deadline, "x did not start moving"
                    time.sleep(0.005)
                # ?pos keeps the interpreter busy for 50 ms; '!moa y 5' waits behind it
                # in the input buffer when Ctrl+C arrives, and is discarded.
                port.write(b"?pos\r!moa y 5\r\x03")
                port.timeout = 0.3
                stopped = read_until_settled(lambda: port.read(4096), stopped_all)
                port.timeout = 2
                return stopped, tango.ask("?pos y"), tango.ask("sa")

        stopped, pos_y, status = await asyncio.to_thread(host)
        assert server.wire.ctrl_c_count == 1
    assert re.fullmatch(rb"\d+\.\d{4} 0\.0000 0\.0000\rE@@-\.\r", stopped), stopped
    assert pos_y == "0.0000"
    assert status == "E@@-.-"


async def test_tcp_socket_url_round_trip() -> None:
    async with await serve_tcp(controller()) as server:

        def host() -> list[str]:
            port = serial.serial_for_url(f"socket://127.0.0.1:{server.port}", timeout=2)
            try:
                tango = Host(port)
                replies = [tango.ask("?version 1"), tango.ask("?pitch")]
                tango.tell("!moa 1")
                replies.append(tango.line())
                replies.append(tango.ask("?pos x"))
                return replies
            finally:
                port.close()

        replies = await asyncio.to_thread(host)
    assert replies == ["1.71", "1.0000 1.0000 1.0000", "@@@-.", "1.0000"]


@pytest.mark.parametrize("profile", ["manual", "legacy"])
async def test_micro_manager_adapter_shaped_session(profile: str) -> None:
    """What Micro-Manager's TANGO adapter does: a bare CR to flush the controller's line
    at start, ``?err`` after every set, moves polled with ``?statusaxis``, ``?pos``
    reads; autostatus stays at its power-on 1 except where the adapter turns it off."""
    async with await serve_pty(controller(profile=profile)) as server:

        def host() -> dict[str, object]:
            with open_port(server.path) as port:
                tango = Host(port)
                port.write(b"\r")  # flush whatever a previous session left half-typed
                out: dict[str, object] = {"flush": tango.quiet(0.2)}
                out["version"] = tango.ask("?version")
                sets = ["!autostatus 0", "!dim 2 2 2", "!vel 20 20 20", "!accel 1 1 1"]
                out["set_errors"] = [tango.ask(f"{line}\r?err") for line in sets]
                moves = []
                for target in ("5 2.5", "-1.25 0", "0.5 0.5"):
                    err = tango.ask(f"!moa {target}\r?err")
                    polls = tango.wait_idle()
                    moves.append((err, polls[-1], tango.ask("?pos x"), tango.ask("?pos y")))
                out["moves"] = moves
                out["relative"] = tango.ask("!mor y 1\r?err")
                out["rel_poll"] = tango.wait_idle()[-1]
                out["pos"] = tango.ask("?pos")
                out["stray"] = tango.quiet()
                return out

        out = await asyncio.to_thread(host)
        model = model_of(server.wire)
    assert out["flush"] == b""
    assert str(out["version"]).startswith("TANGO-DT, Version 1.71, Jun  4 2019")
    assert out["set_errors"] == ["0"] * 4
    assert out["moves"] == [("0", "@@@-.-", "5.0000", "2.5000"),
                            ("0", "@@@-.-", "-1.2500", "0.0000"),
                            ("0", "@@@-.-", "0.5000", "0.5000")]
    assert out["relative"] == "0"
    assert out["rel_poll"] == "@@@-.-"
    assert out["pos"] == "0.5000 1.5000 0.0000"
    assert out["stray"] == b""
    assert model.internal_errors == []
    assert server.wire.lost_bytes == 0


@pytest.mark.parametrize("profile", ["manual", "legacy"])
async def test_lab_script_shaped_session(profile: str) -> None:
    """A typical lab script: ``!autostatus 0`` before each move (in case anything turned
    it on), the move, ``sa`` polled until no ``M``, ``?pos`` read back."""
    async with await serve_pty(controller(axes=2, profile=profile)) as server:

        def host() -> list[tuple[str, str]]:
            with open_port(server.path) as port:
                tango = Host(port)
                results = []
                for x, y in ((1.0, 2.0), (3.5, -1.0), (0.0, 0.0)):
                    tango.tell("!autostatus 0")
                    tango.tell(f"!moa {x} {y}")
                    polls = tango.wait_idle(poll="sa")
                    results.append((polls[-1], tango.ask("?pos")))
                results.append(("stray", tango.quiet().decode()))
                return results

        results = await asyncio.to_thread(host)
        model = model_of(server.wire)
    assert results == [("@@--.-", "1.0000 2.0000"), ("@@--.-", "3.5000 -1.0000"),
                       ("@@--.-", "0.0000 0.0000"), ("stray", "")]
    assert model.internal_errors == []
