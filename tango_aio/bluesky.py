"""TANGO stages as ophyd-async devices for Bluesky (``pip install 'tango-aio[bluesky]'``).

Tested with ophyd-async 0.21 and bluesky 1.15 (the extra pins ophyd-async to 0.21.x,
because its motor API changes between releases)::

    from bluesky import RunEngine
    import bluesky.plans as bp
    from ophyd_async.core import init_devices
    from tango_aio.bluesky import MarzhauserStage

    RE = RunEngine()
    with init_devices():                    # connects on the RunEngine's event loop
        stage = MarzhauserStage("sim://?baud=0", axes="xy")
    RE(bp.grid_scan([stage], stage.y, 0, 1, 3, stage.x, 0, 2, 5))

Devices:

* :class:`MarzhauserStage` - one controller; a child :class:`MarzhauserAxis` per axis
  letter (``stage.x``, ``stage.y``...). ``connect()`` opens the driver (on the event loop
  it runs on, which :func:`ophyd_async.core.init_devices` makes the RunEngine's) and
  checks that the controller has the axes.
* :class:`MarzhauserAxis` - Movable, Locatable, Stoppable, Readable, Configurable:
  ``user_readback`` (hinted; named like the axis, e.g. ``stage-x``) and
  ``user_setpoint`` in the axis's ``dim`` unit with the precision the controller's
  ``?pos`` replies carry; ``velocity``, ``acceleration``, ``low_limit_travel`` and
  ``high_limit_travel`` as configuration. ``set()`` checks the limits (``?lim``), reports
  progress (:class:`~ophyd_async.core.WatcherUpdate` from positions polled while the
  move runs) and publishes the final readback before it completes.
* :class:`MarzhauserFlyer` - a hardware-triggered fly scan of one axis with the trigger
  output (and, optionally, snapshot capture); :func:`fly_raster` runs a raster of them.

Behaviour that follows from the controller:

* Moves on one controller run one after another. Sets of different axes that arrive
  within ``window`` seconds (``bps.mv(stage.x, 1, stage.y, 2)``) are merged by
  :class:`~tango_aio.coalesce.MoveCoalescer` into one ``!moa`` line.
* ``stop()`` of any axis sends ``a``, which stops *every* axis of the controller
  (manual L6785-6800): a move of another axis then fails with
  :class:`~tango_aio.errors.MoveError`. ``stop(success=False)`` makes the stopped
  axis's ``set()`` status fail; ``success=True`` (RunEngine pause) completes it.
* Devices share a plain :class:`StageLink` (URL, open controller, coalescer); an axis
  never keeps its parent device as an attribute, because ophyd-async would adopt it as a
  child.
* Numbers from plans are numpy scalars; they are converted with ``float()`` here.
* ``init_devices(mock=True)`` connects the stage without a controller: the axes move
  instantly (ophyd-async's mock behaviour), for testing plans. The flyer needs a
  controller.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import itertools
import logging
import math
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Sequence
from typing import Any

try:
    import bluesky.plan_stubs as bps
    from bluesky.protocols import Collectable, Pausable, Stoppable
    from bluesky.utils import MsgGenerator
    from event_model import DataKey, PartialEvent
    from ophyd_async.core import (
        DEFAULT_TIMEOUT,
        Device,
        DeviceConnector,
        DeviceMock,
        FlyableLogic,
        MovableLogic,
        SignalR,
        SignalRW,
        SoftSignalBackend,
        StandardFlyable,
        StandardMovable,
        StandardReadable,
        StandardReadableFormat,
        TimeoutCalculator,
    )
except ImportError as exc:  # pragma: no cover - depends on the environment
    raise ImportError("tango_aio.bluesky needs the bluesky extra: "
                      "pip install 'tango-aio[bluesky]'") from exc

from .coalesce import MoveCoalescer
from .connection import connect
from .controller import Controller
from .errors import ControllerTimeoutError, InvalidCommandError, MoveError, TangoError
from .instructions import AXES
from .motion import STOP_WAIT
from .units import DIM_MM_VEL

__all__ = [
    "MarzhauserAxis",
    "MarzhauserFlyer",
    "MarzhauserStage",
    "MissingAxisError",
    "StageLimitsError",
    "StageLink",
    "TriggerScan",
    "close_stage",
    "fly_raster",
]

log = logging.getLogger(__name__)

#: Position unit of each ``dim`` (manual L3061-3144); dim 9 is mm with velocities in mm/s.
DIM_UNITS = {0: "µstep", 1: "µm", 2: "mm", 3: "deg", 4: "rev", 5: "cm", 6: "m",
             7: "in", 8: "mil", 9: "mm"}
#: ``accel`` is always in m/s² (manual L3303, L3329; see tango_aio.units).
ACCEL_UNIT = "m/s^2"


class StageLimitsError(InvalidCommandError):
    """A target lies outside the axis's travel limits (``?lim``); nothing was moved."""


