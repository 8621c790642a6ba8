"""The operator commands: ``demo``, ``info``, ``move``, ``monitor``, ``ports`` and
``upload-trigp``."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import re
import time
from collections.abc import Awaitable, Callable, Iterator, Mapping, Sequence

from rich.live import Live
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table

from .._argtypes import (
    UsageError,
)
from ..catalog import AXES
from ..controller import Controller, connect
from ..errors import (
    InvalidCommandError,
    TangoError,
)
from ..families import MAX_TRIGGERS, validate_trigger_positions
from ..units import DIM_UNITS, velocity_unit
from ._describe import (
    LETTER_MEANINGS,
    describe_error,
    describe_letters,
)
from ._output import (
    _fmt_positions,
    _follow,
    _plural,
    _progress,
    _row,
    _say,
    _sigint_calls,
    _table,
    console,
)
from ._settings import info_rows
from ._shell import (
    read_bounded_line,
)

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
    axis, the rows are passes of X back and forth."""
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
    of another shape as it is, with a single unit behind it."""
    values = text.split()
    units = dict.fromkeys(AXES[: len(values)], unit) if isinstance(unit, str) else dict(unit)
    if len(values) != len(units):
        return f"{text} {next(iter(units.values()), '')}".strip()
    return "  ".join(f"{axis}={value} ({units[axis]})" if named else
                     f"{axis}={value} {units[axis]}"
                     for axis, value in zip(units, values, strict=True))


# -- move -------------------------------------------------------------------------------


#: A number as a user types it (no ``1_000``, no ``nan``), then an optional unit.
_TARGET = re.compile(r"([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([a-zA-Zµ/]*)")


def _axis_target(token: str) -> tuple[str, float, str | None]:
    """argparse type of ``x=1.5``, ``x=1mm`` or ``y=-500um``: axis, value and unit
    (``None``: the controller's unit)."""
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
    on some axes and none on others is refused (which unit would the bare ones be?)."""
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
    answer", "permission denied (...)", "busy (...)", "not found"."""
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
    file's own errors are, not by its index in the list."""
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
    ``lines`` (if given) receives the file line of each position."""
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
