"""``tango_aio.connect()``: open a link to a controller and set it up."""

from __future__ import annotations

import asyncio
import collections.abc
import contextlib
import errno
import functools
import logging
import os
import re
import socket
import sys
import urllib.parse
from collections.abc import Callable, Generator
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from .._checks import check_count, check_timeout
from .._platform import POSIX, WINDOWS
from ..errors import (
    ConnectError,
    ControllerTimeoutError,
    NoControllerError,
    PortBusyError,
    PortNotFoundError,
    PortPermissionError,
)
from ..link import DEAD_AFTER, Closer, Reconnect, ReconnectPolicy, TangoProtocol
from ..sansio import DEFAULT_CHUNK, DEFAULT_LIMIT, CreditWindow, byte_time
from ..transports import FdTransport
from ..units import check_unit
from ._controller import Controller

__all__ = ["DEFAULT_BAUD", "ConnectOptions", "Connecting", "connect"]

#: The TANGO's default line settings: 57600 Bd, 8 data bits, no parity, 2 stop bits (L8-10).
DEFAULT_BAUD = 57600

ProtocolFactory = Callable[[], TangoProtocol]

log = logging.getLogger("tango_aio")


#: Longest wait in :meth:`Controller.aclose` for a serial port to be released (seconds).
RELEASE_WAIT = 5.0


async def _open_serial(url: str, factory: ProtocolFactory, *, baudrate: int, rtscts: bool
                       ) -> tuple[asyncio.BaseTransport, TangoProtocol, Closer]:
    import serial
    import serial_asyncio_fast

    def open_port() -> Any:
        # Opened in a thread, not on the event loop (opening can block). ``exclusive``: a
        # second program (or a second connect()) writing to the same controller would
        # interleave lines and steal replies, so the port is locked (flock on POSIX;
        # Windows opens a COM port for one program at a time anyway, so pyserial takes no
        # lock there); URL handlers such as loop:// accept and ignore it.
        port = serial.serial_for_url(url, baudrate=baudrate, bytesize=8, parity="N",
                                     stopbits=2, rtscts=rtscts, timeout=0, exclusive=True)
        try:
            _check_pollable(port)
            port.reset_input_buffer()
        except BaseException:
            port.close()
            raise
        return port

    try:
        port = await _in_thread(open_port)
    except (OSError, serial.SerialException) as exc:
        raise port_error(url, exc) from exc
    loop = asyncio.get_running_loop()
    released = _watch_release(port, loop)
    try:
        if POSIX and type(port) is serial.Serial:
            # A plain POSIX port: its descriptor read and written directly (fewer system calls per
            # reply than pyserial-asyncio's select-then-read, tango_aio/transports/_fdlink.py).
            protocol = factory()
            transport: asyncio.BaseTransport = FdTransport(loop, protocol, port)
        elif WINDOWS:
            # Windows: a reader and a writer thread around pyserial's blocking calls, not
            # pyserial-asyncio's 0.5 ms polling (tango_aio/transports/_threadlink.py).
            protocol = factory()
            transport = _thread_transport(loop, protocol, port)
        else:
            transport, made = await serial_asyncio_fast.connection_for_serial(
                loop, factory, port)
            assert isinstance(made, TangoProtocol)
            protocol = made
    except BaseException:
        port.close()
        raise

    async def release() -> None:
        """Close the transport and return once the port itself is closed (and its lock
        released): both transports close it in a worker thread after
        ``transport.close()`` returned, and a ``connect()`` to the same port right after
        ``aclose()`` must not find it still locked."""
        transport.close()
        try:
            await asyncio.wait_for(asyncio.shield(released), RELEASE_WAIT)
        except TimeoutError:
            log.warning("%s: the port was not released within %.0f s", url, RELEASE_WAIT)

    return transport, protocol, release


def _thread_transport(loop: asyncio.AbstractEventLoop, protocol: TangoProtocol,
                      port: Any) -> asyncio.BaseTransport:
    """The Windows serial transport (imported here: POSIX never needs it)."""
    from ..transports import ThreadTransport

    return ThreadTransport(loop, protocol, port)


#: errno values of a port that is not there, is not ours, is held by another program.
_MISSING = {errno.ENOENT, errno.ENODEV, errno.ENXIO}
_DENIED = {errno.EACCES, errno.EPERM}
_HELD = {errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY}


