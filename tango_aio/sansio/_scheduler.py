"""The write scheduler: which queued line goes on the wire next, and what goes with it.

1. **Order.** Lines go out in submission order. A line waiting for credit holds back
   every line behind it.
2. **Credit** (:mod:`tango_aio.sansio._flow`). The bytes written and not yet confirmed by a reply
   never exceed the credit limit, so the controller's 256-byte input buffer never
   overflows (manual L129-131). Runs of reply-less lines are confirmed by *credit
   markers*, the bare read ``err``. Each marker covers the reply-less lines written since
   the previous one. If its reply is a non-zero error number, those lines get
   :attr:`Line.chunk_error`.
3. **Separators** (:mod:`tango_aio.sansio._patterns`). Take two lines in a row whose replies
   could be taken for each other, such as ``?vel x`` and then ``?accel y``. They get a
   separator between them, or, when no separator fits, the second waits until the first
   got the lines it is sure to get. The rule is the same in every autostatus mode and
   decided from the lines each is sure to get (:class:`~tango_aio.sansio._patterns.Edge`), with
   the optional ones around them (a read's echo in mode 4), never from an optional line
   alone. Lines of one all-or-nothing *batch* (a list transfer) need neither.
   A line may ask for a separator *behind* it (:attr:`Line.separate_after`: a move's
   confirming ``?pos``, which the next move's ``?err`` probe looks like). It goes out in
   the same write, off the next request's path, and that request then needs none.
4. **Mode projection.** What a line owes depends on the autostatus mode in force when it
   reaches the controller. That is the mode the core believes in force, carried forward
   through the lines still queued (:meth:`WriteScheduler.plan`). Withdrawing lines or a
   resync recomputes it (:meth:`WriteScheduler.reproject`).
"""

from __future__ import annotations

import itertools
import logging
from collections import deque
from collections.abc import Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Final

from ..catalog import Command, parse
from ._core import ProtocolCore
from ._expect import Expectation, expectation, wire_size
from ._flow import DEFAULT_CHUNK, DEFAULT_LIMIT, MARKER, CreditWindow
from ._patterns import Edge, ReplyPattern

__all__ = ["Line", "Run", "WriteScheduler"]

log = logging.getLogger("tango_aio.sansio._scheduler")

#: The credit marker as a command (its bytes are :data:`tango_aio.sansio._flow.MARKER`).
_MARKER: Final = parse(MARKER.decode().rstrip("\r"))
#: The ``?err`` probe of a checked line (what a trailing separator must not look like).
_PROBE: Final = parse("?err")
#: Longest separator line (``?help NN`` and CR; ``?err`` and ``?help`` are shorter).
_SEPARATOR_SIZE: Final = 9


@dataclass(frozen=True, slots=True)
class _Separation:
    """What keeps a line apart from the one owing a reply before it (see
    WriteScheduler._separator_for)."""

    #: The separator line to write first and what it owes (``None``: none is written).
    line: tuple[bytes, ReplyPattern] | None = None
    #: No separator exists: the line waits for the reply it could be taken for instead.
    wait: bool = False

    @property
    def needed(self) -> bool:
        """Whether the line cannot simply follow (a separator or a wait; either way the
        credit counts a separator's bytes for it)."""
        return self.line is not None or self.wait


#: Nothing needed between the two lines.
_APART: Final = _Separation()
#: "No separator fits: wait for the reply".
_WAIT: Final = _Separation(wait=True)
#: The batch of credit markers that confirm lines of no batch.
_MARKERS: Final = object()


