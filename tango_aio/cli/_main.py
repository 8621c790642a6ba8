"""The ``tango-aio`` command line."""

from __future__ import annotations

# First of all: Ctrl+C while the modules below load ends quietly.
from .. import _startup

# isort: split
import argparse
import asyncio
import contextlib
import logging
import re
import signal
import sys
import threading
from collections.abc import Callable, Coroutine, Iterator, Sequence
from typing import Any

from .. import __version__
from .._argtypes import (
    UsageError,
    axes_type,
    baud_type,
    count_type,
    delay_type,
    existing_path,
    seconds_type,
    url_type,
)
from ..controller import connect
from ..epics.command import add_ioc_command
from ..fieldkit import add_probe_command
from ..tango_controls import add_tango_server_command
from ._commands import (
    _axis_target,
    _demo,
    _info,
    _monitor,
    _move,
    _ports,
    _upload_trigp,
)
from ._describe import (
    describe_exception,
)
from ._output import (
    _complain,
    _plural,
    _say,
)
from ._settings import add_settings_command
from ._shell import (
    _shell,
)
from ._simcmd import (
    _sim,
)

__all__ = ["main"]
Command = Callable[[argparse.Namespace], Coroutine[Any, Any, int]]


# -- plumbing ---------------------------------------------------------------------------


def _plain(text: str | None) -> str | None:
    """A docstring for ``--help``: Sphinx roles and literals (````?pos````,
    ``:func:`x```) as plain words."""
    if text is None:
        return None
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", text)
    return re.sub(r"``([^`]+)``", r"\1", text)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tango-aio",
        description="asyncio driver and emulator for Märzhäuser TANGO stepper-motor "
                    "controllers (not Tango Controls).")
    parser.add_argument("--version", action="version", version=f"tango-aio {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="show every line to and from the controller (the "
                             "tango_aio.wire log) on stderr")
    parser.add_argument("--debug", action="store_true",
                        help="show all debug logs of tango_aio on stderr, and the full "
                             "traceback of an error")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = commands.add_parser("demo", help="calibrate and run a raster scan (emulator)",
                               description=_plain(_demo.__doc__))
    demo.add_argument("url", type=url_type, nargs="?", default="sim://",
                      help="controller URL (default: sim://, the emulator)")
    demo.add_argument("--url", type=url_type, dest="old_url", help=argparse.SUPPRESS)
    demo.add_argument("--rows", type=count_type, default=4, help="scan rows (default 4)")
    demo.add_argument("--points", type=count_type, default=10,
                      help="triggers per row (default 10)")
    demo.add_argument("--yes", action="store_true",
                      help="do not ask before moving a real controller's axes")
    demo.set_defaults(run=_demo)
    info = commands.add_parser("info", help="show identity and settings",
                               description=_plain(_info.__doc__))
    info.add_argument("url", type=url_type, help="controller URL, e.g. /dev/ttyUSB0 or sim://")
    info.set_defaults(run=_info)
    sim = commands.add_parser("sim", help="serve the emulator on a pty or TCP",
                              description=_sim.__doc__)
    where = sim.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="serve on a pty (default); "
                       "prints the device path as the first line")
    where.add_argument("--tcp", metavar="[HOST:]PORT",
                       help="serve on TCP for socket:// URLs (host defaults to 127.0.0.1)")
    sim.add_argument("--axes", type=axes_type, default=3, help="number of axes 1-4 (default 3)")
    sim.add_argument("--baud", type=baud_type, default=57600, help="wire speed, 0 = instant")
    sim.add_argument("--latency", type=delay_type, default=0.0, help="reply latency in s")
    sim.add_argument("--processing", type=delay_type, default=0.0, help="time per line in s")
    sim.add_argument("--state", help="JSON file where 'save' persists settings")
    sim.add_argument("--profile", default=None,
                     help="firmware profile: manual (1.71, default) or legacy (older edition)")
    sim.add_argument("--fingerprint", metavar="FILE",
                     help="behave like the unit of this fingerprint (written by "
                          "'tango-aio probe') as far as the firmware switches go")
    sim.add_argument("--switch", action="append", default=[], metavar="NAME=VALUE",
                     help="a firmware switch on top of the profile (repeatable), "
                          "e.g. echo=after; see docs/concepts/firmware-profiles.md")
    sim.add_argument("--speed", default="1", metavar="X",
                     help="run motion, pauses and timeouts X times as fast (the wire "
                          "keeps its baud rate)")
    sim.add_argument("--per-connection", action="store_true",
                     help="with --tcp: a fresh controller for every connection (default: "
                          "one controller for the server's life)")
    sim.set_defaults(run=_sim)
    _add_operator_commands(commands)
    add_ioc_command(commands)
    add_probe_command(commands)
    add_tango_server_command(commands)
    add_settings_command(commands)
    return parser


