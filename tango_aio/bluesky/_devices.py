"""The ophyd-async devices: a stage, its axes, a flyer, and the link they share."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import itertools
import logging
import math
import time
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Mapping, Sequence
from typing import Any, NoReturn

import anyio

try:
    import bluesky.plan_stubs as bps
    from bluesky.protocols import Collectable, Pausable, Stoppable
    from bluesky.utils import MsgGenerator
    from event_model import DataKey, PartialEvent
    from ophyd_async.core import (
        CALCULATE_TIMEOUT,
        DEFAULT_TIMEOUT,
        AsyncStatus,
        CalculatableTimeout,
        Device,
        DeviceConnector,
        DeviceMock,
        FlyableLogic,
        FlyMotorInfo,
        MovableLogic,
        SignalR,
        SignalRW,
        SignalW,
        SoftSignalBackend,
        StandardFlyable,
        StandardMovable,
        StandardReadable,
        StandardReadableFormat,
        TimeoutCalculator,
        WatchableAsyncStatus,
        WatcherUpdate,
        callback_on_mock_put,
        observe_value,
        set_mock_value,
    )
    from ophyd_async.core._movable import MoveTimeout, StopState
except ImportError as exc:  # pragma: no cover - depends on the environment
    from .._install import install_hint

    raise ImportError(f"tango_aio.bluesky needs the bluesky extra: "
                      f"{install_hint('bluesky')}") from exc

from ..catalog import AXES, INSTRUCTIONS
from ..controller import STOP_WAIT, Controller, connect
from ..errors import (
    ControllerTimeoutError,
    InvalidCommandError,
    MissingAxisError,
    MoveError,
    StageLimitsError,
    TangoError,
)
from ..events import MoveAborted, MoveFinished, PositionUpdate, Reconnected, StatusReport
from ..group import MoveCoalescer
from ..moves import position_tolerance
from ..status import ABSENT, ARRIVED_LETTERS, MOVING, AxisStatus, switch_states
from ..units import DIM_MM_VEL, UnitScale
from ..units import DIM_UNITS as _DIM_UNITS

__all__ = [
    "MarzhauserAxis",
    "MarzhauserFlyer",
    "MarzhauserStage",
    "MissingAxisError",
    "StageLimitsError",
    "StageLink",
    "TriggerScan",
    "close_stage",
    "controller_velocity",
    "egu_acceleration",
    "egu_velocity",
    "fly_raster",
    "home",
    "max_velocity",
    "measure_range",
    "run_up_distance",
]

log = logging.getLogger(__name__)

#: Position unit of each ``dim`` (manual L3061-3144); dim 9 is mm with velocities in mm/s.
DIM_UNITS = {dim: unit.symbol for dim, unit in _DIM_UNITS.items()}
#: ``accel`` is always in m/s² (manual L3303, L3329; see tango_aio.units).
ACCEL_UNIT = "m/s^2"


# --------------------------------------------------------------------------------------
# What the devices of one stage share


@dataclasses.dataclass(eq=False)
class Mover:
    """One running move of a :class:`StageLink`'s devices. ``axis``: the axis it moves
    (``None``: it may move any). ``stopped``: ``None`` unless a stop was requested while
    it ran; then whether that stop counts as success. ``timed_out``: its set(timeout=)
    ran out."""

    axis: str | None = None
    stopped: bool | None = None
    timed_out: bool = False

    @property
    def stopped_ok(self) -> bool:
        """Whether a ``stop(success=True)`` (and no failing stop) ended this move."""
        return self.stopped is True


class StageLink:
    """The connection shared by a stage's axes and flyers (a plain object, no Device).

    Holds the URL and connect options, the open :class:`~tango_aio.Controller`,
    its :class:`~tango_aio.group._coalesce.MoveCoalescer`, the axes' units, unit scales, limits
    and precision (read when opening), and the readback publishers of the axes: while any
    move of this link runs, one task polls ``?pos`` every ``progress_interval`` seconds
    (the progress of ``set()``); while idle, nothing is polled: the readbacks follow the
    driver's events (a move, calibration or abort of any caller of the same controller
    ends: one ``?pos``; a position update: published as it is).

    Parameters
    ----------
    url
        The controller's URL.
    axes
        The stage's axis letters (``"xy"``).
    options
        Options of :func:`tango_aio.connect`.
    window
        The longest wait of the move coalescer for announced sets, in seconds.
    progress_interval
        Seconds between two position reads while a move runs.
    """

    def __init__(self, url: str, axes: str, options: dict[str, Any], *,
                 window: float = 0.25, progress_interval: float = 0.1) -> None:
        self.url = url
        self.axes = axes
        self.options = dict(options)
        self.window = window
        self.progress_interval = progress_interval
        #: Per axis: position unit, velocity unit, decimals of the position replies.
        self.units: dict[str, str] = {}
        self.velocity_units: dict[str, str] = {}
        self.precision: dict[str, int] = {}
        #: Per axis: the unit conversion (dim, pitch, gear, usteps) read when opening.
        self.scales: dict[str, UnitScale] = {}
        #: Per axis: the software limits (?lim) as last read.
        self.limits: dict[str, tuple[float, float]] = {}
        self._controller: Controller | None = None
        self._coalescer: MoveCoalescer | None = None
        self._lock: asyncio.Lock | None = None
        self._publishers: dict[str, list[Callable[[float], None]]] = {}
        self._done_publishers: dict[str, list[Callable[[int], None]]] = {}
        self._known: dict[str, float] = {}
        self._published_at = -math.inf
        self._movers: set[Mover] = set()
        self._poller: asyncio.Task[None] | None = None
        self._follower: asyncio.Task[None] | None = None
        self._idle_read: asyncio.Task[dict[str, float]] | None = None

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
            self._coalescer = MoveCoalescer(controller, window=self.window,
                                            collect="announced")
            self._follower = asyncio.ensure_future(self._follow(controller))

    async def aclose(self) -> None:
        """Stop what this link moves and close the controller."""
        for task in (self._poller, self._follower):
            if task is not None:
                task.cancel()
        coalescer, self._coalescer = self._coalescer, None
        controller, self._controller = self._controller, None
        if coalescer is not None:
            await coalescer.aclose()
        if controller is not None:
            await controller.aclose()

    async def refresh(self) -> None:
        """Read the units, unit scales, limits and precision again (after ``dim``,
        ``pitch``, ``gear``, ``usteps`` or ``resolution`` changed)."""
        await self._inspect(self.controller)

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
        scales = await controller.settings.unit_scales()
        for axis in self.axes:
            index = AXES.index(axis)
            dim = int(dims[index])
            self.units[axis] = DIM_UNITS.get(dim, "")
            self.velocity_units[axis] = f"{self.units[axis]}/s"
            word = words[index] if index < len(words) else ""
            self.precision[axis] = len(word.partition(".")[2])
            self.scales[axis] = scales[axis]
            # Axis by axis: '?lim' of all axes is misformatted by some firmware (L4561).
            self.limits[axis] = await controller.axis_limits(axis, cached=False)
            with contextlib.suppress(ValueError):
                self._known[axis] = float(word)

    # -- positions and progress -----------------------------------------------------------

    def add_publisher(self, axis: str, publish: Callable[[float], None]) -> None:
        """Call ``publish(position)`` whenever the link reads the position of ``axis``.

        Parameters
        ----------
        axis
            The axis letter.
        publish
            Called with each position read, in the axis's unit.
        """
        self._publishers.setdefault(axis, []).append(publish)

    def add_done_publisher(self, axis: str, publish: Callable[[int], None]) -> None:
        """Call ``publish(1)`` when a move of ``axis`` ends, ``publish(0)`` when one
        starts (the motor record's DMOV).

        Parameters
        ----------
        axis
            The axis letter.
        publish
            Called with 1 when a move ends, 0 when one starts.
        """
        self._done_publishers.setdefault(axis, []).append(publish)

    def _publish(self, positions: Mapping[str, float]) -> None:
        self._published_at = time.monotonic()
        for axis, publishers in self._publishers.items():
            if axis in positions:
                self._known[axis] = positions[axis]
                for publish in publishers:
                    publish(positions[axis])

    def _publish_done(self, axis: str | None, done: int) -> None:
        for letter, publishers in self._done_publishers.items():
            if axis is None or letter == axis:
                for publish in publishers:
                    publish(done)

    def known_position(self, axis: str) -> float | None:
        """The position of ``axis`` as last read or reported (no read).

        Parameters
        ----------
        axis
            The axis letter.

        Returns
        -------
        float or None
            The latest known position; ``None`` if none was read yet.
        """
        return self._known.get(axis)

    async def positions(self) -> dict[str, float]:
        """Read every position (``?pos``) and publish it to the axes' readbacks. Readers
        that ask while no move of this link runs share one read (``read()`` of a
        two-axis stage reads ``?pos`` once); a read never joins one written before a
        move started or while one ran.

        Returns
        -------
        dict[str, float]
            The position of each axis, by axis letter.
        """
        if self._movers:
            return await self._read_positions()
        task = self._idle_read
        if task is None or task.done():
            task = self._idle_read = asyncio.ensure_future(self._read_positions())
        return dict(await asyncio.shield(task))

    async def _read_positions(self) -> dict[str, float]:
        positions = await self.controller.position()
        self._publish(positions)
        return positions

    async def position(self, axis: str) -> float:
        """The position of ``axis`` (published to the readbacks as well).

        Parameters
        ----------
        axis
            The axis letter.

        Returns
        -------
        float
            Its position.
        """
        return (await self.positions())[axis]

    async def read_limits(self, axis: str, *, cached: bool = False) -> tuple[float, float]:
        """Read the software limits of ``axis`` (``?lim``) and keep them.

        Parameters
        ----------
        axis
            The axis letter.
        cached
            Whether the limits the controller read before may be taken without a read,
            as long as no line that may change them went out since
            (:meth:`~tango_aio.Controller.axis_limits`).

        Returns
        -------
        tuple[float, float]
            The lower and upper limit.
        """
        self.limits[axis] = await self.controller.axis_limits(axis, cached=cached)
        return self.limits[axis]

    @contextlib.asynccontextmanager
    async def moving(self, axis: str | None = None) -> AsyncIterator[Mover]:
        """Run a move of this link's devices: while any such block runs, positions are
        polled every ``progress_interval`` and published; on leaving, the positions are
        published once more (the final readback): those the driver read to confirm the
        arrival if the move succeeded, else read now.

        Parameters
        ----------
        axis
            The axis the move drives; ``None`` if it may drive any.

        Yields
        ------
        Mover
            The running move, on which a stop records its outcome.
        """
        mover = Mover(axis)
        self._movers.add(mover)
        self._idle_read = None  # no later reader may join a read written before this
        self._publish_done(axis, 0)
        if self._poller is None or self._poller.done():
            self._poller = asyncio.ensure_future(self._poll())
        confirmed = False
        try:
            yield mover
            confirmed = True
        finally:
            self._movers.discard(mover)
            if not self._movers and self._poller is not None:
                self._poller.cancel()
            known = self._confirmed_positions() if confirmed else None
            if known is not None:
                self._publish(known)
            else:
                with contextlib.suppress(TangoError):
                    await self._read_positions()
            self._publish_done(axis, 1)

    def _confirmed_positions(self) -> dict[str, float] | None:
        """The positions the driver read behind the latest move's report (its
        confirmation), if it has them.

        Returns
        -------
        dict[str, float] or None
            The positions by axis letter, or ``None``.
        """
        controller = self._controller
        texts = None if controller is None else controller.last_positions
        if not texts:
            return None
        try:
            return {axis: float(text) for axis, text in texts.items()}
        except ValueError:
            return None

    async def _poll(self) -> None:
        while self._movers:
            await asyncio.sleep(self.progress_interval)
            with contextlib.suppress(TangoError):
                await self._read_positions()

    async def _follow(self, controller: Controller) -> None:
        """Keep the readbacks current while idle, from the driver's events (no polling):
        a move, calibration, range measure or abort that ended while none of this link's
        moves ran (another caller of the controller): one ``?pos``; a position update
        (``watch_position``): published as it is."""
        async with controller.events() as events:
            async for event in events:
                if isinstance(event, PositionUpdate):
                    self._publish(event.positions)
                elif isinstance(event, MoveFinished | MoveAborted | StatusReport
                                | Reconnected):
                    if self._movers or event.time <= self._published_at:
                        continue  # our own move: its end publishes the confirmed positions
                    with contextlib.suppress(TangoError):
                        await self.positions()
                    self._publish_done(None, 1)

    def announce(self) -> Callable[[], None]:
        """Announce a move request to the coalescer (see
        :meth:`~tango_aio.group._coalesce.MoveCoalescer.announce`); a no-op before connecting.

        Returns
        -------
        Callable[[], None]
            Ends the announcement (call it once the move was requested, or given up).
        """
        coalescer = self._coalescer
        return coalescer.announce() if coalescer is not None else _nothing

    @property
    def in_flight(self) -> int:
        """How many moves of this link's devices are running."""
        return len(self._movers)

    def mark_stop(self, success: bool, axis: str | None = None) -> None:
        """A stop is coming: record its outcome on the moves it ends (those of ``axis``;
        every move if ``None``). With ``success`` (the RunEngine's pause) they complete
        instead of failing, and so does every other move of this link: a line that merged
        ``axis`` with others fails as a whole, and the RunEngine stops all it has set and
        replays the plan from its checkpoint, so no reading follows such a completion. A
        failing stop wins.

        Parameters
        ----------
        success
            Whether the stopped moves count as completed (a pause) rather than failed.
        axis
            The axis being stopped; ``None`` for every axis.
        """
        for mover in self._movers:
            if axis is None or success or mover.axis in (axis, None):
                mover.stopped = success if mover.stopped is None else \
                    mover.stopped and success

    async def halt(self, axis: str | None = None) -> None:
        """Stop ``axis`` (the manual's one-axis ``a x``, L6785-6844; every axis with
        ``a`` if ``None``) if a move of it by this link runs or it moves; otherwise write
        nothing. Returns without waiting: see :meth:`wait_still`.

        Parameters
        ----------
        axis
            The axis to stop; ``None`` for every axis.
        """
        controller = self._controller
        if controller is None:
            return  # nothing of ours can move
        ours = any(axis is None or mover.axis in (axis, None) for mover in self._movers)
        if not ours:
            letters = await controller.status()
            if not any(letter == MOVING for letter_axis, letter in letters.items()
                       if axis is None or letter_axis == axis):
                return
        if axis is None:
            await controller.stop(wait=False)
        else:
            await controller.stop(axis, wait=False)

    async def wait_still(self, axis: str | None = None) -> None:
        """Wait until ``axis`` (every axis if ``None``) stands still, polling
        ``statusaxis``; raise :class:`~tango_aio.errors.ControllerTimeoutError` if it
        still moves after ``STOP_WAIT`` seconds.

        Parameters
        ----------
        axis
            The axis to wait for; ``None`` for every axis.

        Raises
        ------
        ControllerTimeoutError
            The axis still moves ``STOP_WAIT`` seconds after the stop.
        """
        controller = self._controller
        if controller is None:
            return
        try:
            async with asyncio.timeout(STOP_WAIT):
                while True:
                    letters = await controller.status()
                    if not any(letter == MOVING for moving, letter in letters.items()
                               if axis is None or moving == axis):
                        return
                    await asyncio.sleep(0.05)
        except ControllerTimeoutError:
            raise  # a status query went unanswered
        except TimeoutError:
            raise ControllerTimeoutError(
                f"{self.url!r}: {axis or 'axes'} still moving {STOP_WAIT} s after the "
                "stop") from None


