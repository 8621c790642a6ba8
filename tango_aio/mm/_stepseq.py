"""Stage sequences in Micro-Manager's convention: the stage steps to the next position on
each trigger from the camera, through the controller's snapshot array in step mode 5
(manual chapter 23: "Every snapshot event moves to the next array entry and wraps around
at the end", L14520-14526; mode 5 takes the snapshot input, L14789).

The stages of one controller share its one array: sequences loaded on the XY and the Z
stage with the same length become the columns of one array, each row one stop of the
stage. Where the manual is silent (which entry ``snsi`` names next, L15171-15190), the
first start finds out with one step of its own (``snse 2`` in mode 1, L14823) and keeps
the answer for the connection.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import tango_aio.sync
from tango_aio import MoveError
from tango_aio.status import FAILED_LETTERS
from tango_aio.units import Measure, from_controller, to_controller

from ._hub import UNIT, TangoHub
from ._moves import Moves

_log = logging.getLogger("tango_aio.mm")

#: The snapshot array holds up to 1024 entries (L14550).
MAX_LENGTH = 1024
#: Snapshot modes: step with the key F2, step on the snapshot input (L14759, L14789).
STEP_KEY, STEP_INPUT = 1, 5
#: Bound on the wait for a step to end: only a hang reaches it (seconds).
STEP_WAIT = 600.0
AXES = "xyza"


@dataclass
class StepArray:
    """One controller's snapshot array as its stages loaded it (thread-safe)."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    #: Held while a start arms the array or a stop disarms it (in the driver's loop): the
    #: XY and the Z stage start together, and their lines must not interleave.
    arming: asyncio.Lock = field(default_factory=asyncio.Lock)
    #: The positions of each axis, in µm, one per entry.
    columns: dict[str, tuple[float, ...]] = field(default_factory=dict)
    #: Whether a step moves the pointer on before reading its entry; ``None``: not known.
    advance_first: bool | None = None
    #: The user's ``snsm`` and ``sns`` before the first load, put back at the last stop.
    saved: tuple[int, bool] | None = None
    #: The axes of the sequences running now.
    running: set[str] = field(default_factory=set)

    def load(self, axes: Sequence[str], columns: Sequence[tuple[float, ...]]
             ) -> dict[str, tuple[float, ...]]:
        """Make ``columns`` the array's positions of ``axes``; those of other axes stay
        when they are as long and no sequence runs, else they go. The whole array."""
        with self.lock:
            if self.running:
                raise RuntimeError("a camera-triggered sequence runs: stop it first")
            count = len(columns[0])
            kept = {axis: column for axis, column in self.columns.items()
                    if axis not in axes and len(column) == count}
            kept.update(zip(axes, columns, strict=True))
            self.columns = {axis: kept[axis] for axis in AXES if axis in kept}
            return dict(self.columns)


_ARRAYS: weakref.WeakKeyDictionary[TangoHub, StepArray] = weakref.WeakKeyDictionary()
_ARRAYS_LOCK = threading.Lock()


def array_of(hub: TangoHub) -> StepArray:
    """The snapshot array of ``hub``'s controller."""
    with _ARRAYS_LOCK:
        array = _ARRAYS.get(hub)
        if array is None:
            array = _ARRAYS[hub] = StepArray()
        return array


def checked(values: Sequence[float]) -> tuple[float, ...]:
    """A sequence's positions, checked before any byte: 1..1024 finite numbers."""
    out = tuple(float(value) for value in values)
    if not 1 <= len(out) <= MAX_LENGTH:
        raise ValueError(f"a camera-triggered sequence holds 1..{MAX_LENGTH} positions "
                         f"(the snapshot array, L14550), got {len(out)}")
    if not all(math.isfinite(value) for value in out):
        raise ValueError(f"a sequence position is not finite: {out!r}")
    return out


@dataclass(frozen=True)
class StepStop:
    """Where a stopped sequence left the stage."""

    #: The entry it stands at, from 0.
    entry: int
    #: The number of entries.
    count: int
    #: Where each axis of the array stands, in µm (read).
    positions: Mapping[str, float]

    def __str__(self) -> str:
        where = ", ".join(f"{axis}={value:g} um" for axis, value in self.positions.items())
        return f"entry {self.entry + 1} of {self.count} ({where})"


# -- in the driver's thread ---------------------------------------------------------------

