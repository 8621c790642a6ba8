"""The controller's instruction lines with their proofs: ``command`` and ``set``, a refused
or unanswered line contested, a start or an acceptance proven, the error of a line
blamed, faults, the software limits' cache; a base of
:class:`~tango_aio.controller._controller.Controller`."""

from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING, Any, NoReturn

from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
    Form,
    Value,
    build,
    parse,
)
from ..errors import (
    ERROR_DESCRIPTIONS,
    INTERNAL_ERRORS,
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    GarbledVerdictError,
    InternalControllerError,
    InvalidCommandError,
    ProtocolError,
    RequestAbortedError,
    SettingNotAppliedError,
    TangoError,
    outcome_unknown,
    parse_error_reply,
)
from ..events import (
    ControllerFault,
)
from ..families import (
    check_resolution,
)
from ..link import (
    MoveHandle,
    Response,
)
from ..moves import (
    Prove,
    StartProof,
    acceptance_shown,
    contest,
    moved_axes,
    stop_time,
)
from ..status import MOVING
from ._motion import (
    annotate,
    contested,
    report_came,
)
from ._reads import _read_command, _Reads

log = logging.getLogger("tango_aio")

#: Motion lines that leave the software limits as they are. The limits change only by
#: ``!lim``, by ``cal``/``rm``/``vrm`` (unless nosetlimit, L4575-4580), by reloading the
#: saved parameters (``restore``/``reset``, power-on, L1296) and print in the ``dim``
#: unit (L4555): every other ``!`` line empties the cache of :meth:`Controller.axis_limits`.
_LIMIT_NEUTRAL = frozenset({"moa", "mor"})
#: Lines without a completion report that start motion (a refusal is checked, see
#: :meth:`Controller._contest`).
_STARTS_MOTION = frozenset({"speed", "go"})

#: Seconds between two reads of an axis a speed or go line stops, or speeds up.
_STOP_POLL = 0.01

#: Instructions whose float values are list positions (checked against the resolution).
_LIST_POSITIONS = frozenset({"trigp", "trigr", "snsa"})


#: Whether a move's completion report arrived (its wait not cancelled, not failed).
_reported = report_came