class MissingAxisError(TangoError, LookupError):
    """The controller does not have an axis the device was asked to provide."""


# --------------------------------------------------------------------------------------
# What the devices of one stage share


@dataclasses.dataclass(eq=False)
class Mover:
    """One running move of a :class:`StageLink`'s devices. ``stopped``: ``None`` unless
    a stop was requested while it ran; then whether that stop counts as success."""

    stopped: bool | None = None

    @property
    def stopped_ok(self) -> bool:
        """Whether a ``stop(success=True)`` (and no failing stop) ended this move."""
        return self.stopped is True


class StageLink:
    """The connection shared by a stage's axes and flyers (a plain object, no Device).

    Holds the URL and connect options, the open :class:`~tango_aio.controller.Controller`,
    its :class:`~tango_aio.coalesce.MoveCoalescer`, the axes' units and precision (read
    when opening), and the readback publishers of the axes: while any move of this link
    runs, one task polls ``?pos`` every ``progress_interval`` seconds and hands the
    positions to every axis's readback.
    """

    def __init__(self, url: str, axes: str, options: dict[str, Any], *,
                 window: float = 0.02, progress_interval: float = 0.1) -> None:
        self.url = url
        self.axes = axes
        self.options = dict(options)
        self.window = window
        self.progress_interval = progress_interval
        #: Per axis: position unit, velocity unit, decimals of the position replies.
        self.units: dict[str, str] = {}
        self.velocity_units: dict[str, str] = {}
        self.precision: dict[str, int] = {}
        self._controller: Controller | None = None
        self._coalescer: MoveCoalescer | None = None
        self._lock: asyncio.Lock | None = None
        self._publishers: dict[str, list[Callable[[float], None]]] = {}
        self._movers: set[Mover] = set()
        self._poller: asyncio.Task[None] | None = None

    # -- lifecycle ------------------------------------------------------------------------

    @property
    def controller(self) -> Controller:
        """The open controller (raises :class:`TangoError` before ``connect()``)."""
        if self._controller is None:
            raise TangoError(f"{self.url!r} is not connected: connect the device first")
        return self._controller

    @property
    def connected(self) -> bool:
        """Whether the controller is open (between ``open()`` and ``aclose()``)."""
        return self._controller is not None

    @property
    def coalescer(self) -> MoveCoalescer:
        """The move coalescer of the open controller."""
        if self._coalescer is None:
            raise TangoError(f"{self.url!r} is not connected: connect the device first")
        return self._coalescer

    async def open(self) -> None:
        """Open the controller on the running event loop (once; later calls return at
        once) and check that it has every axis of the stage."""
        if self._lock is None:
            self._lock = asyncio.Lock()
        async with self._lock:
            if self._controller is not None:
                return
            controller = await connect(self.url, **self.options)
            try:
                await self._inspect(controller)
            except BaseException:
                await controller.aclose()
                raise
            self._controller = controller
            self._coalescer = MoveCoalescer(controller, window=self.window)

    async def aclose(self) -> None:
        """Stop what this link moves and close the controller."""
        if self._poller is not None:
            self._poller.cancel()
        coalescer, self._coalescer = self._coalescer, None
        controller, self._controller = self._controller, None
        if coalescer is not None:
            await coalescer.aclose()
        if controller is not None:
            await controller.aclose()

    async def _inspect(self, controller: Controller) -> None:
        present = AXES[: controller.context.axes]
        missing = [axis for axis in self.axes if axis not in present]
        if missing:
            raise MissingAxisError(
                f"{self.url!r} has {controller.context.axes} axes ({', '.join(present)}); "
                f"no {', '.join(missing)}")
        dims = controller.context.dims
        # Decimals as the controller prints them (resolution, dim: L4109-4162), detected
        # from a real reply rather than computed from settings.
        words = (await controller.query("?pos")).split()
        for axis in self.axes:
            index = AXES.index(axis)
            dim = int(dims[index])
            self.units[axis] = DIM_UNITS.get(dim, "")
            self.velocity_units[axis] = "mm/s" if dim == DIM_MM_VEL else "rev/s"
            word = words[index] if index < len(words) else ""
            self.precision[axis] = len(word.partition(".")[2])

    # -- positions and progress -----------------------------------------------------------

    def add_publisher(self, axis: str, publish: Callable[[float], None]) -> None:
        """Call ``publish(position)`` whenever the link reads the position of ``axis``."""
        self._publishers.setdefault(axis, []).append(publish)

    async def positions(self) -> dict[str, float]:
        """Read every position (``?pos``) and publish it to the axes' readbacks."""
        positions = await self.controller.position()
        for axis, publishers in self._publishers.items():
            if axis in positions:
                for publish in publishers:
                    publish(positions[axis])
        return positions

    async def position(self, axis: str) -> float:
        """The position of ``axis`` (published to the readbacks as well)."""
        return (await self.positions())[axis]

    @contextlib.asynccontextmanager
    async def moving(self) -> AsyncIterator[Mover]:
        """Run a move of this link's devices: while any such block runs, positions are
        polled every ``progress_interval`` and published; on leaving, the position is
        published once more (the final readback), also when the move failed. The
        :class:`Mover` says whether a stop ended the move, and with which outcome."""
        mover = Mover()
        self._movers.add(mover)
        if self._poller is None or self._poller.done():
            self._poller = asyncio.ensure_future(self._poll())
        try:
            yield mover
        finally:
            self._movers.discard(mover)
            if not self._movers and self._poller is not None:
                self._poller.cancel()
            with contextlib.suppress(TangoError):
                await self.positions()

    async def _poll(self) -> None:
        while self._movers:
            await asyncio.sleep(self.progress_interval)
            with contextlib.suppress(TangoError):
                await self.positions()

    @property
    def in_flight(self) -> int:
        """How many moves of this link's devices are running."""
        return len(self._movers)

    def mark_stop(self, success: bool) -> None:
        """A stop is coming: record its outcome on every move now running. ``a`` stops
        every axis, so the moves of the other devices end too; with ``success`` (the
        RunEngine's pause) they complete instead of failing. A failing stop wins."""
        for mover in self._movers:
            mover.stopped = success if mover.stopped is None else mover.stopped and success

    async def halt(self) -> None:
        """Send ``a`` (stops every axis of the controller, L6785-6800) if a move of this
        link runs or any axis moves; otherwise write nothing. Returns without waiting:
        see :meth:`wait_still`."""
        controller = self._controller
        if controller is None:
            return  # nothing of ours can move
        if not self._movers and "M" not in (await controller.status()).values():
            return
        await controller.abort(soft=True, wait=False)

    async def wait_still(self) -> None:
        """Wait until no axis moves (polling ``statusaxis``); raise
        :class:`~tango_aio.errors.ControllerTimeoutError` if one still moves after
        ``STOP_WAIT`` seconds."""
        controller = self._controller
        if controller is None:
            return
        try:
            await controller.wait_idle(timeout=STOP_WAIT)
        except ControllerTimeoutError:
            raise  # a status query went unanswered
        except TimeoutError:
            raise ControllerTimeoutError(
                f"{self.url!r}: axes still moving {STOP_WAIT} s after the stop") from None


