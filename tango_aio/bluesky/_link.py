"""What the devices of one stage share: the controller's link, its mover and signal backends."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from typing import Any

try:
    from ophyd_async.core import Device, DeviceConnector, SoftSignalBackend
except ImportError as exc:  # pragma: no cover - depends on the environment
    from .._install import install_hint

    raise ImportError(f"tango_aio.bluesky needs the bluesky extra: "
                      f"{install_hint('bluesky')}") from exc

from ..catalog import AXES
from ..controller import STOP_WAIT, Controller, connect
from ..errors import ControllerTimeoutError, MissingAxisError, TangoError
from ..events import MoveAborted, MoveFinished, PositionUpdate, Reconnected, StatusReport
from ..group import MoveCoalescer
from ..status import MOVING
from ..units import DIM_UNITS as _DIM_UNITS
from ..units import UnitScale

#: Position unit of each ``dim`` (manual L3061-3144); dim 9 is mm with velocities in mm/s.
DIM_UNITS = {dim: unit.symbol for dim, unit in _DIM_UNITS.items()}


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
        confirmation), if it has them."""
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


def _nothing() -> None:
    """An announcement that announced nothing (no coalescer yet, or mock mode)."""
