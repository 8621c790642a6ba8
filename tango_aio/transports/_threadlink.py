"""A pyserial port as an asyncio transport, read and written by two threads (Windows)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from typing import Any

from ._portlink import CLOSE_DRAIN, PortTransport

__all__ = ["CLOSE_DRAIN", "READ_TIMEOUT", "ThreadTransport"]

log = logging.getLogger("tango_aio.transports._threadlink")

#: Seconds a blocking read waits for a first byte before the reader thread looks again
#: whether it should stop (a port without ``cancel_read`` stops within this time).
READ_TIMEOUT = 0.1
#: Seconds closing waits for each thread to end (a driver that never returns from a
#: read or write must not hang the program; the port is closed regardless).
JOIN_WAIT = 5.0


class ThreadTransport(PortTransport):
    """An open pyserial port as a transport, through a reader and a writer thread (see
    the module docstring). ``port`` is any object with pyserial's blocking ``Serial``
    interface: ``read``, ``write``, ``in_waiting``, ``timeout``, ``close``, and optionally
    ``cancel_read``/``cancel_write``."""

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol,
                 port: Any) -> None:
        super().__init__(loop, protocol, port)
        port.timeout = READ_TIMEOUT
        self._held: list[bytes] = []  # read while paused, delivered on resume
        self._pending = 0  # bytes handed to write() and not yet written (loop side)
        # Shared with the threads (under _lock): the bytes to write, and the stop flag.
        self._lock = threading.Lock()
        self._wake_writer = threading.Condition(self._lock)
        self._outgoing = bytearray()
        self._stop = threading.Event()
        self._may_read = threading.Event()
        self._may_read.set()
        self._reader = threading.Thread(target=self._read_loop, daemon=True,
                                        name=f"tango_aio reader {_name(port)}")
        self._writer = threading.Thread(target=self._write_loop, daemon=True,
                                        name=f"tango_aio writer {_name(port)}")
        loop.call_soon(protocol.connection_made, self)
        loop.call_soon(self._start)

    # -- asyncio.Transport --------------------------------------------------------------

    def pause_reading(self) -> None:
        if self._reading and not self._closing:
            self._reading = False
            self._may_read.clear()

    def resume_reading(self) -> None:
        if self._reading or self._closing:
            return
        self._reading = True
        self._may_read.set()
        held, self._held = self._held, []
        for data in held:
            self._protocol.data_received(data)

    def get_write_buffer_size(self) -> int:
        """The bytes written but not yet written to the port by its thread."""
        return self._pending

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Hand ``data`` to the port's writer thread (never blocks)."""
        if self._closing or not data:
            return
        self._pending += len(data)
        with self._lock:
            self._outgoing += data
            self._wake_writer.notify()

    # -- loop side ----------------------------------------------------------------------

    def _start(self) -> None:
        if self._lost:
            return
        self._reader.start()
        self._writer.start()

    def _received(self, data: bytes) -> None:
        if self._closing:
            return
        if not self._reading:
            self._held.append(data)
            return
        self._protocol.data_received(data)

    def _written(self, count: int) -> None:
        if self._lost:  # the buffer was dropped meanwhile
            return
        self._pending -= count
        if self._closing and not self._pending:
            self._finish(None)

    def _fail(self, exc: BaseException | None) -> None:
        """End the link now (a failed read or write, or :meth:`abort`)."""
        if exc is not None and not self._lost:
            log.debug("serial port %s: %r", _name(self._port), exc)
        self._closing = True
        self._pending = 0
        with self._lock:
            self._outgoing.clear()
        self._finish(exc)

    def _stop_reading(self) -> None:
        self._may_read.clear()

    def _close_blocking(self) -> None:
        """In a worker thread: end both threads, then close the port."""
        self._stop.set()
        self._may_read.set()  # a paused reader wakes up to see the stop
        with self._lock:
            self._outgoing.clear()
            self._wake_writer.notify()
        for cancel in ("cancel_read", "cancel_write"):
            with contextlib.suppress(Exception):
                getattr(self._port, cancel, lambda: None)()
        for thread in (self._reader, self._writer):
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(JOIN_WAIT)
        self._port.close()

    # -- the threads --------------------------------------------------------------------

    def _call(self, callback: Any, *args: Any) -> bool:
        """Run ``callback(*args)`` on the loop; False once the loop is closed."""
        try:
            self._loop.call_soon_threadsafe(callback, *args)
        except RuntimeError:
            return False
        return True

    def _read_loop(self) -> None:
        port = self._port
        while not self._stop.is_set() and not self._loop.is_closed():
            if not self._may_read.is_set():
                self._may_read.wait(READ_TIMEOUT)
                continue
            try:
                data = port.read(port.in_waiting or 1)
            except Exception as exc:  # SerialException, OSError: the device is gone
                if not self._stop.is_set():
                    self._call(self._fail, exc)
                return
            if data and not self._call(self._received, bytes(data)):
                return

    def _write_loop(self) -> None:
        port = self._port
        while True:
            with self._lock:
                while not self._outgoing and not self._stop.is_set():
                    self._wake_writer.wait()
                if self._stop.is_set():
                    return
                data = bytes(self._outgoing)
                self._outgoing.clear()
            try:
                written = port.write(data)
            except Exception as exc:  # SerialException, OSError, a write timeout
                if not self._stop.is_set():
                    self._call(self._fail, exc)
                return
            if written is not None and written < len(data):
                # pyserial returns the count handed over; a short count only comes from a
                # write timeout, which is not set here: say so rather than lose bytes.
                self._call(self._fail, ConnectionError(
                    f"serial port wrote {written} of {len(data)} bytes"))
                return
            if not self._call(self._written, len(data)):
                return


def _name(port: Any) -> str:
    return str(getattr(port, "port", None) or getattr(port, "name", "") or "port")


