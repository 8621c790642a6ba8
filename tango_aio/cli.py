"""The ``tango-aio`` command line.

Every command takes ``--help``. Errors are printed as one line and give exit code 1
(2 for usage errors). URLs are those of :func:`tango_aio.connect`; ``sim://`` runs the
embedded emulator.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from rich.console import Console
from rich.live import Live
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from .bulk import validate_trigger_positions
from .connection import connect
from .controller import Controller
from .core import is_completion_line
from .epics.command import add_ioc_command
from .errors import (
    ERROR_DESCRIPTIONS,
    InvalidCommandError,
    ProtocolError,
    TangoError,
    parse_error_reply,
)
from .events import (
    ConnectionLost,
    MoveAborted,
    MoveFinished,
    Reconnected,
    StatusReport,
    Subscription,
    TangoEvent,
    UnsolicitedLine,
)
from .instructions import AXES, parse
from .instructions import Command as CommandLine

__all__ = ["main"]

console = Console(highlight=False)
Command = Callable[[argparse.Namespace], Coroutine[Any, Any, int]]


# -- demo -------------------------------------------------------------------------------


async def _demo(args: argparse.Namespace) -> int:
    """Identify, calibrate, measure the range, then run a raster scan with a trigger list."""
    started = time.monotonic()
    async with connect(args.url) as tango:
        ident = tango.identity
        assert ident is not None
        console.print(f"[bold]Connected[/] to {ident.model} firmware {ident.firmware}, "
                      f"{ident.axes} axes at {args.url}")
        await _demo_reference(tango)
        triggers = await _demo_scan(tango, rows=args.rows, points=args.points)
        summary = Table(title="Summary", show_header=False)
        summary.add_row("controller", f"{ident.model} {ident.firmware}")
        summary.add_row("final position", _fmt_positions(await tango.position()))
        summary.add_row("limits", str(await tango.query("?statuslimit")))
        summary.add_row("trigger pulses", str(triggers))
        summary.add_row("elapsed", f"{time.monotonic() - started:.1f} s")
        console.print(summary)
    return 0


async def _demo_reference(tango: Controller) -> None:
    for label, action in (("calibrate (cal)", tango.calibrate),
                          ("range measure (rm)", tango.measure_range)):
        with _progress() as progress:
            task = progress.add_task(label, total=None)
            letters = await _with_positions(tango, action(), progress, task)
        console.print(f"  {label}: {letters}")


async def _demo_scan(tango: Controller, *, rows: int, points: int) -> int:
    """A raster over a 10 x 10 mm field; X carries a trigger list of ``points`` pulses."""
    await tango.move_to(x=0.0, y=0.0)
    step = 10.0 / max(points - 1, 1)
    await tango.command("!trigp x 0")
    for index in range(points):
        await tango.command(f"!trigp -1 {index * step + 0.5:.4f}")
    await tango.command("!trigcount 0")
    await tango.command("!trig 1")  # the list only fires once enabled (manual L12565)
    with _progress() as progress:
        task = progress.add_task("raster scan", total=rows)
        for row in range(rows):
            x_end = 11.0 if row % 2 == 0 else 0.0
            await tango.move_to(y=row * 10.0 / max(rows - 1, 1))
            await _with_positions(tango, tango.move_to(x=x_end), progress, task)
            progress.advance(task)
    return int(await tango.get("trigcount"))


async def _with_positions(tango: Controller, move: Awaitable[dict[str, str]],
                          progress: Progress, task: object) -> dict[str, str]:
    """Await ``move`` while showing live positions in the progress line."""
    job = asyncio.ensure_future(move)
    while not job.done():
        with contextlib.suppress(TangoError):
            progress.update(task, description=_fmt_positions(await tango.position()))  # type: ignore[arg-type]
        await asyncio.wait({job}, timeout=0.2)
    return job.result()


def _fmt_positions(positions: dict[str, float]) -> str:
    return "  ".join(f"{axis}={value:9.4f}" for axis, value in positions.items())


def _progress() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                    console=console, transient=False)


# -- info -------------------------------------------------------------------------------


async def _info(args: argparse.Namespace) -> int:
    """Print the controller's identity and main settings."""
    async with connect(args.url) as tango:
        ident = tango.identity
        assert ident is not None
        table = Table(title=f"TANGO at {args.url}", show_header=False)
        table.add_row("model", ident.model)
        table.add_row("firmware", ident.firmware)
        table.add_row("axes", str(ident.axes))
        table.add_row("options", ", ".join(sorted(ident.det.options)) or "-")
        table.add_row("serial", await tango.query("?readsn"))
        table.add_row("position", _fmt_positions(await tango.position()))
        table.add_row("status", " ".join(f"{a}={s}" for a, s in (await tango.status()).items()))
        for name in ("dim", "pitch", "vel", "accel", "secvel"):
            table.add_row(name, str(await tango.query(f"?{name}")))
        console.print(table)
    return 0


