"""The :class:`Controller` API: identity, typed settings, awaitable motion, events."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from decimal import Decimal
from fractions import Fraction
from types import TracebackType
from typing import Any

import anyio

from ._checks import check_count, check_timeout
from .bulk import (
    ListTransfer,
    Progress,
    check_axis,
    snapshot_spec,
    trigger_spec,
    validate_rows,
    validate_trigger_positions,
)
from .core import Completed, Dropped, Event, Unsolicited
from .errors import (
    ConnectionLostError,
    ControllerTimeoutError,
    InvalidCommandError,
    MoveError,
    ProtocolError,
    RequestAbortedError,
    TangoError,
)
from .events import (
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
from .instructions import (
    AXES,
    Command,
    Completion,
    Context,
    DetInfo,
    Form,
    Value,
    VersionInfo,
    build,
    build_axes,
    parse,
    parse_reply,
)
from .protocol import MoveHandle, Response, Submission, TangoProtocol
from .reconnect import Closer, IdentityMismatchError, Reconnect
from .status import AxisStatus, axis_statuses
from .units import UnitScale, from_controller, plain, to_controller

__all__ = ["Controller", "Identity"]

log = logging.getLogger("tango_aio")

#: Longest wait for the axes to stop after a cancelled move (seconds).
STOP_WAIT = 10.0

#: Status letters that mean a move did not end where it should (manual L2689-2711).
FAILED_LETTERS = frozenset("EST")

_KINDS = {Completion.MOVE: "move", Completion.CAL: "cal", Completion.RM: "rm"}


@dataclass(frozen=True, slots=True)
class Identity:
    """What ``?version`` and ``?det`` say about the controller."""

    model: str
    firmware: str
    axes: int
    version: VersionInfo
    det: DetInfo


@dataclass(slots=True)
class _Settings:
    """Per-axis settings the driver caches to compute move timeouts and contexts."""

    dims: list[int] = field(default_factory=lambda: [2, 2, 2, 2])
    pitch: list[float] = field(default_factory=lambda: [1.0] * 4)
    vel: list[float] = field(default_factory=lambda: [10.0] * 4)
    accel: list[float] = field(default_factory=lambda: [1.0] * 4)
    secvel: list[float] = field(default_factory=lambda: [10.0] * 4)
    extmode: int = 0


class Controller:
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
    :mod:`tango_aio.reconnect`) and :class:`~tango_aio.events.Reconnected` follows. Calls
    made while the link is down fail at once with ConnectionLostError, they do not wait;
    :meth:`wait_connected` waits for the link.
    """

    def __init__(
        self,
        protocol: TangoProtocol,
        *,
        url: str = "",
        reply_timeout: float = 5.0,
        on_close: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        self.url = url
        self.reply_timeout = reply_timeout
        self._protocol = protocol
        self._hub = EventHub()
        self._motion_lock = asyncio.Lock()
        self._settings = _Settings()
        self._identity: Identity | None = None
        self._on_close = on_close
        self._detached: asyncio.Future[None] | None = None
        self._closing = False
        self._reconnect: Reconnect | None = None
        self._reconnect_task: asyncio.Task[None] | None = None
        self._reconnect_attempt = 0
        #: Set (and replaced) whenever the link goes up or down: wakes wait_connected().
        self._link_event = asyncio.Event()
        #: The physical position unit of this connection (``connect(url, units="mm")``);
        #: ``None``: the controller's dim unit. See :mod:`tango_aio.units`.
        self.units: str | None = None
        protocol.set_callbacks(self._on_protocol_event, self._on_connection_lost)

    # -- lifecycle ------------------------------------------------------------------------

    @property
    def protocol(self) -> TangoProtocol:
        """The underlying protocol (for diagnostics)."""
        return self._protocol

    @property
    def identity(self) -> Identity:
        """The identity read when connecting. Raises :class:`RuntimeError` if
        identification was skipped (``connect(url, identify=False)``)."""
        if self._identity is None:
            raise RuntimeError("the controller was not identified: connect(identify=False) "
                               "skips it (identify() reads the identity)")
        return self._identity

    @property
    def autostatus(self) -> int:
        """The autostatus mode the driver believes is in force."""
        return self._protocol.autostatus

    @property
    def context(self) -> Context:
        """Controller state used to validate lines (dims, axis count, extmode)."""
        return self._protocol.context

    async def aclose(self) -> None:
        """Close the connection and stop reconnecting. Pending requests fail with
        ConnectionLostError."""
        self._closing = True
        if self._detached is not None:
            self._detached.cancel()
        task, self._reconnect_task = self._reconnect_task, None
        if task is not None:
            task.cancel()  # it closes a link it was setting up
            await asyncio.wait([task])
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

    async def setup(self, *, autostatus: int | None = 1, identify: bool = True) -> None:
        """Bring the controller into a known state (called by :func:`connect`).

        Drains stale input by resynchronising, identifies the controller, reads the
        settings the driver needs and selects ``autostatus`` (``None``: keep the mode the
        controller is in). The mode in force is read first (reads are neither echoed nor
        acknowledged in any mode): a previous session may have left any mode behind, and
        how ``!autostatus`` itself is answered depends on it.
        """
        await self._protocol.resync(timeout=self.reply_timeout)
        current = await self._protocol.read_autostatus(timeout=self.reply_timeout)
        if autostatus is not None and autostatus != current:
            await self.command(f"!autostatus {autostatus}")
        if identify:
            self._identity = await self.identify()
        await self.refresh_settings()

    # -- connection state and automatic reconnect ----------------------------------------

    @property
    def connected(self) -> bool:
        """Whether the link is up (False once lost, while reconnecting, after aclose)."""
        return self._protocol.is_connected

    @property
    def reconnecting(self) -> bool:
        """Whether an automatic reconnect is under way."""
        return self._reconnect_task is not None and not self._reconnect_task.done()

    @property
    def reconnect_attempt(self) -> int:
        """Number of the current (or last) reconnect attempt of the latest outage (0:
        none yet)."""
        return self._reconnect_attempt

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Return once the link is up (at once if it is).

        Raises :class:`~tango_aio.errors.ConnectionLostError` when it will not come back:
        no automatic reconnect, reconnecting gave up (``__cause__`` says why, e.g.
        :class:`~tango_aio.reconnect.IdentityMismatchError`), or :meth:`aclose` was
        called; :class:`TimeoutError` after ``timeout`` seconds.
        """
        async with asyncio.timeout(check_timeout(timeout, zero=True)):
            while not self.connected:
                if not self.reconnecting:
                    self._protocol.check()
                    raise ConnectionLostError("not connected")
                await self._link_event.wait()

    def _enable_reconnect(self, reconnect: Reconnect) -> None:
        """Reconnect on its own after a loss (called by :func:`~tango_aio.connect`)."""
        self._reconnect = reconnect

    def _link_changed(self) -> None:
        event, self._link_event = self._link_event, asyncio.Event()
        event.set()

    def _on_connection_lost(self, exc: BaseException | None) -> None:
        self._hub.publish(ConnectionLost(exc))
        if self._reconnect is not None and not self._closing and not self.reconnecting:
            self._reconnect_attempt = 0
            mode = self._protocol.autostatus
            self._reconnect_task = asyncio.get_running_loop().create_task(
                self._reconnect_loop(self._reconnect, mode), name=f"tango_aio reconnect {self.url}")
        else:
            self._hub.close()
        self._link_changed()

    async def _reconnect_loop(self, reconnect: Reconnect, mode: int) -> None:
        """Try again after each delay of the policy until a link is up or it gives up."""
        error: BaseException | None = None
        for attempt, delay in enumerate(reconnect.policy.delays(), start=1):
            await asyncio.sleep(delay)
            self._reconnect_attempt = attempt
            try:
                await self._reconnect_once(reconnect, mode)
            except IdentityMismatchError as exc:
                error = exc
                break  # not transient: see tango_aio.reconnect
            except (TangoError, OSError, TimeoutError) as exc:
                error = exc
                log.warning("reconnect attempt %d to %s failed: %s", attempt, self.url, exc)
                continue
            except Exception as exc:  # a bug: do not retry it forever
                log.exception("reconnect attempt %d to %s failed", attempt, self.url)
                error = exc
                break
            self._hub.publish(Reconnected(attempt))
            self._link_changed()
            return
        self._give_up(error)

    async def _reconnect_once(self, reconnect: Reconnect, mode: int) -> None:
        """Open the URL again, set the new link up like the lost one and swap it in.

        The set-up runs on a throw-away Controller, so calls made meanwhile still fail
        at once on the lost link instead of reaching a half-set-up one.
        """
        closer, self._on_close = self._on_close, None
        if closer is not None:
            await closer()  # e.g. the sim:// emulator of the lost link
        protocol, closer = await reconnect.opener()
        fresh = Controller(protocol, url=self.url, reply_timeout=self.reply_timeout,
                           on_close=closer)
        try:
            await fresh.setup(autostatus=mode, identify=reconnect.identify)
            self._check_identity(fresh._identity)
            protocol.check()  # the new link may have dropped at the very end
        except BaseException:
            await fresh.aclose()
            raise
        self._adopt(fresh, closer)

    def _check_identity(self, found: Identity | None) -> None:
        known = self._identity
        if known is None or found is None:
            return
        if (found.model, found.firmware, found.axes) != (known.model, known.firmware,
                                                         known.axes):
            raise IdentityMismatchError(
                f"{self.url}: expected {known.model} firmware {known.firmware} with "
                f"{known.axes} axes, found {found.model} firmware {found.firmware} with "
                f"{found.axes} axes; not reconnecting")

    def _adopt(self, fresh: Controller, closer: Closer | None) -> None:
        """Take over ``fresh``'s link, settings and identity (no await: atomic)."""
        self._protocol = fresh._protocol
        self._protocol.set_callbacks(self._on_protocol_event, self._on_connection_lost)
        self._settings = fresh._settings
        self._identity = fresh._identity or self._identity
        self._on_close = closer

    def _give_up(self, error: BaseException | None) -> None:
        lost = ConnectionLostError(f"reconnecting to {self.url!r} gave up: {error}")
        lost.__cause__ = error
        self._protocol.give_up(lost)
        self._hub.close()
        self._link_changed()

    # -- identity and raw access -------------------------------------------------------------

    async def identify(self) -> Identity:
        """Read ``?version`` and ``?det``: model, firmware and number of axes."""
        version = await self.get("version")
        det = await self.get("det")
        assert isinstance(version, VersionInfo) and isinstance(det, DetInfo)
        axes = det.axes or 4
        context = self._protocol.context
        self._protocol.context = Context(context.dims, axes, context.extmode)
        return Identity(version.model, version.firmware, axes, version, det)

    async def refresh_settings(self) -> None:
        """Re-read dim, pitch, vel, accel, secvel and extmode (used for move timeouts)."""
        settings = self._settings
        settings.extmode = int(await self.get("extmode"))
        for name in ("dim", "pitch", "vel", "accel", "secvel"):
            values = await self.get(name)
            assert isinstance(values, dict)
            target = getattr(settings, "dims" if name == "dim" else name)
            for index, axis in enumerate(AXES):
                if axis in values:
                    target[index] = type(target[index])(values[axis])
        self._update_context()

    def _update_context(self) -> None:
        settings = self._settings
        self._protocol.context = Context(
            tuple(settings.dims), self._protocol.context.axes,  # type: ignore[arg-type]
            settings.extmode)

    async def query(self, line: str, timeout: float | None = None) -> str:
        """Send a read such as ``"?pos x"`` and return its reply text (lines joined by
        ``"\\n"``). Raises :class:`InvalidCommandError` for a line that does not read."""
        command = parse(line, self.context)
        if not command.is_read:
            raise InvalidCommandError(f"{command.line!r} does not read; use command()",
                                      instruction=command.name)
        response = await self._request(command, timeout)
        return "\n".join(response.lines)

    async def command(self, line: str, *, check: bool = True,
                      timeout: float | None = None) -> None:
        """Send a set/execute line such as ``"!vel y 12.5"``.

        With ``check`` (the default) the controller's error state is read right after the
        line (``?err``, or the acknowledgement in autostatus 2) and a non-zero error
        raises the typed :class:`~tango_aio.errors.ControllerError`.
        """
        command = parse(line, self.context)
        if command.is_read:
            raise InvalidCommandError(f"{command.line!r} is a read; use query()",
                                      instruction=command.name)
        await self._execute(command, check=check, timeout=timeout)

    def _check_axes(self, command: Command, names: Iterable[str] = ()) -> None:
        """Refuse an axis the controller does not have, before anything is written."""
        present = AXES[: self.context.axes]
        for letter in (*names, *(command.axis or "")):
            if letter not in present:
                raise InvalidCommandError(
                    f"{command.line!r}: the controller has no {letter.upper()} axis "
                    f"(its axes: {' '.join(present).upper()})",
                    instruction=command.name, parameter="axis", code=1)

    async def _request(self, command: Command, timeout: float | None = None) -> Response:
        self._check_axes(command)
        return await self._protocol.query(command, timeout=self._timeout(timeout))

    def _timeout(self, timeout: float | None) -> float:
        return self.reply_timeout if timeout is None else check_timeout(timeout) or 0.0

    async def _execute(self, command: Command, *, check: bool,
                       timeout: float | None = None) -> Response:
        """Write ``command`` (checked, see :meth:`TangoProtocol.execute`) and wait."""
        self._check_axes(command)
        response = await self._protocol.execute(command, timeout=self._timeout(timeout),
                                                check=check)
        self._track(command)
        return response

    def _send(self, command: Command, *, check: bool) -> MoveHandle:
        """Write a motion line and its check (see :meth:`TangoProtocol.start_move`)."""
        self._check_axes(command)
        return self._protocol.start_move(command, check=check)

    async def _confirm(self, sent: MoveHandle, timeout: float | None = None) -> None:
        """Wait for the check of a :meth:`_send`; raise the controller's error, if any."""
        await sent.confirm(self._timeout(timeout))
        self._track(sent.command)

    def _track(self, command: Command) -> None:
        name = command.name
        if name in ("dim", "pitch", "vel", "accel", "secvel", "extmode") and command.values:
            index = AXES.index(command.axis) if command.axis else 0
            target = {"dim": self._settings.dims}.get(name, getattr(self._settings, name, None))
            if name == "extmode":
                self._settings.extmode = int(command.values[0])
                return
            assert isinstance(target, list)
            for offset, value in enumerate(command.values[: len(AXES) - index]):
                target[index + offset] = type(target[index + offset])(value)
            self._update_context()

    # -- typed access ---------------------------------------------------------------------

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        """Read instruction ``name`` and return its parsed reply.

        Per-axis values come as ``{"x": 1.0, "y": 2.0}`` (only present axes), or a scalar
        when ``axis`` is given. ``args`` are extra read arguments (``get("trigp", 3)``).
        """
        command = build(name, *args, form=Form.READ, axis=axis, context=self.context)
        response = await self._request(command, timeout)
        return parse_reply(command, response.lines)

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        """Set instruction ``name``: ``set("vel", x=10, y=5)``, ``set("vel", 3, axis="z")``,
        ``set("autostatus", 1)``. Checks the error state like :meth:`command`."""
        command = build(name, *args, form=Form.SET, axis=axis, context=self.context, **axes)
        self._check_axes(command, axes)
        await self._execute(command, check=check)

    async def position(self, *, unit: str | None = None) -> dict[str, float]:
        """The position of every present axis, in ``unit`` (default: the connection's
        ``units``, else the axis' dim unit)."""
        chosen = self._reading_unit(unit, 0)
        positions = await self.get("pos")
        assert isinstance(positions, dict)
        return await self._from_controller(positions, chosen, 0)

    async def status(self) -> dict[str, str]:
        """The ``statusaxis`` letter of every present axis (``@`` idle, ``M`` moving...)."""
        letters = await self.get("statusaxis")
        assert isinstance(letters, dict)
        return dict(letters)

    # -- motion ---------------------------------------------------------------------------

    async def move_to(self, /, *, timeout: float | None = None, stop_on_cancel: bool = True,
                      unit: str | None = None, **axes: float) -> dict[str, str]:
        """Move to absolute positions (``move_to(x=10, y=5)``) and wait until they are
        reached. Returns the per-axis status letters; raises :class:`MoveError` if an axis
        reports E (error/aborted), S (limit switch) or T (timeout). Positions are in
        ``unit`` (``move_to(x=1.5, unit="mm")``; default: the connection's ``units``,
        else the dim unit) or pint Quantities."""
        axes = await self._to_controller(axes, unit, 0)
        return await self._motion(build_axes("moa", axes, context=self.context),
                                  timeout, stop_on_cancel, axes)

    async def move_by(self, /, *, timeout: float | None = None, stop_on_cancel: bool = True,
                      unit: str | None = None, **axes: float) -> dict[str, str]:
        """Move by relative distances (``move_by(x=-1.5)``) and wait; see :meth:`move_to`."""
        axes = await self._to_controller(axes, unit, 0)
        return await self._motion(build_axes("mor", axes, context=self.context),
                                  timeout, stop_on_cancel, axes, relative=True)

    async def calibrate(self, *axes: str, timeout: float | None = None,
                        stop_on_cancel: bool = True) -> dict[str, str]:
        """Calibrate (``cal``): travel to the lower limit switch and set the origin.
        Without arguments all enabled axes calibrate together."""
        return await self._per_axis_motion("cal", axes, timeout, stop_on_cancel)

    async def measure_range(self, *axes: str, timeout: float | None = None,
                            stop_on_cancel: bool = True) -> dict[str, str]:
        """Range measure (``rm``): travel to the upper limit switch and set the upper
        limit."""
        return await self._per_axis_motion("rm", axes, timeout, stop_on_cancel)

    async def move_to_center(self, *axes: str, timeout: float | None = None,
                             stop_on_cancel: bool = True) -> dict[str, str]:
        """Move to the centre of the measured range (``moc``)."""
        return await self._per_axis_motion("moc", axes, timeout, stop_on_cancel)

    async def _per_axis_motion(self, name: str, axes: tuple[str, ...], timeout: float | None,
                               stop_on_cancel: bool) -> dict[str, str]:
        if not axes:
            return await self._motion(build(name, form=Form.SET), timeout, stop_on_cancel, {})
        letters: dict[str, str] = {}
        for axis in axes:
            command = build(name, form=Form.SET, axis=axis)
            letters.update(await self._motion(command, timeout, stop_on_cancel, {}))
        return letters

    async def go(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Start ``go`` moves to absolute targets (no completion report; use
        :meth:`wait_idle`). A later ``go`` overrides the targets mid-move. Targets in
        ``unit`` as for :meth:`move_to`."""
        axes = await self._to_controller(axes, unit, 0)
        command = build_axes("go", axes, context=self.context)
        self._check_axes(command, axes)
        await self._execute(command, check=True)

    async def speed(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Run axes at constant speed (rev/s, or mm/s in dim 9; or in ``unit``, e.g.
        ``"mm/s"``, default the connection's ``units`` per second); 0 stops. No completion
        report: use :meth:`wait_idle`."""
        axes = await self._to_controller(axes, unit, 1)
        command = build_axes("speed", axes, context=self.context)
        self._check_axes(command, axes)
        await self._execute(command, check=True)

    async def wait_idle(self, *, poll_interval: float = 0.05,
                        timeout: float | None = None) -> dict[str, str]:
        """Poll ``statusaxis`` until no axis is moving; return the letters."""
        async with asyncio.timeout(check_timeout(timeout)):
            while True:
                letters = await self.status()
                if "M" not in letters.values():
                    return letters
                await asyncio.sleep(poll_interval)

    async def abort(self, *, soft: bool = False, wait: bool = True) -> None:
        """Stop all axes.

        By default this sends Ctrl+C (0x03): it stops every axis and makes the controller
        discard its input buffer, so requests still queued fail with
        :class:`~tango_aio.errors.RequestAbortedError` and the reply stream is
        resynchronised. ``soft=True`` sends ``a`` instead, which stops the axes but leaves
        queued lines alone. Moves being awaited raise :class:`MoveError` (status ``E``).
        With ``wait``, returns once the axes have stopped.
        """
        self._hub.publish(MoveAborted(ctrl_c=not soft))
        moving = self._protocol.moves_awaiting
        await self._protocol.stop_axes(soft, timeout=self.reply_timeout)
        if wait:
            letters = await self.wait_idle(timeout=60.0)
            # Moves whose line Ctrl+C discarded never report: stop waiting for them.
            error = MoveError("move aborted", {a: "E" if s == "@" else s
                                               for a, s in letters.items()})
            self._protocol.fail_completions(error, only=moving)

    async def _motion(self, command: Command, timeout: float | None, stop_on_cancel: bool,
                      targets: Mapping[str, float], relative: bool = False) -> dict[str, str]:
        self._check_axes(command, targets)
        limit = check_timeout(timeout) or await self._motion_timeout(
            command, targets, relative)
        async with self._motion_lock:
            await self._join_detached()
            sent = self._send(command, check=True)
            try:
                return await self._run_motion(sent, limit)
            except asyncio.CancelledError:
                if stop_on_cancel:
                    await self._stop_after_cancel(sent)
                else:
                    self._detached = asyncio.ensure_future(self._finish_detached(sent, limit))
                raise

    async def _run_motion(self, sent: MoveHandle, limit: float) -> dict[str, str]:
        try:
            await self._confirm(sent)
        except (RequestAbortedError, ControllerTimeoutError):
            # The check was lost (Ctrl+C or a resync): the move may or may not run.
            await self._settle(sent)
            letters = sent.reported_letters
            if letters:  # it ran, and reported before the axes stood still
                return _check_letters(sent.command, letters)
            raise
        return await self._await_completion(sent, limit)

    async def _settle(self, submission: MoveHandle) -> None:
        """Stop the axes, wait until they stand still and forget ``submission``'s report."""
        with contextlib.suppress(TangoError, TimeoutError):
            await self._protocol.stop_axes(True)
            await self.wait_idle(timeout=60.0)
        submission.forget()

    async def _await_completion(self, submission: MoveHandle, limit: float) -> dict[str, str]:
        try:
            async with asyncio.timeout(limit) as scope:
                letters = await self._completion_letters(submission)
        except TimeoutError:
            if not scope.expired():
                raise
            letters = await self._completion_timeout(submission, limit)
        return _check_letters(submission.command, letters)

    async def _completion_letters(self, submission: MoveHandle) -> dict[str, str]:
        """The status letters of a finished move: from its report, or by polling
        ``statusaxis`` (autostatus 0, and the bare CR of autostatus 3)."""
        if submission.expects_report:
            report = await submission.report()
            if report.letters is not None:
                return dict(report.letters)
        return await self._poll_idle()

    async def _poll_idle(self, poll_interval: float = 0.05) -> dict[str, str]:
        """Like :meth:`wait_idle`, but a poll lost to a resync (Ctrl+C) is repeated.

        Polls only the link the caller's move was sent on: should that link be lost
        between two polls and a reconnect be quick, the new link's idle axes must not
        pass for the end of the move (it fails with ConnectionLostError instead).
        """
        link = self._protocol
        while True:
            link.check()
            try:
                letters = await self.status()
            except RequestAbortedError:
                continue
            if "M" not in letters.values():
                return letters
            await asyncio.sleep(poll_interval)

    async def _completion_timeout(self, submission: MoveHandle, limit: float
                                  ) -> dict[str, str]:
        # The report may never come (autostatus changed to 0 mid-move, or a firmware whose
        # mode 4 echo replaces the report). If the axes are idle, take their status.
        letters = await self.status()
        submission.forget()
        if "M" not in letters.values():
            log.warning("no completion report for %r; axes idle, using statusaxis",
                        submission.command.line)
            return letters
        await self._protocol.stop_axes(True)
        raise ControllerTimeoutError(
            f"{submission.command.line!r} did not complete within {limit:.1f} s; axes stopped"
        )

    async def _stop_after_cancel(self, sent: MoveHandle) -> None:
        """The awaiting task was cancelled: stop the axes and wait for them to stop."""
        with contextlib.suppress(TangoError):
            await self._protocol.stop_axes(True)
        try:
            # Shielded (with a time limit) so that the stop is awaited even when the
            # cancellation comes from a level-triggered anyio scope that would otherwise
            # cancel every await of this clean-up at once.
            with contextlib.suppress(Exception, asyncio.CancelledError), \
                    anyio.move_on_after(STOP_WAIT, shield=True):
                if not await self._refused(sent):
                    await self._stopped(sent)
        finally:
            sent.forget()

    async def _refused(self, sent: MoveHandle) -> bool:
        """Wait for the check of a sent motion line; True if the controller refused it."""
        error = await sent.error(self.reply_timeout)
        return error is not None

    async def _stopped(self, submission: MoveHandle) -> None:
        if not submission.expects_report:
            await self._poll_idle()
        else:
            await submission.report()

    async def _finish_detached(self, sent: MoveHandle, limit: float) -> None:
        """Let a move whose caller was cancelled (``stop_on_cancel=False``) run to its end,
        consuming its report, so that the next move starts after it."""
        try:
            with contextlib.suppress(Exception):
                if not await self._refused(sent):
                    await self._await_completion(sent, limit)
        finally:
            sent.forget()

    async def _join_detached(self) -> None:
        detached, self._detached = self._detached, None
        if detached is not None:
            await asyncio.shield(detached)

    async def _motion_timeout(self, command: Command, targets: Mapping[str, float],
                              relative: bool) -> float:
        """A generous upper bound of the move duration: trapezoid time at the slowest
        plausible speed (vel capped by secvel), doubled, plus two seconds."""
        if command.instruction.completion in (Completion.CAL, Completion.RM):
            return 150.0  # caltimeout is at most 120 s per axis (manual L5251)
        if command.name == "moc" or not targets:
            return 120.0
        start = {} if relative else await self.position()
        worst = 0.0
        for axis, target in targets.items():
            distance = abs(target - start.get(axis, 0.0)) if not relative else abs(target)
            worst = max(worst, self._travel_time(AXES.index(axis), distance))
        return 2.0 * worst + 2.0

    def _travel_time(self, index: int, distance: float) -> float:
        s = self._settings
        scale = UnitScale(dim=s.dims[index], pitch=s.pitch[index])
        revs = abs(scale.pos_from_user(distance))
        speed = min(scale.vel_from_user(s.vel[index]), scale.mm_to_rev(s.secvel[index]))
        accel = scale.accel_to_rev(s.accel[index])
        if speed <= 0 or accel <= 0:
            return 60.0
        ramp = speed / accel
        if revs < speed * ramp:
            return 2.0 * math.sqrt(revs / accel)
        return revs / speed + ramp

    # -- trigger and snapshot lists ---------------------------------------------------------

    def _transfer(self) -> ListTransfer:
        return ListTransfer(self._protocol, self.reply_timeout)

    async def upload_trigger_positions(self, positions: Sequence[float], axis: str = "x",
                                       progress: Progress | None = None) -> None:
        """Replace the trigger position list of ``axis`` with ``positions`` at wire speed.

        The list is validated first (at most 10000 finite, strictly monotonic values),
        cleared with ``!trigp axis 0``, then every entry is appended through the write-credit
        limiter and the count is checked along the way. ``progress(done, total)`` is called
        at each checkpoint. A rejected entry raises :class:`~tango_aio.bulk.UploadError`
        with its index and error code. Cancelling stops sending and leaves the driver in
        sync (the list then holds what was sent so far).
        """
        values = validate_trigger_positions(positions)
        await self.command(f"!trigp {check_axis(axis)} 0")
        await self._transfer().upload(trigger_spec(), [[v] for v in values], progress)

    async def read_trigger_positions(self) -> list[float]:
        """Read the whole trigger position list with pipelined ``?trigp n`` reads."""
        rows = await self._transfer().download(trigger_spec())
        return [row[0] for row in rows]

    async def set_trigger_range(self, start: float, end: float, count: int,
                                axis: str | None = None) -> None:
        """Set equidistant trigger positions (``!trigr [axis] start end count``); ``count``
        includes both ends."""
        command = build("trigr", start, end, count, axis=axis, context=self.context)
        await self._execute(command, check=True)

    async def upload_snapshot_positions(self, rows: Sequence[Sequence[float]],
                                        progress: Progress | None = None) -> None:
        """Replace the snapshot array with ``rows`` (at most 1024 rows of per-axis
        positions, X first), like :meth:`upload_trigger_positions`."""
        axes = self._identity.axes if self._identity else len(AXES)
        values = validate_rows(rows, axes)
        await self.command("!snsa 0")
        await self._transfer().upload(snapshot_spec(), values, progress)

    async def read_snapshot_positions(self) -> list[list[float]]:
        """Read every snapshot entry (``?snsc`` of them) with pipelined ``?snsa n`` reads;
        each row holds the positions of the present axes."""
        return await self._transfer().download(snapshot_spec())

    # -- physical units and typed settings ------------------------------------------------

    async def unit_scales(self) -> dict[str, UnitScale]:
        """The unit conversion of every present axis: its ``dim``, ``pitch``, ``gear`` and
        the global ``usteps``, read now (four pipelined reads)."""
        dims, pitch, gear, usteps = await asyncio.gather(
            self.get("dim"), self.get("pitch"), self.get("gear"), self.get("usteps"))
        return {axis: UnitScale(int(dims[axis]), float(pitch[axis]), float(gear[axis]),
                                int(usteps)) for axis in dims}

    def _unit(self, unit: str | None, power: int) -> str | None:
        """The caller's unit, else the connection's ``units`` per second ``power``."""
        if unit is not None or self.units is None:
            return unit
        return self.units + ("", "/s", "/s2")[power]

    async def _to_controller(self, values: Mapping[str, Any], unit: str | None,
                             power: int) -> dict[str, Any]:
        """Per-axis ``values`` in the controller's unit (``power`` 0 position, 1 velocity,
        2 acceleration; see :func:`tango_aio.units.to_controller`). Without a unit and
        without pint Quantities nothing is read and they are returned as they are, but
        for Decimal and Fraction as floats (the move-time estimate computes with them)."""
        chosen = self._unit(unit, power)
        if chosen is None and not any(hasattr(v, "magnitude") for v in values.values()):
            return {axis: float(value) if isinstance(value, Decimal | Fraction) else value
                    for axis, value in values.items()}
        try:  # checked before anything is read or written
            given = {axis: plain(value, chosen, power) for axis, value in values.items()}
        except (TypeError, ValueError) as exc:
            raise InvalidCommandError(f"{exc}", instruction=None, code=5) from exc
        scales = await self.unit_scales()
        return {axis: to_controller(number, of, power, scales[axis]) if axis in scales
                else number for axis, (number, of) in given.items()}

    def _reading_unit(self, unit: str | None, power: int) -> str | None:
        """The unit a reading is converted to (see :meth:`_unit`), checked before
        anything is read."""
        chosen = self._unit(unit, power)
        if chosen is not None:
            try:
                plain(0.0, chosen, power)
            except ValueError as exc:
                raise InvalidCommandError(f"{exc}", instruction=None, code=5) from exc
        return chosen

    async def _from_controller(self, values: Mapping[str, Any], chosen: str | None,
                               power: int) -> dict[str, Any]:
        """Per-axis readings (numbers, or sequences of numbers) converted from the
        controller's unit to ``chosen`` (from :meth:`_reading_unit`)."""
        scales = await self.unit_scales() if chosen is not None else {}

        def convert(axis: str, value: float) -> float:
            if chosen is None:
                return float(value)
            return from_controller(float(value), chosen, power, scales[axis])

        return {axis: tuple(convert(axis, v) for v in value)
                if isinstance(value, list | tuple) else convert(axis, value)
                for axis, value in values.items()}

    async def velocity(self, *, unit: str | None = None) -> dict[str, float]:
        """The ``vel`` of every present axis: rev/s (mm/s in dim 9), or in ``unit``
        (``"mm/s"``; default: the connection's ``units`` per second)."""
        chosen = self._reading_unit(unit, 1)
        return await self._from_controller(await self.get("vel"), chosen, 1)

    async def set_velocity(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Set ``vel`` per axis (``set_velocity(x=5, unit="mm/s")``), see :meth:`velocity`."""
        await self.set("vel", **await self._to_controller(axes, unit, 1))

    async def acceleration(self, *, unit: str | None = None) -> dict[str, float]:
        """The ``accel`` of every present axis: m/s², or in ``unit`` (``"mm/s2"``;
        default: the connection's ``units`` per second squared)."""
        chosen = self._reading_unit(unit, 2)
        return await self._from_controller(await self.get("accel"), chosen, 2)

    async def set_acceleration(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Set ``accel`` per axis, see :meth:`acceleration`."""
        await self.set("accel", **await self._to_controller(axes, unit, 2))

    async def limits(self, *, unit: str | None = None) -> dict[str, tuple[float, float]]:
        """The software limits (``lim``) of every present axis as ``(lower, upper)``, in
        ``unit`` (default: the connection's ``units``, else the dim unit)."""
        chosen = self._reading_unit(unit, 0)
        pairs = await self.get("lim")
        return await self._from_controller(pairs, chosen, 0)

    async def set_limits(self, /, *, unit: str | None = None,
                         **axes: tuple[float, float]) -> None:
        """Set the software limits per axis (``set_limits(x=(0, 100), unit="mm")``)."""
        lower = await self._to_controller({a: p[0] for a, p in axes.items()}, unit, 0)
        upper = await self._to_controller({a: p[1] for a, p in axes.items()}, unit, 0)
        await self.set("lim", axis=None, check=True,
                       **{axis: [lower[axis], upper[axis]] for axis in axes})

    async def trigger_count(self) -> int:
        """The number of trigger events generated so far (``?trigcount``)."""
        return int(await self.get("trigcount"))

    async def set_trigger_count(self, count: int = 0) -> None:
        """Set (usually reset) the trigger event counter (``!trigcount``)."""
        await self.set("trigcount", count)

    async def trigger_enabled(self) -> bool:
        """Whether the trigger output is switched on (``?trig``)."""
        return bool(await self.get("trig"))

    async def set_trigger_enabled(self, enabled: bool) -> None:
        """Switch the trigger output on or off (``!trig 1`` / ``!trig 0``); the trigger
        setup must be complete before switching it on."""
        if not isinstance(enabled, bool):
            raise TypeError(f"enabled must be True or False, got {enabled!r}")
        await self.set("trig", int(enabled))

    async def axis_status(self) -> dict[str, AxisStatus]:
        """Like :meth:`status`, as :class:`~tango_aio.status.AxisStatus` members."""
        return axis_statuses(await self.status())

    # -- events ---------------------------------------------------------------------------

    def events(self, maxsize: int = 256) -> Subscription:
        """Subscribe to the controller's events (an async iterator). When the buffer is
        full the oldest events are dropped (counted in ``Subscription.dropped``)."""
        return self._hub.subscribe(check_count(maxsize, "maxsize"))

    async def watch_position(self, interval: float = 0.1, *, follow: bool = False,
                             unit: str | None = None) -> AsyncIterator[PositionUpdate]:
        """Yield positions (in ``unit``, as :meth:`position`) every ``interval`` seconds
        while any axis moves or a move of this driver is in flight, then once more when
        all is idle. Each update is also published to :meth:`events`.

        ``follow=True`` follows a whole scan: it goes on through the idle moments between
        moves, until the caller stops iterating (``break``) or cancels; while all is idle
        it yields only when a position changed, so a paused scan does not flood the
        caller."""
        check_timeout(interval, "interval")
        last: Mapping[str, float] | None = None
        while True:
            letters = await self.status()
            update = PositionUpdate(await self.position(unit=unit))
            idle = "M" not in letters.values() and not self._motion_lock.locked()
            if not (follow and idle and update.positions == last):
                self._hub.publish(update)
                yield update
            last = update.positions
            if idle and not follow:
                return
            await asyncio.sleep(interval)

    def _on_protocol_event(self, event: Event, submission: Submission | None) -> None:
        if isinstance(event, Completed):
            self._publish_completion(event, submission)
        elif isinstance(event, Unsolicited):
            self._hub.publish(UnsolicitedLine(event.line))
        elif isinstance(event, Dropped):
            log.debug("dropped %r", event.line)

    def _publish_completion(self, event: Completed, submission: Submission | None) -> None:
        letters = event.letters or {}
        if submission is None:
            self._hub.publish(StatusReport(letters, event.line))
            return
        completion = submission.command.instruction.completion
        kind = _KINDS.get(completion, "move") if completion else "move"
        ok = not (set(letters.values()) & FAILED_LETTERS)
        self._hub.publish(MoveFinished(kind, letters, ok))



def _moved_axes(command: Command) -> set[str] | None:
    """The axes a motion command moves (``None``: every enabled axis, e.g. ``cal``)."""
    if command.axis is not None:
        return {command.axis}
    if command.values:
        return set(AXES[: len(command.values)])
    return None


def _check_letters(command: Command, letters: Mapping[str, str]) -> dict[str, str]:
    """Raise :class:`MoveError` if an axis the command moved reports E, S or T.

    Only the moved axes count: letters polled from ``statusaxis`` (autostatus 0 and 3)
    keep the sticky ``E`` of an axis aborted earlier, which says nothing about this move.
    """
    moved = _moved_axes(command)
    failed = {axis for axis, letter in letters.items()
              if letter in FAILED_LETTERS and (moved is None or axis in moved)}
    if failed:
        raise MoveError(f"{command.line!r} ended with status {dict(letters)}", letters)
    return dict(letters)


__all__ += ["FAILED_LETTERS", "ProtocolError"]
