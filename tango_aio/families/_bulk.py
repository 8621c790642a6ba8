"""Bulk transfers of trigger and snapshot lists at wire speed."""

from __future__ import annotations

import asyncio
import itertools
import math
import operator
from collections.abc import Awaitable, Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TypeVar, overload

from ..catalog import (
    AXES,
    MAX_SNAPSHOTS,
    MAX_TRIGGERS,
    Command,
    Form,
    build,
    build_rows,
    check_rows,
    encode_rows,
    parse,
    wire_number,
)
from ..errors import (
    InvalidCommandError,
    ProtocolError,
    UploadError,
    controller_error,
)
from ..link import Submission, TangoProtocol
from ..sansio import Line, Run

__all__ = [
    "CHECKPOINT",
    "MAX_SNAPSHOTS",
    "MAX_TRIGGERS",
    "Column",
    "ListSpec",
    "ListTransfer",
    "Progress",
    "UploadError",
    "check_axis",
    "check_entries",
    "check_resolution",
    "prepare",
    "prepare_lines",
    "snapshot_spec",
    "trigger_spec",
    "validate_rows",
    "validate_trigger_positions",
]

#: Entries between two length checks (progress reports and early error detection).
CHECKPOINT = 200
#: Entries built and queued between two turns of the event loop.
SLICE = 25

Progress = Callable[[int, int], None]


@dataclass(frozen=True, slots=True)
class ListSpec:
    """How one controller list is written, counted and read: what
    :meth:`ListTransfer.replace`, :meth:`ListTransfer.download` and :func:`prepare` take.
    :func:`trigger_spec` and :func:`snapshot_spec` give the two lists of the manual."""

    #: Builds the append lines of the given rows (validating each against the catalog).
    append: Callable[[Sequence[Sequence[float]]], Iterator[Command]]
    #: The same lines as bytes, CR included (no Command per entry).
    encode: Callable[[Sequence[Sequence[float]]], Iterator[bytes]]
    #: ``True`` per good row; raises what :attr:`append` raises for the first bad one,
    #: without making the lines.
    check: Callable[[Sequence[Sequence[float]]], Iterator[bool]]
    #: The instruction that counts (``?trigc``) and truncates (``!trigc n``) the list.
    count: str
    #: Builds the read of entry ``n`` (``?trigp n``).
    read: Callable[[int], Command]


class Column(Sequence[Sequence[float]]):
    """A list of numbers seen as rows of one value each, without a list per row: an
    upload keeps its rows until each chunk is made, and one object per entry made a
    64-link upload's full garbage collections long.

    Parameters
    ----------
    values
        The numbers, one per row.
    """

    def __init__(self, values: list[float]) -> None:
        self._values = values

    @property
    def values(self) -> list[float]:
        """The numbers (not a copy: do not change them)."""
        return self._values

    def __len__(self) -> int:
        return len(self._values)

    def __iter__(self) -> Iterator[Sequence[float]]:
        return zip(self._values, strict=True)  # one-tuples, made in C

    @overload
    def __getitem__(self, index: int) -> Sequence[float]: ...

    @overload
    def __getitem__(self, index: slice) -> Sequence[Sequence[float]]: ...

    def __getitem__(self, index: int | slice) -> Sequence[float] | Sequence[Sequence[float]]:
        if isinstance(index, slice):
            return [(value,) for value in self._values[index]]
        return (self._values[index],)


def _positions(values: object, what: str, name: str) -> list[float]:
    """``values`` as floats, refusing what only looks like a sequence of numbers: a string
    (``"123"`` would be the positions 1, 2, 3), booleans, ``None`` and other non-numbers
    (:func:`~tango_aio.catalog._instructions.wire_number` decides what a number is)."""
    if isinstance(values, str | bytes | bytearray) or not isinstance(values, Iterable):
        raise InvalidCommandError(f"{name}: {what} must be a sequence of numbers, got "
                                  f"{type(values).__name__} {values!r:.40}",
                                  instruction=name, parameter="position", number=5)
    if type(values) is list and all(type(value) is float for value in values):
        return values.copy()  # what the loop below makes of plain floats, in C
    out: list[float] = []
    for index, value in enumerate(values):
        try:
            out.append(float(wire_number(value)))
        except (TypeError, ValueError, OverflowError):
            raise InvalidCommandError(f"{name}: {what} entry {index} is not a number: "
                                      f"{value!r:.40}", instruction=name,
                                      parameter="position", number=5) from None
    return out


