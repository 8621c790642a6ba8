"""The asyncio protocol: connects the sans-IO core to a transport and to futures.

:class:`TangoProtocol` is the only writer to the transport. It owns the FIFO of pending
requests (inside :class:`~tango_aio.core.ProtocolCore`), resolves each request's future when
its reply arrives, resolves move futures when their completion report arrives, and hands
everything unsolicited to an event callback.

Cancellation never desynchronises the stream: a cancelled request keeps its place in the
core's FIFO, and its late reply is consumed there and dropped. A *timed-out* request is
different: its reply may be lost for good, so the protocol resynchronises (see the core's
theory of operation), failing every request still pending with
:class:`~tango_aio.errors.RequestAbortedError`. When resyncs overlap, the reply to the
newest marker ends all of them.

A lost link fails every pending future with :class:`~tango_aio.errors.ConnectionLostError`
whose ``__cause__`` is the transport's error (a :class:`ConnectionResetError` when the other
end closed cleanly); later calls raise the same class at once.

Flow control: every line goes through a write queue and is written only while the bytes
written but not yet confirmed by a reply stay within the credit limit (255 by default), so
the controller's 256-byte input buffer never overflows (:mod:`tango_aio.flow`). Runs of
reply-less lines are confirmed by ``err`` markers the protocol inserts itself; a marker
reporting an error marks the lines it covers (:attr:`Submission.chunk_error`). A line is
registered with the core when it is written, so a queued line can still be withdrawn.

Wire tracing: the ``tango_aio.wire`` logger at DEBUG logs every line written (``->``) and
every line received (``<-``), CR removed, with a monotonic timestamp.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import logging
import time
from collections import deque
from collections.abc import Callable, Collection, Hashable, Iterable
from dataclasses import dataclass, field
from typing import Any

from .core import (
    Acknowledged,
    Completed,
    Dropped,
    Echoed,
    Event,
    Expectation,
    Mismatched,
    ProtocolCore,
    Replied,
    RequestLost,
    Unsolicited,
    expectation,
    owed_pattern,
)
from .errors import (
    ConnectionLostError,
    ControllerTimeoutError,
    InvalidCommandError,
    ProtocolError,
    RequestAbortedError,
    UnknownControllerError,
    controller_error,
)
from .flow import DEFAULT_CHUNK, DEFAULT_LIMIT, CreditWindow
from .instructions import Command, Context, parse
from .patterns import ReplyPattern

__all__ = ["Response", "Submission", "TangoProtocol"]

wire_log = logging.getLogger("tango_aio.wire")
log = logging.getLogger("tango_aio.protocol")


@dataclass(slots=True)
class Response:
    """Everything a request got back: its echo, data lines and acknowledgement."""

    lines: tuple[str, ...] = ()
    ack: int | None = None
    acked: bool = False
    echo: str | None = None


@dataclass(eq=False, slots=True)
class Submission:
    """A command written to the controller.

    ``reply`` resolves with the :class:`Response` when the request owes a reply (else it
    is ``None``); ``completion`` resolves with the :class:`~tango_aio.core.Completed`
    report of a move, ``cal`` or ``rm``.
    """

    command: Command
    tag: Hashable
    expectation: Expectation
    reply: asyncio.Future[Response] | None
    completion: asyncio.Future[Completed] | None
    response: Response = field(default_factory=Response)
    #: Whether the line has been written (it may wait in the queue for credit).
    written: bool = False
    #: Error number reported by the credit marker that followed this reply-less line
    #: (``?err`` reports the state after the last line before it), if non-zero.
    chunk_error: int | None = None
    #: Lines of one all-or-nothing batch (``None``: on its own) may be pipelined even
    #: when their replies look alike (:mod:`tango_aio.patterns`).
    batch: object | None = None
    #: Pattern of the first line owed, ``None`` if none.
    owes: ReplyPattern | None = None
    #: Whether a reply (data or acknowledgement) will confirm this line's bytes.
    confirming: bool = field(init=False)
    #: Bytes this line takes on the wire (with a read's internal follow-up).
    size: int = field(init=False)
    #: The autostatus mode ``expectation`` was computed for.
    mode: int = 1

    def __post_init__(self) -> None:
        # Both are asked for on every flush while the line waits for credit: computed once.
        expect = self.expectation
        rule = expect.rule
        self.confirming = expect.ack or rule.count > 0 or rule.terminator is not None \
            or rule.continuation is not None
        follow_up = 5 if rule.continuation is not None else 0
        self.size = len(self.command.to_bytes()) + follow_up


#: Called with each unsolicited event, completion report and dropped line; the second
#: argument is the submission a completion belongs to (``None`` if unsolicited).
EventCallback = Callable[[Event, "Submission | None"], None]


class TangoProtocol(asyncio.Protocol):
    """Routes the controller's lines to awaiting requests, moves and the event callback."""

    def __init__(
        self,
        *,
        autostatus: int = 1,
        context: Context | None = None,
        on_event: EventCallback | None = None,
        on_lost: Callable[[BaseException | None], None] | None = None,
        credit_limit: int = DEFAULT_LIMIT,
        marker_chunk: int = DEFAULT_CHUNK,
    ) -> None:
        self.core = ProtocolCore(autostatus=autostatus, context=context)
        #: The write-credit account (see :mod:`tango_aio.flow`).
        self.credit = CreditWindow(credit_limit, marker_chunk)
        self._queue: deque[Submission] = deque()
        self._queued_mode = autostatus
        self._unmarked: list[Submission] = []
        self._credit_markers: dict[Hashable, list[Submission]] = {}
        self._marker_batches: dict[Hashable, object] = {}
        self._transport: asyncio.BaseTransport | None = None
        self._tags = itertools.count(1)
        self._submissions: dict[Hashable, Submission] = {}
        self._markers: dict[Hashable, asyncio.Future[Response]] = {}
        self._on_event = on_event
        self._on_lost = on_lost
        self._lost: ConnectionLostError | None = None
        self._closing = False
        self._peer_eof = False
        self._trace_buffer = b""
        self._connected = asyncio.get_running_loop().create_future()

    def set_callbacks(self, on_event: EventCallback | None,
                      on_lost: Callable[[BaseException | None], None] | None) -> None:
        """Set where unsolicited events and the connection loss are reported."""
        self._on_event = on_event
        self._on_lost = on_lost

    # -- connection ------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Called by asyncio when the link is up."""
        self._transport = transport
        if not self._connected.done():
            self._connected.set_result(None)
        if self._closing:
            # close() ran first (e.g. a cancelled connect(): a serial transport reports
            # connection_made one loop iteration after it was created): do not leak it.
            transport.close()

    async def wait_connected(self) -> None:
        """Wait until :meth:`connection_made` has run."""
        await self._connected

    def eof_received(self) -> bool | None:
        """Called by asyncio when the other end closed a stream (TCP): close as well."""
        self._peer_eof = True
        return None

    def connection_lost(self, exc: Exception | None) -> None:
        """Called by asyncio when the link is gone: fail everything that waits.

        The error's ``__cause__`` is ``exc``; when the other end closed the link without
        an error, a :class:`ConnectionResetError` saying so stands in for it.
        """
        if exc is None and not self._closing:
            how = "the other end closed the connection" if self._peer_eof else "link closed"
            exc = ConnectionResetError(how)
        error = ConnectionLostError(f"connection to the controller lost: {exc or 'closed'}")
        error.__cause__ = exc
        self._lost = error
        for submission in list(self._submissions.values()):
            _fail(submission.reply, error)
            _fail(submission.completion, error)
        for marker in self._markers.values():
            _fail(marker, error)
        self._submissions.clear()
        self._markers.clear()
        self._queue.clear()
        if self._on_lost is not None:
            self._on_lost(exc)

    @property
    def transport(self) -> asyncio.BaseTransport | None:
        """The transport (``None`` before :meth:`connection_made`)."""
        return self._transport

    @property
    def is_connected(self) -> bool:
        """Whether the link is up and not lost."""
        return self._transport is not None and self._lost is None

    def close(self) -> None:
        """Close the transport (pending requests fail with ConnectionLostError)."""
        self._closing = True
        if self._transport is not None and not self._transport.is_closing():
            self._transport.close()

    def give_up(self, error: ConnectionLostError) -> None:
        """Record why a lost link will not come back: later calls raise ``error``'s class
        with its message and cause (used when an automatic reconnect gives up)."""
        if self._lost is not None:
            self._lost = error

    def check(self) -> None:
        """Raise the connection error if the link is gone."""
        if self._lost is not None:
            raise ConnectionLostError(str(self._lost)) from self._lost.__cause__
        if self._transport is None:
            raise ConnectionLostError("not connected")

    # -- writing ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        transport = self._transport
        assert isinstance(transport, asyncio.WriteTransport)
        if wire_log.isEnabledFor(logging.DEBUG):
            for line in data.split(b"\r")[:-1]:
                wire_log.debug("%.6f -> %r", time.monotonic(), line)
        transport.write(data)

    def _trace_received(self, data: bytes) -> None:
        """Log each complete received line (CR removed) on the ``tango_aio.wire`` logger."""
        if not wire_log.isEnabledFor(logging.DEBUG):
            self._trace_buffer = b""
            return
        *lines, self._trace_buffer = (self._trace_buffer + data).split(b"\r")
        for line in lines:
            wire_log.debug("%.6f <- %r", time.monotonic(), line)
        if len(self._trace_buffer) > 4096:
            wire_log.debug("%.6f <- %r (no CR yet)", time.monotonic(), self._trace_buffer)
            self._trace_buffer = b""

    def submit(self, command: Command, *, batch: object | None = None) -> Submission:
        """Queue ``command`` for writing and return its :class:`Submission` (futures for
        the reply and the completion report, where the line owes them).

        The line is written at once when the credit allows, else as soon as replies free
        enough credit; lines are always written in submission order. A line whose reply
        could be taken for the reply of the newest line in flight waits until that one is
        answered, unless both belong to the same ``batch`` (see :mod:`tango_aio.patterns`).
        """
        self.check()
        _check_framing(command)
        tag = next(self._tags)
        was_queued = bool(self._queue)
        mode = self._queued_mode if was_queued else self.core.autostatus
        expect = expectation(command, mode, self.core.context)
        self._queued_mode = expect.mode_after
        loop = asyncio.get_running_loop()
        submission = Submission(
            command,
            tag,
            expect,
            loop.create_future() if expect.expects_reply else None,
            loop.create_future() if expect.completion is not None else None,
            batch=batch,
            owes=owed_pattern(command, expect, self.core.context),
            mode=mode,
        )
        if submission.reply is not None or submission.completion is not None:
            self._submissions[tag] = submission
        self._queue.append(submission)
        if not was_queued:
            # Otherwise the head of the queue is still waiting for credit or a reply, and
            # this line can only follow it: nothing could be written now.
            self._flush()
        return submission

    @property
    def queued(self) -> int:
        """Number of lines waiting in the write queue for credit."""
        return len(self._queue)

    def withdraw(self, submissions: Iterable[Submission]) -> int:
        """Take lines that are still queued out of the queue; return how many were.

        Their futures are cancelled. Lines already written are not affected.
        """
        doomed = {id(s) for s in submissions if not s.written}
        if not doomed:
            return 0
        kept = deque(s for s in self._queue if id(s) not in doomed)
        removed = [s for s in self._queue if id(s) in doomed]
        self._queue = kept
        for submission in removed:
            self._submissions.pop(submission.tag, None)
            _cancel(submission.reply)
            _cancel(submission.completion)
        self._reproject()
        return len(removed)

    def _reproject(self) -> None:
        mode = self.core.autostatus
        for submission in self._queue:
            mode = expectation(submission.command, mode, self.core.context).mode_after
        self._queued_mode = mode

    def _flush(self) -> None:
        """Write queued lines while the credit allows, inserting markers where due."""
        if self._transport is None or self._lost is not None:
            return
        out = bytearray()
        while self._queue:
            head = self._queue[0]
            if self.credit.marker_due(head.size, head.confirming):
                if not self.credit.marker_fits() or self._must_wait(_MARKER_OWES,
                                                                    self._marker_batch()):
                    break
                out += self._marker()
                continue
            if not self.credit.fits(head.size, head.confirming) or \
                    self._must_wait(head.owes, head.batch):
                break
            self._queue.popleft()
            out += self._register(head)
        if out:
            self._write(bytes(out))

    def _must_wait(self, owes: ReplyPattern | None, batch: object | None) -> bool:
        """Whether a line owing ``owes`` must wait for the newest line in flight to be
        answered: their replies could be taken for each other (tango_aio.patterns)."""
        if owes is None:
            return False
        tail = self.core.tail
        if tail is None or not tail[1].overlaps(owes):
            return False
        return batch is None or self._batch_of(tail[0]) is not batch

    def _batch_of(self, tag: Hashable) -> object | None:
        submission = self._submissions.get(tag)
        if submission is not None:
            return submission.batch
        return self._marker_batches.get(tag)

    def _marker_batch(self) -> object:
        """A credit marker joins the batch of the lines it confirms; markers after lines
        of no batch form a batch of their own (their replies only return credit)."""
        last = self._unmarked[-1].batch if self._unmarked else None
        return last if last is not None else _MARKERS

    def _register(self, submission: Submission) -> bytes:
        data, _ = self.core.send(submission.command, submission.tag,
                                 (submission.mode, submission.expectation))
        submission.written = True
        confirming = submission.confirming
        self.credit.wrote(len(data), submission.tag if confirming else None)
        if not confirming:
            self._unmarked.append(submission)
        return data

    def _marker(self) -> bytes:
        tag = next(self._tags)
        data, _ = self.core.send(_MARKER, tag)
        self.credit.wrote(len(data), tag)
        self._credit_markers[tag] = self._unmarked
        self._marker_batches[tag] = self._marker_batch()
        self._unmarked = []
        return data

    def _on_credit_marker(self, tag: Hashable, lines: tuple[str, ...]) -> None:
        covered = self._credit_markers.pop(tag)
        self._marker_batches.pop(tag, None)
        try:
            code = int(lines[0])
        except (IndexError, ValueError):
            log.warning("credit marker got a garbled reply %r", lines)
            return
        if code:
            log.warning("error %d after %s", code, covered[-1].command.line if covered else "?")
            for submission in covered:
                submission.chunk_error = code

    def _drop_queue(self) -> None:
        """Forget every line not yet written (their futures fail: they were never sent)."""
        error = RequestAbortedError("the line was not sent: the stream was resynchronised")
        for submission in self._queue:
            self._submissions.pop(submission.tag, None)
            _fail(submission.reply, error)
            _fail(submission.completion, error)
        self._queue.clear()
        self._queued_mode = self.core.autostatus

    async def request(self, command: Command, timeout: float | None = 5.0) -> Response:
        """Write ``command`` and wait for its reply (an empty Response if it owes none).

        On timeout the stream is resynchronised and :class:`ControllerTimeoutError` raised.
        """
        submission = self.submit(command)
        if submission.reply is None:
            return submission.response
        return await self.wait_reply(submission, timeout)

    async def wait_reply(self, submission: Submission, timeout: float | None) -> Response:
        """Wait for ``submission``'s reply; on timeout resync (the marker gets the same
        time) and raise :class:`ControllerTimeoutError`."""
        assert submission.reply is not None
        try:
            async with asyncio.timeout(timeout):
                return await asyncio.shield(submission.reply)
        except TimeoutError:
            self.check()
            await self.resync(timeout=timeout if timeout is not None else 2.0)
            raise ControllerTimeoutError(
                f"no reply to {submission.command.line!r} within {timeout} s"
            ) from None

    async def resync(self, *, ctrl_c: bool = False, timeout: float = 2.0) -> None:
        """Resynchronise the reply stream (optionally sending Ctrl+C first).

        Every pending request fails with :class:`RequestAbortedError`; the call returns
        when the marker's reply has arrived.
        """
        self.check()
        tag, marker = self._begin_resync(ctrl_c)
        try:
            async with asyncio.timeout(timeout):
                await asyncio.shield(marker)
        except TimeoutError:
            raise ControllerTimeoutError(
                f"controller did not answer within {timeout} s the query sent to realign "
                f"its replies (resync marker)"
            ) from None
        finally:
            self._markers.pop(tag, None)

    def _begin_resync(self, ctrl_c: bool = False, *, keep_queue: bool = False
                      ) -> tuple[Hashable, asyncio.Future[Response]]:
        """Write the resync marker (see :meth:`resync`); return its tag and future. Lines
        still queued are dropped, or with ``keep_queue`` written after the marker."""
        tag = next(self._tags)
        marker: asyncio.Future[Response] = asyncio.get_running_loop().create_future()
        if not keep_queue:
            self._drop_queue()
        data = self.core.resync(tag, ctrl_c=ctrl_c)
        # Ctrl+C empties the controller's buffer; after a timeout the controller is
        # assumed to have caught up (a lost reply would otherwise never return its credit).
        self.credit.cleared()
        self._credit_markers.clear()
        self._marker_batches.clear()
        self._unmarked = []
        self._markers[tag] = marker
        self._dispatch_pending()
        self._write(data)
        self.credit.wrote(len(data) - (1 if ctrl_c else 0), tag)
        return tag, marker

    def forget_completion(self, submission: Submission) -> None:
        """Stop waiting for ``submission``'s completion (e.g. the move was refused)."""
        for tag, known in list(self._submissions.items()):
            if known is submission:
                self.core.forget_completion(tag)
                if submission.reply is None or submission.reply.done():
                    del self._submissions[tag]
        _cancel(submission.completion)

    # -- receiving ------------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        """Called by asyncio with bytes from the controller."""
        self._trace_received(data)
        self.core.receive_data(data)
        self._dispatch_pending()
        self._flush()

    def _dispatch_pending(self) -> None:
        while True:
            try:
                event = self.core.next_event()
            except ProtocolError as exc:
                log.warning("protocol error: %s", exc)
                continue
            if event is None:
                return
            self._dispatch(event)

    def _dispatch(self, event: Event) -> None:
        if isinstance(event, Completed) and self._on_event:
            known = self._submissions.get(event.tag) if event.tag is not None else None
            self._on_event(event, known)
        if isinstance(event, Replied | Acknowledged | Echoed):
            self._on_reply_part(event)
        elif isinstance(event, Completed):
            self._on_completed(event)
        elif isinstance(event, RequestLost):
            self._on_request_lost(event)
        elif isinstance(event, Mismatched):
            self._on_mismatch(event)
        elif isinstance(event, Dropped):
            log.debug("dropped while resynchronising: %r", event.line)
        if isinstance(event, Unsolicited | Dropped) and self._on_event:
            self._on_event(event, None)

    def _on_reply_part(self, event: Replied | Acknowledged | Echoed) -> None:
        if not isinstance(event, Echoed):
            # A reply is sent after its line was executed: everything up to it is processed.
            self.credit.confirm(event.tag)
        if event.tag in self._credit_markers and isinstance(event, Replied):
            self._on_credit_marker(event.tag, event.lines)
            return
        if event.tag in self._markers and isinstance(event, Replied):
            # The core only waits for the newest marker; its reply ends older resyncs too.
            for marker in self._markers.values():
                if not marker.done():
                    marker.set_result(Response(lines=event.lines))
            return
        submission = self._submissions.get(event.tag)
        if submission is None:
            return
        response = submission.response
        if isinstance(event, Replied):
            response.lines = event.lines
        elif isinstance(event, Acknowledged):
            response.ack, response.acked = event.code, True
            if event.code != 0:  # a refused move never completes (the core forgot it)
                _fail(submission.completion, _ack_error(event.code, submission))
        else:
            response.echo = event.line
        if event.done:
            if submission.reply is not None and not submission.reply.done():
                submission.reply.set_result(response)
            self._release(event.tag, submission)

    def _on_completed(self, event: Completed) -> None:
        if event.tag is None:
            return
        submission = self._submissions.get(event.tag)
        if submission is None:
            return
        if submission.completion is not None and not submission.completion.done():
            submission.completion.set_result(event)
        self._release(event.tag, submission)

    def _on_request_lost(self, event: RequestLost) -> None:
        submission = self._submissions.get(event.tag)
        if submission is None:
            return
        error = RequestAbortedError(
            f"{submission.command.line!r} got no reply: the reply stream was resynchronised"
        )
        _fail(submission.reply, error)
        if submission.completion is None or submission.completion.done():
            del self._submissions[event.tag]

    def _on_mismatch(self, event: Mismatched) -> None:
        """A line that cannot be the reply it would be taken for: fail that request with
        :class:`ProtocolError` and resynchronise: the other lines in flight fail with
        :class:`RequestAbortedError`; lines still queued are written after the marker."""
        submission = self._submissions.get(event.tag)
        command = submission.command.line if submission is not None else "a marker"
        line = repr(event.line) if len(event.line) <= 60 else repr(event.line[:60]) + "..."
        log.warning("reply mismatch: %s is not a reply to %r (%s expected), resyncing",
                    line, command, event.expected.kind.value)
        if submission is not None:
            _fail(submission.reply, ProtocolError(
                f"{line} cannot be the reply to {command!r} "
                f"({event.expected.kind.value} expected): a line was lost or added; "
                "the reply stream was resynchronised"))
        # The controller answers fine (a line was lost or added on the way), so lines not
        # yet written go out after the marker.
        tag, marker = self._begin_resync(keep_queue=True)
        # Nobody awaits this marker: its reply ends the resync in the core; if it never
        # comes, the next request's timeout resyncs again.
        marker.add_done_callback(functools.partial(self._forget_marker, tag))

    def _forget_marker(self, tag: Hashable, _future: asyncio.Future[Response]) -> None:
        self._markers.pop(tag, None)

    def _release(self, tag: Hashable, submission: Submission) -> None:
        reply_open = submission.reply is not None and not submission.reply.done()
        completion_open = submission.completion is not None and not submission.completion.done()
        if not reply_open and not completion_open:
            self._submissions.pop(tag, None)

    def fail_completions(self, error: BaseException,
                         only: Collection[Hashable] | None = None) -> None:
        """Fail every move still waiting for its completion report (or those of ``only``,
        a list of tags from ``core.awaiting_completion``)."""
        if only is None:
            tags = self.core.drop_completions()
        else:
            tags = [tag for tag in only if self.core.forget_completion(tag)]
        for tag in tags:
            submission = self._submissions.pop(tag, None)
            if submission is not None:
                _fail(submission.completion, error)
                _fail(submission.reply, error)