@dataclass(eq=False, slots=True)
class Line:
    """One queued line and what the scheduler knows about it."""

    command: Command
    tag: int
    expectation: Expectation
    #: The autostatus mode ``expectation`` was computed for.
    mode: int = 1
    #: Lines of one all-or-nothing batch (``None``: on its own) may be pipelined even
    #: when their replies look alike (:mod:`tango_aio.sansio._patterns`).
    batch: object | None = None
    #: Whether the line has been written (it may wait in the queue for credit).
    written: bool = False
    #: Error number reported by the credit marker that followed this reply-less line
    #: (``?err`` reports the state after the last line before it), if non-zero.
    chunk_error: int | None = None
    #: Front edge of its reply (:func:`tango_aio.sansio._core.owed_edge`): the lines it may get up
    #: to the first one it is sure to get; ``None`` if it is sure to get none (set by
    #: :meth:`WriteScheduler.submit`).
    owes: Edge | None = None
    #: The edge compared with the rear edge of the line owed before this one to decide
    #: whether a separator goes first (``owes``, or for a line sure to get nothing that
    #: is checked by the probe behind it, the probe's: the separator must not go between
    #: the two).
    guard: Edge | None = None
    #: Write a separator right behind this line, in the same write, where the credit
    #: allows (:meth:`WriteScheduler.next_write`): a request that usually comes next and
    #: looks like this one's reply then needs none of its own (a move's confirming
    #: ``?pos`` and the next move's ``?err`` probe).
    separate_after: bool = False
    #: Whether a reply (data or acknowledgement) will confirm this line's bytes.
    confirming: bool = field(init=False)
    #: Bytes this line takes on the wire (with a read's internal follow-up).
    size: int = field(init=False)
    #: The mode the core believed in force when the line was written.
    written_mode: int = field(default=-1, init=False)
    #: Number of the line among those written on the link (0: not written yet).
    serial: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        # Both are asked for on every flush while the line waits for credit: computed once.
        expect = self.expectation
        rule = expect.rule
        self.confirming = expect.ack or rule.count > 0 or rule.terminator is not None \
            or rule.continuation is not None
        self.size = wire_size(self.command, expect)


@dataclass(eq=False, slots=True)
class Run(Line):
    """A run of reply-less lines kept as one record: their bytes in one blob, and where
    each line ends (a list upload: one record per run, not one object per line)."""

    blob: bytes = b""
    #: Offset just past each line's CR in :attr:`blob`.
    ends: tuple[int, ...] = ()
    #: Index of the next line to write.
    next: int = 0

    def __post_init__(self) -> None:
        self.confirming = False
        self.size = self.ends[0] if self.ends else 0

    def line_at(self, index: int) -> str:
        """The text of line ``index`` (no CR)."""
        start = self.ends[index - 1] if index else 0
        return self.blob[start:self.ends[index] - 1].decode("ascii")

    def __len__(self) -> int:
        return len(self.ends)