class _LinkConnector(DeviceConnector):
    """Opens the shared :class:`StageLink` before connecting the children."""

    def __init__(self, link: StageLink) -> None:
        self.link = link

    async def connect_real(self, device: Device, timeout: float,
                           force_reconnect: bool) -> None:
        async with asyncio.timeout(timeout):
            await self.link.open()
        await super().connect_real(device, timeout, force_reconnect)


class _Backend(SoftSignalBackend[Any]):
    """A soft signal's backend whose source names the controller instruction, with an
    optional getter (called on every read) and setter (called on every put). Connected
    with ``mock=True`` the device :meth:`detach` es them: the signal then keeps the value
    written to it, as ophyd-async's mock signals do, and never reaches for a controller."""

    def __init__(self, datatype: type[Any], source: str, units: str | None = None, *,
                 initial: Any = None,
                 getter: Callable[[], Awaitable[Any]] | None = None,
                 setter: Callable[[Any], Awaitable[Any]] | None = None) -> None:
        super().__init__(datatype, initial, units, getter=getter, setter=setter)
        self._source = source

    def source(self, name: str, read: bool) -> str:
        return self._source

    def detach(self) -> None:
        """Forget the getter and setter (mock mode)."""
        self._getter = None
        self._setter = None


def _vel_bounds() -> tuple[float, float]:
    """The upper bound of ``vel``: rev/s in dims 0-8, mm/s in dim 9 (manual L3452-3525,
    read from the catalog).

    Returns
    -------
    tuple[float, float]
        The bound in rev/s and in mm/s.
    """
    param = INSTRUCTIONS["vel"].write[0].per_axis[0]
    assert param.hi is not None
    return float(param.hi), float(param.hi_dim9 if param.hi_dim9 is not None else param.hi)