# -- sim --------------------------------------------------------------------------------


async def _sim(args: argparse.Namespace) -> int:
    """Serve an emulated controller on a pty or a TCP port until interrupted."""
    from .sim.inprocess import configs_from_url
    from .sim.model import ControllerModel
    from .sim.serve import serve_pty, serve_tcp
    from .sim.wire import Emit

    sim_config, wire_config = configs_from_url(_sim_url(args))

    def factory(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, sim_config)

    if args.tcp:
        host, _, port = args.tcp.rpartition(":")
        server = await serve_tcp(factory, host=host or "127.0.0.1", port=int(port),
                                 config=wire_config)
        print(f"socket://{server.host}:{server.port}", flush=True)
    else:
        server = await serve_pty(factory, config=wire_config)  # type: ignore[assignment]
        print(server.path, flush=True)  # type: ignore[attr-defined]
    async with server:
        await server.wait_closed()
    return 0


def _sim_url(args: argparse.Namespace) -> str:
    query = [f"axes={args.axes}", f"baud={args.baud}", f"latency={args.latency}",
             f"processing={args.processing}"]
    if args.state:
        query.append(f"state={args.state}")
    return "sim://?" + "&".join(query)


# -- decoding of replies and events -----------------------------------------------------

#: What each status letter means (manual L2689-2711; C and U from the older manual).
LETTER_MEANINGS: dict[str, str] = {
    "@": "ok", "M": "moving", "J": "ok, joystick", "S": "limit switch",
    "A": "ok, calibrated", "D": "ok, range measured", "E": "error/aborted",
    "T": "timeout", "C": "closed loop", "U": "manual adjustment", "-": "absent",
}

_KIND_NAMES = {"move": "move", "cal": "calibration", "rm": "range measure"}


def describe_letters(statuses: Mapping[str, str]) -> str:
    """``{"x": "@", "y": "E"}`` → ``"x=@ (ok) y=E (error/aborted)"``."""
    return " ".join(f"{axis}={letter} ({LETTER_MEANINGS.get(letter, 'unknown')})"
                    for axis, letter in statuses.items())


def letters_of_line(line: str) -> dict[str, str]:
    """The per-axis letters of a completion or statusaxis line (``@@E-.``, ``@@@-.-``);
    absent axes (``-``) are left out."""
    head = line.strip().split(".", 1)[0]
    return {axis: letter for axis, letter in zip(AXES, head, strict=False) if letter != "-"}


def describe_error(code: int | None) -> str:
    """An error number in words, from the manual's error table."""
    if code is None:
        return "error (the controller gave no number)"
    if code == 0:
        return "no error"
    return f"error {code}: {ERROR_DESCRIPTIONS.get(code, 'undocumented error number')}"


def describe_reply(command: CommandLine, reply: str) -> str:
    """The reply text, with error numbers, ``ERR n`` and status letters decoded."""
    return "\n".join(_describe_reply_line(command, line) for line in reply.split("\n"))


def _describe_reply_line(command: CommandLine, line: str) -> str:
    text = line.strip()
    if command.name == "err" or text.startswith("ERR"):
        try:
            code, _ = parse_error_reply(text)
        except ProtocolError:
            return line
        return f"{line}  → {describe_error(code)}"
    if command.name == "statusaxis" and text:
        letters = {command.axis: text} if command.axis else letters_of_line(text)
        return f"{line}  → {describe_letters(letters)}"
    return line


def describe_line(line: str) -> str:
    """An unsolicited line from the controller in words."""
    text = line.strip()
    if is_completion_line(text):
        return f"status report: {describe_letters(letters_of_line(text))}"
    if text.startswith("ERR"):
        with contextlib.suppress(ProtocolError):
            return f"controller reports {describe_error(parse_error_reply(text)[0])}"
    return f"unsolicited line: {line!r}"


