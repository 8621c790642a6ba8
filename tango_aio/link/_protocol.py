"""The asyncio protocol: connects the sans-IO core to a transport and to futures."""

from __future__ import annotations

import asyncio
import contextlib
import functools
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any

from ..catalog import Command, Context, Form, build, parse
from ..errors import (
    ControllerError,
    ControllerTimeoutError,
    GarbledVerdictError,
    RequestAbortedError,
    SettingNotAppliedError,
    TangoError,
    UnknownControllerError,
    WrongEventLoopError,
    controller_error,
)
from ..moves import Verdict, ack_verdict, err_verdict
from ..sansio import (
    DEAD_AFTER,
    STATUS_READ,
    Barrier,
    Completed,
    Exchange,
    ModeVerdict,
    Outcome,
    Overdue,
    ReadBack,
    Silence,
    Until,
    expectation,
    mismatch,
    read_back,
)
from ._router import (
    LineRouter,
    Response,
    Submission,
    _ack_error,
    _wake,
    log,
)

__all__ = ["DEAD_AFTER", "MoveHandle", "Response", "Submission", "TangoProtocol",
           "WrongEventLoopError"]


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
    #: its own (:func:`~tango_aio.sansio._readback.read_back`), and its submission.
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
        (or unchecked)."""
        return await self.protocol._error_of(self.submission, self.probe, self.check,
                                             timeout, self.proof)

    async def confirm(self, timeout: float | None) -> None:
        """Like :meth:`error`, but raise the controller's error (and forget the report)."""
        error = await self.error(timeout)
        if error is not None:
            self.forget()
            raise error

    async def report(self) -> Completed:
        """Wait for the completion report (only when :attr:`expects_report`); cancelling
        the wait leaves the report awaited."""
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


