"""Finding TANGO controllers: :func:`discover` probes serial ports concurrently with
``?version`` and lists the controllers that answer (:class:`DiscoveredController`);
:func:`probe_ports` gives a result for every port probed (:class:`PortProbe`), so that a
port that could not be opened is told apart from one where nothing answered.

Each probe runs in a worker thread (pyserial's blocking API): open the port exclusively at
the given baud rate (57600,8,2,N by default, manual L10), write ``?version``, read lines until a
version reply or the timeout, close. A probe stuck in the operating system is abandoned
after the timeout plus a grace period, so :func:`discover` always returns in bounded time.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass

import anyio

from ..catalog import VersionInfo, parse, parse_reply
from ..controller import DEFAULT_BAUD, port_error
from ..errors import PortBusyError, PortNotFoundError, PortPermissionError, TangoError

__all__ = ["DiscoveredController", "PortProbe", "discover", "probe_ports"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class DiscoveredController:
    """A TANGO controller found by :func:`discover`.

    ``port`` is the device path (pass it to :func:`~tango_aio.connect`); ``model`` and
    ``firmware`` come from its ``?version`` reply (``version``). ``description`` and
    ``hwid`` are what the operating system says about the port (empty for ports given
    explicitly).
    """

    port: str
    model: str
    firmware: str
    version: VersionInfo
    description: str = ""
    hwid: str = ""


@dataclass(frozen=True, slots=True)
class PortProbe:
    """What probing one port found (:func:`probe_ports`).

    ``result`` is a few words for the user: ``TANGO <model> <firmware>``, ``no answer``,
    ``permission denied (add yourself to the dialout group)``, ``busy (held by another
    program)``, ``not found``, ``stuck (abandoned)`` or ``cannot open: <reason>``.
    ``controller`` is set when a TANGO answered; ``error`` is the error that kept the port
    from being probed, if any.
    """

    port: str
    result: str
    controller: DiscoveredController | None = None
    error: BaseException | None = None


#: Probe results for ports that could not be opened, by the class of their error.
NOT_FOUND = "not found"
PERMISSION_DENIED = "permission denied (add yourself to the dialout group)"
BUSY = "busy (held by another program)"
NO_ANSWER = "no answer"
STUCK = "stuck (abandoned)"


def _result_of_error(port: str, exc: BaseException) -> str:
    """A probe's error in a few words (the user's terms of :func:`port_error`)."""
    error = port_error(port, exc) if not isinstance(exc, TangoError) else exc
    if isinstance(error, PortNotFoundError):
        return NOT_FOUND
    if isinstance(error, PortPermissionError):
        return PERMISSION_DENIED
    if isinstance(error, PortBusyError):
        return BUSY
    return str(error).replace(f"{port}: ", "", 1)


_VERSION = parse("?version")
_PROBE_LINE = b"?version\r"
#: Seconds beyond ``timeout`` after which a probe thread that is stuck (e.g. in ``open``)
#: is abandoned.
_PROBE_GRACE = 0.5
#: Probes that run at once, in their own worker threads.
_PROBE_THREADS = 32


def _version_of(raw: bytes) -> VersionInfo | None:
    """The :class:`VersionInfo` of a full ``?version`` reply line, else ``None``."""
    text = raw.decode("ascii", "replace").strip()
    if "Version" not in text:
        return None
    try:
        info = parse_reply(_VERSION, [text])
    except (TangoError, ValueError):
        return None
    return info if isinstance(info, VersionInfo) and info.model else None


def _probe(port: str, baudrate: int, timeout: float) -> VersionInfo | None:
    """Open ``port``, ask ``?version`` and wait up to ``timeout`` s for a version reply."""
    import serial

    start = time.monotonic()
    with serial.serial_for_url(port, baudrate=baudrate, bytesize=8, parity="N",
                               stopbits=2, timeout=timeout, write_timeout=timeout,
                               exclusive=True) as link:
        link.reset_input_buffer()
        for deadline in (start + timeout / 2, start + timeout):
            link.write(_PROBE_LINE)
            while (remaining := deadline - time.monotonic()) > 0:
                link.timeout = remaining
                line = link.read_until(b"\r", 256)
                if not line.endswith(b"\r"):
                    if len(line) < 256:
                        break  # timed out
                    continue  # noise without line ends
                version = _version_of(line)
                if version is not None:
                    return version
    return None


async def discover(*, timeout: float = 0.5, ports: Iterable[str] | None = None,
                   baudrate: int = DEFAULT_BAUD) -> list[DiscoveredController]:
    """Find the TANGO controllers on this machine's serial ports.

    Lists the serial ports (``serial.tools.list_ports.comports()``), or takes ``ports``,
    and probes them all concurrently (:func:`probe_ports`), each in a worker thread: open
    at ``baudrate`` 8N2 (exclusively, so ports locked by another program are skipped),
    write ``?version``, read the reply, close. A port counts as a TANGO controller when it
    answers ``<model>, Version <firmware>, ...`` within ``timeout`` seconds. Returns the
    controllers found, in port order; returns in about ``timeout`` seconds even if a
    port's driver hangs (the stuck thread is abandoned). Ports that cannot be opened are
    logged at INFO level with the reason (permission denied, busy, not found);
    :func:`probe_ports` returns the result of every port.

    The probe writes a line to every port listed: on a port where another device is
    connected that line reaches it. Do not probe a port that a driver has open; its
    reply stream would be disturbed.

    Parameters
    ----------
    timeout
        Seconds to wait for each port's reply.
    ports
        The ports to probe; ``None`` for every serial port listed.
    baudrate
        The baud rate to open them at.

    Returns
    -------
    list[DiscoveredController]
        The controllers found, in port order.
    """
    results = await probe_ports(timeout=timeout, ports=ports, baudrate=baudrate)
    for result in results:
        if result.error is not None:
            log.info("discover: %s: %s", result.port, result.result)
    return [result.controller for result in results if result.controller is not None]


async def probe_ports(*, timeout: float = 0.5, ports: Iterable[str] | None = None,
                      baudrate: int = DEFAULT_BAUD) -> list[PortProbe]:
    """Probe serial ports as :func:`discover` does and return one :class:`PortProbe` per
    port, in port order: what answered, or why nothing did (``no answer``,
    ``permission denied ...``, ``busy ...``, ``not found``).

    Parameters
    ----------
    timeout
        Seconds to wait for each port's reply.
    ports
        The ports to probe; ``None`` for every serial port listed.
    baudrate
        The baud rate to open them at.

    Returns
    -------
    list[PortProbe]
        One result per port, in port order.
    """
    if ports is None:
        from serial.tools import list_ports

        infos = await anyio.to_thread.run_sync(list_ports.comports)
        candidates = [(info.device, info.description or "", info.hwid or "")
                      for info in infos]
    else:
        candidates = [(port, "", "") for port in dict.fromkeys(ports)]
    found: dict[int, PortProbe] = {}
    limiter = anyio.CapacityLimiter(_PROBE_THREADS)

    async def probe(index: int, port: str, description: str, hwid: str) -> None:
        version = None
        with anyio.move_on_after(timeout + _PROBE_GRACE) as scope:
            try:
                version = await anyio.to_thread.run_sync(
                    _probe, port, baudrate, timeout, abandon_on_cancel=True, limiter=limiter)
            except Exception as exc:
                log.debug("discover: %s: %r", port, exc)
                found[index] = PortProbe(port, _result_of_error(port, exc), error=exc)
                return
        if scope.cancelled_caught:
            log.debug("discover: %s: probe stuck, abandoned", port)
            found[index] = PortProbe(port, STUCK)
        elif version is None:
            log.debug("discover: %s: no TANGO reply within %.2f s", port, timeout)
            found[index] = PortProbe(port, NO_ANSWER)
        else:
            controller = DiscoveredController(port, version.model, version.firmware,
                                              version, description, hwid)
            found[index] = PortProbe(port, f"TANGO {version.model} {version.firmware}",
                                     controller)

    async with anyio.create_task_group() as tg:
        for index, (port, description, hwid) in enumerate(candidates):
            tg.start_soon(probe, index, port, description, hwid)
    return [found[index] for index in sorted(found)]
