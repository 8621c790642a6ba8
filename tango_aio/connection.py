"""``tango_aio.connect()``: open a link to a controller and set it up.

URLs:

* a serial device (``/dev/ttyUSB0``, ``COM3``), opened at 57600 Bd 8N2 by default;
* any pyserial URL (``rfc2217://``, ``loop://``, ...);
* ``socket://host:port`` for ser2net and terminal servers (a plain asyncio TCP connection);
* ``sim://`` for the in-process emulator, options in the query
  (``sim://?axes=3&baud=57600``).

Opening is cancel-safe: a ``connect()`` cancelled at any point closes what it opened
(the serial port, even while it is being opened in a thread; the socket; the emulator).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import urllib.parse
from collections.abc import Callable, Generator
from types import TracebackType
from typing import Any

from .controller import Controller
from .errors import ConnectionLostError
from .flow import DEFAULT_CHUNK, DEFAULT_LIMIT
from .protocol import TangoProtocol
from .reconnect import Closer, Reconnect, ReconnectPolicy

__all__ = ["DEFAULT_BAUD", "Connecting", "connect"]

#: The TANGO's default line settings: 57600 Bd, 8 data bits, no parity, 2 stop bits (L8-10).
DEFAULT_BAUD = 57600

ProtocolFactory = Callable[[], TangoProtocol]


async def _open_serial(url: str, factory: ProtocolFactory, *, baudrate: int,
                       rtscts: bool) -> tuple[asyncio.BaseTransport, TangoProtocol]:
    import serial
    import serial_asyncio

    def open_port() -> Any:
        # pyserial-asyncio 0.6 opens the port on the event loop, which blocks; open it
        # in a thread instead and hand the open port over. ``exclusive``: a second program
        # (or a second connect()) writing to the same controller would interleave lines
        # and steal replies, so the port is locked (flock on POSIX; Windows ports are
        # exclusive anyway); URL handlers such as loop:// accept and ignore it.
        port = serial.serial_for_url(url, baudrate=baudrate, bytesize=8, parity="N",
                                     stopbits=2, rtscts=rtscts, timeout=0, exclusive=True)
        try:
            port.reset_input_buffer()
        except BaseException:
            port.close()
            raise
        return port

    try:
        port = await _in_thread(open_port)
    except (OSError, serial.SerialException) as exc:
        raise ConnectionLostError(f"cannot open {url!r}: {exc}") from exc
    loop = asyncio.get_running_loop()
    try:
        transport, protocol = await serial_asyncio.connection_for_serial(loop, factory, port)
    except BaseException:
        port.close()
        raise
    return transport, protocol


async def _in_thread(open_port: Callable[[], Any]) -> Any:
    """Run ``open_port`` in a thread; if the caller is cancelled meanwhile, the thread
    still finishes (threads cannot be interrupted), and the port it opened is closed."""
    task = asyncio.ensure_future(asyncio.to_thread(open_port))
    try:
        return await asyncio.shield(task)
    except asyncio.CancelledError:
        task.add_done_callback(_close_opened)
        raise


def _close_opened(task: asyncio.Future[Any]) -> None:
    if not task.cancelled() and task.exception() is None:
        task.result().close()


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


async def _open_link(url: str, make: ProtocolFactory, options: dict[str, Any]
                     ) -> tuple[TangoProtocol, Closer | None]:
    """Open ``url`` and wait until the protocol is connected; on any failure, including
    cancellation, close whatever was opened (no leaked port, socket or emulator task)."""
    made: list[TangoProtocol] = []

    def factory() -> TangoProtocol:
        made.append(make())
        return made[-1]

    closer: Closer | None = None
    try:
        protocol, closer = await _open(url, factory, options)
        await protocol.wait_connected()
    except BaseException:
        await _discard(made, closer)
        raise
    return protocol, closer


async def _discard(made: list[TangoProtocol], closer: Closer | None) -> None:
    """Close the transports of ``made`` (a transport not yet handed to its protocol is
    closed when it is, see :meth:`TangoProtocol.connection_made`) and run ``closer``."""
    for protocol in made:
        protocol.close()
        wait_closed = getattr(protocol.transport, "wait_closed", None)
        if closer is None and wait_closed is not None:  # the sim:// emulator task
            with contextlib.suppress(Exception):
                await asyncio.shield(wait_closed())
    if closer is not None:
        with contextlib.suppress(Exception):
            await asyncio.shield(closer())


def _reconnect_policy(options: dict[str, Any]) -> ReconnectPolicy | None:
    """Take the ``reconnect*`` options out of ``options`` (validated before opening)."""
    enabled = bool(options.pop("reconnect", False))
    policy = ReconnectPolicy(initial=float(options.pop("reconnect_initial", 0.1)),
                             maximum=float(options.pop("reconnect_max", 5.0)),
                             attempts=options.pop("reconnect_attempts", None))
    return policy if enabled else None


async def _connect(url: str, *, autostatus: int | None = 1, identify: bool = True,
                   reply_timeout: float = 5.0, credit_limit: int = DEFAULT_LIMIT,
                   marker_chunk: int = DEFAULT_CHUNK, **options: Any) -> Controller:
    liveness = {name: options.pop(name) for name in ("dead_after", "keepalive")
                if name in options}

    def factory() -> TangoProtocol:
        return TangoProtocol(credit_limit=credit_limit, marker_chunk=marker_chunk,
                             reply_timeout=reply_timeout, detect=True, **liveness)

    policy = _reconnect_policy(options)
    opener = functools.partial(_open_link, url, factory, options)
    protocol, closer = await opener()
    controller = Controller(protocol, url=url, reply_timeout=reply_timeout, on_close=closer)
    try:
        await controller.setup(autostatus=autostatus, identify=identify)
    except BaseException:
        await controller.aclose()
        raise
    if policy is not None:  # only once set up: a failing first connect() just raises
        controller._enable_reconnect(Reconnect(policy, opener, identify))
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

    Options: ``baudrate`` (57600), ``rtscts`` (False) for serial ports, which are opened
    exclusively (a second open of the same port fails); ``autostatus`` (1; ``None`` keeps
    the controller's mode), ``identify`` (True), ``reply_timeout`` (5.0 s: a request
    unanswered for that long raises ControllerTimeoutError after the stream was
    resynchronised); ``credit_limit`` (255 bytes written but not yet processed, at most)
    and ``marker_chunk`` (160 reply-less bytes between ``err`` markers) for flow control;
    ``dead_after`` (2) consecutive requests without a reply (a request's own timeout, then
    its resync marker's) declare a link that stays open lost (ConnectionLostError, and a
    reconnect when enabled), and ``keepalive`` (None; seconds) probes an idle link with
    ``?autostatus`` so that a dead link, or a controller that restarted behind an adapter
    that stayed up (its mode is restored), is noticed without traffic of the caller's.

    Automatic reconnect (off by default): ``reconnect=True`` keeps the Controller usable
    across link losses. After a loss it waits ``reconnect_initial`` (0.1 s), opens the same
    URL again, resynchronises, checks that the same model and firmware answer (else it
    stops with :class:`~tango_aio.reconnect.IdentityMismatchError` as the cause), selects
    the autostatus mode that was in force and publishes
    :class:`~tango_aio.events.Reconnected`; each failed attempt doubles the wait, up to
    ``reconnect_max`` (5.0 s), for at most ``reconnect_attempts`` attempts (``None``: until
    :meth:`~tango_aio.controller.Controller.aclose`). What was in flight at the loss fails
    with ConnectionLostError and is not retried; calls made while the link is down fail at
    once with ConnectionLostError (``await tango.wait_connected(timeout)`` waits instead).
    """
    return Connecting(url, options)
