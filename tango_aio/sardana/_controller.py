"""The Sardana motor controller: one TANGO controller, its axes as pool motors."""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable
from typing import Any, ClassVar

import anyio
from sardana import State as SardanaState
from sardana.pool.controller import (
    Access,
    DefaultValue,
    Description,
    MotorController,
    Type,
)

import tango_aio.sync
from tango_aio.errors import TangoError
from tango_aio.status import switch_states
from tango_aio.units import LENGTH_UNITS

from ._links import acquire, release
from ._state import AxisState, Outcome, State, axis_state, switch_bits

_AXES = "xyza"

_SARDANA_STATES = {
    State.ON: SardanaState.On,
    State.MOVING: SardanaState.Moving,
    State.ALARM: SardanaState.Alarm,
    State.FAULT: SardanaState.Fault,
}

#: Relative difference below which a Deceleration equals the Acceleration time.
_SAME_TIME = 1e-6


def _on(letter: str, value: Any) -> dict[str, Any]:
    """``{letter: float(value)}``, to pass as one axis' keyword."""
    return {letter: float(value)}


class _Move:
    """One move started by ``StartAll``: its axes, and how it stands (shared with the
    driver's thread)."""

    def __init__(self, targets: dict[str, Any]) -> None:
        self.targets = targets
        self.axes = frozenset(targets)
        #: Set once the driver's verdict is in and the axes stand still (clean-up done).
        self.done = threading.Event()
        self.error: BaseException | None = None
        #: Axes the pool stopped or aborted.
        self.stopped: set[str] = set()
        #: Cancelled before its task began (then it never writes its line).
        self.cancelled_early = False
        self.scope: anyio.CancelScope | None = None

    def outcome(self, axis: str) -> Outcome:
        if not self.done.is_set():
            return Outcome(running=True)
        error = self.error
        text = None if error is None else (str(error) or type(error).__name__)
        return Outcome(running=False, error=text, stopped_on_request=axis in self.stopped)


