"""Serve an emulated controller over a pseudo-terminal (POSIX only).

The pty emulator: a host opens the slave path with pyserial as it would a real serial
port. It needs ``os.openpty``, ``termios``, ``tty`` and ``fcntl``, which exist on Linux
and macOS only, so it lives apart from :mod:`tango_aio.sim.serve` (TCP and in-process
serving, which work everywhere): importing this module on Windows raises
``ModuleNotFoundError``. On Windows, serve over TCP instead (``tango-aio sim --tcp``,
then ``socket://`` or a com0com pair); ``tests/unit/test_posix_imports.py`` checks that
nothing else in the package imports a POSIX-only module at the top level.
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import struct
import termios
import tty

from tango_aio.sim.clock import scaled_factory
from tango_aio.sim.serve import (
    _DRAIN_POLL,
    _DRAIN_QUIET,
    _READ_SIZE,
    DRAIN_GRACE,
    OUTPUT_QUEUE_LIMIT,
    WireRunner,
    _wait_task,
)
from tango_aio.sim.wire import HandlerFactory, Wire, WireConfig

__all__ = ["PtyServer", "serve_pty"]


class PtyServer:
    """One emulated controller behind a pseudo-terminal."""

    def __init__(self, wire: Wire) -> None:
        self._loop = asyncio.get_running_loop()
        self._master, self._slave = os.openpty()
        # Raw mode on the slave: no echo, no CR/NL translation, for hosts that do not set
        # their own termios (pyserial does set raw mode itself on open).
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path: str = os.ttyname(self._slave)
        """Device path of the slave end, for the host to open."""
        self.wire = wire
        """The emulated link (fault injection, counters)."""
        self._out = bytearray()
        self._open = True
        self._reading = True
        self._runner = WireRunner(wire, self._write, throttle=self._throttle)
        self._loop.add_reader(self._master, self._on_readable)
        self._task = self._loop.create_task(self._serve())

    def close(self) -> None:
        """Stop serving and close the pty."""
        self._task.cancel()

    async def wait_closed(self) -> None:
        """Wait until serving has ended (close() or a disconnect fault)."""
        await _wait_task(self._task)

    async def __aenter__(self) -> PtyServer:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        self.close()
        await self.wait_closed()

    async def _serve(self) -> None:
        try:
            await self._runner.run()
            await self._drain()
        finally:
            self._close_fds()

    async def _drain(self) -> None:
        """Before a disconnect, wait (up to :data:`DRAIN_GRACE`) until the host has read all."""
        quiet = 0
        for _ in range(int(DRAIN_GRACE / _DRAIN_POLL)):
            quiet = quiet + 1 if not self._out and self._unread() == 0 else 0
            if quiet >= _DRAIN_QUIET:
                return
            await asyncio.sleep(_DRAIN_POLL)

    def _unread(self) -> int:
        """Bytes written to the host that it has not read yet (slave input queue)."""
        try:
            raw = fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0")
        except OSError:
            return 0
        return int(struct.unpack("i", raw)[0])

    def _on_readable(self) -> None:
        try:
            data = os.read(self._master, _READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # EIO: no slave open; cannot happen while we hold one.
            return
        if data:
            self._runner.feed(data)

    def _write(self, chunk: bytes) -> None:
        self._out += chunk
        self._flush()

    def _flush(self) -> None:
        """Write pending output; if the pty buffer is full, retry when it drains."""
        while self._out and self._open:
            try:
                written = os.write(self._master, self._out)
            except BlockingIOError:
                self._loop.add_writer(self._master, self._flush)
                self._update_reading()
                return
            except OSError:
                self._out.clear()
                break
            del self._out[:written]
        if self._open:
            self._loop.remove_writer(self._master)
            self._update_reading()

    def _throttle(self, paused: bool) -> None:
        self._update_reading()

    def _update_reading(self) -> None:
        """Read from the host only while its input and our output are within bounds; the
        kernel's pty buffer then fills and the host's writes block, as on a real port."""
        reading = self._open and not self._runner.input_paused \
            and len(self._out) <= OUTPUT_QUEUE_LIMIT
        if reading == self._reading:
            return
        self._reading = reading
        if reading:
            self._loop.add_reader(self._master, self._on_readable)
        else:
            self._loop.remove_reader(self._master)

    def _close_fds(self) -> None:
        if not self._open:
            return
        self._flush()
        self._open = False
        self._loop.remove_reader(self._master)
        self._loop.remove_writer(self._master)
        os.close(self._master)
        os.close(self._slave)


async def serve_pty(factory: HandlerFactory, config: WireConfig | None = None, *,
                    speed: float = 1.0) -> PtyServer:
    """Start serving a fresh controller on a new pty; returns at once (see ``.path``).

    ``speed``: the controller runs that many times as fast as the host's clock
    (:mod:`tango_aio.sim.clock`); the wire keeps its timing.

    Parameters
    ----------
    factory
        Makes the controller logic.
    config
        The wire's configuration; ``None`` for the default.
    speed
        How many times as fast as the host's clock the controller runs.

    Returns
    -------
    PtyServer
        The running server.
    """
    return PtyServer(Wire(scaled_factory(factory, speed), config))
