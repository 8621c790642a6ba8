"""The probe's raw link: lines written and every line read, below the driver's routing."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable

from ..errors import ConnectionLostError
from ..link import TangoProtocol
from ._trace import format_record, trace_header

# ---------------------------------------------------------------------------------------
# The link: raw lines over connection.py's transports


class _RawProtocol(TangoProtocol):
    """A :class:`TangoProtocol` that hands every received byte to the probe instead of
    routing it (so that ``connection.open_link`` opens it like the driver's own)."""

    def __init__(self, sink: Callable[[bytes], None], lost: Callable[[], None],
                 reply_timeout: float) -> None:
        super().__init__(reply_timeout=reply_timeout)
        self._sink = sink
        self._lost_cb = lost

    def data_received(self, data: bytes) -> None:
        """Bytes from the controller, to the probe (and the ``tango_aio.wire`` log)."""
        self._trace_received(data)
        self._sink(data)

    def connection_lost(self, exc: Exception | None) -> None:
        """The link is gone: wake the probe."""
        super().connection_lost(exc)
        self._lost_cb()


class _Link:
    """Raw lines to and from the controller, with the wire trace."""

    def __init__(self, reply_timeout: float) -> None:
        self.reply_timeout = reply_timeout
        self.records: list[tuple[float, str, bytes]] = []
        self.inbox: list[str] = []
        self.lf_lines: list[str] = []
        self.local_echo = False
        self._rx = b""
        self._tx = b""
        self._echo_pending = bytearray()
        self._arrived = asyncio.Event()
        self._lost = False
        self._protocol: _RawProtocol | None = None
        self._closer: Callable[[], Awaitable[None]] | None = None

    async def open(self, url: str, *, baudrate: int, rtscts: bool) -> None:
        from ..controller import open_link

        def make() -> TangoProtocol:
            return _RawProtocol(self._feed, self._on_lost, self.reply_timeout)

        protocol, self._closer = await open_link(url, make, {"baudrate": baudrate,
                                                             "rtscts": rtscts})
        assert isinstance(protocol, _RawProtocol)
        self._protocol = protocol

    async def close(self) -> None:
        protocol, self._protocol = self._protocol, None
        if protocol is None:
            return
        protocol.close()
        if self._closer is not None:
            await self._closer()
        else:
            wait_closed = getattr(protocol.transport, "wait_closed", None)
            if wait_closed is not None:
                with contextlib.suppress(Exception):
                    await wait_closed()

    def _on_lost(self) -> None:
        self._lost = True
        self._arrived.set()

    def _feed(self, data: bytes) -> None:
        now = time.monotonic()
        *lines, self._rx = (self._rx + data).split(b"\r")
        for raw in lines:
            self.records.append((now, "<-", raw))
            bare = raw.lstrip(b"\n")
            text = raw.decode("latin-1")
            if raw.startswith(b"\n"):
                self.lf_lines.append(text)
            if self.local_echo and self._echo_pending.startswith(bare + b"\r"):
                del self._echo_pending[:len(bare) + 1]
                continue
            self.inbox.append(bare.decode("latin-1"))
        self._arrived.set()

    def write(self, data: bytes) -> None:
        """Write ``data`` (lines with their CR, or a bare Ctrl+C)."""
        if self._protocol is None or self._lost:
            raise ConnectionLostError("the link to the controller is gone")
        now = time.monotonic()
        *lines, self._tx = (self._tx + data).split(b"\r")
        for line in lines:
            self.records.append((now, "->", line))
        if self.local_echo:
            self._echo_pending += data
        self._protocol._write(data)

    def send(self, *lines: str) -> None:
        """Write command lines."""
        self.write(b"".join(line.encode("latin-1") + b"\r" for line in lines))

    def take(self) -> list[str]:
        """Every line received since the last take."""
        lines, self.inbox = self.inbox, []
        return lines

    async def until(self, done: Callable[[list[str]], bool], timeout: float) -> None:
        """Wait until ``done(lines received so far)``; TimeoutError after ``timeout``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not done(self.inbox):
            if self._lost:
                raise ConnectionLostError("the link to the controller was lost")
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise TimeoutError
            self._arrived.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), remaining)

    async def quiet(self, settle: float) -> None:
        """Wait until no line arrived for ``settle`` seconds."""
        while True:
            if self._lost:
                raise ConnectionLostError("the link to the controller was lost")
            self._arrived.clear()
            try:
                await asyncio.wait_for(self._arrived.wait(), settle)
                continue
            except TimeoutError:
                pass
            for _ in range(3):
                await asyncio.sleep(0)
            if not self._arrived.is_set():
                return

    def trace_text(self) -> str:
        """The wire trace (:mod:`tango_aio.fieldkit._trace`'s format)."""
        lines = [trace_header()]
        lines += [format_record(t, "->" if d == "->" else "<-", data)
                  for t, d, data in self.records]
        return "\n".join(lines) + "\n"
