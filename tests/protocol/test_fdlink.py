"""Tier 2: :class:`tango_aio.transports._fdlink.FdTransport` on a pseudo-terminal pair.

The transport's side of the pair stands for the serial port; the test reads and writes the
other side as the controller would. A full kernel buffer, a close with bytes still
buffered, an abort, and the other side going away are each driven deterministically.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import pytest
from helpers import WINDOWS

from tango_aio.transports import _portlink as portlink
from tango_aio.transports._fdlink import FdTransport

pytestmark = pytest.mark.timeout(30)

if WINDOWS:
    pytest.skip("POSIX only: needs a pty pair (os.openpty, tty) and a descriptor the event "
                "loop can watch (the POSIX fd transport)", allow_module_level=True)
import tty  # noqa: E402  (POSIX only)


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


@dataclass
class Pair:
    transport: FdTransport
    protocol: Recorder
    port: Port
    other: int  # the controller's side

    def read_other(self, size: int = 1 << 20) -> bytes:
        os.set_blocking(self.other, False)
        try:
            return os.read(self.other, size)
        except BlockingIOError:
            return b""


@pytest.fixture
async def pair() -> AsyncIterator[Pair]:
    controller, port_fd = os.openpty()
    tty.setraw(controller)
    tty.setraw(port_fd)
    protocol = Recorder()
    port = Port(port_fd)
    transport = FdTransport(asyncio.get_running_loop(), protocol, port)
    await protocol.made.wait()
    yield Pair(transport, protocol, port, controller)
    transport.abort()
    await protocol.lost
    os.close(controller)


async def test_bytes_go_both_ways(pair: Pair) -> None:
    pair.transport.write(b"?pos\r")
    assert pair.read_other() == b"?pos\r"
    os.write(pair.other, b"1.0 2.0 3.0\r")
    while b"\r" not in pair.protocol.received:
        pair.protocol.arrived.clear()
        await pair.protocol.arrived.wait()
    assert pair.protocol.received == b"1.0 2.0 3.0\r"
    assert pair.transport.get_extra_info("serial") is pair.port


async def test_what_the_kernel_does_not_take_is_written_later_in_order(pair: Pair) -> None:
    block = bytes(range(256)) * 64  # more than a pty holds unread
    pair.transport.write(block)
    pair.transport.write(b"tail")
    assert pair.transport.get_write_buffer_size() > 0
    got = bytearray()
    while len(got) < len(block) + 4:
        got += pair.read_other()
        await asyncio.sleep(0.001)
    assert bytes(got) == block + b"tail"
    assert pair.transport.get_write_buffer_size() == 0


async def test_close_writes_what_is_buffered_then_closes_the_port(pair: Pair) -> None:
    block = b"x" * 100_000
    pair.transport.write(block)
    pair.transport.close()
    assert pair.transport.is_closing() and not pair.port.closed
    pair.transport.write(b"ignored")  # after close: dropped
    got = bytearray()
    while not pair.protocol.lost.done():
        got += pair.read_other()
        await asyncio.sleep(0.001)
    assert await pair.protocol.lost is None and pair.port.closed
    with contextlib.suppress(OSError):  # EIO once the rest is read: the port is closed
        while len(got) < len(block):
            got += pair.read_other()
    assert bytes(got) == block


async def test_abort_drops_the_buffer(pair: Pair) -> None:
    pair.transport.write(b"y" * 100_000)
    pair.transport.abort()
    assert await pair.protocol.lost is None and pair.port.closed
    assert len(pair.read_other()) < 100_000


async def test_the_other_side_going_away_ends_the_link_with_the_error(pair: Pair) -> None:
    os.close(pair.other)
    pair.other = os.open(os.devnull, os.O_RDONLY)  # for the fixture to close
    exc = await pair.protocol.lost
    assert isinstance(exc, OSError)  # EIO from the pty, as from an unplugged adapter
    assert pair.port.closed


async def test_paused_reading_holds_the_bytes_until_resumed(pair: Pair) -> None:
    pair.transport.pause_reading()
    assert not pair.transport.is_reading()
    os.write(pair.other, b"0\r")
    await asyncio.sleep(0.02)
    assert pair.protocol.received == b""
    pair.transport.resume_reading()
    await pair.protocol.arrived.wait()
    assert pair.protocol.received == b"0\r"


async def test_close_drops_what_cannot_drain(pair: Pair,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    # Nobody reads the other side: the bytes cannot all go; the port is released anyway.
    monkeypatch.setattr(portlink, "CLOSE_DRAIN", 0.05)
    pair.transport.write(b"z" * 100_000)
    pair.transport.close()
    assert await asyncio.wait_for(pair.protocol.lost, 5.0) is None
    assert pair.port.closed