def describe_event(event: TangoEvent) -> str | None:
    """An event of :meth:`Controller.events` in words (``None``: not worth showing)."""
    if isinstance(event, MoveFinished):
        what = _KIND_NAMES.get(event.kind, event.kind)
        letters = describe_letters(event.statuses) or "no status letters (autostatus 3)"
        return f"{what} finished: {letters}"
    if isinstance(event, StatusReport):
        return f"status report: {describe_letters(event.statuses)}"
    if isinstance(event, MoveAborted):
        return f"abort sent ({'Ctrl+C' if event.ctrl_c else 'a'}): all axes stop"
    if isinstance(event, UnsolicitedLine):
        return describe_line(event.line)
    if isinstance(event, ConnectionLost):
        return f"connection lost: {event.cause or 'closed'}"
    if isinstance(event, Reconnected):
        return f"reconnected (attempt {event.attempt})"
    return None


def _say(text: str, style: str = "") -> None:
    """Print ``text`` literally (no rich markup)."""
    console.print(Text(text, style=style), soft_wrap=True)


@contextlib.contextmanager
def _sigint_calls(callback: Callable[[], None]) -> Iterator[None]:
    """Run ``callback`` on SIGINT (Ctrl+C) instead of interrupting the program. Does
    nothing where the event loop cannot handle signals (Windows, other threads)."""
    loop = asyncio.get_running_loop()
    previous = signal.getsignal(signal.SIGINT)
    try:
        loop.add_signal_handler(signal.SIGINT, callback)
    except (NotImplementedError, RuntimeError, ValueError):
        installed = False
    else:
        installed = True
    try:
        yield
    finally:
        if installed:
            loop.remove_signal_handler(signal.SIGINT)
            signal.signal(signal.SIGINT, previous)


# -- shell ------------------------------------------------------------------------------

#: Default history file of the shell; the environment variable TANGO_AIO_HISTORY overrides.
HISTORY_FILE = "~/.tango_aio_history"
_PROMPT = "tango> "


class LineReader(Protocol):
    """Where the shell gets its input lines."""

    async def read(self) -> str:
        """The next line; raises EOFError at the end, KeyboardInterrupt for Ctrl+C."""
        ...


class _TerminalReader:
    """prompt_toolkit input with editing and a persistent history (stdin is a tty)."""

    def __init__(self, history: Path) -> None:
        from prompt_toolkit import PromptSession
        from prompt_toolkit.history import FileHistory

        self._session: PromptSession[str] = PromptSession(history=FileHistory(str(history)))

    async def read(self) -> str:
        return await self._session.prompt_async(_PROMPT, handle_sigint=False)


class _PipeReader:
    """Lines from a non-interactive stdin, read by a daemon thread (never blocks exit)."""

    def __init__(self) -> None:
        self._lines: asyncio.Queue[str] = asyncio.Queue()
        loop = asyncio.get_running_loop()

        def pump() -> None:
            while True:
                line = sys.stdin.readline()
                loop.call_soon_threadsafe(self._lines.put_nowait, line)
                if not line:
                    return

        threading.Thread(target=pump, name="tango-aio-stdin", daemon=True).start()

    async def read(self) -> str:
        line = await self._lines.get()
        if not line:
            raise EOFError
        return line.rstrip("\r\n")


def history_path() -> Path:
    """The shell's history file: $TANGO_AIO_HISTORY, or ~/.tango_aio_history."""
    return Path(os.environ.get("TANGO_AIO_HISTORY") or HISTORY_FILE).expanduser()


