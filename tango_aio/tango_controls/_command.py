"""The ``tango-aio tango-server`` subcommand: serve a Märzhäuser TANGO controller's axes as
Tango Controls devices.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import sys
from typing import Any

from .._argtypes import UsageError, number_type, seconds_type, url_type
from ._server import DEFAULT_PREFIX, ServerOptions

__all__ = ["add_tango_server_command", "run_tango_server"]

#: One field of a Tango Controls device name (``domain``, ``family``).
_FIELD = r"[A-Za-z0-9_.\-]+"


def _name(text: str, fields: int, want: str) -> str:
    """``text`` as ``fields`` name fields joined by ``/`` (argparse's error if not)."""
    name = text.rstrip("/")
    if not re.fullmatch("/".join([_FIELD] * fields), name):
        raise argparse.ArgumentTypeError(f"want {want} (letters, digits, _ . -), got {text!r}")
    return name


def _prefix_type(text: str) -> str:
    """argparse type of the device names' prefix, ``DOMAIN/FAMILY``."""
    return _name(text, 2, "DOMAIN/FAMILY")


def _instance_type(text: str) -> str:
    """argparse type of the server's instance name."""
    return _name(text, 1, "one name")


def _port_type(text: str) -> int:
    port = number_type(int, "a TCP port", allow_minimum=True)(text)
    if port > 65535:
        raise argparse.ArgumentTypeError(f"a TCP port is at most 65535, got {text!r}")
    return port


def add_tango_server_command(commands: Any) -> None:
    """Register the ``tango-server`` subcommand on the ``tango-aio`` sub-parsers.

    Parameters
    ----------
    commands
        The CLI's subparsers (``argparse``'s ``add_subparsers()``).
    """
    server = commands.add_parser(
        "tango-server", help="serve the axes as Tango Controls devices (needs "
                             "tango-aio[tango-controls])",
        description=run_tango_server.__doc__)
    server.add_argument("url", type=url_type, help="controller URL, e.g. /dev/ttyUSB0")
    server.add_argument("--prefix", type=_prefix_type, default=DEFAULT_PREFIX,
                        help=f"device names PREFIX/x ... (default {DEFAULT_PREFIX})")
    server.add_argument("--instance", type=_instance_type,
                        help="the server's instance name (default: FAMILY of --prefix)")
    server.add_argument("--nodb", action="store_true",
                        help="serve without a Tango database (clients add #dbase=no)")
    server.add_argument("--port", type=_port_type, default=0,
                        help="TCP port of the server (default: any free one; printed "
                             "with --nodb)")
    server.add_argument("--interface", default="127.0.0.1", metavar="ADDRESS",
                        help="listen on this local address (default 127.0.0.1, this "
                             "machine only)")
    server.add_argument("--poll", type=seconds_type, default=0.1,
                        help="seconds between state reads (default 0.1)")
    server.set_defaults(run=run_tango_server)


async def run_tango_server(args: argparse.Namespace) -> int:
    """Serve a Märzhäuser TANGO controller as Tango Controls devices: one per axis
    (PREFIX/x ...) and PREFIX/controller. With a Tango database (TANGO_HOST) the devices
    are registered as TangoAio/INSTANCE; with --nodb clients reach them at
    tango://ADDRESS:PORT/PREFIX/x#dbase=no. Runs until interrupted; moves it started are
    stopped on exit."""
    if not args.nodb and not os.environ.get("TANGO_HOST"):
        raise UsageError("no Tango database: set TANGO_HOST, or serve with --nodb")
    try:
        import tango  # noqa: F401 - pytango present?
    except ImportError as exc:
        from .._install import install_hint

        print(f"error: the tango-server command needs pytango ({exc}); "
              f"install it with: {install_hint('tango-controls')}", file=sys.stderr)
        return 1
    from ._server import serve

    options = ServerOptions(url=args.url, prefix=args.prefix,
                            instance=args.instance or args.prefix.rpartition("/")[2],
                            nodb=args.nodb, port=args.port, interface=args.interface,
                            interval=args.poll)
    code = await asyncio.to_thread(serve, options)
    if code == 130:
        print("interrupted", file=sys.stderr)  # Tango's signal thread took the Ctrl+C
    return code