def validate_trigger_positions(positions: Sequence[float]) -> list[float]:
    """Check a trigger list before anything is sent: at most 10000 finite values, strictly
    increasing or strictly decreasing (manual L13767-13830); a string, booleans or other
    non-numbers are refused.

    Parameters
    ----------
    positions
        The trigger positions, in the order the axis passes them.

    Returns
    -------
    list[float]
        The positions as floats.

    Raises
    ------
    InvalidCommandError
        The list is too long, holds a non-number or a non-finite value, or is not strictly
        monotonic.
    """
    values = _positions(positions, "the trigger list", "trigp")
    if len(values) > MAX_TRIGGERS:
        raise InvalidCommandError(f"trigp: {len(values)} entries, at most {MAX_TRIGGERS}",
                                  instruction="trigp", parameter="position", number=5)
    if _finite_and_monotonic(values):
        return values  # the loops below find nothing (64 uploads: 0.5 ms each saved)
    for index, value in enumerate(values):
        if not math.isfinite(value):
            raise InvalidCommandError(f"trigp: entry {index} is not finite ({value})",
                                      instruction="trigp", parameter="position", number=5)
    if len(values) >= 2:
        rising = values[1] > values[0]
        for index in range(1, len(values)):
            step = values[index] - values[index - 1]
            if step == 0 or (step > 0) != rising:
                raise InvalidCommandError(
                    f"trigp: entry {index} ({values[index]}) breaks the monotonic order",
                    instruction="trigp", parameter="position", number=5)
    return values


def _finite_and_monotonic(values: list[float]) -> bool:
    """Whether every value is finite and the list strictly rising or strictly falling: what
    :func:`validate_trigger_positions` checks value by value, in C (``map``), so that a
    good list costs no Python loop; ``False`` sends the caller to its loops, which name
    the first bad entry."""
    if not all(map(math.isfinite, values)):
        return False
    if len(values) < 2:
        return True
    order = operator.lt if values[1] > values[0] else operator.gt
    return all(map(order, values, itertools.islice(values, 1, None)))


def prepare(spec: ListSpec, rows: Sequence[Sequence[float]]) -> list[Command]:
    """Build (and so validate against the catalog) every append line before anything is
    sent; raises :class:`InvalidCommandError` naming the first bad entry."""
    return list(_numbered(spec.append(rows)))


def prepare_lines(spec: ListSpec, rows: Sequence[Sequence[float]]) -> list[bytes]:
    """:func:`prepare`, the lines as bytes (CR included) without a :class:`Command` per
    entry (:func:`~tango_aio.catalog._instructions.encode_rows`): the same checks and errors."""
    return list(_numbered(spec.encode(rows)))


def check_entries(spec: ListSpec, rows: Sequence[Sequence[float]]) -> None:
    """Raise what :func:`prepare` raises for the first bad entry, without making the
    lines (:func:`~tango_aio.catalog._instructions.check_rows`)."""
    for _ in _numbered(spec.check(rows)):
        pass


_Line = TypeVar("_Line")


def _numbered(lines: Iterator[_Line]) -> Iterator[_Line]:
    """``lines``; an invalid entry raises :class:`InvalidCommandError` naming its index."""
    index = 0
    while True:
        try:
            line = next(lines)
        except StopIteration:
            return
        except InvalidCommandError as exc:
            raise InvalidCommandError(f"entry {index}: {exc}", instruction=exc.instruction,
                                      parameter=exc.parameter, number=exc.number) from exc
        yield line
        index += 1