async def upload(tango: Any, array: StepArray,
                 columns: Mapping[str, tuple[float, ...]]) -> None:
    """Write the array (``!snsa 0``, then ``!snsa n x y ...`` per entry, in each axis's dim
    unit, L15324-15390) with snapshots off (L14554-14556), the user's snapshot mode kept
    for the stop; axes without a column hold no position, a step leaves them
    (L15389-15390)."""
    scales = await tango.settings.unit_scales()
    dim = {axis: [to_controller(value, UNIT, Measure.POSITION, scales[axis])
                  for value in column] for axis, column in columns.items()}
    snapshots = tango.snapshots
    if array.saved is None:
        array.saved = (int(await snapshots.snsm()), bool(await snapshots.sns()))
    await snapshots.set_sns(False)
    await tango.command("!snsa 0")
    for index in range(len(next(iter(columns.values())))):
        await snapshots.set_snsa(index + 1, **{axis: dim[axis][index] for axis in dim})


async def _tolerance(tango: Any, axes: Sequence[str]) -> dict[str, float]:
    """One and a half of ``?pos``'s last printed digits per axis, in µm (``resolution``,
    L4109)."""
    digits = int(await tango.get("resolution"))
    scales = await tango.settings.unit_scales()
    return {axis: 1.5 * abs(from_controller(10.0 ** -digits, UNIT, Measure.POSITION,
                                            scales[axis])) for axis in axes}


async def _stand(tango: Any, axes: Sequence[str], what: str) -> dict[str, float]:
    """Wait until no axis moves; the positions of ``axes`` in µm, or a MoveError if one
    of them shows a failure letter."""
    letters = await tango.wait_idle(timeout=STEP_WAIT)
    here = await tango.position()
    failed = {axis: letters.get(axis, "") for axis in axes
              if letters.get(axis, "") in FAILED_LETTERS}
    if failed:
        raise MoveError(f"{what}: {', '.join(f'{a.upper()} {s}' for a, s in failed.items())}"
                        f" (status letters), standing at {_where(here, axes)}",
                        letters)
    return {axis: float(here[axis]) for axis in axes}


def _where(here: Mapping[str, Any], axes: Sequence[str]) -> str:
    return ", ".join(f"{axis.upper()}={float(here[axis]):g} um" for axis in axes)


def _at(here: Mapping[str, float], row: Mapping[str, float],
        tolerance: Mapping[str, float]) -> bool:
    return all(abs(here[axis] - value) <= tolerance[axis] for axis, value in row.items())


def _rows(columns: Mapping[str, tuple[float, ...]]) -> list[dict[str, float]]:
    count = len(next(iter(columns.values())))
    return [{axis: column[index] for axis, column in columns.items()}
            for index in range(count)]


async def _find_pointer(tango: Any, columns: Mapping[str, tuple[float, ...]]) -> bool:
    """Whether a step moves the pointer on before it reads its entry: one step with the
    key F2 in mode 1 (``snse 2``, L14823) from a pointer whose entry differs from the next
    one, and where the stage stood after it."""
    rows = _rows(columns)
    first = next((k for k in range(len(rows) - 1) if rows[k] != rows[k + 1]), None)
    if first is None:
        return False  # every entry alike: both readings step to the same place
    snapshots = tango.snapshots
    await snapshots.set_snsm(STEP_KEY)
    await snapshots.set_sns(True)
    await snapshots.set_snsi(first)
    await snapshots.snse(2)
    try:
        here = await _stand(tango, list(columns), "the step that reads the pointer")
    finally:
        await snapshots.set_sns(False)
    tolerance = await _tolerance(tango, list(columns))
    if _at(here, rows[first], tolerance):
        return False
    if _at(here, rows[first + 1], tolerance):
        return True
    raise MoveError(f"a step from entry {first + 1} stands at {_where(here, list(columns))}"
                    f", at neither entry {first + 1} nor {first + 2}",
                    await tango.status())


async def start(tango: Any, array: StepArray, axes: Sequence[str]) -> None:
    """Move the array's axes to its first entry (the first frame's position), then step
    mode 5 with snapshots on and the pointer on the second entry: each trigger from the
    camera moves them to the next one."""
    with array.lock:
        columns = dict(array.columns)
        missing = [axis for axis in axes if axis not in columns]
        if missing or not columns:
            raise RuntimeError("no camera-triggered sequence loaded for this stage (another "
                               "stage's sequence of another length replaced it)")
        array.running.update(axes)
    async with array.arming:
        await _arm(tango, array, axes, columns)


