"""Hardware-triggered fly scans: the flyer and its raster plan."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import itertools
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

try:
    import bluesky.plan_stubs as bps
    from bluesky.protocols import Collectable, Pausable, Stoppable
    from bluesky.utils import MsgGenerator
    from event_model import DataKey, PartialEvent
    from ophyd_async.core import AsyncStatus, FlyableLogic, StandardFlyable
except ImportError as exc:  # pragma: no cover - depends on the environment
    from .._install import install_hint

    raise ImportError(f"tango_aio.bluesky needs the bluesky extra: "
                      f"{install_hint('bluesky')}") from exc

from ..catalog import AXES
from ..errors import MoveError, TangoError
from ..status import AxisStatus
from ._axis import _pass_move, _started
from ._link import Mover, StageLink, _LinkConnector, _nothing
from ._stage import MarzhauserStage

log = logging.getLogger("tango_aio.bluesky")

@dataclasses.dataclass(frozen=True)
class TriggerScan:
    """One pass of a fly scan, what :meth:`MarzhauserFlyer.prepare` takes.

    ``axis`` travels from ``start`` to ``end``; the trigger output fires at ``positions``
    (uploaded with ``!trigp``) or, with ``trigger_range=(first, last, count)``, at
    ``count`` equidistant positions including both ends (``!trigr``, L13496-13692).
    The pass must start before the first trigger position and end at or past the last
    (L13826: the list fires in the direction of travel). ``snapshots``: clear the
    snapshot array before the pass and collect the positions captured during it (the
    snapshot input must be configured on the controller, ``sns``/``snsm``).
    """

    axis: str
    start: float
    end: float
    positions: Sequence[float] | None = None
    trigger_range: tuple[float, float, int] | None = None
    snapshots: bool = False

    def __post_init__(self) -> None:
        if (self.positions is None) == (self.trigger_range is None):
            raise ValueError("give either positions or trigger_range")
        if self.axis not in AXES:
            raise ValueError(f"axis must be one of {AXES!r}, got {self.axis!r}")
        object.__setattr__(self, "start", float(self.start))
        object.__setattr__(self, "end", float(self.end))
        if self.positions is not None:
            object.__setattr__(self, "positions", tuple(float(p) for p in self.positions))
        if self.trigger_range is not None:
            first, last, count = self.trigger_range
            if int(count) != count or count < 1:
                raise ValueError(f"trigger count must be a positive integer, got {count!r}")
            object.__setattr__(self, "trigger_range", (float(first), float(last), int(count)))
        triggers = self.trigger_positions
        if not triggers:
            raise ValueError("a fly scan needs at least one trigger position")
        up = self.end > self.start
        first, last = triggers[0], triggers[-1]
        inside = (self.start < first and last <= self.end) if up else \
            (self.start > first and last >= self.end)
        ordered = all((b > a) if up else (b < a) for a, b in itertools.pairwise(triggers))
        if self.start == self.end or not inside or not ordered:
            raise ValueError(
                f"the pass {self.start} -> {self.end} must start before the first trigger "
                f"position and reach the last, in travel order: {first} ... {last}")

    @property
    def trigger_positions(self) -> tuple[float, ...]:
        """Where the triggers fire, in travel order."""
        if self.positions is not None:
            return tuple(self.positions)
        assert self.trigger_range is not None
        first, last, count = self.trigger_range
        if count == 1:
            return (first,)
        return tuple(first + (last - first) * i / (count - 1) for i in range(count))

    @property
    def expected(self) -> int:
        """How many trigger pulses the pass should give."""
        return len(self.trigger_positions)


@dataclasses.dataclass
class _Pass:
    """The context of one pass, threaded from prepare through kickoff to complete."""

    scan: TriggerScan
    travel: asyncio.Task[bool] | None = None
    #: Set when a stop ends the pass: whether it counts as success (RunEngine pause).
    stopped: bool | None = None
    #: When the trigger positions were uploaded (``time.time()``).
    uploaded: float = 0.0

    def stopped_ok(self, mover: Mover | None = None) -> bool:
        """Whether a stop(success=True), and no failing stop, ended the pass."""
        outcomes = {self.stopped, None if mover is None else mover.stopped} - {None}
        return outcomes == {True}


@dataclasses.dataclass(frozen=True)
class _PassResult:
    """What one completed pass gives: times are ``time.time()`` as the driver saw them."""

    number: int
    scan: TriggerScan
    trigger_count: int
    #: When the trigger positions were uploaded (or the range set).
    uploaded: float
    #: When ``?trigcount`` was read behind the pass's end.
    ended: float
    snapshots: tuple[tuple[float, ...], ...]
    #: When the snapshot array was read (the controller records no capture times).
    snapshots_read: float


@dataclasses.dataclass
class _FlyLogic(FlyableLogic[TriggerScan, _Pass]):
    """prepare: trigger list, ``!trigcount 0``, ``!trig 1``; kickoff: start the pass;
    complete: wait, then read ``?trigcount`` (and the snapshot array)."""

    link: StageLink
    results: list[_PassResult]
    running: list[_Pass] = dataclasses.field(default_factory=list)
    #: The latest pass prepared (describe_collect needs to know about snapshots).
    prepared: TriggerScan | None = None
    #: Passes completed so far (numbers the passes in the documents).
    passes: int = 0
    #: The announcement of the run-up move that prepare() made (ends once it joined).
    announced: Callable[[], None] = _nothing

    async def on_prepare(self, value: TriggerScan) -> _Pass:
        scan, ctx = value, _Pass(value)
        self.prepared = scan
        controller = self.link.controller
        # Settings first with the output disabled, then !trig 1 (L12529, L12565).
        await controller.set("trig", 0)
        if not await self._move(ctx, scan.start):
            return ctx  # stopped with success (RunEngine pause): nothing armed
        if scan.positions is not None:
            await controller.triggers.upload_positions(scan.positions, axis=scan.axis)
        else:
            assert scan.trigger_range is not None
            await controller.triggers.set_range(*scan.trigger_range, axis=scan.axis)
        ctx.uploaded = time.time()
        await controller.set("trigcount", 0)
        if scan.snapshots:
            await controller.set("snsc", 0)  # captures append (L15171-15222): start empty
        await controller.set("trig", 1)
        return ctx

    async def _move(self, ctx: _Pass, target: float) -> bool:
        """Move the pass's axis; False if a stop(success=True) ended the move."""
        announced, self.announced = self.announced, _nothing
        arrived = await _pass_move(self.link, ctx.scan.axis, target, ctx.stopped_ok,
                                   announced)
        if not arrived:
            ctx.stopped = True
        return arrived

    async def on_kickoff(self, ctx: _Pass) -> _Pass:
        if ctx.stopped is not None:
            raise MoveError(f"the preparation of the {ctx.scan.axis} pass was stopped",
                            {ctx.scan.axis: AxisStatus.ERROR.value})
        ctx.travel = asyncio.ensure_future(self._move(ctx, ctx.scan.end))
        self.running.append(ctx)
        await _started(self.link.controller, ctx.scan.axis, ctx.travel, ctx.stopped_ok)
        return ctx

    async def on_complete(self, ctx: _Pass) -> None:
        travel = ctx.travel
        assert travel is not None
        try:
            await asyncio.wait([travel])
        finally:
            if travel.done():
                self.running.remove(ctx)
        # A stop with success (RunEngine pause) gives no data: the plan replays the pass.
        if travel.cancelled():
            if ctx.stopped_ok():
                return
            raise MoveError(f"the fly pass of {ctx.scan.axis} was stopped",
                            {ctx.scan.axis: AxisStatus.ERROR.value})
        if not travel.result():  # raises the pass's error, if any
            return
        controller = self.link.controller
        count = int(await controller.get("trigcount"))
        ended = time.time()
        rows: list[list[float]] = []
        if ctx.scan.snapshots:
            rows = await controller.snapshots.read_positions()
        if count != ctx.scan.expected:
            log.warning("fly pass of %s gave %d trigger pulses, expected %d",
                        ctx.scan.axis, count, ctx.scan.expected)
        self.passes += 1
        self.results.append(_PassResult(self.passes, ctx.scan, count, ctx.uploaded, ended,
                                        tuple(map(tuple, rows)), time.time()))

    async def stop(self, success: bool = False) -> None:
        """Stop a running pass (its axis alone, ``a x``) and disable the trigger output;
        with ``success`` its ``complete()`` returns without data instead of failing."""
        for ctx in list(self.running):
            if ctx.travel is not None:
                ctx.stopped = success if ctx.stopped is None else ctx.stopped and success
                self.link.mark_stop(success, ctx.scan.axis)
                if not ctx.travel.done():
                    with contextlib.suppress(TangoError):
                        await self.link.halt(ctx.scan.axis)
                ctx.travel.cancel()
                await asyncio.wait([ctx.travel])
        if self.link.connected:
            with contextlib.suppress(TangoError):
                await self.link.controller.set("trig", 0)


