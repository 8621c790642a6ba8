"""A serial port's file descriptor as an asyncio transport, read and written directly."""

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