class MarzhauserMotorController(MotorController):  # type: ignore[misc]
    """The axes of a Märzhäuser TANGO stage controller as Sardana pool motors.

    Axis 1 is X, 2 is Y, 3 is Z, 4 is A. Positions are in the ``Units`` property's unit
    (default mm), velocities in ``Units`` per second, Acceleration and Deceleration in
    seconds (Sardana's convention: the time to reach Velocity). Motors started together
    (a motor group, a ``mv`` of several motors, a scan step) move in one interpolated
    ``!moa`` when they are X, XY, XYZ or XYZA; any other set moves axis by axis
    (:meth:`tango_aio.Controller.move_to`).

    ``StateOne`` reports ``Moving`` from ``StartAll`` until the driver's verdict on the
    move is in, so the pool never sees a motor stopped while it runs or before its final
    position can be read; ``On`` when the move arrived (or was stopped on request);
    ``Alarm`` with the reason in the status when it did not (limit switch, refused line,
    stopped by another client), and while a limit switch is actuated; ``Fault`` while
    the controller cannot be read (the link is lost). The driver runs in a thread of its
    own (:mod:`tango_aio.sync`), as the pool calls controllers from several threads.

    See the how-to "Use TANGO stages in a Sardana pool" in the documentation.
    """

    MaxDevice = 4
    model = "Märzhäuser TANGO"
    organization = "tango_aio"

    ctrl_properties: ClassVar[dict[str, dict[Any, Any]]] = {
        "URL": {
            Type: str,
            Description: "Where the TANGO controller is: a serial port (/dev/ttyUSB0, "
                         "COM3), socket://host:port, or sim:// for the emulator "
                         "(tango_aio.connect)",
        },
        "Units": {
            Type: str,
            Description: "The unit of positions (mm, um, ...); velocities are in it per "
                         "second",
            DefaultValue: "mm",
        },
        "Reconnect": {
            Type: bool,
            Description: "Reconnect by itself when the link is lost (motors read Fault "
                         "meanwhile); false: the controller must be initialised again",
            DefaultValue: True,
        },
    }

    axis_attributes: ClassVar[dict[str, dict[Any, Any]]] = {
        "ControllerBacklash": {
            Type: float,
            Access: "read_write",
            Description: "The controller's own backlash compensation (backlash), in "
                         "micrometres whatever the unit (0: off)",
        },
        "Calibrated": {
            Type: bool,
            Access: "read",
            Description: "Whether the axis has been calibrated (cal) since power-on",
        },
    }

    def __init__(self, inst: str, props: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        super().__init__(inst, props, *args, **kwargs)
        self._lock = threading.Lock()
        self._moves: dict[str, _Move] = {}
        self._pending: dict[str, Any] = {}
        self._stopping: set[str] = set()
        self._aborting = False
        #: One round's reads (``PreStateAll``/``PreReadAll`` to the last ``...One``), by
        #: thread: a read begun before another thread's round never serves that round.
        self._round = threading.local()
        #: The axes of the pool's motors (AddDevice, DeleteDevice).
        self._axes: set[int] = set()
        self._tango: tango_aio.sync.Controller | None = None
        self._open()

    def _open(self) -> None:
        self._tango = acquire(self.URL, self.Units, bool(self.Reconnect))
        with self._lock:
            self._moves = {}  # outcomes of a link closed since: not this link's

    # -- life cycle ------------------------------------------------------------------------

    @property
    def tango(self) -> tango_aio.sync.Controller:
        """The blocking driver object this controller drives (for tests and diagnostics).

        Raises
        ------
        TangoError
            The link is closed (the pool has no motor of this controller).
        """
        if self._tango is None:
            raise TangoError("the link to the TANGO controller is closed: the pool has no "
                             "motor of this controller")
        return self._tango

    def close(self) -> None:
        """Let go of the link to the TANGO controller (closed with the last controller of
        this URL in the process); ``AddDevice`` opens it again."""
        tango, self._tango = self._tango, None
        if tango is not None:
            release(tango)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def AddDevice(self, axis: int) -> None:
        """A motor of this axis was created in the pool (the link is opened again if the
        last motor's deletion closed it).

        Raises
        ------
        ValueError
            The controller has no such axis.
        """
        if self._tango is None:
            self._open()
        self._letter(axis)
        self._axes.add(axis)

    def DeleteDevice(self, axis: int) -> None:
        """The motor of this axis was deleted; with the last one the link is closed, so
        that a controller the pool initialises again (which deletes every motor first)
        finds the serial port free (ports are opened exclusively)."""
        self._axes.discard(axis)
        if not self._axes:
            self.close()

    def _letter(self, axis: int) -> str:
        """The axis letter of a Sardana axis number (1 is X)."""
        count = self.tango.identity.axes
        if not 1 <= axis <= count:
            raise ValueError(f"axis {axis}: the TANGO controller has axes 1-{count} "
                             f"({' '.join(_AXES[:count]).upper()})")
        return _AXES[axis - 1]

    def _call(self, func: Callable[[], Any]) -> Any:
        """Run ``func`` in the driver's thread and return its result."""
        async def run() -> Any:
            return func()
        return self.tango.portal.call(run)

    # -- state -----------------------------------------------------------------------------

    def PreStateAll(self) -> None:
        """A new round of state reads begins: read the controller again."""
        self._round.states = None

    def StateOne(self, axis: int) -> tuple[Any, str, int]:
        """The state of one axis, its status text and its limit switches.

        Returns
        -------
        tuple
            ``(sardana.State, status, limit switch bits)``.
        """
        letter = self._letter(axis)
        with self._lock:
            move = self._moves.get(letter)
        outcome = None if move is None else move.outcome(letter)
        if outcome is not None and outcome.running:
            found = axis_state(outcome)
        else:
            found = self._idle_state(letter, outcome)
        return _SARDANA_STATES[found.state], found.status, found.switches

    def _idle_state(self, letter: str, outcome: Outcome | None) -> AxisState:
        # Without a move of this controller in flight: one read per round (PreStateAll).
        states = getattr(self._round, "states", None)
        if states is None:
            states = self._round.states = self._read_states()
        read = states[letter]
        if read.state is State.FAULT:
            return axis_state(outcome, unreadable=read.status)
        return axis_state(outcome, letter=read.status, switches=read.switches)

    def _read_states(self) -> dict[str, AxisState]:
        # Each axis' statusaxis letter (as the status) and switches, or FAULT and why.
        tango = self.tango
        present = _AXES[: tango.identity.axes]
        try:
            if not tango.connected:
                raise TangoError("the link to the TANGO controller is lost (reconnecting)")
            letters = tango.status()
            reply = tango.query("?readsw")
            switches = {axis: switch_states(reply, axis) for axis in present}
            if None in switches.values():
                raise TangoError(f"?readsw replied {reply!r}, not 12 switch states "
                                 "(manual L5057-5066)")
            return {axis: AxisState(State.ON, letters[axis], switch_bits(states))
                    for axis, states in switches.items() if states is not None}
        except TangoError as exc:
            reason = f"the TANGO controller cannot be read: {exc}"
            return dict.fromkeys(present, AxisState(State.FAULT, reason))

    # -- position --------------------------------------------------------------------------

    def PreReadAll(self) -> None:
        """A new round of position reads begins."""
        self._round.positions = None

    def ReadOne(self, axis: int) -> float:
        """The position of one axis (one ``?pos`` read per round for every axis).

        Returns
        -------
        float
            The position, in ``Units``.
        """
        letter = self._letter(axis)
        positions = getattr(self._round, "positions", None)
        if positions is None:
            positions = self._round.positions = self.tango.position()
        return positions[letter]

    # -- motion ----------------------------------------------------------------------------

    def PreStartAll(self) -> None:
        """A new start begins: forget targets of a start that failed."""
        with self._lock:
            self._pending = {}

    def StartOne(self, axis: int, position: float) -> None:
        """Take the target of one axis; ``StartAll`` moves every axis taken together.

        Raises
        ------
        ValueError
            ``position`` is not a finite number, or the axis is moving.
        """
        letter = self._letter(axis)
        if not math.isfinite(position):
            raise ValueError(f"axis {letter.upper()}: target {position!r} is not a number")
        with self._lock:
            move = self._moves.get(letter)
            if move is not None and not move.done.is_set():
                raise ValueError(f"axis {letter.upper()} is moving")
            self._pending[letter] = float(position)

    def StartAll(self) -> None:
        """Start the axes taken by ``StartOne`` in one move, and return at once."""
        with self._lock:
            targets, self._pending = self._pending, {}
            if not targets:
                return
            move = _Move(targets)
            for letter in targets:
                self._moves[letter] = move
        try:
            self.tango.portal.start(self._run, move)
        except BaseException as exc:  # never started: nothing moves
            move.error = exc
            move.done.set()
            raise

    async def _run(self, move: _Move) -> None:
        """The move, in the driver's thread; ``move.done`` once its axes stand still."""
        try:
            with anyio.CancelScope() as scope:
                move.scope = scope
                if move.cancelled_early:
                    move.error = TangoError("stopped before the move was written")
                    return
                await self.tango.aio.move_to(**move.targets)
        except BaseException as exc:
            move.error = exc
            raise
        finally:
            if scope.cancelled_caught and move.error is None:
                move.error = TangoError("the move was cancelled in the driver (its axes "
                                        "were stopped)")
            move.done.set()

    # -- stop and abort --------------------------------------------------------------------

    def PreStopAll(self) -> None:
        """A new stop begins."""
        with self._lock:
            self._stopping = set()

    def StopOne(self, axis: int) -> None:
        """Take one axis to stop; ``StopAll`` stops them (``a x``, manual L6785-6844)."""
        letter = self._letter(axis)
        with self._lock:
            self._stopping.add(letter)

    def StopAll(self) -> None:
        """Stop the axes taken by ``StopOne``: a move whose axes are all stopped is
        cancelled (never written if it was not yet, else the driver stops its axes and
        waits until they stand still); the others get ``a`` for those axes alone."""
        with self._lock:
            chosen, self._stopping = self._stopping, set()
            moves = {id(m): m for a, m in self._moves.items() if a in chosen}.values()
        if not chosen:
            return
        rest = sorted(a for a in chosen if not any(
            a in m.axes and m.axes <= chosen and not m.done.is_set() for m in moves))
        self._call(lambda: self._cancel(moves, chosen))
        if rest:
            self.tango.stop(*rest, wait=False)

    def _cancel(self, moves: Any, axes: set[str]) -> None:
        """In the driver's thread: cancel each move whose axes all stop, and mark the
        stopped axes of every one."""
        for move in moves:
            move.stopped |= move.axes & axes
            if not move.axes <= axes or move.done.is_set():
                continue
            if move.scope is None:
                move.cancelled_early = True
            else:
                move.scope.cancel()

    def PreAbortAll(self) -> None:
        """A new abort begins."""
        with self._lock:
            self._aborting = False

    def AbortOne(self, axis: int) -> None:
        """Abort: every axis of the controller stops (see ``AbortAll``)."""
        self._letter(axis)
        with self._lock:
            self._aborting = True

    def AbortAll(self) -> None:
        """Stop every axis of the controller at once: this controller's moves are
        cancelled, then Ctrl+C (manual L6808-6814, with ``a`` before and after it) stops
        whatever else moves; returns without waiting (the motors read ``Moving`` until
        their axes stand still)."""
        with self._lock:
            aborting, self._aborting = self._aborting, False
            moves = {id(m): m for m in self._moves.values()}.values()
        if not aborting:
            return
        self._call(lambda: self._cancel(moves, set(_AXES)))
        self.tango.abort(wait=False)

    # -- axis parameters -------------------------------------------------------------------

    def GetAxisPar(self, axis: int, name: str) -> float:
        """Read a standard axis parameter (see the how-to's table for each).

        Returns
        -------
        float
            The parameter's value.

        Raises
        ------
        ValueError
            A parameter this controller does not know.
        """
        letter = self._letter(axis)
        parameter = name.lower()
        tango = self.tango
        if parameter == "velocity":
            return float(tango.settings.velocity()[letter])
        if parameter in ("acceleration", "deceleration"):
            return self._ramp_time(letter)
        if parameter == "base_rate":
            return 0.0
        if parameter == "step_per_unit":
            return self._steps_per_unit(letter)
        raise ValueError(f"no axis parameter {name!r}")

    def SetAxisPar(self, axis: int, name: str, value: float) -> None:
        """Write a standard axis parameter (see the how-to's table for each).

        Raises
        ------
        ValueError
            A read-only parameter, or a value the controller does not take.
        """
        letter = self._letter(axis)
        parameter = name.lower()
        tango = self.tango
        if parameter == "velocity":
            tango.settings.set_velocity(**_on(letter, value))
        elif parameter == "acceleration":
            if not value > 0:
                raise ValueError(f"Acceleration (a time, s) must be positive, got {value!r}")
            velocity = float(tango.settings.velocity()[letter])
            tango.settings.set_acceleration(**_on(letter, velocity / float(value)))
        elif parameter == "deceleration":
            if not math.isclose(value, self._ramp_time(letter), rel_tol=_SAME_TIME):
                raise ValueError("the TANGO decelerates with the acceleration of its moves "
                                 "(accel, manual L3298-3399): set Acceleration; "
                                 "Deceleration follows it")
        elif parameter == "base_rate":
            if value != 0:
                raise ValueError("the TANGO ramps from standstill: none of its axis "
                                 "settings is a start speed (manual L3061-4521)")
        elif parameter == "step_per_unit":
            raise ValueError("Step_per_unit follows from the axis' motorsteps, gear and "
                             "pitch (manual L3145-3297), which describe the mechanics: "
                             "it is read-only here")
        else:
            raise ValueError(f"no axis parameter {name!r}")

    def _ramp_time(self, letter: str) -> float:
        """Seconds to reach the axis' velocity: ``vel`` / ``accel``."""
        tango = self.tango
        settings = tango.settings
        return float(settings.velocity()[letter]) / float(settings.acceleration()[letter])

    def _steps_per_unit(self, letter: str) -> float:
        """Full motor steps per ``Units``: motorsteps × gear / pitch (per mm)."""
        tango = self.tango
        per_mm = LENGTH_UNITS.get(self.Units)
        if per_mm is None:
            raise ValueError(f"Step_per_unit is known for length units only, not "
                             f"{self.Units!r}")
        steps = float(tango.get("motorsteps", axis=letter))
        gear = float(tango.get("gear", axis=letter))
        pitch = float(tango.get("pitch", axis=letter))
        return steps * gear / pitch * float(per_mm)

    def GetAxisExtraPar(self, axis: int, name: str) -> Any:
        """Read ``ControllerBacklash`` (µm) or ``Calibrated``.

        Returns
        -------
        Any
            The value.

        Raises
        ------
        ValueError
            An unknown attribute.
        """
        letter = self._letter(axis)
        if name.lower() == "controllerbacklash":
            return float(self.tango.get("backlash", axis=letter))
        if name.lower() == "calibrated":
            return bool(self.tango.is_calibrated(letter))
        raise ValueError(f"no axis attribute {name!r}")

    def SetAxisExtraPar(self, axis: int, name: str, value: Any) -> None:
        """Write ``ControllerBacklash`` (µm, -100 to 100, manual L4168-4221).

        Raises
        ------
        ValueError
            An unknown or read-only attribute.
        """
        letter = self._letter(axis)
        if name.lower() != "controllerbacklash":
            raise ValueError(f"axis attribute {name!r} cannot be written")
        self.tango.set("backlash", **_on(letter, value))

    def DefinePosition(self, axis: int, position: float) -> None:
        """Not supported: set the motor's Offset instead.

        Raises
        ------
        NotImplementedError
            Always.
        """
        raise NotImplementedError("redefining a TANGO position is not supported here: set "
                                  "the motor's Offset instead")
