"""``tango_aio.connect()``: open a link to a controller and set it up.

URLs:

* a serial device (``/dev/ttyUSB0``, ``COM3``), opened at 57600 Bd 8N2 by default;
* any pyserial URL (``rfc2217://``, ``loop://``, ...);
* ``socket://host:port`` for ser2net and terminal servers (a plain asyncio TCP connection);
* ``sim://`` for the in-process emulator, options in the query
  (``sim://?axes=3&baud=57600``).
"""

from __future__ import annotations

import asyncio
import urllib.parse
from collections.abc import Awaitable, Callable, Generator
from types import TracebackType
from typing import Any

from .controller import Controller
from .errors import ConnectionLostError
from .flow import DEFAULT_CHUNK, DEFAULT_LIMIT
from .protocol import TangoProtocol

__all__ = ["DEFAULT_BAUD", "Connecting", "connect"]

#: The TANGO's default line settings: 57600 Bd, 8 data bits, no parity, 2 stop bits (L8-10).
DEFAULT_BAUD = 57600

ProtocolFactory = Callable[[], TangoProtocol]
Closer = Callable[[], Awaitable[None]]


async def _open_serial(url: str, factory: ProtocolFactory, *, baudrate: int,
                       rtscts: bool) -> tuple[asyncio.BaseTransport, TangoProtocol]:
    import serial
    import serial_asyncio

    def open_port() -> Any:
        # pyserial-asyncio 0.6 opens the port on the event loop, which blocks; open it
        # in a thread instead and hand the open port over.
        port = serial.serial_for_url(url, baudrate=baudrate, bytesize=8, parity="N",
                                     stopbits=2, rtscts=rtscts, timeout=0)
        port.reset_input_buffer()
        return port

    try:
        port = await asyncio.to_thread(open_port)
    except (OSError, serial.SerialException) as exc:
        raise ConnectionLostError(f"cannot open {url!r}: {exc}") from exc
    loop = asyncio.get_running_loop()
    transport, protocol = await serial_asyncio.connection_for_serial(loop, factory, port)
    return transport, protocol


async def _open_socket(url: str, factory: ProtocolFactory
                       ) -> tuple[asyncio.BaseTransport, TangoProtocol]:
    parts = urllib.parse.urlsplit(url)
    if not parts.hostname or not parts.port:
        raise ValueError(f"socket URL needs host and port: {url!r}")
    loop = asyncio.get_running_loop()
    try:
        return await loop.create_connection(factory, parts.hostname, parts.port)
    except OSError as exc:
        raise ConnectionLostError(f"cannot connect to {url!r}: {exc}") from exc


async def _open(url: str, factory: ProtocolFactory, options: dict[str, Any]
                ) -> tuple[TangoProtocol, Closer | None]:
    if url.startswith("sim://"):
        from .sim.inprocess import open_sim

        return await open_sim(url, factory)
    if url.startswith("socket://"):
        _, protocol = await _open_socket(url, factory)
        return protocol, None
    baudrate = int(options.get("baudrate", DEFAULT_BAUD))
    rtscts = bool(options.get("rtscts", False))
    _, protocol = await _open_serial(url, factory, baudrate=baudrate, rtscts=rtscts)
    return protocol, None


async def _connect(url: str, *, autostatus: int | None = 1, identify: bool = True,
                   reply_timeout: float = 5.0, credit_limit: int = DEFAULT_LIMIT,
                   marker_chunk: int = DEFAULT_CHUNK, **options: Any) -> Controller:
    def factory() -> TangoProtocol:
        return TangoProtocol(credit_limit=credit_limit, marker_chunk=marker_chunk)

    protocol, closer = await _open(url, factory, options)
    await protocol.wait_connected()
    controller = Controller(protocol, url=url, reply_timeout=reply_timeout, on_close=closer)
    try:
        await controller.setup(autostatus=autostatus, identify=identify)
    except BaseException:
        await controller.aclose()
        raise
    return controller


class Connecting:
    """What :func:`connect` returns: await it, or use it with ``async with``."""

    def __init__(self, url: str, options: dict[str, Any]) -> None:
        self._url = url
        self._options = options
        self._controller: Controller | None = None

    def __await__(self) -> Generator[Any, None, Controller]:
        return _connect(self._url, **self._options).__await__()

    async def __aenter__(self) -> Controller:
        self._controller = await _connect(self._url, **self._options)
        return self._controller

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._controller is not None:
            await self._controller.aclose()


def connect(url: str = "sim://", **options: Any) -> Connecting:
    """Connect to a TANGO controller.

    ``async with tango_aio.connect("/dev/ttyUSB0") as tango: ...`` or
    ``tango = await tango_aio.connect("sim://?axes=3")`` then ``await tango.aclose()``.

    Options: ``baudrate`` (57600), ``rtscts`` (False) for serial ports; ``autostatus``
    (1; ``None`` keeps the controller's mode), ``identify`` (True), ``reply_timeout``
    (5.0 s); ``credit_limit`` (255 bytes written but not yet processed, at most) and
    ``marker_chunk`` (160 reply-less bytes between ``err`` markers) for flow control.
    """
    return Connecting(url, options)