class _Exchanges(_Reads):
    """The lines of a controller and their proofs. Of what is built on it, it calls
    :meth:`stop` alone (a refused move line that started motion is stopped)."""

    if TYPE_CHECKING:
        async def stop(self, *axes: str, wait: bool = True) -> None: ...

    async def command(self, line: str, *, check: bool = True,
                      timeout: float | None = None) -> None:
        """Send a set/execute line such as ``"!vel y 12.5"``."""
        command = parse(line, self.context)
        if command.is_read:
            raise InvalidCommandError(f"{command.line!r} is a read; use query()",
                                      instruction=command.name)
        if command.name in _LIST_POSITIONS:
            # A non-zero list position below the resolution is stored as 0.0 (L4080-4100),
            # as triggers.upload_positions() refuses it.
            tiny = [v for v in command.values if isinstance(v, float) and 0 < abs(v) < 0.5]
            if tiny:
                check_resolution([tiny], [min(await self._resolution())], command.name)
        await self._execute(command, check=check, timeout=timeout)

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        """Set instruction ``name``: ``set("vel", x=10, y=5)``, ``set("vel", 3, axis="z")``,
        ``set("autostatus", 1)``. Checks the error state like :meth:`command`."""
        command = build(name, *args, form=Form.SET, axis=axis, context=self.context, **axes)
        self._check_axes(command, axes)
        await self._execute(command, check=check)

    async def _execute(self, command: Command, *, check: bool,
                       timeout: float | None = None) -> Response:
        """Write ``command`` (checked, see :meth:`TangoProtocol.execute`) and wait."""
        self._check_axes(command)
        if not command.is_read:
            self._forget_start(command)
        raw_move = command.instruction.completion is not None and command.executes
        starts = check and command.executes and (raw_move or command.name in _STARTS_MOTION)
        # A speed or go line owes no answer in autostatus 0, 1, 3: its ?err 0 is also
        # what a lost line gets, so the state read behind it proves it (_prove_started).
        unanswered = starts and not raw_move and not self._protocol.answers(command)
        busy = await self._moving_before(command) if unanswered else frozenset()
        try:
            if raw_move and check:
                # (execute() is start_move() and confirm(); the handle is kept here for
                # its completion report, which may prove a deferred acceptance.)
                handle = self._protocol.start_move(command, check=True)
                await handle.confirm(self._timeout(timeout))
                response = handle.submission.response
                if response.deferred:
                    await self._prove_accepted(handle, self._timeout(timeout))
            else:
                response = await self._protocol.execute(
                    command, timeout=self._timeout(timeout), check=check)
        except ControllerError as error:
            if error.number < INTERNAL_ERRORS or \
                    await self._blame(error.number, self._timeout(timeout)):
                if starts:
                    await self._contest(error, command)
                raise
            if check and not raw_move:
                # The ?err showed a standing internal error, which a lost line gets too:
                # the read-back decides (the one pipelined behind it was not awaited).
                try:
                    await self._protocol.prove_set(command, self._timeout(timeout))
                except SettingNotAppliedError as failed:
                    raise failed from error
            response = Response()
        except GarbledVerdictError as error:
            if starts:
                await self._contest(error, command)
            raise
        except (ControllerTimeoutError, RequestAbortedError, ProtocolError,
                ConnectionLostError) as error:
            if not raw_move:
                if not (isinstance(error, RequestAbortedError) and check and not starts
                        and await self._held_after_abort(command, timeout)):
                    raise
                response = Response()
            else:
                if starts and not isinstance(error, ConnectionLostError):
                    await self._contest(error, command)  # it may have run: is it running?
                raise outcome_unknown(error, command.line) from error.__cause__
        if unanswered:
            await self._prove_started(command, busy, self._timeout(timeout))
        self._track(command)
        if starts:
            self._turned(command)
        if self._moves.accepted(command):
            self._moves.inputs_read(await self._inputs_are_idle())
        return response

    async def _held_after_abort(self, command: Command, timeout: float | None) -> bool:
        """A set line a resync aborted in flight (its answer went with the stream, the
        line may have run): whether its read-back, written once the stream is in step,
        shows the value. Another value, or no read that proves it: the abort stands."""
        try:
            return await self._protocol.prove_set(command, self._timeout(timeout),
                                                  aborted=True)
        except TangoError:
            return False

    def _turned(self, command: Command) -> None:
        """An accepted line that starts motion nobody follows: its axes may move on."""
        moved = moved_axes(command, AXES[: self.context.axes])
        if command.name == "speed":
            for axis, value in zip(moved, command.values, strict=False):
                (self._turning.add if value else self._turning.discard)(axis)
        else:
            self._turning.update(moved)

    async def _contest(self, cause: TangoError, command: Command) -> NoReturn:
        """A refusal stands if none of the line's axes moves; else stop them and say so."""
        # (The verdict on a line that starts motion refused it or made no sense:
        # timing.contest judges ?statusaxis, read behind it. The driver's own motion in
        # flight, a followed move or what _turning holds, does not contradict a refusal.)
        moved = moved_axes(command, AXES[: self.context.axes])
        busy = set(AXES) if self._motion.busy else set(self._turning)
        try:
            letters = await self.status()
        except TangoError as exc:
            raise contested(cause, command.line, "the state could not be read behind it",
                            (), moved) from exc
        found = contest(moved, letters, clean=isinstance(cause, ControllerError), busy=busy)
        if found.stands:
            raise annotate(cause, found.reason) if found.reason else cause
        try:
            if found.moving:
                await self.stop(*found.moving)
        except TangoError:
            raise contested(cause, command.line, found.reason, (), found.moving) from None
        raise contested(cause, command.line, found.reason, found.moving, ())

    async def _moving_before(self, command: Command) -> frozenset[str]:
        # The axes a speed line sets running that moved before it (their M proves
        # nothing behind it), read only when the driver may have left them running. A
        # go that retargets a moving axis is accepted on its M: no read shows its new
        # target before it ends (L6616).
        if command.name != "speed":
            return frozenset()
        axes = [a for a, v in zip(moved_axes(command, AXES[: self.context.axes]),
                                  command.values, strict=False) if v]
        if not set(axes) & self._turning:
            return frozenset()
        letters = await self.status()
        return frozenset(a for a in axes if letters.get(a) == MOVING)

    async def _prove_started(self, command: Command, busy: frozenset[str],
                             timeout: float) -> None:
        """Prove from the state behind it that a speed or go line arrived, or stop it."""
        # The tracker's StartProof says which read comes next and judges it (timing's
        # acceptance, stop_time, speed_shown). Unproven: the line's axes that move are
        # stopped, and the MoveProtocolUnknownError says so and that the line may not
        # have been applied.
        present = AXES[: self.context.axes]
        loop = asyncio.get_running_loop()
        proof = StartProof(command, present, busy=busy, poll=_STOP_POLL,
                           deadline=loop.time() + stop_time(self._settings, present))
        step = proof.begin()
        try:
            while step.found is None:
                if step.wait:
                    await asyncio.sleep(step.wait)
                if step.next is Prove.READ_STATUS:
                    step = proof.status(await self.status(), loop.time())
                elif step.next is Prove.READ_POSITIONS:
                    step = proof.positions(await self._position_texts(), loop.time())
                else:
                    reply = await self._request(
                        _read_command("speed", step.axis, self.context), timeout)
                    step = proof.speed(step.axis, " ".join(reply.lines), loop.time())
        except TangoError as exc:
            raise contested(ProtocolError(f"{command.line!r} was answered without an "
                                          "error, but the state behind it could not be "
                                          "read: it may not have been applied"),
                            command.line, "", (), moved_axes(command, present)) from exc
        if step.next is Prove.PROVEN:
            return
        cause = ProtocolError(f"{command.line!r} was answered without an error, yet "
                              f"nothing shows that it arrived: it may not have been applied")
        running, reason = step.running, step.found.reason
        try:
            if running:
                await self.stop(*running)
        except TangoError:
            raise contested(cause, command.line, reason, (), running) from None
        raise contested(cause, command.line, reason or "nothing of it moves", running, ())

    async def _prove_accepted(self, handle: MoveHandle, timeout: float) -> None:
        """Prove that a move line whose acceptance rests only on the ``?err`` behind it
        (:attr:`~tango_aio.link._protocol.Response.deferred`) arrived, or raise.

        In autostatus 2 the ``OK...`` (L2099-2103: "immediately acknowledged", yet some
        firmware sends a move's only with its report: switch ``move_ok``) and in
        autostatus 4 the echo (L2115-2117, when is not said: switch ``echo``) may come
        with the completion report. Then the ``?err`` reply arrives where they were owed,
        and its 0 is all the driver has: the same as when the move line was lost (it
        reached a controller that was off) and the ``?err`` behind it was answered. So
        ``?statusaxis`` is read, behind the line: the interpreter executes lines in
        order, so the move has started by then if it arrived, and its report (which
        carries the deferred ``OK...`` or echo) came before the reply if it already
        ended (L2087-2089). A moved axis moving, or the report, proves it
        (:func:`~tango_aio.moves.acceptance_shown`)."""
        completion = handle.submission.completion
        if completion is None or _reported(completion):
            return  # its report came (a refusal fails confirm() before this)
        # (A report no longer awaited, e.g. dropped when a restart was noticed, is no
        # proof: only a report that came is.)
        letters = await self.get("statusaxis", timeout=timeout)
        assert isinstance(letters, dict)
        moved = moved_axes(handle.command, AXES[: self.context.axes])
        if acceptance_shown(_reported(completion), letters, moved):
            return
        handle.forget()  # it never ran: its report must not be taken for a later move's
        self._restarts.suspect()
        raise ProtocolError(
            f"the acceptance of {handle.command.line!r} could not be proven: its "
            f"{'OK...' if handle.submission.expectation.ack else 'echo'} did not come "
            f"(only the ?err behind it answered 0), no completion report came, and "
            f"?statusaxis shows {' '.join(moved).upper()} standing: the line may have "
            f"been lost")

    def _forget_start(self, command: Command) -> None:
        """A ``!`` line other than a move: any of them may move the stage or change what
        ``?pos`` prints (``go``, ``speed``, ``pos``, ``cal``, a list...), so no remembered
        position is a move_by's start any more until a move confirms it again."""
        self._moves.written(command.name)
        if command.name not in _LIMIT_NEUTRAL:
            self._forget_limits()

    def _forget_power_state(self) -> None:
        """What a power cycle may have changed behind the link: the HDI is on again, the
        saved limits are back, positions may differ; no remembered start or limit
        survives it (setup, and a restart noticed on a live link)."""
        self._moves.power_cycled()
        self._forget_limits()

    def _forget_limits(self) -> None:
        """Something may have changed the software limits: read them again."""
        self._limits.clear()
        self._limits_epoch += 1

    async def axis_limits(self, axis: str, *, cached: bool = True) -> tuple[float, float]:
        """The software limits of ``axis`` as ``(lower, upper)`` in its dim unit.

        With ``cached``, the limits this Controller read before are returned without a
        read, as long as nothing could have changed them since: any ``!`` line other than
        a move (``!lim``, ``cal``, ``rm``, ``vrm``, ``restore``, ``dim``...), the end of a
        calibration or range measurement, a setup or a reconnect reads them again. A
        target beyond limits changed behind the driver's back (the stage's own keys) is
        still no success: the controller refuses it or stops at its limit (L4526-4540),
        and the confirmation behind the report finds the axis short of its target."""
        known = self._limits.get(axis)
        if cached and known is not None:
            return known
        epoch = self._limits_epoch
        low, high = await self.get("lim", axis=axis)
        pair = (float(low), float(high))
        if epoch == self._limits_epoch:  # no line that may change them went out meanwhile
            self._limits[axis] = pair
        return pair

    async def _inputs_are_idle(self) -> bool:
        """Whether neither input moves the stage by itself: a snapshot event moves it in
        snapshot modes other than 0 (L14520-14530; snsm 0 only captures, L900), and the
        pulse/direction input drives an axis in tvr modes other than 0 (L9914-9930)."""
        known = self._identity
        if known is not None and known.family == "older" and not all(
                INSTRUCTIONS[name].in_older_manual for name in ("snsm", "tvr")):
            return False  # the older edition lacks them: a read would wait out its timeout
        try:
            snsm = await self.get("snsm")
            tvr = await self.get("tvr")
        except (ControllerError, ControllerTimeoutError, ProtocolError):  # not known
            return False
        modes = tvr.values() if isinstance(tvr, dict) else [tvr]
        return snsm == 0 and all(mode == 0 for mode in modes)

    def _send(self, command: Command, *, check: bool, batch: object | None = None
              ) -> MoveHandle:
        """Write a motion line and its check (see :meth:`TangoProtocol.start_move`)."""
        self._check_axes(command)
        if command.name not in _LIMIT_NEUTRAL:
            self._forget_limits()  # cal, rm: and again when they end
        return self._protocol.start_move(command, check=check, batch=batch)

    async def _error_of(self, sent: MoveHandle, timeout: float) -> ControllerError | None:
        """The error the controller reported for ``sent`` (``None``: accepted).

        A number of 20 and above may be a persistent internal error rather than the
        line's own (L2853-2867: "if the previously executed instruction returned no error,
        the 'err' response is either 0 or ... the internal error"): see :meth:`_blame`."""
        error = await sent.error(timeout)
        if error is not None and error.number >= INTERNAL_ERRORS \
                and not await self._blame(error.number, timeout):
            return None
        return error

    async def _blame(self, code: int, timeout: float) -> bool:
        """Whether error ``code`` (>= 20) belongs to the line just checked.

        Every instruction overwrites the error state, and after one that was fine ``?err``
        answers 0 or the internal error (L2853-2867). So ``?err`` is asked again after a
        read that cannot fail (``?autostatus``; ``?err`` itself is not used for this, as
        the manual does not say whether reading it overwrites the state): 0 means ``code``
        was the line's own, the same number a persistent internal condition. That one is
        not the line's fault: it is published as a :class:`ControllerFault` event (once
        per change) and the line counts as accepted."""
        again = await self._internal_error(timeout)
        if again != code:
            self._fault_seen(again)
            return True
        self._fault_seen(code)
        return False

    async def _internal_error(self, timeout: float | None = None) -> int:
        """``?err`` right after a read that is always fine: 0 or the internal error."""
        # Written back to back: no other line can come between the read and the probe.
        self._protocol.submit(parse("?autostatus"))
        reply = await self._protocol.query(parse("?err"), timeout=self._timeout(timeout))
        code, _ = parse_error_reply(reply.lines[0])
        return code or 0

    def _fault_seen(self, code: int) -> None:
        if code < INTERNAL_ERRORS:
            code = 0
        if code != self._fault:
            self._fault = code
            if code:
                log.warning("controller reports internal error %d: %s", code,
                            ERROR_DESCRIPTIONS.get(code, "undocumented"))
                self._hub.publish(ControllerFault(code, ERROR_DESCRIPTIONS.get(
                    code, "undocumented internal error")))

    @property
    def fault(self) -> int:
        """The persistent internal error (>= 20) the controller last reported in ``?err``
        although the instruction before was fine, 0 if none (see :meth:`check_fault`)."""
        return self._fault

    async def check_fault(self) -> None:
        """Raise :class:`~tango_aio.errors.InternalControllerError` if the controller is
        in a persistent internal error state (an error number >= 20 that ``?err`` reports
        after an instruction that itself was fine, L2853-2867); else return."""
        code = await self._internal_error()
        self._fault_seen(code)
        if code >= INTERNAL_ERRORS:
            raise InternalControllerError(code)

    def _track(self, command: Command) -> None:
        """Keep the cached settings in step with a set the controller accepted."""
        if self._settings.observe(command):
            self._update_context()

    def _update_context(self) -> None:
        settings = self._settings
        settings.axes = self._protocol.context.axes  # identify() sets it from ?det
        self._protocol.context = settings.context