def egu_velocity(controller_value: float, scale: UnitScale) -> float:
    """A ``vel`` as the controller prints it (rev/s, mm/s in dim 9: L189, L3452) in the
    axis's position unit per second (EGU/s), through :mod:`tango_aio.units`.

    Parameters
    ----------
    controller_value
        The velocity as ``?vel`` prints it.
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The velocity in EGU/s.
    """
    return scale.pos_to_user(scale.vel_from_user(controller_value))


def controller_velocity(egu_per_s: float, scale: UnitScale) -> float:
    """The inverse of :func:`egu_velocity`: EGU/s to what ``!vel`` takes.

    Parameters
    ----------
    egu_per_s
        A velocity in EGU/s.
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The value to write with ``!vel``.
    """
    return scale.vel_to_user(scale.pos_from_user(egu_per_s))


def egu_acceleration(m_per_s2: float, scale: UnitScale) -> float:
    """An ``accel`` (always m/s², L3298-3329) in EGU/s².

    Parameters
    ----------
    m_per_s2
        The acceleration as ``?accel`` prints it (m/s²).
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The acceleration in EGU/s².
    """
    return scale.pos_to_user(scale.accel_to_rev(m_per_s2))


def max_velocity(scale: UnitScale) -> float:
    """The highest velocity ``!vel`` accepts, in EGU/s (its catalog bound converted).

    Parameters
    ----------
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The highest velocity, in EGU/s.
    """
    rev_per_s, mm_per_s = _vel_bounds()
    if scale.dim == DIM_MM_VEL:
        return mm_per_s
    return scale.pos_to_user(rev_per_s)


def run_up_distance(speed: float, acceleration: float) -> float:
    """Distance (EGU) to reach ``speed`` (EGU/s) from rest at ``acceleration`` (EGU/s²):
    v² / 2a, the linear ramp the controller's ``accel`` describes (L3298).

    Parameters
    ----------
    speed
        The speed to reach, in EGU/s.
    acceleration
        The ramp's acceleration, in EGU/s² (positive).

    Returns
    -------
    float
        The distance, in EGU.

    Raises
    ------
    ValueError
        ``acceleration`` is not positive.
    """
    if not acceleration > 0:
        raise ValueError(f"acceleration must be positive, got {acceleration!r}")
    return 0.0 if math.isinf(acceleration) else speed * speed / (2.0 * acceleration)


def _switches(reply: str, axis: str) -> tuple[int, int]:
    """(lower, upper) limit-switch state of ``axis`` from a ``?readsw`` reply: 12
    characters, E0 of X Y Z A, then Ref of X Y Z A, then EE of X Y Z A (L5027-5078).

    Returns
    -------
    tuple[int, int]
        The lower and the upper switch, 1 if active.

    Raises
    ------
    TangoError
        The reply is not 12 switch states.
    """
    states = switch_states(reply, axis)
    if states is None:
        raise TangoError(f"?readsw replied {reply!r}, not 12 switch states (L5057-5066)")
    return int(states[0]), int(states[2])


@dataclasses.dataclass
class _FlyCtx:
    """State of one fly pass of an axis, threaded prepare -> kickoff -> complete."""

    info: FlyMotorInfo
    run_up_start: float
    run_down_end: float
    #: Seconds to reach the pass velocity (velocity / acceleration).
    ramp_time: float
    travel: asyncio.Task[bool] | None = None
    #: Set when a stop ends the pass: whether it counts as success (RunEngine pause).
    stopped: bool | None = None


