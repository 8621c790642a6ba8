"""The routing half of the asyncio link: the transport, the futures of each line written
(:class:`Submission`, :class:`Response`), the writes the sans-IO scheduler releases, the
lines received routed to their requests, moves and the event callback, the background
resync that follows a lost or mismatched reply, and the wire trace (the ``tango_aio.wire``
logger, :func:`traced`). :class:`~tango_aio.link._protocol.TangoProtocol` builds on
:class:`LineRouter`."""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import time
from collections.abc import Callable, Collection, Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..catalog import Command, Context, check_framing, check_rows_framing
from ..errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    ProtocolError,
    RequestAbortedError,
    TangoError,
    UnknownControllerError,
    WrongEventLoopError,
    controller_error,
)
from ..sansio import (
    DEAD_AFTER,
    DEFAULT_CHUNK,
    DEFAULT_LIMIT,
    Acknowledged,
    Completed,
    CreditWindow,
    Dropped,
    Echoed,
    Event,
    Line,
    LinkSession,
    LinkTiming,
    Mismatched,
    Outcome,
    ProtocolCore,
    Replied,
    RequestLost,
    Run,
    Silence,
    Unsolicited,
    WriteScheduler,
)

__all__ = ["TRACE_LINE", "EventCallback", "LineRouter", "Response", "Submission", "traced",
           "wire_log"]

wire_log = logging.getLogger("tango_aio.wire")
#: The link's own log (named after the module of the protocol, its public home).
log = logging.getLogger("tango_aio.link._protocol")


@dataclass(slots=True)
class Response:
    """Everything a request got back: its echo, data lines and acknowledgement."""

    lines: tuple[str, ...] = ()
    ack: int | None = None
    acked: bool = False
    echo: str | None = None
    #: Whether the line's acceptance rests only on the ``?err`` behind it: its
    #: autostatus-2 ``OK...`` or autostatus-4 echo did not come where it was owed (see
    #: ``Acknowledged.deferred``, ``Echoed.deferred``).
    #: Such a verdict does not prove the line arrived (:meth:`Controller.command
    #: <tango_aio.Controller.command>` proves it before it returns).
    deferred: bool = False
    #: The acknowledgement as received (``OK...``, ``ERR 5``; the ``?err`` reply when
    #: :attr:`deferred`), ``None`` before it came.
    ack_line: str | None = None


@dataclass(eq=False, slots=True)
class Submission(Line):
    """A command written to the controller: the scheduler's ``Line``
    with the futures of its caller."""

    reply: asyncio.Future[Response] | None = None
    completion: asyncio.Future[Completed] | None = None
    response: Response = field(default_factory=Response)
    #: The future a :meth:`TangoProtocol.wait_reply` sleeps on, woken in the same loop
    #: turn as ``reply`` is resolved (a done-callback would take one more turn).
    waiter: asyncio.Future[None] | None = None


#: Called with each unsolicited event, completion report and dropped line; the second
#: argument is the submission a completion belongs to (``None`` if unsolicited).
EventCallback = Callable[[Event, "Submission | None"], None]