class _LinkConnector(DeviceConnector):
    """Opens the shared :class:`StageLink` before connecting the children."""

    def __init__(self, link: StageLink) -> None:
        self.link = link

    async def connect_real(self, device: Device, timeout: float,
                           force_reconnect: bool) -> None:
        async with asyncio.timeout(timeout):
            await self.link.open()
        await super().connect_real(device, timeout, force_reconnect)


class _Backend(SoftSignalBackend[float]):
    """A soft float signal's backend whose source names the controller instruction; the
    devices keep it to set units and precision once connected."""

    def __init__(self, source: str, units: str | None = None, *,
                 getter: Callable[[], Any] | None = None,
                 setter: Callable[[float | None], Awaitable[float | None]] | None = None
                 ) -> None:
        super().__init__(float, 0.0, units, getter=getter, setter=setter)
        self._source = source

    def source(self, name: str, read: bool) -> str:
        return self._source


# --------------------------------------------------------------------------------------
# Axes


@dataclasses.dataclass
class _AxisLogic(MovableLogic[float]):
    """How a :class:`MarzhauserAxis` moves: through the link's coalescer."""

    link: StageLink
    axis: str
    #: Resolved when the latest move() has ended (its clean-up included).
    ended: asyncio.Future[None] | None = dataclasses.field(default=None, init=False)
    #: Connected with ``mock=True``: ophyd-async's mock signals move instantly, no
    #: controller is involved (for testing plans without hardware).
    mocked: bool = dataclasses.field(default=False, init=False)

    async def stop(self) -> None:
        if self.mocked:
            return
        # Called before StandardMovable.stop cancels our move: no waiting here, or the
        # move would end (with the letters of the abort) before it is cancelled.
        await self.link.halt()

    async def wait_stopped(self) -> None:
        """Wait until the latest move has ended and the axes stand still (bounded)."""
        if self.ended is not None:
            await asyncio.wait([self.ended], timeout=STOP_WAIT + 5)
        await self.link.wait_still()

    async def check_move(self, new_position: float) -> None:
        target = float(new_position)
        if not math.isfinite(target):
            raise StageLimitsError(f"{self.axis}: target {target!r} is not a finite number",
                                   instruction="moa", parameter="position", number=5)
        if self.mocked:
            return
        low, high = await _limits(self.link, self.axis)
        if not low <= target <= high:
            raise StageLimitsError(
                f"{self.axis}: target {target} outside the limits [{low}, {high}] "
                f"{self.link.units.get(self.axis, '')}", instruction="moa",
                parameter="position", number=5)

    async def get_units_precision(self) -> tuple[str | None, int | None]:
        return self.link.units.get(self.axis), self.link.precision.get(self.axis)

    async def move(self, new_position: float, timeout: TimeoutCalculator) -> None:
        # The controller bounds each move with its own estimate (Controller.move_to);
        # an explicit set(timeout=...) is applied on top.
        target = float(new_position)
        if self.mocked:
            await super().move(target, timeout)
            return
        self.ended = ended = asyncio.get_running_loop().create_future()
        try:
            await self.setpoint.set(target)
            async with self.link.moving() as mover, asyncio.timeout(timeout()):
                try:
                    await self.link.coalescer.move_to(self.axis, target)
                except MoveError:
                    # ``a`` of another device's stop(success=True) (RunEngine pause)
                    # ended this move too: complete, as StandardMovable does for ours.
                    if not mover.stopped_ok:
                        raise
        finally:
            ended.set_result(None)