def _add_operator_commands(commands: Any) -> None:
    """The subcommands shell, move, monitor, ports and upload-trigp."""
    shell = commands.add_parser("shell", help="interactive command line shell",
                                description=_plain(_shell.__doc__))
    shell.add_argument("url", type=url_type, help="controller URL, e.g. /dev/ttyUSB0 or sim://")
    shell.set_defaults(run=_shell)
    move = commands.add_parser("move", help="move axes with a progress bar",
                               description=_plain(_move.__doc__))
    move.add_argument("url", type=url_type, help="controller URL")
    move.add_argument("targets", nargs="+", type=_axis_target, metavar="AXIS=VALUE",
                      help="target (or distance with --relative) per axis, e.g. x=10 y=5")
    move.add_argument("--relative", action="store_true", help="move by distances (mor)")
    move.set_defaults(run=_move)
    monitor = commands.add_parser("monitor", help="live table of positions and status",
                                  description=_plain(_monitor.__doc__))
    monitor.add_argument("url", type=url_type, help="controller URL")
    monitor.add_argument("--interval", type=seconds_type, default=0.2,
                         help="seconds between refreshes (default 0.2)")
    monitor.add_argument("--count", type=count_type, help="stop after N refreshes")
    monitor.set_defaults(run=_monitor)
    ports = commands.add_parser("ports", help="list serial ports, optionally probe them",
                                description=_plain(_ports.__doc__))
    ports.add_argument("--probe", action="store_true", help="find TANGO controllers")
    ports.add_argument("--port", action="append", default=[], metavar="DEVICE",
                       help="probe DEVICE instead of every listed port (repeatable)")
    ports.add_argument("--timeout", type=seconds_type, default=0.5,
                       help="seconds to wait for each port's reply (default 0.5)")
    ports.set_defaults(run=_ports)
    upload = commands.add_parser("upload-trigp", help="upload a trigger position list",
                                 description=_plain(_upload_trigp.__doc__))
    upload.add_argument("url", type=url_type, help="controller URL")
    upload.add_argument("file", type=existing_path, help="text file with one position per line")
    upload.add_argument("--axis", default="x", choices=["x", "y", "z", "a"],
                        help="trigger axis (default x)")
    upload.set_defaults(run=_upload_trigp)


@contextlib.contextmanager
def _logging(args: argparse.Namespace) -> Iterator[None]:
    """``-v``: the wire trace on stderr; ``--debug``: every tango_aio debug log."""
    if not (args.verbose or args.debug):
        yield
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(message)s"))
    logger = logging.getLogger("tango_aio" if args.debug else "tango_aio.wire")
    level = logger.level
    logger.setLevel(logging.DEBUG)
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def _is_emulator(url: str) -> bool:
    return url.lower().startswith("sim://")


async def _identify(args: argparse.Namespace) -> int:
    """Connect, say which controller answers at ``args.url``, and close again."""
    async with connect(args.url) as tango:
        ident = tango.identity
        _say(f"Found {ident.model} firmware {ident.firmware}, "
             f"{_plural(ident.axes, 'axis', 'axes')} at {args.url}")
    return 0


