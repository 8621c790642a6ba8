"""What the controller reads: settings by name, the state and positions of the axes
(``?statusaxis`` and ``?pos`` back to back), physical units and lists; the base of
:class:`~tango_aio.controller._controller.Controller`."""

from __future__ import annotations

import asyncio
import functools
from collections.abc import (
    Iterable,
    Mapping,
    Sequence,
)
from dataclasses import dataclass, field
from typing import Any, Final

from .._checks import check_timeout
from ..catalog import (
    AXES,
    Command,
    Context,
    DetInfo,
    Form,
    Value,
    VersionInfo,
    build,
    check_axis_word,
    parse,
    parse_reply,
)
from ..errors import (
    ControllerTimeoutError,
    InvalidCommandError,
    ProtocolError,
)
from ..events import (
    EventHub,
)
from ..families import (
    ControllerInfo,
    Info,
    ListTransfer,
    convert_from,
    convert_to,
    reading_unit,
)
from ..link import (
    Response,
    Submission,
    TangoProtocol,
)
from ..moves import (
    MoveTracker,
    position_tolerance,
)
from ..sansio import (
    DriverState,
)
from ..status import MOVING, AxisStatus, axis_statuses
from ..units import Measure
from ._motion import (
    Motion,
)
from ._restart import (
    RestartWatch,
)

#: Reads whose all-axes form is unreliable: read axis by axis. ``?lim`` sends an extra CR
#: after the X pair in extmode 0 (L4559-4621), ``?swtyp`` prints its groups without
#: separating blanks there (L4814-4824).
AXIS_BY_AXIS = frozenset({"lim", "swtyp"})


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