async def _limits(link: StageLink, axis: str) -> tuple[float, float]:
    low, high = await link.controller.get("lim", axis=axis)
    return float(low), float(high)


class MarzhauserAxis(StandardReadable, StandardMovable[float]):
    """One axis of a :class:`MarzhauserStage` (created by the stage)."""

    def __init__(self, link: StageLink, axis: str, name: str = "") -> None:
        self._link = link  # a plain object: ophyd-async does not adopt it as a child
        self._axis = axis
        where = f"{link.url} {{}} {axis}".format
        self._readback = _Backend(where("?pos"), getter=self._read_position)
        self._setpoint = _Backend(where("!moa"))
        self._velocity = _Backend(where("vel"), getter=lambda: self._get("vel"),
                                  setter=functools.partial(self._put, "vel"))
        self._acceleration = _Backend(where("accel"), ACCEL_UNIT,
                                      getter=lambda: self._get("accel"),
                                      setter=functools.partial(self._put, "accel"))
        self._low = _Backend(where("?lim"), getter=lambda: self._limit(0))
        self._high = _Backend(where("?lim"), getter=lambda: self._limit(1))
        with self.add_children_as_readables(StandardReadableFormat.HINTED_SIGNAL):
            self.user_readback = SignalR(backend=self._readback)
        self.user_setpoint = SignalRW(backend=self._setpoint)
        with self.add_children_as_readables(StandardReadableFormat.CONFIG_SIGNAL):
            self.velocity = SignalRW(backend=self._velocity)
            self.acceleration = SignalRW(backend=self._acceleration)
            self.low_limit_travel = SignalR(backend=self._low)
            self.high_limit_travel = SignalR(backend=self._high)
        link.add_publisher(axis, self._readback.set_value)
        super().__init__(name=name)

    @property
    def axis(self) -> str:
        """The axis letter (``"x"``...)."""
        return self._axis

    async def stop(self, success: bool = False) -> None:
        """Stop the stage (``a`` stops every axis) and return once the axes stand still.
        A running ``set()`` of this axis then fails (``success=False``: RuntimeError) or
        completes (``success=True``, as the RunEngine does on pause)."""
        self._link.mark_stop(success)
        await super().stop(success=success)  # type: ignore[no-untyped-call]
        await self.movable_logic.wait_stopped()

    @functools.cached_property
    def movable_logic(self) -> _AxisLogic:
        return _AxisLogic(setpoint=self.user_setpoint, readback=self.user_readback,
                          link=self._link, axis=self._axis)

    def _set_units(self) -> None:
        """Take the units and precision the link read when it opened."""
        units = self._link.units.get(self._axis)
        precision = self._link.precision.get(self._axis)
        for backend in (self._readback, self._setpoint, self._low, self._high):
            backend.metadata["units"] = units or ""
            if precision is not None:
                backend.metadata["precision"] = precision
        self._velocity.metadata["units"] = self._link.velocity_units.get(self._axis, "")

    # Getters and setters of the signals; connected with mock=True they keep the value
    # in the signal and never reach for a controller.

    def _mocked(self, backend: _Backend) -> float | None:
        return float(backend.reading["value"]) if self.movable_logic.mocked else None

    async def _read_position(self) -> float:
        cached = self._mocked(self._readback)
        return await self._link.position(self._axis) if cached is None else cached

    async def _get(self, name: str) -> float:
        cached = self._mocked(self._velocity if name == "vel" else self._acceleration)
        if cached is not None:
            return cached
        return float(await self._link.controller.get(name, axis=self._axis))

    async def _put(self, name: str, value: float | None) -> float | None:
        if value is None:
            raise ValueError(f"{self.name}: {name} needs a number")
        if self.movable_logic.mocked:
            return float(value)
        await self._link.controller.set(name, float(value), axis=self._axis)
        return None  # read back from the controller

    async def _limit(self, which: int) -> float:
        cached = self._mocked(self._high if which else self._low)
        if cached is not None:
            return cached
        return (await _limits(self._link, self._axis))[which]

    async def connect(self, mock: bool | DeviceMock[Any] = False, timeout: float = DEFAULT_TIMEOUT,
                      force_reconnect: bool = False) -> None:
        """Connect (the stage has opened the link); take units, precision and the current
        position as the setpoint, so that ``locate()`` is right from the start."""
        await super().connect(mock=mock, timeout=timeout, force_reconnect=force_reconnect)
        self.movable_logic.mocked = bool(mock)
        if not mock:
            self._set_units()
            await self.user_setpoint.set(await self._read_position())