class Shell:
    """The interactive line shell of ``tango-aio shell`` on a connected controller."""

    def __init__(self, tango: Controller, reader: LineReader) -> None:
        self.tango = tango
        self.reader = reader
        self._job: asyncio.Future[None] | None = None
        self._aborting: asyncio.Future[None] | None = None
        self._lost = False

    async def run(self) -> int:
        """Read, validate and send lines until ``exit``, ``quit`` or end of input."""
        async with self.tango.events() as events:
            printer = asyncio.ensure_future(self._print_events(events))
            try:
                with _sigint_calls(self._on_sigint):
                    return await self._loop()
            finally:
                printer.cancel()

    async def _loop(self) -> int:
        while not self._lost:
            try:
                line = (await self.reader.read()).strip()
            except EOFError:
                return 0
            except KeyboardInterrupt:  # Ctrl+C at the prompt
                await self._abort()
                continue
            if line.lower() in ("exit", "quit"):
                return 0
            if line:
                await self._settle_abort()
                await self._run_line(line)
        return 1

    async def _run_line(self, line: str) -> None:
        """Run one line as a job that Ctrl+C cancels (and then aborts)."""
        job = self._job = asyncio.ensure_future(self.execute(line))
        try:
            await asyncio.wait({job})
        finally:
            self._job = None
            job.cancel()
        if job.cancelled():
            _say(f"interrupted: {line}", "yellow")
            await self._abort()
        elif isinstance(job.exception(), InvalidCommandError):
            _say(f"invalid: {job.exception()} (nothing sent)", "yellow")
        elif isinstance(job.exception(), TangoError):
            _say(f"error: {job.exception()}", "red")
        else:
            job.result()

    async def execute(self, line: str) -> None:
        """Validate ``line``; send a read with ``query`` and show the decoded reply, or
        anything else with ``command(check=False)``."""
        command = parse(line, self.tango.context)
        if command.is_read:
            _say(describe_reply(command, await self.tango.query(line)))
        else:
            await self.tango.command(line, check=False)
            _say("sent", "dim")

    def _on_sigint(self) -> None:
        if self._job is not None:
            self._job.cancel()  # _run_line aborts once the job is gone
        elif self._aborting is None or self._aborting.done():
            self._aborting = asyncio.ensure_future(self._abort())

    async def _settle_abort(self) -> None:
        if self._aborting is not None:
            await asyncio.wait({self._aborting})

    async def _abort(self) -> None:
        try:
            await self.tango.abort()
        except (TangoError, TimeoutError) as exc:
            _say(f"error: abort: {exc}", "red")

    async def _print_events(self, events: Subscription) -> None:
        async for event in events:
            text = describe_event(event)
            if text is not None:
                _say(text, "red" if isinstance(event, ConnectionLost) else "cyan")
            if isinstance(event, ConnectionLost):
                self._lost = True


async def _shell(args: argparse.Namespace) -> int:
    """Interactive shell: type instruction lines (``?pos``, ``!moa 10 5``), validated
    before sending. Completion reports, error numbers and unsolicited lines are shown in
    words. Ctrl+C aborts (all axes stop); Ctrl+D, ``exit`` or ``quit`` leave. History is
    kept in ~/.tango_aio_history ($TANGO_AIO_HISTORY)."""
    async with connect(args.url) as tango:
        ident = tango.identity
        if ident is not None:
            _say(f"connected to {ident.model} firmware {ident.firmware}, {ident.axes} axes "
                 f"at {args.url}; Ctrl+C aborts, Ctrl+D or 'exit' leaves", "bold")
        if sys.stdin.isatty() and sys.stdout.isatty():
            from prompt_toolkit.patch_stdout import patch_stdout

            with patch_stdout(raw=True):
                return await Shell(tango, _TerminalReader(history_path())).run()
        return await Shell(tango, _PipeReader()).run()


# -- move -------------------------------------------------------------------------------


def _axis_target(token: str) -> tuple[str, float]:
    """argparse type of ``x=1.5``."""
    axis, sep, text = token.partition("=")
    axis = axis.strip().lower()
    if not sep or axis not in AXES:
        raise argparse.ArgumentTypeError(f"expected AXIS=VALUE, AXIS one of x y z a: {token!r}")
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {token!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"not a finite number: {token!r}")
    return axis, value


def _distance(start: Mapping[str, float], end: Mapping[str, float]) -> float:
    return math.dist([start.get(a, 0.0) for a in end], list(end.values()))


async def _move(args: argparse.Namespace) -> int:
    """Move axes to absolute positions (``x=10 y=5``), or by distances with
    ``--relative``, showing the distance covered; prints the final status letters."""
    targets: dict[str, float] = {}
    for axis, value in args.targets:
        if axis in targets:
            raise ValueError(f"axis {axis} given twice")
        targets[axis] = value
    async with connect(args.url) as tango:
        start = await tango.position()
        ends = {a: start.get(a, 0.0) + v if args.relative else v for a, v in targets.items()}
        mover: Callable[..., Awaitable[dict[str, str]]] = (
            tango.move_by if args.relative else tango.move_to)
        motion = mover(**targets)
        with Progress(TextColumn("moving"), BarColumn(),
                      TextColumn("{task.completed:.4f} / {task.total:.4f}"),
                      TimeElapsedColumn(), console=console, transient=True,
                      disable=not console.is_terminal) as progress:
            task = progress.add_task("", total=max(_distance(start, ends), 1e-9))
            letters = await _follow(tango, motion, progress, task, start)
        _say(f"done: {describe_letters(letters)}")
        _say(f"position: {_fmt_positions(await tango.position())}")
    return 0


