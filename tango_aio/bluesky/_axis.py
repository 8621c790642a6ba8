"""One axis as an ophyd-async motor: its moves, stops, fly passes and signals."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import math
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, NoReturn

import anyio

try:
    from bluesky.protocols import Pausable
    from ophyd_async.core import (
        CALCULATE_TIMEOUT,
        DEFAULT_TIMEOUT,
        AsyncStatus,
        CalculatableTimeout,
        DeviceMock,
        FlyableLogic,
        FlyMotorInfo,
        MovableLogic,
        SignalR,
        SignalRW,
        SignalW,
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

from ..controller import STOP_WAIT, Controller
from ..errors import InvalidCommandError, MoveError, StageLimitsError, TangoError
from ..moves import position_tolerance
from ..status import ABSENT, ARRIVED_LETTERS, MOVING, AxisStatus, switch_states
from ..units import UnitScale
from ._link import Mover, StageLink, _Backend
from ._speeds import (
    controller_velocity,
    egu_acceleration,
    egu_velocity,
    max_velocity,
    run_up_distance,
)

#: ``accel`` is always in m/s² (manual L3303, L3329; see tango_aio.units).
ACCEL_UNIT = "m/s^2"


def _switches(reply: str, axis: str) -> tuple[int, int]:
    """(lower, upper) limit-switch state of ``axis`` from a ``?readsw`` reply: 12
    characters, E0 of X Y Z A, then Ref of X Y Z A, then EE of X Y Z A (L5027-5078)."""
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
        request has joined a batch."""
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
        driver's own rule). Anything else: False, and the line's error stands."""
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
        the axis stopped."""
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
        TimeoutError naming the axis, the target and where it stopped."""
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
    ``timed_out.timed_out`` set."""
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


async def _until_stopped(move: Awaitable[str], mover: Mover, limit: float | None = None,
                         halt: Callable[[], Awaitable[None]] | None = None) -> str:
    """Await ``move``; when cancelled after a stop was requested for it (the stop has
    sent ``a x``), let the line end by itself (bounded) instead of cancelling it: the
    driver's cancel would stop every axis of the line with ``a``. After ``limit``
    seconds (a set's or a pass's own timeout): mark ``mover`` timed out, ``halt()`` (the
    axis's one-axis stop), let the line end the same way and raise TimeoutError."""
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
