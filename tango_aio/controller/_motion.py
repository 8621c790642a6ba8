"""Awaitable motion: completion, confirmation, timeouts, cancel and detached moves.

   * ``!joy 0`` sends ``@@@-.`` while the axes may still run (L2093, L7154);
   * ``!pause`` delays the report after the axes stopped (L6873-6899), so a report may
     arrive after the move was already settled by polling and be taken for the next one;
   * the ``a`` instruction may send a report of its own (older firmware, old L725);
   * an older unit may leave absent axes out of the report, so the letters cannot be
     assigned to axes (the report ``@S.`` says nothing certain about Y).

3. Each hint is *confirmed* by reading the state: ``?statusaxis`` (the manual's way to
   poll a move, L2662-2721: every letter except ``M`` means the axis stopped) and
   ``?pos``, written back to back (one round trip: their replies, letters and numbers,
   cannot be taken for each other, so neither waits for the other), the position checked
   against the target for ``move_to``/``move_by``. The letters come first: an axis that
   reads stopped stays where it stopped until the position is read right behind them.
   This read is as short as the unit allows: ``sa`` (the 1.71 alias, L2663) for
   the letters, and ``?pos x`` for a move of one axis X, so that a tile step pays
   ``sa`` and ``?pos x`` (10 bytes out with their CRs, 14 back) instead of
   ``?statusaxis`` and ``?pos`` (17 out, 28 back on three axes); see
   ``Controller._status_and_positions``. A move succeeds only when every
   moved axis reads neither ``M`` nor a failure letter (``E``, ``S``, ``T``, L2689-2711)
   and stands within :func:`~tango_aio.moves._timing.position_tolerance` of its target (the
   verdict is :func:`tango_aio.moves._timing.verdict`). An axis that stopped
   elsewhere (cut short) or with a failure letter ends the move with :class:`MoveError`
   at once (a limit switch, an abort, a disabled axis), unless the driver knows a
   reason why the read may come too early: a move that has not started yet
   (``!delay``, L6845-6868) can read like the previous state until the delay is over,
   and an axis may still settle in closed loop (``ctrt``, L11616-11631) until the
   expected end (:func:`tango_aio.moves._timing.too_early`). In a move of several axes, one
   that reads a failure letter while the others still move ends the move too
   (:func:`tango_aio.moves._timing.cut_short`): the others are stopped and the error names
   every axis; their report would come only once all of them stand.
4. A move during which the driver itself stopped one of its axes (``a``, ``a x`` or
   Ctrl+C) never succeeds, whatever letters are reported: the "stop epoch" counts the
   driver's stops per axis, and a move that saw the count of one of its axes change
   raises :class:`MoveError` once its axes stand still. (Older firmware reports axes
   stopped by ``a`` as ``@``, old L1917, so the letter alone cannot tell.) A one-axis
   stop (``a x``, L6785-6844: "aborts ... of all axes or of a specified axis") counts
   for that axis only: a move of other axes goes on and may succeed.

Timeouts
========
A move's time budget counts from the moment its line is written (a move waiting behind
another one does not spend it), and covers ``delay`` before the start (L6845-6868), the
travel (trapezoid at the slowest plausible speed), ``pause`` after it (L6873-6899) and
the closed-loop settling time ``ctrt`` (L11616-11631). When no report comes, the state is
polled from shortly after the expected end, with an interval that grows to
:data:`POLL_MAX` (in autostatus 0, which sends no reports, and for a move of several
axes, every :data:`POLL_MAX` during the move as well: an early end is seen within that,
:func:`tango_aio.moves._timing.polled_during`); the move fails with
:class:`ControllerTimeoutError` (axes stopped) when the budget is spent and an axis still
moves.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import logging
from collections.abc import Awaitable, Callable, Coroutine, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import NoReturn, Protocol

import anyio

from ..catalog import AXES, Command, Completion
from ..errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    GarbledVerdictError,
    MoveError,
    ProtocolError,
    RequestAbortedError,
    TangoError,
    outcome_unknown,
)
from ..events import MoveFinished
from ..link import MoveHandle, Submission
from ..moves import (
    POLL_MAX,
    POLL_MIN,
    Budget,
    Follow,
    Next,
    contest,
    describe_stop,
    failed_letters,
    optional_axes,
    report_shows_run,
    shifted_axes,
)
from ..sansio import Completed
from ..status import ABSENT, MOVING

__all__ = ["POLL_MAX", "POLL_MIN", "STOP_WAIT", "Motion", "MotionPort", "MovePlan",
           "annotate", "contested", "report_came"]

log = logging.getLogger("tango_aio")

#: Longest wait for the axes to stop after a cancelled or aborted move (seconds).
STOP_WAIT = 10.0

#: A state read that failed but left the link usable (ConnectionLostError is not one).
_LOST_READ = (RequestAbortedError, ControllerTimeoutError, ProtocolError)

_KINDS = {Completion.MOVE: "move", Completion.CAL: "cal", Completion.RM: "rm"}


@dataclass(frozen=True, slots=True)
class MovePlan:
    """What one motion line does and how long it may take."""

    command: Command
    #: The axes the line moves (every present axis for ``cal``/``rm`` without one).
    moved: tuple[str, ...]
    #: Absolute targets to confirm with ``?pos`` (``None``: cal, rm, moc have none).
    targets: Mapping[str, float] | None
    #: How long the line may take (:func:`~tango_aio.moves._timing.move_budget`): its expected
    #: end, its limit, its ``!delay`` (until then a stopped axis may be one that has not
    #: started yet) and its closed-loop settling (until the expected end an axis near its
    #: target may still be settling).
    budget: Budget
    #: Position tolerance per moved axis (``targets`` only).
    tolerance: Mapping[str, float] = field(default_factory=dict)
    #: Whether the mode in force sends completion reports (not autostatus 0, L2060-2103):
    #: without them the state is polled every :data:`POLL_MAX` during the move, so that
    #: an early end (a limit switch, an abort) ends the call at once too.
    reports: bool = True
    #: When ``limit`` was sized from a position read before this move (the last one the
    #: driver knows, see :attr:`Motion.positions`): seconds from now that the move may
    #: still take, given the positions printed now. Called once, when the axes still move
    #: at ``limit`` (``None``: ``limit`` is final).
    extend: Callable[[Mapping[str, str]], float] | None = None
    #: For a relative move whose start is read in the same write, right before its line
    #: (``move_by``): reads that start (as printed); ``targets`` then holds the distances
    #: until :meth:`resolved` adds them.
    start: Callable[[], Awaitable[Mapping[str, str]]] | None = None
    #: The protocol batch of that start read, which the line and its check join: no
    #: separator goes between them. A shifted reply among them cannot make a false
    #: success: a wrong start gives a wrong target, which the confirmation then misses.
    batch: object | None = None

    async def resolved(self) -> MovePlan:
        """The plan with absolute targets."""
        if self.start is None or self.targets is None:
            return self
        start = await self.start()
        if not set(self.targets) <= set(start):
            raise ProtocolError(f"?pos before {self.command.line!r} printed {dict(start)}")
        targets = {a: float(start[a]) + d for a, d in self.targets.items()}
        return replace(self, targets=targets, start=None, batch=None)

    @property
    def expected(self) -> float:
        """Seconds from writing the line to its expected end (delay + travel + pause)."""
        return self.budget.expected

    @property
    def limit(self) -> float:
        """Seconds from writing the line before the move is given up (timeout)."""
        return self.budget.limit

    @property
    def kind(self) -> str:
        """``"move"``, ``"cal"`` or ``"rm"`` (for :class:`MoveFinished`)."""
        completion = self.command.instruction.completion
        return _KINDS.get(completion, "move") if completion else "move"


class MotionPort(Protocol):
    """What :class:`Motion` needs from the controller facade: six intents, each one
    step of a move (the controller keeps the link, the settings and the subscribers)."""

    def start(self, command: Command, batch: object | None) -> MoveHandle:
        """Write a motion line and its check; return at once."""
        ...

    async def accepted(self, sent: MoveHandle) -> ControllerError | None:
        """Wait (up to the reply timeout) for the check of a line."""
        ...

    async def stop(self) -> None:
        """Write ``a`` (stop every axis, keep queued lines)."""
        ...

    def read_state(self, axes: Sequence[str]
                   ) -> Awaitable[tuple[dict[str, str], dict[str, str]]]:
        """Read the state: the letters and positions written back to back (see
        :meth:`Controller._status_and_positions
        <tango_aio.Controller._status_and_positions>`). The lines are
        submitted by the time the awaitable is first awaited (the controller's: when
        this is called, so that :meth:`Motion.reported` writes them in the loop turn the
        report arrived); one that is never awaited is a coroutine, closed unstarted."""
        ...

    def finished(self, event: MoveFinished) -> None:
        """A followed move has ended: hand its event to the subscribers."""
        ...

    def unreported(self) -> None:
        """A followed move ended short of its target and its completion report never
        came: the controller may have restarted (it loses the move and the report)."""
        ...


@dataclass(slots=True)
class _Job:
    """One motion line being followed."""

    plan: MovePlan
    sent: MoveHandle
    started: float
    #: The driver's stops of the moved axes when the line was written (see
    #: :meth:`Motion.epoch`).
    epoch: int
    #: The hint count when the state was last read (at first: when the line was written;
    #: a hint from before it says nothing about this move).
    hints: int
    #: When the line's check came back: the controller had taken the line by then, so
    #: its ``!delay`` ends at the latest :attr:`MovePlan.delay` later.
    checked: float = 0.0
    #: The state read :meth:`Motion.reported` wrote while this move waited for a hint.
    early: Awaitable[tuple[dict[str, str], dict[str, str]]] | None = None
    #: The positions the driver knew when the line was written (:attr:`Motion.positions`).
    before: dict[str, str] | None = None


class Motion:
    """Runs and follows the moves of one controller (serialised: one at a time)."""

    def __init__(self, port: MotionPort) -> None:
        self._port = port
        self._lock = asyncio.Lock()
        self._detached: asyncio.Task[None] | None = None
        #: Per axis, how often the driver stopped it (``a``, ``a x`` or Ctrl+C): the stop
        #: epoch.
        self._stops = dict.fromkeys(AXES, 0)
        #: How many hints (reports, stops, link changes) came so far.
        self._hints = 0
        self._wake = asyncio.Event()
        #: The submissions of the moves being followed.
        self._followed: set[Submission] = set()
        #: The positions (as printed) the driver read last, per axis (a confirmation reads
        #: only the moved axes, so the others may be older), ``None`` before the first.
        #: Only move timeouts are sized from them (see :meth:`Controller._plan
        #: <tango_aio.Controller._plan>`), never a target or a verdict.
        self.positions: dict[str, str] | None = None
        #: The positions of the latest read alone (the axes it read).
        self.latest: dict[str, str] | None = None
        #: The move waiting for a hint in :meth:`_follow` (its next step is a state read).
        self._waiting: _Job | None = None

    def saw(self, texts: Mapping[str, str]) -> None:
        """Record the positions of one read of some or all axes."""
        self.latest = dict(texts)
        self.positions = {**(self.positions or {}), **texts}

    # -- state seen by the facade ---------------------------------------------------------

    @property
    def busy(self) -> bool:
        """Whether a move of this driver is in flight (awaited or detached)."""
        return self._lock.locked() or (self._detached is not None
                                       and not self._detached.done())

    def follows(self, submission: Submission) -> bool:
        """Whether a line is a move this module follows (and confirms)."""
        return submission in self._followed

    def stopped(self, axes: Sequence[str] | None = None) -> None:
        """The driver stopped axes: no move in flight that moves one of them may succeed;
        wake every move."""
        for axis in AXES if axes is None else axes:
            self._stops[axis] += 1
        self.hint()

    def epoch(self, axes: Sequence[str]) -> int:
        """How often the driver stopped any of some axes so far."""
        return sum(self._stops.get(axis, 0) for axis in axes)

    def _was_stopped(self, job: _Job) -> bool:
        """Whether the driver stopped one of ``job``'s axes since its line was written."""
        return job.epoch != self.epoch(job.plan.moved)

    def reported(self) -> None:
        """A completion report arrived (matched or not): a :meth:`hint`. A move that waits
        for one reads the state next, whatever the report says; that read is written
        here, in the loop turn the report arrived, instead of once the move's task runs
        again (a loop turn and the wake-up later, on the path of every move)."""
        job = self._waiting
        if job is not None and job.early is None:
            try:
                job.early = self._port.read_state(job.plan.moved)
            except TangoError:
                pass  # the link is gone: the move's own read meets it after the wake
            else:
                job.hints = self._hints + 1  # this read comes after this hint
        self.hint()

    def hint(self) -> None:
        """Something happened that may have ended a move (a completion report, matched or
        not, a stop, a lost link): every move being followed re-reads the state."""
        self._hints += 1
        wake, self._wake = self._wake, asyncio.Event()
        wake.set()

    def cancel_detached(self) -> None:
        """Stop following a detached move (the connection is being closed)."""
        if self._detached is not None:
            self._detached.cancel()

    # -- running a move ------------------------------------------------------------------

    async def run(self, command: Command,
                  plan_for: Callable[[Command, Mapping[str, str] | None], Awaitable[MovePlan]],
                  stop_on_cancel: bool) -> dict[str, str]:
        """Write a motion line once no other move is in flight and follow it to its end."""
        async with self._lock:
            await self._join_detached()
            plan = await plan_for(command, self.positions)
            hints = self._hints
            job = _Job(plan, self._port.start(command, plan.batch),
                       asyncio.get_running_loop().time(), self.epoch(plan.moved), hints,
                       before=None if self.positions is None else dict(self.positions))
            try:
                return await self._run(job)
            except asyncio.CancelledError:
                if stop_on_cancel:
                    await self._stop_after_cancel(job)
                else:
                    self._detached = asyncio.ensure_future(self._finish_detached(job))
                raise

    async def _join_detached(self) -> None:
        """Wait until a detached move has ended. If this wait is cancelled, the detached
        move stays recorded, so the next move still waits for it."""
        while (detached := self._detached) is not None:
            await asyncio.shield(detached)
            if self._detached is detached:
                self._detached = None

    async def _run(self, job: _Job) -> dict[str, str]:
        self._followed.add(job.sent.submission)
        try:
            return await self._checked(job)
        finally:
            self._followed.discard(job.sent.submission)

    async def _checked(self, job: _Job) -> dict[str, str]:
        try:
            error = await self._port.accepted(job.sent)
            job.checked = asyncio.get_running_loop().time()
            if error is None:
                job.plan = await job.plan.resolved()
        except GarbledVerdictError as exc:
            await self._contest(job, exc)
        except _LOST_READ as exc:
            # The check (or the start of a move_by) was lost (Ctrl+C or a resync): the
            # move may or may not run. Stop it and fail: success is never assumed, and
            # the error says the line may have run (so that the caller does not retry
            # blindly).
            aborted = self._was_stopped(job)
            stopped = await self._stop_and_wait(job) is not None
            if aborted:
                await self._aborted(job, {})
            raise outcome_unknown(_with_stop(exc, job, stopped),
                                  job.sent.command.line) from exc.__cause__
        except ConnectionLostError as exc:
            raise outcome_unknown(exc, job.sent.command.line) from exc.__cause__
        if error is not None:
            await self._contest(job, error)
        try:
            letters = await self._follow(job)
        except _LOST_READ as exc:
            # The state could not be read (a call that raises never leaves the axes
            # it set moving): stop them and say so, or say that they may still move.
            stopped = await self._stop_and_wait(job) is not None
            raise _with_stop(exc, job, stopped) from exc.__cause__
        except ConnectionLostError as exc:
            job.sent.forget()
            raise _with_stop(exc, job, False) from exc.__cause__
        except BaseException:
            job.sent.forget()
            raise
        job.sent.forget()
        return letters

    async def _contest(self, job: _Job, cause: TangoError) -> NoReturn:
        """A refusal stands if none of the line's axes moves; else stop them and say so."""
        # (The verdict refused the line or made no sense: timing.contest judges the state.)
        line, moved = job.plan.command.line, job.plan.moved
        try:
            letters, texts = await self._state(moved)
        except _LOST_READ as exc:
            stopped = await self._stop_and_wait(job) is not None
            raise contested(cause, line, "the state could not be read behind it",
                            moved if stopped else (), () if stopped else moved) from exc
        completion = job.sent.submission.completion
        reported = report_came(completion) and completion is not None and \
            report_shows_run(moved, completion.result().letters)
        found = contest(moved, letters, clean=isinstance(cause, ControllerError),
                        reported=reported, shifted=shifted_axes(moved, job.before, texts))
        if found.stands:
            job.sent.forget()
            raise annotate(cause, found.reason) if found.reason else cause
        if found.moving and await self._stop_and_wait(job) is None:
            raise contested(cause, line, found.reason, (), found.moving)
        job.sent.forget()
        raise contested(cause, line, found.reason, found.moving, ())

    async def _follow(self, job: _Job) -> dict[str, str]:
        """Wait for hints and confirm them until the move has ended (see module doc)."""
        # The tracker's Follow judges each read; this carries out its intents.
        loop = asyncio.get_running_loop()
        plan = job.plan
        follow = Follow(plan.moved, plan.targets, plan.tolerance, plan.budget, job.started,
                        reports=plan.reports, extend=plan.extend,
                        optional=optional_axes(plan.command, plan.moved))
        follow.check_came(job.checked)
        while True:
            delay = follow.wake - loop.time()
            if delay > 0 and not self._was_stopped(job) and job.hints == self._hints:
                await self._wait_hint(job, delay)
            early, job.early = job.early, None
            if early is None:
                job.hints = self._hints  # hints from now on come after this state read
            follow.reading()
            texts: dict[str, str] = {}
            try:
                letters, texts = await self._state(plan.moved, early)
            except _LOST_READ:
                if not self._was_stopped(job):
                    raise
                # The driver's stop (e.g. an ignored Ctrl+C) disturbed the read.
                intent = follow.read_lost(loop.time(), stopped=True)
            else:
                report = job.sent.submission.completion
                intent = follow.read(
                    letters, texts, loop.time(), stopped=self._was_stopped(job),
                    report=report.result().letters if report_came(report) and report
                    else None,
                    report_owed=report is not None and not report.done())
            match intent.next:
                case Next.WAIT:
                    continue
                case Next.ARRIVED:
                    if intent.unreported:
                        log.warning("no completion report for %r; axes at the target, "
                                    "settled by polling ?statusaxis", plan.command.line)
                    self._finished(job, intent.letters, ok=True)
                    return dict(intent.letters)
                case Next.ABORTED:
                    return await self._aborted(job, dict(intent.letters))
                case Next.CUT_SHORT:
                    await self._cut_short(job, intent.ended, intent.letters, texts)
                case Next.TIMED_OUT:
                    await self._timed_out(job)
                case Next.FAILED:
                    self._finished(job, intent.letters, ok=False)
                    if intent.unreported:
                        self._port.unreported()
                    raise MoveError(f"{plan.command.line!r} {intent.message}",
                                    intent.letters)

    async def _wait_hint(self, job: _Job, delay: float) -> None:
        """Wait up to ``delay`` seconds for a hint; a read :meth:`reported` wrote meanwhile
        is left in ``job.early`` (and given up if the wait is cancelled)."""
        self._waiting = job
        try:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(delay):
                    await self._wake.wait()
        except BaseException:
            early, job.early = job.early, None
            if isinstance(early, Coroutine):
                early.close()  # never started: its replies are routed and dropped
            raise
        finally:
            self._waiting = None

    async def _state(self, axes: Sequence[str],
                     early: Awaitable[tuple[dict[str, str], dict[str, str]]] | None = None
                     ) -> tuple[dict[str, str], dict[str, str]]:
        """The status letters and the positions (``?statusaxis`` and ``?pos`` written back
        to back: one round trip), read again (up to 3 times) when the read was lost:
        discarded by a Ctrl+C resync, unanswered, or met by a line that is not its reply
        (the stream is resynchronised each time, so the next read is in step).
        ``early``: the first read, already written (:meth:`reported`)."""
        for _ in range(2):
            with contextlib.suppress(*_LOST_READ):
                read = early if early is not None else self._port.read_state(axes)
                early = None
                return self._remember(await read)
        return self._remember(await self._port.read_state(axes))

    def _remember(self, state: tuple[dict[str, str], dict[str, str]]
                  ) -> tuple[dict[str, str], dict[str, str]]:
        self.saw(state[1])
        return state

    async def _aborted(self, job: _Job, letters: dict[str, str]) -> dict[str, str]:
        """The driver stopped the axes during this move: wait until they stand still,
        then fail (never a success, whatever the letters say)."""
        texts: Mapping[str, str] = {}
        # After a one-axis stop (``a x``) the line's other axes go on to their targets:
        # wait for them within the move's own budget, at least STOP_WAIT.
        left = job.started + job.plan.limit - asyncio.get_running_loop().time()
        with contextlib.suppress(TimeoutError, *_LOST_READ):
            letters = await self._idle(job, max(STOP_WAIT, left))
            texts = self.positions or {}
        self._finished(job, letters, ok=False)
        plan = job.plan
        raise MoveError(
            f"{plan.command.line!r} was aborted: " + "; ".join(
                describe_stop(a, letters.get(a, ABSENT), texts.get(a),
                              None if plan.targets is None else plan.targets.get(a),
                              why="was stopped by this program (a stop, abort or cancel)")
                for a in plan.moved),
            failed_letters(letters, plan.moved))

    async def _cut_short(self, job: _Job, ended: Sequence[str], letters: Mapping[str, str],
                         texts: Mapping[str, str]) -> NoReturn:
        """Axes of a move ended it early (:func:`~tango_aio.moves._timing.cut_short`) while the
        others still move: stop those, wait until they stand, and fail."""
        idle = await self._stop_and_wait(job)
        stopped = idle is not None
        # The letters seen when they stood, the ended axes' letters of the read that
        # showed them (a stop may turn them into the abort's letter).
        final = {**letters, **(idle or {}), **{a: letters.get(a, ABSENT) for a in ended}}
        plan = job.plan
        targets = plan.targets or {}
        others = [a for a in plan.moved if a not in ended]
        where = self.positions or {}
        parts = [describe_stop(a, final[a], texts.get(a), targets.get(a)) for a in ended]
        parts += [describe_stop(a, final.get(a, ABSENT), where.get(a), targets.get(a),
                                why=f"was stopped by this program when "
                                    f"{' '.join(ended).upper()} stopped")
                  if stopped else f"{a.upper()} may still move" for a in others]
        # Every moved axis failed: those that ended it, and the others stopped short.
        final = failed_letters(final, plan.moved)
        self._finished(job, final, ok=False)
        raise MoveError(f"{plan.command.line!r} did not end at its target: "
                        + "; ".join(parts), final)

    async def _idle(self, job: _Job, timeout: float) -> dict[str, str]:
        async with asyncio.timeout(timeout):
            while True:
                letters, _ = await self._state(job.plan.moved)
                if all(letters.get(a) != MOVING for a in job.plan.moved):
                    return letters
                await asyncio.sleep(POLL_MIN)

    async def _timed_out(self, job: _Job) -> NoReturn:
        await self._stop_and_wait(job)
        raise ControllerTimeoutError(
            f"{job.plan.command.line!r} did not complete within {job.plan.limit:.1f} s; "
            "axes stopped")

    async def _stop_and_wait(self, job: _Job) -> dict[str, str] | None:
        """Write ``a`` and wait (bounded) until the moved axes stand still."""
        with contextlib.suppress(TangoError):
            await self._port.stop()
            self.stopped()
        idle = None
        with contextlib.suppress(TangoError, TimeoutError):
            idle = await self._idle(job, STOP_WAIT)
        job.sent.forget()
        return idle

    async def _stop_after_cancel(self, job: _Job) -> None:
        """The awaiting task was cancelled: stop the axes and wait for them to stop."""
        with contextlib.suppress(TangoError):
            await self._port.stop()
            self.stopped()
        try:
            with contextlib.suppress(Exception, asyncio.CancelledError), \
                    anyio.move_on_after(STOP_WAIT, shield=True):
                if await self._port.accepted(job.sent) is None:
                    await self._idle(job, STOP_WAIT)
        finally:
            job.sent.forget()

    async def _finish_detached(self, job: _Job) -> None:
        """Follow a move whose caller was cancelled (``stop_on_cancel=False``) to its end,
        so that the next move starts after it."""
        try:
            with contextlib.suppress(Exception):
                await self._run(job)
        finally:
            job.sent.forget()

    def _finished(self, job: _Job, letters: Mapping[str, str], ok: bool) -> None:
        self._port.finished(MoveFinished(job.plan.kind, dict(letters), ok))