class _Reads:
    """The reads of a controller: what the controller fills in (the attributes below) and
    the reads of settings, state and positions over its protocol."""

    url: str
    reply_timeout: float
    units: str | None
    info: Info
    _protocol: TangoProtocol
    _hub: EventHub
    _settings: DriverState
    _motion: Motion
    _motion_calls: set[asyncio.Event]
    _turning: set[str]
    _identity: Identity | None
    _letters_by_axis: bool
    _moves: MoveTracker
    _limits: dict[str, tuple[float, float]]
    _limits_epoch: int
    _fault: int
    _list_lock: asyncio.Lock
    _restarts: RestartWatch

    @property
    def context(self) -> Context:
        """Controller state used to validate lines (dims, axis count, extmode)."""
        return self._protocol.context

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

    async def query(self, line: str, timeout: float | None = None) -> str:
        """Send a read such as ``"?pos x"`` and return its reply text (lines joined by
        ``"\\n"``). Raises :class:`InvalidCommandError` for a line that does not read."""
        command = parse(line, self.context)
        if not command.is_read:
            raise InvalidCommandError(f"{command.line!r} does not read; use command()",
                                      instruction=command.name)
        response = await self._request(command, timeout)
        return "\n".join(response.lines)

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        """Read instruction ``name`` and return its parsed reply.

        Per-axis values come as ``{"x": 1.0, "y": 2.0}`` (exactly the axes found at
        identification), or a scalar when ``axis`` is given. ``args`` are extra read
        arguments (``get("trigp", 3)``). ``lim`` and ``swtyp`` are read axis by axis, as
        the manual recommends (L4559, L4814); any other per-axis reply with fewer or more
        values than axes is read again axis by axis, so that no value is credited to the
        wrong axis (a unit that leaves disabled axes out)."""
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

    @property
    def last_positions(self) -> dict[str, str] | None:
        """The positions (as printed, dim units) of the driver's latest state read: after
        a move returned, those read behind its report to confirm the arrival (no read
        here; ``None`` before the first)."""
        known = self._motion.latest
        return None if known is None else dict(known)

    async def position(self, *, unit: str | None = None) -> dict[str, float]:
        """The position of every present axis, in ``unit`` (default: the connection's
        ``units``, else the axis' dim unit)."""
        chosen = self._reading_unit(unit, Measure.POSITION)
        positions = await self.get("pos")
        assert isinstance(positions, dict)
        return await self._from_controller(positions, chosen, Measure.POSITION)

    async def status(self) -> dict[str, str]:
        """The ``statusaxis`` letter of every present axis (``@`` idle, ``M`` moving...)."""
        letters = await self.get("statusaxis")
        assert isinstance(letters, dict)
        self._turning.difference_update(a for a, s in letters.items() if s != MOVING)
        return dict(letters)

    async def _position_texts(self) -> dict[str, str]:
        """``?pos`` as printed (the number of digits gives the resolution), one text per
        present axis; read axis by axis when the reply has another number of values."""
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

    async def axis_status(self) -> dict[str, AxisStatus]:
        """Like :meth:`status`, as :class:`~tango_aio.status.AxisStatus` members."""
        return axis_statuses(await self.status())

    async def read_info(self) -> ControllerInfo:
        """The controller's serial number, versions, temperature, uptime, axes, maximum
        current and the serial numbers of connected stages (``?readsn``, ``?ver``, ...,
        manual chapter 6)."""
        return await self.info.read()

    def _transfer(self) -> ListTransfer:
        return ListTransfer(self._protocol, self.reply_timeout, self._list_lock)

    async def _resolution(self) -> list[float]:
        """Per present axis, one unit of the last digit ``?pos`` prints (the position
        resolution, L4080-4100)."""
        texts = await self._position_texts()
        return [position_tolerance(text) / 1.5 for text in texts.values()]

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

    def _exact_replies(self) -> bool:
        """Whether per-axis replies were found to have one value per axis (identify)."""
        found = self._identity
        return found is not None and found.detected.get("per_axis_replies") == "exact"

    async def _status_and_positions(self, *, separate_after: bool = False,
                                    axes: Sequence[str] = ()
                                    ) -> tuple[dict[str, str], dict[str, str]]:
        """``?statusaxis`` and ``?pos`` of every present axis, written back to back:
        one round trip. Their replies (letters, numbers) cannot be taken for each other,
        so the protocol writes no separator between them and neither waits for the other.
        ``separate_after``: a separator follows in the same write (a move's confirmation:
        the next move's ``?err`` probe would otherwise need one in front of its line).
        A reply with another number of values than axes is read again the plain way,
        axis by axis (:meth:`status`, :meth:`_position_texts`)."""
        if self._letters_by_axis:
            return await self._state_by_axis()
        return await self._state_replies(self._submit_state(separate_after, axes))

    async def _state_by_axis(self) -> tuple[dict[str, str], dict[str, str]]:
        """The state on a unit whose letters are read axis by axis: the letters first
        (:meth:`status`), then the positions (:meth:`_position_texts`)."""
        letters = await self.status()
        positions = await self._position_texts()
        self._motion.saw(positions)
        return letters, positions

    def _submit_state(self, separate_after: bool, axes: Sequence[str]) -> _StateRead:
        """Submit the two lines of :meth:`_status_and_positions` (written at once where
        the credit allows); :meth:`_state_replies` reads their replies."""
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
        :meth:`_status_and_positions`)."""
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


@dataclass(frozen=True, slots=True)
class _StateRead:
    """A state read in flight (:meth:`Controller._submit_state`)."""

    #: The letters' line (``sa`` or ``?statusaxis``).
    status: Command
    #: The one axis whose position alone was asked (``?pos x``); ``None``: ``?pos``.
    single: str | None
    first: Submission
    second: Submission


def _ignore_outcome(future: asyncio.Future[Any]) -> None:
    """Retrieve a future's outcome that nobody awaits (no "never retrieved" log)."""
    if not future.cancelled():
        future.exception()


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
    per-request path need not validate the same line again."""
    return build(name, form=Form.READ, axis=axis, context=context)