async def _follow(tango: Controller, motion: Awaitable[dict[str, str]], progress: Progress,
                  task: TaskID, start: Mapping[str, float]) -> dict[str, str]:
    """Await ``motion`` while polling the position every 0.1 s into the progress bar."""
    job = asyncio.ensure_future(motion)
    try:
        while not job.done():
            with contextlib.suppress(TangoError):
                position = await tango.position()
                covered = _distance(start, {a: position[a] for a in start})
                progress.update(task, completed=covered)
            await asyncio.wait({job}, timeout=0.1)
    finally:
        if not job.done():  # cancelled (Ctrl+C): move_to stops the axes
            job.cancel()
            await asyncio.wait({job})
    return job.result()


# -- monitor ----------------------------------------------------------------------------


def _monitor_table(url: str, positions: Mapping[str, float],
                   letters: Mapping[str, str]) -> Table:
    table = Table(title=f"TANGO at {url}")
    for column in ("axis", "position", "status", "meaning"):
        table.add_column(column, justify="right" if column == "position" else "left")
    for axis, value in positions.items():
        letter = letters.get(axis, "?")
        table.add_row(axis, f"{value:.4f}", letter, LETTER_MEANINGS.get(letter, "unknown"))
    return table


async def _monitor(args: argparse.Namespace) -> int:
    """Show a live table of the positions and status letters of every axis, refreshed
    every ``--interval`` seconds, until Ctrl+C (or ``--count`` refreshes)."""
    stop = asyncio.Event()
    async with connect(args.url) as tango:
        with _sigint_calls(stop.set), Live(console=console, auto_refresh=False) as live:
            refreshes = 0
            while not stop.is_set():
                table = _monitor_table(args.url, await tango.position(), await tango.status())
                live.update(table, refresh=True)
                refreshes += 1
                if args.count is not None and refreshes >= args.count:
                    break
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), args.interval)
        if not console.is_terminal:
            console.line()  # Live leaves its last render without a newline
    return 0


# -- ports ------------------------------------------------------------------------------


async def _probe(timeout: float, ports: Sequence[str] | None) -> dict[str, str] | None:
    """Port → "model firmware" of the controllers :func:`tango_aio.discover` finds, or
    ``None`` when this installation has no ``discover``."""
    try:
        from .group import discover
    except ImportError:
        return None
    found = await discover(timeout=timeout, ports=ports or None)
    return {item.port: f"{item.model} {item.firmware}" for item in found}


async def _ports(args: argparse.Namespace) -> int:
    """List the serial ports; with ``--probe``, ask each one for ``?version`` to find the
    TANGO controllers (this writes a line to every port probed)."""
    from serial.tools import list_ports

    infos = await asyncio.to_thread(list_ports.comports)
    rows = {info.device: (info.description or "", info.hwid or "") for info in infos}
    rows.update({port: ("", "") for port in args.port if port not in rows})
    found = await _probe(args.timeout, args.port) if args.probe else None
    if args.probe and found is None:
        _say("probing is not available: tango_aio.discover() is missing", "yellow")
    table = Table(title="Serial ports")
    for column in ("device", "description", "hwid", *(("TANGO",) if found is not None else ())):
        table.add_column(column)
    for device, (description, hwid) in rows.items():
        probed = not args.port or device in args.port
        extra = () if found is None else (found.get(device, "-" if probed else "not probed"),)
        table.add_row(device, description, hwid, *extra)
    console.print(table if rows else "no serial ports found")
    return 0


# -- upload-trigp -----------------------------------------------------------------------


async def _upload_trigp(args: argparse.Namespace) -> int:
    """Upload a trigger position list (one position per line; blank lines and lines
    starting with # are ignored) at wire speed, with a progress bar."""
    positions = validate_trigger_positions(_read_positions(args.file))  # before connecting
    async with connect(args.url) as tango:
        with _progress() as progress:
            task = progress.add_task(f"trigp {args.axis}", total=len(positions))
            await tango.upload_trigger_positions(
                positions, axis=args.axis,
                progress=lambda done, total: progress.update(task, completed=done))
        count = int(await tango.get("trigc"))
    console.print(f"uploaded {count} trigger positions to axis {args.axis}")
    return 0