@dataclasses.dataclass
class _AxisLogic(MovableLogic[float], FlyableLogic[FlyMotorInfo, _FlyCtx]):
    """How a :class:`MarzhauserAxis` moves and flies: through the link's coalescer."""

    link: StageLink
    axis: str
    device: weakref.ReferenceType[MarzhauserAxis]
    #: Resolved when the latest move() has ended (its clean-up included).
    ended: asyncio.Future[None] | None = dataclasses.field(default=None, init=False)
    #: Connected with ``mock=True``: ophyd-async's mock signals move instantly, no
    #: controller is involved (for testing plans without hardware).
    mocked: bool = dataclasses.field(default=False, init=False)
    #: The fly pass running (kicked off and not yet complete).
    flying: _FlyCtx | None = dataclasses.field(default=None, init=False)

    @property
    def name(self) -> str:
        """The device's name (for messages)."""
        device = self.device()
        return device.name if device is not None and device.name else self.axis

    async def stop(self) -> None:
        if self.mocked:
            return
        # Called before StandardMovable.stop cancels our move: no waiting here, or the
        # move would end (with the letters of the stop) before it is cancelled.
        await self.link.halt(self.axis)

    async def wait_stopped(self) -> None:
        """Wait until the latest move has ended and the axes stand still (bounded)."""
        if self.ended is not None:
            await asyncio.wait([self.ended], timeout=STOP_WAIT + 5)
        await self.link.wait_still(self.axis)

    async def check_move(self, new_position: float) -> None:
        target = float(new_position)
        if not math.isfinite(target):
            raise StageLimitsError(f"{self.axis}: target {target!r} is not a finite number",
                                   instruction="moa", parameter="position", number=5)
        if self.mocked:
            return
        # The controller does not refuse a target outside them, it stops the axis there
        # (L4526-4540). Known without a read while no line that may change them went
        # out through this controller, from any of its callers (Controller.axis_limits);
        # limits changed behind the driver's back still fail the move, as its
        # confirmation finds the axis short of its target.
        low, high = await self.link.read_limits(self.axis, cached=True)
        if not low <= target <= high:
            raise StageLimitsError(
                f"{self.name}: target {target} outside the limits [{low}, {high}] "
                f"{self.link.units.get(self.axis, '')}", instruction="moa",
                parameter="position", number=5)

    async def get_units_precision(self) -> tuple[str | None, int | None]:
        return self.link.units.get(self.axis), self.link.precision.get(self.axis)

    async def move(self, new_position: float, timeout: TimeoutCalculator) -> None:
        await self.move_announced(new_position, timeout, None)

    async def move_announced(self, new_position: float, timeout: TimeoutCalculator,
                             arrived: Callable[[], None] | None) -> None:
        """:meth:`move`, ending the announcement ``arrived`` of the coalescer once the
        request has joined a batch.

        Raises
        ------
        MoveError
            The move failed, unless a successful stop or an arrival all the same excuses it.
        TimeoutError
            The move ran out of ``timeout``.
        """
        # The controller bounds each move with its own estimate (Controller.move_to);
        # an explicit set(timeout=...) is applied on top.
        target = float(new_position)
        if self.mocked:
            await super().move(target, timeout)
            return
        self.ended = ended = asyncio.get_running_loop().create_future()
        limit = timeout()
        try:
            await self.setpoint.set(target)
            async with self.link.moving(self.axis) as mover:
                try:
                    await _until_stopped(
                        self.link.coalescer.move_to(self.axis, target, arrived), mover,
                        limit, functools.partial(self.link.halt, self.axis))
                except MoveError as exc:
                    # A stop(success=True) (RunEngine pause) of another device ended
                    # this move too: complete, as StandardMovable does for ours.
                    if not mover.stopped_ok and not await self._arrived_anyway(
                            target, exc, mover):
                        raise
                except TimeoutError:
                    if not mover.timed_out:
                        raise  # the driver's (ControllerTimeoutError), not ours
            if mover.timed_out:
                await self._timed_out(target, limit)
        finally:
            ended.set_result(None)

    async def _arrived_anyway(self, target: float, error: MoveError,
                              mover: Mover) -> bool:
        """Whether this axis, moved in a line that failed because *another* axis of it
        was stopped (``a x`` stops one axis; the driver fails the whole line once all of
        its axes stand still, and marks them all as stopped), arrived all the same: no
        stop was asked for it, the line did not end it at a limit switch or timeout
        (``S``/``T``), a fresh ``?statusaxis`` says it is idle (``@``), and a fresh
        ``?pos`` puts it at the target (within 1.5 units of the printed digit, the
        driver's own rule). Anything else: False, and the line's error stands.

        Returns
        -------
        bool
            Whether the axis arrived.
        """
        ended_short = (AxisStatus.LIMIT_SWITCH, AxisStatus.TIMEOUT)
        if mover.stopped is not None or error.statuses.get(self.axis) in ended_short:
            return False
        controller = self.link.controller
        try:
            if (await controller.status()).get(self.axis) != AxisStatus.READY:
                return False
            position = await self.link.position(self.axis)
        except TangoError:
            return False
        digits = self.link.precision.get(self.axis, 0)
        tolerance = position_tolerance("0." + "0" * digits if digits else "0")
        return abs(position - target) <= tolerance

    async def _timed_out(self, target: float, limit: float | None) -> NoReturn:
        """Raise the TimeoutError of a move that ran out of ``limit`` seconds (the
        cancelled move has stopped its axes): it names the axis, the target and where
        the axis stopped.

        Raises
        ------
        TimeoutError
            Always.
        """
        unit = self.link.units.get(self.axis, "")
        try:
            where = f"stopped at {await self.link.position(self.axis)} {unit}"
        except TangoError as exc:
            where = f"its position could not be read ({exc})"
        within = "its time limit" if limit is None else f"{limit:.3g} s"
        raise TimeoutError(f"{self.name}: the move to {target} {unit} did not end within "
                           f"{within}; {where}")

    # -- fly scans (ophyd-async Motor's semantics) ----------------------------------------

    async def on_prepare(self, value: FlyMotorInfo) -> _FlyCtx:
        device = self.device()
        assert device is not None
        speed = value.speed
        if self.mocked:  # Motor's arithmetic on the mock signals
            accel_time = await device.acceleration_time.get_value()
            accel = speed / accel_time if accel_time > 0 else math.inf
            top = await device.max_velocity.get_value()
        else:
            top, accel = await asyncio.gather(device.max_velocity.get_value(),
                                              device.acceleration_egu())
        unit = self.link.units.get(self.axis, "")
        if speed > top:
            raise StageLimitsError(
                f"{self.name}: speed {speed} {unit}/s above the max velocity {top} "
                f"{unit}/s", instruction="vel", parameter="velocity", number=5)
        if not speed > 0:
            raise StageLimitsError(f"{self.name}: a fly pass needs a positive speed",
                                   instruction="vel", parameter="velocity", number=5)
        distance = run_up_distance(speed, accel)
        sign = 1.0 if value.end_position >= value.start_position else -1.0
        start = value.start_position - sign * distance
        end = value.end_position + sign * distance
        for position in (start, end):  # both checked before anything moves
            await self.check_move(position)
        ctx = _FlyCtx(value, start, end, 0.0 if math.isinf(accel) else speed / accel)
        # To the run-up start at the axis's own velocity (Motor uses its maximum; a
        # stage's catalog maximum, 200 rev/s, is no safe travel speed), then the pass's.
        await self.move(start, lambda: None)
        await device.velocity.set(speed)
        return ctx

    async def on_kickoff(self, ctx: _FlyCtx) -> _FlyCtx:
        if self.mocked:
            ctx.travel = asyncio.ensure_future(self._mock_fly(ctx))
            return ctx
        ctx.travel = asyncio.ensure_future(self._fly(ctx))
        self.flying = ctx
        await _started(self.link.controller, self.axis, ctx.travel,
                       lambda: ctx.stopped is True)
        if not ctx.travel.done():
            # As Motor: return once the run-up is over, so the pass runs at its speed.
            await asyncio.wait([ctx.travel], timeout=ctx.ramp_time)
        return ctx

    async def _mock_fly(self, ctx: _FlyCtx) -> bool:
        await self.move(ctx.run_down_end, lambda: None)
        return True

    async def _fly(self, ctx: _FlyCtx) -> bool:
        """The pass's move; False if a stop(success=True) ended it. A number as the
        FlyMotorInfo's ``timeout`` bounds it, as for Motor (the default leaves the bound
        to the driver's own estimate); running out stops the axis and raises a
        TimeoutError naming the axis, the target and where it stopped.

        Returns
        -------
        bool
            True if the pass ran to its end.

        Raises
        ------
        TimeoutError
            The pass ran out of its timeout.
        """
        limit = ctx.info.timeout
        seconds = None if limit is None or isinstance(limit, str) else float(limit)
        timed_out = Mover()
        try:
            arrived = await _pass_move(self.link, self.axis, ctx.run_down_end,
                                       lambda mover: mover.stopped_ok, limit=seconds,
                                       timed_out=timed_out)
        except TimeoutError:
            if not timed_out.timed_out:
                raise  # the driver's (ControllerTimeoutError), not ours
            await self._timed_out(ctx.run_down_end, seconds)
        if not arrived:
            ctx.stopped = True
        return arrived

    async def on_complete(self, ctx: _FlyCtx) -> None:
        travel = ctx.travel
        assert travel is not None
        try:
            await asyncio.wait([travel])
        finally:
            if travel.done() and self.flying is ctx:
                self.flying = None
        if travel.cancelled():
            if ctx.stopped is True:
                return
            raise MoveError(f"the fly pass of {self.name} was stopped",
                            {self.axis: AxisStatus.ERROR.value})
        travel.result()  # the pass's error, if any

    async def stop_flying(self, success: bool) -> None:
        """Stop the running pass, if any (the caller has sent the axis's stop): its
        ``complete()`` fails, or with ``success`` returns."""
        ctx = self.flying
        if ctx is not None and ctx.travel is not None and not ctx.travel.done():
            ctx.stopped = success if ctx.stopped is None else ctx.stopped and success
            ctx.travel.cancel()
            await asyncio.wait([ctx.travel])