class MarzhauserStage(StandardReadable):
    """A TANGO controller as an ophyd-async device with one child axis per letter.

    ``MarzhauserStage(url, axes="xy", name="stage", **connect_options)``:
    ``connect_options`` go to :func:`tango_aio.connect`; ``window`` (0.02 s) is how long
    sets of different axes are collected into one move, ``progress_interval`` (0.1 s)
    how often positions are polled while a move runs. ``stage.x``, ``stage.y``... (or
    ``stage.axis("x")``) are the :class:`MarzhauserAxis` children; ``read()`` reads them
    all. Close with ``await stage.aclose()`` (or the :func:`close_stage` plan stub).
    """

    x: MarzhauserAxis
    y: MarzhauserAxis
    z: MarzhauserAxis
    a: MarzhauserAxis

    def __init__(self, url: str, axes: str = "xy", name: str = "stage", *,
                 window: float = 0.02, progress_interval: float = 0.1,
                 **connect_options: Any) -> None:
        letters = axes.lower()
        if not letters or len(set(letters)) != len(letters) or set(letters) - set(AXES):
            raise ValueError(f"axes must be distinct letters of {AXES!r}, got {axes!r}")
        self._link = StageLink(url, letters, connect_options, window=window,
                               progress_interval=progress_interval)
        self._axes: dict[str, MarzhauserAxis] = {}
        with self.add_children_as_readables():
            for letter in letters:
                axis = MarzhauserAxis(self._link, letter)
                setattr(self, letter, axis)
                self._axes[letter] = axis
        super().__init__(name=name, connector=_LinkConnector(self._link))

    @property
    def link(self) -> StageLink:
        """The link shared by the axes (and by flyers made for this stage)."""
        return self._link

    @property
    def controller(self) -> Controller:
        """The open controller (after ``connect()``), for anything the devices lack."""
        return self._link.controller

    def axis(self, letter: str) -> MarzhauserAxis:
        """The child axis ``letter``."""
        try:
            return self._axes[letter.lower()]
        except KeyError:
            raise MissingAxisError(f"{self.name} has no axis {letter!r}") from None

    async def aclose(self) -> None:
        """Stop what the devices move and close the controller."""
        await self._link.aclose()