def _read_positions(path: str) -> list[float]:
    """Positions from a text file, one per line."""
    values: list[float] = []
    with open(path, encoding="utf-8") as handle:
        for number, raw in enumerate(handle, start=1):
            text = raw.strip()
            if not text or text.startswith("#"):
                continue
            try:
                values.append(float(text))
            except ValueError:
                raise ValueError(f"{path}:{number}: not a number: {text!r}") from None
    return values


# -- plumbing ---------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tango-aio",
        description="asyncio driver and emulator for Märzhäuser TANGO stepper-motor "
                    "controllers (not Tango Controls).")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = commands.add_parser("demo", help="calibrate and run a raster scan (emulator)",
                               description=_demo.__doc__)
    demo.add_argument("--url", default="sim://", help="controller URL (default: sim://)")
    demo.add_argument("--rows", type=int, default=4, help="scan rows (default 4)")
    demo.add_argument("--points", type=int, default=10, help="triggers per row (default 10)")
    demo.set_defaults(run=_demo)
    info = commands.add_parser("info", help="show identity and settings",
                               description=_info.__doc__)
    info.add_argument("url", help="controller URL, e.g. /dev/ttyUSB0 or sim://")
    info.set_defaults(run=_info)
    sim = commands.add_parser("sim", help="serve the emulator on a pty or TCP",
                              description=_sim.__doc__)
    where = sim.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="serve on a pty (default); "
                       "prints the device path as the first line")
    where.add_argument("--tcp", metavar="HOST:PORT",
                       help="serve on TCP for socket:// URLs (host defaults to 127.0.0.1)")
    sim.add_argument("--axes", type=int, default=3, help="number of axes 1-4 (default 3)")
    sim.add_argument("--baud", type=int, default=57600, help="wire speed, 0 = instant")
    sim.add_argument("--latency", type=float, default=0.0, help="reply latency in s")
    sim.add_argument("--processing", type=float, default=0.0, help="time per line in s")
    sim.add_argument("--state", help="JSON file where 'save' persists settings")
    sim.set_defaults(run=_sim)
    _add_new_commands(commands)
    add_ioc_command(commands)
    return parser


def _add_new_commands(commands: Any) -> None:
    """The subcommands shell, move, monitor, ports and upload-trigp."""
    shell = commands.add_parser("shell", help="interactive command line shell",
                                description=_shell.__doc__)
    shell.add_argument("url", help="controller URL, e.g. /dev/ttyUSB0 or sim://")
    shell.set_defaults(run=_shell)
    move = commands.add_parser("move", help="move axes with a progress bar",
                               description=_move.__doc__)
    move.add_argument("url", help="controller URL")
    move.add_argument("targets", nargs="+", type=_axis_target, metavar="AXIS=VALUE",
                      help="target (or distance with --relative) per axis, e.g. x=10 y=5")
    move.add_argument("--relative", action="store_true", help="move by distances (mor)")
    move.set_defaults(run=_move)
    monitor = commands.add_parser("monitor", help="live table of positions and status",
                                  description=_monitor.__doc__)
    monitor.add_argument("url", help="controller URL")
    monitor.add_argument("--interval", type=float, default=0.2,
                         help="seconds between refreshes (default 0.2)")
    monitor.add_argument("--count", type=int, help="stop after N refreshes")
    monitor.set_defaults(run=_monitor)
    ports = commands.add_parser("ports", help="list serial ports, optionally probe them",
                                description=_ports.__doc__)
    ports.add_argument("--probe", action="store_true", help="find TANGO controllers")
    ports.add_argument("--port", action="append", default=[], metavar="DEVICE",
                       help="probe DEVICE instead of every listed port (repeatable)")
    ports.add_argument("--timeout", type=float, default=0.5,
                       help="seconds to wait for each port's reply (default 0.5)")
    ports.set_defaults(run=_ports)
    upload = commands.add_parser("upload-trigp", help="upload a trigger position list",
                                 description=_upload_trigp.__doc__)
    upload.add_argument("url", help="controller URL")
    upload.add_argument("file", help="text file with one position per line")
    upload.add_argument("--axis", default="x", choices=["x", "y", "z", "a"],
                        help="trigger axis (default x)")
    upload.set_defaults(run=_upload_trigp)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tango-aio`` command."""
    args = _parser().parse_args(argv)
    try:
        run: Command = args.run
        return asyncio.run(run(args))
    except KeyboardInterrupt:
        return 130
    except (TangoError, OSError, ValueError) as exc:
        console.print(f"[red]error:[/] {exc}", soft_wrap=True)
        return 1


if __name__ == "__main__":
    sys.exit(main())
