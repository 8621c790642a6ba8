"""The :class:`Controller` API: identity, typed settings, awaitable motion, events."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import (
    AsyncIterator,
    Awaitable,
    Callable,
    Coroutine,
    Mapping,
    Sequence,
)
from types import TracebackType
from typing import Any

from .._checks import check_count, check_timeout
from ..catalog import (
    AXES,
    Command,
    Completion,
    build_axes,
    check_axis_word,
)
from ..errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    InvalidCommandError,
    MoveOutcomeUnknown,
    TangoError,
)
from ..events import (
    ConnectionLost,
    EventHub,
    MoveAborted,
    MoveFinished,
    PositionUpdate,
    Reconnected,
    StatusReport,
    Subscription,
    UnsolicitedLine,
)
from ..families import (
    IO,
    ClosedLoop,
    DevicePort,
    Encoders,
    Info,
    Joystick,
    Settings,
    Snapshots,
    Triggers,
)
from ..link import (
    Closer,
    MoveHandle,
    Reconnect,
    Reconnector,
    Signature,
    Submission,
    TangoProtocol,
)
from ..moves import (
    MoveTracker,
)
from ..sansio import (
    Completed,
    DriverState,
    Dropped,
    Event,
    Unsolicited,
)
from ..status import CALIBRATED_FLAG, FAILED_LETTERS, MOVING
from ..units import Measure
from ._exchanges import _LIMIT_NEUTRAL
from ._motion import (
    STOP_WAIT,
    Motion,
    annotate,
)
from ._planning import Speed, _line_groups, _Planning
from ._ports import _Devices, _Port, _Relink
from ._reads import Identity, _read_command
from ._restart import (
    RestartWatch,
    report_suggests_restart,
    unreported_end_suggests_restart,
)

__all__ = ["Controller"]

log = logging.getLogger("tango_aio")

#: Seconds :meth:`Controller.aclose` waits at most for the replies to the driver's own
#: lines still in flight (a separator behind a move's confirmation: a few milliseconds
#: at 57600 Bd), so that the next program on the port does not read them.
CLOSE_SETTLE = 0.25


class Controller(_Planning, _Devices):
    """A connected TANGO controller. Get one with :func:`tango_aio.connect`.

    Every method validates its input with the instruction catalog before a byte is
    written (:class:`~tango_aio.errors.InvalidCommandError`), and reports errors the
    controller signals as the typed :class:`~tango_aio.errors.ControllerError` subclass.

    Motion methods return when the controller reports completion (autostatus 1-4), or,
    in autostatus 0, when polling ``statusaxis`` shows the axes stopped. Moves on one
    controller are serialised: a second concurrent move waits until the first finished,
    so completion reports can never be mixed up.

    Connection loss: everything awaited fails with
    :class:`~tango_aio.errors.ConnectionLostError` (``__cause__`` says why) and
    :meth:`events` yields :class:`~tango_aio.events.ConnectionLost`. Without automatic
    reconnect the event streams then end. With ``connect(url, reconnect=True)`` they go on:
    the object stays valid, the same URL is opened again in the background (see
    :mod:`tango_aio.link._reconnect`) and :class:`~tango_aio.events.Reconnected` follows. Calls
    made while the link is down fail at once with ConnectionLostError, they do not wait;
    :meth:`wait_connected` waits for the link. ``reconnect`` (what ``connect`` passes) says
    how to open the link again; it takes effect once :meth:`setup` has succeeded, and the
    controller's :class:`~tango_aio.link._reconnect.Reconnector` does the work.

    Parameters
    ----------
    protocol
        The connected protocol the controller drives.
    url
        The URL the link was opened with (opened again by a reconnect).
    reply_timeout
        Seconds a request waits for its reply unless a call says otherwise.
    on_close
        Awaited by :meth:`aclose` once the link is closed (e.g. closes the port).
    reconnect
        How to open the link again after a loss; ``None``: no automatic reconnect.
    """

    def __init__(
        self,
        protocol: TangoProtocol,
        *,
        url: str = "",
        reply_timeout: float = 5.0,
        on_close: Callable[[], Awaitable[None]] | None = None,
        reconnect: Reconnect | None = None,
    ) -> None:
        self.url = url
        self.reply_timeout = reply_timeout
        self._protocol = protocol
        self._hub = EventHub()
        #: The cached settings (move timing, validation context): tango_aio.sansio._state.
        self._settings = DriverState()
        self._motion = Motion(_Port(self._start_move, self._accepted, self._stop_all,
                                    self._read_state, self._hub.publish, self._unreported))
        #: Motion calls under way, each an event set when it ends (wait_idle, is_busy).
        self._motion_calls: set[asyncio.Event] = set()
        #: Axes a line of this driver whose end nobody follows (speed, go, a raw move)
        #: may keep moving, until a status read shows them standing: their motion does
        #: not contradict a refusal of a later line (see _contest).
        self._turning: set[str] = set()
        #: Held by a move with its own velocity/acceleration (set, moved, restored).
        self._move_settings_lock = asyncio.Lock()
        self._identity: Identity | None = None
        #: Whether the letters are read axis by axis: the unit's all-axes ``?statusaxis``
        #: ends with ``.`` alone (not ``.-``, L2668-2670), like a completion report.
        self._letters_by_axis = False
        #: What this connection knows of its moves: where a move_by's start comes from
        #: (the HDI, the inputs, the positions confirmed since; tango_aio.moves).
        self._moves = MoveTracker()
        #: The software limits (``?lim``, dim unit) per axis as last read, for
        #: :meth:`axis_limits`; ``_limits_epoch`` counts what may have changed them.
        self._limits: dict[str, tuple[float, float]] = {}
        self._limits_epoch = 0
        self._on_close = on_close
        #: The persistent internal error (>= 20) last seen in ``?err``, 0 if none.
        self._fault = 0
        #: One list upload or download at a time (tango_aio.families._bulk).
        self._list_lock = asyncio.Lock()
        self._closing = False
        #: Reconnects after a loss (``reconnect``), armed once setup() has succeeded.
        self._reconnector: Reconnector[Controller] | None = (
            None if reconnect is None else Reconnector(reconnect, _Relink(
                lambda: self.url, self._signature, self._release_link, self._stage,
                self._adopt, self._reconnected, self._give_up)))
        #: Set (and replaced) whenever the link goes up or down: wakes wait_connected().
        self._link_event = asyncio.Event()
        #: The physical position unit of this connection (``connect(url, units="mm")``);
        #: ``None``: the controller's dim unit. See :mod:`tango_aio.units`.
        self.units: str | None = None
        #: Every setting by name, in physical units, and as a whole (snapshot, diff,
        #: restore, save): :class:`~tango_aio.families.Settings`.
        self.settings = Settings(self)
        #: The controller's identity and condition (manual chapter 6).
        self.info = Info(self)
        protocol.set_callbacks(self._on_protocol_event, self._on_connection_lost)
        #: Notices a controller that restarted behind the link and recovers
        #: (:mod:`tango_aio.controller._restart`).
        self._restarts = RestartWatch(self._reload_settings, self._hub.publish, reply_timeout)
        self._restarts.attach(protocol)
        devices: DevicePort = self  # the device families' port: the controller itself
        #: The HDI: on and off around automated moves (:class:`~tango_aio.families.Joystick`).
        self.joystick = Joystick(devices)
        #: Digital and analogue I/O, shutter, LED strobe (:class:`~tango_aio.families.IO`).
        self.io = IO(devices)
        #: Encoders (:class:`~tango_aio.families.Encoders`).
        self.encoders = Encoders(devices)
        #: Closed loop (:class:`~tango_aio.families.ClosedLoop`).
        self.closed_loop = ClosedLoop(devices)
        #: The trigger output and its list (:class:`~tango_aio.families.Triggers`).
        self.triggers = Triggers(devices)
        #: The snapshot input and array (:class:`~tango_aio.families.Snapshots`).
        self.snapshots = Snapshots(devices)

    # -- lifecycle ------------------------------------------------------------------------

    @property
    def protocol(self) -> TangoProtocol:
        """The underlying protocol (for diagnostics)."""
        return self._protocol

    @property
    def identity(self) -> Identity:
        """The identity read when connecting. Raises :class:`RuntimeError` if
        identification was skipped (``connect(url, identify=False)``).

        Raises
        ------
        RuntimeError
            The controller was not identified.
        """
        if self._identity is None:
            raise RuntimeError("the controller was not identified: connect(identify=False) "
                               "skips it (identify() reads the identity)")
        return self._identity

    @property
    def autostatus(self) -> int:
        """The autostatus mode the driver believes is in force."""
        return self._protocol.autostatus

    async def aclose(self) -> None:
        """Close the connection and stop reconnecting. Pending requests fail with
        ConnectionLostError. The replies to the driver's own lines still in flight
        (separators, credit markers) are waited for first, for at most
        :data:`CLOSE_SETTLE` seconds."""
        self._closing = True
        self._restarts.close()
        self._motion.cancel_detached()
        if self._reconnector is not None:
            await self._reconnector.stop()
        try:
            await self._protocol.settle(CLOSE_SETTLE)
        except BaseException:
            self._protocol.close()
            self._hub.close()
            raise
        self._protocol.close()
        closer, self._on_close = self._on_close, None
        if closer is not None:
            await closer()
        self._hub.close()
        self._link_changed()

    async def __aenter__(self) -> Controller:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()

    # -- connection state and automatic reconnect ----------------------------------------

    @property
    def connected(self) -> bool:
        """Whether the link is up (False once lost, while reconnecting, after aclose)."""
        return self._protocol.is_connected

    @property
    def reconnecting(self) -> bool:
        """Whether an automatic reconnect is under way."""
        return self._reconnector is not None and self._reconnector.running

    @property
    def reconnect_attempt(self) -> int:
        """Number of the current (or last) reconnect attempt of the latest outage (0:
        none yet)."""
        return 0 if self._reconnector is None else self._reconnector.attempt

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Return once the link is up (at once if it is).

        Raises :class:`~tango_aio.errors.ConnectionLostError` when it will not come back:
        no automatic reconnect, reconnecting gave up (``__cause__`` says why, e.g.
        :class:`~tango_aio.link._reconnect.IdentityMismatchError`), or :meth:`aclose` was
        called; :class:`TimeoutError` after ``timeout`` seconds.

        Parameters
        ----------
        timeout
            Seconds to wait at most; ``None``: no limit.

        Raises
        ------
        ConnectionLostError
            The link will not come back.
        TimeoutError
            It did not come back within ``timeout`` seconds.
        """
        async with asyncio.timeout(check_timeout(timeout, zero=True)):
            while not self.connected:
                if not self.reconnecting:
                    self._protocol.check()
                    raise ConnectionLostError("not connected")
                await self._link_event.wait()

    def _link_changed(self) -> None:
        event, self._link_event = self._link_event, asyncio.Event()
        event.set()

    def _on_connection_lost(self, exc: BaseException | None) -> None:
        self._hub.publish(ConnectionLost(exc))
        self._motion.hint()  # moves being followed fail at once, not at their next poll
        if self._closing or self._reconnector is None or \
                not self._reconnector.start(self._protocol.autostatus):
            self._hub.close()  # no reconnect: the event streams end
        self._link_changed()

    # -- motion (followed by _motion.py, planned by _planning.py) -------------------------

    def validate_move(self, /, *, relative: bool = False, **axes: float) -> None:
        """Check the targets of a move (``relative``: distances, as for :meth:`move_by`)
        exactly as :meth:`move_to` does before a byte is written, without moving.

        Raises :class:`~tango_aio.errors.InvalidCommandError` (a :class:`ValueError`) for
        no axis at all, an unknown axis keyword or one this controller does not have, a
        value that is not a finite number (``nan``, a string, a bool) or is out of the
        catalog's range. Values are in the controller's unit (no ``unit=`` conversion:
        that needs the scales read from the controller). Reads the cached context only, so
        it is safe to call from any task; used by
        :class:`~tango_aio.ControllerGroup` to check every member first.

        Parameters
        ----------
        relative
            The values are distances (:meth:`move_by`), not positions (:meth:`move_to`).
        **axes
            The target (or distance) of each axis, in the controller's unit.

        Raises
        ------
        InvalidCommandError
            The move would be refused by :meth:`move_to` (or :meth:`move_by`).
        """
        name = "mor" if relative else "moa"
        for part in _line_groups(axes):
            self._check_axes(build_axes(name, part, context=self.context), part)

    async def move_to(self, /, *, timeout: float | None = None, stop_on_cancel: bool = True,
                      unit: str | None = None, velocity: Speed | None = None,
                      acceleration: Speed | None = None, **axes: float) -> dict[str, str]:
        """Move to absolute positions (``move_to(x=10, y=5)``, any set of axes) and wait
        until every named axis stands still at its target.

        Returns the per-axis status letters; raises :class:`MoveError` if a moved axis
        reports E (error/aborted), S (limit switch) or T (timeout), stopped short of its
        target, or was stopped by :meth:`abort`; :class:`ControllerTimeoutError` (axes
        stopped) if it still moves after ``timeout`` seconds (default: computed from the
        distance, speed, ``delay``, ``pause`` and ``ctrt``), counted from when its line is
        written. Axes not named are never moved: a set that does not start at X without
        gaps (``move_to(y=5, z=1)``) is moved axis by axis (docs/concepts/motion.md).
        Positions are in ``unit`` (``move_to(x=1.5, unit="mm")``; default: the
        connection's ``units``, else the dim unit) or pint Quantities.

        ``velocity`` and ``acceleration`` apply to this move only: one number for every
        moved axis, or a mapping per axis (``velocity={"x": 5}``), in ``unit`` per second
        (squared) when ``unit`` is given, else as :meth:`set_velocity` and
        :meth:`set_acceleration` take them. The moved axes' ``vel``/``accel`` are read,
        set, and written back once the move has ended (also when it failed or was
        cancelled). Moves of this controller that pass their own ``velocity`` or
        ``acceleration`` run one after the other; a move without them that runs at the
        same time moves at the speed in force (so either give every concurrent move its
        speed, or none).

        Parameters
        ----------
        timeout
            Seconds the move may take from when its line is written; ``None``: computed
            from the distance, the speed and the settings.
        stop_on_cancel
            Stop the moved axes when the awaiting task is cancelled.
        unit
            The unit of the values and of ``velocity``/``acceleration``; ``None``: the
            connection's ``units``, else the controller's dim unit.
        velocity
            The ``vel`` for this move only: one number for every moved axis, or by axis.
        acceleration
            The ``accel`` for this move only: one number for every moved axis, or by axis.
        **axes
            The target position of each axis (``x=10``).

        Returns
        -------
        dict[str, str]
            The status letter of each moved axis (``@`` once it stands still).

        Raises
        ------
        MoveError
            A moved axis reported E, S or T, stopped short of its target, or was stopped
            by :meth:`stop` or :meth:`abort`.
        ControllerTimeoutError
            An axis still moved after ``timeout`` seconds (the axes are stopped).
        InvalidCommandError
            A target or an axis is refused (an axis the controller does not have, a value
            out of range), before anything is written.
        ValueError
            ``timeout`` is NaN, infinite, zero or negative (before anything is written).
        """
        check_timeout(timeout)  # refused before anything is read or written
        with self._motion_call():
            axes = await self._to_controller(axes, unit, Measure.POSITION)
            async with self._move_settings(axes, unit, velocity, acceleration):
                return await self._move("moa", axes, timeout, stop_on_cancel)

    async def move_by(self, /, *, timeout: float | None = None, stop_on_cancel: bool = True,
                      unit: str | None = None, velocity: Speed | None = None,
                      acceleration: Speed | None = None, **axes: float) -> dict[str, str]:
        """Move by relative distances (``move_by(x=-1.5)``) and wait; see :meth:`move_to`
        (``velocity`` and ``acceleration`` for this move only, too).

        Parameters
        ----------
        timeout
            The move's time limit in seconds, as for :meth:`move_to`.
        stop_on_cancel
            Whether cancelling the call stops the moved axes.
        unit
            The unit of the distances (and of the speeds), as for :meth:`move_to`.
        velocity
            This move's ``vel`` (a number, or a mapping by axis).
        acceleration
            This move's ``accel`` (a number, or a mapping by axis).
        **axes
            The distance of each axis (``x=-1.5``).

        Returns
        -------
        dict[str, str]
            Each moved axis's status letter once all stand still.

        Raises
        ------
        MoveError
            As for :meth:`move_to`; the target is the start plus the distance.
        ControllerTimeoutError
            Still moving after ``timeout`` seconds (the axes are stopped).
        InvalidCommandError
            A distance or an axis is refused before anything is written.
        """
        check_timeout(timeout)  # refused before anything is read or written
        with self._motion_call():
            axes = await self._to_controller(axes, unit, Measure.POSITION)
            async with self._move_settings(axes, unit, velocity, acceleration):
                return await self._move("mor", axes, timeout, stop_on_cancel)

    async def calibrate(self, *axes: str, timeout: float | None = None,
                        stop_on_cancel: bool = True) -> dict[str, str]:
        """Calibrate (``cal``): travel to the lower limit switch and set the origin.
        Without arguments all enabled axes calibrate together.

        Parameters
        ----------
        *axes
            The axes to calibrate (``"x"``...), one after the other; none: every enabled
            axis together.
        timeout
            Seconds the motion may take from when its line is written; ``None``: computed
            from the settings.
        stop_on_cancel
            Stop the axes when the awaiting task is cancelled.

        Returns
        -------
        dict[str, str]
            The status letter of each axis (``@`` once it stands still).

        Raises
        ------
        MoveError
            An axis reported E, S or T, or was stopped by :meth:`stop` or :meth:`abort`.
        ControllerTimeoutError
            An axis still moved after ``timeout`` seconds (the axes are stopped).
        """
        return await self._per_axis_motion("cal", axes, timeout, stop_on_cancel)

    async def measure_range(self, *axes: str, timeout: float | None = None,
                            stop_on_cancel: bool = True) -> dict[str, str]:
        """Range measure (``rm``): travel to the upper limit switch and set the upper
        limit.

        Parameters
        ----------
        *axes
            The axes to measure, one after the other; none: all enabled axes at once.
        timeout
            Seconds allowed from when the line is written (``None``: estimated from the
            settings).
        stop_on_cancel
            Whether cancelling the call stops the travelling axes.

        Returns
        -------
        dict[str, str]
            The final status letter of every measured axis.

        Raises
        ------
        MoveError
            As for :meth:`calibrate`.
        ControllerTimeoutError
            As for :meth:`calibrate`.
        """
        return await self._per_axis_motion("rm", axes, timeout, stop_on_cancel)

    async def move_to_center(self, *axes: str, timeout: float | None = None,
                             stop_on_cancel: bool = True) -> dict[str, str]:
        """Move to the centre of the measured range (``moc``).

        Parameters
        ----------
        *axes
            The axes to centre, one after the other; none: all enabled axes at once.
        timeout
            Seconds allowed for each line from when it is written (``None``: estimated
            from the settings).
        stop_on_cancel
            Whether cancelling the call stops the axes on their way.

        Returns
        -------
        dict[str, str]
            The final status letter of every centred axis.

        Raises
        ------
        MoveError
            An axis did not reach the centre (see :meth:`calibrate`).
        ControllerTimeoutError
            An axis was still under way after ``timeout`` seconds (it is stopped).
        """
        return await self._per_axis_motion("moc", axes, timeout, stop_on_cancel)

    async def go(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Start ``go`` moves to absolute targets (no completion report; use
        :meth:`wait_idle`). A later ``go`` overrides the targets mid-move. Targets in
        ``unit`` as for :meth:`move_to`.

        Parameters
        ----------
        unit
            The unit of the values (``"mm"``, ``"um"``...); ``None``: the connection's
            ``units``, else the controller's dim unit.
        **axes
            The target position of each axis.

        Raises
        ------
        InvalidCommandError
            A target or an axis is not valid, before anything is written.
        ControllerError
            The controller refused the line.
        MoveOutcomeUnknown
            In autostatus 0, 1 and 3 (no answer of its own): nothing in the state read
            behind the line shows that it arrived (an axis it sends neither moves nor
            stands at its target; one it stops still moves): it may not have been
            applied. The message says which axes were stopped or may still move.
        """
        axes = await self._to_controller(axes, unit, Measure.POSITION)
        command = build_axes("go", axes, context=self.context)
        self._check_axes(command, axes)
        await self._execute(command, check=True)

    async def speed(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Run axes at constant speed (rev/s, or mm/s in dim 9; or in ``unit``, e.g.
        ``"mm/s"``, default the connection's ``units`` per second); 0 stops. No completion
        report: use :meth:`wait_idle`.

        Parameters
        ----------
        unit
            The unit of the speeds (``"mm/s"``); ``None``: the connection's ``units`` per
            second, else rev/s (mm/s in dim 9).
        **axes
            The speed of each axis (0 stops it).

        Raises
        ------
        InvalidCommandError
            A speed or an axis is not valid, before anything is written.
        ControllerError
            The controller refused the line (nothing changed: none of its axes moves,
            or only as before).
        MoveOutcomeUnknown
            The line's verdict was garbled, or a refusal its moving axes contradict; or,
            in autostatus 0, 1 and 3 (no answer of its own), nothing in the state read
            behind the line shows that it arrived (an axis it sets running stands, or
            runs as before without ``?speed`` showing the new speed; one it stops still
            moves after its ramp): it may not have been applied. The message says which
            axes were stopped or may still move.
        TangoError
            The line's answer was lost; its note says whether the running axes were
            stopped.
        """
        axes = await self._to_controller(axes, unit, Measure.VELOCITY)
        command = build_axes("speed", axes, context=self.context)
        self._check_axes(command, axes)
        try:
            await self._execute(command, check=True)
        except (ControllerError, MoveOutcomeUnknown):
            # Refused with nothing of it moving: the line changed nothing (L2853-2856); or
            # a verdict that motion contradicted or that made no sense, the error saying
            # what was stopped (Controller._contest).
            raise
        except TangoError as exc:
            # Its answer was lost: the axes may run. A call that raises never leaves
            # axes it set moving: stop them and say so.
            running = [axis for axis, value in axes.items() if value]
            if running:
                named = " ".join(running).upper()
                try:
                    await self.stop(*running)
                except TangoError:
                    raise annotate(exc, f"axes {named} may still move") from exc.__cause__
                raise annotate(exc, f"axes {named} stopped") from exc.__cause__
            raise

    async def wait_idle(self, *, poll_interval: float = 0.05,
                        timeout: float | None = None) -> dict[str, str]:
        """Wait until no motion call of this controller is under way (one started a moment
        ago, e.g. with ``asyncio.ensure_future(tango.move_to(...))``, included, though its
        line is not written yet), then poll ``statusaxis`` until no axis is moving; return
        the letters.

        Parameters
        ----------
        poll_interval
            Seconds between two ``statusaxis`` reads.
        timeout
            Seconds to wait at most; ``None``: no limit.

        Returns
        -------
        dict[str, str]
            The status letter of each present axis.

        Raises
        ------
        TimeoutError
            Still busy after ``timeout`` seconds.
        """
        async with asyncio.timeout(check_timeout(timeout)):
            await asyncio.sleep(0)  # a motion task just scheduled takes its first step
            while self._motion_calls:
                await next(iter(self._motion_calls)).wait()
            while True:
                letters = await self.status()
                if MOVING not in letters.values():
                    return letters
                await asyncio.sleep(poll_interval)

    async def is_busy(self) -> bool:
        """Whether a motion call of this controller is under way or any axis moves
        (``statusaxis`` ``M``): the momentary answer; :meth:`wait_idle` waits.

        Returns
        -------
        bool
            ``True`` if a motion call is under way or an axis moves.
        """
        await asyncio.sleep(0)  # a motion task just scheduled takes its first step
        return bool(self._motion_calls) or MOVING in (await self.status()).values()

    async def is_calibrated(self, *axes: str) -> bool:
        """Whether ``axes`` (default: every present axis) have been calibrated (``cal``)
        since power-on, from ``?statuslimit`` (its characters 0-3 are ``A`` for a
        calibrated X, Y, Z, A; L5136-5191).

        Parameters
        ----------
        *axes
            The axes to check (``"x"``...); none: every present axis.

        Returns
        -------
        bool
            ``True`` if every one of them is calibrated.

        Raises
        ------
        InvalidCommandError
            An axis the controller does not have.
        """
        present = AXES[: self.context.axes]
        for axis in axes:
            check_axis_word(axis, "statuslimit")
        wanted = [axis.lower() for axis in axes] or list(present)
        self._check_axes(_read_command("statuslimit", None, self.context), wanted)
        flags = str(await self.query("?statuslimit")).strip()
        return all(len(flags) > AXES.index(axis) and flags[AXES.index(axis)] == CALIBRATED_FLAG
                   for axis in wanted)

    async def stop(self, *axes: str, wait: bool = True) -> None:
        """Stop the named axes (``stop("x")``, ``stop("x", "z")``) with the manual's
        one-axis abort ``a x`` (L6785-6844: stops the moves of that axis with stopaccel);
        the other axes go on. Without axes, stops every axis with ``a`` (as
        ``abort(soft=True)``), and so on firmware of the older manual, whose ``a`` takes no
        axis (:attr:`Identity.family` ``"older"``: every axis stops). Moves being awaited
        (or detached) that move a stopped axis raise :class:`MoveError` once their axes
        stand still; moves of other axes are not affected. An axis the controller lacks
        raises :class:`~tango_aio.errors.InvalidCommandError` before anything is written.
        With ``wait``, returns once the stopped axes stand still; raises
        :class:`~tango_aio.errors.ControllerTimeoutError` if they still move after
        ``STOP_WAIT`` seconds.

        Parameters
        ----------
        *axes
            The axes to stop (``"x"``...); none: every axis.
        wait
            Return only once the stopped axes stand still.

        Raises
        ------
        InvalidCommandError
            An axis the controller does not have (nothing is written).
        ControllerTimeoutError
            With ``wait``: an axis still moved ``STOP_WAIT`` seconds
            after the stop.
        """
        present = AXES[: self.context.axes]
        chosen: list[str] = []
        for axis in axes:
            letter = axis.lower() if isinstance(axis, str) else axis
            if letter not in present:
                raise InvalidCommandError(
                    f"stop({axis!r}): the controller has no {str(axis).upper()} axis "
                    f"(its axes: {' '.join(present).upper()})",
                    instruction="a", parameter="axis", number=1)
            if letter not in chosen:
                chosen.append(letter)
        if not chosen or (self._identity is not None and self._identity.family == "older"):
            # The older edition's `a` takes no axis ("stops all axes", old L1907-1919):
            # what it would make of `a x` is not written, so every axis is stopped.
            await self.abort(soft=True, wait=wait)
            return
        self._hub.publish(MoveAborted(ctrl_c=False, axes=tuple(chosen)))
        self._motion.stopped(chosen)
        await self._protocol.stop_soft(axes=chosen)
        if wait:
            try:
                async with asyncio.timeout(STOP_WAIT):
                    while True:
                        letters = await self.status()
                        if all(letters.get(axis) != MOVING for axis in chosen):
                            return
                        await asyncio.sleep(0.05)
            except TimeoutError:
                raise ControllerTimeoutError(
                    f"{' '.join(chosen).upper()} still moving {STOP_WAIT:.0f} s after the "
                    "stop") from None

    async def abort(self, *, soft: bool = False, wait: bool = True) -> None:
        """Stop all axes.

        By default this sends Ctrl+C (0x03): it stops every axis and makes the controller
        discard its input buffer (L6808-6814), so requests still queued fail with
        :class:`~tango_aio.errors.RequestAbortedError` and the reply stream is
        resynchronised. ``a`` is written before and after it, because a controller may
        ignore Ctrl+C (the manual does not say every interface passes it); ``a`` alone
        stops the axes and leaves queued lines alone (``soft=True``). Moves being awaited
        raise :class:`MoveError` (status ``E``) once their axes stand still, whatever
        letters the controller reports (older firmware reports ``@``, old L1917). With ``wait``,
        returns once the axes have stopped; raises
        :class:`~tango_aio.errors.ControllerTimeoutError` if they still move after
        ``STOP_WAIT`` seconds.

        Parameters
        ----------
        soft
            Write ``a`` only, without Ctrl+C (queued lines are kept).
        wait
            Return only once every axis stands still.

        Raises
        ------
        ControllerTimeoutError
            With ``wait``: an axis still moved ``STOP_WAIT`` seconds
            after the abort.
        """
        self._hub.publish(MoveAborted(ctrl_c=not soft))
        self._motion.stopped()
        # ``a`` first: it stops the axes at once even on a controller that ignores Ctrl+C,
        # and Ctrl+C behind it still discards whatever is queued in the input buffer.
        await self._protocol.stop_soft()
        if not soft:
            try:
                await self._protocol.stop_hard(timeout=self.reply_timeout)
            except ControllerTimeoutError:
                # Ctrl+C may have been taken as part of the marker line (a controller that
                # ignores it): resync again without it.
                await self._protocol.resync(timeout=self.reply_timeout)
                await self._protocol.read_autostatus(timeout=self.reply_timeout)
            await self._protocol.stop_soft()  # in case Ctrl+C discarded the first ``a``
            self._motion.stopped()
        if wait:
            try:
                await self.wait_idle(timeout=STOP_WAIT)
            except TimeoutError:
                raise ControllerTimeoutError(
                    f"axes still moving {STOP_WAIT:.0f} s after the abort") from None

    # -- events ---------------------------------------------------------------------------

    def events(self, maxsize: int = 256) -> Subscription:
        """Subscribe to the controller's events (an async iterator). When the buffer is
        full the oldest events are dropped (counted in ``Subscription.dropped``).

        Parameters
        ----------
        maxsize
            The size of the buffer (in events).

        Returns
        -------
        Subscription
            An async iterator of the events from now on; close it when done.
        """
        return self._hub.subscribe(check_count(maxsize, "maxsize"))

    async def watch_position(self, interval: float = 0.1, *, follow: bool = False,
                             unit: str | None = None) -> AsyncIterator[PositionUpdate]:
        """Yield positions (in ``unit``, as :meth:`position`) every ``interval`` seconds
        while any axis moves or a move of this driver is in flight, then once more when
        all is idle. Each update is also published to :meth:`events`.

        ``follow=True`` follows a whole scan: it goes on through the idle moments between
        moves, until the caller stops iterating (``break``) or cancels; while all is idle
        it yields only when a position changed, so a paused scan does not flood the
        caller.

        Parameters
        ----------
        interval
            Seconds between two reads.
        follow
            Go on through idle moments until the caller stops.
        unit
            The unit of the values (``"mm"``, ``"um"``...); ``None``: the connection's
            ``units``, else the controller's dim unit.

        Yields
        ------
        PositionUpdate
            The positions of the present axes.
        """
        check_timeout(interval, "interval")
        chosen = self._reading_unit(unit, Measure.POSITION)
        last: Mapping[str, float] | None = None
        while True:
            letters, texts = await self._status_and_positions()
            update = PositionUpdate(await self._from_controller(texts, chosen, Measure.POSITION))
            idle = MOVING not in letters.values() and not self._motion.busy
            if not (follow and idle and update.positions == last):
                self._hub.publish(update)
                yield update
            last = update.positions
            if idle and not follow:
                return
            await asyncio.sleep(interval)

    def _on_protocol_event(self, event: Event, submission: Submission | None) -> None:
        if isinstance(event, Completed):
            if report_suggests_restart(self._protocol.autostatus, bool(event.letters)):
                self._restarts.suspect()  # a report the mode in force does not send
            if submission is None or submission.command.name not in _LIMIT_NEUTRAL:
                self._forget_limits()  # the end of a cal or rm sets limits (L4575-4580)
            self._publish_completion(event, submission)
            self._motion.reported()
        elif isinstance(event, Unsolicited):
            self._hub.publish(UnsolicitedLine(event.line))
        elif isinstance(event, Dropped):
            log.debug("dropped %r", event.line)

    def _publish_completion(self, event: Completed, submission: Submission | None) -> None:
        """A report is a hint for the moves tango_aio.controller._motion follows (they publish
        MoveFinished once confirmed). A report no move waited for is a StatusReport; one
        that ends a raw ``command()`` move is published as it came."""
        letters = event.letters or {}
        if submission is None:
            self._hub.publish(StatusReport(letters, event.line))
        elif not self._motion.follows(submission):
            completion = submission.command.instruction.completion
            kind = {Completion.CAL: "cal", Completion.RM: "rm"}.get(completion, "move") \
                if completion else "move"
            ok = not (set(letters.values()) & FAILED_LETTERS)
            self._hub.publish(MoveFinished(kind, letters, ok))

    # -- what Motion and the Reconnector see (handed over as _Port and _Relink) -------------

    def _start_move(self, command: Command, batch: object | None) -> MoveHandle:
        return self._send(command, check=True, batch=batch)

    async def _accepted(self, sent: MoveHandle) -> ControllerError | None:
        error = await self._error_of(sent, self.reply_timeout)
        if error is None:
            self._track(sent.command)
        return error

    async def _stop_all(self) -> None:
        await self._protocol.stop_soft()

    def _unreported(self) -> None:
        if unreported_end_suggests_restart(self._protocol.autostatus):
            self._restarts.suspect()

    def _read_state(self, axes: Sequence[str]
                    ) -> Coroutine[Any, Any, tuple[dict[str, str], dict[str, str]]]:
        # Written now (MotionPort.read_state: also from a report's callback, in the loop
        # turn the report arrived); the coroutine reads the replies.
        self._protocol.check()
        if self._letters_by_axis:
            return self._state_by_axis()
        # A raster's next move_to follows this read: its ?err probe looks like the
        # positions, and a separator behind them keeps it off the move's path.
        return self._state_replies(self._submit_state(True, axes))

    def _signature(self, controller: Controller | None = None) -> Signature | None:
        identity = (controller or self)._identity
        return None if identity is None else (identity.model, identity.firmware,
                                              identity.axes)

    async def _release_link(self) -> None:
        closer, self._on_close = self._on_close, None
        if closer is not None:
            await closer()  # e.g. the sim:// emulator of the lost link

    def _stage(self, protocol: TangoProtocol, closer: Closer | None) -> Controller:
        return Controller(protocol, url=self.url, reply_timeout=self.reply_timeout,
                          on_close=closer)

    def _adopt(self, staged: Controller, closer: Closer | None) -> None:
        self._protocol = staged._protocol
        self._protocol.set_callbacks(self._on_protocol_event, self._on_connection_lost)
        self._restarts.attach(self._protocol)
        self._settings = staged._settings
        self._identity = staged._identity or self._identity
        self._forget_limits()  # the controller may have been power cycled
        self._on_close = closer

    def _reconnected(self, attempt: int) -> None:
        self._hub.publish(Reconnected(attempt))
        self._link_changed()

    def _give_up(self, lost: ConnectionLostError) -> None:
        self._protocol.give_up(lost)
        self._hub.close()
        self._link_changed()