class LineRouter(asyncio.Protocol):
    """The routing half of :class:`~tango_aio.link._protocol.TangoProtocol`: the transport,
    the futures of the lines written, the writes the scheduler releases, each line received
    routed to its request, move or the event callback, and the resync in the background;
    the protocol adds what its callers and the link's own exchanges ask for."""

    def __init__(
        self,
        *,
        autostatus: int = 1,
        context: Context | None = None,
        on_event: EventCallback | None = None,
        on_lost: Callable[[BaseException | None], None] | None = None,
        credit_limit: int = DEFAULT_LIMIT,
        marker_chunk: int = DEFAULT_CHUNK,
        reply_timeout: float = 5.0,
        dead_after: int = DEAD_AFTER,
        keepalive: float | None = None,
        separators: bool = True,
        detect: bool = False,
    ) -> None:
        if not (math.isfinite(reply_timeout) and reply_timeout > 0):
            raise ValueError(f"reply_timeout must be a positive number, got {reply_timeout}")
        if dead_after < 2:
            raise ValueError(f"dead_after must be at least 2, got {dead_after}")
        if keepalive is not None and not (math.isfinite(keepalive) and keepalive > 0):
            raise ValueError(f"keepalive must be None or a positive number, got {keepalive}")
        self.core = ProtocolCore(autostatus=autostatus, context=context)
        #: The link's state, resyncs, exchanges, detection and liveness, sans-IO
        #: (:mod:`tango_aio.sansio._session`); this class carries out what it decides.
        self.session = LinkSession(self.core, dead_after=dead_after, keepalive=keepalive,
                                   detect=detect)
        #: Time a resync marker or keepalive read the protocol writes itself may take.
        self.reply_timeout = reply_timeout
        self._keepalive_task: asyncio.Task[None] | None = None
        self._loop = asyncio.get_running_loop()
        #: The write queue, credit markers and separators (:mod:`tango_aio.sansio._scheduler`).
        self.scheduler = WriteScheduler(self.core, credit_limit=credit_limit,
                                        marker_chunk=marker_chunk, separators=separators)
        self._transport: asyncio.BaseTransport | None = None
        self._writer: Callable[[bytes], object] | None = None
        self._submissions: dict[Hashable, Submission] = {}
        self._markers: dict[Hashable, asyncio.Future[Response]] = {}
        self._on_event = on_event
        self._on_lost = on_lost
        self._lost: ConnectionLostError | None = None
        self._closing = False
        self._peer_eof = False
        self._trace_buffer = b""
        self._connected = self._loop.create_future()
        #: Called when a request or marker got no answer in time, and when
        #: :meth:`verify_autostatus` restored the driver's mode (found, restored): a
        #: controller may have restarted behind the link (:mod:`tango_aio.controller._restart`).
        self.on_unanswered: Callable[[], None] | None = None
        self.on_restored: Callable[[int, int], None] | None = None
        self._quiet_timer: asyncio.TimerHandle | None = None
        self._collected: asyncio.Future[None] | None = None
        self._barrier_lock = asyncio.Lock()
        #: The hold taken when a restart was suspected (``hold_for_check``), until the
        #: read of the mode that checks for it takes it over.
        self._check_hold: int | None = None
        self._queue_drops = 0  # times the queue was dropped (a mode change waiting fails)

    @property
    def dead_after(self) -> int:
        """Consecutive unanswered requests (resync markers included) after which a link
        that stays open is declared lost (see :meth:`_unanswered`)."""
        return self.session.dead_after

    @property
    def keepalive(self) -> float | None:
        """Seconds of silence after which an idle link is probed (``None``: never)."""
        return self.session.keepalive

    @property
    def quiet_interval(self) -> float:
        """Seconds without a byte after the reply of ``help`` that end a resync without a
        marker (:attr:`~tango_aio.sansio._core.HelpStyle.NONE`) and connect's exchanges: grown by
        the link's timing (:attr:`link`), so that a slow link's next reply is not
        taken for silence."""
        return self.session.quiet_interval

    @quiet_interval.setter
    def quiet_interval(self, seconds: float) -> None:
        self.session.quiet_interval = seconds

    def wire_paced(self, byte_seconds: float) -> None:
        """The link carries bytes at ``byte_seconds`` per byte or slower, both ways (the
        emulator's paced wire): a reply that starts before its request's bytes could have
        passed is not its reply (:func:`~tango_aio.sansio._linktiming.earliest_reply`). Not for a
        serial port's opened rate, which USB and PCI units do not keep (L10, L1645-1653)."""
        self.core.wire_seconds = byte_seconds

    @property
    def link(self) -> LinkTiming:
        """The link's timing: its byte time where the baud rate is known and the longest
        round trip connect's exchanges measured (the session's
        :attr:`~tango_aio.sansio._session.LinkSession.timing`)."""
        return self.session.timing

    def set_callbacks(self, on_event: EventCallback | None,
                      on_lost: Callable[[BaseException | None], None] | None) -> None:
        """Set where unsolicited events and the connection loss are reported."""
        self._on_event = on_event
        self._on_lost = on_lost

    # -- connection ------------------------------------------------------------------------

    async def wait_connected(self) -> None:
        """Wait until :meth:`connection_made` has run."""
        await self._connected

    def eof_received(self) -> bool | None:
        """Called by asyncio when the other end closed a stream (TCP): close as well."""
        self._peer_eof = True
        return None

    def connection_lost(self, exc: Exception | None) -> None:
        """Called by asyncio when the link is gone: fail everything that waits."""
        if self._keepalive_task is not None:
            self._keepalive_task.cancel()
        if self._lost is not None:
            return  # declared lost already (a dead link, see _unanswered)
        if exc is None and not self._closing:
            how = "the other end closed the connection" if self._peer_eof else "link closed"
            exc = ConnectionResetError(how)
        self._fail_all(exc)

    def _fail_all(self, exc: BaseException | None) -> None:
        """Fail everything that waits with ConnectionLostError (cause ``exc``) and tell
        the owner (once)."""
        error = ConnectionLostError(f"connection to the controller lost: {exc or 'closed'}")
        error.__cause__ = exc
        self._lost = error
        self.session.closed()
        for submission in list(self._submissions.values()):
            _fail(submission.reply, error)
            _fail(submission.completion, error)
        for marker in self._markers.values():
            _fail(marker, error)
        # An exchange of connect's (detect, a mode exchange) waits on its own future: it
        # fails here too, at once, not after its reply timeout.
        if self._collected is not None:
            _fail(self._collected, error)
        self._submissions.clear()
        self._markers.clear()
        self.scheduler.drop_queue()
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

    async def settle(self, timeout: float) -> None:
        """Wait up to ``timeout`` seconds while the only lines in flight are the driver's
        own (separators, credit markers), so that whoever opens the port next does not
        read their replies (:meth:`Controller.aclose`; a move's confirmation leaves a
        separator behind it). Returns at once when the link is gone, a resync runs, or a
        caller's request is in flight (closing fails that one anyway)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        owns = self.scheduler.owns
        while self._lost is None and self.is_connected and not self.core.resyncing:
            pending = self.core.pending_tags
            if not pending or not all(map(owns, pending)) or loop.time() >= deadline:
                return
            await asyncio.sleep(0.002)

    def give_up(self, error: ConnectionLostError) -> None:
        """Record why a lost link will not come back: later calls raise ``error``'s class
        with its message and cause (used when an automatic reconnect gives up)."""
        if self._lost is not None:
            self._lost = error

    def check(self) -> None:
        """Raise the connection error if the link is gone; raise
        :class:`WrongEventLoopError` when called from another event loop than the one the
        link was opened on (its callbacks run there; a future made here would never be
        resolved)."""
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is not self._loop:
            raise WrongEventLoopError(
                "this connection belongs to another event loop: a Controller can only be "
                "used from the event loop it was connected on (open one per loop or thread)")
        if self._lost is not None:
            raise ConnectionLostError(str(self._lost)) from self._lost.__cause__
        if self._transport is None:
            raise ConnectionLostError("not connected")

    # -- writing ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        # Duck-typed: uvloop's TCP transport is no asyncio.WriteTransport subclass;
        # every transport asyncio hands to a stream protocol has write().
        write = self._writer
        if write is None:
            raise ConnectionLostError("not connected")
        if wire_log.isEnabledFor(logging.DEBUG):
            for line in data.split(b"\r")[:-1]:
                wire_log.debug("%.6f -> %s", time.monotonic(), traced(line))
        write(data)

    def _trace_received(self, data: bytes) -> None:
        """Log each complete received line (CR removed) on the ``tango_aio.wire`` logger."""
        if not wire_log.isEnabledFor(logging.DEBUG):
            self._trace_buffer = b""
            return
        *lines, self._trace_buffer = (self._trace_buffer + data).split(b"\r")
        for line in lines:
            wire_log.debug("%.6f <- %s", time.monotonic(), traced(line))
        if len(self._trace_buffer) > TRACE_LINE:
            wire_log.debug("%.6f <- %s (no CR yet)", time.monotonic(),
                           traced(self._trace_buffer))
            self._trace_buffer = b""

    def submit(self, command: Command, *, batch: object | None = None,
               hold: bool = False) -> Submission:
        """Queue ``command`` for writing and return its :class:`Submission` (futures for
        the reply and the completion report, where the line owes them)."""
        self.check()
        check_framing(command)
        tag, mode, expect = self.scheduler.plan(command)
        loop = self._loop
        submission = Submission(
            command, tag, expect, mode, batch,
            reply=loop.create_future() if expect.expects_reply else None,
            completion=loop.create_future() if expect.completion is not None else None,
        )
        if submission.reply is not None or submission.completion is not None:
            self._submissions[tag] = submission
        if self.scheduler.submit(submission) and not hold:
            # Otherwise the head of the queue is still waiting for credit or a reply, and
            # this line can only follow it: nothing could be written now. (``hold``: the
            # caller flushes once the lines that belong together are queued.)
            self._flush()
        return submission

    def submit_together(self, commands: Sequence[Command], *,
                        separate_after: bool = False) -> list[Submission]:
        """:meth:`submit` each of ``commands`` and write them in one write where the
        credit allows (e.g. reads whose replies cannot be taken for each other: one write
        instead of one per line)."""
        submissions = [self.submit(command, hold=True) for command in commands]
        if submissions:
            submissions[-1].separate_after = separate_after
        self._flush()
        return submissions

    @property
    def queued(self) -> int:
        """Number of lines waiting in the write queue for credit."""
        return self.scheduler.queued

    @property
    def credit(self) -> CreditWindow:
        """The write-credit account (see :mod:`tango_aio.sansio._flow`)."""
        return self.scheduler.credit

    @property
    def separators(self) -> bool:
        """Look-alike requests: ``True`` writes a separator between two in a row (a stray
        line is detected); ``False`` only keeps them from being in flight together (no
        extra line, but a stray line that fits the waiting request shifts the replies
        after it: for benchmarks and hand-fed tests)."""
        return self.scheduler.separators

    @separators.setter
    def separators(self, value: bool) -> None:
        self.scheduler.separators = value

    def withdraw(self, submissions: Iterable[Line]) -> int:
        """Take lines that are still queued out of the queue; return how many were."""
        removed = self.scheduler.withdraw(submissions)
        for submission in removed:
            if isinstance(submission, Submission):
                self._submissions.pop(submission.tag, None)
                _cancel(submission.reply)
                _cancel(submission.completion)
        return len(removed)

    def pack(self, commands: Sequence[Command], *, batch: object | None = None
             ) -> Run | None:
        """Reply-less lines (list entries) as one record to :meth:`submit_run`: one bytes
        blob, not one object per line (:class:`~tango_aio.sansio._scheduler.Run`); ``None`` when
        a line would owe something in the mode in force (then :meth:`submit` each)."""
        for command in commands:
            check_framing(command)
        return self.scheduler.pack(commands, batch)

    def pack_lines(self, template: Command, lines: Sequence[bytes], *,
                   batch: object | None = None) -> Run | None:
        """:meth:`pack` for list entries given as bytes, each a line of ``template``'s
        instruction and form (``encode_rows``), framing checked on the whole blob."""
        check_framing(template)
        run = self.scheduler.pack_lines(template, lines, batch)
        if run is not None:
            check_rows_framing(template, run.blob, len(run))
        return run

    def submit_run(self, run: Run) -> Run:
        """Queue a run from :meth:`pack`. On the wire the same bytes, credit markers and
        separators as one :meth:`submit` per line; :meth:`withdraw` takes back the lines
        of the run not yet written."""
        self.check()
        if self.scheduler.submit(run):
            self._flush()
        return run

    def _flush(self, now: float | None = None) -> None:
        """Write what the scheduler lets go now (queued lines as the credit allows, with
        the markers and separators due); ``now``: the loop time, if just read."""
        if self._transport is None or self._lost is not None:
            return
        if self.core.wire_seconds:
            # Before the lines are registered: on a paced wire, a reply that starts before
            # this time plus their bytes' is not theirs (the arrival times' clock).
            self.core.write_time = self._loop.time() if now is None else now
        data = self.scheduler.next_write()
        if data:
            self._write(data)

    def _drop_queue(self) -> None:
        """Forget every line not yet written (their futures fail: they were never sent)."""
        error = RequestAbortedError("the line was not sent: the stream was resynchronised")
        self._queue_drops += 1
        for submission in self.scheduler.drop_queue():
            if not isinstance(submission, Submission):
                continue  # a run of reply-less lines: nobody waits for it
            self._submissions.pop(submission.tag, None)
            _fail(submission.reply, error)
            _fail(submission.completion, error)

    # -- silence, and the resync in the background -----------------------------------------

    def _unanswered(self, error: TangoError, serial: int, marker: Hashable | None = None
                    ) -> Silence:
        """Count a request (or marker) that got no reply in time; declare the link lost
        after :attr:`dead_after` in a row with no line at all in between (a link that stays
        open but no longer forwards: a serial-to-TCP adapter that stopped, a controller
        power-cycled behind one). ``serial`` numbers the line among those written: lines
        that were in flight together count once (they time out together when one reply is
        lost), so each count is a line written after the previous count. ``marker``: the
        tag of an overdue resync marker (the session may ask for a new one)."""
        if self.on_unanswered is not None and self._lost is None:
            self.on_unanswered()
        written = self.scheduler.written_lines
        silence = self.session.unanswered(serial, written) if marker is None else \
            self.session.marker_overdue(serial, written,
                                        newest=self._newest_marker() == marker)
        if silence is not Silence.DEAD:
            return silence
        cause = ConnectionAbortedError(f"{self.session.silent} requests in a row got no "
                                       f"reply: the link is dead ({error})")
        log.warning("%s", cause)
        self._fail_all(cause)
        if self._transport is not None and not self._transport.is_closing():
            self._transport.close()
        return silence

    def _background_resync(self, timeout: float) -> asyncio.Future[Response] | None:
        """Resync without anybody awaiting it: lines still queued wait for its end; if its
        marker is not answered within ``timeout`` it counts as unanswered and the next
        resync starts."""
        if self._lost is not None or self._transport is None:
            return None
        tag, marker = self._begin_resync(keep_queue=True)
        handle = self._loop.call_later(timeout, self._marker_deadline, tag, marker, timeout,
                                       self.scheduler.written_lines)
        marker.add_done_callback(functools.partial(self._forget_marker, tag, handle))
        return marker

    def _marker_deadline(self, tag: Hashable, marker: asyncio.Future[Response],
                         timeout: float, serial: int) -> None:
        if marker.done() or self._lost is not None:
            return
        error = ControllerTimeoutError(
            f"controller did not answer the resync marker within {timeout} s")
        if self._unanswered(error, serial, tag) is Silence.MARKER_AGAIN:
            self._background_resync(timeout)

    def _newest_marker(self) -> Hashable | None:
        return next(reversed(self._markers), None)

    def _on_dropped(self, line: str) -> None:
        """A line dropped while resynchronising (or collected by :meth:`_exchange`): the
        session says what follows."""
        outcome = self.session.line_dropped(line, self._loop.time())
        if outcome is Outcome.WAIT_QUIET:
            self._quiet_from_now()
        elif outcome is Outcome.COLLECTED:
            self._end_collection()

    def _quiet_from_now(self) -> None:
        """(Re)arm the session's quiet deadline (:meth:`_quiet_check`)."""
        if self._quiet_timer is not None:
            self._quiet_timer.cancel()
        deadline = self.session.quiet_deadline
        assert deadline is not None
        self._quiet_timer = self._loop.call_at(deadline, self._quiet_check)

    def _end_collection(self) -> None:
        """What :meth:`_exchange` waits for has come (or the link is quiet)."""
        if self._quiet_timer is not None:
            self._quiet_timer.cancel()
            self._quiet_timer = None
        if self._collected is not None and not self._collected.done():
            self._collected.set_result(None)

    def _quiet_check(self) -> None:
        """The quiet deadline passed: end the exchange, or the quiet resync."""
        self._quiet_timer = None
        outcome = self.session.quiet_elapsed()
        if outcome is Outcome.COLLECTED:
            self._end_collection()
        elif outcome is Outcome.IN_STEP:
            self.scheduler.in_step()
            for marker in self._markers.values():
                if not marker.done():
                    marker.set_result(Response())
            self._flush()

    def _begin_resync(self, ctrl_c: bool = False, *, keep_queue: bool = False
                      ) -> tuple[Hashable, asyncio.Future[Response]]:
        """Write the resync marker (see :meth:`resync`); return its tag and future. Lines
        still queued are dropped, or with ``keep_queue`` written after the marker."""
        tag = self.scheduler.next_tag()
        marker: asyncio.Future[Response] = asyncio.get_running_loop().create_future()
        if not keep_queue:
            self._drop_queue()
        data = self.session.begin_resync(tag, ctrl_c=ctrl_c)
        # The credit counts the marker's line, not Ctrl+C (the controller drops it).
        self.scheduler.restarted(tag, len(data) - (1 if ctrl_c else 0))
        self._markers[tag] = marker
        self._dispatch_pending()
        self._write(data)
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
        # Read after the bytes were: never earlier than they arrived (linktiming).
        now = self._loop.time()
        if self.session.bytes_received(now) is Outcome.WAIT_QUIET:
            self._quiet_from_now()
        self.core.receive_data(data, now)
        self._dispatch_pending()
        self._flush(now)

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
        if not isinstance(event, RequestLost):
            # Any line at all, even one nobody can use (junk, a garbled reply, a line
            # dropped while resynchronising), shows the link still forwards: only
            # silence counts towards a dead link (:meth:`_unanswered`).
            self.session.line_received()
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
            self._on_dropped(event.line)
        if isinstance(event, Unsolicited | Dropped) and self._on_event:
            self._on_event(event, None)

    def _on_reply_part(self, event: Replied | Acknowledged | Echoed) -> None:
        self._heard()
        # A reply is sent after its line was executed: everything up to it is processed
        # (an echo of mode 4 comes before).
        if self.scheduler.replied(event.tag,
                                  event.lines if isinstance(event, Replied) else None,
                                  confirms=not isinstance(event, Echoed)):
            return
        if isinstance(event, Replied) and self.session.replied(event.tag) \
                and event.tag in self._markers:
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
            response.ack, response.acked, response.ack_line = event.code, True, event.line
            if event.deferred:
                response.deferred = True
            if event.code != 0:  # a refused move never completes (the core forgot it)
                _fail(submission.completion, _ack_error(event.code, submission))
        else:
            response.echo = event.line
            if event.deferred:
                response.deferred = True
        if event.done:
            if submission.reply is not None and not submission.reply.done():
                submission.reply.set_result(response)
                _wake(submission.waiter)
            self._release(event.tag, submission)

    def _heard(self) -> None:
        """A reply line arrived: the link is alive and answers (the keepalive waits)."""
        self.session.reply_heard(self._loop.time())

    def _on_completed(self, event: Completed) -> None:
        self._heard()
        self.session.report_seen(event.line)
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
        command = submission.command.line if submission is not None else \
            "a line the driver wrote on its own (credit marker, separator, ?err follow-up)"
        line = repr(event.line) if len(event.line) <= 60 else repr(event.line[:60]) + "..."
        # A link that echoes every byte fails connect() with the same words: no warning.
        level = logging.DEBUG if self.core.local_echo else logging.WARNING
        if event.reason:
            log.log(level, "reply mismatch: %s (%r), resyncing", event.reason, command)
        else:
            log.log(level, "reply mismatch: %s is not a reply to %r (%s expected), resyncing",
                        line, command, event.expected.kind.value)
        if submission is not None:
            why = event.reason or (f"{line} cannot be the reply to {command!r} "
                                   f"({event.expected.kind.value} expected): a line was "
                                   "lost or added")
            _fail(submission.reply, ProtocolError(
                f"{why} ({command!r}); the reply stream was resynchronised"))
        if self.session.acknowledgement_missing(event.expected) \
                and self.on_unanswered is not None and self._lost is None:
            self.on_unanswered()  # (a controller that restarted acknowledges nothing)
        # The controller answers fine (a line was lost or added on the way), so lines not
        # yet written go out after the marker.
        self._background_resync(self.reply_timeout)

    def _forget_marker(self, tag: Hashable, deadline: asyncio.TimerHandle,
                       _future: asyncio.Future[Response]) -> None:
        deadline.cancel()
        self._markers.pop(tag, None)

    def _release(self, tag: Hashable, submission: Submission) -> None:
        reply_open = submission.reply is not None and not submission.reply.done()
        completion_open = submission.completion is not None and not submission.completion.done()
        if not reply_open and not completion_open:
            self._submissions.pop(tag, None)

    def fail_completions(self, error: BaseException,
                         only: Collection[Hashable] | None = None) -> None:
        """Fail every move still waiting for its completion report (or those of ``only``)."""
        if only is None:
            tags = self.core.drop_completions()
        else:
            tags = [tag for tag in only if self.core.forget_completion(tag)]
        for tag in tags:
            submission = self._submissions.pop(tag, None)
            if submission is not None:
                _fail(submission.completion, error)
                _fail(submission.reply, error)


def _fail(future: asyncio.Future[Any] | None, error: BaseException) -> None:
    if future is not None and not future.done():
        future.set_exception(error)
        # Mark the exception retrieved: nobody may be awaiting a move's future any more.
        future.exception()


def _ack_error(code: int | None, submission: Submission) -> ControllerError:
    line = submission.command.line
    return UnknownControllerError(None, line) if code is None else controller_error(code, line)


#: Bytes of one line a wire-log record shows at most, so that a long line (or one whose
#: CR never comes) cannot make a record of any size; the rest is counted, not shown.
TRACE_LINE = 256


def traced(line: bytes) -> str:
    """``repr`` of a traced line, cut at :data:`TRACE_LINE` bytes."""
    if len(line) <= TRACE_LINE:
        return repr(line)
    return f"{line[:TRACE_LINE]!r}... ({len(line)} bytes)"


def _wake(waiter: asyncio.Future[None] | None) -> None:
    if waiter is not None and not waiter.done():
        waiter.set_result(None)


def _cancel(future: asyncio.Future[Any] | None) -> None:
    if future is not None and not future.done():
        future.cancel()
