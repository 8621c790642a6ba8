"""How the controller's moves are planned and run: the lines that move exactly the named
axes, a move's own velocity and acceleration set and restored, the plan handed to
:class:`~tango_aio.controller._motion.Motion` (its budget, its start read); a base of
:class:`~tango_aio.controller._controller.Controller`, whose move methods check input
and hand over to it."""

from __future__ import annotations

import asyncio
import contextlib
import functools
from collections.abc import (
    AsyncIterator,
    Awaitable,
    Callable,
    Iterator,
    Mapping,
    Sequence,
)
from typing import TYPE_CHECKING, Any

from .._checks import check_timeout
from ..catalog import (
    AXES,
    Command,
    Form,
    build,
    build_axes,
)
from ..errors import (
    InvalidCommandError,
)
from ..moves import (
    Budget,
    Start,
    move_budget,
    moved_axes,
    rest_budget,
)
from ..units import Measure
from ._motion import (
    MovePlan,
)
from ._reads import Identity, _ignore_outcome, _read_command
from ._setup import _Setup


def _line_groups(axes: Mapping[str, float]) -> list[dict[str, float]]:
    """The lines that move exactly the named axes.

    The manual addresses either one axis (``moa y 34.5``) or the leading axes from X
    (``moa 10 0.5`` moves X and Y, L6353-6361); it has no form for another subset. Naming
    an axis that should not move, with its current position, would move it by the
    rounding of that position, and the ``distance``+``m`` form (L6420-6455) is relative
    and changes a setting. So a set that starts at X without gaps is one vector line; any
    other set is moved axis by axis, one line after the other, each followed to its end
    (the controller's behaviour for a second move line while axes run is not documented,
    so moves never overlap)."""
    order = [axis for axis in AXES if axis in axes]
    unknown = set(axes) - set(AXES)
    if unknown or not order:
        return [dict(axes)]  # build_axes reports the error
    if order == list(AXES[: len(order)]):
        return [{axis: axes[axis] for axis in order}]
    return [{axis: axes[axis]} for axis in order]


#: A per-move velocity or acceleration: one number for every moved axis, or per axis.
Speed = float | Mapping[str, float]


def _per_moved_axis(name: str, value: Speed, axes: Mapping[str, Any]) -> dict[str, Any]:
    """``value`` for each moved axis; a mapping must name moved axes only."""
    if isinstance(value, Mapping):
        extra = sorted(set(value) - set(axes))
        if extra:
            raise InvalidCommandError(f"{name}: {', '.join(extra)} is not moved by this "
                                      f"call (moved: {', '.join(axes)})",
                                      instruction=name, parameter="axis", number=1)
        return dict(value)
    return dict.fromkeys(axes, value)


