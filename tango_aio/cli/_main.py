"""The ``tango-aio`` command line.

Every command takes ``--help``. Errors are printed as one line and give exit code 1
(2 for usage errors, 130 after Ctrl+C); a move that did not end at its target gives 1,
in the shell too (docs/reference/cli.md, "Exit codes"). URLs are those of :func:`tango_aio.connect`;
``sim://`` runs the embedded emulator. Text that comes from the user or the controller is
printed literally (never as rich markup). Ctrl+C stops the axes that a command started
before it exits.
"""

from __future__ import annotations

# First of all: Ctrl+C while the modules below load ends quietly.
from .. import _startup

# isort: split
import argparse
import asyncio
import contextlib
import errno
import functools
import logging
import math
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO, Protocol, TypeVar

from rich.console import Console
from rich.live import Live
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

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
from ..catalog import AXES, Form, Instruction, Signature, lookup, parse, similar_names
from ..catalog import Command as CommandLine
from ..controller import Controller, connect
from ..epics.command import add_ioc_command
from ..errors import (
    ERROR_DESCRIPTIONS,
    InvalidCommandError,
    MoveError,
    ProtocolError,
    TangoError,
    parse_error_reply,
)
from ..events import (
    ConnectionLost,
    ControllerRestarted,
    MoveAborted,
    MoveFinished,
    Reconnected,
    StatusReport,
    Subscription,
    TangoEvent,
    UnsolicitedLine,
)
from ..families import MAX_TRIGGERS, validate_trigger_positions
from ..fieldkit import add_probe_command
from ..moves import describe_stop, failed_axes, moved_axes, optional_axes
from ..sansio import is_completion_line
from ..status import ABSENT, MOVING, AxisStatus
from ..tango_controls import add_tango_server_command
from ..units import DIM_UNITS, velocity_unit
from ._settings import add_settings_command, info_rows

__all__ = ["main"]

console = Console(highlight=False)
#: Diagnostics (errors, warnings, "interrupted"): stderr, so that stdout holds only results.
err_console = Console(stderr=True, highlight=False)
Command = Callable[[argparse.Namespace], Coroutine[Any, Any, int]]
_T = TypeVar("_T")


#: Control characters but the line feed: C0, DEL and C1 (ESC ] ... rewrites a terminal).
_CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f-\x9f]")


def _escaped(text: str) -> str:
    """``text`` with every control character but the line feed written as ``\\xNN``:
    text from the controller (or a proxy) never reaches the terminal raw.

    Returns
    -------
    str
        The escaped text.
    """
    return _CONTROL.sub(lambda match: f"\\x{ord(match.group()):02x}", text)


def _say(text: str, style: str = "") -> None:
    """Print ``text`` literally (no rich markup, control characters escaped)."""
    console.print(Text(_escaped(text), style=style), soft_wrap=True)


def _complain(text: str, style: str = "") -> None:
    """Print a diagnostic on stderr, as :func:`_say` prints a result on stdout."""
    err_console.print(Text(_escaped(text), style=style), soft_wrap=True)


def _table(title: str, columns: Sequence[str] = (), *, show_header: bool = True) -> Table:
    """A table whose title is printed literally (control characters escaped)."""
    table = Table(title=Text(_escaped(title)), show_header=show_header)
    for column in columns:
        table.add_column(column, justify="right" if column == "position" else "left")
    return table


def _row(table: Table, *cells: str) -> None:
    """Add a row whose cells are printed literally (control characters escaped)."""
    table.add_row(*(Text(_escaped(cell)) for cell in cells))


def _plural(count: int, one: str, many: str) -> str:
    return f"{count} {one if count == 1 else many}"


async def _follow(motion: Awaitable[_T], poll: Callable[[], Awaitable[None]],
                  interval: float) -> _T:
    """Await ``motion`` while calling ``poll`` every ``interval`` seconds (errors of a
    poll are ignored). If the caller is cancelled (Ctrl+C), ``motion`` is cancelled and
    awaited first, so that a move stops its axes before the connection closes.

    Returns
    -------
    _T
        What ``motion`` returned.
    """
    job = asyncio.ensure_future(motion)
    try:
        while not job.done():
            with contextlib.suppress(TangoError):
                await poll()
            await asyncio.wait({job}, timeout=interval)
    finally:
        if not job.done():
            job.cancel()
            await asyncio.wait({job})
    return job.result()


def _fmt_positions(positions: Mapping[str, float]) -> str:
    return "  ".join(f"{axis}={value:9.4f}" for axis, value in positions.items())


def _progress() -> Progress:
    return Progress(TextColumn("{task.description}", markup=False), BarColumn(),
                    TimeElapsedColumn(), console=console, transient=False)


# -- demo -------------------------------------------------------------------------------

#: Side of the square field of the demo's raster scan, in mm.
_FIELD = 10.0


async def _demo(args: argparse.Namespace) -> int:
    """Identify the controller, calibrate and measure the range of every axis, then run a
    raster scan over a 10 x 10 mm field with a trigger list on X. On a real controller
    (any URL but sim://) every axis, Z/focus included, moves to its limit switches: the
    demo asks first unless --yes is given."""
    started = time.monotonic()
    async with connect(args.url) as tango:
        ident = tango.identity
        _say(f"Connected to {ident.model} firmware {ident.firmware}, "
             f"{_plural(ident.axes, 'axis', 'axes')} at {args.url}", "bold")
        await _demo_reference(tango)
        pulses = await _demo_scan(tango, rows=args.rows, points=args.points)
        final = await tango.position()
        summary = _table("Summary", show_header=False)
        _row(summary, "controller", f"{ident.model} {ident.firmware}")
        _row(summary, "final position", _fmt_positions(final))
        _row(summary, "trigger pulses", str(pulses))
        _row(summary, "elapsed", f"{time.monotonic() - started:.1f} s")
        console.print(summary)
    return 0


async def _demo_reference(tango: Controller) -> None:
    phases = (("Phase 1/3: calibrate (cal), every axis to its lower limit switch",
               tango.calibrate),
              ("Phase 2/3: range measure (rm), every axis to its upper limit switch",
               tango.measure_range))
    for label, action in phases:
        _say(label, "bold")
        with _progress() as progress:
            task = progress.add_task("starting", total=None)
            letters = await _follow(action(), _show_position(tango, progress, task), 0.2)
        _say(f"  done: {describe_letters(letters)}")
    if tango.context.axes >= 3:
        # The range measure leaves Z, the focus on a microscope, at its upper limit
        # switch: it goes back to the middle of its range (moc, L6509).
        _say("  Z (focus) back to the middle of its range (moc z)")
        await _follow(tango.move_to_center("z"), lambda: asyncio.sleep(0), 0.2)