def check_resolution(values: Sequence[Sequence[float]], quantum: Sequence[float],
                     name: str) -> None:
    """Refuse a non-zero position smaller than half the controller's position resolution
    ``quantum`` (one unit of the last digit it prints, L4080-4100): it would be stored and
    read back as 0.0.

    Parameters
    ----------
    values
        The entries, one sequence of positions each.
    quantum
        The position resolution of each column.
    name
        The instruction's name, for the error.

    Raises
    ------
    InvalidCommandError
        An entry is non-zero but below half the resolution.
    """
    if isinstance(values, Column) and quantum:
        # One column (a trigger list): a good list costs one comprehension, not a row
        # tuple and a loop per entry; a hit goes on to the loop, which names it.
        half = quantum[0] / 2
        if not [value for value in values.values if value != 0.0 and abs(value) < half]:
            return
    for index, row in enumerate(values):
        for column, value in enumerate(row):
            step = quantum[column] if column < len(quantum) else quantum[-1]
            if value != 0.0 and abs(value) < step / 2:
                raise InvalidCommandError(
                    f"{name}: entry {index} value {value} is below the position resolution "
                    f"{step} and would read back as 0.0", instruction=name,
                    parameter="position", number=5)


class ListTransfer:
    """Pipelined list uploads and downloads on one protocol.

    Parameters
    ----------
    protocol
        The link's protocol.
    reply_timeout
        Seconds to wait for each reply.
    lock
        The lock held for a whole transfer; ``None`` for a new one.
    """

    def __init__(self, protocol: TangoProtocol, reply_timeout: float = 5.0,
                 lock: asyncio.Lock | None = None) -> None:
        self._protocol = protocol
        self._timeout = reply_timeout
        #: Held for a whole upload or download (one list transfer at a time).
        self.lock = lock if lock is not None else asyncio.Lock()

    # -- generic machinery ------------------------------------------------------------------

    async def _query(self, name: str, *args: int) -> str:
        command = build(name, *args, form=Form.READ)
        response = await self._protocol.request(command, self._timeout)
        return response.lines[0]

    async def _count(self, spec: ListSpec) -> int:
        return int(await self._query(spec.count))

    async def replace(self, spec: ListSpec, clear: Callable[[], Awaitable[None]],
                      rows: Sequence[Sequence[float]], progress: Progress | None) -> None:
        """Check every entry of ``rows``, then (holding :attr:`lock`) await ``clear`` (the
        checked clearing line) and append the rows.

        Every entry is checked before the clear (:func:`check_entries`, in one go: checks
        cut into slices with loop turns between made 64 uploads starting together start
        later, each link's check spread over every link's turns; ``benchmarks/scaling.py
        --trace``, BENCHMARKS.md). Each chunk's lines are then made when it is queued,
        while the chunks before it are on the wire
        (:func:`~tango_aio.catalog._instructions.encode_rows`, which cannot fail on rows checked
        so), as one :class:`~tango_aio.sansio._scheduler.Run` where they owe no reply (modes 0,
        1, 3), or as commands where they do (mode 2: building all of them before the
        clear made 8 uploads in one process start 60-140 ms later). So ``rows`` must not
        change until the upload has ended (the controller's methods pass copies they
        validated).

        Parameters
        ----------
        spec
            The list (which instruction appends, counts and reads).
        clear
            Writes the line that clears the list, and checks its reply.
        rows
            The entries, one sequence of numbers each.
        progress
            Called with (entries the list holds, entries in all) after each length check;
            ``None`` for no reports.

        Raises
        ------
        InvalidCommandError
            An entry is not valid (the first one is named; nothing was written).
        """
        total = len(rows)
        check_entries(spec, rows)
        chunks = self._encoded(spec, rows)
        async with self.lock:
            await clear()
            await self._upload(spec, chunks, total, progress)

    def _encoded(self, spec: ListSpec, rows: Sequence[Sequence[float]]
                 ) -> Iterator[Run | list[Command]]:
        """The append lines of ``rows`` (checked) cut at the checkpoints, each piece made
        when it is asked for: as one row value (a :class:`~tango_aio.sansio._scheduler.Run`: its
        bytes, no Command per entry) where its lines owe no reply in the mode they will be
        written in, else as the commands :func:`prepare` builds (mode 2, or a mode change
        since the upload began)."""
        runs = True  # whether the last piece went as a run
        for start in range(0, len(rows), CHECKPOINT):
            part = rows[start:start + CHECKPOINT]
            if runs:
                piece = list(spec.encode(part))
                template = parse(piece[0][:-1].decode("ascii"))
                run = self._protocol.pack_lines(template, piece)
                if run is not None:
                    yield run
                    continue
            built = list(spec.append(part))
            run = self._protocol.pack(built)
            runs = run is not None
            yield built if run is None else run

    async def _upload(self, spec: ListSpec, chunks: Iterable[Run | list[Command]],
                      total: int, progress: Progress | None) -> None:
        """Append the lines of ``chunks`` (validated, the list cleared; ``total`` lines)
        with a check of the list's length after each chunk."""
        self._total = total  # for progress reports
        sent: list[Run | list[Command]] = []
        pending: list[tuple[int, Submission, list[Line]]] = []
        # All or nothing: a lost or added reply anywhere fails the whole upload, so its
        # lines may be pipelined even where their replies look alike (tango_aio.sansio._patterns).
        whole = object()
        loose: list[Line] = []  # submitted, not yet under a checkpoint
        done = 0
        try:
            for chunk in chunks:
                sent.append(chunk)
                if isinstance(chunk, Run):
                    chunk.batch = whole
                    loose.append(self._protocol.submit_run(chunk))
                else:
                    for offset in range(0, len(chunk), SLICE):
                        loose += [self._protocol.submit(c, batch=whole)
                                  for c in chunk[offset:offset + SLICE]]
                        await asyncio.sleep(0)
                # Let the replies of other links through between chunks (with many
                # controllers on one loop, benchmarks/scaling.py).
                await asyncio.sleep(0)
                done += len(chunk)
                check = self._protocol.submit(build(spec.count, form=Form.READ), batch=whole)
                pending.append((done, check, loose))
                loose = []
                if len(pending) > 1:
                    await self._checkpoint(spec, sent, pending, progress)
            while pending:
                await self._checkpoint(spec, sent, pending, progress)
        finally:
            # Cancelled or failed: lines still queued are never sent.
            self._protocol.withdraw([*loose, *(s for _, check, batch in pending
                                               for s in (*batch, check))])

    async def _checkpoint(self, spec: ListSpec, sent: list[Run | list[Command]],
                          pending: list[tuple[int, Submission, list[Line]]],
                          progress: Progress | None) -> None:
        """Await the oldest checkpoint; on a short count stop the upload and raise."""
        expected, check, _batch = pending[0]
        response = await self._protocol.wait_reply(check, self._timeout)
        pending.pop(0)  # only now: if the wait is cancelled, the caller withdraws it
        count = int(response.lines[0])
        if count != expected:
            self._protocol.withdraw(s for _, c, batch in pending for s in (*batch, c))
            pending.clear()
            await self._locate_rejection(spec, _commands(sent, count + 1), count)
        if progress is not None:
            progress(count, self._total)

    async def _locate_rejection(self, spec: ListSpec, commands: list[Command],
                                count: int) -> None:
        """Find the first entry that did not make it, get its error and raise."""
        if count > len(commands):
            # More entries than this upload sent: something else wrote to the list (uploads
            # of this driver are serialised, so another program, or a lost clear).
            raise UploadError(len(commands), 0, f"?{spec.count} = {count}") from ProtocolError(
                f"the list holds {count} entries, this upload sent {len(commands)}")
        rows = await self._download(spec, count)
        first = next((i for i, row in enumerate(rows) if not _same(row, commands[i])), count)
        if first >= len(commands):
            raise UploadError(first, 0, f"?{spec.count} = {count}") from ProtocolError(
                f"the list holds {count} entries where {len(commands)} were expected")
        await self._command(spec.count, first)
        code = await self._probe(commands[first])
        await self._command(spec.count, first)
        raise UploadError(first, code or 5, commands[first].line) from (
            controller_error(code or 5, commands[first].line))

    async def _probe(self, command: Command) -> int:
        self._protocol.submit(command)
        return int(await self._query("err"))

    async def _command(self, name: str, *args: int) -> None:
        command = build(name, *args)
        self._protocol.submit(command)
        code = int(await self._query("err"))
        if code:
            raise controller_error(code, command.line)

    async def download(self, spec: ListSpec) -> list[list[float]]:
        """Read the whole list with pipelined reads (not while an upload runs).

        Parameters
        ----------
        spec
            The list (which instruction counts and reads).

        Returns
        -------
        list[list[float]]
            The entries, in order.
        """
        async with self.lock:
            return await self._download(spec)

    async def _download(self, spec: ListSpec, count: int | None = None
                        ) -> list[list[float]]:
        """Read entries 1..count (default: the whole list) with pipelined reads."""
        total = await self._count(spec) if count is None else count
        whole = object()  # all or nothing, like an upload
        submissions = [self._protocol.submit(spec.read(i), batch=whole)
                       for i in range(1, total + 1)]
        try:
            replies = [await self._protocol.wait_reply(s, self._timeout) for s in submissions]
        finally:
            self._protocol.withdraw(submissions)
        return [[float(v) for v in r.lines[0].split()] for r in replies]


