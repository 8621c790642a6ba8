"""Merge single-axis moves that arrive together into one multi-axis move."""

from __future__ import annotations

import asyncio
import contextlib
import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import anyio

from ..catalog import AXES, build_axes
from ..controller import STOP_WAIT, Controller
from ..errors import InvalidCommandError, MoveError, TangoError
from ..status import AxisStatus

__all__ = ["MoveCoalescer"]

#: Longest wait for a cancelled merged move to clean up (its stop is bounded by STOP_WAIT).
_CLEANUP_WAIT = STOP_WAIT + 5.0


class _State(enum.Enum):
    COLLECTING = "collecting"  # accepts requests for axes not yet in it
    CLOSED = "closed"          # no more requests; waits for the batch before it
    MOVING = "moving"          # its move_to was called: axes may move


@dataclass(eq=False)
class _Batch:
    """One merged move: the targets collected so far and the task that runs it."""

    targets: dict[str, float] = field(default_factory=dict)
    state: _State = _State.COLLECTING
    closed: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[dict[str, str]] | None = None
    #: Why the batch was cancelled, for the callers that did not cancel it.
    cancel_reason: str = ""
    #: The positions its lines' confirmations read, taken as each line returned.
    positions: dict[str, str] = field(default_factory=dict)
    #: One future per caller, given the batch's outcome: on success in the batch's own
    #: last step (the caller resumes one loop turn after the last line returned, not
    #: three: task done -> shield -> caller), otherwise by the task's done-callback.
    waiters: list[asyncio.Future[dict[str, str]]] = field(default_factory=list)

    def settle(self, task: asyncio.Task[dict[str, str]] | None = None,
               letters: dict[str, str] | None = None) -> None:
        """Give every caller still waiting the batch's outcome: ``letters``, or the
        ended ``task``'s result, exception, or (cancelled) a MoveError with status E."""
        outcome: BaseException | None = None
        if letters is None and task is not None:
            if task.cancelled():
                outcome = MoveError(f"merged move {self.targets} {self.cancel_reason}",
                                    dict.fromkeys(self.targets, AxisStatus.ERROR))
            else:
                outcome = task.exception()
                letters = None if outcome is not None else task.result()
        for waiter in self.waiters:
            if waiter.done():  # its caller was cancelled, or it was settled already
                continue
            if outcome is not None:
                waiter.set_exception(outcome)
            else:
                waiter.set_result(letters or {})

    def close(self) -> None:
        """Stop collecting; the batch runs as soon as the batch before it has ended."""
        if self.state is _State.COLLECTING:
            self.state = _State.CLOSED
        self.closed.set()