def _show_position(tango: Controller, progress: Progress,
                   task: TaskID) -> Callable[[], Awaitable[None]]:
    async def poll() -> None:
        progress.update(task, description=_fmt_positions(await tango.position()))
    return poll


async def _demo_scan(tango: Controller, *, rows: int, points: int) -> int:
    """A raster over the field; X carries a trigger list of ``points`` positions. With one
    axis, the rows are passes of X back and forth.

    Returns
    -------
    int
        The exit status.
    """
    two_d = tango.context.axes >= 2
    await (tango.move_to(x=0.0, y=0.0) if two_d else tango.move_to(x=0.0))
    step = _FIELD / max(points - 1, 1)
    await tango.command("!trigp x 0")
    for index in range(points):
        await tango.command(f"!trigp -1 {index * step + 0.5:.4f}")
    await tango.command("!trigcount 0")
    await tango.command("!trig 1")  # the list only fires once enabled (manual L12565)
    _say(f"Phase 3/3: raster scan, {_plural(rows, 'row', 'rows')} of X from 0 to "
         f"{_FIELD + 1:g} mm and back, a trigger list of "
         f"{_plural(points, 'position', 'positions')} on X", "bold")
    with _progress() as progress:
        task = progress.add_task("raster scan", total=rows)
        for row in range(rows):
            x_end = _FIELD + 1.0 if row % 2 == 0 else 0.0
            if two_d:
                await tango.move_to(y=row * _FIELD / max(rows - 1, 1))
            await _follow(tango.move_to(x=x_end), _show_position(tango, progress, task), 0.2)
            progress.advance(task)
    pulses = int(await tango.get("trigcount"))
    forward = (rows + 1) // 2
    _say(f"  {_plural(pulses, 'trigger pulse', 'trigger pulses')}: the list's positions "
         f"rise, so it fires while X moves in that direction, on the "
         f"{_plural(forward, 'forward row', 'forward rows')} of {rows}; the return rows "
         f"fire none")
    return pulses


# -- info -------------------------------------------------------------------------------


async def _info(args: argparse.Namespace) -> int:
    """Print the controller's identity and main settings."""
    async with connect(args.url) as tango:
        ident = tango.identity
        table = _table(f"TANGO at {args.url}", show_header=False)
        _row(table, "model", ident.model)
        _row(table, "firmware", ident.firmware)
        _row(table, "axes", str(ident.axes))
        _row(table, "options", ", ".join(sorted(ident.det.options)) or "-")
        for name, value in info_rows(await tango.read_info()):
            _row(table, name, value)
        dims = await tango.get("dim")
        units = {axis: DIM_UNITS[int(dim)].symbol if int(dim) in DIM_UNITS else f"dim {dim}"
                 for axis, dim in dims.items()}
        positions = await tango.position()
        _row(table, "position", "  ".join(f"{axis}={value:9.4f} {units.get(axis, '')}"
                                          for axis, value in positions.items()))
        _row(table, "status", describe_letters(await tango.status()))
        velocity = {axis: velocity_unit(int(dim)) for axis, dim in dims.items()}
        for name, unit in (("dim", units), ("pitch", "mm/rev"), ("vel", velocity),
                           ("accel", "m/s²"), ("secvel", "mm/s")):
            text = str(await tango.query(f"?{name}"))
            _row(table, name, _with_units(text, unit, name == "dim"))
        console.print(table)
    return 0


def _with_units(text: str, unit: str | Mapping[str, str], named: bool) -> str:
    """A per-axis reply (``2 2 2``) as ``x=2 mm ...`` (``named``: ``x=2 (mm)``); a reply
    of another shape as it is, with a single unit behind it.

    Returns
    -------
    str
        The reply with its units.
    """
    values = text.split()
    units = dict.fromkeys(AXES[: len(values)], unit) if isinstance(unit, str) else dict(unit)
    if len(values) != len(units):
        return f"{text} {next(iter(units.values()), '')}".strip()
    return "  ".join(f"{axis}={value} ({units[axis]})" if named else
                     f"{axis}={value} {units[axis]}"
                     for axis, value in zip(units, values, strict=True))


# -- sim --------------------------------------------------------------------------------


async def _sim(args: argparse.Namespace) -> int:
    """Serve an emulated controller on a pty or a TCP port until interrupted."""
    from ..sim.inprocess import configs_from_url, speed_from_url
    from ..sim.model import ControllerModel
    from ..sim.serve import serve_tcp
    from ..sim.wire import Emit

    address = _tcp_address(args.tcp) if args.tcp else None
    if args.per_connection and address is None:
        raise UsageError("--per-connection needs --tcp (a pty serves one controller)")
    url = _sim_url(args)
    sim_config, wire_config = configs_from_url(url)
    speed = speed_from_url(url)

    def factory(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, sim_config)

    factory(lambda data: None)  # a bad --state file: one error now, not one per connection
    if address is not None:
        try:
            server = await serve_tcp(factory, host=address[0], port=address[1],
                                     config=wire_config, speed=speed,
                                     shared=not args.per_connection)
        except OSError as exc:
            raise OSError(_bind_failure(address, exc)) from exc
        host = f"[{server.host}]" if ":" in server.host else server.host
        print(f"socket://{host}:{server.port}", flush=True)
    else:
        _check_pty_platform()
        from ..sim.ptyserve import serve_pty

        server = await serve_pty(factory, config=wire_config,  # type: ignore[assignment]
                                 speed=speed)
        print(server.path, flush=True)  # type: ignore[attr-defined]
    async with server:
        await server.wait_closed()
    return 0


def _bind_failure(address: tuple[str, int], exc: OSError) -> str:
    """Why ``sim --tcp`` could not listen, in words, with the next step."""
    host, port = address
    if exc.errno == errno.EADDRINUSE:
        return (f"port {port} on {host} is already in use (another tango-aio sim?): choose "
                f"another, or --tcp {host}:0 for any free port")
    if exc.errno == errno.EADDRNOTAVAIL:
        return f"{host} is not an address of this machine: use 127.0.0.1 or one of its own"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return f"this user may not listen on port {port}: choose a port above 1023"
    reason = exc.strerror or str(exc)
    return f"cannot listen on {host}:{port}: {reason}"