def close_stage(stage: MarzhauserStage) -> MsgGenerator[None]:
    """Plan stub: close the stage's controller on the RunEngine's loop."""
    yield from bps.wait_for([stage.aclose])


# --------------------------------------------------------------------------------------
# Hardware-triggered fly scans


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

    def stopped_ok(self, mover: Mover | None = None) -> bool:
        """Whether a stop(success=True), and no failing stop, ended the pass."""
        outcomes = {self.stopped, None if mover is None else mover.stopped} - {None}
        return outcomes == {True}


@dataclasses.dataclass(frozen=True)
class _PassResult:
    scan: TriggerScan
    trigger_count: int
    snapshots: tuple[tuple[float, ...], ...]
    time: float


@dataclasses.dataclass
class _FlyLogic(FlyableLogic[TriggerScan, _Pass]):
    """prepare: trigger list, ``!trigcount 0``, ``!trig 1``; kickoff: start the pass;
    complete: wait, then read ``?trigcount`` (and the snapshot array)."""

    link: StageLink
    results: list[_PassResult]
    running: list[_Pass] = dataclasses.field(default_factory=list)
    #: The latest pass prepared (describe_collect needs to know about snapshots).
    prepared: TriggerScan | None = None

    async def on_prepare(self, value: TriggerScan) -> _Pass:
        scan, ctx = value, _Pass(value)
        self.prepared = scan
        controller = self.link.controller
        # Settings first with the output disabled, then !trig 1 (L12529, L12565).
        await controller.set("trig", 0)
        if not await self._move(ctx, scan.start):
            return ctx  # stopped with success (RunEngine pause): nothing armed
        if scan.positions is not None:
            await controller.upload_trigger_positions(scan.positions, axis=scan.axis)
        else:
            assert scan.trigger_range is not None
            await controller.set_trigger_range(*scan.trigger_range, axis=scan.axis)
        await controller.set("trigcount", 0)
        if scan.snapshots:
            await controller.set("snsc", 0)  # captures append (L15171-15222): start empty
        await controller.set("trig", 1)
        return ctx

    async def _move(self, ctx: _Pass, target: float) -> bool:
        """Move the pass's axis; False if a stop(success=True) ended the move."""
        async with self.link.moving() as mover:
            try:
                await self.link.coalescer.move_to(ctx.scan.axis, target)
            except MoveError:
                if not ctx.stopped_ok(mover):
                    raise
                ctx.stopped = True
                return False
        return True

    async def on_kickoff(self, ctx: _Pass) -> _Pass:
        if ctx.stopped is not None:
            raise MoveError(f"the preparation of the {ctx.scan.axis} pass was stopped",
                            {ctx.scan.axis: "E"})
        ctx.travel = asyncio.ensure_future(self._move(ctx, ctx.scan.end))
        self.running.append(ctx)
        await _started(self.link.controller, ctx.scan.axis, ctx.travel)
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
                            {ctx.scan.axis: "E"})
        if not travel.result():  # raises the pass's error, if any
            return
        controller = self.link.controller
        count = int(await controller.get("trigcount"))
        rows: list[list[float]] = []
        if ctx.scan.snapshots:
            rows = await controller.read_snapshot_positions()
        if count != ctx.scan.expected:
            log.warning("fly pass of %s gave %d trigger pulses, expected %d",
                        ctx.scan.axis, count, ctx.scan.expected)
        self.results.append(_PassResult(ctx.scan, count, tuple(map(tuple, rows)),
                                        time.time()))

    async def stop(self, success: bool = False) -> None:
        """Stop a running pass (every axis stops) and disable the trigger output; with
        ``success`` its ``complete()`` returns without data instead of failing."""
        for ctx in list(self.running):
            if ctx.travel is not None:
                ctx.stopped = success if ctx.stopped is None else ctx.stopped and success
                ctx.travel.cancel()
                await asyncio.wait([ctx.travel])
        if self.link.connected:
            with contextlib.suppress(TangoError):
                await self.link.controller.set("trig", 0)


