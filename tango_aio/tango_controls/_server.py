"""Running the Tango Controls device server: connect to the Märzhäuser TANGO, declare the
devices (in a Tango database, or in a file for a server without one), run pytango's server
loop on the event loop the controller was opened on, and close everything at the end.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TextIO

from ..controller import connect

__all__ = ["DEFAULT_PREFIX", "SERVER", "ServerOptions", "device_names", "serve"]

log = logging.getLogger("tango_aio.tango_controls")

#: The server's executable name in the Tango database (``SERVER/instance``).
SERVER = "TangoAio"

#: The default ``DOMAIN/FAMILY`` of the device names.
DEFAULT_PREFIX = "marzhauser/stage"


@dataclass(frozen=True)
class ServerOptions:
    """How to serve one controller.

    ``port`` 0: any free port (with ``nodb``, the port chosen is printed).
    """

    url: str
    prefix: str = DEFAULT_PREFIX
    instance: str = "stage"
    nodb: bool = False
    port: int = 0
    interface: str = "127.0.0.1"
    interval: float = 0.1


def device_names(prefix: str, axes: int) -> tuple[list[str], str]:
    """The axis devices' names and the controller device's name.

    Parameters
    ----------
    prefix
        ``DOMAIN/FAMILY``.
    axes
        How many axes the controller has.

    Returns
    -------
    tuple[list[str], str]
        ``PREFIX/x`` ... and ``PREFIX/controller``.
    """
    return [f"{prefix}/{letter}" for letter in "xyza"[:axes]], f"{prefix}/controller"


def serve(options: ServerOptions, out: TextIO | None = None) -> int:
    """Serve the controller at ``options.url`` until the server is shut down (a signal,
    or the ``Kill`` command of its admin device); blocks.

    Parameters
    ----------
    options
        What to serve, and how.
    out
        Where the one line saying what is served goes (default: stdout).

    Returns
    -------
    int
        0 once the server has shut down cleanly, 130 if Ctrl+C (SIGINT) ended it.
    """
    import tango
    from tango import GreenMode
    from tango.asyncio_executor import AsyncioExecutor, set_global_executor
    from tango.server import run

    from ._axis import StageLink
    from ._device import SERVING, MarzhauserAxis, MarzhauserController

    out = out or sys.stdout
    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    try:
        controller = loop.run_until_complete(connect(options.url, reconnect=True))
        link = StageLink(controller, options.interval)
        axes, controller_name = device_names(options.prefix, len(link.axes))
        for name, axis in zip(axes, link.axes.values(), strict=True):
            SERVING.axes[name.lower()] = axis
        SERVING.controllers[controller_name.lower()] = link
        running: list[asyncio.Task[None]] = []

        async def one_request_at_a_time() -> None:
            # pytango's asyncio mode lets requests run together; one at a time per device
            # lets an event push wait until a request has answered (see Serving).
            tango.Util.instance().set_serial_model(tango.SerialModel.BY_DEVICE)

        async def started() -> None:
            task = loop.create_task(link.run())
            running.append(task)
            # The axes leave INIT before the line says "serving".
            first = loop.create_task(link.first_read.wait())
            await asyncio.wait([first, task], return_when=asyncio.FIRST_COMPLETED)
            first.cancel()
            print(_announce(options, [*axes, controller_name]), file=out, flush=True)

        set_global_executor(AsyncioExecutor(loop=loop))
        with _declared(options, axes, controller_name) as args:
            run((MarzhauserAxis, MarzhauserController), args=args, msg_stream=None,
                green_mode=GreenMode.Asyncio, pre_init_callback=one_request_at_a_time,
                post_init_callback=started, raises=True)
        loop.run_until_complete(_close(link, running))
    finally:
        loop.close()
    return 130 if SERVING.interrupted else 0


async def _close(link: object, running: list[asyncio.Task[None]]) -> None:
    from ._axis import StageLink

    assert isinstance(link, StageLink)
    for axis in link.axes.values():
        axis.publish = _unpublished  # the devices are gone with the server
    for task in running:
        task.cancel()
    with contextlib.suppress(asyncio.CancelledError, Exception):
        await asyncio.gather(*running)
    await link.aclose()
    await link.controller.aclose()
    from ._device import SERVING

    SERVING.pusher.shutdown(wait=False, cancel_futures=True)


def _unpublished(name: str, value: object) -> None:
    """Where an axis publishes once the server has shut down."""


def _announce(options: ServerOptions, names: Sequence[str]) -> str:
    if options.nodb:
        port = options.port or _port()
        where = f"tango://{options.interface}:{port}/NAME#dbase=no"
        return f"serving {', '.join(names)} without a Tango database at {where}"
    return f"serving {', '.join(names)} as {SERVER}/{options.instance}"


def _port() -> int:
    from tango.test_context import get_server_host_port

    return int(get_server_host_port()[1])


@contextlib.contextmanager
def _declared(options: ServerOptions, axes: Sequence[str], controller: str
              ) -> Iterator[list[str]]:
    """The server's command line, the devices declared where the server looks for them:
    a file (no database), or the Tango database (TANGO_HOST), where they are added."""
    endpoint = ["-ORBendPoint", f"giop:tcp:{options.interface}:{options.port or ''}"]
    if not options.nodb:
        _register(options, axes, controller)
        yield [SERVER, options.instance, *endpoint]
        return
    handle, path = tempfile.mkstemp(prefix="tango-aio-", suffix=".db")
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(f"{SERVER}/{options.instance}/DEVICE/MarzhauserAxis: "
                       f"{', '.join(axes)}\n")
            file.write(f"{SERVER}/{options.instance}/DEVICE/MarzhauserController: "
                       f"{controller}\n")
        yield [SERVER, options.instance, *endpoint, f"-file={path}"]
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)


def _register(options: ServerOptions, axes: Sequence[str], controller: str) -> None:
    """Add the devices to the Tango database (TANGO_HOST), as this server's."""
    import tango

    database = tango.Database()
    server = f"{SERVER}/{options.instance}"
    for names, klass in ((axes, "MarzhauserAxis"), ([controller], "MarzhauserController")):
        for name in names:
            info = tango.DbDevInfo()
            info.name, info._class, info.server = name, klass, server
            database.add_device(info)