class MarzhauserFlyer(StandardFlyable[TriggerScan, _Pass], Collectable, Stoppable, Pausable):
    """A hardware-triggered fly scan on a :class:`MarzhauserStage`.

    ``prepare(TriggerScan(...))`` moves the axis to the start of the pass, uploads the
    trigger list (or sets the range), clears the trigger counter and enables the trigger
    output; ``kickoff()`` starts the pass and returns once it runs; ``complete()`` waits
    for its end. ``collect()`` then yields, per pass, one event in the stream named like
    the flyer with ``<name>-trigger_count`` and ``<name>-triggers_expected``; one event
    per trigger position in ``<name>_triggers`` (pass, index, axis, position with its
    unit); and with ``snapshots`` one event per captured position in
    ``<name>_snapshots`` (``<name>-snapshot_x``... for the stage's axes only; the
    controller records no capture time, so these events carry the time the driver read
    the snapshot array, and their data keys say so). ``stop()`` stops a running pass (its
    axis alone, ``a x``) and disables the trigger output.

    Parameters
    ----------
    stage
        The stage whose axes fly.
    name
        The device name.
    """

    def __init__(self, stage: MarzhauserStage, name: str = "flyer") -> None:
        self._link = stage.link  # the plain link, never the stage (it would become a child)
        self._results: list[_PassResult] = []
        super().__init__(name=name, connector=_LinkConnector(stage.link))

    @functools.cached_property
    def flyable_logic(self) -> _FlyLogic:
        return _FlyLogic(self._link, self._results)

    def prepare(self, value: TriggerScan) -> AsyncStatus[None]:
        """Move to the start of the pass and arm the trigger output (see the class).
        The run-up move is announced at once, so that it merges with sets the RunEngine
        starts together with it (``fly_raster``: the slow axis's move of the row).

        Parameters
        ----------
        value
            The pass: its axis, start, end and trigger positions.

        Returns
        -------
        AsyncStatus[None]
            Done when the axis stands at the run-up start and the trigger output is armed.
        """
        logic = self.flyable_logic
        logic.announced()  # an earlier prepare's, if it never moved
        logic.announced = arrived = self._link.announce()
        status = super().prepare(value)
        status.add_callback(lambda _: arrived())
        return status

    async def stop(self, success: bool = False) -> None:
        """Stop a running pass (its axis alone, ``a x``) and disable the trigger output.
        Its ``complete()`` then fails with MoveError, or with ``success`` returns without
        data.

        Parameters
        ----------
        success
            Whether a running ``complete()`` returns (True) or fails (False).
        """
        await self.flyable_logic.stop(success)

    async def pause(self) -> None:
        """RunEngine pause: ``stop(success=True)``. The RunEngine only stops the devices
        it has ``set``, so without this a pass would fly on; on resume the plan is
        replayed from its last checkpoint (:func:`fly_raster`: the row)."""
        await self.stop(success=True)

    async def resume(self) -> None:
        """RunEngine resume: nothing to do (the replayed plan prepares the pass again)."""

    def _keys(self) -> tuple[str, str, dict[str, str]]:
        name = self.name
        return (f"{name}-trigger_count", f"{name}-triggers_expected",
                {axis: f"{name}-snapshot_{axis}" for axis in self._link.axes})

    def describe_collect(self) -> dict[str, dict[str, DataKey]]:
        """The streams :meth:`collect` fills (doubly nested: stream -> data keys): the
        trigger count per pass; the trigger positions of each pass (their own stream,
        one event per trigger, joined to detector frames by ``trigger_index``); with
        snapshots, one event per captured position, one key per axis of the stage.

        Returns
        -------
        dict[str, dict[str, DataKey]]
            The data keys of each stream, by stream name.
        """
        count_key, expected_key, snapshot_keys = self._keys()
        name, url = self.name, self._link.url
        source = f"{url} ?trigcount"
        streams: dict[str, dict[str, DataKey]] = {name: {
            count_key: {"source": source, "dtype": "integer", "shape": []},
            expected_key: {"source": f"{name} prepare", "dtype": "integer",
                           "shape": []},
        }}
        scan = self.flyable_logic.prepared or next(
            (result.scan for result in self._results), None)
        axis = scan.axis if scan is not None else self._link.axes[0]
        unit = self._link.units.get(axis, "")
        streams[f"{name}_triggers"] = {
            f"{name}-trigger_pass": {"source": f"{name} pass number", "dtype": "integer",
                                     "shape": []},
            f"{name}-trigger_index": {"source": f"{name} trigger index (0 = first pulse)",
                                      "dtype": "integer", "shape": []},
            f"{name}-trigger_axis": {"source": f"{name} prepare", "dtype": "string",
                                     "shape": []},
            f"{name}-trigger_position": {
                "source": f"{url} trigger positions of axis {axis} as uploaded "
                          "(!trigp, or computed from !trigr)",
                "dtype": "number", "shape": [], "units": unit,
                "precision": self._link.precision.get(axis, 4)},
        }
        if any(result.scan.snapshots for result in self._results) or \
                self._snapshots_prepared():
            streams[f"{name}_snapshots"] = {
                key: {"source": f"{url} ?snsa {letter} (event time: when the driver read "
                                "the snapshot array; the controller records no capture "
                                "time)",
                      "dtype": "number", "shape": [],
                      "units": self._link.units.get(letter, ""),
                      "precision": self._link.precision.get(letter, 4)}
                for letter, key in snapshot_keys.items()}
        return streams

    def _snapshots_prepared(self) -> bool:
        scan = self.flyable_logic.prepared
        return scan is not None and scan.snapshots

    def collect(self) -> Iterator[PartialEvent]:
        """Per completed pass: one event with the trigger count (at the time the count
        was read), one per trigger position (at the time of the upload), and one per
        snapshot row (at the time the array was read).

        Yields
        ------
        PartialEvent
            The events of the completed passes, in the order above.
        """
        count_key, expected_key, snapshot_keys = self._keys()
        name = self.name
        results, self._results[:] = list(self._results), []
        for result in results:
            yield {"data": {count_key: result.trigger_count,
                            expected_key: result.scan.expected},
                   "timestamps": {count_key: result.ended, expected_key: result.ended},
                   "time": result.ended}
            for index, position in enumerate(result.scan.trigger_positions):
                data: dict[str, Any] = {
                    f"{name}-trigger_pass": result.number, f"{name}-trigger_index": index,
                    f"{name}-trigger_axis": result.scan.axis,
                    f"{name}-trigger_position": position}
                yield {"data": data, "timestamps": dict.fromkeys(data, result.uploaded),
                       "time": result.uploaded}
            for row in result.snapshots:
                data = {key: row[AXES.index(letter)]
                        for letter, key in snapshot_keys.items()
                        if AXES.index(letter) < len(row)}
                yield {"data": data,
                       "timestamps": dict.fromkeys(data, result.snapshots_read),
                       "time": result.snapshots_read}