class _Planning(_Setup):
    """The machinery behind the move methods. Of what is built on it, it (and the
    device families' port) reads :attr:`autostatus` and :attr:`identity` alone."""

    _move_settings_lock: asyncio.Lock

    if TYPE_CHECKING:
        @property
        def autostatus(self) -> int: ...

        @property
        def identity(self) -> Identity: ...

    @contextlib.asynccontextmanager
    async def _move_settings(self, axes: Mapping[str, Any], unit: str | None,
                             velocity: Speed | None, acceleration: Speed | None
                             ) -> AsyncIterator[None]:
        """Set ``vel``/``accel`` of the moved axes for the block, then write back what
        was read before (shielded: also after a failure or a cancellation)."""
        wanted = [(name, value, measure) for name, value, measure in
                  (("vel", velocity, Measure.VELOCITY),
                   ("accel", acceleration, Measure.ACCELERATION)) if value is not None]
        if not wanted:
            yield
            return
        async with self._move_settings_lock:
            lines: list[Command] = []
            for name, value, measure in wanted:
                per_axis = _per_moved_axis(name, value, axes)
                scaled = unit if unit is None else unit + measure.suffix
                converted = await self._to_controller(per_axis, scaled, measure)
                lines += [build(name, v, axis=a, context=self.context)
                          for a, v in converted.items()]  # all checked before a byte
            for line in lines:
                self._check_axes(line)
            saved: list[Command] = []
            try:
                for line in lines:
                    assert line.axis is not None
                    before = await self.get(line.name, axis=line.axis)
                    saved.append(build(line.name, before, axis=line.axis,
                                       context=self.context))
                    await self._execute(line, check=True)
                yield
            finally:
                if saved:
                    await asyncio.shield(self._restore(saved))

    async def _restore(self, lines: Sequence[Command]) -> None:
        for line in reversed(lines):
            await self._execute(line, check=True)

    async def _move(self, name: str, axes: Mapping[str, float], timeout: float | None,
                    stop_on_cancel: bool) -> dict[str, str]:
        groups = _line_groups(axes)
        lines = [build_axes(name, part, context=self.context) for part in groups]
        for line, part in zip(lines, groups, strict=True):
            self._check_axes(line, part)
        if len(lines) == 1:
            return await self._run_motion(lines[0], timeout, stop_on_cancel, groups[0])
        letters: dict[str, str] = {}
        for line, part in zip(lines, groups, strict=True):
            letters.update(await self._run_motion(line, timeout, stop_on_cancel, part))
        return letters

    async def _per_axis_motion(self, name: str, axes: tuple[str, ...], timeout: float | None,
                               stop_on_cancel: bool) -> dict[str, str]:
        with self._motion_call():
            try:
                return await self._per_axis_motion_run(name, axes, timeout, stop_on_cancel)
            finally:
                self._forget_limits()  # cal and rm set limits as they end (L4575-4580)

    @contextlib.contextmanager
    def _motion_call(self) -> Iterator[None]:
        """Record a motion call (move_to, calibrate...) from its first step to its end, so
        that :meth:`wait_idle` waits for a move whose line is not written yet."""
        done = asyncio.Event()
        self._motion_calls.add(done)
        try:
            yield
        finally:
            self._motion_calls.discard(done)
            done.set()

    async def _per_axis_motion_run(self, name: str, axes: tuple[str, ...],
                                   timeout: float | None, stop_on_cancel: bool
                                   ) -> dict[str, str]:
        check_timeout(timeout)  # refused before anything is written
        if not axes:
            return await self._run_motion(build(name, form=Form.SET), timeout,
                                          stop_on_cancel, None)
        letters: dict[str, str] = {}
        for axis in axes:
            command = build(name, form=Form.SET, axis=axis)
            letters.update(await self._run_motion(command, timeout, stop_on_cancel, None))
        return letters

    async def _run_motion(self, command: Command, timeout: float | None, stop_on_cancel: bool,
                          targets: Mapping[str, float] | None) -> dict[str, str]:
        self._check_axes(command, targets or ())

        async def plan(line: Command, known: Mapping[str, str] | None) -> MovePlan:
            return await self._plan(line, targets, timeout, known)

        moved = moved_axes(command, AXES[: self.context.axes])
        executed = self._moves.executed
        letters = await self._motion.run(command, plan, stop_on_cancel)
        # Confirmed where they stand: the next move_by's start, if nothing else went out.
        self._moves.confirmed(command.name, moved, executed)
        return letters

    async def _plan(self, command: Command, targets: Mapping[str, float] | None,
                    timeout: float | None, last: Mapping[str, str] | None) -> MovePlan:
        """Targets and timing of a motion line, from where its axes are now (called once
        the previous move has ended). ``targets``: the line's values per axis, distances
        for ``mor`` (relative to the current position, L6365-6376), absolute positions for
        ``moa``. ``last``: the positions (as printed) the driver read last, if any."""
        relative = command.name == "mor"
        moved = moved_axes(command, AXES[: self.context.axes])
        reports = self.autostatus != 0
        timeout = check_timeout(timeout)
        # Where the start comes from is the tracker's (tango_aio.moves.MoveTracker.start).
        # A move_to does not read ?pos first (a whole round trip per move): its budget is
        # provisional, sized from the latest state read (motion.py "Timeouts"), extended
        # once from the positions read at its end. A move_by's target is start + distance:
        # its ?pos is written right before the line, in the same write (BATCH), or read
        # first, unless the remembered position is known to be where the axes stand.
        source = self._moves.start(moved, None if targets is None else set(targets),
                                   relative=relative, last=last,
                                   exact_replies=self._exact_replies())
        if targets is None:  # cal, rm, moc: the distance is not known here
            return MovePlan(command, moved, None,
                            move_budget(self._settings, command, None, timeout),
                            reports=reports)
        if source is Start.BATCH:
            batch = object()
            return MovePlan(command, moved, dict(targets),
                            move_budget(self._settings, command, targets, timeout),
                            start=self._start_reader(batch), batch=batch, reports=reports)
        if source is Start.KNOWN and last is not None:
            start = {a: float(last[a]) for a in targets}
        else:
            start = {a: float(t) for a, t in (await self._position_texts()).items()}
        absolute = {a: (start[a] + v if relative else float(v)) for a, v in targets.items()}
        budget = move_budget(self._settings, command,
                             {a: absolute[a] - start[a] for a in absolute}, timeout)
        extend: Callable[[Mapping[str, str]], float] | None = None
        if source is Start.KNOWN and timeout is None:
            extend = functools.partial(self._rest_budget, absolute, budget)
        return MovePlan(command, moved, absolute, budget, extend=extend, reports=reports)

    def _start_reader(self, batch: object) -> Callable[[], Awaitable[dict[str, str]]]:
        """Write ``?pos`` now (in ``batch``); return what reads its reply, one text per
        present axis (awaitable again after a cancelled wait)."""
        present = AXES[: self.context.axes]
        submission = self._protocol.submit(_read_command("pos", None, self.context),
                                           batch=batch)
        if submission.reply is not None:  # a refused move never reads it
            submission.reply.add_done_callback(_ignore_outcome)

        async def start() -> dict[str, str]:
            reply = await self._protocol.wait_reply(submission, self.reply_timeout)
            texts = " ".join(reply.lines).split()
            return dict(zip(present, texts, strict=False)) if len(texts) == len(present) \
                else {}

        return start

    def _rest_budget(self, targets: Mapping[str, float], budget: Budget,
                     now: Mapping[str, str]) -> float:
        """Seconds a move to ``targets`` may still take from the positions printed
        ``now`` (:func:`~tango_aio.moves._timing.rest_budget` with the settings in force)."""
        return rest_budget(self._settings, targets, now, budget.fallback)
