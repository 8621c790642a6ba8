"""Wire traces: one format for the driver's wire log, ``tango-aio probe --trace`` and
:func:`tango_aio.testing.replay`.
"""

from __future__ import annotations

import ast
import contextlib
import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from ..link import traced, wire_log

__all__ = ["TraceRecord", "format_record", "parse_trace", "read_trace", "record_trace",
           "trace_header"]

Direction = Literal["->", "<-"]

_RECORD = re.compile(
    r"(?P<time>-?\d+\.\d+) (?P<dir>->|<-) "
    r"(?P<data>b'(?:[^'\\]|\\.)*'|b\"(?:[^\"\\]|\\.)*\")"
    r"(?:\.\.\. \((?P<length>\d+) bytes\))?(?P<partial> \(no CR yet\))?\s*$")


@dataclass(frozen=True, slots=True)
class TraceRecord:
    """One line of a trace."""

    #: Monotonic time in seconds (only differences mean something).
    time: float
    #: ``->`` written to the controller, ``<-`` received from it.
    direction: Direction
    #: The line's bytes without its CR (its first ``TRACE_LINE`` bytes if cut).
    data: bytes
    #: The line's full length when the trace shows only its start, else ``None``.
    length: int | None = None
    #: A received piece without CR (shown because it grew over ``TRACE_LINE``).
    partial: bool = False
    #: The line of the trace text the record is on (1-based), for messages.
    lineno: int = 0

    @property
    def complete(self) -> bool:
        """Whether the record holds the whole line."""
        return self.length is None and not self.partial


def format_record(time: float, direction: Direction, data: bytes) -> str:
    """One record, as the ``tango_aio.wire`` logger writes it.

    Parameters
    ----------
    time
        The record's time stamp, in seconds.
    direction
        ``"->"`` written by the driver, ``"<-"`` received.
    data
        The bytes.

    Returns
    -------
    str
        The record's text.
    """
    return f"{time:.6f} {direction} {traced(data)}"


def trace_header() -> str:
    """The comment line a trace file starts with (the project version).

    Returns
    -------
    str
        The comment line.
    """
    from .. import __version__

    return f"# tango_aio wire trace, tango-aio {__version__}"


def parse_trace(text: str) -> list[TraceRecord]:
    """The records of a trace's text, in order.

    Parameters
    ----------
    text
        The trace's text (comment lines and other log lines are skipped).

    Returns
    -------
    list[TraceRecord]
        The records.
    """
    records = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if line.lstrip().startswith("#"):
            continue
        match = _RECORD.search(line)
        if match is None:
            continue
        data = ast.literal_eval(match["data"])
        assert isinstance(data, bytes)
        length = int(match["length"]) if match["length"] else None
        direction: Direction = "->" if match["dir"] == "->" else "<-"
        records.append(TraceRecord(float(match["time"]), direction, data, length,
                                   bool(match["partial"]), lineno))
    return records


def read_trace(path: str | os.PathLike[str]) -> list[TraceRecord]:
    """The records of a trace file.

    Parameters
    ----------
    path
        The trace file.

    Returns
    -------
    list[TraceRecord]
        The records.
    """
    return parse_trace(Path(path).read_text(encoding="utf-8", errors="replace"))


@contextlib.contextmanager
def record_trace(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Write the driver's wire log (every connection's) to ``path`` while the block runs.

    Sets the ``tango_aio.wire`` logger to DEBUG for the block (its level is restored
    after) and writes its records, nothing else, with a :func:`trace_header`::

        with record_trace("session.trace"):
            asyncio.run(session())

    Parameters
    ----------
    path
        The trace file to write (replaced if it exists).

    Yields
    ------
    Path
        ``path``, as a :class:`~pathlib.Path`.
    """
    target = Path(path)
    target.write_text(trace_header() + "\n", encoding="utf-8")
    handler = logging.FileHandler(target, mode="a", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(message)s"))
    handler.setLevel(logging.DEBUG)
    level = wire_log.level
    wire_log.addHandler(handler)
    wire_log.setLevel(logging.DEBUG)
    try:
        yield target
    finally:
        wire_log.removeHandler(handler)
        wire_log.setLevel(level)
        handler.close()