class WriteScheduler:
    """The write queue, the credit window, credit markers and separators (see the module
    docstring). ``core`` registers every line written."""

    def __init__(self, core: ProtocolCore, *, credit_limit: int = DEFAULT_LIMIT,
                 marker_chunk: int = DEFAULT_CHUNK, separators: bool = True) -> None:
        self.core = core
        #: The write-credit account (see :mod:`tango_aio.sansio._flow`).
        #: A marker may need a separator before it: both must fit behind a full chunk of
        #: unconfirmed reply-less bytes (the window's ``reserve``; 160 of 255 by default
        #: is not cut).
        self.credit = CreditWindow(credit_limit, marker_chunk, reserve=_SEPARATOR_SIZE)
        #: Look-alike lines: ``True`` writes a separator between two in a row; ``False``
        #: only keeps them from being in flight together (see :mod:`tango_aio.sansio._patterns`).
        self.separators = separators
        #: Lines written so far (requests, and the resync lines the caller reports).
        self.written_lines = 0
        self._tags = itertools.count(1)
        self._last_tag = 0
        self._queue: deque[Line] = deque()
        self._queued_mode = core.autostatus
        self._unmarked: list[Line] = []
        self._credit_markers: dict[Hashable, list[Line]] = {}
        self._separators: set[Hashable] = set()
        # The rear edge (front and back, ProtocolCore.tail) of the last line written that
        # is sure to get a line, its batch and tag (see _separator_for).
        self._last_owed: Edge | None = None
        self._last_batch: object | None = None
        self._last_owing: Hashable | None = None
        self._hold_after: int | None = None
        #: Tag of each line unrolled from a run: the run's tag.
        self._unrolled: dict[int, int] = {}

    # -- queueing ---------------------------------------------------------------------

    def next_tag(self) -> int:
        """A fresh tag (for lines the caller registers with the core itself)."""
        return next(self._tags)

    def plan(self, command: Command) -> tuple[int, int, Expectation]:
        """A tag for ``command``, the mode it will reach the controller in (the mode in
        force, carried through the queued lines) and what it owes there. Pass them to a
        :class:`Line` and :meth:`submit` it next."""
        tag = self._last_tag = next(self._tags)
        mode = self._queued_mode if self._queue else self.core.autostatus
        return tag, mode, expectation(command, mode, self.core.context)

    def pack(self, commands: Iterable[Command], batch: object | None = None) -> Run | None:
        """A :class:`Run` of ``commands`` to :meth:`submit` (now or later), when every one
        owes nothing in the mode they would now be written in (no reply, no report, no
        mode change: the core need not register them one by one); ``None`` otherwise, or
        for no command. A run written in another mode after all is unrolled into its
        lines then (:meth:`_unroll`)."""
        mode = self._queued_mode if self._queue else self.core.autostatus
        context = self.core.context
        first: tuple[Command, Expectation] | None = None
        lines: list[bytes] = []
        for command in commands:
            expect = expectation(command, mode, context)
            if not _replyless(expect, mode):
                return None
            if first is None:
                first = command, expect
            lines.append(command.to_bytes())
        if first is None:
            return None
        return _run(first[0], first[1], mode, lines, batch)

    def pack_lines(self, template: Command, lines: Sequence[bytes],
                   batch: object | None = None) -> Run | None:
        """:meth:`pack` for lines given as bytes (CR included), every one a line of
        ``template``'s instruction in its form (what
        :func:`~tango_aio.catalog._encode.encode_rows` gives: a list upload without a
        Command per entry). What a line owes depends only on its instruction and
        form in a mode (:func:`~tango_aio.sansio._core.expectation`), so ``template`` speaks for
        all; a line that does not start like it gives ``None``."""
        mode = self._queued_mode if self._queue else self.core.autostatus
        expect = expectation(template, mode, self.core.context)
        head = (template.form.value + template.name + " ").encode("ascii")
        if not lines or not _replyless(expect, mode) or not all(
                line.startswith(head) for line in lines):
            return None
        return _run(template, expect, mode, lines, batch)

    def submit(self, line: Line) -> bool:
        """Queue ``line`` (from :meth:`plan`, or a run from :meth:`pack`); return whether
        the queue was empty before (otherwise the head waits for credit or a reply, and
        nothing could be written)."""
        was_empty = not self._queue
        if isinstance(line, Run):
            line.tag = self._last_tag = next(self._tags)  # runs change no mode
        else:
            expect = line.expectation
            line.owes = line.guard = self.core.owed(line.command, expect, line.mode)
            self._queued_mode = expect.mode_after
        self._queue.append(line)
        return was_empty

    @property
    def queued(self) -> int:
        """Number of lines waiting in the queue."""
        return len(self._queue)

    def queued_up_to(self, tag: int) -> bool:
        """Whether a line planned no later than ``tag`` still waits in the queue."""
        return any(line.tag <= tag for line in self._queue)

    def withdraw(self, lines: Iterable[Line]) -> list[Line]:
        """Take the lines of ``lines`` that are still queued out of the queue; return
        them. Lines already written are not affected."""
        doomed = {id(line) for line in lines if not line.written}
        # A run unrolled into lines (see _unroll) lives on in lines of its tag.
        unrolled = {line.tag for line in lines if isinstance(line, Run) and line.written}
        if not doomed and not unrolled:
            return []
        removed = [line for line in self._queue if id(line) in doomed
                   or self._unrolled.get(line.tag) in unrolled]
        if not removed:
            return []
        gone = {id(line) for line in removed}
        for line in removed:
            self._unrolled.pop(line.tag, None)
        self._queue = deque(line for line in self._queue if id(line) not in gone)
        self.reproject()
        return removed

    def drop_queue(self) -> list[Line]:
        """Forget every line not yet written; return them."""
        dropped = list(self._queue)
        self._queue.clear()
        self._unrolled.clear()
        self._queued_mode = self.core.autostatus
        return dropped

    def reproject(self) -> None:
        """Recompute the mode at the queue's tail from the mode in force (after it was
        adopted from the controller, or lines were withdrawn)."""
        mode = self.core.autostatus
        for line in self._queue:
            mode = expectation(line.command, mode, self.core.context).mode_after
        self._queued_mode = mode

    def hold(self) -> int:
        """Write no line submitted from now on until :meth:`release`; return the tag of
        the last line that may still go."""
        self._hold_after = self._last_tag
        return self._last_tag

    def release(self) -> None:
        """End :meth:`hold`."""
        self._hold_after = None

    # -- writing ----------------------------------------------------------------------

    def next_write(self) -> bytes:
        """The bytes to write now (empty: nothing may go yet): queued lines while the
        credit allows, with the markers and separators due before them. Each line is
        registered with the core as it is taken."""
        if self.core.resyncing:
            # During a resync nothing is written until its marker is answered: the lines
            # queued behind it go out once the stream is in step.
            return b""
        out = bytearray()
        credit = self.credit
        queue = self._queue
        while queue:
            head = queue[0]
            if self._hold_after is not None and head.tag > self._hold_after:
                break  # behind a mode change
            separator = self._separator_for(head.guard, head.batch)
            size = head.size + (_SEPARATOR_SIZE if separator.needed else 0)
            if credit.marker_due(head.size, head.confirming) or (
                    separator.needed and credit.marker_due(size, True)):
                # (The second: the line and its separator would not fit behind the
                # reply-less bytes even once all else is confirmed; a small limit.)
                batch = self._marker_batch()
                marker = self._edge_of(_MARKER)
                separator = self._separator_for(marker, batch)
                if not credit.marker_fits() or (
                        separator.wait and self._must_wait(marker, batch)) or (
                        separator.needed
                        and not credit.fits(_SEPARATOR_SIZE + len(MARKER), True)):
                    break
                if separator.line is not None:
                    out += self._separator(separator.line)
                out += self._marker(batch)
                continue
            if not credit.fits(size, head.confirming) or (
                    separator.wait and self._must_wait(head.owes, head.batch)):
                break
            if separator.line is not None:
                out += self._separator(separator.line)
            if isinstance(head, Run):
                out += self._run_line(head)
                continue
            queue.popleft()
            if self._unrolled:
                self._unrolled.pop(head.tag, None)
            out += self._register(head)
            if head.separate_after:
                out += self._trailing_separator()
        return bytes(out)

    def _trailing_separator(self) -> bytes:
        """A separator behind the line just written (:attr:`Line.separate_after`), chosen
        so that neither that line's reply nor a number (the ``?err`` of a checked line)
        can be taken for its reply; nothing when none exists or the credit is short."""
        last = self._last_owed
        probe = self._edge_of(_PROBE)
        if not self.separators or last is None or probe is None:
            return b""
        separator = self.core.separator(last, probe)
        if separator is None or not self.credit.fits(len(separator[0]), True):
            return b""
        return self._separator(separator)

    def _edge_of(self, command: Command) -> Edge | None:
        """The front edge of a read of the scheduler's own, written now."""
        mode = self.core.autostatus
        return self.core.owed(command, expectation(command, mode, self.core.context), mode)

    def _run_line(self, run: Run) -> bytes:
        """Write the next line of ``run`` (at the head of the queue, checked by the caller)
        and the lines after it that the credit takes at once, with no marker due: the
        bytes the core would have written for them one by one. The run leaves the queue
        after its last line."""
        if run.mode != self.core.autostatus:
            # The mode in force is not the one the run was planned for (rare: a mode
            # read adopted another): its lines go out one by one, as planned now.
            self._unroll(run)
            return b""
        ends, first = run.ends, run.next
        start = ends[first - 1] if first else 0
        index, count = self.credit.wrote_run(ends, first), len(ends)
        if not first:
            run.written_mode = self.core.autostatus
            run.serial = self.written_lines + 1
        self.written_lines += index - first
        run.next = index
        if index == count:
            run.written = True
            self._queue.popleft()
        else:
            run.size = ends[index] - ends[index - 1]
        if not self._unmarked or self._unmarked[-1] is not run:
            self._unmarked.append(run)
        return run.blob[start:ends[index - 1]]

    def _unroll(self, run: Run) -> None:
        """Replace ``run`` (the head) by its lines not yet written, one :class:`Line`
        each, planned in the mode in force. (Only after the mode was adopted from the
        controller behind a run queued after the barrier: fresh tags, also behind it.)"""
        self._queue.popleft()
        mode = self.core.autostatus
        lines = []
        for index in range(run.next, len(run.ends)):
            command = parse(run.line_at(index), self.core.context)
            expect = expectation(command, mode, self.core.context)
            line = Line(command, next(self._tags), expect, mode, run.batch)
            self._unrolled[line.tag] = run.tag
            line.owes = line.guard = self.core.owed(command, expect, mode)
            lines.append(line)
            mode = expect.mode_after
        run.written = True  # as a run; withdrawing it withdraws these lines
        self._queue.extendleft(reversed(lines))

    def _must_wait(self, owes: Edge | None, batch: object | None) -> bool:
        """Without a separator: whether a line whose reply's front edge is ``owes`` must
        wait for the newest line in flight to get the lines it is sure to get (their
        replies could be taken for each other)."""
        if owes is None:
            return False
        tail = self.core.tail
        if tail is None or not tail[1].overlaps(owes):
            return False
        return batch is None or self._batch_of(tail[0]) is not batch

    def _batch_of(self, tag: Hashable) -> object | None:
        return self._last_batch if tag == self._last_owing else None

    def _separator_for(self, owes: Edge | None, batch: object | None
                       ) -> _Separation:
        """What goes before a line whose reply's front edge is ``owes``: nothing
        (:data:`_APART`), a separator line, or :data:`_WAIT` (none exists, wait for the
        reply instead). One is needed when the rear edge of the last line written that is
        sure to get a line overlaps it: a line too many (or too few) between them, or that
        line's own line lost, would shift a reply onto the wrong request
        (:mod:`tango_aio.sansio._patterns`). The edges are
        those of the lines each is sure to get, with the optional ones around them, in
        every mode: a read's optional echo in mode 4 hides nothing. Lines of one batch
        need none: it fails as a whole."""
        last = self._last_owed
        if owes is None or last is None or not last.overlaps(owes):
            return _APART
        if batch is not None and batch is self._last_batch:
            return _APART
        if not self.separators:
            return _WAIT
        line = self.core.separator(last, owes)
        return _WAIT if line is None else _Separation(line)

    def _separator(self, separator: tuple[bytes, ReplyPattern]) -> bytes:
        tag = next(self._tags)
        data = self.core.separate(tag, separator)
        self._separators.add(tag)
        self.credit.wrote(len(data), tag)
        self._owed(None)
        return data

    def _owed(self, batch: object | None) -> None:
        """Remember the rear edge of the line just registered (or of the follow-up the
        core wrote behind it), if it is sure to get a line."""
        sent = self.core.sent
        if sent is not None:
            self._last_owed, self._last_batch, self._last_owing = sent[1], batch, sent[0]

    def _marker_batch(self) -> object:
        """A credit marker joins the batch of the lines it confirms; markers after lines
        of no batch form a batch of their own (their replies only return credit)."""
        last = self._unmarked[-1].batch if self._unmarked else None
        return last if last is not None else _MARKERS

    def _register(self, line: Line) -> bytes:
        line.written_mode = self.core.autostatus
        self.written_lines += 1
        line.serial = self.written_lines
        data, _ = self.core.send(line.command, line.tag, (line.mode, line.expectation))
        line.written = True
        if line.owes is not None:
            self._owed(line.batch)
        confirming = line.confirming
        self.credit.wrote(len(data), line.tag if confirming else None)
        if not confirming:
            self._unmarked.append(line)
        return data

    def _marker(self, batch: object) -> bytes:
        tag = next(self._tags)
        data, _ = self.core.send(_MARKER, tag)
        self._owed(batch)
        self.credit.wrote(len(data), tag)
        self._credit_markers[tag] = self._unmarked
        self._unmarked = []
        return data

    def owns(self, tag: Hashable) -> bool:
        """Whether ``tag`` is a line the scheduler wrote on its own (a separator or a
        credit marker) and nobody awaits."""
        return tag in self._separators or tag in self._credit_markers

    # -- what came back ---------------------------------------------------------------

    def replied(self, tag: Hashable, lines: tuple[str, ...] | None, *,
                confirms: bool = True) -> bool:
        """A reply part of ``tag`` arrived: its data ``lines`` (``None`` for an
        acknowledgement or echo). ``confirms``: it was sent after the line was processed
        (not an echo of mode 4, sent before), so it returns the credit of every line up
        to this one. Returns whether ``tag`` was the scheduler's own line (a separator or
        a credit marker): then the caller has nothing more to do with it."""
        if confirms:
            self.credit.confirm(tag)
        if tag in self._separators:
            self._separators.discard(tag)
            return True
        if tag in self._credit_markers:
            if lines is not None:
                self._on_credit_marker(tag, lines)
            return True
        return False

    def _on_credit_marker(self, tag: Hashable, lines: tuple[str, ...]) -> None:
        covered = self._credit_markers.pop(tag)
        try:
            code = int(lines[0])
        except (IndexError, ValueError):
            log.warning("credit marker got a garbled reply %r", lines)
            return
        if code:
            log.warning("error %d after %s", code, covered[-1].command.line if covered else "?")
            for line in covered:
                line.chunk_error = code

    def restarted(self, tag: Hashable, size: int) -> None:
        """The caller wrote a resync marker of ``size`` bytes under ``tag`` (registered
        with :meth:`ProtocolCore.resync`): what was in flight is forgotten (after Ctrl+C
        the controller's buffer is empty; after a timeout it is assumed to have caught
        up, or a lost reply would never return its credit)."""
        self.credit.cleared()
        self._credit_markers.clear()
        self._separators.clear()
        self._last_owed, self._last_batch, self._last_owing = None, None, None
        self._unmarked = []
        self.written_lines += 1
        self.credit.wrote(size, tag)

    def exchanged(self, count: int) -> int:
        """The caller wrote ``count`` lines of an exchange of its own, outside the queue
        and the credit (:meth:`TangoProtocol._exchange
        <tango_aio.link._protocol.TangoProtocol._exchange>`)."""
        self.written_lines += count
        return self.written_lines

    def in_step(self) -> None:
        """The stream is in step and nothing is in flight (a quiet resync or an exchange
        ended): all credit is free."""
        self.credit.cleared()
        self._last_owed, self._last_batch, self._last_owing = None, None, None


def _replyless(expect: Expectation, mode: int) -> bool:
    """Whether a line owing ``expect`` in ``mode`` may go into a :class:`Run`: no reply,
    no report, no mode change, no continuation."""
    return not (expect.expects_reply or expect.completion is not None
                or expect.mode_after != mode or expect.rule.continuation is not None)


def _run(first: Command, expect: Expectation, mode: int, lines: Sequence[bytes],
         batch: object | None) -> Run:
    """The :class:`Run` of ``lines`` (bytes, CR included), ``first`` its first line."""
    return Run(first, 0, expect, mode, batch, blob=b"".join(lines),
               ends=tuple(itertools.accumulate(map(len, lines))))