async def _pass_move(link: StageLink, axis: str, target: float,
                     stopped_ok: Callable[[Mover], bool],
                     arrived: Callable[[], None] | None = None, *,
                     limit: float | None = None, timed_out: Mover | None = None) -> bool:
    """Move ``axis`` to ``target`` for a fly pass (through the coalescer, published as a
    move of ``axis``); False if a stop that ``stopped_ok`` accepts ended it. After
    ``limit`` seconds the axis is stopped (``a x``) and TimeoutError raised, with
    ``timed_out.timed_out`` set.

    Returns
    -------
    bool
        True if the move ran to its end.

    Raises
    ------
    MoveError
        The move failed and no accepted stop ended it.
    TimeoutError
        The move ran out of ``limit``.
    """
    async with link.moving(axis) as mover:
        try:
            await _until_stopped(link.coalescer.move_to(axis, target, arrived), mover,
                                 limit, functools.partial(link.halt, axis))
        except TimeoutError:
            if timed_out is not None:
                timed_out.timed_out = mover.timed_out
            raise
        except MoveError:
            if not stopped_ok(mover):
                raise
            return False
    return True


def _nothing() -> None:
    """An announcement that announced nothing (no coalescer yet, or mock mode)."""


async def _until_stopped(move: Awaitable[str], mover: Mover, limit: float | None = None,
                         halt: Callable[[], Awaitable[None]] | None = None) -> str:
    """Await ``move``; when cancelled after a stop was requested for it (the stop has
    sent ``a x``), let the line end by itself (bounded) instead of cancelling it: the
    driver's cancel would stop every axis of the line with ``a``. After ``limit``
    seconds (a set's or a pass's own timeout): mark ``mover`` timed out, ``halt()`` (the
    axis's one-axis stop), let the line end the same way and raise TimeoutError.

    Returns
    -------
    str
        The result of ``move``.

    Raises
    ------
    CancelledError
        The await was cancelled (re-raised once the line has ended).
    TimeoutError
        ``move`` ran out of ``limit``.
    """
    task = asyncio.ensure_future(move)
    try:
        done, _ = await asyncio.wait([task], timeout=limit)
        if done:
            return task.result()
        mover.timed_out = True
        mover.stopped = False
        if halt is not None:
            with contextlib.suppress(TangoError):
                await halt()
        raise TimeoutError
    except (asyncio.CancelledError, TimeoutError):
        if mover.stopped is not None and not task.done():
            with anyio.move_on_after(STOP_WAIT + 5, shield=True):
                await asyncio.wait([task])
        if not task.done():
            task.cancel()
            with anyio.move_on_after(STOP_WAIT + 5, shield=True):
                await asyncio.wait([task])
        if task.done() and not task.cancelled():
            task.exception()  # its outcome is the stop's: retrieved, not raised
        raise


class _AxisMock(DeviceMock["MarzhauserAxis"]):
    """``init_devices(mock=True)``: what ophyd-async's InstantMotorMock does for Motor
    (instant moves, a non-zero velocity and max velocity, done-move 1)."""

    async def connect(self, device: MarzhauserAxis) -> None:
        """Give the mock signals sensible values and move instantly on a setpoint put."""
        set_mock_value(device.velocity, 1000.0)
        set_mock_value(device.max_velocity, 1000.0)
        set_mock_value(device.acceleration, 1000.0)
        set_mock_value(device.acceleration_time, 0.0)
        set_mock_value(device.motor_done_move, 1)

        def _instant_move(value: float) -> None:
            set_mock_value(device.motor_done_move, 0)
            set_mock_value(device.user_readback, value)
            set_mock_value(device.motor_done_move, 1)

        callback_on_mock_put(device.user_setpoint, _instant_move)


