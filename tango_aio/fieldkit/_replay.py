"""Replay a recorded wire trace as a test: the controller's side plays back, the driver's
lines are checked. Use it as :func:`tango_aio.testing.replay`.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, cast

from ._trace import TraceRecord, parse_trace

__all__ = ["Replay", "ReplayMismatch", "replay"]

_HELP = re.compile(rb"^(\x03?\?help )(\d+)$")
_ERROR = re.compile(rb"^ERROR (\d+),")

#: Longest wait, on leaving the block, for the client's last lines and its close (s).
DRAIN_WAIT = 5.0


class ReplayMismatch(AssertionError):
    """The client wrote other lines than the trace (the message names the first differing
    trace line), or stopped before writing all of them."""


@dataclass
class Replay:
    """A trace being played (what :func:`replay` yields)."""

    #: The records played.
    records: list[TraceRecord]
    #: ``recorded`` or ``fast`` (see the module text).
    timing: str
    #: ``socket://127.0.0.1:PORT``: connect the client here.
    url: str = ""
    #: The first difference, once one was seen.
    mismatch: str | None = None
    #: Trace records the client's lines matched so far.
    matched: int = 0
    _cursor: int = 0
    _connections: int = 0
    _closed: asyncio.Event = field(default_factory=asyncio.Event)
    _queue: asyncio.Queue[tuple[float, bytes] | None] = field(default_factory=asyncio.Queue)
    _transport: asyncio.Transport | None = None
    _anchor: tuple[float, float] | None = None  # (loop time, trace time) of the last match
    _last_due: float = 0.0
    _codes: dict[bytes, bytes] = field(default_factory=dict)  # trace's marker -> client's

    def check(self) -> None:
        """Raise :class:`ReplayMismatch` if the client's lines differed from the trace or
        stopped short of its last ``->`` line.

        Raises
        ------
        ReplayMismatch
            The client's lines differed from the trace, or stopped short of it.
        """
        if self.mismatch is not None:
            raise ReplayMismatch(self.mismatch)
        rest = [r for r in self.records[self._cursor:] if r.direction == "->"]
        if rest:
            raise ReplayMismatch(f"trace line {rest[0].lineno}: the client stopped writing; "
                                 f"the trace has {rest[0].data!r} next "
                                 f"({len(rest)} lines not written)")

    # -- playing -------------------------------------------------------------------------

    def _connected(self, transport: asyncio.Transport) -> None:
        self._connections += 1
        if self._connections > 1:
            self._differ("a second connection was opened; the trace has one")
            transport.close()
            return
        self._transport = transport
        self._anchor = (asyncio.get_running_loop().time(),
                        self.records[0].time if self.records else 0.0)
        self._pump()

    def _pump(self) -> None:
        """Queue every ``<-`` record up to the next ``->`` record."""
        loop = asyncio.get_running_loop()
        while self._cursor < len(self.records) and \
                self.records[self._cursor].direction == "<-":
            record = self.records[self._cursor]
            self._cursor += 1
            due = loop.time()
            if self.timing == "recorded" and self._anchor is not None:
                due = self._anchor[0] + max(0.0, record.time - self._anchor[1])
            self._last_due = max(self._last_due, due)
            data = _ERROR.sub(self._map_code, record.data, count=1)
            self._queue.put_nowait((self._last_due, data + b"\r"))

    def _map_code(self, match: re.Match[bytes]) -> bytes:
        return b"ERROR " + self._codes.get(match[1], match[1]) + b","

    def _same_marker(self, expected: bytes, line: bytes) -> bool:
        """Whether ``line`` is the trace's ``?help K`` with the client's number for K
        (binding K to it the first time, one to one)."""
        ours, theirs = _HELP.match(expected), _HELP.match(line)
        if ours is None or theirs is None or ours[1] != theirs[1]:
            return False
        bound = self._codes.get(ours[2])
        if bound is None:
            if theirs[2] in self._codes.values():
                return False
            self._codes[ours[2]] = theirs[2]
            return True
        return bound == theirs[2]

    def _written(self, line: bytes) -> None:
        if self.mismatch is not None:
            return
        if self._cursor >= len(self.records):
            self._differ(f"after the trace's last line the client wrote {line!r}")
            return
        record = self.records[self._cursor]
        if not _same(record, line) and not (record.complete and
                                            self._same_marker(record.data, line)):
            self._differ(f"trace line {record.lineno}: the trace has {record.data!r}"
                         f"{'' if record.complete else ' (cut)'}, the client wrote {line!r}")
            return
        self._cursor += 1
        self.matched += 1
        self._anchor = (asyncio.get_running_loop().time(), record.time)
        self._pump()

    def _differ(self, text: str) -> None:
        if self.mismatch is None:
            self.mismatch = text
        self._queue.put_nowait(None)
        if self._transport is not None:
            self._transport.close()

    async def _send(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            item = await self._queue.get()
            if item is None:
                return
            due, data = item
            delay = due - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            if self._transport is None or self._transport.is_closing():
                return
            self._transport.write(data)


def _same(record: TraceRecord, line: bytes) -> bool:
    if record.length is not None:
        return len(line) == record.length and line.startswith(record.data)
    return line == record.data


class _Player(asyncio.Protocol):
    def __init__(self, state: Replay) -> None:
        self.state = state
        self.buffer = b""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # A stream transport, though not always a subclass of asyncio.Transport (uvloop's
        # TCPTransport is not).
        self.state._connected(cast(asyncio.Transport, transport))

    def data_received(self, data: bytes) -> None:
        *lines, self.buffer = (self.buffer + data).split(b"\r")
        for line in lines:
            self.state._written(line)

    def connection_lost(self, exc: Exception | None) -> None:
        self.state._closed.set()


def _records(trace: str | os.PathLike[str] | Sequence[TraceRecord]) -> list[TraceRecord]:
    if isinstance(trace, str) and "\n" in trace:
        records = parse_trace(trace)
    elif isinstance(trace, str | os.PathLike):
        records = parse_trace(Path(trace).read_text(encoding="utf-8", errors="replace"))
    else:
        records = list(trace)
    for record in records:
        if record.direction == "<-" and not record.complete:
            raise ValueError(f"trace line {record.lineno}: a received line the trace shows "
                             f"cut cannot be played back")
    return records


@contextlib.asynccontextmanager
async def replay(trace: str | os.PathLike[str] | Sequence[TraceRecord], *,
                 timing: Literal["recorded", "fast"] = "recorded") -> AsyncIterator[Replay]:
    """Play the controller's side of ``trace`` (a file path, the trace's text, or its
    records) on ``socket://127.0.0.1:PORT`` (the yielded :attr:`Replay.url`) for one
    connection; leaving the block checks that the client wrote the trace's lines
    (:class:`ReplayMismatch` names the first that differs). See the module text.

    Parameters
    ----------
    trace
        A trace file's path, a trace's text, or its records.
    timing
        ``"recorded"`` sends each reply after the delay the trace shows; ``"fast"`` sends
        it at once.

    Yields
    ------
    Replay
        The replay, whose :attr:`Replay.url` the client connects to.

    Raises
    ------
    ValueError
        An unknown ``timing``.
    ReplayMismatch
        On leaving the block: the client's lines differed from the trace.
    """
    if timing not in ("recorded", "fast"):
        raise ValueError(f"timing must be 'recorded' or 'fast', got {timing!r}")
    state = Replay(_records(trace), timing)
    loop = asyncio.get_running_loop()
    server = await loop.create_server(lambda: _Player(state), "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    state.url = f"socket://127.0.0.1:{port}"
    sender = asyncio.create_task(state._send(), name="tango_aio replay")
    failed = False
    try:
        yield state
    except BaseException as exc:
        failed = True
        if state.mismatch is None:
            raise
        raise ReplayMismatch(state.mismatch) from exc
    finally:
        server.close()
        if not failed and state._connections and state.mismatch is None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(state._closed.wait(), DRAIN_WAIT)
        sender.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await sender
        if state._transport is not None:
            state._transport.close()
        await server.wait_closed()
    state.check()