async def _started(controller: Controller, axis: str, travel: asyncio.Task[bool]) -> None:
    """Return once ``axis`` moves or the pass has already ended (a short pass may end
    between two polls); raise its error if it failed."""
    while not travel.done():
        if (await controller.status()).get(axis) == "M":
            return
        await asyncio.wait([travel], timeout=0.01)
    travel.result()


class MarzhauserFlyer(StandardFlyable[TriggerScan, _Pass], Collectable, Stoppable, Pausable):
    """A hardware-triggered fly scan on a :class:`MarzhauserStage`.

    ``prepare(TriggerScan(...))`` moves the axis to the start of the pass, uploads the
    trigger list (or sets the range), clears the trigger counter and enables the trigger
    output; ``kickoff()`` starts the pass and returns once it runs; ``complete()`` waits
    for its end. ``collect()`` then yields, per pass, one event in the stream named like
    the flyer with ``<name>-trigger_count`` and ``<name>-triggers_expected``, and with
    ``snapshots`` one event per captured position in ``<name>_snapshots``
    (``<name>-snapshot_x``...; the capture time is not reported, so these events carry
    the time of the pass's end). ``stop()`` stops a running pass (every axis, ``a``) and
    disables the trigger output.
    """

    def __init__(self, stage: MarzhauserStage, name: str = "flyer") -> None:
        self._link = stage.link  # the plain link, never the stage (it would become a child)
        self._results: list[_PassResult] = []
        super().__init__(name=name, connector=_LinkConnector(stage.link))

    @functools.cached_property
    def flyable_logic(self) -> _FlyLogic:
        return _FlyLogic(self._link, self._results)

    async def stop(self, success: bool = False) -> None:
        """Stop a running pass (``a``: every axis stops) and disable the trigger output.
        Its ``complete()`` then fails with MoveError, or with ``success`` returns without
        data."""
        self._link.mark_stop(success)
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
                {axis: f"{name}-snapshot_{axis}" for axis in self._present()})

    def _present(self) -> tuple[str, ...]:
        return AXES[: self._link.controller.context.axes]

    def describe_collect(self) -> dict[str, dict[str, DataKey]]:
        """The streams :meth:`collect` fills (doubly nested: stream -> data keys)."""
        count_key, expected_key, snapshot_keys = self._keys()
        source = f"{self._link.url} ?trigcount"
        streams: dict[str, dict[str, DataKey]] = {self.name: {
            count_key: {"source": source, "dtype": "integer", "shape": []},
            expected_key: {"source": f"{self.name} prepare", "dtype": "integer",
                           "shape": []},
        }}
        if any(result.scan.snapshots for result in self._results) or \
                self._snapshots_prepared():
            streams[f"{self.name}_snapshots"] = {
                key: {"source": f"{self._link.url} ?snsa", "dtype": "number", "shape": [],
                      "units": self._link.units.get(axis, ""),
                      "precision": self._link.precision.get(axis, 4)}
                for axis, key in snapshot_keys.items()}
        return streams

    def _snapshots_prepared(self) -> bool:
        scan = self.flyable_logic.prepared
        return scan is not None and scan.snapshots

    def collect(self) -> Iterator[PartialEvent]:
        """One event per completed pass (trigger count), and one per snapshot row."""
        count_key, expected_key, snapshot_keys = self._keys()
        results, self._results[:] = list(self._results), []
        for result in results:
            yield {"data": {count_key: result.trigger_count,
                            expected_key: result.scan.expected},
                   "timestamps": {count_key: result.time, expected_key: result.time},
                   "time": result.time}
            for row in result.snapshots:
                data = {key: row[AXES.index(axis)] for axis, key in snapshot_keys.items()
                        if AXES.index(axis) < len(row)}
                yield {"data": data, "timestamps": dict.fromkeys(data, result.time),
                       "time": result.time}


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

