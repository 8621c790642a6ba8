"""The ``tango-aio ioc`` subcommand: serve controllers as EPICS motor records.

``tango-aio ioc /dev/ttyUSB0 --prefix LAB:STAGE:`` serves one controller (PVs
``LAB:STAGE:X`` ...); ``--controller stage=URL --controller focus=URL`` serves several
(``LAB:stage:X``, ``LAB:focus:X``). The IOC binds to loopback unless ``--interface`` says
otherwise; see ``docs/howto/epics.md`` for a lab network.

This module does not import caproto (the ``epics`` extra) until the command runs.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import ipaddress
import logging
import os
import signal
import sys
from collections.abc import Awaitable, Callable, Iterator
from typing import Any

from .._argtypes import UsageError
from .._platform import signal_calls
from ..controller import Controller, connect
from ..errors import TangoError
from .access import AccessPolicy

__all__ = ["add_ioc_command", "parse_controllers", "run_ioc"]

#: Where the IOC listens unless told otherwise: this machine only.
DEFAULT_INTERFACE = "127.0.0.1"


def parse_controllers(url: str | None, named: list[str]) -> dict[str, str]:
    """``URL`` and ``--controller NAME=URL`` values as ``{name: url}`` (``""``: the one
    unnamed controller). Exactly one of the two forms must be used."""
    if url and named:
        raise ValueError("give either URL or --controller NAME=URL, not both")
    if url:
        return {"": url}
    if not named:
        raise ValueError("give a controller URL, or --controller NAME=URL (repeatable)")
    controllers: dict[str, str] = {}
    for item in named:
        name, sep, target = item.partition("=")
        if not sep or not name or not target or ":" in name or "." in name:
            raise ValueError(f"--controller wants NAME=URL (NAME without ':' or '.'), "
                             f"got {item!r}")
        if name in controllers:
            raise ValueError(f"controller name {name!r} given twice")
        controllers[name] = target
    return controllers


def loopback_only(interfaces: list[str]) -> bool:
    """Whether every interface address is a loopback address."""
    try:
        return all(ipaddress.ip_address(i).is_loopback for i in interfaces)
    except ValueError:
        return False


def add_ioc_command(commands: Any) -> None:
    """Register the ``ioc`` subcommand on the ``tango-aio`` sub-parsers."""
    ioc = commands.add_parser(
        "ioc", help="serve controllers as EPICS motor records (needs tango-aio[epics])",
        description=run_ioc.__doc__)
    ioc.add_argument("url", nargs="?", help="controller URL (or use --controller)")
    ioc.add_argument("--prefix", required=True, help="PV prefix, e.g. LAB:STAGE:")
    ioc.add_argument("--controller", action="append", default=[], metavar="NAME=URL",
                     help="serve this controller as PREFIX NAME: (repeatable)")
    ioc.add_argument("--interface", action="append", default=[], metavar="ADDRESS",
                     help="listen on this local address (repeatable; default 127.0.0.1, "
                          "this machine only; 0.0.0.0 for every network)")
    ioc.add_argument("--port", type=int, help="CA server port (default 5064, or "
                     "EPICS_CAS_SERVER_PORT)")
    ioc.add_argument("--read-only", action="store_true", help="serve readbacks only")
    ioc.add_argument("--allow-host", action="append", default=[], metavar="HOST",
                     help="only clients reporting this host name may write (repeatable)")
    ioc.add_argument("--allow-user", action="append", default=[], metavar="USER",
                     help="only clients reporting this user name may write (repeatable)")
    ioc.add_argument("--poll", type=float, default=0.1,
                     help="seconds between position reads (default 0.1)")
    ioc.add_argument("--merge", choices=("turn", "window"), default="turn",
                     help="puts to other axes become one move: 'turn' (default) those "
                          "that arrive together, with no fixed wait; 'window' those "
                          "within --merge-window seconds, a wait every put pays")
    ioc.add_argument("--merge-window", type=float, default=0.02,
                     help="with --merge window: seconds a move waits for puts to other "
                          "axes; with --merge turn: the longest wait for puts already on "
                          "their way (default 0.02)")
    ioc.add_argument("--autosave", metavar="FILE",
                     help="keep OFF, the soft limits, VELO and VMAX of every record in "
                          "FILE (JSON) and put them back when the IOC starts")
    ioc.set_defaults(run=run_ioc)


class _BeaconFailures(logging.Filter):
    """Let caproto's "Failed to send beacon" through once, without its traceback: with
    no caRepeater listening (usual on a PC that only serves) it repeats for ever. On
    loopback (``quiet``) it is not shown at all: no caRepeater there is the normal case,
    and clients on this machine find the IOC by its search replies, not its beacons."""

    def __init__(self, quiet: bool = False) -> None:
        super().__init__()
        self.seen = quiet

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.getMessage().startswith("Failed to send beacon"):
            return True
        if self.seen:
            return False
        self.seen = True
        record.exc_info = record.exc_text = None
        record.msg, record.args = "%s (no caRepeater listening; shown once)", (
            record.getMessage(),)
        return True


def _environment(interfaces: list[str], port: int | None) -> None:
    """Set the CA server environment the command line implies (never overrides a
    variable the user set): beacons stay on loopback when the IOC does."""
    if port is not None:
        os.environ["EPICS_CAS_SERVER_PORT"] = str(port)
    if loopback_only(interfaces):
        os.environ.setdefault("EPICS_CAS_AUTO_BEACON_ADDR_LIST", "NO")
        os.environ.setdefault("EPICS_CAS_BEACON_ADDR_LIST", "127.0.0.1")


async def run_ioc(args: argparse.Namespace) -> int:
    """Serve TANGO controllers over EPICS Channel Access: one motor record per axis
    (PREFIX X, Y, Z, A) and controller PVs (PREFIX CONNECTED, ERROR, AUTOSTATUS,
    TRIGCOUNT). Runs until interrupted; moves this IOC started are stopped on exit."""
    try:
        controllers = parse_controllers(args.url, args.controller)
        policy = AccessPolicy.build(read_only=args.read_only, hosts=args.allow_host,
                                    users=args.allow_user)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    interfaces = args.interface or [DEFAULT_INTERFACE]
    try:
        from . import ioc  # noqa: F401 - caproto present?
    except ImportError as exc:
        from .._install import install_hint

        print(f"error: the ioc command needs caproto ({exc}); "
              f"install it with: {install_hint('epics')}", file=sys.stderr)
        return 1
    _environment(interfaces, args.port)
    logging.getLogger("caproto.ctx").addFilter(_BeaconFailures(loopback_only(interfaces)))
    with _terminated_by_sigterm() as terminated:
        try:
            await _serve(args, controllers, policy, interfaces)
        except asyncio.CancelledError:
            if not terminated:
                raise
    return 0


@contextlib.contextmanager
def _terminated_by_sigterm() -> Iterator[list[bool]]:
    """SIGTERM (a service manager stopping the IOC) cancels the IOC like Ctrl+C does, so
    the moves it started are stopped and the ports closed; yields ``[True]`` once it
    came."""
    task = asyncio.current_task()
    came: list[bool] = []

    def terminate() -> None:
        came.append(True)
        if task is not None:
            task.cancel()

    # Windows: through signal.signal (only raise_signal can send SIGTERM there).
    with signal_calls(signal.SIGTERM, terminate):
        yield came


async def _serve(args: argparse.Namespace, controllers: dict[str, str],
                 policy: AccessPolicy, interfaces: list[str]) -> None:
    from .ioc import build_ioc

    async with contextlib.AsyncExitStack() as stack:
        connected: dict[str, Controller] = {}
        waiting: dict[str, Callable[[], Awaitable[Controller]]] = {}
        for name, url in controllers.items():
            try:
                connected[name] = await stack.enter_async_context(
                    connect(url, reconnect=True))
            except (TangoError, OSError) as exc:
                # Down at start: serve CONNECTED=0 and keep trying, so that
                # clients see the IOC and its link state before the controller is up.
                print(f"controller {url} not reachable ({exc}); serving "
                      f"{args.prefix}{name + ':' if name else ''}CONNECTED=0 until it "
                      "answers", file=sys.stderr, flush=True)
                waiting[name] = functools.partial(_open, url)
        ioc = await build_ioc(connected, args.prefix, policy=policy, poll=args.poll,
                              window=args.merge_window, merge=args.merge,
                              autosave=args.autosave,
                              waiting=waiting)
        records = [axis.record.pvname for server in ioc.servers for axis in server.axes]
        print(f"serving motor records {', '.join(records) or '(none yet)'} on "
              f"{', '.join(interfaces)}; {policy.describe()}", flush=True)
        await ioc.run(interfaces)


async def _open(url: str) -> Controller:
    """Open a controller that was down when the IOC started (closed by the IOC)."""
    return await connect(url, reconnect=True)
