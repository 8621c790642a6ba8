"""Tier 2: what only :class:`tango_aio.transports._threadlink.ThreadTransport`, the Windows serial
transport, has; the contract it shares with the POSIX transport (bytes both ways, writes
that never block, close, abort, a device that goes away, paused reading) is
``test_transports.py``'s, run against both.

Its logic runs against :class:`~fakeserial.FakeWindowsSerial` (pyserial's Windows
``Serial`` as the transport uses it): reads that time out, reads that take what waits,
write completion, the threads and where the port is closed. Then the public API:
``connect("COM3")`` over pyserial's ``socket://`` port to a TCP emulator (a real blocking
port on every platform), a port another program holds ("Access is denied"), and, where
there are ptys, the real transport over a pty against the pty emulator.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
import serial
from fakeserial import FakeWindowsSerial
from helpers import make_model, posix_only, serve_pty

import tango_aio
import tango_aio.controller._connection as connection_module
from tango_aio.sim.serve import serve_tcp
from tango_aio.transports import _threadlink as threadlink
from tango_aio.transports._threadlink import ThreadTransport

pytestmark = pytest.mark.timeout(60)


@dataclass
class Recorder(asyncio.Protocol):
    """A protocol that records what the transport does to it."""

    data: bytearray = field(default_factory=bytearray)
    chunks: list[bytes] = field(default_factory=list)
    lost: list[Exception | None] = field(default_factory=list)
    made: asyncio.Event = field(default_factory=asyncio.Event)
    gone: asyncio.Event = field(default_factory=asyncio.Event)
    grew: asyncio.Event = field(default_factory=asyncio.Event)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.made.set()

    def data_received(self, data: bytes) -> None:
        self.chunks.append(data)
        self.data += data
        self.grew.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.append(exc)
        self.gone.set()

    async def until(self, check: Callable[[], bool]) -> None:
        while not check():
            self.grew.clear()
            await asyncio.wait_for(self.grew.wait(), 10)


@dataclass
class Link:
    port: FakeWindowsSerial
    protocol: Recorder
    transport: ThreadTransport


@pytest.fixture
async def link() -> AsyncIterator[Link]:
    port = FakeWindowsSerial()
    protocol = Recorder()
    transport = ThreadTransport(asyncio.get_running_loop(), protocol, port)
    await asyncio.wait_for(protocol.made.wait(), 10)
    yield Link(port, protocol, transport)
    transport.abort()
    await asyncio.wait_for(protocol.gone.wait(), 10)


async def _until(check: Callable[[], bool]) -> None:
    """Wait (on the loop, in small steps) until ``check()`` holds: the fake's threads
    are not the loop's, so there is no event to wait for."""
    async with asyncio.timeout(10):
        while not check():  # noqa: ASYNC110 (set by other threads, not the loop)
            await asyncio.sleep(0.001)


async def test_bytes_arrive_in_order_and_a_reply_is_not_read_byte_by_byte(link: Link) -> None:
    assert link.port.timeout == threadlink.READ_TIMEOUT  # set by the transport
    link.port.arrive(b"ER")
    await link.protocol.until(lambda: link.protocol.data == b"ER")
    link.port.arrive(b"R 4\r@@@-.\r")
    await link.protocol.until(lambda: link.protocol.data == b"ERR 4\r@@@-.\r")
    # Each read asks for what is waiting (or 1 byte to block on): a reply that is there
    # at once comes in one chunk, not one call per byte.
    link.port.arrive(b"x" * 100)
    await link.protocol.until(lambda: len(link.protocol.data) == 112)
    assert len(link.protocol.chunks) < 20
    assert max(link.port.reads) > 1


async def test_read_timeouts_return_nothing_and_the_link_goes_on(link: Link) -> None:
    await _until(lambda: link.port.timeouts >= 2)  # two reads timed out with b""
    assert link.protocol.chunks == [] and not link.transport.is_closing()
    link.port.arrive(b"10288\r")
    await link.protocol.until(lambda: link.protocol.data == b"10288\r")


async def test_an_unplug_during_a_blocked_read_ends_both_threads(link: Link) -> None:
    link.port.arrive(b"@@@-.\r")
    await link.protocol.until(lambda: bool(link.protocol.data))
    link.port.unplug()  # while the reader thread is blocked in read()
    await asyncio.wait_for(link.protocol.gone.wait(), 10)
    [cause] = link.protocol.lost
    assert isinstance(cause, serial.SerialException) and "ClearCommError" in str(cause)
    assert not link.transport._reader.is_alive() and not link.transport._writer.is_alive()


async def test_a_failed_write_ends_the_link_with_the_cause(link: Link) -> None:
    link.port.fail_writes(serial.SerialTimeoutException("Write timeout"))
    link.transport.write(b"?pos\r")
    await asyncio.wait_for(link.protocol.gone.wait(), 10)
    assert isinstance(link.protocol.lost[0], serial.SerialTimeoutException)
    assert not link.port.is_open


async def test_close_closes_the_port_in_a_worker_and_ends_both_threads(link: Link) -> None:
    link.port.hold_writes.set()
    link.transport.write(b"!moa 1 2\r")
    link.transport.close()
    link.port.hold_writes.clear()
    await asyncio.wait_for(link.protocol.gone.wait(), 10)
    assert link.protocol.lost == [None] and link.port.written == b"!moa 1 2\r"
    assert link.port.closed_in is not None
    assert link.port.closed_in != threading.current_thread().name  # not on the loop
    assert link.port.cancelled_reads >= 1  # the blocked read ended at once
    assert not link.transport._reader.is_alive() and not link.transport._writer.is_alive()