def _commands(sent: list[Run | list[Command]], limit: int) -> list[Command]:
    """The first ``limit`` lines of ``sent`` (or all) as commands (a run's parsed back:
    only when an upload failed)."""
    commands: list[Command] = []
    for chunk in sent:
        if len(commands) >= limit:
            break
        if isinstance(chunk, Run):
            commands += [parse(chunk.line_at(i)) for i in range(len(chunk))]
        else:
            commands += chunk
    return commands


def _same(row: Sequence[float], command: Command) -> bool:
    sent = [float(v) for v in command.values[1:]]
    return len(row) >= len(sent) and all(
        math.isclose(a, b, abs_tol=1e-3) for a, b in zip(row, sent, strict=False))


def trigger_spec() -> ListSpec:
    """The trigger position list (``!trigp -1 pos``, ``?trigc``, ``?trigp n``).

    Returns
    -------
    ListSpec
        The description of the trigger position list.
    """
    return ListSpec(
        append=lambda rows: build_rows("trigp", [-1], rows),
        encode=lambda rows: encode_rows("trigp", [-1], rows),
        check=lambda rows: check_rows("trigp", [-1], rows),
        count="trigc",
        read=lambda index: build("trigp", index, form=Form.READ),
    )


def snapshot_spec() -> ListSpec:
    """The snapshot array (``!snsa -1 x y ...``, ``?snsc``, ``?snsa n``).

    Returns
    -------
    ListSpec
        The description of the snapshot array.
    """
    return ListSpec(
        append=lambda rows: build_rows("snsa", [-1], rows),
        encode=lambda rows: encode_rows("snsa", [-1], rows),
        check=lambda rows: check_rows("snsa", [-1], rows),
        count="snsc",
        read=lambda index: build("snsa", index, form=Form.READ),
    )