class MarzhauserAxis(StandardReadable, StandardMovable[float],
                     StandardFlyable[FlyMotorInfo, _FlyCtx], Pausable):
    """One axis of a :class:`MarzhauserStage` (created by the stage), with the signals
    and methods of ophyd-async's ``epics.motor.Motor`` that the controller can back
    (the how-to ``docs/howto/bluesky.md`` has the table).

    Parameters
    ----------
    link
        The stage's link.
    axis
        The axis letter.
    name
        The device name (the stage names its children).
    """

    # What ophyd-async's default_mock_class decorator sets (a plain attribute, so that the
    # docs build, which mocks ophyd_async, still sees the class).
    _mock_class = _AxisMock

    def __init__(self, link: StageLink, axis: str, name: str = "") -> None:
        self._link = link  # a plain object: ophyd-async does not adopt it as a child
        self._axis = axis
        where = f"{link.url} {{}} {axis}".format
        get = self._controller_get
        self._backends: list[_Backend] = []

        def backend(datatype: type[Any], source: str, units: str | None = None, *,
                    initial: Any = None, getter: Callable[[], Awaitable[Any]] | None = None,
                    setter: Callable[[Any], Awaitable[Any]] | None = None) -> _Backend:
            made = _Backend(datatype, where(source), units, initial=initial, getter=getter,
                            setter=setter)
            self._backends.append(made)
            return made

        self._readback = backend(float, "?pos", getter=self._read_position)
        self._setpoint = backend(float, "!moa")
        self._velocity = backend(float, "vel", getter=self._get_velocity,
                                 setter=self._put_velocity)
        self._low = backend(float, "?lim", getter=lambda: self._limit(0),
                            setter=functools.partial(self._put_limit, 0))
        self._high = backend(float, "?lim", getter=lambda: self._limit(1),
                             setter=functools.partial(self._put_limit, 1))
        self._position_backends = [self._readback, self._setpoint, self._low, self._high]
        with self.add_children_as_readables(StandardReadableFormat.HINTED_SIGNAL):
            self.user_readback = SignalR(backend=self._readback)
        self.user_setpoint = SignalRW(backend=self._setpoint)
        with self.add_children_as_readables(StandardReadableFormat.CONFIG_SIGNAL):
            self.motor_egu = SignalR(backend=backend(str, "dim", getter=self._egu))
            self.motor_resolution = SignalR(backend=backend(
                float, "dim pitch gear usteps", getter=self._resolution))
            self.steps_per_revolution = SignalR(backend=backend(
                int, "usteps", getter=self._usteps))
            self.units_per_revolution = SignalR(backend=backend(
                float, "dim pitch gear", getter=self._per_rev))
            self.velocity = SignalRW(backend=self._velocity)
            self.offset = SignalRW(backend=backend(float, "posclr", getter=self._offset,
                                                   setter=self._put_offset))
            self.acceleration = SignalRW(backend=backend(
                float, "accel", ACCEL_UNIT, getter=lambda: get("accel"),
                setter=functools.partial(self._controller_put, "accel")))
            self.low_limit_travel = SignalRW(backend=self._low)
            self.high_limit_travel = SignalRW(backend=self._high)
        self.max_velocity = SignalR(backend=backend(float, "vel (catalog bound)",
                                                    getter=self._max_velocity))
        self.acceleration_time = SignalRW(backend=backend(
            float, "vel accel", "s", getter=self._acceleration_time,
            setter=self._put_acceleration_time))
        self.precision = SignalR(backend=backend(int, "?pos (decimals)",
                                                 getter=self._precision))
        self._done = backend(int, "?statusaxis", initial=1, getter=self._done_move)
        self.motor_done_move = SignalR(backend=self._done)
        self._dial_low = backend(float, "?lim ?posclr", getter=lambda: self._dial(0),
                                 setter=functools.partial(self._put_dial, 0))
        self._dial_high = backend(float, "?lim ?posclr", getter=lambda: self._dial(1),
                                  setter=functools.partial(self._put_dial, 1))
        self._position_backends += [self._dial_low, self._dial_high]
        self.dial_low_limit_travel = SignalRW(backend=self._dial_low)
        self.dial_high_limit_travel = SignalRW(backend=self._dial_high)
        self.low_limit_switch = SignalR(backend=backend(int, "?readsw E0",
                                                        getter=lambda: self._switch(0)))
        self.high_limit_switch = SignalR(backend=backend(int, "?readsw EE",
                                                         getter=lambda: self._switch(1)))
        self.motor_stop = SignalW(backend=backend(int, "a", setter=self._put_stop))
        link.add_publisher(axis, self._readback.set_value)
        link.add_done_publisher(axis, self._done.set_value)
        super().__init__(name=name)

    @property
    def axis(self) -> str:
        """The axis letter (``"x"``...)."""
        return self._axis

    @functools.cached_property
    def _limit_lock(self) -> asyncio.Lock:
        return asyncio.Lock()

    @functools.cached_property
    def _logic(self) -> _AxisLogic:
        return _AxisLogic(setpoint=self.user_setpoint, readback=self.user_readback,
                          link=self._link, axis=self._axis, device=weakref.ref(self))

    @functools.cached_property
    def movable_logic(self) -> _AxisLogic:
        return self._logic

    @functools.cached_property
    def flyable_logic(self) -> _AxisLogic:
        return self._logic

    def set(self, new_position: float,
            timeout: CalculatableTimeout = CALCULATE_TIMEOUT  # type: ignore[assignment]
            ) -> WatchableAsyncStatus[float]:
        """Move to ``new_position`` (StandardMovable's set, with progress from the
        polled readback). The set announces itself to the move coalescer at once (as
        the RunEngine calls it), so that sets started together merge into one line and
        a single one waits for nothing. The start of the progress reports is the
        position the link knows (published by the latest read or event), so that a step
        costs no read of its own; what completes the status is the controller's
        confirmed arrival.

        Parameters
        ----------
        new_position
            The target, in the axis's unit (EGU).
        timeout
            Seconds the move may take; ``CALCULATE_TIMEOUT`` (the default) leaves the limit to
            the driver's own move budget.

        Returns
        -------
        WatchableAsyncStatus[float]
            Done when the controller confirms the arrival; it fails with the move's error.
        """
        arrived = self._link.announce()
        try:
            return self._set(new_position, timeout, arrived)
        except BaseException:
            arrived()
            raise

    @WatchableAsyncStatus.wrap
    async def _set(self, new_position: float, timeout: CalculatableTimeout,
                   arrived: Callable[[], None]) -> AsyncIterator[WatcherUpdate[float]]:
        try:
            async for update in self._moving(new_position, timeout, arrived):
                yield update
        finally:
            arrived()

    async def _moving(self, new_position: float, timeout: CalculatableTimeout,
                      arrived: Callable[[], None]) -> AsyncIterator[WatcherUpdate[float]]:
        logic = self.movable_logic
        self._stop_state = StopState.NONE
        known = self._link.known_position(self._axis)
        initial = known if known is not None else await logic.readback.get_value()
        units, precision = await logic.get_units_precision()
        await logic.check_move(new_position)
        move_timeout = None if timeout == CALCULATE_TIMEOUT or isinstance(timeout, str) \
            else timeout
        try:
            async with AsyncStatus(logic.move_announced(
                    new_position, MoveTimeout(move_timeout), arrived)) as self._move_status:
                async for current in observe_value(logic.readback,
                                                   done_status=self._move_status):
                    yield WatcherUpdate(current=current, initial=initial,
                                        target=new_position, name=self.name, unit=units,
                                        precision=precision)
        except asyncio.CancelledError:
            if self._stop_state == StopState.NONE:
                raise
        finally:
            self._move_status = None
        stop_state, self._stop_state = self._stop_state, StopState.NONE
        if stop_state == StopState.USER_FAILURE:
            raise RuntimeError(f"Device {self.name} was stopped.")

    async def stop(self, success: bool = False) -> None:
        """Stop this axis (only this one where the controller has a one-axis stop) and
        return once it stands still. A running ``set()`` of this axis then fails
        (``success=False``: RuntimeError) or completes (``success=True``, as the
        RunEngine does on pause); so does a running fly pass (``complete()``).

        Parameters
        ----------
        success
            Whether a running ``set()`` completes (True) or fails (False).
        """
        self._link.mark_stop(success, self._axis)
        await super().stop(success=success)  # type: ignore[no-untyped-call]
        await self.movable_logic.stop_flying(success)
        await self.movable_logic.wait_stopped()
        if not self.movable_logic.mocked:
            # As the motor record (and SimMotor): the setpoint becomes where it stopped.
            await self.user_setpoint.set(await self._link.position(self._axis))

    async def pause(self) -> None:
        """RunEngine pause: stop a running fly pass with success (its ``complete()``
        returns; on resume the plan replays it from its checkpoint). The RunEngine stops
        the axes it has ``set`` itself, but not a pass started by ``kickoff``."""
        if self.movable_logic.flying is not None:
            await self.stop(success=True)

    async def resume(self) -> None:
        """RunEngine resume: nothing to do (the replayed plan prepares the pass again)."""

    # -- homing, range measure, offset (plan-friendly: each returns a status) ----------

    def home(self) -> AsyncStatus[None]:
        """Calibrate (``!cal``, L5259-5342): travel to the lower limit switch and set
        the origin there. The status fails (MoveError) if the controller reports one.

        Returns
        -------
        AsyncStatus[None]
            Done when the calibration has ended.
        """
        return AsyncStatus(self._motion("calibrate"))

    def measure_range(self) -> AsyncStatus[None]:
        """Range measure (``!rm``, L5343-5424): travel to the upper limit switch and set
        the upper limit. The status fails (MoveError) if the controller reports one.

        Returns
        -------
        AsyncStatus[None]
            Done when the range measure has ended.
        """
        return AsyncStatus(self._motion("measure_range"))

    def set_current_position(self, position: float) -> AsyncStatus[None]:
        """Redefine where the axis is (``!pos``, L6900-6952) without moving: the offset
        changes by the difference (see :attr:`offset`).

        Parameters
        ----------
        position
            The position the axis's current place gets, in EGU.

        Returns
        -------
        AsyncStatus[None]
            Done when the controller has taken it.
        """
        return AsyncStatus(self._redefine(float(position)))

    def clear_offset(self) -> AsyncStatus[None]:
        """Remove every ``!pos`` offset of this axis (``!posclr``, L6953-6996).

        Returns
        -------
        AsyncStatus[None]
            Done when the controller has taken it.
        """
        return AsyncStatus(self._clear_offset())

    async def _clear_offset(self) -> None:
        await self.offset.set(0.0)

    async def _motion(self, which: str) -> None:
        if self.movable_logic.mocked:
            return
        controller = self._link.controller
        async with self._link.moving(self._axis):
            letters = await getattr(controller, which)(self._axis)
        # Success letters: A after cal, D after rm (L2662-2721), @ from firmware that
        # reports idle; '-' (axis disabled) and anything else is no calibration.
        letter = letters.get(self._axis, ABSENT)
        if letter not in ARRIVED_LETTERS:
            raise MoveError(f"{self.name}: {which} ended with status {letter!r}",
                            dict(letters))
        await self.user_setpoint.set(await self._link.position(self._axis))
        await self._link.read_limits(self._axis)  # cal/rm may set limits (L4727-4760)

    def _set_units(self) -> None:
        """Take the units and precision the link read when it opened."""
        units = self._link.units.get(self._axis) or ""
        precision = self._link.precision.get(self._axis)
        for backend in self._position_backends:
            backend.metadata["units"] = units
            if precision is not None:
                backend.metadata["precision"] = precision
        self._velocity.metadata["units"] = f"{units}/s"

    # Getters and setters of the signals (detached in mock mode).

    async def _read_position(self) -> float:
        return await self._link.position(self._axis)

    async def _scale(self) -> UnitScale:
        """The axis' unit scale, read now."""
        # dim, pitch, gear or usteps may have changed through any path since the link
        # opened: a raw line, a restore, another device, another program.
        scale = (await self._link.controller.settings.unit_scales())[self._axis]
        self._link.scales[self._axis] = scale
        return scale

    async def _controller_get(self, name: str) -> float:
        return float(await self._link.controller.get(name, axis=self._axis))

    async def _controller_put(self, name: str, value: float | None) -> None:
        if value is None:
            raise ValueError(f"{self.name}: {name} needs a number")
        await self._link.controller.set(name, float(value), axis=self._axis)

    async def _get_velocity(self) -> float:
        scale, vel = await asyncio.gather(self._scale(), self._controller_get("vel"))
        return egu_velocity(vel, scale)

    async def _put_velocity(self, value: float | None) -> None:
        if value is None:
            raise ValueError(f"{self.name}: velocity needs a number")
        await self._controller_put("vel", controller_velocity(float(value),
                                                              await self._scale()))

    async def acceleration_egu(self) -> float:
        """The acceleration in EGU/s² (``accel`` converted).

        Returns
        -------
        float
            The acceleration, in EGU/s².
        """
        scale, accel = await asyncio.gather(self._scale(), self._controller_get("accel"))
        return egu_acceleration(accel, scale)

    async def _max_velocity(self) -> float:
        return max_velocity(await self._scale())

    async def _acceleration_time(self) -> float:
        velocity, accel = await asyncio.gather(self._get_velocity(),
                                               self.acceleration_egu())
        return velocity / accel

    async def _put_acceleration_time(self, value: float | None) -> None:
        if value is None or not float(value) > 0:
            raise ValueError(f"{self.name}: acceleration_time must be positive, "
                             f"got {value!r}")
        velocity = await self._get_velocity()
        per_m_s2 = egu_acceleration(1.0, await self._scale())
        await self._controller_put("accel", velocity / float(value) / per_m_s2)

    async def _egu(self) -> str:
        return self._link.units.get(self._axis, "")

    async def _precision(self) -> int:
        return self._link.precision.get(self._axis, 0)

    async def _usteps(self) -> int:
        return (await self._scale()).usteps

    async def _per_rev(self) -> float:
        return (await self._scale()).user_per_rev

    async def _resolution(self) -> float:
        return (await self._scale()).resolution

    async def _done_move(self) -> int:
        letters = await self._link.controller.status()
        return int(letters.get(self._axis) != MOVING)

    async def _offset(self) -> float:
        return await self._controller_get("posclr")

    async def _put_offset(self, value: float | None) -> None:
        if value is None:
            raise ValueError(f"{self.name}: offset needs a number")
        old = await self._offset()
        position = await self._link.position(self._axis)
        await self._redefine(position - old + float(value))

    async def _redefine(self, position: float) -> None:
        """``!pos`` of this axis (refused while it moves: the origin would slip)."""
        controller = self._link.controller
        if (await controller.status()).get(self._axis) == MOVING:
            raise InvalidCommandError(f"{self.name}: cannot redefine the position while "
                                      "the axis moves", instruction="pos", number=5)
        old = await self._link.position(self._axis)
        await controller.set("pos", position, axis=self._axis)
        now = await self._link.position(self._axis)
        setpoint = await self.user_setpoint.get_value()
        await self.user_setpoint.set(setpoint + (now - old))

    async def _limit(self, which: int) -> float:
        return (await self._link.read_limits(self._axis))[which]

    async def _put_limit(self, which: int, value: float | None) -> None:
        if value is None:
            raise ValueError(f"{self.name}: a limit needs a number")
        # Both limits go in one !lim line (L4540): a put of the other one at the same
        # time (bps.mv(low, a, high, b)) waits, so that neither undoes the other.
        async with self._limit_lock:
            pair = list(await self._link.read_limits(self._axis))
            pair[which] = float(value)
            limits: dict[str, Any] = {self._axis: (pair[0], pair[1])}
            await self._link.controller.settings.set_limits(**limits)
            await self._link.read_limits(self._axis)

    async def _dial(self, which: int) -> float:
        return await self._limit(which) - await self._offset()

    async def _put_dial(self, which: int, value: float | None) -> None:
        if value is None:
            raise ValueError(f"{self.name}: a limit needs a number")
        await self._put_limit(which, float(value) + await self._offset())

    async def _switch(self, which: int) -> int:
        return _switches(await self._link.controller.query("?readsw"), self._axis)[which]

    async def _put_stop(self, value: int | None) -> None:
        if value:
            await self.stop()

    async def connect(self, mock: bool | DeviceMock[Any] = False,
                      timeout: float = DEFAULT_TIMEOUT, force_reconnect: bool = False
                      ) -> None:
        """Connect (the stage has opened the link); take units, precision and the current
        position as the setpoint, so that ``locate()`` is right from the start.

        Parameters
        ----------
        mock
            Connect to a mock instead (ophyd-async's ``Device.connect``).
        timeout
            Seconds the connection may take.
        force_reconnect
            Connect again even if connected.
        """
        if mock:
            for backend in self._backends:
                backend.detach()
        await super().connect(mock=mock, timeout=timeout, force_reconnect=force_reconnect)
        self.movable_logic.mocked = bool(mock)
        if not mock:
            self._set_units()
            await self.user_setpoint.set(await self._read_position())


