"""The ``tango-aio`` command line.

Every command takes ``--help``. Errors are printed as one line and give exit code 1
(2 for usage errors). URLs are those of :func:`tango_aio.connect`; ``sim://`` runs the
embedded emulator.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from .connection import connect
from .controller import Controller
from .errors import TangoError

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
    return parser


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