def annotate(exc: TangoError, text: str) -> TangoError:
    """``exc`` (a driver error raised by a call that had set axes moving) saying whether
    they were stopped."""
    new = copy.copy(exc)
    if exc.args and isinstance(exc.args[0], str):
        new.args = (f"{exc.args[0]}; {text}", *exc.args[1:])
    else:
        new.add_note(text)
    return new


def contested(cause: TangoError, line: str, reason: str, stopped: Sequence[str],
              moving: Sequence[str]) -> TangoError:
    """The error of a motion line whose verdict (a refusal, or a garbled reply) the
    state contradicted or could not settle (:func:`~tango_aio.moves._timing.contest`): a
    :class:`~tango_aio.errors.MoveProtocolUnknownError` saying what the state showed,
    which axes were stopped and which may still move."""
    error = ProtocolError(str(cause)) if isinstance(cause, ControllerError) else cause
    if reason:
        error = annotate(error, reason)
    if stopped:
        error = annotate(error, f"axes {' '.join(stopped).upper()} stopped")
    if moving:
        error = annotate(error, f"axes {' '.join(moving).upper()} may still move")
    return outcome_unknown(error, line)


def report_came(completion: asyncio.Future[Completed] | None) -> bool:
    """Whether a move's completion report arrived (not: its wait was cancelled or failed)."""
    return completion is not None and completion.done() and not completion.cancelled() \
        and completion.exception() is None


def _with_stop(exc: TangoError, job: _Job, stopped: bool) -> TangoError:
    """``exc`` saying whether the axes of ``job`` were seen to stop after it."""
    return annotate(exc, "axes stopped" if stopped else
                    f"axes {' '.join(job.plan.moved).upper()} may still move")