#: The credit marker: the bare read ``err`` (4 bytes), see :mod:`tango_aio.flow`.
_MARKER = parse("err")
_MARKER_OWES = owed_pattern(_MARKER, expectation(_MARKER, 1))
#: The batch of credit markers that confirm lines of no batch.
_MARKERS = object()


def _check_framing(command: Command) -> None:
    """Refuse a line that would frame more than one line, or Ctrl+C, on the wire.

    :func:`~tango_aio.instructions.parse` already rejects these; this guards
    :class:`Command` objects built by hand (defence in depth: CR would end the line early
    and smuggle in a second command, 0x03 would abort every axis).
    """
    line = command.line
    # CR, LF and 0x03 are not printable: one test covers all three.
    if not (line.isascii() and line.isprintable()):
        raise InvalidCommandError(
            f"control or non-ASCII character inside the command line {line!r}",
            instruction=command.name, code=4)


def _fail(future: asyncio.Future[Any] | None, error: BaseException) -> None:
    if future is not None and not future.done():
        future.set_exception(error)
        # Mark the exception retrieved: nobody may be awaiting a move's future any more.
        future.exception()


def _ack_error(code: int | None, submission: Submission) -> Exception:
    line = submission.command.line
    return UnknownControllerError(None, line) if code is None else controller_error(code, line)


def _cancel(future: asyncio.Future[Any] | None) -> None:
    if future is not None and not future.done():
        future.cancel()
