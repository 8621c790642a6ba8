"""Tier 2: one contract, every serial transport. :class:`tango_aio.transports._fdlink.FdTransport`
(POSIX: the port's descriptor in the event loop) and
:class:`tango_aio.transports._threadlink.ThreadTransport` (Windows: a reader and a writer thread)
each run the same tests, through a rig that plays the device at the other end:

* ``fd``: the transport's side of a pseudo-terminal pair stands for the serial port; the
  test reads and writes the other side as the controller would. Output is held back by
  not reading it (a write larger than the pty holds stays partly buffered).
* ``thread``: the port is :class:`~fakeserial.FakeWindowsSerial`, pyserial's Windows
  ``Serial`` as far as the transport sees it. Output is held back by not completing
  writes (as hardware flow control does).

What only one transport has is tested beside it: ``test_threadlink.py`` (read timeouts,
the threads, ``connect("COM3")``).
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
import serial
from fakeserial import FakeWindowsSerial
from helpers import posix_only

from tango_aio.transports import _portlink as portlink
from tango_aio.transports._portlink import PortTransport
from tango_aio.transports._threadlink import ThreadTransport

pytestmark = pytest.mark.timeout(60)

#: Bytes the device does not take while its output is held (more than a pty holds).
HELD = 100_000
#: A bound that only catches a hang.
HANG = 10.0


@dataclass
class Recorder(asyncio.Protocol):
    """Records what the transport tells its protocol."""

    received: bytearray = field(default_factory=bytearray)
    made: asyncio.Event = field(default_factory=asyncio.Event)
    lost: asyncio.Future[Exception | None] = field(
        default_factory=lambda: asyncio.get_running_loop().create_future())
    arrived: asyncio.Event = field(default_factory=asyncio.Event)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.made.set()

    def data_received(self, data: bytes) -> None:
        self.received += data
        self.arrived.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.set_result(exc)

    async def until(self, check: Callable[[], bool]) -> None:
        async with asyncio.timeout(HANG):
            while not check():
                self.arrived.clear()
                await self.arrived.wait()


async def _until(check: Callable[[], bool]) -> None:
    """Wait in small steps until ``check()`` holds: the device's side (another thread, or
    the pty's other end) sets nothing the loop can wait for."""
    async with asyncio.timeout(HANG):
        while not check():  # noqa: ASYNC110 (no event to wait for)
            await asyncio.sleep(0.001)


class Rig:
    """A transport and the device at the other end of its port."""

    transport: PortTransport
    port: Any
    protocol: Recorder
    #: What a transport's protocol hears when the device goes away.
    unplugged: type[BaseException]

    def feed(self, data: bytes) -> None:
        """The device sends ``data``."""
        raise NotImplementedError

    def take(self) -> bytes:
        """What reached the device since the last call (output held: nothing)."""
        raise NotImplementedError

    def hold_output(self) -> None:
        """The device takes no more output until :meth:`release_output`."""
        raise NotImplementedError

    def release_output(self) -> None:
        raise NotImplementedError

    def writing(self) -> bool:
        """Whether the port has begun to take the transport's output."""
        raise NotImplementedError

    def unplug(self) -> None:
        """The device goes away."""
        raise NotImplementedError

    def port_closed(self) -> bool:
        raise NotImplementedError

    def dispose(self) -> None:
        """Release what the rig holds (after the transport ended)."""

    async def read_all(self, count: int) -> bytes:
        """Read from the device's side until ``count`` bytes came."""
        got = bytearray()

        def enough() -> bool:
            got.extend(self.take())
            return len(got) >= count

        await _until(enough)
        return bytes(got)


class PtyRig(Rig):
    """:class:`~tango_aio.transports._fdlink.FdTransport` on a pty pair."""

    unplugged = OSError  # EIO from the pty, as from an unplugged adapter

    class Port:
        """What FdTransport needs of a pyserial port: ``fileno()``, ``close()``, ``port``."""

        def __init__(self, fd: int) -> None:
            self.fd = fd
            self.port = f"pty fd {fd}"
            self.closed = False

        def fileno(self) -> int:
            return self.fd

        def close(self) -> None:
            if not self.closed:
                self.closed = True
                os.close(self.fd)

    def __init__(self, protocol: Recorder) -> None:
        posix_only("a pty pair (os.openpty, tty) and a descriptor the event loop can watch "
                   "(the POSIX fd transport)")
        import tty

        from tango_aio.transports._fdlink import FdTransport

        self.other, port_fd = os.openpty()
        tty.setraw(self.other)
        tty.setraw(port_fd)
        os.set_blocking(self.other, False)
        self.protocol = protocol
        self.port = self.Port(port_fd)
        self.held = False
        self.transport = FdTransport(asyncio.get_running_loop(), protocol, self.port)

    def feed(self, data: bytes) -> None:
        os.write(self.other, data)

    def take(self) -> bytes:
        if self.held:
            return b""
        try:
            return os.read(self.other, 1 << 20)
        except BlockingIOError:
            return b""
        except OSError:  # EIO once the port is closed and its rest read
            return b""

    def hold_output(self) -> None:
        self.held = True

    def release_output(self) -> None:
        self.held = False

    def writing(self) -> bool:
        return True  # the kernel takes what fits within write() itself

    def unplug(self) -> None:
        os.close(self.other)
        self.other = os.open(os.devnull, os.O_RDONLY)  # for dispose() to close

    def port_closed(self) -> bool:
        return bool(self.port.closed)

    def dispose(self) -> None:
        os.close(self.other)


