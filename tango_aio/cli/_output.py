"""Output of the command line: the consoles, literal text, tables, progress, Ctrl+C as a call."""

from __future__ import annotations

import asyncio
import contextlib
import re
import signal
from collections.abc import Awaitable, Callable, Iterator, Mapping, Sequence
from typing import TypeVar

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from ..errors import (
    TangoError,
)

console = Console(highlight=False)
#: Diagnostics (errors, warnings, "interrupted"): stderr, so that stdout holds only results.
err_console = Console(stderr=True, highlight=False)
_T = TypeVar("_T")


#: Control characters but the line feed: C0, DEL and C1 (ESC ] ... rewrites a terminal).
_CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f-\x9f]")


def _escaped(text: str) -> str:
    """``text`` with every control character but the line feed written as ``\\xNN``:
    text from the controller (or a proxy) never reaches the terminal raw."""
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
    awaited first, so that a move stops its axes before the connection closes."""
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


@contextlib.contextmanager
def _sigint_calls(callback: Callable[[], None]) -> Iterator[None]:
    """Run ``callback`` on SIGINT (Ctrl+C) instead of interrupting the program; on
    Windows through ``signal.signal`` (:func:`tango_aio._platform.signal_calls`); nothing
    is installed outside the main thread."""
    from .._platform import signal_calls

    with signal_calls(signal.SIGINT, callback):
        yield