def port_error(url: str, exc: BaseException) -> ConnectError:
    """The :class:`ConnectError` for a failure to open the serial port ``url``, in the
    user's terms with the next step. pyserial repeats the errno in its messages ("[Errno
    2] could not open port ...: [Errno 2] ..."), so only the operating system's words are
    kept."""
    number = getattr(exc, "errno", None)
    if not isinstance(number, int):
        number = next((arg for arg in getattr(exc, "args", ()) if isinstance(arg, int)), None)
    text = str(exc)
    if number in _MISSING or "FileNotFoundError" in text:
        return PortNotFoundError(f"no serial port {url}: is the adapter plugged in, is the "
                                 f"name right? `tango-aio ports` lists the serial ports",
                                 url)
    if number in _DENIED and "lock" not in text.lower():
        return PortPermissionError(f"permission denied for {url}: {_permission_advice(url)}",
                                   url)
    if number in _HELD or "exclusively lock" in text or (
            WINDOWS and "PermissionError" in text):  # Windows: in use is EACCES
        return PortBusyError(f"{url} is busy: another program holds it (a tango-aio shell, "
                             f"a terminal program, another connect()); close that first",
                             url)
    reason = os.strerror(number) if number is not None else \
        re.sub(r"\[Errno -?\d+\] ?", "", text)
    return ConnectError(f"cannot open {url}: {reason}", url)


def _permission_advice(url: str) -> str:
    # The dialout group is the answer for a serial adapter on Linux, not for a pty or a file.
    if WINDOWS:
        return "another user or program may own it; close that program, or run as its user"
    if sys.platform.startswith("linux") and re.match(r"/dev/tty(USB|ACM|S|AMA|XRUSB)\d", url):
        return ("add yourself to the dialout group (sudo usermod -aG dialout $USER) and "
                "log in again")
    return f"this user may not read and write it; see its owner and mode with ls -l {url}"


def check_url(url: str) -> None:
    """Raise ValueError for a URL that names a scheme the driver does not open (before
    anything is opened): ``tcp://`` and the like suggest ``socket://``; ``sim:/`` and
    other almost-URLs are not taken for device paths."""
    match = re.match(r"([A-Za-z][A-Za-z0-9+.-]+):(/*)", url)
    if match is None:
        return
    scheme, slashes = match.group(1).lower(), match.group(2)
    if scheme in ("tcp", "telnet", "ip", "tcpip", "ser2net", "raw"):
        rest = url[match.end():]
        raise ValueError(f"{url!r}: for a TCP connection (ser2net, a terminal server) "
                         f"write socket://{rest or 'HOST:PORT'}")
    if scheme in ("sim", "socket") and slashes != "//":
        raise ValueError(f"{url!r}: write {scheme}://{url[match.end():]}")
    if scheme == "socket":
        _socket_address(url)


def _socket_address(url: str) -> tuple[str, int]:
    """``socket://HOST:PORT``'s host and port, or a ValueError that says what to write."""
    parts = urllib.parse.urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if not parts.hostname or port is None or not 0 < port < 65536:
        raise ValueError(f"{url!r}: write socket://HOST:PORT, with PORT a number 1-65535 "
                         f"(e.g. socket://127.0.0.1:4001)")
    return parts.hostname, port


def _watch_release(port: Any, loop: asyncio.AbstractEventLoop) -> asyncio.Future[None]:
    """A future that is done once ``port.close()`` has returned, in whatever thread."""
    released: asyncio.Future[None] = loop.create_future()
    close = port.close

    def set_released() -> None:
        if not released.done():
            released.set_result(None)

    def close_and_tell() -> None:
        try:
            close()
        finally:
            with contextlib.suppress(RuntimeError):  # the loop is already closed
                loop.call_soon_threadsafe(set_released)

    port.close = close_and_tell
    return released


def _check_pollable(port: Any) -> None:
    """pyserial-asyncio watches the port's file descriptor on POSIX; URL handlers without
    one (``loop://``, ``spy://`` of such) would fail later inside the event loop."""
    if not POSIX:
        return
    try:
        port.fileno()
    except (OSError, AttributeError):
        raise OSError("this kind of port has no file descriptor, which asyncio needs "
                      "to read it") from None