def fly_raster(stage: MarzhauserStage, flyer: MarzhauserFlyer,
               fast_start: float, fast_stop: float, fast_num: int,
               slow_start: float, slow_stop: float, slow_num: int, *,
               fast: str = "x", slow: str = "y", run_up: float = 0.5, snake: bool = True,
               snapshots: bool = False, md: dict[str, Any] | None = None
               ) -> MsgGenerator[str]:
    """A raster fly scan: ``slow_num`` rows at equidistant positions of the ``slow``
    axis; in each, the ``fast`` axis flies across with ``fast_num`` trigger pulses from
    ``fast_start`` to ``fast_stop`` (run-up ``run_up`` before the first and after the
    last). ``snake`` reverses every other row (the range is set again for each pass,
    L13581). Per row: one event with the slow axis's readback in the ``primary`` stream,
    then the flyer's events. Each row starts at a checkpoint, so a pause re-runs the row.

    Parameters
    ----------
    stage
        The stage whose axes fly.
    flyer
        The stage's flyer (the trigger output).
    fast_start
        The first trigger position of the fast axis.
    fast_stop
        The last trigger position of the fast axis.
    fast_num
        Triggers per row (at least 1).
    slow_start
        The first row position of the slow axis.
    slow_stop
        The last row position of the slow axis.
    slow_num
        Number of rows (at least 1).
    fast
        The letter of the fast axis.
    slow
        The letter of the slow axis.
    run_up
        Distance (EGU, positive) before the first and after the last trigger position.
    snake
        Reverse every other row.
    snapshots
        Capture the positions of every axis at each trigger (the flyer's snapshot stream).
    md
        Metadata merged into the start document.

    Yields
    ------
    Msg
        The plan's messages.

    Returns
    -------
    str
        The run's uid (the generator's return value).

    Raises
    ------
    ValueError
        ``fast_num`` or ``slow_num`` is below 1, or ``run_up`` is not positive.
    """
    if fast_num < 1 or slow_num < 1:
        raise ValueError("fast_num and slow_num must be at least 1")
    if not run_up > 0:
        raise ValueError("run_up must be positive: the pass must start before the first "
                         "trigger position")
    fast_axis, slow_axis = stage.axis(fast), stage.axis(slow)
    rows = [float(slow_start)] if slow_num == 1 else [
        float(slow_start) + (float(slow_stop) - float(slow_start)) * i / (slow_num - 1)
        for i in range(slow_num)]
    metadata = {
        "plan_name": "fly_raster",
        "motors": [slow_axis.name, fast_axis.name],
        "shape": [slow_num, fast_num],
        "plan_args": {"fast": fast, "slow": slow, "fast_start": float(fast_start),
                      "fast_stop": float(fast_stop), "fast_num": fast_num,
                      "slow_start": float(slow_start), "slow_stop": float(slow_stop),
                      "slow_num": slow_num, "run_up": run_up, "snake": snake},
        "hints": {"dimensions": [([slow_axis.user_readback.name], "primary")]},
        **(md or {}),
    }

    uid: str = yield from bps.open_run(metadata)
    for index, position in enumerate(rows):
        forward = not (snake and index % 2)
        first, last = (fast_start, fast_stop) if forward else (fast_stop, fast_start)
        first, last = float(first), float(last)
        sign = 1.0 if last > first or (last == first and forward) else -1.0
        scan = TriggerScan(fast, first - sign * run_up, last + sign * run_up,
                           trigger_range=(first, last, fast_num), snapshots=snapshots)
        yield from bps.checkpoint()
        group = f"row-{index}"
        yield from bps.abs_set(slow_axis, position, group=group)
        yield from bps.prepare(flyer, scan, group=group)
        yield from bps.wait(group=group)
        yield from bps.trigger_and_read([slow_axis])
        yield from bps.kickoff(flyer, wait=True)
        yield from bps.complete(flyer, wait=True)
        yield from bps.collect(flyer)
    yield from bps.close_run()
    return uid