def check_axis(axis: str) -> str:
    """Validate an axis letter (a string, one of x y z a in either case).

    Parameters
    ----------
    axis
        The axis letter.

    Returns
    -------
    str
        The letter, lower case.

    Raises
    ------
    InvalidCommandError
        ``axis`` is not one of x, y, z, a.
    """
    letter = axis.lower() if isinstance(axis, str) else axis
    if letter not in AXES:
        raise InvalidCommandError(f"{axis!r} is not an axis (x, y, z, a)", parameter="axis",
                                  number=1)
    return letter


def validate_rows(rows: Sequence[Sequence[float]], axes: int) -> list[list[float]]:
    """Check snapshot rows: at most 1024, each exactly ``axes`` finite values (a shorter
    row would leave the controller to fill in the missing axes, which the manual does not
    specify).

    Parameters
    ----------
    rows
        The snapshot rows, one position per axis each.
    axes
        The number of axes.

    Returns
    -------
    list[list[float]]
        The rows as floats.

    Raises
    ------
    InvalidCommandError
        Too many rows, or a row of the wrong length or with a non-finite value.
    """
    if len(rows) > MAX_SNAPSHOTS:
        raise InvalidCommandError(f"snsa: {len(rows)} rows, at most {MAX_SNAPSHOTS}",
                                  instruction="snsa", number=5)
    out: list[list[float]] = []
    if isinstance(rows, str | bytes | bytearray):
        raise InvalidCommandError(f"snsa: rows must be a sequence of rows, got {rows!r:.40}",
                                  instruction="snsa", parameter="position", number=5)
    for index, row in enumerate(rows):
        values = _positions(row, f"row {index}", "snsa")
        if len(values) != axes or not all(math.isfinite(v) for v in values):
            raise InvalidCommandError(f"snsa: row {index} must hold {axes} finite values "
                                      f"(one per axis), got {row!r}",
                                      instruction="snsa", parameter="position", number=5)
        out.append(values)
    return out