async def test_close_before_the_threads_started() -> None:
    port = FakeWindowsSerial()
    protocol = Recorder()
    transport = ThreadTransport(asyncio.get_running_loop(), protocol, port)
    transport.close()
    await asyncio.wait_for(protocol.gone.wait(), 10)
    assert protocol.lost == [None] and not port.is_open
    assert not transport._reader.is_alive()


# -- the public API: tango_aio.connect("COM3") on Windows -----------------------------------


@pytest.fixture
def on_windows(monkeypatch: pytest.MonkeyPatch) -> None:
    """connect() takes its Windows branch (the serial transport), whatever runs the test."""
    monkeypatch.setattr(connection_module, "WINDOWS", True)
    monkeypatch.setattr(connection_module, "POSIX", False)


def _com3_is(monkeypatch: pytest.MonkeyPatch, opener: Callable[..., Any]) -> list[dict[str, Any]]:
    """Make pyserial open ``COM3`` with ``opener``; returns the options it was given."""
    real = serial.serial_for_url
    calls: list[dict[str, Any]] = []

    def serial_for_url(url: str, *args: Any, **kwargs: Any) -> Any:
        if url != "COM3":
            return real(url, *args, **kwargs)
        calls.append(kwargs)
        return opener(**kwargs)

    monkeypatch.setattr(serial, "serial_for_url", serial_for_url)
    return calls


@pytest.mark.usefixtures("on_windows")
async def test_connect_com3_runs_moves_and_closes(monkeypatch: pytest.MonkeyPatch) -> None:
    """``connect("COM3")`` through the thread transport, the port being pyserial's real
    blocking ``socket://`` port to a TCP emulator."""
    async with await serve_tcp(make_model) as server:
        url = f"socket://127.0.0.1:{server.port}"
        opened: list[Any] = []

        def open_port(**options: Any) -> Any:
            port = serial.serial_for_url(url, timeout=options["timeout"])
            opened.append(port)
            return port

        calls = _com3_is(monkeypatch, open_port)
        async with tango_aio.connect("COM3") as tango:
            transport = tango.protocol.transport
            assert isinstance(transport, ThreadTransport)
            assert tango.identity.model == "TANGO-DT"
            await tango.move_to(x=1.5, y=-2)
            assert await tango.position() == {"x": 1.5, "y": -2.0, "z": 0.0}
        assert calls[0]["exclusive"] is True and calls[0]["baudrate"] == 57600
        assert not opened[0].is_open  # released when aclose() returned


@pytest.mark.usefixtures("on_windows")
async def test_connect_com3_held_by_another_program_is_a_typed_error(
        monkeypatch: pytest.MonkeyPatch) -> None:
    def held(**options: Any) -> Any:
        raise serial.SerialException("could not open port 'COM3': PermissionError(13, "
                                     "'Access is denied.', None, 5)")

    _com3_is(monkeypatch, held)
    with pytest.raises(tango_aio.PortBusyError, match="COM3 is busy: another program"):
        await tango_aio.connect("COM3")


@pytest.mark.usefixtures("on_windows")
async def test_connect_com3_unplugged_is_a_lost_connection(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The device goes away under an open link (the TCP emulator drops the connection:
    pyserial's read raises ``SerialException``): the controller sees the loss, the next
    call fails with ConnectionLostError, and the port is closed."""
    async with await serve_tcp(make_model) as server:
        url = f"socket://127.0.0.1:{server.port}"
        opened: list[Any] = []

        def open_port(**options: Any) -> Any:
            opened.append(serial.serial_for_url(url, timeout=options["timeout"]))
            return opened[-1]

        _com3_is(monkeypatch, open_port)
        async with tango_aio.connect("COM3") as tango:
            assert tango.connected
            server.close()  # unplugged
            await _until(lambda: not tango.connected)
            with pytest.raises(tango_aio.ConnectionLostError):
                await tango.query("?version")
        assert not opened[0].is_open


# -- the real transport over a pty, against the pty emulator ---------------------------------


@pytest.mark.usefixtures("on_windows")
async def test_the_thread_transport_over_a_pty_end_to_end() -> None:
    posix_only("a pty (pyserial opens its slave path as it would COM3)")
    async with await serve_pty(make_model) as server:
        async with tango_aio.connect(server.path) as tango:
            assert isinstance(tango.protocol.transport, ThreadTransport)
            await tango.move_to(x=0.25, y=0.5)
            await tango.move_by(x=-0.125)
            assert await tango.position() == {"x": 0.125, "y": 0.5, "z": 0.0}
            with pytest.raises(tango_aio.PortBusyError, match="is busy"):
                await tango_aio.connect(server.path)  # exclusive, as before
        async with tango_aio.connect(server.path) as tango:  # released at once
            assert await tango.position() == {"x": 0.125, "y": 0.5, "z": 0.0}
            server.close()  # the device goes away: the read raises
            await _until(lambda: not tango.connected)
            with pytest.raises(tango_aio.ConnectionLostError):
                await tango.query("?version")
