"""A stand-in for pyserial's Windows ``Serial`` (``serialwin32``) as the thread transport
(:class:`tango_aio.transports._threadlink.ThreadTransport`) uses it: ``read(size)`` blocks until
``size`` bytes arrived or ``timeout`` passed and returns what it has (maybe ``b""``),
``in_waiting``, ``write`` returns once the bytes are handed over (write completion),
``cancel_read``/``cancel_write`` end a blocked call, and a read raises ``SerialException``
once the device is unplugged. Shared by the transport suite (``test_transports.py``) and
the thread transport's own tests (``test_threadlink.py``)."""

from __future__ import annotations

import threading

import serial

__all__ = ["FakeWindowsSerial"]


class FakeWindowsSerial:
    """pyserial's Windows ``Serial`` as far as the transport sees it (see the module
    docstring); the test plays the device through :meth:`arrive`, :meth:`unplug`,
    :attr:`hold_writes` and :attr:`written`."""

    def __init__(self, port: str = "COM3") -> None:
        self.port = port
        self.timeout: float | None = None
        self.is_open = True
        self.written = bytearray()
        self.reads: list[int] = []  # the size of each read call
        self.timeouts = 0  # reads that returned b"" because the timeout passed
        self.hold_writes = threading.Event()  # set: write() blocks until it is cleared
        self.write_started = threading.Event()
        self.closed_in: str | None = None  # the thread that called close()
        self.cancelled_reads = 0
        self._incoming = bytearray()
        self._unplugged: Exception | None = None
        self._cancel = False
        self._changed = threading.Condition()
        self._write_error: Exception | None = None

    # -- the device ---------------------------------------------------------------------

    def arrive(self, data: bytes) -> None:
        """Bytes arrive from the controller (into the driver's input buffer)."""
        with self._changed:
            self._incoming += data
            self._changed.notify_all()

    def unplug(self) -> None:
        """The USB adapter is pulled: a blocked or later read raises."""
        with self._changed:
            self._unplugged = serial.SerialException(
                "ClearCommError failed (PermissionError(13, 'The device does not "
                "recognize the command.', None, 22))")
            self._changed.notify_all()

    def fail_writes(self, exc: Exception) -> None:
        self._write_error = exc

    # -- pyserial's interface -----------------------------------------------------------

    @property
    def in_waiting(self) -> int:
        with self._changed:
            if self._unplugged is not None:
                raise self._unplugged
            return len(self._incoming)

    def read(self, size: int = 1) -> bytes:
        self.reads.append(size)
        with self._changed:
            timed_out = not self._changed.wait_for(
                lambda: len(self._incoming) >= size or self._unplugged is not None
                or self._cancel or not self.is_open, self.timeout)
            if self._unplugged is not None:
                raise self._unplugged
            if not self.is_open:
                raise serial.PortNotOpenError()
            self._cancel = False
            data = bytes(self._incoming[:size])
            del self._incoming[:size]
            if timed_out and not data:
                self.timeouts += 1
            return data

    def write(self, data: bytes) -> int:
        self.write_started.set()
        if self._write_error is not None:
            raise self._write_error
        while self.hold_writes.is_set() and self.is_open:
            threading.Event().wait(0.001)
        self.written += data
        return len(data)

    def reset_input_buffer(self) -> None:
        with self._changed:
            self._incoming.clear()

    def cancel_read(self) -> None:
        with self._changed:
            self.cancelled_reads += 1
            self._cancel = True
            self._changed.notify_all()

    def cancel_write(self) -> None:
        self.hold_writes.clear()

    def close(self) -> None:
        self.closed_in = threading.current_thread().name
        with self._changed:
            self.is_open = False
            self._changed.notify_all()