async def _in_thread(open_port: Callable[[], Any]) -> Any:
    """Run ``open_port`` in a thread; if the caller is cancelled meanwhile, the thread
    still finishes (threads cannot be interrupted), and the port it opened is closed
    before the cancellation goes on: a connect() to the same port right after must not
    find it locked. Cancelled again while it waits, it leaves the closing to the thread's
    end."""
    task = asyncio.ensure_future(asyncio.to_thread(open_port))
    try:
        return await asyncio.shield(task)
    except asyncio.CancelledError:
        task.add_done_callback(_close_opened)  # runs before asyncio.wait's own callback
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.wait([task])
        raise


def _close_opened(task: asyncio.Future[Any]) -> None:
    if not task.cancelled() and task.exception() is None:
        task.result().close()


async def _open_socket(url: str, factory: ProtocolFactory
                       ) -> tuple[asyncio.BaseTransport, TangoProtocol]:
    host, port = _socket_address(url)
    loop = asyncio.get_running_loop()
    try:
        return await loop.create_connection(factory, host, port)
    except socket.gaierror as exc:  # its errno is the resolver's, not the system's
        raise ConnectError(f"cannot connect to {url}: the host name {host!r} does not "
                           f"resolve ({exc.strerror}); check the name, or give the "
                           f"address (socket://192.0.2.10:{port})", url) from exc
    except OSError as exc:
        reason = os.strerror(exc.errno) if exc.errno else str(exc) or type(exc).__name__
        raise ConnectError(f"cannot connect to {url}: {reason} (is the server running, "
                           f"are host and port right?)", url) from exc


async def _open(url: str, factory: ProtocolFactory, options: dict[str, Any]
                ) -> tuple[TangoProtocol, Closer | None]:
    if url.startswith("sim://"):
        from ..sim.inprocess import configs_from_url, open_sim

        protocol, closer = await open_sim(url, factory)
        baud = configs_from_url(url)[1].baud
        if baud:  # the emulator's wire carries bytes at this rate, both ways
            protocol.wire_paced(byte_time(baud))
        return protocol, closer
    if url.startswith("socket://"):
        _, protocol = await _open_socket(url, factory)
        return protocol, None
    _, protocol, release = await _open_serial(url, factory, baudrate=options["baudrate"],
                                              rtscts=options["rtscts"])
    return protocol, release