async def _arm(tango: Any, array: StepArray, axes: Sequence[str],
               columns: Mapping[str, tuple[float, ...]]) -> None:
    snapshots = tango.snapshots
    try:
        await snapshots.set_sns(False)
        if array.advance_first is None:
            array.advance_first = await _find_pointer(tango, columns)
        await tango.move_to(**_rows(columns)[0])
        count = len(next(iter(columns.values())))
        pointer = 0 if array.advance_first else 1 % count
        await snapshots.set_snsm(STEP_INPUT)
        await snapshots.set_sns(True)
        await snapshots.set_snsi(pointer)
        shown = int(await snapshots.snsi())
        if shown != pointer:
            raise RuntimeError(f"the snapshot pointer reads {shown} after !snsi {pointer}"
                               ": the sequence is not armed")
    except Exception:
        await _release(tango, array, axes)
        raise


async def _release(tango: Any, array: StepArray, axes: Sequence[str]) -> None:
    """Snapshots off, the axes no longer running, the user's snapshot mode back once no
    sequence runs."""
    snapshots = tango.snapshots
    with array.lock:
        array.running.difference_update(axes)
        saved = array.saved if not array.running else None
        if saved is not None:
            array.saved = None
    await snapshots.set_sns(False)
    if saved is not None:
        await snapshots.set_snsm(saved[0])
        await snapshots.set_sns(saved[1])


async def stop(tango: Any, array: StepArray, axes: Sequence[str]) -> StepStop | None:
    """Nothing if no sequence of ``axes`` runs; else snapshots off (no trigger moves the
    stage any more), a step under way ended, the user's snapshot mode back once no
    sequence runs; where the stage stands, checked against the entry the last step went
    to."""
    async with array.arming:
        return await _disarm(tango, array, axes)


async def _disarm(tango: Any, array: StepArray, axes: Sequence[str]) -> StepStop | None:
    snapshots = tango.snapshots
    with array.lock:
        if not array.running.intersection(axes):
            return None  # nothing of this stage runs: the user's snapshots untouched
        columns = dict(array.columns)
    await snapshots.set_sns(False)
    try:
        here = await _stand(tango, list(columns), "a step of the sequence failed")
        pointer = int(await snapshots.snsi())
    finally:
        await _release(tango, array, axes)
    rows = _rows(columns)
    entry = (pointer if array.advance_first else pointer - 1) % len(rows)
    if not _at(here, rows[entry], await _tolerance(tango, list(columns))):
        raise MoveError(f"the sequence stopped with the stage at {_where(here, list(columns))}"
                        f", not at entry {entry + 1} of {len(rows)} where its last step "
                        "went (a step that ended short, or was refused while the stage "
                        "still moved: a trigger came too early)", await tango.status())
    return StepStop(entry, len(rows), here)


# -- a stage's side (the core's threads) --------------------------------------------------

class CameraSteps:
    """One stage's camera-triggered sequences: its axes' columns of the controller's
    array, loaded, started and stopped through the driver's thread."""

    def __init__(self, hub: TangoHub, axes: tuple[str, ...], moves: Moves) -> None:
        self._hub = hub
        self._axes = axes
        self._moves = moves
        self.stopped: StepStop | None = None

    @property
    def _controller(self) -> tango_aio.sync.Controller:
        return self._hub.controller

    def load(self, columns: Sequence[Sequence[float]]) -> None:
        """Make ``columns`` (one per axis, µm) this stage's part of the array and write
        the array; checked before any byte."""
        checked_columns = [checked(column) for column in columns]
        if len({len(column) for column in checked_columns}) != 1:
            raise ValueError("the axes' sequences differ in length")
        self._moves.check()
        whole = array_of(self._hub).load(self._axes, checked_columns)
        tango = self._controller
        tango.portal.call(upload, tango.aio, array_of(self._hub), whole)

    def start(self) -> None:
        """Start arming in the driver's thread; the stage is busy until armed."""
        self._moves.check()
        tango = self._controller
        self._moves.add(tango.portal.start(start, tango.aio, array_of(self._hub),
                                           self._axes))

    def stop(self) -> None:
        """Stop stepping (nothing if no sequence runs): :attr:`stopped` and the log say
        where the stage stands; a MoveError if it is not where its last step went."""
        for move in self._moves.stopping():
            move.cancel()
        tango = self._controller
        where = tango.portal.call(stop, tango.aio, array_of(self._hub), self._axes)
        if where is not None:
            self.stopped = where
            _log.info("camera-triggered sequence stopped at %s", where)