class MoveCoalescer:
    """Merges moves of different axes of one Controller that arrive within `window`
    seconds into one `move_to` (one `!moa` line)."""

    def __init__(self, controller: Controller, *, window: float = 0.02,
                 collect: str = "window") -> None:
        if not (math.isfinite(window) and window >= 0):
            raise ValueError(f"window must be a finite number >= 0, got {window!r}")
        if collect not in ("window", "announced"):
            raise ValueError(f"collect must be 'window' or 'announced', got {collect!r}")
        self.controller = controller
        self.window = window
        self.collect = collect
        self._announced = 0
        self._arrived = asyncio.Event()
        self._collecting: _Batch | None = None
        self._last: asyncio.Task[dict[str, str]] | None = None
        self._batches: set[_Batch] = set()
        self._closed = False

    def announce(self) -> Callable[[], None]:
        """Announce a request that is on its way (``collect="announced"``): the batch
        being collected waits for it. Returns the function that ends the announcement
        (call it once the request was made, or given up; later calls do nothing)."""
        self._announced += 1
        done = False

        def arrived() -> None:
            nonlocal done
            if not done:
                done = True
                self._announced -= 1
                self._arrived.set()

        return arrived

    async def move_to(self, axis: str, target: float,
                      arrived: Callable[[], None] | None = None, *,
                      positions: dict[str, str] | None = None) -> str:
        """Move one axis as part of the next merged move; return its status letter,
        raise the merged move's MoveError/TangoError. A second request for an axis that is
        already in the batch being collected closes that batch and starts the next one.
        Cancelling one caller stops the merged move (all axes), as Controller.move_to does."""
        try:
            value = self._checked(axis, target)
            batch = self._batch_for(axis)
            batch.targets[axis] = value
        finally:
            if arrived is not None:
                arrived()  # it has joined (or failed): no batch waits for it any more
        task = batch.task
        assert task is not None
        # A future of this caller's own (cancelling it withdraws this caller alone): the
        # batch settles it (another caller's cancellation: a MoveError with status E).
        waiter: asyncio.Future[dict[str, str]] = asyncio.get_running_loop().create_future()
        batch.waiters.append(waiter)
        try:
            letters = await waiter
        except asyncio.CancelledError:
            if not task.done():
                await self._withdraw(batch, axis)
            elif waiter.done() and not waiter.cancelled():
                waiter.exception()  # cancelled just as the batch ended: its outcome is moot
            raise
        finally:
            if positions is not None:
                positions.update(batch.positions)
        return letters.get(axis, AxisStatus.READY)

    def pending(self, axis: str) -> bool:
        """Whether a move of ``axis`` waits in a batch not yet sent (cancelling its
        caller then only withdraws it; nothing has moved)."""
        return any(batch.state is not _State.MOVING and axis in batch.targets
                   for batch in self._batches)

    async def aclose(self) -> None:
        """Stop every pending and running merged move (running axes are stopped) and
        refuse new requests."""
        self._closed = True
        self._collecting = None
        tasks = []
        for batch in list(self._batches):
            batch.cancel_reason = "stopped: the MoveCoalescer was closed"
            if batch.task is not None:
                batch.task.cancel()
                tasks.append(batch.task)
        if tasks:
            with anyio.move_on_after(_CLEANUP_WAIT, shield=True):
                await asyncio.wait(tasks)

    # -- internals ------------------------------------------------------------------------

    def _checked(self, axis: str, target: float) -> float:
        """Validate one request before it joins a batch (no other caller suffers)."""
        if self._closed:
            raise TangoError("the MoveCoalescer is closed")
        present = AXES[: self.controller.context.axes]
        if not isinstance(axis, str) or axis not in present:
            raise InvalidCommandError(
                f"the controller has no axis {axis!r} (axes: {', '.join(present)})",
                instruction="moa", parameter="axis", number=1)
        value = float(target)  # numpy scalars and ints are welcome; float() is the boundary
        build_axes("moa", {axis: value}, context=self.controller.context)  # range, finite
        return value

    def _batch_for(self, axis: str) -> _Batch:
        """The batch being collected, or a new one if there is none or it has ``axis``."""
        batch = self._collecting
        if batch is not None and axis not in batch.targets:
            return batch
        if batch is not None:
            batch.close()
            self._arrived.set()  # a batch waiting for announced requests runs now
        batch = _Batch()
        batch.task = asyncio.ensure_future(self._run(batch, self._last))
        self._last = batch.task
        self._collecting = batch
        self._batches.add(batch)
        batch.task.add_done_callback(lambda task: self._ended(batch, task))
        return batch

    def _ended(self, batch: _Batch, task: asyncio.Task[dict[str, str]]) -> None:
        self._batches.discard(batch)
        if self._collecting is batch:
            self._collecting = None
        batch.settle(task)  # (retrieves its exception: no "exception never retrieved")

    async def _run(self, batch: _Batch,
                   previous: asyncio.Task[dict[str, str]] | None) -> dict[str, str]:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(self.window):
                if self.collect == "window":
                    await batch.closed.wait()
                else:
                    await asyncio.sleep(0)  # requests made in this loop turn join
                    while self._announced and not batch.closed.is_set():
                        self._arrived.clear()
                        await self._arrived.wait()
        batch.close()
        if self._collecting is batch:
            self._collecting = None
        if previous is not None and not previous.done():
            # Batches keep their order; the controller would serialise them anyway, but
            # not necessarily in the order they were started.
            await asyncio.wait([previous])
        batch.state = _State.MOVING
        letters: dict[str, str] = {}
        for line in _lines(batch.targets):
            axes: dict[str, Any] = line  # only axis letters, never move_to's options
            letters.update(await self.controller.move_to(**axes))
            batch.positions.update(self.controller.last_positions or {})
        batch.settle(letters=letters)  # now, in this step: the callers resume next turn
        return letters

    async def _withdraw(self, batch: _Batch, axis: str) -> None:
        """The caller of ``axis`` was cancelled: drop its target if nothing moves yet,
        else stop the merged move and wait (bounded, shielded) until it has ended."""
        task = batch.task
        assert task is not None
        if batch.state is not _State.MOVING:
            del batch.targets[axis]
            if batch.targets:
                return
            if self._collecting is batch:
                self._collecting = None
        batch.cancel_reason = f"stopped: the caller moving {axis!r} was cancelled"
        task.cancel()
        with anyio.move_on_after(_CLEANUP_WAIT, shield=True):
            await asyncio.wait([task])


def _lines(targets: dict[str, float]) -> list[dict[str, float]]:
    """Split ``targets`` into the moves one ``!moa`` line can express, in axis order.

    A ``moa`` line takes either positional values starting at X (``moa 10 0.5`` moves X
    and Y, manual L6353-6355) or one axis named by its letter (``moa y 34.5``, L6357-6361);
    the manual shows no way to skip an axis in between. So the run of axes from X without
    a gap travels together in one line, and each other axis gets a line of its own (run
    one after another). Filling a gap with the gap axis's current position is avoided: a
    read-back rounded to the reply's decimals would move that axis slightly."""
    ordered: list[str] = [axis for axis in AXES if axis in targets]
    prefix = 0
    while prefix < len(ordered) and ordered[prefix] == AXES[prefix]:
        prefix += 1
    lines = [{axis: targets[axis] for axis in ordered[:prefix]}] if prefix else []
    lines += [{axis: targets[axis]} for axis in ordered[prefix:]]
    return lines