async def open_link(url: str, make: ProtocolFactory, options: dict[str, Any]
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


@dataclass(frozen=True, slots=True)
class ConnectOptions:
    """The options of one :func:`connect` call, checked before anything is opened."""

    baudrate: int = DEFAULT_BAUD
    rtscts: bool = False
    autostatus: int | None = 1
    identify: bool = True
    reply_timeout: float = 5.0
    credit_limit: int = DEFAULT_LIMIT
    marker_chunk: int = DEFAULT_CHUNK
    reconnect: bool = False
    reconnect_initial: float = 0.1
    reconnect_max: float = 5.0
    reconnect_attempts: int | None = None
    units: str | None = None
    dead_after: int = DEAD_AFTER
    keepalive: float | None = None

    def __post_init__(self) -> None:
        check_count(self.baudrate, "baudrate")
        if self.autostatus is not None and self.autostatus not in range(5):
            raise ValueError(f"autostatus must be None or 0..4, got {self.autostatus!r}")
        check_timeout(self.reply_timeout, "reply_timeout")
        check_count(self.credit_limit, "credit_limit")
        check_count(self.marker_chunk, "marker_chunk")
        CreditWindow(self.credit_limit, self.marker_chunk)  # its own limits, e.g. too small
        if self.units is not None:
            check_unit(self.units)
        check_count(self.dead_after, "dead_after", minimum=2)
        if self.keepalive is not None:
            check_timeout(self.keepalive, "keepalive")
        self.policy()  # checks the reconnect options

    def policy(self) -> ReconnectPolicy | None:
        """The reconnect policy, or ``None`` when reconnecting is off.

        Returns
        -------
        ReconnectPolicy or None
            The policy of the ``reconnect_*`` options.
        """
        policy = ReconnectPolicy(initial=self.reconnect_initial, maximum=self.reconnect_max,
                                 attempts=self.reconnect_attempts)
        return policy if self.reconnect else None


async def _connect(url: str, options: ConnectOptions) -> Controller:
    def factory() -> TangoProtocol:
        protocol = TangoProtocol(credit_limit=options.credit_limit,
                                 marker_chunk=options.marker_chunk,
                                 reply_timeout=options.reply_timeout, detect=True,
                                 dead_after=options.dead_after, keepalive=options.keepalive)
        if not url.startswith(("sim://", "socket://")):  # a serial port opened at baudrate
            protocol.session.baud_known(byte_time(options.baudrate))
        return protocol

    policy = options.policy()
    opener = functools.partial(open_link, url, factory,
                               {"baudrate": options.baudrate, "rtscts": options.rtscts})
    protocol, closer = await opener()
    # Reconnecting is armed once setup() succeeded: a failing first connect() just raises.
    controller = Controller(protocol, url=url, reply_timeout=options.reply_timeout,
                            on_close=closer, reconnect=None if policy is None else Reconnect(
                                policy, opener, options.identify))
    controller.units = options.units
    try:
        await controller.setup(autostatus=options.autostatus, identify=options.identify)
    except ControllerTimeoutError as exc:
        await controller.aclose()
        raise _no_controller(url, options) from exc
    except BaseException:
        await controller.aclose()
        raise
    return controller


def _no_controller(url: str, options: ConnectOptions) -> NoControllerError:
    """Nothing answered while :func:`connect` set the controller up: said in the user's
    terms (not the lines the driver sent)."""
    where = url if url.startswith(("sim://", "socket://", "rfc2217://")) \
        else f"{url} at {options.baudrate} Bd"
    return NoControllerError(f"no TANGO answered on {where}: is it switched on, is this "
                             f"its port? `tango-aio ports --probe` lists the ports that "
                             f"answer", url)


class Connecting(collections.abc.Coroutine[Any, Any, Controller]):
    """What :func:`connect` returns: await it, use it with ``async with``, or hand it to
    anything that takes a coroutine (``asyncio.run(tango_aio.connect(url))``,
    ``asyncio.create_task``): it is one, created lazily, so a ``Connecting`` that is never
    awaited opens nothing and warns about nothing.

    Parameters
    ----------
    url
        The controller's URL.
    options
        The checked options.
    """

    def __init__(self, url: str, options: ConnectOptions) -> None:
        self.url = url
        self.options = options
        self._controller: Controller | None = None
        self._coroutine: collections.abc.Coroutine[Any, Any, Controller] | None = None

    def _started(self) -> collections.abc.Coroutine[Any, Any, Controller]:
        if self._coroutine is None:
            self._coroutine = _connect(self.url, self.options)
        return self._coroutine

    def __await__(self) -> Generator[Any, None, Controller]:
        return self._started().__await__()

    def send(self, value: Any) -> Any:
        """Coroutine protocol: resume the connection attempt.

        Parameters
        ----------
        value
            The value to resume it with.

        Returns
        -------
        Any
            What the attempt yields next.
        """
        return self._started().send(value)

    def throw(self, typ: Any, val: Any = None, tb: Any = None) -> Any:
        """Coroutine protocol: raise an exception inside the connection attempt.

        Parameters
        ----------
        typ
            The exception (or its type) to raise inside.
        val, tb
            The legacy value and traceback arguments.

        Returns
        -------
        Any
            What the attempt yields next.
        """
        if val is None and tb is None:
            return self._started().throw(typ)
        return self._started().throw(typ, val, tb)  # pragma: no cover - legacy signature

    def close(self) -> None:
        """Coroutine protocol: abandon the connection attempt (nothing to do if it never
        started)."""
        if self._coroutine is not None:
            self._coroutine.close()

    async def __aenter__(self) -> Controller:
        self._controller = await _connect(self.url, self.options)
        return self._controller

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._controller is not None:
            await self._controller.aclose()


def connect(url: str = "sim://", *, baudrate: int = DEFAULT_BAUD, rtscts: bool = False,
            autostatus: int | None = 1, identify: bool = True, reply_timeout: float = 5.0,
            credit_limit: int = DEFAULT_LIMIT, marker_chunk: int = DEFAULT_CHUNK,
            reconnect: bool = False, reconnect_initial: float = 0.1,
            reconnect_max: float = 5.0, reconnect_attempts: int | None = None,
            units: str | None = None, dead_after: int = DEAD_AFTER,
            keepalive: float | None = None) -> Connecting:
    """Connect to a TANGO controller.

    ``async with tango_aio.connect("/dev/ttyUSB0") as tango: ...`` or
    ``tango = await tango_aio.connect("sim://?axes=3")`` then ``await tango.aclose()``.
    Every option is a keyword (a misspelt one raises :class:`TypeError`) and is checked
    before anything is opened (:class:`ValueError`), as is the URL (``tcp://`` is refused
    with a pointer to ``socket://``). A link that cannot be set up raises a
    :class:`~tango_aio.errors.ConnectError`: :class:`~tango_aio.errors.PortNotFoundError`,
    :class:`~tango_aio.errors.PortPermissionError`,
    :class:`~tango_aio.errors.PortBusyError`, :class:`~tango_aio.errors.NoControllerError`
    (nothing answered), or the class itself (e.g. a refused TCP connection).

    Automatic reconnect (off by default): ``reconnect=True`` keeps the Controller usable
    across link losses. After a loss it waits ``reconnect_initial`` (0.1 s), opens the same
    URL again, resynchronises, checks that the same model and firmware answer (else it
    stops with :class:`~tango_aio.link._reconnect.IdentityMismatchError` as the cause), selects
    the autostatus mode that was in force and publishes
    :class:`~tango_aio.events.Reconnected`; each failed attempt doubles the wait, up to
    ``reconnect_max`` (5.0 s), for at most ``reconnect_attempts`` attempts (``None``: until
    :meth:`~tango_aio.Controller.aclose`). What was in flight at the loss fails
    with ConnectionLostError and is not retried; calls made while the link is down fail at
    once with ConnectionLostError (``await tango.wait_connected(timeout)`` waits instead).

    Parameters
    ----------
    url
        A serial device (``/dev/ttyUSB0``, ``COM3``), a pyserial URL, ``socket://host:port``
        or ``sim://`` (see the module).
    baudrate
        The baud rate of a serial port (57600). Serial ports are opened exclusively (a
        second open of the same port fails).
    rtscts
        RTS/CTS handshake on a serial port (False).
    autostatus
        The autostatus mode to select (1; ``None`` keeps the controller's mode).
    identify
        Read the controller's identity when connecting (True).
    reply_timeout
        Seconds (5.0): a request unanswered for that long raises ControllerTimeoutError
        after the stream was resynchronised.
    credit_limit
        Flow control: at most this many bytes (255) written but not yet processed.
    marker_chunk
        Flow control: at most this many reply-less bytes (160) between ``err`` markers.
    reconnect
        Reconnect automatically after a link loss (False), described above.
    reconnect_initial
        Seconds to wait before the first attempt (0.1).
    reconnect_max
        The longest wait between two attempts, in seconds (5.0).
    reconnect_attempts
        The most attempts after a loss (``None``: until the controller is closed).
    units
        The physical unit of positions for the whole connection (``"mm"``, ``"um"``, ...;
        see :mod:`tango_aio.units`; ``None``: the controller's ``dim`` unit); velocities
        are then in ``units`` per second, accelerations per second squared.
    dead_after
        Consecutive requests without a reply (2; a request's own timeout, then its resync
        marker's) that declare a link that stays open lost (ConnectionLostError, and a
        reconnect when enabled).
    keepalive
        Seconds (``None``: off) after which an idle link is probed with ``?autostatus``, so
        that a dead link, or a controller that restarted behind an adapter that stayed up
        (its mode is restored), is noticed without traffic of the caller's.

    Returns
    -------
    Connecting
        Await it for the connected :class:`~tango_aio.Controller`, or use it as
        an async context manager.

    Raises
    ------
    TypeError
        An unknown option (raised by Python at the call).
    ValueError
        An invalid option or URL, before anything is opened.
    ConnectError
        When awaited: the link cannot be set up (one of the subclasses above, or the
        class itself).
    """
    check_url(url)
    options = ConnectOptions(
        baudrate=baudrate, rtscts=rtscts, autostatus=autostatus, identify=identify,
        reply_timeout=reply_timeout, credit_limit=credit_limit, marker_chunk=marker_chunk,
        reconnect=reconnect, reconnect_initial=reconnect_initial,
        reconnect_max=reconnect_max, reconnect_attempts=reconnect_attempts, units=units,
        dead_after=dead_after, keepalive=keepalive)
    return Connecting(url, options)
