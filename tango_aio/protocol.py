"""The asyncio protocol: connects the sans-IO core to a transport and to futures.

:class:`TangoProtocol` is the only writer to the transport. It owns the FIFO of pending
requests (inside :class:`~tango_aio.core.ProtocolCore`), resolves each request's future when
its reply arrives, resolves move futures when their completion report arrives, and hands
everything unsolicited to an event callback.

Cancellation never desynchronises the stream: a cancelled request keeps its place in the
core's FIFO, and its late reply is consumed there and dropped. A *timed-out* request is
different: its reply may be lost for good. Its caller gets
:class:`~tango_aio.errors.ControllerTimeoutError` at its own timeout (a line that went out
only during the wait gets the time once more from then; one never written is withdrawn,
and goes on as below only when the reply it was held behind is one nobody waits for:
:meth:`~tango_aio.session.LinkSession.reply_overdue`), and the protocol resynchronises in
the background (see the core's theory of operation): requests
still in flight fail with :class:`~tango_aio.errors.RequestAbortedError`, lines still
queued wait until the marker is answered. When resyncs overlap, the reply to the newest marker ends
all of them. Lines that get no reply ``dead_after`` times in a row, with no line at all
arriving in between (a link that stays open but no longer forwards), declare the link lost;
a link that still delivers lines, even garbled ones, is slow or noisy, not dead.

A lost link fails every pending future with :class:`~tango_aio.errors.ConnectionLostError`
whose ``__cause__`` is the transport's error (a :class:`ConnectionResetError` when the other
end closed cleanly); later calls raise the same class at once.

Flow control: every line goes through the sans-IO write scheduler
(:mod:`tango_aio.scheduler`), which writes it only while the bytes written but not yet
confirmed by a reply stay within the credit limit (255 by default), so the controller's
256-byte input buffer never overflows (:mod:`tango_aio.flow`). Runs of reply-less lines
are confirmed by ``err`` markers the scheduler inserts itself; a marker reporting an error
marks the lines it covers (:attr:`Submission.chunk_error`). A line is registered with the
core when it is written, so a queued line can still be withdrawn.

What the link decides about itself (resync and quiet resync, the mode exchange and the
verdict on it, the detection at connect, what an overdue reply or marker calls for,
dead-link counting, the keepalive's schedule) is the sans-IO
:class:`~tango_aio.session.LinkSession`'s, and whether a line is well framed is
:mod:`~tango_aio.instructions`'; the protocol keeps the futures, the transport, the timers
and the tracing, and carries out what the session and the scheduler decide.

Wire tracing: the ``tango_aio.wire`` logger at DEBUG logs every line written (``->``) and
every line received (``<-``), CR removed, with a monotonic timestamp; a record shows at
most the first :data:`TRACE_LINE` (256) bytes of its line and the line's length.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import time
from collections.abc import Callable, Collection, Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from .core import (
    Acknowledged,
    Completed,
    Dropped,
    Echoed,
    Event,
    Mismatched,
    ProtocolCore,
    Replied,
    RequestLost,
    Unsolicited,
    expectation,
)
from .errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    GarbledVerdictError,
    ProtocolError,
    RequestAbortedError,
    SettingNotAppliedError,
    TangoError,
    UnknownControllerError,
    WrongEventLoopError,
    controller_error,
)
from .flow import DEFAULT_CHUNK, DEFAULT_LIMIT, CreditWindow
from .instructions import Command, Context, Form, build, check_framing, check_rows_framing, parse
from .linktiming import LinkTiming
from .readback import ReadBack, mismatch, read_back
from .scheduler import Line, Run, WriteScheduler
from .session import (
    DEAD_AFTER,
    STATUS_READ,
    Barrier,
    Exchange,
    LinkSession,
    ModeVerdict,
    Outcome,
    Overdue,
    Silence,
    Until,
)
from .timing import Verdict, ack_verdict, err_verdict

__all__ = ["DEAD_AFTER", "MoveHandle", "Response", "Submission", "TangoProtocol",
           "WrongEventLoopError"]

wire_log = logging.getLogger("tango_aio.wire")
log = logging.getLogger("tango_aio.protocol")



@dataclass(slots=True)
class Response:
    """Everything a request got back: its echo, data lines and acknowledgement."""

    lines: tuple[str, ...] = ()
    ack: int | None = None
    acked: bool = False
    echo: str | None = None
    #: Whether the line's acceptance rests only on the ``?err`` behind it: its
    #: autostatus-2 ``OK...`` or autostatus-4 echo did not come where it was owed (see
    #: :attr:`tango_aio.core.Acknowledged.deferred`, :attr:`tango_aio.core.Echoed.deferred`).
    #: Such a verdict does not prove the line arrived (:meth:`Controller.command
    #: <tango_aio.controller.Controller.command>` proves it before it returns).
    deferred: bool = False
    #: The acknowledgement as received (``OK...``, ``ERR 5``; the ``?err`` reply when
    #: :attr:`deferred`), ``None`` before it came.
    ack_line: str | None = None


@dataclass(eq=False, slots=True)
class Submission(Line):
    """A command written to the controller: the scheduler's :class:`~tango_aio.scheduler.Line`
    with the futures of its caller.

    ``reply`` resolves with the :class:`Response` when the request owes a reply (else it
    is ``None``); ``completion`` resolves with the :class:`~tango_aio.core.Completed`
    report of a move, ``cal`` or ``rm``.
    """

    reply: asyncio.Future[Response] | None = None
    completion: asyncio.Future[Completed] | None = None
    response: Response = field(default_factory=Response)
    #: The future a :meth:`TangoProtocol.wait_reply` sleeps on, woken in the same loop
    #: turn as ``reply`` is resolved (a done-callback would take one more turn).
    waiter: asyncio.Future[None] | None = None


@dataclass(eq=False, slots=True)
class MoveHandle:
    """A motion line (move, ``cal``, ``rm``...) written by :meth:`TangoProtocol.start_move`,
    with the ``?err`` probe that checks it (``None`` when autostatus 2 acknowledges it, or
    unchecked)."""

    protocol: TangoProtocol
    submission: Submission
    probe: Submission | None
    check: bool
    #: A set line's read-back, written behind the probe where the line owes no answer of
    #: its own (:func:`~tango_aio.readback.read_back`), and its submission.
    proof: tuple[ReadBack, Submission] | None = None

    @property
    def command(self) -> Command:
        """The motion line."""
        return self.submission.command

    @property
    def expects_report(self) -> bool:
        """Whether a completion report is awaited (not in autostatus 0)."""
        return self.submission.completion is not None

    async def error(self, timeout: float | None) -> ControllerError | None:
        """Wait for the line's check; the controller's error, ``None`` if it was accepted
        (or unchecked).

        Parameters
        ----------
        timeout
            Seconds the check's reply may take (``None``: no limit).

        Returns
        -------
        ControllerError or None
            The error the controller reported for the line; ``None`` if it was accepted
            (or unchecked).

        Raises
        ------
        ControllerTimeoutError
            The check got no reply within ``timeout`` seconds.
        RequestAbortedError
            The check was lost to a resync.
        ConnectionLostError
            The link is gone.
        SettingNotAppliedError
            A set line's read-back shows another value than the one written.
        """
        return await self.protocol._error_of(self.submission, self.probe, self.check,
                                             timeout, self.proof)

    async def confirm(self, timeout: float | None) -> None:
        """Like :meth:`error`, but raise the controller's error (and forget the report).

        Parameters
        ----------
        timeout
            Seconds the check's reply may take (``None``: no limit).

        Raises
        ------
        ControllerError
            The controller reported an error for the line.
        SettingNotAppliedError
            A set line's read-back shows another value than the one written.
        ControllerTimeoutError, RequestAbortedError, ConnectionLostError
            The check itself was lost (see :meth:`error`).
        """
        error = await self.error(timeout)
        if error is not None:
            self.forget()
            raise error

    async def report(self) -> Completed:
        """Wait for the completion report (only when :attr:`expects_report`); cancelling
        the wait leaves the report awaited.

        Returns
        -------
        Completed
            The completion report.

        Raises
        ------
        RuntimeError
            The line expects no completion report.
        """
        completion = self.submission.completion
        if completion is None:
            raise RuntimeError(f"{self.command.line!r} expects no completion report")
        return await asyncio.shield(completion)

    @property
    def reported_letters(self) -> dict[str, str] | None:
        """The letters of the completion report if it has arrived (``None`` otherwise,
        and for the bare CR of autostatus 3)."""
        report = self.submission.completion
        if report is None or not report.done() or report.cancelled() or report.exception():
            return None
        letters = report.result().letters
        return None if letters is None else dict(letters)

    def forget(self) -> None:
        """Stop waiting for the completion report (refused, settled by polling...)."""
        self.protocol.forget_completion(self.submission)


#: Called with each unsolicited event, completion report and dropped line; the second
#: argument is the submission a completion belongs to (``None`` if unsolicited).
EventCallback = Callable[[Event, "Submission | None"], None]


class TangoProtocol(asyncio.Protocol):
    """Routes the controller's lines to awaiting requests, moves and the event callback.

    Parameters
    ----------
    autostatus
        The autostatus mode in force when the first line reaches the controller.
    context
        Controller state that shapes replies and validates lines (dims, axes, extmode).
    on_event
        Called with each unsolicited event, completion report and dropped line.
    on_lost
        Called once when the link is lost, with the transport's error.
    credit_limit
        Bytes written but not yet confirmed by a reply, at most (:mod:`tango_aio.flow`).
    marker_chunk
        Bytes of reply-less lines one credit marker confirms at most.
    reply_timeout
        Seconds a resync marker or keepalive read the protocol writes itself may take.
    dead_after
        Consecutive unanswered requests, with no line in between, that declare the link
        dead (at least 2).
    keepalive
        Seconds of silence after which an idle link is probed (``None``: never).
    separators
        Whether a separator is written between two requests whose replies look alike
        (:attr:`separators`).
    detect
        Whether the first resync runs :meth:`detect` instead (set by ``connect``).

    Raises
    ------
    ValueError
        ``reply_timeout`` or ``keepalive`` is not a positive number, or ``dead_after`` is
        less than 2.
    """

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
        #: (:mod:`tango_aio.session`); this class carries out what it decides.
        self.session = LinkSession(self.core, dead_after=dead_after, keepalive=keepalive,
                                   detect=detect)
        #: Time a resync marker or keepalive read the protocol writes itself may take.
        self.reply_timeout = reply_timeout
        self._keepalive_task: asyncio.Task[None] | None = None
        self._loop = asyncio.get_running_loop()
        #: The write queue, credit markers and separators (:mod:`tango_aio.scheduler`).
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
        #: controller may have restarted behind the link (:mod:`tango_aio.restart`).
        self.on_unanswered: Callable[[], None] | None = None
        self.on_restored: Callable[[int, int], None] | None = None
        self._quiet_timer: asyncio.TimerHandle | None = None
        self._collected: asyncio.Future[None] | None = None
        self._barrier_lock = asyncio.Lock()
        #: The hold taken when a restart was suspected (:meth:`hold_for_check`), until
        #: the read of the mode that checks for it takes it over.
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
        marker (:attr:`~tango_aio.core.HelpStyle.NONE`) and connect's exchanges: grown by
        the link's timing (:attr:`link`), so that a slow link's next reply is not
        taken for silence."""
        return self.session.quiet_interval

    @quiet_interval.setter
    def quiet_interval(self, seconds: float) -> None:
        self.session.quiet_interval = seconds

    def wire_paced(self, byte_seconds: float) -> None:
        """The link carries bytes at ``byte_seconds`` per byte or slower, both ways (the
        emulator's paced wire): a reply that starts before its request's bytes could have
        passed is not its reply (:func:`~tango_aio.linktiming.earliest_reply`). Not for a
        serial port's opened rate, which USB and PCI units do not keep (L10, L1645-1653).

        Parameters
        ----------
        byte_seconds
            Seconds per byte (:func:`~tango_aio.linktiming.byte_time`).
        """
        self.core.wire_seconds = byte_seconds

    @property
    def link(self) -> LinkTiming:
        """The link's timing: its byte time where the baud rate is known and the longest
        round trip connect's exchanges measured (the session's
        :attr:`~tango_aio.session.LinkSession.timing`)."""
        return self.session.timing

    def set_callbacks(self, on_event: EventCallback | None,
                      on_lost: Callable[[BaseException | None], None] | None) -> None:
        """Set where unsolicited events and the connection loss are reported.

        Parameters
        ----------
        on_event
            Called with each unsolicited event, completion report and dropped line.
        on_lost
            Called once when the link is lost, with the transport's error.
        """
        self._on_event = on_event
        self._on_lost = on_lost

    # -- connection ------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Called by asyncio when the link is up.

        Parameters
        ----------
        transport
            The link's transport.

        Raises
        ------
        TypeError
            The transport has no ``write``.
        """
        write = getattr(transport, "write", None)
        if not callable(write):
            raise TypeError(f"{type(transport).__name__} cannot write")
        self._writer = write
        self._transport = transport
        self.session.reply_heard(self._loop.time())
        if not self._connected.done():
            self._connected.set_result(None)
        if self.keepalive is not None and self._keepalive_task is None:
            self._keepalive_task = self._loop.create_task(
                self._keep_alive(), name="tango_aio keepalive")
        if self._closing:
            # close() ran first (e.g. a cancelled connect(): a serial transport reports
            # connection_made one loop iteration after it was created): do not leak it.
            transport.close()

    async def wait_connected(self) -> None:
        """Wait until :meth:`connection_made` has run."""
        await self._connected

    def eof_received(self) -> bool | None:
        """Called by asyncio when the other end closed a stream (TCP): close as well.

        Returns
        -------
        None
            The transport closes itself.
        """
        self._peer_eof = True
        return None

    def connection_lost(self, exc: Exception | None) -> None:
        """Called by asyncio when the link is gone: fail everything that waits.

        The error's ``__cause__`` is ``exc``; when the other end closed the link without
        an error, a :class:`ConnectionResetError` saying so stands in for it.

        Parameters
        ----------
        exc
            The transport's error (``None``: closed without one).
        """
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
        caller's request is in flight (closing fails that one anyway).

        Parameters
        ----------
        timeout
            Seconds to wait at most.
        """
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
        with its message and cause (used when an automatic reconnect gives up).

        Parameters
        ----------
        error
            Why the link will not come back.
        """
        if self._lost is not None:
            self._lost = error

    def check(self) -> None:
        """Raise the connection error if the link is gone; raise
        :class:`WrongEventLoopError` when called from another event loop than the one the
        link was opened on (its callbacks run there; a future made here would never be
        resolved).

        Raises
        ------
        WrongEventLoopError
            Called from another event loop than the link's.
        ConnectionLostError
            The link is gone, or was never made.
        """
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

    # -- intents: what the Controller asks for ----------------------------------------

    @property
    def autostatus(self) -> int:
        """The autostatus mode in force after the last line written (known for certain
        after :meth:`read_autostatus` and after every mode change through
        :meth:`execute`)."""
        return self.core.autostatus

    @property
    def context(self) -> Context:
        """Controller state that shapes replies and validates lines (dims, axes, extmode)."""
        return self.core.context

    @context.setter
    def context(self, context: Context) -> None:
        self.core.context = context

    @property
    def moves_awaiting(self) -> tuple[Hashable, ...]:
        """Tags of the moves still waiting for their completion report, oldest first (pass
        them to :meth:`fail_completions`)."""
        return tuple(self.core.awaiting_completion)

    async def query(self, command: Command, *, timeout: float | None) -> Response:
        """Write the read ``command`` and return its reply lines.

        Parameters
        ----------
        command
            The read.
        timeout
            Seconds the reply may take (``None``: no limit).

        Returns
        -------
        Response
            The reply, its data lines in :attr:`Response.lines`.

        Raises
        ------
        ControllerTimeoutError
            No reply within ``timeout`` seconds (the stream is resynchronised).
        """
        return await self.request(command, timeout)

    async def execute(self, command: Command, *, timeout: float | None,
                      check: bool = True) -> Response:
        """Write a set/execute line and wait until it is confirmed.

        With ``check`` the controller's verdict is read right behind it (the autostatus-2
        acknowledgement, else an ``?err`` probe written back to back with the line) and an
        error raises the typed :class:`~tango_aio.errors.ControllerError`. Lines that owe
        a completion report go through :meth:`start_move` instead.

        Parameters
        ----------
        command
            The set/execute line.
        timeout
            Seconds its confirmation may take (``None``: no limit).
        check
            Whether the controller's verdict is read and an error raised.

        Returns
        -------
        Response
            What the line got back (empty for a mode change).

        Raises
        ------
        UnknownControllerError
            A mode change left the controller in another mode (that mode is adopted).
        ControllerError
            With ``check``: the controller reported an error for the line.
        ControllerTimeoutError
            The confirmation got no reply within ``timeout`` seconds.
        """
        if command.name == "autostatus" and command.form is Form.SET and command.values:
            return await self._change_mode(command, int(command.values[0]), timeout)
        handle = self._send_checked(command, check)
        await handle.confirm(timeout)
        return handle.submission.response

    async def _change_mode(self, command: Command, mode: int, timeout: float | None
                           ) -> Response:
        """A mode change is a barrier: every line before it is answered before it is
        written. Whether ``!autostatus n`` is echoed (mode 4 echoes before or after
        executing?) or acknowledged (per the old or the new mode?), and whether mode 2
        acknowledges reads, the manual leaves open (L2079-2161): see
        :meth:`_mode_exchange`. A controller that kept another mode raises
        :class:`~tango_aio.errors.UnknownControllerError`; that mode is adopted.

        Returns
        -------
        Response
            An empty response.

        Raises
        ------
        UnknownControllerError
            The controller kept another mode.
        """
        _, actual = await self._mode_exchange([command.line], timeout)
        if self.session.mode_changed(mode, actual) is ModeVerdict.KEPT_ANOTHER:
            raise UnknownControllerError(None, command.line)
        return Response()

    async def _mode_exchange(self, lines: list[str], timeout: float | None, *,
                             restore: bool = False) -> tuple[int, int]:
        """Once every line before is answered (later lines wait), write ``lines``,
        ``?autostatus`` and ``?help`` with the core dropping every line; collect what
        comes back up to the reply of ``?help`` (``ERROR n,text``, L2915) and a quiet
        :attr:`quiet_interval` (in modes 2 and 4 only:
        :func:`~tango_aio.session.nothing_trails_help`). The session reads the mode in
        force (adopted before the lines held behind the exchange are written) and, in
        mode 2, how reads are acknowledged from those lines
        (:meth:`~tango_aio.session.LinkSession.mode_read`).

        With ``restore``, a mode found that is not the driver's (the controller
        restarted, :meth:`~tango_aio.session.LinkSession.mode_verified`) is replaced by
        the driver's in a second exchange before any held line goes out: those lines
        were submitted for the driver's mode (a mode-2 move relies on its ``OK...``),
        so they are written in it.

        Returns
        -------
        tuple of (int, int)
            The mode the driver had in force once every line before was answered, and the
            mode in force (with ``restore``: the mode found, before it was replaced).

        Raises
        ------
        ControllerTimeoutError
            The lines before got no reply within ``timeout`` seconds.
        UnknownControllerError
            With ``restore``: the controller kept another mode (that mode is adopted).
        """
        sent = self.session.mode_lines(lines)
        async with self._barrier_lock:
            early, self._check_hold = self._check_hold, None
            hold = early if restore and early is not None else self.scheduler.hold()
            try:
                if not await self._idle(hold, timeout):
                    if not self.session.barrier_overdue_resyncs(restore=restore):
                        raise ControllerTimeoutError(
                            f"the lines before {sent[0]!r} got no reply within {timeout} s")
                    await self._resync_held(hold, timeout)
            except BaseException:
                self.scheduler.release()
                self._flush()
                raise
            driver = self.core.autostatus  # the driver's, once all is answered
            found: list[int] = []

            def adopt(received: Exchange, sent: list[str]) -> bool:
                # Before the lines held behind the exchange go out: the core encodes
                # them in the mode found (a move written in mode 1 owes no OK...).
                found.append(self.session.mode_read(sent, received.lines))
                self.scheduler.reproject()
                return restore and len(found) == 1 and self.session.mode_verified(
                    driver, found[0]) is ModeVerdict.RESTARTED

            try:
                await self._exchange(sent, timeout, Until.HELP,
                                     adopt=functools.partial(adopt, sent=sent))
                if restore and self.session.mode_verified(
                        driver, found[0]) is ModeVerdict.RESTARTED:
                    again = self.session.mode_lines(
                        [build("autostatus", driver, form=Form.SET).line])
                    await self._exchange(again, timeout, Until.HELP,
                                         adopt=functools.partial(adopt, sent=again))
            finally:
                self.scheduler.release()  # (a no-op unless a restore did not start)
                self._flush()
        self._heard()
        if restore and len(found) == 2 and self.session.mode_changed(
                driver, found[1]) is ModeVerdict.KEPT_ANOTHER:
            raise UnknownControllerError(None, f"!autostatus {driver}")
        return driver, found[0]

    async def _idle(self, hold: int, timeout: float | None) -> bool:
        """Wait until every line up to ``hold`` (:meth:`Scheduler.hold
        <tango_aio.scheduler.Scheduler.hold>`: later lines are held) is written and
        answered (polled: mode changes are rare).

        Returns
        -------
        bool
            Whether they were; false if that took more than ``timeout`` seconds.

        Raises
        ------
        RequestAbortedError
            Ctrl+C discarded the queued lines: the mode change is not sent.
        """
        dropped = self._queue_drops
        deadline = None if timeout is None else self._loop.time() + timeout
        while (barrier := self.session.barrier(
                queued_before=self.scheduler.queued_up_to(hold),
                queue_dropped=self._queue_drops != dropped)) is not Barrier.CLEAR:
            self.check()
            if barrier is Barrier.ABORTED:
                raise RequestAbortedError(
                    "the mode change was not sent: the stream was resynchronised")
            if deadline is not None and self._loop.time() >= deadline:
                return False
            await asyncio.sleep(0.002)
        return True

    async def _resync_held(self, hold: int, timeout: float | None) -> None:
        """The lines up to ``hold`` went unanswered: resync (their callers get
        :class:`~tango_aio.errors.RequestAbortedError`) while the later lines stay held,
        then wait for the lines up to ``hold`` once more.

        Raises
        ------
        ControllerTimeoutError
            The marker, or the lines before, got no reply within ``timeout`` seconds.
        """
        limit = timeout if timeout is not None else self.reply_timeout
        marker = self._background_resync(limit)
        try:
            if marker is not None:
                async with asyncio.timeout(limit):
                    await asyncio.shield(marker)
        except TimeoutError:
            raise ControllerTimeoutError(
                f"the resync marker got no reply within {limit} s") from None
        if not await self._idle(hold, timeout):
            raise ControllerTimeoutError(
                f"the lines before a read of the mode got no reply within {timeout} s")

    def start_move(self, command: Command, *, check: bool = True,
                   batch: object | None = None) -> MoveHandle:
        """Write a motion line (and its check) and return its :class:`MoveHandle`: await
        :meth:`MoveHandle.confirm`, then :meth:`MoveHandle.report`. ``batch``: the line
        and its check join the batch of the line submitted right before them (see
        :meth:`submit`; the caller treats the lines as one, e.g. a ``move_by`` whose start
        ``?pos`` fails is stopped and fails).

        Parameters
        ----------
        command
            The motion line.
        check
            Whether the controller's verdict is read (the autostatus-2 acknowledgement,
            else an ``?err`` probe written back to back with the line).
        batch
            The batch the line and its check join, if any.

        Returns
        -------
        MoveHandle
            The line's handle.
        """
        return self._send_checked(command, check, batch)

    def _send_checked(self, command: Command, check: bool,
                      batch: object | None = None) -> MoveHandle:
        submission = self.submit(command, hold=True, batch=batch)
        probe = None
        proof = None
        if check and not submission.expectation.ack:
            # Written back to back with the command, so no other line can change the
            # error state in between (each instruction overwrites it, manual L2853): a
            # separator the probe needs goes before the command.
            probe = self.submit(_PROBE, hold=True, batch=batch)
            if submission.owes is None:
                submission.guard, probe.guard = probe.owes, None
            if not submission.expectation.echo:
                # No answer of its own (autostatus 0, 1, 3): the probe's 0 is also what a
                # lost line gets, so a set is proven by reading its setting behind it.
                back = read_back(command, self.core.context)
                if back is not None:
                    proof = (back, self.submit(back.read, hold=True, batch=batch))
        self._flush()
        return MoveHandle(self, submission, probe, check, proof)

    async def _error_of(self, submission: Submission, probe: Submission | None, check: bool,
                        timeout: float | None,
                        proof: tuple[ReadBack, Submission] | None = None
                        ) -> ControllerError | None:
        line = submission.command.line
        if submission.reply is not None:
            response = await self.wait_reply(submission, timeout)
            if check and submission.expectation.ack:
                code = _judged(response.ack_line, response.deferred, line) \
                    if response.ack_line is not None else response.ack
                if code != 0:
                    return _ack_error(code, submission)
        if probe is not None:
            reply = await self.wait_reply(probe, timeout)
            code = _judged(reply.lines[0], True, line)
            if code:
                return controller_error(code, line)
        if proof is not None:
            back, read = proof
            _judge(back, (await self.wait_reply(read, timeout)).lines)
        return None

    def answers(self, command: Command) -> bool:
        """Whether ``command`` owes an answer of its own in the mode in force (the
        autostatus-2 ``OK...``, the autostatus-4 echo), which proves that it arrived.

        Parameters
        ----------
        command
            A set or execute line.

        Returns
        -------
        bool
            Whether it is acknowledged or echoed.
        """
        expect = expectation(command, self.core.autostatus, self.core.context)
        return expect.ack or expect.echo

    async def prove_set(self, command: Command, timeout: float | None) -> None:
        """Read the setting the set line ``command`` wrote, where the line owes no answer
        of its own (autostatus 0, 1, 3), and raise unless the reply shows the value (see
        :mod:`tango_aio.readback`; no read: nothing to do). For a line whose ``?err``
        answered only a standing internal error (L2853-2867), which proves nothing.

        Parameters
        ----------
        command
            The set line, already written and answered.
        timeout
            Seconds the read may take (``None``: no limit).

        Raises
        ------
        SettingNotAppliedError
            The read shows another value.
        """
        expect = expectation(command, self.core.autostatus, self.core.context)
        back = None if expect.ack or expect.echo else read_back(command, self.core.context)
        if back is not None:
            _judge(back, (await self.query(back.read, timeout=timeout)).lines)

    async def stop_soft(self, *, axes: Sequence[str] = ()) -> None:
        """Stop every axis with ``a`` (queued lines stay), or with ``axes`` one ``a x``
        per axis, stopping only those (L6785-6844). Returns once the lines are queued.

        Parameters
        ----------
        axes
            The axes to stop (empty: every axis).
        """
        for axis in axes:
            self.submit(build("a", form=Form.SET, axis=axis))
        if not axes:
            self.submit(_SOFT_STOP)

    async def stop_hard(self, *, timeout: float = 5.0) -> None:
        """Stop every axis with Ctrl+C, which also makes the controller discard its input
        buffer (L6808-6814): requests in flight fail with
        :class:`~tango_aio.errors.RequestAbortedError`, the stream is resynchronised and
        the mode in force is read again (a discarded line may have changed it). Returns
        once the stream is in step.

        Parameters
        ----------
        timeout
            Seconds the resync and the read of the mode may take, each.
        """
        await self.resync(ctrl_c=True, timeout=timeout)
        await self.read_autostatus(timeout=timeout)

    async def read_autostatus(self, *, timeout: float | None, status: bool = False) -> int:
        """Read the mode in force and adopt it; return it. Any mode may be in force (an
        earlier session's), and how reads are answered in it is not known yet: read the
        way a mode change is confirmed (:meth:`_mode_exchange`).

        Parameters
        ----------
        timeout
            Seconds the exchange may take (``None``: no limit).
        status
            Also write ``?statusaxis`` in front, and record in :attr:`detected` how its
            reply ends (``status_tail``, :func:`~tango_aio.session.status_tail`): the
            exchange sees the raw lines, which the core would route a reply shaped like
            a completion report away from.

        Returns
        -------
        int
            The mode in force.
        """
        return (await self._mode_exchange([STATUS_READ] if status else [], timeout))[1]

    # -- liveness and the mode -----------------------------------------------------------

    async def _keep_alive(self) -> None:
        """While the link is idle, read ``?autostatus`` after :attr:`keepalive` seconds
        without a reply (:meth:`~tango_aio.session.LinkSession.keepalive_wait`): an
        unanswered probe counts towards declaring the link dead
        (:meth:`_unanswered`), and a mode other than the one in force means the controller
        restarted behind an adapter that stayed up (it restores the mode)."""
        session = self.session
        while self._lost is None:
            busy = bool(self._submissions or self.scheduler.queued or self._markers
                        or self.core.pending_tags or self._barrier_lock.locked())
            wait = session.keepalive_wait(self._loop.time(), busy=busy)
            if wait > 0:
                await asyncio.sleep(wait)
                continue
            with contextlib.suppress(TangoError):
                await self.verify_autostatus(timeout=self.reply_timeout)
            session.keepalive_probed(self._loop.time())

    def hold_for_check(self) -> None:
        """A restart is suspected: hold every line submitted from now on until the read
        of the mode that checks for it (:meth:`verify_autostatus`) has run, so that the
        call after the one that met the restart is not written in a mode the controller
        may no longer have (back in mode 1, L2062, it leaves the acknowledgement or echo
        of modes 2 and 4 unsent, L2099-2117). Nothing is done while a barrier holds
        lines already; :meth:`release_check_hold` ends a hold no read took over."""
        if self._check_hold is None and not self._barrier_lock.locked():
            self._check_hold = self.scheduler.hold()

    def release_check_hold(self) -> None:
        """Let the lines held by :meth:`hold_for_check` go, if no read of the mode took
        the hold over."""
        if self._check_hold is not None:
            self._check_hold = None
            self.scheduler.release()
            self._flush()

    async def verify_autostatus(self, *, timeout: float | None) -> bool:
        """Read the mode in force (the way a mode change is confirmed, so that whatever
        the controller's mode, its reply is understood) and compare it with the mode the
        driver has in force; if they differ (the controller restarted: power-on mode 1,
        L2062), restore the driver's mode before any later line.

        Parameters
        ----------
        timeout
            Seconds each exchange may take (``None``: no limit).

        Returns
        -------
        bool
            Whether the mode had to be restored.
        """
        expected, actual = await self._mode_exchange([], timeout, restore=True)
        if self.session.mode_verified(expected, actual) is ModeVerdict.IN_FORCE:
            return False
        log.warning("the controller was in autostatus %d, the driver had %d in force: it "
                    "restarted; autostatus %d restored", actual, expected, expected)
        if self.on_restored is not None:
            self.on_restored(actual, expected)
        return True

    # -- writing ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        # Duck-typed: uvloop's TCP transport is no asyncio.WriteTransport subclass;
        # every transport asyncio hands to a stream protocol has write().
        write = self._writer
        if write is None:
            raise ConnectionLostError("not connected")
        if wire_log.isEnabledFor(logging.DEBUG):
            for line in data.split(b"\r")[:-1]:
                wire_log.debug("%.6f -> %s", time.monotonic(), _traced(line))
        write(data)

    def _trace_received(self, data: bytes) -> None:
        """Log each complete received line (CR removed) on the ``tango_aio.wire`` logger."""
        if not wire_log.isEnabledFor(logging.DEBUG):
            self._trace_buffer = b""
            return
        *lines, self._trace_buffer = (self._trace_buffer + data).split(b"\r")
        for line in lines:
            wire_log.debug("%.6f <- %s", time.monotonic(), _traced(line))
        if len(self._trace_buffer) > TRACE_LINE:
            wire_log.debug("%.6f <- %s (no CR yet)", time.monotonic(),
                           _traced(self._trace_buffer))
            self._trace_buffer = b""

    def submit(self, command: Command, *, batch: object | None = None,
               hold: bool = False) -> Submission:
        """Queue ``command`` for writing and return its :class:`Submission` (futures for
        the reply and the completion report, where the line owes them).

        The line is written at once when the credit allows, else as soon as replies free
        enough credit; lines are always written in submission order. A line whose reply
        could be taken for the reply of the line written before it gets a separator
        first, unless both belong to the same ``batch`` (see :mod:`tango_aio.patterns`).

        Parameters
        ----------
        command
            The line.
        batch
            Lines of one batch get no separator between them (``None``: no batch).
        hold
            Whether to leave the writing to the caller's next flush (lines that belong
            together are queued first).

        Returns
        -------
        Submission
            The line's submission.

        Raises
        ------
        ConnectionLostError
            The link is gone.
        InvalidCommandError
            The line holds a control or non-ASCII character.
        """
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
        instead of one per line).

        Parameters
        ----------
        commands
            The lines, in order.
        separate_after
            Whether a separator follows the last one in the same write (see
            :attr:`~tango_aio.scheduler.Line.separate_after`).

        Returns
        -------
        list of Submission
            Their submissions, in order.
        """
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
        """The write-credit account (see :mod:`tango_aio.flow`)."""
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
        """Take lines that are still queued out of the queue; return how many were.

        Their futures are cancelled. Lines already written are not affected.

        Parameters
        ----------
        submissions
            The lines (submissions or runs) to take back.

        Returns
        -------
        int
            How many were still queued.
        """
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
        blob, not one object per line (:class:`~tango_aio.scheduler.Run`); ``None`` when
        a line would owe something in the mode in force (then :meth:`submit` each).

        Parameters
        ----------
        commands
            The lines, in order.
        batch
            The batch the lines belong to, if any.

        Returns
        -------
        Run or None
            The run; ``None`` when a line owes something.

        Raises
        ------
        InvalidCommandError
            A line holds a control or non-ASCII character.
        """
        for command in commands:
            check_framing(command)
        return self.scheduler.pack(commands, batch)

    def pack_lines(self, template: Command, lines: Sequence[bytes], *,
                   batch: object | None = None) -> Run | None:
        """:meth:`pack` for list entries given as bytes, each a line of ``template``'s
        instruction and form (:func:`~tango_aio.instructions.encode_rows`), framing
        checked on the whole blob (:meth:`~tango_aio.scheduler.WriteScheduler.pack_lines`).

        Parameters
        ----------
        template
            A line of the entries' instruction and form.
        lines
            The encoded lines, each CR-terminated.
        batch
            As for :meth:`pack`.

        Returns
        -------
        Run or None
            As for :meth:`pack`.

        Raises
        ------
        InvalidCommandError
            A line holds a control or non-ASCII character, or the blob is not one line
            per entry.
        """
        check_framing(template)
        run = self.scheduler.pack_lines(template, lines, batch)
        if run is not None:
            check_rows_framing(template, run.blob, len(run))
        return run

    def submit_run(self, run: Run) -> Run:
        """Queue a run from :meth:`pack`. On the wire the same bytes, credit markers and
        separators as one :meth:`submit` per line; :meth:`withdraw` takes back the lines
        of the run not yet written.

        Parameters
        ----------
        run
            The run, from :meth:`pack` or :meth:`pack_lines`.

        Returns
        -------
        Run
            The same run.

        Raises
        ------
        ConnectionLostError
            The link is gone.
        """
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

    async def request(self, command: Command, timeout: float | None = 5.0) -> Response:
        """Write ``command`` and wait for its reply (an empty Response if it owes none).

        On timeout the stream is resynchronised and :class:`ControllerTimeoutError` raised.

        Parameters
        ----------
        command
            The line.
        timeout
            Seconds the reply may take (``None``: no limit).

        Returns
        -------
        Response
            The reply (empty if the line owes none).

        Raises
        ------
        ControllerTimeoutError
            No reply within ``timeout`` seconds.
        """
        submission = self.submit(command)
        if submission.reply is None:
            return submission.response
        return await self.wait_reply(submission, timeout)

    async def wait_reply(self, submission: Submission, timeout: float | None) -> Response:
        """Wait for ``submission``'s reply.

        After ``timeout`` seconds raise :class:`ControllerTimeoutError` naming the line,
        at once: the reply may be lost for good, so a resync starts in the background
        (its marker gets ``timeout`` too) and holds the lines queued behind it until the
        stream is in step. The timeout counts towards declaring a dead link lost
        (:meth:`_unanswered`); then :class:`ConnectionLostError` is raised instead, with
        the timeout as its cause.

        Parameters
        ----------
        submission
            The submission whose reply is awaited (it owes one).
        timeout
            Seconds from now the reply may take (``None``: no limit); a line that was
            still queued when the wait began and went out during it gets them once more,
            from then.

        Returns
        -------
        Response
            Its echo, data lines and acknowledgement.

        Raises
        ------
        ControllerTimeoutError
            No reply within ``timeout`` seconds.
        ConnectionLostError
            The link is gone, or this timeout declared it dead.
        """
        reply = submission.reply
        assert reply is not None
        queued = not submission.written
        if not reply.done():
            await _until_done(reply, timeout, submission)
            if not reply.done():
                return await self._reply_overdue(submission, reply, queued, timeout)
        return reply.result()

    async def _reply_overdue(self, submission: Submission, reply: asyncio.Future[Response],
                             queued: bool, timeout: float | None) -> Response:
        """``submission``'s reply did not come within ``timeout``: do what the session
        says (:meth:`~tango_aio.session.LinkSession.reply_overdue`), waiting once more if
        it says so.

        Returns
        -------
        Response
            The reply, when it came during a second wait.

        Raises
        ------
        ControllerTimeoutError
            No reply in time.
        ConnectionLostError
            The link is gone, or this timeout declared it dead.
        """
        waits = 1
        while (overdue := self.session.reply_overdue(
                queued=queued, written=submission.written, waits=waits,
                awaited=self._awaited())) is Overdue.WAIT_AGAIN:
            await _until_done(reply, timeout, submission)
            if reply.done():
                return reply.result()
            waits += 1
        self.check()
        error = ControllerTimeoutError(
            f"no reply to {submission.command.line!r} within {timeout} s")
        serial = submission.serial
        if overdue is not Overdue.UNANSWERED:
            self.withdraw([submission])
            if overdue is Overdue.WITHDRAW:
                raise error
            error = ControllerTimeoutError(
                f"no reply to {submission.command.line!r} within {timeout} s: it was not "
                "written, a reply owed before it did not come")
            serial = self.scheduler.written_lines  # the lines ahead of it
        if self._unanswered(error, serial) is Silence.DEAD:
            self.check()
        self._background_resync(timeout if timeout is not None else self.reply_timeout)
        raise error

    def _awaited(self) -> set[Hashable]:
        """The tags of the lines whose callers wait for their replies now."""
        return {tag for tag, s in self._submissions.items() if s.waiter is not None}

    def _unanswered(self, error: TangoError, serial: int, marker: Hashable | None = None
                    ) -> Silence:
        """Count a request (or marker) that got no reply in time; declare the link lost
        after :attr:`dead_after` in a row with no line at all in between (a link that stays
        open but no longer forwards: a serial-to-TCP adapter that stopped, a controller
        power-cycled behind one). ``serial`` numbers the line among those written: lines
        that were in flight together count once (they time out together when one reply is
        lost), so each count is a line written after the previous count. ``marker``: the
        tag of an overdue resync marker (the session may ask for a new one).

        Returns
        -------
        Silence
            What the session concluded (:attr:`~tango_aio.session.Silence.DEAD`: the link
            was declared lost).
        """
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
        resync starts.

        Returns
        -------
        asyncio.Future[Response] | None
            The marker's future; ``None``: the link is gone, nothing was written.
        """
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

    async def resync(self, *, ctrl_c: bool = False, timeout: float = 2.0) -> None:
        """Resynchronise the reply stream (optionally sending Ctrl+C first).

        Every pending request fails with :class:`RequestAbortedError`; the call returns
        when the marker's reply has arrived. The first resync of a link opened by
        ``connect`` runs :meth:`detect` instead.

        Parameters
        ----------
        ctrl_c
            Whether Ctrl+C goes first (it stops all axes and empties the controller's input
            buffer, L6808-6814).
        timeout
            Seconds the marker's reply may take.

        Raises
        ------
        ControllerTimeoutError
            The marker got no reply within ``timeout`` seconds.
        ConnectionLostError
            The link is gone, or this timeout declared it dead.
        """
        self.check()
        if self.session.detects_first(ctrl_c=ctrl_c):
            await self.detect(timeout=timeout)
            return
        tag, marker = self._begin_resync(ctrl_c)
        serial = self.scheduler.written_lines
        try:
            async with asyncio.timeout(timeout):
                await asyncio.shield(marker)
        except TimeoutError:
            self.check()
            error = ControllerTimeoutError(
                f"controller did not answer within {timeout} s the query sent to realign "
                f"its replies (resync marker)")
            if self._unanswered(error, serial) is Silence.DEAD:
                self.check()
            raise error from None
        finally:
            self._markers.pop(tag, None)

    # -- what this controller does where the manual is silent ---------------------------

    @property
    def detected(self) -> dict[str, str]:
        """What the driver found out about this controller: ``help_number``
        (``"yes"``: ``?help N`` answers ``ERROR N,text``; ``"no"``: the text only;
        ``"none"``: not at all), found by :meth:`detect` at connect; and, once seen,
        ``optional_echo`` / ``optional_ack``: how many echoes and acknowledgements arrived
        that the manual does not promise (a read echoed in mode 4 or acknowledged in mode
        2, a mode change echoed or acknowledged) and were tolerated."""
        found = dict(self.session.detected)
        for item, count in self.core.tolerated.items():
            found["optional_" + item.rstrip("?")] = str(count)
        return found

    async def detect(self, *, timeout: float) -> dict[str, str]:
        """Bring the stream in step without relying on a unique reply, then find out how
        ``?help N`` answers (the manual's editions differ: L2919, old L805-819), and make
        the markers accordingly.

        0. The quick way, for firmware that answers ``?help N`` with ``ERROR N,...``
           (1.71, L2919): ``help``, ``?help N`` twice and ``?err`` in one write (N a
           marker number no recent step 0 of this process used:
           :meth:`~tango_aio.session.LinkSession.begin_detect`; see
           :meth:`~tango_aio.session.LinkSession.numbered_marker_lines`), every line
           dropped.
           Their replies in a row put the stream in step, and the markers use N. Any
           other answer (the link then quiet for :attr:`quiet_interval`) proves
           nothing: steps 1 and 2 follow.
        1. A resync that needs no unique reply: ``help`` is written and every line is
           dropped until the last one looks like its reply (``ERROR n,text``, the form
           both editions document: L2915-2919, old L805-819) and the link has been quiet
           for :attr:`quiet_interval`.
        2. ``?help N`` then ``?err``. The lines before the ``?err`` number tell:
           ``ERROR N,...`` (firmware 1.71, L2919), the text alone (some firmware: then
           the markers use N and wait for that text), or nothing (older firmware, whose
           ``help`` takes no parameter: resyncs wait for quiet).

        Parameters
        ----------
        timeout
            Seconds each exchange may take.

        Returns
        -------
        dict of str to str
            What the driver found out (:attr:`detected`).
        """
        # The barrier lock keeps a keepalive's mode exchange from starting in between (one
        # exchange at a time: the session refuses a second).
        async with self._barrier_lock:
            code = self.session.begin_detect()
            lines, marker = self.session.numbered_marker_lines(code)
            if not self.session.numbered_read(
                    await self._exchange(lines, timeout, Until.MARKER, marker)):
                await self.resync(timeout=timeout)
                code = self.core.pick_marker_code()
                sent = self.session.help_lines(code)
                received = await self._exchange(sent, timeout, Until.NUMBER)
                self.session.help_read(code, sent, received.lines)
            self.session.end_detect()
        return self.detected

    async def _exchange(self, lines: list[str], timeout: float | None, until: Until,
                        marker: str | None = None, *,
                        adopt: Callable[[Exchange], bool] | None = None) -> Exchange:
        """Write ``lines`` with the core dropping every line; return what the session
        collected up to what ends the exchange (:class:`~tango_aio.session.Until`).
        Only call it when nothing is owed. ``adopt`` learns from the lines collected
        before the lines held behind the exchange are written; when it returns true,
        they stay held (the caller releases them).

        Returns
        -------
        Exchange
            The lines collected.
        """
        data = self.session.begin_exchange(lines, until, marker, now=self._loop.time())
        collected = self.session.exchange
        assert collected is not None
        self._collected = self._loop.create_future()
        in_step = keep = False
        try:
            self._write(data)
            serial = self.scheduler.exchanged(len(lines))
            try:
                async with asyncio.timeout(timeout):
                    await self._collected
            except TimeoutError:
                error = ControllerTimeoutError(f"no reply to {lines!r} within {timeout} s")
                self._collected = None
                self.session.exchange_timed_out()
                if self._unanswered(error, serial) is Silence.DEAD:
                    self.check()
                self._background_resync(timeout if timeout is not None
                                        else self.reply_timeout)
                raise error from None
            in_step = True
            keep = adopt is not None and adopt(collected)
        finally:
            self._collected = None
            if not keep:
                self.scheduler.release()
            if self._quiet_timer is not None:
                self._quiet_timer.cancel()
            ended = self.session.end_exchange(in_step=in_step)
            if ended is Outcome.RESYNC:
                self._background_resync(self.reply_timeout)
            elif ended is Outcome.IN_STEP:
                self.scheduler.in_step()
            self._flush()
        return collected

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
        still queued are dropped, or with ``keep_queue`` written after the marker.

        Returns
        -------
        tuple
            The marker's tag and the future its reply resolves.
        """
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
        """Stop waiting for ``submission``'s completion (e.g. the move was refused).

        Parameters
        ----------
        submission
            The move's submission.
        """
        for tag, known in list(self._submissions.items()):
            if known is submission:
                self.core.forget_completion(tag)
                if submission.reply is None or submission.reply.done():
                    del self._submissions[tag]
        _cancel(submission.completion)

    # -- receiving ------------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        """Called by asyncio with bytes from the controller.

        Parameters
        ----------
        data
            Bytes as they were read, any fragment of the stream.
        """
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
        """Fail every move still waiting for its completion report (or those of ``only``).

        Parameters
        ----------
        error
            The error their futures fail with.
        only
            Tags of the moves to fail (from :attr:`moves_awaiting`); ``None``: every move.
        """
        if only is None:
            tags = self.core.drop_completions()
        else:
            tags = [tag for tag in only if self.core.forget_completion(tag)]
        for tag in tags:
            submission = self._submissions.pop(tag, None)
            if submission is not None:
                _fail(submission.completion, error)
                _fail(submission.reply, error)


#: The check written behind a set/execute line.
_PROBE = parse("?err")
#: The soft stop (manual L6797).
_SOFT_STOP = build("a", form=Form.SET)


def _fail(future: asyncio.Future[Any] | None, error: BaseException) -> None:
    if future is not None and not future.done():
        future.set_exception(error)
        # Mark the exception retrieved: nobody may be awaiting a move's future any more.
        future.exception()


def _judged(reply: str, err: bool, line: str) -> int | None:
    """The error number a verdict on ``line`` gives; ``err``: the reply of an ``?err``
    (else an acknowledgement).

    Returns
    -------
    int | None
        0: accepted; else the error number (``None``: a bare ``ERR``).

    Raises
    ------
    GarbledVerdictError
        The reply is not a clean verdict: it proves nothing about the line.
    """
    verdict, code = err_verdict(reply) if err else ack_verdict(reply)
    if verdict is Verdict.GARBLED:
        raise GarbledVerdictError(line, reply)
    return code


def _ack_error(code: int | None, submission: Submission) -> ControllerError:
    line = submission.command.line
    return UnknownControllerError(None, line) if code is None else controller_error(code, line)


def _judge(back: ReadBack, lines: Sequence[str]) -> None:
    """Raise :class:`SettingNotAppliedError` unless the read-back's reply shows the value."""
    held = mismatch(back, lines)
    if held is not None:
        command = back.command
        raise SettingNotAppliedError(command.line, instruction=command.name, axis=command.axis,
                                     sent=" ".join(command.tokens), read=back.read.line,
                                     held=held)


#: Bytes of one line a wire-log record shows at most, so that a long line (or one whose
#: CR never comes) cannot make a record of any size; the rest is counted, not shown.
TRACE_LINE = 256


def _traced(line: bytes) -> str:
    """``repr`` of a traced line, cut at :data:`TRACE_LINE` bytes."""
    if len(line) <= TRACE_LINE:
        return repr(line)
    return f"{line[:TRACE_LINE]!r}... ({len(line)} bytes)"


async def _until_done(future: asyncio.Future[Any], timeout: float | None,
                      submission: Submission) -> None:
    """Wait until ``future`` (``submission``'s reply) is done or ``timeout`` seconds have
    passed, whichever comes first; cancelling the wait leaves ``future`` alone (it may
    have other waiters).

    The effect of ``asyncio.timeout`` around ``asyncio.shield``, with one helper future,
    one callback and one timer instead of a shield's future and two callbacks and a
    timeout context: this is the per-request path of every read. The protocol wakes the
    helper itself when it resolves the reply (:attr:`Submission.waiter`), in the same
    loop turn; the callback covers every other way the reply ends (failed, cancelled)."""
    loop = future.get_loop()
    waiter = loop.create_future()

    def wake(_: object = None) -> None:
        _wake(waiter)

    future.add_done_callback(wake)
    timer = None if timeout is None else loop.call_later(timeout, wake)
    previous, submission.waiter = submission.waiter, waiter
    try:
        await waiter
    finally:
        submission.waiter = previous
        future.remove_done_callback(wake)
        if timer is not None:
            timer.cancel()


def _wake(waiter: asyncio.Future[None] | None) -> None:
    if waiter is not None and not waiter.done():
        waiter.set_result(None)


def _cancel(future: asyncio.Future[Any] | None) -> None:
    if future is not None and not future.done():
        future.cancel()
