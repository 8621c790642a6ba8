"""A serial port's file descriptor as an asyncio transport, read and written directly.

Theory of operation
===================
pyserial opens and configures the port (baud rate, 8N2, the advisory lock); this
transport then does the I/O on its file descriptor itself, the way asyncio's own pipe
transports do: the event loop's reader callback takes what has arrived with one
non-blocking ``os.read``, and ``write`` hands the bytes to ``os.write`` at once, keeping
only what the kernel did not take and writing it when the descriptor is writable again.

Why not pyserial-asyncio: its reads go through ``Serial.read``, which calls
``select`` before every ``os.read`` (two system calls and a Python loop per received
chunk). At 57600 Bd a reply arrives in chunks of a few bytes, so per-chunk costs are what
a position watch or a many-link upload pays for; ``benchmarks/watch.py`` and
``benchmarks/scaling.py`` measure the difference.

Only POSIX ports whose ``fileno()`` is a real descriptor use it (``serial.Serial`` on
Linux and macOS); other pyserial URL handlers keep pyserial-asyncio
(:func:`tango_aio.controller._connection._open_serial`).

Ending: an error on the descriptor (``EIO`` when a USB adapter is unplugged or a pty's
other side closes) or end of file ends the link with ``connection_lost(exc)``; ``close()``
writes what is buffered first (for at most :data:`CLOSE_DRAIN` seconds); ``abort()``
drops it. Closing the port itself can block
(a driver draining its output), so ``port.close()`` runs in a worker thread, and the
protocol hears ``connection_lost`` after it returned.
"""

from __future__ import annotations

import asyncio
import logging
import os
from typing import Any

from ._portlink import CLOSE_DRAIN, PortTransport

__all__ = ["CLOSE_DRAIN", "FdTransport"]

log = logging.getLogger("tango_aio.transports._fdlink")

#: Bytes taken per read (a 256-byte input buffer on the controller; replies are short).
READ_SIZE = 4096
class FdTransport(PortTransport):
    """An open pyserial port's descriptor as a transport (see the module docstring)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol,
                 port: Any) -> None:
        super().__init__(loop, protocol, port)
        self._fd: int = port.fileno()
        os.set_blocking(self._fd, False)
        self._buffer = bytearray()
        loop.call_soon(protocol.connection_made, self)
        loop.call_soon(self._start_reading)

    # -- asyncio.Transport --------------------------------------------------------------

    def pause_reading(self) -> None:
        if self._reading and not self._closing:
            self._reading = False
            self._loop.remove_reader(self._fd)

    def resume_reading(self) -> None:
        if not self._reading and not self._closing:
            self._reading = True
            self._loop.add_reader(self._fd, self._read_ready)

    def get_write_buffer_size(self) -> int:
        """The bytes written but not yet handed to the file descriptor."""
        return len(self._buffer)

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Write ``data`` to the file descriptor, buffering what it does not take now."""
        if self._closing or not data:
            return
        if self._buffer:
            self._buffer += data
            return
        try:
            written = os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            written = 0
        except OSError as exc:
            self._fail(exc)
            return
        if written < len(data):
            self._buffer += memoryview(data)[written:]
            self._loop.add_writer(self._fd, self._write_ready)

    # -- internals ----------------------------------------------------------------------

    def _start_reading(self) -> None:
        if self._reading and not self._closing:
            self._loop.add_reader(self._fd, self._read_ready)

    def _stop_reading(self) -> None:
        if self._reading:
            self._loop.remove_reader(self._fd)

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._fail(exc)
            return
        if not data:
            self._fail(ConnectionResetError("end of file on the serial port"))
            return
        self._protocol.data_received(data)

    def _write_ready(self) -> None:
        try:
            written = os.write(self._fd, self._buffer)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._fail(exc)
            return
        del self._buffer[:written]
        if not self._buffer:
            self._loop.remove_writer(self._fd)
            if self._closing:
                self._finish(None)

    def _fail(self, exc: BaseException | None) -> None:
        """End the link now (an I/O error, end of file, or :meth:`abort`)."""
        if exc is not None:
            log.debug("serial port %s: %r", self._port.port, exc)
        self._closing = True
        self._stop_reading()
        if self._buffer:
            self._loop.remove_writer(self._fd)
            self._buffer.clear()
        self._finish(exc)
