"""What the two serial-port transports share: an open pyserial port as an asyncio transport."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

__all__ = ["CLOSE_DRAIN", "PortTransport"]

#: Seconds ``close()`` lets buffered bytes be written before it drops them (a port whose
#: output is held back, e.g. by hardware flow control, is still released).
CLOSE_DRAIN = 2.0


class PortTransport(asyncio.Transport):
    """An open pyserial port as a transport: the part both serial transports share (see
    the module docstring). Subclasses do the reading and writing."""

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol,
                 port: Any) -> None:
        super().__init__({"serial": port})
        self._loop = loop
        self._protocol = protocol
        self._port = port
        #: ``close()``, ``abort()`` or a failure came.
        self._closing = False
        #: The port is being closed; ``connection_lost`` follows.
        self._lost = False
        self._reading = True
        self._drain: asyncio.TimerHandle | None = None

    # -- asyncio.Transport --------------------------------------------------------------

    def get_protocol(self) -> asyncio.BaseProtocol:
        """The protocol the received bytes go to."""
        return self._protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        """Hand the received bytes to ``protocol`` from now on."""
        assert isinstance(protocol, asyncio.Protocol)
        self._protocol = protocol

    def is_closing(self) -> bool:
        """Whether the transport is closing or closed."""
        return self._closing

    def is_reading(self) -> bool:
        """Whether received bytes are being delivered."""
        return self._reading and not self._closing

    def can_write_eof(self) -> bool:
        """A serial port has no end of file to send."""
        return False

    def close(self) -> None:
        """Stop reading, write what is buffered (at most :data:`CLOSE_DRAIN` seconds),
        then close the port and tell the protocol."""
        if self._closing:
            return
        self._closing = True
        self._stop_reading()
        if not self.get_write_buffer_size():
            self._finish(None)
        else:
            self._drain = self._loop.call_later(CLOSE_DRAIN, self._fail, None)

    def abort(self) -> None:
        """Drop what is buffered, close the port and tell the protocol."""
        self._fail(None)

    # -- what a subclass provides -------------------------------------------------------

    def _stop_reading(self) -> None:
        """Stop taking bytes from the port (closing)."""
        raise NotImplementedError

    def _fail(self, exc: BaseException | None) -> None:
        """End the link now: drop what is buffered, then :meth:`_finish`."""
        raise NotImplementedError

    def _close_blocking(self) -> None:
        """Close the port (in a worker thread: it may block)."""
        self._port.close()

    # -- the end ------------------------------------------------------------------------

    def _finish(self, exc: BaseException | None) -> None:
        """Close the port in a worker thread, then tell the protocol (once)."""
        if self._lost:
            return
        self._lost = True
        self._reading = False
        if self._drain is not None:
            self._drain.cancel()
        task = self._loop.create_task(self._close_port(exc))
        _background.add(task)
        task.add_done_callback(_background.discard)

    async def _close_port(self, exc: BaseException | None) -> None:
        with contextlib.suppress(Exception):
            await self._loop.run_in_executor(None, self._close_blocking)
        error = exc if isinstance(exc, Exception) or exc is None else ConnectionError(exc)
        self._protocol.connection_lost(error)


#: Tasks closing ports (kept referenced until done).
_background: set[asyncio.Task[None]] = set()