def _confirm_demo(args: argparse.Namespace) -> bool:
    """Whether to run the demo on a real controller: one answers there, the user agrees."""
    url = args.url
    if not sys.stdin.isatty():
        raise UsageError(f"demo on {url} calibrates and range-measures every axis; "
                          f"confirm with --yes (stdin is not a terminal to ask)")
    _run_loop(argparse.Namespace(**{**vars(args), "run": _identify}))
    _complain(f"The demo calibrates and range-measures every axis of the controller at {url}, "
         f"Z/focus included: each axis drives to both of its limit switches. Make sure "
         f"nothing (objective, sample, cables) is in the way.", "yellow")
    try:
        answer = input("Continue? [y/N] ")
    except EOFError:
        answer = ""
    return answer.strip().lower() in ("y", "yes")


def _loop_exception(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    """Report an error nobody awaited as one line (the traceback with --debug). A second
    Ctrl+C that lands in a task while the first one's shutdown runs is not reported:
    ``main()`` already said "interrupted" and exits with 130."""
    error = context.get("exception")
    if isinstance(error, KeyboardInterrupt):
        return
    text = describe_exception(error) if error is not None else context.get("message", "")
    logging.getLogger("tango_aio").debug("unhandled: %s", context.get("message"),
                                         exc_info=error)
    _complain(f"warning: {text}", "yellow")


async def _run(run: Command, args: argparse.Namespace) -> int:
    asyncio.get_running_loop().set_exception_handler(_loop_exception)
    return await run(args)


def _run_loop(args: argparse.Namespace) -> int:
    """``asyncio.run(_run(...))``, but a Ctrl+C cannot land while the event loop is being
    built: one that came meanwhile is delivered once it stands, and the loop is closed as
    usual (``asyncio.run`` would leave a half-built loop behind, whose ``__del__`` prints a
    traceback, and the command's coroutine never awaited)."""
    runner = asyncio.Runner()  # builds nothing yet (entering it as a context would)
    try:
        with _sigint_deferred():
            runner.get_loop()
        return runner.run(_run(args.run, args))
    finally:
        runner.close()


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold SIGINT back (in the main thread) for the block: blocked where the platform
    can (POSIX), else (Windows) recorded by a handler and raised again after it."""
    from .._platform import POSIX

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if not POSIX or not hasattr(signal, "pthread_sigmask"):
        with _sigint_recorded():
            yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


@contextlib.contextmanager
def _sigint_recorded() -> Iterator[None]:
    """Where SIGINT cannot be blocked (Windows): a handler notes it during the block,
    and the previous handler gets it once the block is over."""
    came: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: came.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if came:
            signal.raise_signal(signal.SIGINT)


def _ignore_sigint() -> None:
    """Ignore SIGINT from now on (main thread only): the process is already on its way
    out after a Ctrl+C."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tango-aio`` command: 0 on success, 1 after an error (printed
    as one line), 2 for usage errors, 130 after Ctrl+C (from then on the process ignores
    SIGINT: it is on its way out)."""
    debug = False
    try:
        # The module's body has run to its end (class and function definitions, not only
        # the imports): only now does Ctrl+C belong to main().
        _startup.finished()
        args = _parser().parse_args(argv)
        debug = args.debug
        if getattr(args, "old_url", None):  # demo --url, the old spelling of its argument
            args.url = args.old_url
        with _logging(args):
            if args.command == "demo" and not args.yes and not _is_emulator(args.url) \
                    and not _confirm_demo(args):
                _complain("demo cancelled: nothing was moved")
                return 1
            return _run_loop(args)
    except KeyboardInterrupt:
        _ignore_sigint()  # a further Ctrl+C while we say so must not end in a traceback
        _complain("interrupted", "yellow")
        return 130
    except UsageError as exc:
        _complain(f"error: {describe_exception(exc)}", "red")
        return 2
    except Exception as exc:
        if debug:
            raise
        _complain(f"error: {describe_exception(exc)}", "red")
        return 1


if __name__ == "__main__":
    sys.exit(main())