class TangoProtocol(LineRouter):
    """Routes the controller's lines to awaiting requests, moves and the event callback."""

    # -- connection ------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Called by asyncio when the link is up."""
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
        """Write the read ``command`` and return its reply lines."""
        return await self.request(command, timeout)

    async def execute(self, command: Command, *, timeout: float | None,
                      check: bool = True) -> Response:
        """Write a set/execute line and wait until it is confirmed."""
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
        :class:`~tango_aio.errors.UnknownControllerError`; that mode is adopted."""
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
        :func:`~tango_aio.sansio._session.nothing_trails_help`). The session reads the mode in
        force (adopted before the lines held behind the exchange are written) and, in
        mode 2, how reads are acknowledged from those lines
        (:meth:`~tango_aio.sansio._session.LinkSession.mode_read`)."""
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
        <tango_aio.sansio._scheduler.Scheduler.hold>`: later lines are held) is written and
        answered (polled: mode changes are rare)."""
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
        then wait for the lines up to ``hold`` once more."""
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
        ``?pos`` fails is stopped and fails)."""
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
        autostatus-2 ``OK...``, the autostatus-4 echo), which proves that it arrived."""
        expect = expectation(command, self.core.autostatus, self.core.context)
        return expect.ack or expect.echo

    async def prove_set(self, command: Command, timeout: float | None, *,
                        aborted: bool = False) -> bool:
        """Read the setting the set line ``command`` wrote, where the line owes no answer
        of its own (autostatus 0, 1, 3), and raise unless the reply shows the value (see
        :mod:`tango_aio.sansio._readback`; no read: nothing to do); return whether a read
        was made. For a line whose ``?err`` answered only a standing internal error
        (L2853-2867), which proves nothing; with ``aborted``, for a line whose answer a
        resync took (in every mode: its acknowledgement or echo is gone)."""
        expect = expectation(command, self.core.autostatus, self.core.context)
        owes = expect.ack or expect.echo
        back = None if owes and not aborted else read_back(command, self.core.context)
        if back is None:
            return False
        _judge(back, (await self.query(back.read, timeout=timeout)).lines)
        return True

    async def stop_soft(self, *, axes: Sequence[str] = ()) -> None:
        """Stop every axis with ``a`` (queued lines stay), or with ``axes`` one ``a x``
        per axis, stopping only those (L6785-6844). Returns once the lines are queued."""
        for axis in axes:
            self.submit(build("a", form=Form.SET, axis=axis))
        if not axes:
            self.submit(_SOFT_STOP)

    async def stop_hard(self, *, timeout: float = 5.0) -> None:
        """Stop every axis with Ctrl+C, which also makes the controller discard its input
        buffer (L6808-6814): requests in flight fail with
        :class:`~tango_aio.errors.RequestAbortedError`, the stream is resynchronised and
        the mode in force is read again (a discarded line may have changed it). Returns
        once the stream is in step."""
        await self.resync(ctrl_c=True, timeout=timeout)
        await self.read_autostatus(timeout=timeout)

    async def read_autostatus(self, *, timeout: float | None, status: bool = False) -> int:
        """Read the mode in force and adopt it; return it. Any mode may be in force (an
        earlier session's), and how reads are answered in it is not known yet: read the
        way a mode change is confirmed (:meth:`_mode_exchange`)."""
        return (await self._mode_exchange([STATUS_READ] if status else [], timeout))[1]

    # -- liveness and the mode -----------------------------------------------------------

    async def _keep_alive(self) -> None:
        """While the link is idle, read ``?autostatus`` after :attr:`keepalive` seconds
        without a reply (:meth:`~tango_aio.sansio._session.LinkSession.keepalive_wait`): an
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
        L2062), restore the driver's mode before any later line."""
        expected, actual = await self._mode_exchange([], timeout, restore=True)
        if self.session.mode_verified(expected, actual) is ModeVerdict.IN_FORCE:
            return False
        log.warning("the controller was in autostatus %d, the driver had %d in force: it "
                    "restarted; autostatus %d restored", actual, expected, expected)
        if self.on_restored is not None:
            self.on_restored(actual, expected)
        return True

    # -- requests and their replies --------------------------------------------------------

    async def request(self, command: Command, timeout: float | None = 5.0) -> Response:
        """Write ``command`` and wait for its reply (an empty Response if it owes none)."""
        submission = self.submit(command)
        if submission.reply is None:
            return submission.response
        return await self.wait_reply(submission, timeout)

    async def wait_reply(self, submission: Submission, timeout: float | None) -> Response:
        """Wait for ``submission``'s reply."""
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
        says (:meth:`~tango_aio.sansio._session.LinkSession.reply_overdue`), waiting once more if
        it says so."""
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

    async def resync(self, *, ctrl_c: bool = False, timeout: float = 2.0) -> None:
        """Resynchronise the reply stream (optionally sending Ctrl+C first)."""
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
           :meth:`~tango_aio.sansio._session.LinkSession.begin_detect`; see
           :meth:`~tango_aio.sansio._session.LinkSession.numbered_marker_lines`), every line
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
           ``help`` takes no parameter: resyncs wait for quiet)."""
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
        collected up to what ends the exchange (:class:`~tango_aio.sansio._session.Until`).
        Only call it when nothing is owed. ``adopt`` learns from the lines collected
        before the lines held behind the exchange are written; when it returns true,
        they stay held (the caller releases them)."""
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


#: The check written behind a set/execute line.
_PROBE = parse("?err")


#: The soft stop (manual L6797).
_SOFT_STOP = build("a", form=Form.SET)


def _judged(reply: str, err: bool, line: str) -> int | None:
    """The error number a verdict on ``line`` gives; ``err``: the reply of an ``?err``
    (else an acknowledgement)."""
    verdict, code = err_verdict(reply) if err else ack_verdict(reply)
    if verdict is Verdict.GARBLED:
        raise GarbledVerdictError(line, reply)
    return code


def _judge(back: ReadBack, lines: Sequence[str]) -> None:
    """Raise :class:`SettingNotAppliedError` unless the read-back's reply shows the value."""
    held = mismatch(back, lines)
    if held is not None:
        command = back.command
        raise SettingNotAppliedError(command.line, instruction=command.name, axis=command.axis,
                                     sent=" ".join(command.tokens), read=back.read.line,
                                     held=held)


async def _until_done(future: asyncio.Future[Any], timeout: float | None,
                      submission: Submission) -> None:
    """Wait until ``future`` (``submission``'s reply) is done or ``timeout`` seconds have
    passed, whichever comes first; cancelling the wait leaves ``future`` alone (it may
    have other waiters)."""
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