#: What ``tango-aio sim --pty`` says on Windows (one line).
PTY_NEEDS_POSIX = ("the pty emulator needs a POSIX system (Linux, macOS); on Windows serve "
                   "over TCP: tango-aio sim --tcp 127.0.0.1:4001, then connect to "
                   "socket://127.0.0.1:4001 (or bridge it to a com0com port pair)")


def _check_pty_platform() -> None:
    """Raise a one-line error where there are no ptys (Windows)."""
    from .._platform import WINDOWS

    if WINDOWS:
        raise ValueError(PTY_NEEDS_POSIX)


def _tcp_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` (host 127.0.0.1) or ``[IPv6]:PORT`` as (host,
    port); a usage error with the reason for anything else.

    Returns
    -------
    tuple[str, int]
        The host and the port.

    Raises
    ------
    UsageError
        The text is no such address.
    """
    host, _, port_text = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise UsageError(f"--tcp {text!r}: write an IPv6 address in brackets, e.g. "
                          f"[::1]:4001")
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise UsageError(f"--tcp {text!r}: expected [HOST:]PORT, the port a number 0-65535 "
                          f"(0: any free one), e.g. 4001 or 127.0.0.1:4001")
    return host or "127.0.0.1", int(port_text)


def _sim_url(args: argparse.Namespace) -> str:
    """The ``sim://`` URL of the sim command's options (checked by its parser)."""
    from urllib.parse import urlencode

    from ..sim.profiles import Firmware

    switches = dict(_switch(text) for text in args.switch)
    fingerprint = getattr(args, "fingerprint", None)
    try:
        if fingerprint is not None:
            if args.profile is not None:
                raise ValueError("--fingerprint and --profile exclude each other")
            # A probe's fingerprint: the unit's switch values (unknown names or values)
            Firmware.from_fingerprint(fingerprint).with_(**switches)
            base: dict[str, object] = {"fingerprint": fingerprint}
        else:
            profile = args.profile or "manual"
            Firmware.from_options(profile, **switches)  # unknown names or values
            base = {"profile": profile}
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    query: dict[str, object] = {
        "axes": args.axes, "baud": args.baud, "latency": args.latency,
        "processing": args.processing, "speed": _speed(args.speed), **base, **switches}
    if args.state:
        query["state"] = args.state
    return "sim://?" + urlencode(query)


def _speed(text: str) -> float:
    from ..sim.clock import check_speed

    try:
        return check_speed(float(text))
    except ValueError:
        raise UsageError(f"--speed {text!r}: expected a finite number > 0, e.g. 20") from None


def _switch(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise UsageError(f"--switch {text!r}: expected NAME=VALUE, e.g. echo=after")
    return name.strip(), value.strip()


# -- decoding of replies and events -----------------------------------------------------

#: Each status letter (:mod:`tango_aio.status`) in the shell's short words.
LETTER_MEANINGS: dict[str, str] = {
    AxisStatus.READY: "ok", AxisStatus.MOVING: "moving", AxisStatus.JOYSTICK: "ok, joystick",
    AxisStatus.LIMIT_SWITCH: "limit switch", AxisStatus.CALIBRATED: "ok, calibrated",
    AxisStatus.RANGE_MEASURED: "ok, range measured", AxisStatus.ERROR: "error/aborted",
    AxisStatus.TIMEOUT: "timeout", AxisStatus.CLOSED_LOOP: "closed loop",
    AxisStatus.MANUAL_ADJUSTMENT: "manual adjustment", ABSENT: "absent",
}

_KIND_NAMES = {"move": "move", "cal": "calibration", "rm": "range measure"}


def describe_letters(statuses: Mapping[str, str]) -> str:
    """``{"x": "@", "y": "E"}`` → ``"x=@ (ok) y=E (error/aborted)"``.

    Parameters
    ----------
    statuses
        The status letter of each axis, by axis letter.

    Returns
    -------
    str
        The letters with their meanings.
    """
    return " ".join(f"{axis}={letter} ({LETTER_MEANINGS.get(letter, 'unknown')})"
                    for axis, letter in statuses.items())


def letters_of_line(line: str) -> dict[str, str]:
    """The per-axis letters of a completion or statusaxis line (``@@E-.``, ``@@@-.-``);
    absent axes (``-``) are left out.

    Parameters
    ----------
    line
        The line, as received.

    Returns
    -------
    dict[str, str]
        The letter of each axis present, by axis letter.
    """
    head = line.strip().split(".", 1)[0]
    return {axis: letter for axis, letter in zip(AXES, head, strict=False) if letter != ABSENT}


def describe_error(code: int | None) -> str:
    """An error number in words, from the manual's error table.

    Parameters
    ----------
    code
        The error number, or ``None`` if the controller gave none.

    Returns
    -------
    str
        The words.
    """
    if code is None:
        return "error (the controller gave no number)"
    if code == 0:
        return "no error"
    return f"error {code}: {ERROR_DESCRIPTIONS.get(code, 'undocumented error number')}"


def describe_reply(command: CommandLine, reply: str) -> str:
    """The reply text, with error numbers, ``ERR n`` and status letters decoded.

    Parameters
    ----------
    command
        The line that was sent.
    reply
        Its reply, lines separated by LF.

    Returns
    -------
    str
        The reply with what it means.
    """
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
    """An unsolicited line from the controller in words.

    Parameters
    ----------
    line
        The line, as received.

    Returns
    -------
    str
        The words.
    """
    text = line.strip()
    if is_completion_line(text):
        return f"status report: {describe_letters(letters_of_line(text))}"
    if text.startswith("ERR"):
        with contextlib.suppress(ProtocolError):
            return f"controller reports {describe_error(parse_error_reply(text)[0])}"
    return f"unsolicited line: {line!r}"


def describe_event(event: TangoEvent) -> str | None:
    """An event of :meth:`Controller.events` in words (``None``: not worth showing).

    Parameters
    ----------
    event
        The event.

    Returns
    -------
    str or None
        The words, or ``None``.
    """
    if isinstance(event, MoveFinished):
        what = _KIND_NAMES.get(event.kind, event.kind)
        letters = describe_letters(event.statuses) or "no status letters (autostatus 3)"
        return f"{what} finished: {letters}"
    if isinstance(event, StatusReport):
        return f"status report: {describe_letters(event.statuses)}"
    if isinstance(event, MoveAborted):
        if event.axes:
            lines = ", ".join(f"a {axis}" for axis in event.axes)
            return f"stop sent ({lines}): {' '.join(event.axes).upper()} stop"
        return f"abort sent ({'Ctrl+C' if event.ctrl_c else 'a'}): all axes stop"
    if isinstance(event, UnsolicitedLine):
        return describe_line(event.line)
    if isinstance(event, ConnectionLost):
        return f"connection lost: {event.cause or 'closed'}"
    if isinstance(event, Reconnected):
        return f"reconnected (attempt {event.attempt})"
    if isinstance(event, ControllerRestarted):
        changed = ", ".join(event.settings) or "none changed"
        return (f"the controller restarted (it was in autostatus {event.found}): "
                f"autostatus {event.autostatus} selected again, settings read again "
                f"({changed}); positions restart at 0")
    return None


def describe_exception(exc: BaseException) -> str:
    """An error as one line for the user: the message, with a move's status letters in
    words, and each member of an exception group.

    Parameters
    ----------
    exc
        The error.

    Returns
    -------
    str
        The line.
    """
    if isinstance(exc, BaseExceptionGroup):
        return "; ".join(dict.fromkeys(describe_exception(e) for e in exc.exceptions))
    text = _escaped(" ".join(str(exc).split()) or type(exc).__name__)
    if isinstance(exc, MoveError) and exc.statuses:
        text = re.sub(r" with status \{[^{}]*\}", "", text)  # said in words below
        text = re.sub(r"\{([^{}]*)\}", _pairs, text)
        text = f"{text}: {describe_letters(exc.statuses)}"
    return text


def _pairs(match: re.Match[str]) -> str:
    """``{'x': '0.5000', 'y': 1.0}`` (a dict in a message) as ``x=0.5000 y=1.0``."""
    pairs = re.findall(r"'([^']*)': '?([^',]*)'?", match.group(1))
    return " ".join(f"{key}={value}" for key, value in pairs) if pairs else match.group(0)


_FORM_ORDER = [Form.SET, Form.READ, Form.BARE]


def describe_instruction(entry: Instruction) -> str:
    """Help text of one instruction from the catalog (the shell's ``help NAME``).

    Parameters
    ----------
    entry
        The instruction.

    Returns
    -------
    str
        The help text.
    """
    first, *more = _summary_parts(entry.summary)
    lines = [f"{entry.name}: {first}", *(f"  {part}" for part in more)]
    if entry.aliases:
        lines.append(f"  also written: {', '.join(entry.aliases)}")
    for form in sorted(entry.forms, key=_FORM_ORDER.index):
        prefix = form.value
        what = ("reads" if entry.is_read(form) else "sets or runs")
        for sig in entry.signatures(form) or (Signature(),):
            usage = " ".join((f"{prefix}{entry.name}", *_usage(sig))).rstrip()
            lines.append(f"  {usage:<40} {what}")
    if entry.completion is not None:
        lines.append("  sends a completion report when the axes have stopped (autostatus)")
    if entry.section:
        lines.append(f"  manual section {entry.section}, line {entry.line}")
    return "\n".join(lines)


@functools.lru_cache(maxsize=1)
def _summary_split() -> re.Pattern[str]:
    """Where a catalog summary runs two of the manual's example lines together: before a
    verb that starts summaries (``... 10 10 10 Move Y axis to ...``).

    Returns
    -------
    re.Pattern[str]
        The pattern.
    """
    from ..catalog import INSTRUCTIONS

    verbs = {entry.summary.split()[0] for entry in INSTRUCTIONS.values() if entry.summary}
    verbs = {verb for verb in verbs if len(verb) > 2 and verb.isalpha() and verb.istitle()
             and verb not in _NOT_VERBS}
    alternatives = "|".join(sorted(verbs))
    return re.compile(rf"(?<=[a-z0-9)\]]) (?=(?:{alternatives}) )")


#: Words that start some summaries but do not start a sentence of their own.
_NOT_VERBS = frozenset({"Maximum", "Closed", "Multi", "One", "Only", "Liquid", "Trigger",
                        "Virtual", "Power", "Dummy"})


def _summary_parts(summary: str) -> list[str]:
    """A catalog summary as its sentences (see :func:`_summary_split`)."""
    return [part.strip() for part in _summary_split().split(summary) if part.strip()]


def _usage(sig: Signature) -> list[str]:
    words = [] if sig.axis.value == "none" else [
        "AXIS" if sig.axis.value == "required" else "[AXIS]"]
    for param in sig.lead:
        words.append(_param_word(param))
    if sig.per_axis:
        group = " ".join(_param_word(p) for p in sig.per_axis)
        words.append(group if sig.axis.value == "all" else f"{group}...")
    if sig.precision is not None:
        words.append("[digits]")
    return words


def _param_word(param: Any) -> str:
    if param.choices:
        text = f"{param.name}={'|'.join(str(c) for c in param.choices)}"
    elif param.lo is not None and param.hi is not None:
        text = f"{param.name}({param.lo:g}..{param.hi:g}{' ' + param.unit if param.unit else ''})"
    else:
        text = f"{param.name}{'(' + param.unit + ')' if param.unit else ''}"
    return f"[{text}]" if param.optional else text


@contextlib.contextmanager
def _sigint_calls(callback: Callable[[], None]) -> Iterator[None]:
    """Run ``callback`` on SIGINT (Ctrl+C) instead of interrupting the program; on
    Windows through ``signal.signal`` (:func:`tango_aio._platform.signal_calls`); nothing
    is installed outside the main thread."""
    from .._platform import signal_calls

    with signal_calls(signal.SIGINT, callback):
        yield


# -- shell ------------------------------------------------------------------------------

#: Default history file of the shell; the environment variable TANGO_AIO_HISTORY overrides.
HISTORY_FILE = "~/.tango_aio_history"
_PROMPT = "tango> "
#: Longest input line the shell reads; the rest of a longer line is skipped. Instruction
#: lines are at most 255 bytes (manual L129-131), so the validator rejects such lines.
_MAX_INPUT = 4096

SHELL_HELP = """\
Type instruction lines: ?pos reads, !moa 10 5 sets or runs, sa (bare form) as the manual
allows. Each line is checked against the instruction catalog before it is sent; lines
that set or run something are confirmed, so that a rejection shows its error number.
Shell commands:
  help           this text
  help NAME      an instruction from the catalog, e.g. help moa
  help NUMBER    an error number in words, e.g. help 5
  wait           wait until no axis moves
  exit, quit     leave (Ctrl+D too); axes still moving are stopped
Ctrl+C stops all axes (Ctrl+C to the controller) and the shell goes on.
Status letters: @ ok, M moving, S limit switch, E error/aborted, T timeout,
A calibrated, D range measured, J joystick, - absent."""


class LineReader(Protocol):
    """Where the shell gets its input lines."""

    async def read(self) -> str:
        """The next line; raises EOFError at the end, KeyboardInterrupt for Ctrl+C.

        Returns
        -------
        str
            The line.

        Raises
        ------
        EOFError
            At the end of input.
        KeyboardInterrupt
            For Ctrl+C.
        """
        ...


class _TerminalReader:
    """prompt_toolkit input with editing and a persistent history (stdin is a tty)."""

    def __init__(self, history: Path) -> None:
        from prompt_toolkit import PromptSession
        from prompt_toolkit.history import FileHistory, History, InMemoryHistory

        class KeptHistory(FileHistory):
            """A history file that, once it cannot be written, warns once and is no
            longer written (instead of an error in the prompt after every line)."""

            failed = False

            def store_string(self, string: str) -> None:
                if not self.failed:
                    try:
                        super().store_string(string)
                    except OSError as exc:
                        self.failed = True
                        _history_warning(history, exc)

        kept: History
        try:
            with open(history, "ab"):  # can it be written? Say so once, at the start
                pass
        except OSError as exc:
            _history_warning(history, exc)
            kept = InMemoryHistory()
        else:
            kept = KeptHistory(str(history))
        self._session: PromptSession[str] = PromptSession(history=kept)

    async def read(self) -> str:
        return await self._session.prompt_async(_PROMPT, handle_sigint=False)


def _history_warning(history: Path, exc: OSError) -> None:
    _complain(f"warning: the history file {history} cannot be written "
         f"({exc.strerror or exc}): no history is kept; set TANGO_AIO_HISTORY to another "
         f"file", "yellow")


def read_bounded_line(stream: BinaryIO, limit: int) -> tuple[bytes, bool]:
    """The next line, reading at most ``limit + 1`` bytes, and whether it is longer than
    ``limit`` bytes (then it was cut, and the next read continues it). ``b""`` with False
    at the end of input.

    Parameters
    ----------
    stream
        The binary input.
    limit
        The most bytes a line may have.

    Returns
    -------
    tuple[bytes, bool]
        The line (or its first ``limit`` bytes) and whether it was cut.
    """
    line = stream.readline(limit + 1)
    return line, len(line) > limit and not line.endswith(b"\n")


class _PipeReader:
    """Lines from a non-interactive stdin, read by a daemon thread (never blocks exit).
    Bytes are decoded as UTF-8 with replacement characters, so no input kills the reader;
    a read error ends the input."""

    def __init__(self, stream: BinaryIO | None = None) -> None:
        self._lines: asyncio.Queue[str] = asyncio.Queue()
        loop = asyncio.get_running_loop()
        source = stream if stream is not None else sys.stdin.buffer

        def deliver(text: str) -> bool:
            """Hand ``text`` to the loop; False once the loop is closed (the shell has
            ended while this thread still read: nobody is left to take the line).

            Returns
            -------
            bool
                Whether the loop took the text.
            """
            try:
                loop.call_soon_threadsafe(self._lines.put_nowait, text)
            except RuntimeError:
                return False
            return True

        def pump() -> None:
            skipping = False  # inside the rest of a line that was too long
            try:
                while True:
                    line, cut = read_bounded_line(source, _MAX_INPUT)
                    if not line:
                        break
                    if skipping:
                        skipping = cut
                        continue
                    skipping = cut
                    if not deliver(line.decode("utf-8", errors="replace")):
                        return
            except (OSError, ValueError):
                pass
            finally:
                deliver("")  # the end of the input

        self._thread = threading.Thread(target=pump, name="tango-aio-stdin", daemon=True)
        self._thread.start()

    async def read(self) -> str:
        line = await self._lines.get()
        if not line:
            raise EOFError
        return line.rstrip("\r\n")


def history_path() -> Path:
    """The shell's history file: $TANGO_AIO_HISTORY, or ~/.tango_aio_history.

    Returns
    -------
    Path
        The file.
    """
    return Path(os.environ.get("TANGO_AIO_HISTORY") or HISTORY_FILE).expanduser()


class Shell:
    """The interactive line shell of ``tango-aio shell`` on a connected controller.

    :meth:`run` returns the exit status: 1 when the connection was lost, when a move a
    line started did not end at its target (judged at ``wait``, when its completion
    report comes, and on leaving: a move still running then is stopped and counts as
    failed) or, for a ``script``, when a line failed (invalid, rejected by the
    controller, an error); else 0.

    Parameters
    ----------
    tango
        The connected controller.
    reader
        Where the input lines come from.
    script
        The input is piped (a failed line makes the exit status 1).
    """

    def __init__(self, tango: Controller, reader: LineReader, *, script: bool = False
                 ) -> None:
        self.tango = tango
        self.reader = reader
        #: Whether the input is a script (piped): then a failed line makes the exit status 1.
        self.script = script
        self.failures = 0
        self._job: asyncio.Future[None] | None = None
        self._aborting: asyncio.Future[None] | None = None
        self._lost = asyncio.Event()
        #: Moves the shell's lines started and not judged yet: axis -> (serial, target;
        #: ``None`` where the line gives no absolute target: mor, cal, rm, moc).
        self._moves: dict[str, tuple[int, float | None, bool]] = {}
        self._serial = 0
        self._judging = asyncio.Lock()
        #: How many judged moves did not end at their target.
        self.move_failures = 0

    async def run(self) -> int:
        """Read, validate and send lines until ``exit``, ``quit``, end of input or the
        loss of the connection; stop axes still moving when leaving.

        Returns
        -------
        int
            The exit status: 1 if a line of a script or a move failed, or the connection was
            lost; else 0.
        """
        async with self.tango.events() as events:
            printer = asyncio.ensure_future(self._print_events(events))
            try:
                with _sigint_calls(self._on_sigint):
                    await self._loop()
                    if not self._lost.is_set():
                        await self._settle_abort()
                        await self._judge(leaving=True)
                        await self._stop_moving()
            finally:
                printer.cancel()
                await asyncio.wait({printer})
        failed = (self.script and self.failures) or self.move_failures or self._lost.is_set()
        return 1 if failed else 0

    async def _loop(self) -> None:
        while True:
            try:
                line = await self._next_line()
            except EOFError:
                return
            except KeyboardInterrupt:  # Ctrl+C at the prompt
                await self._abort()
                continue
            if line is None:  # the connection is gone
                return
            if line.lower() in ("exit", "quit"):
                return
            if line:
                await self._settle_abort()
                await self._run_line(line)

    async def _next_line(self) -> str | None:
        """The next input line, or ``None`` as soon as the connection is lost."""
        read = asyncio.ensure_future(self._read())
        lost = asyncio.ensure_future(self._lost.wait())
        try:
            await asyncio.wait({read, lost}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            lost.cancel()
            if not read.done():
                read.cancel()
                await asyncio.wait({read})
        if self._lost.is_set():
            return None
        line = read.result()
        if isinstance(line, BaseException):
            raise line
        return line.strip()

    async def _read(self) -> str | KeyboardInterrupt:
        """A line, or the reader's KeyboardInterrupt as a value: raised inside a task it
        would stop the event loop.

        Returns
        -------
        str or KeyboardInterrupt
            The line, or the interrupt.
        """
        try:
            return await self.reader.read()
        except KeyboardInterrupt as interrupt:
            return interrupt

    async def _run_line(self, line: str) -> None:
        """Run one line as a job that Ctrl+C cancels (and then aborts)."""
        job = self._job = asyncio.ensure_future(self.execute(line))
        try:
            await asyncio.wait({job})
        finally:
            self._job = None
            job.cancel()
        if job.cancelled():
            _complain(f"interrupted: {line}", "yellow")
            self.failures += 1
            await self._abort()
            return
        error = job.exception()
        if isinstance(error, InvalidCommandError):
            _complain(f"invalid: {describe_exception(error)} (nothing sent)", "yellow")
        elif isinstance(error, TangoError):
            _complain(f"error: {describe_exception(error)}", "red")
        else:
            job.result()
            return
        self.failures += 1

    async def execute(self, line: str) -> None:
        """Run one line: a shell command (``help``, ``wait``), or an instruction line,
        validated first; a read is sent with ``query`` and its decoded reply shown,
        anything else with ``command`` and confirmed (a rejection raises).

        Parameters
        ----------
        line
            The line typed or piped.
        """
        words = line.split()
        if words[0].lower() == "help" and len(words) <= 2:
            _say(self.help(words[1] if len(words) == 2 else None))
            return
        if words == ["wait"]:
            letters = await self.tango.wait_idle()
            _say(f"idle: {describe_letters(letters)}")
            await self._judge()
            return
        command = parse(line, self.tango.context)
        if command.is_read:
            _say(describe_reply(command, await self.tango.query(line)))
        else:
            await self.tango.command(line)
            self._started(command)
            _say("ok", "dim")

    def _started(self, command: CommandLine) -> None:
        """Remember the axes (and absolute targets) of a move line the controller took,
        to judge later whether it ended at its target."""
        if command.instruction.completion is None and command.name != "go":
            return
        present = AXES[: self.tango.context.axes]
        axes = moved_axes(command, present)
        targets: dict[str, float] = {}
        if command.name in ("moa", "go") and command.values:
            targets = dict(zip(axes, (float(v) for v in command.values), strict=False))
        optional = optional_axes(command, axes)
        for axis in axes:
            self._serial += 1
            self._moves[axis] = (self._serial, targets.get(axis), axis in optional)

    async def _judge(self, *, leaving: bool = False) -> None:
        """Judge the moves the shell's lines started whose axes stand now, by the
        driver's own rule (:func:`~tango_aio.moves.failed_axes`). ``leaving``: an axis
        still moving counts as failed (it is stopped next). Failures are printed in words
        and counted."""
        async with self._judging:
            pending = dict(self._moves)
            if not pending:
                return
            try:
                letters = await self.tango.status()
                reply = await self.tango.query("?pos")
            except (TangoError, TimeoutError) as exc:
                _complain(f"error: reading the state after a move: {describe_exception(exc)}",
                     "red")
                self.move_failures += 1
                return
            texts = dict(zip(AXES[: self.tango.context.axes], reply.split(),
                             strict=False))
            failed = []
            for axis, (serial, target, optional) in pending.items():
                letter = letters.get(axis, ABSENT)
                if letter == MOVING and not leaving:
                    continue  # not ended yet
                if self._moves.get(axis, (0, None, False))[0] == serial:
                    del self._moves[axis]
                text = texts.get(axis)
                if letter == MOVING:
                    failed.append(describe_stop(axis, letter, text, target,
                                                why="still moving when the shell was left"))
                elif failed_axes((axis,), None if target is None else {axis: target}, {},
                                 letters, texts, optional=(axis,) if optional else ()):
                    failed.append(describe_stop(axis, letter, text, target))
            if failed:
                self.move_failures += 1
                _complain(f"move failed: {'; '.join(failed)}", "red")

    @staticmethod
    def help(topic: str | None) -> str:
        """The shell's help: its commands, an instruction, or an error number.

        Parameters
        ----------
        topic
            A shell command, an instruction name or an error number; ``None`` for the list of
            the shell's commands.

        Returns
        -------
        str
            The help text.
        """
        if topic is None:
            return SHELL_HELP
        if topic.lstrip("-").isdigit():
            return describe_error(int(topic))
        name = topic.lstrip("!?").lower()
        try:
            return describe_instruction(lookup(name))
        except InvalidCommandError:
            close = similar_names(name)
            hint = f"did you mean {' or '.join(close)}? " if close else ""
            return (f"no instruction {topic!r} in the catalog; {hint}'help' lists the "
                    f"shell's commands")

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
            _complain(f"error: abort: {describe_exception(exc)}", "red")

    async def _stop_moving(self) -> None:
        """Stop the axes that still move when the shell is left."""
        await self._settle_abort()
        try:
            moving = [a for a, s in (await self.tango.status()).items() if s == MOVING]
            if moving:
                _complain(f"stopping the axes that still move: {' '.join(moving)}", "yellow")
                await self.tango.abort()
        except (TangoError, TimeoutError) as exc:
            _complain(f"error: stopping the axes: {describe_exception(exc)}", "red")
            self.failures += 1

    async def _print_events(self, events: Subscription) -> None:
        async for event in events:
            text = describe_event(event)
            if text is not None:
                _say(text, "red" if isinstance(event, ConnectionLost) else "cyan")
            if isinstance(event, ConnectionLost):
                self._lost.set()
            elif isinstance(event, MoveFinished | StatusReport) and self._moves:
                with contextlib.suppress(TangoError, TimeoutError):
                    await self._judge()


async def _shell(args: argparse.Namespace) -> int:
    """Interactive shell: type instruction lines (``?pos``, ``!moa 10 5``), validated
    before sending; lines that set or run something are confirmed, so that a rejection
    shows its error. Completion reports, error numbers and unsolicited lines are shown in
    words. ``help`` lists the shell's commands, ``help moa`` explains an instruction.
    Ctrl+C aborts (all axes stop); Ctrl+D, ``exit`` or ``quit`` leave, stopping axes that
    still move. Lines piped into the shell run as a script, whose exit status is 1 if any
    line failed; in both modes it is 1 if a move did not end at its target (a move still
    running at the end is stopped and counts as failed). History is kept
    in ~/.tango_aio_history ($TANGO_AIO_HISTORY)."""
    async with connect(args.url) as tango:
        ident = tango.identity
        # On stderr: stdout holds the replies only (a script's).
        _complain(f"connected to {ident.model} firmware {ident.firmware}, "
                  f"{_plural(ident.axes, 'axis', 'axes')} at {args.url}; 'help' lists the "
                  f"commands, Ctrl+C aborts, Ctrl+D or 'exit' leaves", "bold")
        if sys.stdin.isatty() and sys.stdout.isatty():
            from prompt_toolkit.patch_stdout import patch_stdout

            with patch_stdout(raw=True):
                return await Shell(tango, _TerminalReader(history_path())).run()
        return await Shell(tango, _PipeReader(), script=True).run()


# -- move -------------------------------------------------------------------------------


#: A number as a user types it (no ``1_000``, no ``nan``), then an optional unit.
_TARGET = re.compile(r"([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([a-zA-Zµ/]*)")


def _axis_target(token: str) -> tuple[str, float, str | None]:
    """argparse type of ``x=1.5``, ``x=1mm`` or ``y=-500um``: axis, value and unit
    (``None``: the controller's unit).

    Returns
    -------
    tuple[str, float, str | None]
        The axis, the value and its unit.

    Raises
    ------
    argparse.ArgumentTypeError
        The token is no such target.
    """
    from ..units import check_unit

    axis, sep, text = token.partition("=")
    axis = axis.strip().lower()
    if not sep or axis not in AXES:
        raise argparse.ArgumentTypeError(f"expected AXIS=VALUE, AXIS one of x y z a: {token!r}")
    match = _TARGET.fullmatch(text.strip())
    if match is None:
        raise argparse.ArgumentTypeError(f"not a number: {token!r} (write e.g. x=1000, "
                                         f"x=1.5mm or x=-500um)")
    value = float(match.group(1))
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"not a finite number: {token!r}")
    unit = match.group(2) or None
    if unit is not None:
        try:
            check_unit(unit)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"{token!r}: {exc}") from None
    return axis, value, unit


def _one_unit(targets: Sequence[tuple[str, float, str | None]]
              ) -> tuple[dict[str, float], str | None]:
    """The targets in one unit: lengths in different units are converted to mm; a unit
    on some axes and none on others is refused (which unit would the bare ones be?).

    Returns
    -------
    tuple[dict[str, float], str | None]
        The target of each axis, and their unit.

    Raises
    ------
    UsageError
        Units are mixed with bare values, do not convert, or an axis is given twice.
    """
    from ..units import LENGTH_UNITS

    units = {unit for _, _, unit in targets}
    if len(units) > 1 and None in units:
        raise UsageError("give every axis a unit, or none (the controller's unit)")
    if len(units) > 1 and not units <= set(LENGTH_UNITS):
        raise UsageError(f"the units {', '.join(sorted(map(str, units)))} do not convert "
                          f"into each other: give every axis the same unit")
    chosen = next(iter(units)) if len(units) == 1 else "mm"
    values: dict[str, float] = {}
    for axis, value, unit in targets:
        if axis in values:
            raise UsageError(f"axis {axis} given twice")
        values[axis] = value if unit == chosen or unit is None else \
            float(value * LENGTH_UNITS[unit])
    return values, chosen


def _distance(start: Mapping[str, float], end: Mapping[str, float]) -> float:
    return math.dist([start.get(a, 0.0) for a in end], list(end.values()))


async def _move(args: argparse.Namespace) -> int:
    """Move axes to absolute positions (x=10 y=5), or by distances with --relative,
    showing the distance covered; prints the final status letters in words. Values are in
    the controller's unit, or carry their own (x=1.5mm, y=-500um; nm um mm cm m in mil
    rev ustep). Ctrl+C stops the axes."""
    targets, unit = _one_unit(args.targets)
    async with connect(args.url, units=unit) as tango:
        start = await tango.position()
        ends = {a: start.get(a, 0.0) + v if args.relative else v for a, v in targets.items()}
        mover: Callable[..., Awaitable[dict[str, str]]] = (
            tango.move_by if args.relative else tango.move_to)
        with Progress(TextColumn("moving"), BarColumn(),
                      TextColumn("{task.completed:.4f} / {task.total:.4f}"),
                      TimeElapsedColumn(), console=console, transient=True,
                      disable=not console.is_terminal) as progress:
            task = progress.add_task("", total=max(_distance(start, ends), 1e-9))

            async def poll() -> None:
                position = await tango.position()
                covered = _distance(start, {a: position[a] for a in start})
                progress.update(task, completed=covered)

            letters = await _follow(mover(**targets), poll, 0.1)
        _say(f"done: {describe_letters(letters)}")
        _say(f"position: {_fmt_positions(await tango.position())}")
    return 0


# -- monitor ----------------------------------------------------------------------------


def _monitor_table(url: str, positions: Mapping[str, float],
                   letters: Mapping[str, str]) -> Table:
    table = _table(f"TANGO at {url}", ("axis", "position", "status", "meaning"))
    for axis, value in positions.items():
        letter = letters.get(axis, "?")
        _row(table, axis, f"{value:.4f}", letter, LETTER_MEANINGS.get(letter, "unknown"))
    return table


async def _monitor(args: argparse.Namespace) -> int:
    """Show a live table of the positions and status letters of every axis, refreshed
    every --interval seconds, until Ctrl+C (exit code 130) or --count refreshes (0)."""
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
    return 130 if stop.is_set() else 0  # Ctrl+C ended it: 130, as every command


# -- ports ------------------------------------------------------------------------------


async def _probe(timeout: float, ports: Sequence[str] | None) -> dict[str, str]:
    """Port → what probing it found, in a few words: "TANGO model firmware", "no
    answer", "permission denied (...)", "busy (...)", "not found".

    Returns
    -------
    dict[str, str]
        What each port answered, by port name.
    """
    from ..group import probe_ports

    results = await probe_ports(timeout=timeout, ports=ports or None)
    return {item.port: item.result for item in results}


async def _ports(args: argparse.Namespace) -> int:
    """List the serial ports; with --probe, ask each one for ?version to find the TANGO
    controllers (this writes a line to every port probed) and say for each port what it
    found: TANGO model firmware, no answer, permission denied, busy or not found."""
    from serial.tools import list_ports

    infos = await asyncio.to_thread(list_ports.comports)
    rows = {info.device: (info.description or "", info.hwid or "") for info in infos}
    rows.update({port: ("", "") for port in args.port if port not in rows})
    found = await _probe(args.timeout, args.port) if args.probe else None
    table = _table("Serial ports", ("device", "description", "hwid",
                                    *(("probe",) if found is not None else ())))
    for device, (description, hwid) in rows.items():
        probed = not args.port or device in args.port
        extra = () if found is None else (found.get(device, "-") if probed else "not probed",)
        _row(table, device, description, hwid, *extra)
    if rows:
        console.print(table)
    else:
        _say("no serial ports found")
    return 0


# -- upload-trigp -----------------------------------------------------------------------

#: Longest line of a position file, in bytes; a position needs far fewer.
_MAX_POSITION_LINE = 200
#: Most lines read from a position file (comments included).
_MAX_POSITION_LINES = 10 * MAX_TRIGGERS


async def _upload_trigp(args: argparse.Namespace) -> int:
    """Upload a trigger position list (one position per line; blank lines and lines
    starting with # are ignored) at wire speed, with a progress bar."""
    lines: list[int] = []
    positions = read_positions(args.file, lines)
    if not positions:
        raise ValueError(f"{args.file}: no positions (an empty list would clear the "
                         f"controller's list; send !trigp {args.axis} 0 for that)")
    with _by_file_line(args.file, lines):
        validate_trigger_positions(positions)  # before connecting
        async with connect(args.url) as tango:
            with _progress() as progress:
                task = progress.add_task(f"trigp {args.axis}", total=len(positions))
                await tango.triggers.upload_positions(
                    positions, axis=args.axis,
                    progress=lambda done, total: progress.update(task, completed=done))
            count = int(await tango.get("trigc"))
    _say(f"uploaded {count} trigger positions to axis {args.axis}")
    return 0


@contextlib.contextmanager
def _by_file_line(path: str, lines: Sequence[int]) -> Iterator[None]:
    """Name a bad or rejected entry by its file line (``positions.txt:7``), as the
    file's own errors are, not by its index in the list.

    Raises
    ------
    TangoError
        For an entry the controller rejected.
    InvalidCommandError
        For an entry that is not valid.
    UploadError
        An upload error that names no entry of the file.
    """
    from ..families import UploadError

    try:
        yield
    except UploadError as exc:
        if 0 <= exc.index < len(lines):
            raise TangoError(f"{path}:{lines[exc.index]}: rejected by the controller with "
                             f"{describe_error(exc.number)}") from exc
        raise
    except InvalidCommandError as exc:
        found = re.search(r"entry (\d+)", str(exc))
        if found is None or int(found.group(1)) >= len(lines):
            raise
        text = re.sub(r"(the trigger list )?entry \d+", "the position", str(exc))
        raise InvalidCommandError(f"{path}:{lines[int(found.group(1))]}: {text}",
                                  instruction=exc.instruction, parameter=exc.parameter,
                                  number=exc.number) from exc


def read_positions(path: str, lines: list[int] | None = None) -> list[float]:
    """Positions from a text file, one per line (blank lines and ``#`` comments skipped);
    ``lines`` (if given) receives the file line of each position.

    Reading is bounded: lines of at most 200 bytes, at most 100000 lines and one position
    more than a trigger list holds (so ``/dev/zero`` or a huge file fails at once).

    Parameters
    ----------
    path
        The file.
    lines
        A list that receives the file line of each position; ``None`` for none.

    Returns
    -------
    list[float]
        The positions.

    Raises
    ------
    ValueError
        A line is too long or not a number, or there are too many lines or positions.
    """
    values: list[float] = []
    with open(path, "rb") as handle:
        for number in range(1, _MAX_POSITION_LINES + 2):
            raw, longer = read_bounded_line(handle, _MAX_POSITION_LINE)
            if not raw:
                return values
            if longer:
                raise ValueError(f"{path}:{number}: line longer than "
                                 f"{_MAX_POSITION_LINE} bytes")
            if number > _MAX_POSITION_LINES:
                break
            text = raw.decode("utf-8", errors="replace").strip()
            if not text or text.startswith("#"):
                continue
            try:
                value = float(text)
            except ValueError:
                raise ValueError(f"{path}:{number}: not a number: {text!r}") from None
            values.append(value)
            if lines is not None:
                lines.append(number)
            if len(values) > MAX_TRIGGERS:
                raise ValueError(f"{path}: more than {MAX_TRIGGERS} positions "
                                 f"(the most a trigger list holds)")
    raise ValueError(f"{path}: more than {_MAX_POSITION_LINES} lines")


# -- plumbing ---------------------------------------------------------------------------


def _plain(text: str | None) -> str | None:
    """A docstring for ``--help``: Sphinx roles and literals (````?pos````,
    ``:func:`x```) as plain words.

    Returns
    -------
    str or None
        The plain text (``None`` for no docstring).
    """
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
    traceback, and the command's coroutine never awaited).

    Returns
    -------
    int
        The command's exit status.
    """
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tango-aio`` command: 0 on success, 1 after an error (printed
    as one line), 2 for usage errors, 130 after Ctrl+C.

    Parameters
    ----------
    argv
        The arguments; ``None`` for the process's own.

    Returns
    -------
    int
        The exit status.
    """
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