class MarzhauserStage(StandardReadable):
    """A TANGO controller as an ophyd-async device with one child axis per letter.

    ``MarzhauserStage(url, axes="xy", name="stage", **connect_options)``:
    ``connect_options`` go to :func:`tango_aio.connect`. Sets of different axes that the
    RunEngine starts together (``bps.mv(stage.x, 1, stage.y, 2)``) are merged into one
    move: each ``set()`` announces itself when called, and a move waits for the sets
    announced while it was being collected, but never for time alone (a single set
    waits for nothing); ``window`` (0.25 s) bounds that wait. ``progress_interval`` (0.1 s)
    how often positions are polled while a move runs. ``stage.x``, ``stage.y``... (or
    ``stage.axis("x")``) are the :class:`MarzhauserAxis` children; ``read()`` reads them
    all. Close with ``await stage.aclose()`` (or the :func:`close_stage` plan stub).

    Parameters
    ----------
    url
        The controller's URL.
    axes
        The axis letters, distinct, of ``xyza``.
    name
        The device name.
    window
        The longest wait for sets announced together, in seconds.
    progress_interval
        Seconds between two position reads while a move runs.
    **connect_options
        Options of :func:`tango_aio.connect`.

    Raises
    ------
    ValueError
        ``axes`` are not distinct axis letters.
    """

    x: MarzhauserAxis
    y: MarzhauserAxis
    z: MarzhauserAxis
    a: MarzhauserAxis

    def __init__(self, url: str, axes: str = "xy", name: str = "stage", *,
                 window: float = 0.25, progress_interval: float = 0.1,
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
        """The child axis ``letter``.

        Parameters
        ----------
        letter
            The axis letter (``"x"``...).

        Returns
        -------
        MarzhauserAxis
            The child device of that axis.

        Raises
        ------
        MissingAxisError
            The stage has no such axis.
        """
        try:
            return self._axes[letter.lower()]
        except KeyError:
            raise MissingAxisError(f"{self.name} has no axis {letter!r}") from None

    async def refresh_settings(self) -> None:
        """Read units, unit scales (``dim``, ``pitch``, ``gear``, ``usteps``), limits
        and precision again: call it after changing them on the controller. Until then
        the axes convert with what was read at connect."""
        await self._link.refresh()
        for axis in self._axes.values():
            axis._set_units()

    async def aclose(self) -> None:
        """Stop what the devices move and close the controller."""
        await self._link.aclose()


def _await_statuses(start: Callable[[], Sequence[Awaitable[Any]]]) -> MsgGenerator[None]:
    """Plan stub: start statuses on the RunEngine's loop, wait for them in turn, and
    raise the first failure in the plan (``bps.wait_for`` alone swallows it).

    Yields
    ------
    Msg
        The plan's messages.
    """
    errors: list[BaseException] = []

    async def wait() -> None:
        for status in start():
            try:
                await status
            except Exception as exc:
                errors.append(exc)

    yield from bps.wait_for([wait])
    if errors:
        raise errors[0]


def home(*axes: MarzhauserAxis) -> MsgGenerator[None]:
    """Plan stub: calibrate (``!cal``) each axis in turn (:meth:`MarzhauserAxis.home`);
    the plan fails with the controller's failure.

    Parameters
    ----------
    *axes
        The axes to calibrate, in this order.

    Returns
    -------
    MsgGenerator[None]
        The plan.
    """
    return _await_statuses(lambda: [axis.home() for axis in axes])


def measure_range(*axes: MarzhauserAxis) -> MsgGenerator[None]:
    """Plan stub: range measure (``!rm``) each axis in turn
    (:meth:`MarzhauserAxis.measure_range`); the plan fails with the controller's failure.

    Parameters
    ----------
    *axes
        The axes to measure, in this order.

    Returns
    -------
    MsgGenerator[None]
        The plan.
    """
    return _await_statuses(lambda: [axis.measure_range() for axis in axes])


def close_stage(stage: MarzhauserStage) -> MsgGenerator[None]:
    """Plan stub: close the stage's controller on the RunEngine's loop.

    Parameters
    ----------
    stage
        The stage whose controller to close.

    Yields
    ------
    Msg
        The plan's messages.
    """
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


async def _started(controller: Controller, axis: str, travel: asyncio.Task[bool],
                   stopped_ok: Callable[[], bool]) -> None:
    """Return once ``axis`` moves or the pass has already ended (a short pass may end
    between two polls); raise its error if it failed. A pass that a stop with success
    (RunEngine pause) cancelled before it was seen moving is no failure (the pause
    that lands during kickoff)."""
    while not travel.done():
        if (await controller.status()).get(axis) == MOVING:
            return
        await asyncio.wait([travel], timeout=0.01)
    if travel.cancelled() and stopped_ok():
        return
    travel.result()


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

