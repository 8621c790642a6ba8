"""The :class:`Controller` API: identity, typed settings, awaitable motion, events."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
from collections.abc import (
    AsyncIterator,
    Awaitable,
    Callable,
    Coroutine,
    Iterable,
    Iterator,
    Mapping,
    Sequence,
)
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Final, NoReturn, Protocol

from .._checks import check_count, check_timeout
from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
    Completion,
    Context,
    DetInfo,
    Form,
    Value,
    VersionInfo,
    build,
    build_axes,
    check_axis_word,
    parse,
    parse_reply,
)
from ..errors import (
    ERROR_DESCRIPTIONS,
    INTERNAL_ERRORS,
    ConnectError,
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    GarbledVerdictError,
    InternalControllerError,
    InvalidCommandError,
    InvalidInstructionError,
    MoveOutcomeUnknown,
    ProtocolError,
    RequestAbortedError,
    SettingNotAppliedError,
    TangoError,
    outcome_unknown,
    parse_error_reply,
)
from ..events import (
    ConnectionLost,
    ControllerFault,
    EventHub,
    MoveAborted,
    MoveFinished,
    PositionUpdate,
    Reconnected,
    StatusReport,
    Subscription,
    TangoEvent,
    UnsolicitedLine,
)
from ..families import (
    IO,
    RESTART_QUIET,
    ClosedLoop,
    ControllerInfo,
    Encoders,
    Info,
    Joystick,
    ListTransfer,
    Settings,
    Snapshots,
    Triggers,
    check_resolution,
    convert_from,
    convert_to,
    reading_unit,
)
from ..link import (
    Closer,
    MoveHandle,
    Reconnect,
    Reconnector,
    Response,
    Signature,
    Submission,
    TangoProtocol,
)
from ..moves import (
    Budget,
    MoveTracker,
    Prove,
    Start,
    StartProof,
    acceptance_shown,
    contest,
    move_budget,
    moved_axes,
    position_tolerance,
    rest_budget,
    stop_time,
)
from ..sansio import (
    CACHED_SETTINGS,
    LOCAL_ECHO,
    Completed,
    DriverState,
    Dropped,
    Event,
    Unsolicited,
)
from ..status import CALIBRATED_FLAG, FAILED_LETTERS, MOVING, AxisStatus, axis_statuses
from ..units import Measure
from ._motion import (
    STOP_WAIT,
    Motion,
    MovePlan,
    annotate,
    contested,
    report_came,
)
from ._restart import (
    RestartWatch,
    report_suggests_restart,
    settings_of,
    unreported_end_suggests_restart,
)

__all__ = ["Controller", "Identity"]

log = logging.getLogger("tango_aio")

#: Reads whose all-axes form is unreliable: read axis by axis. ``?lim`` sends an extra CR
#: after the X pair in extmode 0 (L4559-4621), ``?swtyp`` prints its groups without
#: separating blanks there (L4814-4824).
AXIS_BY_AXIS = frozenset({"lim", "swtyp"})

#: Motion lines that leave the software limits as they are. The limits change only by
#: ``!lim``, by ``cal``/``rm``/``vrm`` (unless nosetlimit, L4575-4580), by reloading the
#: saved parameters (``restore``/``reset``, power-on, L1296) and print in the ``dim``
#: unit (L4555): every other ``!`` line empties the cache of :meth:`Controller.axis_limits`.
_LIMIT_NEUTRAL = frozenset({"moa", "mor"})
#: Seconds :meth:`Controller.aclose` waits at most for the replies to the driver's own
#: lines still in flight (a separator behind a move's confirmation: a few milliseconds
#: at 57600 Bd), so that the next program on the port does not read them.
CLOSE_SETTLE = 0.25
#: Autostatus modes in which a read's own text coming back need not show local echo:
#: mode 4 may echo reads (old L723), mode 2 may acknowledge them before their data
#: (L2099-2103). Setup checks the link in mode 1 first (:meth:`Controller.setup`).
_ECHO_BLIND = frozenset({2, 4})


@dataclass(frozen=True, slots=True)
class Identity:
    """What ``?version`` and ``?det`` say about the controller, and which behaviours the
    driver detected at connect.

    ``family`` is ``"1.71"`` for firmware that answers like the 1.71 manual, ``"older"``
    for the older edition (its ``?version`` format or ``help`` without a number, old
    L805-819). ``detected`` maps each behaviour found at connect to what was found, e.g.
    ``{"help_number": "no", "per_axis_replies": "exact"}`` (docs/getting-started.md).
    """

    model: str
    firmware: str
    axes: int
    version: VersionInfo
    det: DetInfo
    family: str = "1.71"
    detected: Mapping[str, str] = field(default_factory=dict)


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
        devices = _Devices(self)
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

    @property
    def context(self) -> Context:
        """Controller state used to validate lines (dims, axis count, extmode)."""
        return self._protocol.context

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

    async def setup(self, *, autostatus: int | None = 1, identify: bool = True) -> None:
        """Bring the controller into a known state (called by :func:`connect`).

        Drains stale input by resynchronising, identifies the controller, reads the
        settings the driver needs and selects ``autostatus`` (``None``: keep the mode the
        controller is in). The mode in force is read first (the way a mode change is
        confirmed, whatever the mode echoes or acknowledges): a previous session may have
        left any mode behind, and how ``!autostatus`` itself is answered depends on it.
        A link that echoes every byte sent (local echo of an adapter) is refused with a
        :class:`~tango_aio.errors.ConnectError` naming it, whatever mode the controller
        was left in: before mode 2 or 4 is kept or selected, one read runs in a mode that
        answers a read with its data alone (:meth:`_check_local_echo`). A reply out of step
        (a controller still answering an earlier program's lines) starts it over once.

        Parameters
        ----------
        autostatus
            The autostatus mode to select; ``None`` keeps the mode in force.
        identify
            Read the identity (:meth:`identify`); ``False`` skips it.

        Raises
        ------
        ConnectError
            A step failed on a link that echoes every byte back (local echo).
        ProtocolError
            A reply was out of step twice.
        TangoError
            A step failed (no answer, a garbled reply, an error the controller reported).
        """
        self._forget_power_state()
        try:
            try:
                await self._come_into_step(autostatus, identify)
            except ProtocolError:
                if self._protocol.core.local_echo:
                    raise
                # A controller still answering an earlier program's lines, one of which
                # came late (a quiet gap longer than the resync's): in step again, once.
                log.debug("connect: a reply out of step; resynchronising once more")
                await self._come_into_step(autostatus, identify)
        except TangoError as exc:
            if self._protocol.core.local_echo:
                raise ConnectError(LOCAL_ECHO) from exc
            raise
        if self._reconnector is not None:
            self._reconnector.arm()

    async def _come_into_step(self, autostatus: int | None, identify: bool) -> None:
        """Resync, read the mode in force, select ``autostatus``, identify, read settings."""
        await self._protocol.resync(timeout=self.reply_timeout)
        current = await self._protocol.read_autostatus(timeout=self.reply_timeout,
                                                       status=True)
        # A unit whose ?statusaxis ends like a completion report (@@@-.) is read
        # axis by axis ('sa x' answers its letter alone, L2725).
        self._letters_by_axis = \
            self._protocol.detected.get("status_tail") == "dot"
        wanted = current if autostatus is None else autostatus
        if wanted in _ECHO_BLIND:
            current = await self._check_local_echo(current)
        if wanted != current:
            await self.command(f"!autostatus {wanted}")
        if identify:
            self._identity = await self.identify()
        await self.refresh_settings()

    async def _check_local_echo(self, current: int) -> int:
        """Before autostatus 2 or 4 is kept or selected (:data:`_ECHO_BLIND`): one read in
        a mode that answers a read with its data alone, so that a link echoing every byte
        sent (local echo of an adapter) shows as the read answered by itself
        (:data:`~tango_aio.sansio._core.LOCAL_ECHO`; setup refuses it).

        Modes 2 and 4 cannot tell. Mode 4 echoes set and move lines (L2117, L2165-2168)
        and, by the older edition, all input (old L723), so an adapter's copy of a read
        looks like the controller's echo, while the controller's own echo of a read may be
        missing or come after its reply (switches ``echo_all``, ``echo``, ``echo_text``).
        Mode 2 may acknowledge reads before their data (switch ``ack_reads``; L2099-2103
        names ``!`` lines only), and a line where an acknowledgement is owed is passed over.
        Modes 0, 1 and 3 neither echo nor acknowledge a read (L2060-2113), so a unit in
        mode 2 or 4 is taken to mode 1 (the power-on mode, L2062) for the read; the caller
        selects its mode again.

        Parameters
        ----------
        current
            The mode in force.

        Returns
        -------
        int
            The mode in force afterwards (1 if ``current`` was 2 or 4).
        """
        if current in _ECHO_BLIND:
            await self.command("!autostatus 1")
            current = 1
        await self.query("?err")
        return current

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

    # -- identity and raw access -------------------------------------------------------------

    async def identify(self) -> Identity:
        """Read ``?version`` and ``?det`` (model, firmware, number of axes) and record
        which firmware family and behaviours were detected (:class:`Identity`).

        Returns
        -------
        Identity
            The controller's model, firmware and axes, and what the driver detected.
        """
        command = build("version", form=Form.READ)
        raw = await self._request(command)
        version = parse_reply(command, raw.lines)
        det = await self.get("det")
        assert isinstance(version, VersionInfo) and isinstance(det, DetInfo)
        axes = det.axes or 4
        context = self._protocol.context
        self._protocol.context = Context(context.dims, axes, context.extmode)
        detected = dict(getattr(self._protocol, "detected", None) or {})
        # Whether per-axis reads answer one value per axis found by ?det (the 1.71
        # manual, L2711-2721) or leave absent/disabled axes out: then every per-axis read
        # whose count differs is read again axis by axis (see get()).
        positions = await self._request(_read_command("pos", None, self.context))
        count = len(" ".join(positions.lines).split())
        # The 1.71 manual prints a blank before the comma of the build time (L1067,
        # L1105), the older edition none (old L426).
        detected["version_format"] = "new" if " , " in " ".join(raw.lines) else "old"
        detected["per_axis_replies"] = "exact" if count == axes else f"{count} of {axes}"
        # help_number "none": help takes no number, as in the older edition (old L805-819).
        older = detected.get("help_number") == "none" \
            or detected["version_format"] == "old"
        return Identity(version.model, version.firmware, axes, version, det,
                        family="older" if older else "1.71", detected=detected)

    async def refresh_settings(self) -> None:
        """Re-read what move timeouts depend on: dim, pitch, vel, accel, secvel, extmode,
        delay and pause (L6845-6899) and the closed-loop timeout ctrt (L11616-11631).

        Which settings these are is the catalog's
        (:attr:`~tango_aio.catalog._schema.Instruction.cached`). ``extmode``, ``delay``, ``pause``
        and ``ctrt`` count as 0 on a controller that does not know them (older firmware
        answers error 4)."""
        settings = self._settings
        older = self._identity is not None and self._identity.family == "older"
        for entry in CACHED_SETTINGS:  # the catalog's cached settings, in manual order
            if entry.per_axis:
                settings.load(entry, await self.get(entry.name))
                continue
            # A global setting the firmware does not know counts as 0: a read it does not
            # know is answered by error 4 (the older edition lacks e.g. extmode, which then
            # is 0, its behaviour; delay, pause and ctrt: nothing to wait for).
            try:
                known = not older or entry.in_older_manual
                value = await self._read_or_absent(entry.name) if known else 0
                settings.load(entry, value)
            except (ControllerError, ProtocolError, ValueError, TypeError):
                settings.load(entry, 0)
        self._update_context()

    async def _read_or_absent(self, name: str) -> Any:
        """Read the global setting ``name``, which a unit may lack (an optional module,
        a smaller model: no reply at all, error 4, L970): a separator goes right behind
        the read in the same write, so a missing reply shows at once, as the separator's
        reply in its place (:class:`ProtocolError`), and not after the reply timeout.

        Returns
        -------
        Any
            The parsed reply.
        """
        command = _read_command(name, None, self.context)
        (submission,) = self._protocol.submit_together((command,), separate_after=True)
        response = await self._protocol.wait_reply(submission, self.reply_timeout)
        return parse_reply(command, response.lines)

    async def _reload_settings(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """Read the cached settings again (after a restart); their values before and
        after (:func:`~tango_aio.controller._restart.settings_of`).

        Returns
        -------
        tuple[dict[str, Any], dict[str, Any]]
            The cached settings before and after.
        """
        before = settings_of(self._settings)
        self._forget_power_state()
        await self.refresh_settings()
        return before, settings_of(self._settings)

    def _update_context(self) -> None:
        settings = self._settings
        settings.axes = self._protocol.context.axes  # identify() sets it from ?det
        self._protocol.context = settings.context

    async def query(self, line: str, timeout: float | None = None) -> str:
        """Send a read such as ``"?pos x"`` and return its reply text (lines joined by
        ``"\\n"``). Raises :class:`InvalidCommandError` for a line that does not read.

        Parameters
        ----------
        line
            The read line (``?`` form, or an alias that reads).
        timeout
            Seconds to wait for the reply; ``None``: the connection's ``reply_timeout``.

        Returns
        -------
        str
            The reply's lines, joined by ``"\\n"``.

        Raises
        ------
        InvalidCommandError
            The line is not valid, or does not read.
        """
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

        Parameters
        ----------
        line
            The set or execute line (``!`` form).
        check
            Read the controller's error state after the line.
        timeout
            Seconds to wait for the answer; ``None``: the connection's ``reply_timeout``.

        Raises
        ------
        InvalidCommandError
            The line is not valid, or is a read.
        ControllerError
            With ``check``: the controller reported an error for the line (for a line
            that starts motion: and ``?statusaxis`` read behind it shows none of its
            axes moving).
        GarbledVerdictError
            With ``check``: the error state read was no clean error number or
            acknowledgement; the line may or may not have been executed.
        MoveOutcomeUnknown
            With ``check``, for a line that starts motion (a move, ``cal``, ``rm``,
            ``speed``, ``go``): its verdict was lost, garbled, or a refusal its moving
            axes contradict, or (``speed``, ``go`` in autostatus 0, 1, 3) nothing in the
            state read behind it shows that it arrived; the message says which axes were
            stopped or may still move.
        """
        command = parse(line, self.context)
        if command.is_read:
            raise InvalidCommandError(f"{command.line!r} is a read; use query()",
                                      instruction=command.name)
        if command.name in _LIST_POSITIONS:
            # A non-zero list position below the resolution is stored as 0.0 (L4080-4100),
            # as triggers.upload_positions() refuses it.
            tiny = [v for v in command.values if isinstance(v, float) and 0 < abs(v) < 0.5]
            if tiny:
                check_resolution([tiny], [min(await self._resolution())], command.name)
        await self._execute(command, check=check, timeout=timeout)

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

    def _check_axes(self, command: Command, names: Iterable[str] = ()) -> None:
        """Refuse an axis the controller does not have, before anything is written."""
        present = AXES[: self.context.axes]
        for letter in (*names, *(command.axis or "")):
            if letter not in present:
                raise InvalidCommandError(
                    f"{command.line!r}: the controller has no {letter.upper()} axis "
                    f"(its axes: {' '.join(present).upper()})",
                    instruction=command.name, parameter="axis", number=1)

    async def _request(self, command: Command, timeout: float | None = None) -> Response:
        self._check_axes(command)
        return await self._protocol.query(command, timeout=self._timeout(timeout))

    def _timeout(self, timeout: float | None) -> float:
        return self.reply_timeout if timeout is None else check_timeout(timeout) or 0.0

    async def _execute(self, command: Command, *, check: bool,
                       timeout: float | None = None) -> Response:
        """Write ``command`` (checked, see :meth:`TangoProtocol.execute`) and wait."""
        self._check_axes(command)
        if not command.is_read:
            self._forget_start(command)
        raw_move = command.instruction.completion is not None and command.executes
        starts = check and command.executes and (raw_move or command.name in _STARTS_MOTION)
        # A speed or go line owes no answer in autostatus 0, 1, 3: its ?err 0 is also
        # what a lost line gets, so the state read behind it proves it (_prove_started).
        unanswered = starts and not raw_move and not self._protocol.answers(command)
        busy = await self._moving_before(command) if unanswered else frozenset()
        try:
            if raw_move and check:
                # (execute() is start_move() and confirm(); the handle is kept here for
                # its completion report, which may prove a deferred acceptance.)
                handle = self._protocol.start_move(command, check=True)
                await handle.confirm(self._timeout(timeout))
                response = handle.submission.response
                if response.deferred:
                    await self._prove_accepted(handle, self._timeout(timeout))
            else:
                response = await self._protocol.execute(
                    command, timeout=self._timeout(timeout), check=check)
        except ControllerError as error:
            if error.number < INTERNAL_ERRORS or \
                    await self._blame(error.number, self._timeout(timeout)):
                if starts:
                    await self._contest(error, command)
                raise
            if check and not raw_move:
                # The ?err showed a standing internal error, which a lost line gets too:
                # the read-back decides (the one pipelined behind it was not awaited).
                try:
                    await self._protocol.prove_set(command, self._timeout(timeout))
                except SettingNotAppliedError as failed:
                    raise failed from error
            response = Response()
        except GarbledVerdictError as error:
            if starts:
                await self._contest(error, command)
            raise
        except (ControllerTimeoutError, RequestAbortedError, ProtocolError,
                ConnectionLostError) as error:
            if not raw_move:
                raise
            if starts and not isinstance(error, ConnectionLostError):
                await self._contest(error, command)  # it may have run: is it running?
            raise outcome_unknown(error, command.line) from error.__cause__
        if unanswered:
            await self._prove_started(command, busy, self._timeout(timeout))
        self._track(command)
        if starts:
            self._turned(command)
        if self._moves.accepted(command):
            self._moves.inputs_read(await self._inputs_are_idle())
        return response

    def _turned(self, command: Command) -> None:
        """An accepted line that starts motion nobody follows: its axes may move on."""
        moved = moved_axes(command, AXES[: self.context.axes])
        if command.name == "speed":
            for axis, value in zip(moved, command.values, strict=False):
                (self._turning.add if value else self._turning.discard)(axis)
        else:
            self._turning.update(moved)

    async def _contest(self, cause: TangoError, command: Command) -> NoReturn:
        """A refusal stands if none of the line's axes moves; else stop them and say so."""
        # (The verdict on a line that starts motion refused it or made no sense:
        # timing.contest judges ?statusaxis, read behind it. The driver's own motion in
        # flight, a followed move or what _turning holds, does not contradict a refusal.)
        moved = moved_axes(command, AXES[: self.context.axes])
        busy = set(AXES) if self._motion.busy else set(self._turning)
        try:
            letters = await self.status()
        except TangoError as exc:
            raise contested(cause, command.line, "the state could not be read behind it",
                            (), moved) from exc
        found = contest(moved, letters, clean=isinstance(cause, ControllerError), busy=busy)
        if found.stands:
            raise annotate(cause, found.reason) if found.reason else cause
        try:
            if found.moving:
                await self.stop(*found.moving)
        except TangoError:
            raise contested(cause, command.line, found.reason, (), found.moving) from None
        raise contested(cause, command.line, found.reason, found.moving, ())

    async def _moving_before(self, command: Command) -> frozenset[str]:
        # The axes a speed line sets running that moved before it (their M proves
        # nothing behind it), read only when the driver may have left them running. A
        # go that retargets a moving axis is accepted on its M: no read shows its new
        # target before it ends (L6616).
        if command.name != "speed":
            return frozenset()
        axes = [a for a, v in zip(moved_axes(command, AXES[: self.context.axes]),
                                  command.values, strict=False) if v]
        if not set(axes) & self._turning:
            return frozenset()
        letters = await self.status()
        return frozenset(a for a in axes if letters.get(a) == MOVING)

    async def _prove_started(self, command: Command, busy: frozenset[str],
                             timeout: float) -> None:
        """Prove from the state behind it that a speed or go line arrived, or stop it."""
        # The tracker's StartProof says which read comes next and judges it (timing's
        # acceptance, stop_time, speed_shown). Unproven: the line's axes that move are
        # stopped, and the MoveProtocolUnknownError says so and that the line may not
        # have been applied.
        present = AXES[: self.context.axes]
        loop = asyncio.get_running_loop()
        proof = StartProof(command, present, busy=busy, poll=_STOP_POLL,
                           deadline=loop.time() + stop_time(self._settings, present))
        step = proof.begin()
        try:
            while step.found is None:
                if step.wait:
                    await asyncio.sleep(step.wait)
                if step.next is Prove.READ_STATUS:
                    step = proof.status(await self.status(), loop.time())
                elif step.next is Prove.READ_POSITIONS:
                    step = proof.positions(await self._position_texts(), loop.time())
                else:
                    reply = await self._request(
                        _read_command("speed", step.axis, self.context), timeout)
                    step = proof.speed(step.axis, " ".join(reply.lines), loop.time())
        except TangoError as exc:
            raise contested(ProtocolError(f"{command.line!r} was answered without an "
                                          "error, but the state behind it could not be "
                                          "read: it may not have been applied"),
                            command.line, "", (), moved_axes(command, present)) from exc
        if step.next is Prove.PROVEN:
            return
        cause = ProtocolError(f"{command.line!r} was answered without an error, yet "
                              f"nothing shows that it arrived: it may not have been applied")
        running, reason = step.running, step.found.reason
        try:
            if running:
                await self.stop(*running)
        except TangoError:
            raise contested(cause, command.line, reason, (), running) from None
        raise contested(cause, command.line, reason or "nothing of it moves", running, ())

    async def _prove_accepted(self, handle: MoveHandle, timeout: float) -> None:
        """Prove that a move line whose acceptance rests only on the ``?err`` behind it
        (:attr:`~tango_aio.link._protocol.Response.deferred`) arrived, or raise.

        In autostatus 2 the ``OK...`` (L2099-2103: "immediately acknowledged", yet some
        firmware sends a move's only with its report: switch ``move_ok``) and in
        autostatus 4 the echo (L2115-2117, when is not said: switch ``echo``) may come
        with the completion report. Then the ``?err`` reply arrives where they were owed,
        and its 0 is all the driver has: the same as when the move line was lost (it
        reached a controller that was off) and the ``?err`` behind it was answered. So
        ``?statusaxis`` is read, behind the line: the interpreter executes lines in
        order, so the move has started by then if it arrived, and its report (which
        carries the deferred ``OK...`` or echo) came before the reply if it already
        ended (L2087-2089). A moved axis moving, or the report, proves it
        (:func:`~tango_aio.moves.acceptance_shown`).

        Parameters
        ----------
        handle
            The move line, its verdict 0 received.
        timeout
            Seconds the ``?statusaxis`` read may take.

        Raises
        ------
        ProtocolError
            Nothing proves the line arrived (the caller raises it as a
            :class:`~tango_aio.errors.MoveOutcomeUnknown`); the restart watch reads the
            mode in force, since a restart loses lines.
        ControllerTimeoutError, RequestAbortedError, ConnectionLostError
            The ``?statusaxis`` read failed.
        """
        completion = handle.submission.completion
        if completion is None or _reported(completion):
            return  # its report came (a refusal fails confirm() before this)
        # (A report no longer awaited, e.g. dropped when a restart was noticed, is no
        # proof: only a report that came is.)
        letters = await self.get("statusaxis", timeout=timeout)
        assert isinstance(letters, dict)
        moved = moved_axes(handle.command, AXES[: self.context.axes])
        if acceptance_shown(_reported(completion), letters, moved):
            return
        handle.forget()  # it never ran: its report must not be taken for a later move's
        self._restarts.suspect()
        raise ProtocolError(
            f"the acceptance of {handle.command.line!r} could not be proven: its "
            f"{'OK...' if handle.submission.expectation.ack else 'echo'} did not come "
            f"(only the ?err behind it answered 0), no completion report came, and "
            f"?statusaxis shows {' '.join(moved).upper()} standing: the line may have "
            f"been lost")

    def _forget_start(self, command: Command) -> None:
        """A ``!`` line other than a move: any of them may move the stage or change what
        ``?pos`` prints (``go``, ``speed``, ``pos``, ``cal``, a list...), so no remembered
        position is a move_by's start any more until a move confirms it again."""
        self._moves.written(command.name)
        if command.name not in _LIMIT_NEUTRAL:
            self._forget_limits()

    def _forget_power_state(self) -> None:
        """What a power cycle may have changed behind the link: the HDI is on again, the
        saved limits are back, positions may differ; no remembered start or limit
        survives it (setup, and a restart noticed on a live link)."""
        self._moves.power_cycled()
        self._forget_limits()

    def _forget_limits(self) -> None:
        """Something may have changed the software limits: read them again."""
        self._limits.clear()
        self._limits_epoch += 1

    async def axis_limits(self, axis: str, *, cached: bool = True) -> tuple[float, float]:
        """The software limits of ``axis`` as ``(lower, upper)`` in its dim unit.

        With ``cached``, the limits this Controller read before are returned without a
        read, as long as nothing could have changed them since: any ``!`` line other than
        a move (``!lim``, ``cal``, ``rm``, ``vrm``, ``restore``, ``dim``...), the end of a
        calibration or range measurement, a setup or a reconnect reads them again. A
        target beyond limits changed behind the driver's back (the stage's own keys) is
        still no success: the controller refuses it or stops at its limit (L4526-4540),
        and the confirmation behind the report finds the axis short of its target.

        Parameters
        ----------
        axis
            The axis letter.
        cached
            Whether the limits known from an earlier read may be returned (else ``?lim``
            is read, and kept).

        Returns
        -------
        tuple[float, float]
            The lower and upper limit.

        Raises
        ------
        InvalidCommandError
            ``axis`` is not an axis of this controller.
        """
        known = self._limits.get(axis)
        if cached and known is not None:
            return known
        epoch = self._limits_epoch
        low, high = await self.get("lim", axis=axis)
        pair = (float(low), float(high))
        if epoch == self._limits_epoch:  # no line that may change them went out meanwhile
            self._limits[axis] = pair
        return pair

    async def _inputs_are_idle(self) -> bool:
        """Whether neither input moves the stage by itself: a snapshot event moves it in
        snapshot modes other than 0 (L14520-14530; snsm 0 only captures, L900), and the
        pulse/direction input drives an axis in tvr modes other than 0 (L9914-9930).

        Returns
        -------
        bool
            ``True`` if both are off; ``False`` if one is on or cannot be read.
        """
        known = self._identity
        if known is not None and known.family == "older" and not all(
                INSTRUCTIONS[name].in_older_manual for name in ("snsm", "tvr")):
            return False  # the older edition lacks them: a read would wait out its timeout
        try:
            snsm = await self.get("snsm")
            tvr = await self.get("tvr")
        except (ControllerError, ControllerTimeoutError, ProtocolError):  # not known
            return False
        modes = tvr.values() if isinstance(tvr, dict) else [tvr]
        return snsm == 0 and all(mode == 0 for mode in modes)

    def _send(self, command: Command, *, check: bool, batch: object | None = None
              ) -> MoveHandle:
        """Write a motion line and its check (see :meth:`TangoProtocol.start_move`)."""
        self._check_axes(command)
        if command.name not in _LIMIT_NEUTRAL:
            self._forget_limits()  # cal, rm: and again when they end
        return self._protocol.start_move(command, check=check, batch=batch)

    async def _error_of(self, sent: MoveHandle, timeout: float) -> ControllerError | None:
        """The error the controller reported for ``sent`` (``None``: accepted).

        A number of 20 and above may be a persistent internal error rather than the
        line's own (L2853-2867: "if the previously executed instruction returned no error,
        the 'err' response is either 0 or ... the internal error"): see :meth:`_blame`.

        Returns
        -------
        ControllerError | None
            The line's error, ``None`` if it was accepted.
        """
        error = await sent.error(timeout)
        if error is not None and error.number >= INTERNAL_ERRORS \
                and not await self._blame(error.number, timeout):
            return None
        return error

    async def _blame(self, code: int, timeout: float) -> bool:
        """Whether error ``code`` (>= 20) belongs to the line just checked.

        Every instruction overwrites the error state, and after one that was fine ``?err``
        answers 0 or the internal error (L2853-2867). So ``?err`` is asked again after a
        read that cannot fail (``?autostatus``; ``?err`` itself is not used for this, as
        the manual does not say whether reading it overwrites the state): 0 means ``code``
        was the line's own, the same number a persistent internal condition. That one is
        not the line's fault: it is published as a :class:`ControllerFault` event (once
        per change) and the line counts as accepted.

        Returns
        -------
        bool
            ``True`` if the error is the line's own.
        """
        again = await self._internal_error(timeout)
        if again != code:
            self._fault_seen(again)
            return True
        self._fault_seen(code)
        return False

    async def _internal_error(self, timeout: float | None = None) -> int:
        """``?err`` right after a read that is always fine: 0 or the internal error."""
        # Written back to back: no other line can come between the read and the probe.
        self._protocol.submit(parse("?autostatus"))
        reply = await self._protocol.query(parse("?err"), timeout=self._timeout(timeout))
        code, _ = parse_error_reply(reply.lines[0])
        return code or 0

    def _fault_seen(self, code: int) -> None:
        if code < INTERNAL_ERRORS:
            code = 0
        if code != self._fault:
            self._fault = code
            if code:
                log.warning("controller reports internal error %d: %s", code,
                            ERROR_DESCRIPTIONS.get(code, "undocumented"))
                self._hub.publish(ControllerFault(code, ERROR_DESCRIPTIONS.get(
                    code, "undocumented internal error")))

    @property
    def fault(self) -> int:
        """The persistent internal error (>= 20) the controller last reported in ``?err``
        although the instruction before was fine, 0 if none (see :meth:`check_fault`)."""
        return self._fault

    async def check_fault(self) -> None:
        """Raise :class:`~tango_aio.errors.InternalControllerError` if the controller is
        in a persistent internal error state (an error number >= 20 that ``?err`` reports
        after an instruction that itself was fine, L2853-2867); else return.

        Raises
        ------
        InternalControllerError
            The controller reports a persistent internal error.
        """
        code = await self._internal_error()
        self._fault_seen(code)
        if code >= INTERNAL_ERRORS:
            raise InternalControllerError(code)

    def _track(self, command: Command) -> None:
        """Keep the cached settings in step with a set the controller accepted."""
        if self._settings.observe(command):
            self._update_context()

    # -- typed access ---------------------------------------------------------------------

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        """Read instruction ``name`` and return its parsed reply.

        Per-axis values come as ``{"x": 1.0, "y": 2.0}`` (exactly the axes found at
        identification), or a scalar when ``axis`` is given. ``args`` are extra read
        arguments (``get("trigp", 3)``). ``lim`` and ``swtyp`` are read axis by axis, as
        the manual recommends (L4559, L4814); any other per-axis reply with fewer or more
        values than axes is read again axis by axis, so that no value is credited to the
        wrong axis (a unit that leaves disabled axes out).

        Parameters
        ----------
        name
            The instruction (``"vel"``, ``"pos"``, an alias...).
        *args
            Extra read arguments (an index).
        axis
            Read one axis (``"x"``); ``None``: every axis the reply holds.
        timeout
            Seconds to wait for the reply; ``None``: the connection's ``reply_timeout``.

        Returns
        -------
        Any
            The parsed reply: a value by axis, a scalar or the instruction's reply type.
        """
        if axis is not None:
            check_axis_word(axis, name)  # "" or "y 5" would read something else
        command = build(name, *args, form=Form.READ, axis=axis, context=self.context) \
            if args else _read_command(name, axis, self.context)
        if axis is None and not args and (name in AXIS_BY_AXIS or (
                self._letters_by_axis and command.name == "statusaxis")):
            return await self._axis_by_axis(name, timeout)
        response = await self._request(command, timeout)
        value = parse_reply(command, response.lines)
        if axis is None and not args and isinstance(value, dict) and value \
                and set(value) <= set(AXES) and len(value) != self.context.axes:
            return await self._axis_by_axis(name, timeout)
        return value

    async def _axis_by_axis(self, name: str, timeout: float | None) -> dict[str, Any]:
        return {axis: await self.get(name, axis=axis, timeout=timeout)
                for axis in AXES[: self.context.axes]}

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        """Set instruction ``name``: ``set("vel", x=10, y=5)``, ``set("vel", 3, axis="z")``,
        ``set("autostatus", 1)``. Checks the error state like :meth:`command`.

        Parameters
        ----------
        name
            The instruction (``"vel"``, ``"autostatus"``...).
        *args
            The values, for a global setting or for ``axis``.
        axis
            The one axis ``args`` set; ``None``: a global setting or ``axes``.
        check
            Read the controller's error state after the line.
        **axes
            The value of each axis (``x=10``).

        Raises
        ------
        InvalidCommandError
            The line is not valid for the instruction or this controller.
        ControllerError
            With ``check``: the controller refused the value.
        """
        command = build(name, *args, form=Form.SET, axis=axis, context=self.context, **axes)
        self._check_axes(command, axes)
        await self._execute(command, check=check)

    @property
    def last_positions(self) -> dict[str, str] | None:
        """The positions (as printed, dim units) of the driver's latest state read: after
        a move returned, those read behind its report to confirm the arrival (no read
        here; ``None`` before the first)."""
        known = self._motion.latest
        return None if known is None else dict(known)

    async def position(self, *, unit: str | None = None) -> dict[str, float]:
        """The position of every present axis, in ``unit`` (default: the connection's
        ``units``, else the axis' dim unit).

        Parameters
        ----------
        unit
            The unit of the values (``"mm"``, ``"um"``...); ``None``: the connection's
            ``units``, else the controller's dim unit.

        Returns
        -------
        dict[str, float]
            The position of each present axis.
        """
        chosen = self._reading_unit(unit, Measure.POSITION)
        positions = await self.get("pos")
        assert isinstance(positions, dict)
        return await self._from_controller(positions, chosen, Measure.POSITION)

    async def status(self) -> dict[str, str]:
        """The ``statusaxis`` letter of every present axis (``@`` idle, ``M`` moving...).

        Returns
        -------
        dict[str, str]
            The status letter of each present axis.
        """
        letters = await self.get("statusaxis")
        assert isinstance(letters, dict)
        self._turning.difference_update(a for a, s in letters.items() if s != MOVING)
        return dict(letters)

    async def _position_texts(self) -> dict[str, str]:
        """``?pos`` as printed (the number of digits gives the resolution), one text per
        present axis; read axis by axis when the reply has another number of values.

        Returns
        -------
        dict[str, str]
            The position of each present axis, as printed.
        """
        present = AXES[: self.context.axes]
        response = await self._request(_read_command("pos", None, self.context))
        texts = " ".join(response.lines).split()
        if len(texts) == len(present):
            self._motion.saw(dict(zip(present, texts, strict=True)))
            return dict(zip(present, texts, strict=True))
        out = {}
        for axis in present:
            reply = await self._request(_read_command("pos", axis, self.context))
            out[axis] = " ".join(reply.lines).strip()
        return out

    # -- motion (followed by _motion.py) -------------------------------------------------------

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
        ``moa``. ``last``: the positions (as printed) the driver read last, if any.

        Returns
        -------
        MovePlan
            The line's moved axes, targets and time budget.
        """
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

    def _exact_replies(self) -> bool:
        """Whether per-axis replies were found to have one value per axis (identify)."""
        found = self._identity
        return found is not None and found.detected.get("per_axis_replies") == "exact"

    def _start_reader(self, batch: object) -> Callable[[], Awaitable[dict[str, str]]]:
        """Write ``?pos`` now (in ``batch``); return what reads its reply, one text per
        present axis (awaitable again after a cancelled wait).

        Returns
        -------
        Callable[[], Awaitable[dict[str, str]]]
            What reads the positions (empty if the reply had another number of values).
        """
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
        ``now`` (:func:`~tango_aio.moves._timing.rest_budget` with the settings in force).

        Returns
        -------
        float
            The seconds left.
        """
        return rest_budget(self._settings, targets, now, budget.fallback)

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

    # -- trigger and snapshot lists (tango.triggers, tango.snapshots) -----------------------

    def _transfer(self) -> ListTransfer:
        return ListTransfer(self._protocol, self.reply_timeout, self._list_lock)

    async def _resolution(self) -> list[float]:
        """Per present axis, one unit of the last digit ``?pos`` prints (the position
        resolution, L4080-4100).

        Returns
        -------
        list[float]
            The resolution of each present axis, X first.
        """
        texts = await self._position_texts()
        return [position_tolerance(text) / 1.5 for text in texts.values()]

    # -- physical units (the settings family converts; moves and positions use it) --------

    def _reading_unit(self, unit: str | None, measure: Measure) -> str | None:
        """The unit a reading is converted to, checked before anything is read."""
        return reading_unit(self, unit, measure)

    async def _to_controller(self, values: Mapping[str, Any], unit: str | None,
                             measure: Measure) -> dict[str, Any]:
        """Per-axis ``values`` of ``measure`` in the controller's unit, checked first."""
        return await convert_to(self, values, unit, measure)

    async def _from_controller(self, values: Mapping[str, Any], chosen: str | None,
                               measure: Measure) -> dict[str, Any]:
        """Per-axis readings converted from the controller's unit to ``chosen``."""
        return await convert_from(self, values, chosen, measure)

    async def read_info(self) -> ControllerInfo:
        """The controller's serial number, versions, temperature, uptime, axes, maximum
        current and the serial numbers of connected stages (``?readsn``, ``?ver``, ...,
        manual chapter 6).

        Returns
        -------
        ControllerInfo
            What the unit answers; a field it lacks is ``None``.
        """
        return await self.info.read()

    async def wait_restarted(self, *, quiet: float = RESTART_QUIET) -> None:
        """After a line that restarts the controller (``reset``, ``restore -1``): wait
        ``quiet`` seconds while it reboots ("more than 1 second, where the controller is
        not responding", manual L1837-1838), poll until it answers (L1845-1860), select
        the driver's autostatus mode again (it restarts in mode 1, L2062) and read the
        cached settings again.

        Parameters
        ----------
        quiet
            Seconds to wait before the first poll.

        Raises
        ------
        ControllerTimeoutError
            It did not answer in time.
        ConnectionLostError
            The link was declared lost meanwhile.
        """
        await asyncio.sleep(quiet)
        for attempt in range(2):  # the link counts as dead after two unanswered polls
            try:
                await self._protocol.resync(timeout=self.reply_timeout)
                break
            except ControllerTimeoutError:
                if attempt:
                    raise
        await self._protocol.verify_autostatus(timeout=self.reply_timeout)
        await self._reload_settings()

    async def axis_status(self) -> dict[str, AxisStatus]:
        """Like :meth:`status`, as :class:`~tango_aio.status.AxisStatus` members.

        Returns
        -------
        dict[str, AxisStatus]
            The status of each present axis.
        """
        return axis_statuses(await self.status())

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

    async def _status_and_positions(self, *, separate_after: bool = False,
                                    axes: Sequence[str] = ()
                                    ) -> tuple[dict[str, str], dict[str, str]]:
        """``?statusaxis`` and ``?pos`` of every present axis, written back to back:
        one round trip. Their replies (letters, numbers) cannot be taken for each other,
        so the protocol writes no separator between them and neither waits for the other.
        ``separate_after``: a separator follows in the same write (a move's confirmation:
        the next move's ``?err`` probe would otherwise need one in front of its line).
        A reply with another number of values than axes is read again the plain way,
        axis by axis (:meth:`status`, :meth:`_position_texts`).

        ``axes``: the one axis whose position is wanted (a move's confirmation), on
        a unit whose per-axis reads were found to answer one value (identify,
        ``per_axis_replies``): ``?pos x`` instead of ``?pos``, and only that position is
        returned. Its reply is 7 bytes against 21 on a 3-axis unit (about 2.7 ms at
        57600 Bd, on the path of every move). The letters are still read first, for every
        axis: an axis that reads stopped cannot move again before the position read right
        behind it (no line is written in between), so the position is where it stopped.

        Returns
        -------
        tuple[dict[str, str], dict[str, str]]
            The status letter and the position (as printed) of each axis read.
        """
        if self._letters_by_axis:
            return await self._state_by_axis()
        return await self._state_replies(self._submit_state(separate_after, axes))

    async def _state_by_axis(self) -> tuple[dict[str, str], dict[str, str]]:
        """The state on a unit whose letters are read axis by axis: the letters first
        (:meth:`status`), then the positions (:meth:`_position_texts`).

        Returns
        -------
        tuple[dict[str, str], dict[str, str]]
            The status letter and the position (as printed) of each present axis.
        """
        letters = await self.status()
        positions = await self._position_texts()
        self._motion.saw(positions)
        return letters, positions

    def _submit_state(self, separate_after: bool, axes: Sequence[str]) -> _StateRead:
        """Submit the two lines of :meth:`_status_and_positions` (written at once where
        the credit allows); :meth:`_state_replies` reads their replies.

        Returns
        -------
        _StateRead
            The lines and their submissions.
        """
        context = self.context
        identity = self._identity
        read = self._moves.confirmation(
            axes, AXES[: context.axes], family="" if identity is None else identity.family,
            autostatus=self._protocol.autostatus, exact_replies=self._exact_replies())
        status = _SHORT_STATUS if read.short else _read_command("statusaxis", None, context)
        pos = _read_command("pos", read.single, context)
        first, second = self._protocol.submit_together((status, pos),
                                                       separate_after=separate_after)
        return _StateRead(status, read.single, first, second)

    async def _state_replies(self, read: _StateRead
                             ) -> tuple[dict[str, str], dict[str, str]]:
        """The letters and positions of a read :meth:`_submit_state` submitted (see
        :meth:`_status_and_positions`).

        Returns
        -------
        tuple[dict[str, str], dict[str, str]]
            The status letter and the position (as printed) of each axis read.
        """
        status, first, second = read.status, read.first, read.second
        try:
            letters = parse_reply(status, (await self._protocol.wait_reply(
                first, self.reply_timeout)).lines)
        except BaseException as exc:
            if second.reply is not None:  # its outcome is nobody's now
                second.reply.add_done_callback(_ignore_outcome)
            if status is _SHORT_STATUS and isinstance(exc, ControllerTimeoutError
                                                      | ProtocolError):
                # Unanswered (or the position's reply came in its place): a firmware
                # without the alias (error 4, no reply). The read is tried again
                # (Motion._state) the long way, as from now on.
                self._moves.alias_unanswered()
            raise
        texts = " ".join((await self._protocol.wait_reply(
            second, self.reply_timeout)).lines).split()
        present = AXES[: self.context.axes]
        if not isinstance(letters, dict) or len(letters) != len(present):
            letters = await self.status()
        single = read.single
        if single is not None and len(texts) == 1:
            positions = {single: texts[0]}
        elif len(texts) != len(present):
            return letters, await self._position_texts()
        else:
            positions = dict(zip(present, texts, strict=True))
        self._motion.saw(positions)
        return letters, dict(positions)

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


@dataclass(frozen=True, slots=True)
class _Port:
    """The controller as :class:`~tango_aio.controller._motion.Motion` sees it
    (``MotionPort``): the controller's own methods, handed over."""

    start: Callable[[Command, object | None], MoveHandle]
    accepted: Callable[[MoveHandle], Coroutine[Any, Any, ControllerError | None]]
    stop: Callable[[], Coroutine[Any, Any, None]]
    read_state: Callable[[Sequence[str]],
                         Coroutine[Any, Any, tuple[dict[str, str], dict[str, str]]]]
    finished: Callable[[MoveFinished], None]
    unreported: Callable[[], None]


@dataclass(frozen=True, slots=True)
class _StateRead:
    """A state read in flight (:meth:`Controller._submit_state`)."""

    #: The letters' line (``sa`` or ``?statusaxis``).
    status: Command
    #: The one axis whose position alone was asked (``?pos x``); ``None``: ``?pos``.
    single: str | None
    first: Submission
    second: Submission


@dataclass(frozen=True, slots=True)
class _Relink:
    """The controller as its :class:`~tango_aio.link._reconnect.Reconnector` sees it
    (:class:`~tango_aio.link._reconnect.ReconnectPort`): the controller's own methods, handed
    over."""

    url_of: Callable[[], str]
    signature: _SignatureOf
    release_link: Callable[[], Coroutine[Any, Any, None]]
    stage: Callable[[TangoProtocol, Closer | None], Controller]
    adopt: Callable[[Controller, Closer | None], None]
    reconnected: Callable[[int], None]
    give_up: Callable[[ConnectionLostError], None]

    @property
    def url(self) -> str:
        """The URL that is opened again."""
        return self.url_of()


class _SignatureOf(Protocol):
    def __call__(self, controller: Controller | None = None) -> Signature | None: ...





def _ignore_outcome(future: asyncio.Future[Any]) -> None:
    """Retrieve a future's outcome that nobody awaits (no "never retrieved" log)."""
    if not future.cancelled():
        future.exception()


def _line_groups(axes: Mapping[str, float]) -> list[dict[str, float]]:
    """The lines that move exactly the named axes.

    The manual addresses either one axis (``moa y 34.5``) or the leading axes from X
    (``moa 10 0.5`` moves X and Y, L6353-6361); it has no form for another subset. Naming
    an axis that should not move, with its current position, would move it by the
    rounding of that position, and the ``distance``+``m`` form (L6420-6455) is relative
    and changes a setting. So a set that starts at X without gaps is one vector line; any
    other set is moved axis by axis, one line after the other, each followed to its end
    (the controller's behaviour for a second move line while axes run is not documented,
    so moves never overlap).

    Returns
    -------
    list[dict[str, float]]
        The values of each line's axes, one mapping per line, in writing order.
    """
    order = [axis for axis in AXES if axis in axes]
    unknown = set(axes) - set(AXES)
    if unknown or not order:
        return [dict(axes)]  # build_axes reports the error
    if order == list(AXES[: len(order)]):
        return [{axis: axes[axis] for axis in order}]
    return [{axis: axes[axis]} for axis in order]


#: A per-move velocity or acceleration: one number for every moved axis, or per axis.
Speed = float | Mapping[str, float]


#: Whether a move's completion report arrived (its wait not cancelled, not failed).
_reported = report_came


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


#: Lines without a completion report that start motion (a refusal is checked, see
#: :meth:`Controller._contest`).
_STARTS_MOTION = frozenset({"speed", "go"})

#: Seconds between two reads of an axis a speed or go line stops, or speeds up.
_STOP_POLL = 0.01

#: Instructions whose float values are list positions (checked against the resolution).
_LIST_POSITIONS = frozenset({"trigp", "trigr", "snsa"})


class _Devices:
    """The port of the device families: the controller's own methods."""

    __slots__ = ("_controller",)

    def __init__(self, controller: Controller) -> None:
        self._controller = controller

    @property
    def context(self) -> Context:
        return self._controller.context

    @property
    def identity(self) -> Identity:
        return self._controller.identity

    @property
    def units(self) -> str | None:
        return self._controller.units

    @units.setter
    def units(self, value: str | None) -> None:
        self._controller.units = value

    async def refresh_settings(self) -> None:
        await self._controller.refresh_settings()

    async def wait_restarted(self, *, quiet: float = RESTART_QUIET) -> None:
        await self._controller.wait_restarted(quiet=quiet)

    @property
    def axes(self) -> tuple[str, ...]:
        known = self._controller._identity
        return tuple(AXES[: known.axes if known else self._controller.context.axes])

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        return await self._controller.get(name, *args, axis=axis, timeout=timeout)

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        await self._controller.set(name, *args, axis=axis, check=check, **axes)

    async def query(self, line: str, timeout: float | None = None) -> str:
        return await self._controller.query(line, timeout)

    async def command(self, line: str, *, check: bool = True,
                      timeout: float | None = None) -> None:
        await self._controller.command(line, check=check, timeout=timeout)

    async def read_if_known(self, name: str) -> Any:
        controller = self._controller
        known = controller._identity
        if known is not None and known.family == "older" \
                and not INSTRUCTIONS[name].in_older_manual:
            return None
        try:
            return await controller._read_or_absent(name)
        except (InvalidInstructionError, ProtocolError):
            return None

    async def state(self) -> tuple[dict[str, str], dict[str, str]]:
        return await self._controller._status_and_positions()

    async def user_positions(self, texts: Mapping[str, str]) -> dict[str, float]:
        controller = self._controller
        return await controller._from_controller(
            texts, controller._reading_unit(None, Measure.POSITION), Measure.POSITION)

    def publish(self, event: TangoEvent) -> None:
        self._controller._hub.publish(event)

    def moving(self) -> bool:
        return self._controller._motion.busy or bool(self._controller._motion_calls)

    def list_transfer(self) -> ListTransfer:
        return self._controller._transfer()

    async def resolution(self) -> list[float]:
        return await self._controller._resolution()

    def check_axes(self, command: Command) -> None:
        self._controller._check_axes(command)


def _spelled(line: str) -> Command:
    """The command of ``line`` written as spelt (an alias), not by its canonical name."""
    command = parse(line)
    # The caches of the line's text and bytes (schema.Command), filled in by parse().
    object.__setattr__(command, "_line", line)
    object.__setattr__(command, "_bytes", line.encode("ascii") + b"\r")
    return command


#: ``sa``: the letters of every axis, as ``?statusaxis`` (L2662-2725).
_SHORT_STATUS: Final = _spelled("sa")


@functools.lru_cache(maxsize=256)
def _read_command(name: str, axis: str | None, context: Context) -> Command:
    """The read line of instruction ``name`` without arguments (``?pos``, ``?vel x``),
    built once per name, axis and context: commands are immutable values, and the
    per-request path need not validate the same line again.

    Returns
    -------
    Command
        The read line.
    """
    return build(name, form=Form.READ, axis=axis, context=context)