class ThreadRig(Rig):
    """:class:`~tango_aio.transports._threadlink.ThreadTransport` on :class:`FakeWindowsSerial`."""

    unplugged = serial.SerialException

    def __init__(self, protocol: Recorder) -> None:
        self.protocol = protocol
        self.port = FakeWindowsSerial()
        self._taken = 0
        self.transport = ThreadTransport(asyncio.get_running_loop(), protocol, self.port)

    def feed(self, data: bytes) -> None:
        self.port.arrive(data)

    def take(self) -> bytes:
        data = bytes(self.port.written[self._taken:])
        self._taken += len(data)
        return data

    def hold_output(self) -> None:
        self.port.hold_writes.set()

    def release_output(self) -> None:
        self.port.hold_writes.clear()

    def writing(self) -> bool:
        return bool(self.port.write_started.is_set())

    def unplug(self) -> None:
        self.port.unplug()

    def port_closed(self) -> bool:
        return not self.port.is_open


RIGS: dict[str, Callable[[Recorder], Rig]] = {"fd": PtyRig, "thread": ThreadRig}


@pytest.fixture(params=sorted(RIGS))
async def rig(request: pytest.FixtureRequest) -> AsyncIterator[Rig]:
    protocol = Recorder()
    made = RIGS[request.param](protocol)
    async with asyncio.timeout(HANG):
        await protocol.made.wait()
    yield made
    made.transport.abort()
    async with asyncio.timeout(HANG):
        await protocol.lost
    made.dispose()


async def test_bytes_go_both_ways(rig: Rig) -> None:
    rig.transport.write(b"?pos\r")
    assert await rig.read_all(5) == b"?pos\r"
    rig.feed(b"1.0 2.0 ")
    rig.feed(b"3.0\r")
    await rig.protocol.until(lambda: b"\r" in rig.protocol.received)
    assert rig.protocol.received == b"1.0 2.0 3.0\r"
    assert rig.transport.get_extra_info("serial") is rig.port
    assert rig.transport.get_protocol() is rig.protocol
    assert rig.transport.is_reading() and not rig.transport.is_closing()


async def test_what_the_port_does_not_take_is_written_later_in_order(rig: Rig) -> None:
    rig.hold_output()
    block = bytes(range(256)) * (HELD // 256)
    rig.transport.write(block)  # never blocks
    rig.transport.write(b"")  # nothing
    rig.transport.write(b"tail")
    assert rig.transport.get_write_buffer_size() > 0
    rig.release_output()
    assert await rig.read_all(len(block) + 4) == block + b"tail"
    await _until(lambda: rig.transport.get_write_buffer_size() == 0)


async def test_close_writes_what_is_buffered_then_closes_the_port(rig: Rig) -> None:
    rig.hold_output()
    block = b"x" * HELD
    rig.transport.write(block)
    rig.transport.close()
    assert rig.transport.is_closing() and not rig.port_closed()
    rig.transport.write(b"ignored")  # after close: dropped
    rig.release_output()
    got = bytearray()
    async with asyncio.timeout(HANG):
        while not rig.protocol.lost.done():  # the device is read here
            got += rig.take()
            await asyncio.sleep(0.001)
    assert await rig.protocol.lost is None and rig.port_closed()
    while rest := rig.take():  # what is still on its way (a pty keeps it after the close)
        got += rest
    assert bytes(got) == block


async def test_abort_drops_the_buffer(rig: Rig) -> None:
    rig.hold_output()
    rig.transport.write(b"y" * HELD)
    await _until(rig.writing)  # what the port took is gone to the device
    rig.transport.write(b"?vel\r")  # this waits in the transport
    rig.transport.abort()
    assert rig.transport.is_closing()
    assert await rig.protocol.lost is None and rig.port_closed()
    assert rig.transport.get_write_buffer_size() == 0  # dropped, not pending
    rig.release_output()
    got = bytearray()
    while rest := rig.take():
        got += rest
    assert b"?vel" not in got


async def test_close_drops_what_cannot_drain(rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    # Nobody takes the output: the bytes cannot all go; the port is released anyway.
    monkeypatch.setattr(portlink, "CLOSE_DRAIN", 0.05)
    rig.hold_output()
    rig.transport.write(b"z" * HELD)
    rig.transport.close()
    async with asyncio.timeout(HANG):
        assert await rig.protocol.lost is None
    assert rig.port_closed()


async def test_the_device_going_away_ends_the_link_with_the_error(rig: Rig) -> None:
    rig.feed(b"@@@-.\r")
    await rig.protocol.until(lambda: bool(rig.protocol.received))
    rig.unplug()
    async with asyncio.timeout(HANG):
        exc = await rig.protocol.lost
    assert isinstance(exc, rig.unplugged)
    assert rig.port_closed() and rig.transport.is_closing()
    rig.transport.write(b"?pos\r")  # ignored, as on asyncio's transports
    assert rig.take() == b""


async def test_paused_reading_holds_the_bytes_until_resumed(rig: Rig) -> None:
    rig.transport.pause_reading()
    assert not rig.transport.is_reading()
    rig.feed(b"0\r")
    await asyncio.sleep(0.05)  # a chance for a wrong delivery
    assert rig.protocol.received == b""
    rig.transport.resume_reading()
    await rig.protocol.until(lambda: rig.protocol.received == b"0\r")
    assert rig.transport.is_reading()
