"""TANGO axes as Micro-Manager stages: moves followed to the driver's verdict."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from pymmcore_plus.experimental.unicore import (
    Device,
    StageDevice,
    XYStageDevice,
    pymm_property,
)

import tango_aio.sync
from tango_aio.errors import NotSupportedByFirmwareError
from tango_aio.units import Measure, to_controller

from ._hub import UNIT, TangoHub, hub_of
from ._moves import Moves
from ._sequence import MAX_LENGTH, run_sequence, run_through
from ._stepseq import MAX_LENGTH as STEPS_MAX_LENGTH
from ._stepseq import CameraSteps

AXES = "xyza"

#: The velocity and acceleration units of the properties (the controller's own
#: acceleration unit; velocities in µm/s as Micro-Manager's stages give them).
VELOCITY_UNIT = "um/s"
ACCELERATION_UNIT = "m/s2"

#: ``backlash`` is µm whatever the dim (L4168-4180); the older edition lacks it.
BACKLASH_RANGE = (-100.0, 100.0)

if TYPE_CHECKING:
    _Base = Device
else:
    _Base = object


class _Axes(_Base):
    """What both stage types share: the hub, the axes, the moves and the properties (a
    mixin before the stage's device class, whose methods it uses)."""

    def __init__(self, hub: TangoHub | None, axes: tuple[str, ...]) -> None:
        super().__init__()
        for axis in axes:
            if axis not in AXES:
                raise ValueError(f"not a TANGO axis: {axis!r} (one of x, y, z, a)")
        if len(set(axes)) != len(axes):
            raise ValueError(f"an axis given twice: {axes!r}")
        self._hub = hub
        self._axes = axes
        self._moves = Moves()
        self._camera = False
        self._steps: CameraSteps | None = None

    # -- wiring ---------------------------------------------------------------------------

    @property
    def hub(self) -> TangoHub:
        """The hub whose controller moves these axes."""
        if self._hub is None:
            self._hub = hub_of(self.get_parent_label())
        return self._hub

    @property
    def controller(self) -> tango_aio.sync.Controller:
        """The hub's blocking controller."""
        return self.hub.controller

    def initialize(self) -> None:
        """Check the axes against the controller and add the per-axis properties."""
        identity = self.controller.identity
        present = AXES[: identity.axes]
        missing = [axis for axis in self._axes if axis not in present]
        if missing:
            raise ValueError(f"the controller has axes {', '.join(present)} only, "
                             f"not {', '.join(missing)}")
        for axis in self._axes:
            self._add_properties(axis, older=identity.family == "older")

    def _add_properties(self, axis: str, *, older: bool) -> None:
        """Velocity, acceleration, backlash (not in the older edition) and the software
        limits of ``axis``, read and written through the driver's units (each accessor
        takes the device it is called on, so that the device holds no cycle)."""
        tag = axis.upper()

        def prop(name: str, getter: Callable[[_Axes], float],
                 setter: Callable[[_Axes, float], None],
                 limits: tuple[float, float] | None = None) -> None:
            self.register_property(f"{tag} {name}", getter=getter,
                                   setter=lambda dev, v: setter(dev, float(v)),
                                   limits=limits, property_type=float)

        prop(f"Velocity ({VELOCITY_UNIT})",
             lambda dev: dev.controller.settings.velocity(unit=VELOCITY_UNIT)[axis],
             lambda dev, v: dev.controller.settings.set_velocity(unit=VELOCITY_UNIT,
                                                        **_by_axis({axis: v})))
        prop("Acceleration (m/s^2)",
             lambda dev: dev.controller.settings.acceleration(unit=ACCELERATION_UNIT)[axis],
             lambda dev, v: dev.controller.settings.set_acceleration(unit=ACCELERATION_UNIT,
                                                            **_by_axis({axis: v})))
        if not older:
            prop("Backlash (um)",
                 lambda dev: float(dev.controller.get("backlash", axis=axis)),
                 lambda dev, v: dev.controller.set("backlash", **_by_axis({axis: v})),
                 BACKLASH_RANGE)
        prop("Lower limit (um)", lambda dev: dev.limits_um(axis)[0],
             lambda dev, v: dev.set_limits_um(axis, v, dev.limits_um(axis)[1]))
        prop("Upper limit (um)", lambda dev: dev.limits_um(axis)[1],
             lambda dev, v: dev.set_limits_um(axis, dev.limits_um(axis)[0], v))

    def limits_um(self, axis: str) -> tuple[float, float]:
        """The software limits of ``axis`` (``?lim``) in µm: the stage's travel range."""
        self._moves.check()
        lower, upper = self.controller.settings.limits()[axis]
        return float(lower), float(upper)

    def set_limits_um(self, axis: str, lower: float, upper: float) -> None:
        """Set the software limits of ``axis`` (``!lim``) in µm."""
        self._moves.check()
        self.controller.settings.set_limits(**_by_axis({axis: (lower, upper)}))

    # -- motion ---------------------------------------------------------------------------

    def _start(self, method: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Start a motion call of the driver; followed until its verdict."""
        self._moves.check()
        tango = self.controller
        self._moves.add(tango.portal.start(method, *args, **kwargs))

    def _move_to(self, targets: dict[str, float]) -> None:
        self._start(self.controller.aio.move_to, **targets)

    def _move_by(self, distances: dict[str, float]) -> None:
        self._start(self.controller.aio.move_by, **distances)

    def _positions(self) -> dict[str, float]:
        self._moves.check()
        where = self.controller.position()
        return {axis: where[axis] for axis in self._axes}

    def busy(self) -> bool:
        """Whether a move of these axes has not ended with the driver's verdict yet."""
        busy = self._moves.busy()
        if not busy and self._moves.ended():
            self._announce()
        return busy

    def _announce(self) -> None:
        """Tell the core's listeners (stage widgets) where the axes stand now."""
        where = self._positions()
        values = [where[axis] for axis in self._axes]
        events = self.core.events
        signal = events.XYStagePositionChanged if len(values) == 2 \
            else events.stagePositionChanged
        signal.emit(self.get_label(), *values)

    def home(self) -> None:
        """Calibrate the axes (``cal``, L5259: to the lower limit switch, which becomes 0);
        :meth:`busy` until they stand there."""
        self._start(self.controller.aio.calibrate, *self._axes)

    def stop(self) -> None:
        """Stop the axes and wait until they stand: the moves started here are cancelled
        (one whose line is not written yet never is; a running one stops its axes), then
        ``a x``... stops the axes whoever moves them. The stopped moves end without an
        error to report."""
        for move in self._moves.stopping():
            move.cancel()
        self.controller.stop(*self._axes)

    def _zero(self, *axes: str) -> None:
        """Make the current position of ``axes`` 0 (``!pos``, L6900-6920)."""
        self._moves.check()
        self.controller.set("pos", **_by_axis(dict.fromkeys(axes, 0.0)))

    def _call_position(self, where_um: dict[str, float]) -> None:
        """Make the current position of each axis ``where_um`` µm (``!pos`` in its dim
        unit, converted by :mod:`tango_aio.units`)."""
        self._moves.check()
        tango = self.controller
        scales = tango.settings.unit_scales()
        tango.set("pos", **_by_axis({
            axis: to_controller(value, UNIT, Measure.POSITION, scales[axis])
            for axis, value in where_um.items()}))

    def shutdown(self) -> None:
        """Stop following the moves (the hub closes the link)."""
        self._moves.stopping()

    # -- camera-triggered sequences: the snapshot array -----------------------------------

    @pymm_property(name="Camera trigger sequence", allowed_values=("Off", "On"))
    def camera_sequence(self) -> str:
        """Whether the stage offers the core sequences it steps through on each trigger
        from the camera (the camera's trigger output wired to the TANGO's snapshot input;
        manual chapter 23)."""
        return "On" if self._camera else "Off"

    @camera_sequence.setter  # type: ignore[no-redef]
    def camera_sequence(self, value: str) -> None:
        if value == "On" and getattr(self, "_sequencing", False):
            raise ValueError("switch 'Trigger sequence' off first: one kind of sequence "
                             "at a time")
        if value == "On" and self.controller.identity.family == "older":
            # The older edition steps on the key F2 only, without snsi or snse (old
            # L3113-3118, L3191-3227).
            raise NotSupportedByFirmwareError("snsi")
        self._camera = value == "On"

    @pymm_property(name="Sequence stopped at", is_read_only=True)
    def sequence_stopped_at(self) -> str:
        """Where the last camera-triggered sequence left the stage: its entry and the
        positions read ("" before the first stop)."""
        stopped = self._steps.stopped if self._steps is not None else None
        return "" if stopped is None else str(stopped)

    def _camera_steps(self) -> CameraSteps:
        if self._steps is None:
            self._steps = CameraSteps(self.hub, self._axes, self._moves)
        return self._steps

    def _camera_on(self) -> None:
        if not self._camera:
            raise RuntimeError("set the stage's 'Camera trigger sequence' property to 'On' "
                               "first (with the camera's trigger output on the TANGO's "
                               "snapshot input)")


def _by_axis(values: Mapping[str, Any]) -> dict[str, Any]:
    """Per-axis values as keyword arguments of the driver's calls."""
    return dict(values)


class TangoXYStage(_Axes, XYStageDevice):
    """Two axes of a TANGO (X and Y by default) as a Micro-Manager XY stage, in µm.

    :meth:`busy` is true from :meth:`set_position_um` until the driver's verdict that
    both axes stand at their targets; a move that ends short (limit switch, disabled
    axis, ...) makes the next call raise the driver's error, which says why.

    Parameters
    ----------
    hub
        The hub of the controller; ``None``: the initialised hub named by the device's
        parent label.
    x, y
        The controller's axes that move the stage's X and Y.
    """

    def __init__(self, hub: TangoHub | None = None, *, x: str = "x", y: str = "y") -> None:
        super().__init__(hub, (x, y))

    def set_position_um(self, x: float, y: float) -> None:
        """Start the move to ``(x, y)`` µm; returns at once, :meth:`busy` follows it.

        Parameters
        ----------
        x, y
            The target, in µm.
        """
        ax, ay = self._axes
        self._move_to({ax: x, ay: y})

    def set_relative_position_um(self, dx: float, dy: float) -> None:
        """Start a move by ``(dx, dy)`` µm.

        Parameters
        ----------
        dx, dy
            The distances, in µm.
        """
        ax, ay = self._axes
        self._move_by({ax: dx, ay: dy})

    def get_position_um(self) -> tuple[float, float]:
        """The position read now (``?pos``), in µm; never a target.

        Returns
        -------
        tuple[float, float]
            X and Y.
        """
        ax, ay = self._axes
        where = self._positions()
        return where[ax], where[ay]

    def set_origin_x(self) -> None:
        """Make the current X position 0."""
        self._zero(self._axes[0])

    def set_origin_y(self) -> None:
        """Make the current Y position 0."""
        self._zero(self._axes[1])

    def set_origin(self) -> None:
        """Make the current position (0, 0), in one line."""
        self._zero(*self._axes)

    def set_adapter_origin_um(self, x: float, y: float) -> None:
        """Make the current position ``(x, y)`` µm (on the controller, ``!pos``).

        Parameters
        ----------
        x, y
            The new coordinates of the current position, in µm.
        """
        ax, ay = self._axes
        self._call_position({ax: x, ay: y})

    def get_sequence_max_length(self) -> int:
        """The longest sequence: the snapshot array's 1024 entries (L14550); 0 while
        ``Camera trigger sequence`` is off.

        Returns
        -------
        int
            The length.
        """
        return STEPS_MAX_LENGTH if self._camera else 0

    def send_sequence(self, sequence: tuple[tuple[float, float], ...]) -> None:
        """Make ``sequence`` ((x, y) µm each) the stage's columns of the snapshot array
        (``!snsa``, in each axis's dim unit); checked before any byte.

        Parameters
        ----------
        sequence
            1..1024 positions.

        Raises
        ------
        ValueError
            A sequence the array cannot hold (nothing written).
        """
        self._camera_on()
        pairs = [tuple(pair) for pair in sequence]
        if any(len(pair) != 2 for pair in pairs):
            raise ValueError(f"an XY sequence holds (x, y) pairs, got {sequence!r}")
        self._camera_steps().load([[p[0] for p in pairs], [p[1] for p in pairs]])

    def start_sequence(self) -> None:
        """Move to the first position, then step to the next one on each trigger from
        the camera; :meth:`busy` until armed (see :class:`TangoZStage`)."""
        self._camera_on()
        self._camera_steps().start()

    def stop_sequence(self) -> None:
        """Stop stepping (see :class:`TangoZStage`): the stage stands, where it stands is
        ``Sequence stopped at``; a step that ended short raises its MoveError."""
        self._camera_steps().stop()


class TangoZStage(_Axes, StageDevice):
    """One axis of a TANGO (Z by default, or any) as a Micro-Manager stage, in µm; busy
    and errors as for :class:`TangoXYStage`.

    Sequenceable through the trigger position list (manual chapter 21): a sequence the
    core loads (``loadStageSequence``, ``setStageLinearSequence``) becomes the axis's
    list, and ``startStageSequence`` runs one move through it while the controller
    pulses its trigger output at each position (to trigger a camera); the stage sets the
    pace, not an incoming trigger. Off until the ``Trigger sequence`` property is ``On``:
    an acquisition engine that sequences z on its own (pymmcore-plus's does, whenever
    the focus stage says it can) would otherwise take free-running frames while the
    stage moves. The output's wiring (``trigo``, ``trigs``, ``trigl``) is the user's,
    set once with ``tango.triggers.write_config``.

    Sequenceable in Micro-Manager's convention too, through the snapshot array (manual
    chapter 23) while the ``Camera trigger sequence`` property is ``On``: the camera's
    trigger output drives the TANGO's snapshot input, ``startStageSequence`` moves the
    stage to the first position and arms step mode 5, and each trigger moves it to the
    next position (frame k is taken at position k when the camera triggers after each
    exposure and its frame interval outlasts a step). ``stopStageSequence`` switches the
    snapshot input off, lets a step under way end, and says where the stage stands
    (``Sequence stopped at``); a step that ended short raises its ``MoveError`` there.

    Parameters
    ----------
    hub
        The hub of the controller; ``None``: the initialised hub named by the device's
        parent label.
    axis
        The controller's axis.
    """

    def __init__(self, hub: TangoHub | None = None, *, axis: str = "z") -> None:
        super().__init__(hub, (axis,))
        self._run: tuple[float, float] | None = None
        self._sequencing = False

    def set_position_um(self, val: float) -> None:
        """Start the move to ``val`` µm; returns at once, :meth:`busy` follows it.

        Parameters
        ----------
        val
            The target, in µm.
        """
        self._move_to({self._axes[0]: val})

    def set_relative_position_um(self, d: float) -> None:
        """Start a move by ``d`` µm.

        Parameters
        ----------
        d
            The distance, in µm.
        """
        self._move_by({self._axes[0]: d})

    def get_position_um(self) -> float:
        """The position read now (``?pos``), in µm; never a target.

        Returns
        -------
        float
            The position.
        """
        return self._positions()[self._axes[0]]

    def set_origin(self) -> None:
        """Make the current position 0."""
        self._zero(self._axes[0])

    def set_adapter_origin_um(self, newZUm: float) -> None:
        """Make the current position ``newZUm`` µm (on the controller, ``!pos``).

        Parameters
        ----------
        newZUm
            The new coordinate of the current position, in µm.
        """
        self._call_position({self._axes[0]: newZUm})

    # -- sequences: the trigger position list -----------------------------------------------

    @pymm_property(name="Trigger sequence", allowed_values=("Off", "On"))
    def trigger_sequence(self) -> str:
        """Whether the stage offers the core sequences run through the trigger list (only
        for a camera triggered by the TANGO's trigger output)."""
        return "On" if self._sequencing else "Off"

    @trigger_sequence.setter  # type: ignore[no-redef]
    def trigger_sequence(self, value: str) -> None:
        if value == "On" and self._camera:
            raise ValueError("switch 'Camera trigger sequence' off first: one kind of "
                             "sequence at a time")
        self._sequencing = value == "On"

    def get_sequence_max_length(self) -> int:
        """The longest sequence: the trigger list's 10000 entries (L13515, L13773); 0
        while ``Trigger sequence`` is off.

        Returns
        -------
        int
            The length.
        """
        if self._camera:
            return STEPS_MAX_LENGTH
        return MAX_LENGTH if self._sequencing else 0

    def is_linear_sequenceable(self) -> bool:
        """A linear sequence is the manual's trigger range (``!trigr``, L13496-13600),
        while ``Trigger sequence`` is on.

        Returns
        -------
        bool
            Whether the core may load one.
        """
        return self._sequencing or self._camera

    def _in_dim(self, values: list[float]) -> list[float]:
        """``values`` µm in the axis's dim unit (the list's unit, L13773-13780)."""
        scale = self.controller.settings.unit_scales()[self._axes[0]]
        return [to_controller(value, UNIT, Measure.POSITION, scale) for value in values]

    def send_sequence(self, sequence: tuple[float, ...]) -> None:
        """Replace the axis's trigger position list with ``sequence`` µm (``!trigp``, in
        the axis's dim unit, at wire speed; L13767-13830). Checked before any byte.

        Parameters
        ----------
        sequence
            At least two positions, strictly increasing or decreasing.

        Raises
        ------
        ValueError
            A sequence the list cannot hold (nothing written).
        """
        if self._camera:
            self._camera_steps().load([sequence])
            return
        self._sequence_on()
        positions = [float(value) for value in sequence]
        run = run_through(positions)
        self._moves.check()
        self._run = None
        self.controller.triggers.upload_positions(self._in_dim(positions),
                                                  axis=self._axes[0])
        self._run = run

    def set_linear_sequence(self, dZ_um: float, nSlices: int) -> None:
        """Make the trigger list ``nSlices`` positions ``dZ_um`` apart from where the axis
        stands (``!trigr``: start, end, count, both ends included; L13496-13600).

        Parameters
        ----------
        dZ_um
            The step, in µm (its sign the direction).
        nSlices
            How many positions, at least two.

        Raises
        ------
        ValueError
            Fewer than two slices or no step (nothing written).
        """
        if not self._camera:
            self._sequence_on()
        if isinstance(nSlices, bool) or not isinstance(nSlices, int) or nSlices < 2:
            raise ValueError(f"a linear sequence has at least two slices, got {nSlices!r}")
        if not math.isfinite(float(dZ_um)) or float(dZ_um) == 0.0:
            raise ValueError(f"a linear sequence needs a finite, non-zero step, got {dZ_um!r}")
        here = self.get_position_um()
        if self._camera:
            self._camera_steps().load([[here + k * float(dZ_um) for k in range(nSlices)]])
            return
        run = run_through([here + k * float(dZ_um) for k in range(nSlices)])
        self._run = None
        start, end = self._in_dim([here, here + (nSlices - 1) * float(dZ_um)])
        self.controller.triggers.set_range(start, end, nSlices, axis=self._axes[0])
        self._run = run

    def _sequence_on(self) -> None:
        if not self._sequencing:
            raise RuntimeError("set the stage's 'Trigger sequence' property to 'On' first "
                               "(with a camera triggered by the TANGO's trigger output)")

    def start_sequence(self) -> None:
        """Start the run through the loaded sequence; returns at once, :meth:`busy` follows
        it: a move one step behind the first position, the trigger counter reset and the
        output switched on (``!trigcount 0``, ``!trig 1``), then a move one step past
        the last; the controller pulses at each position it passes.

        Raises
        ------
        RuntimeError
            No sequence loaded.
        """
        if self._camera:
            self._camera_steps().start()
            return
        if self._run is None:
            raise RuntimeError("no sequence loaded: loadStageSequence or "
                               "setStageLinearSequence first")
        self._start(run_sequence, self.controller.aio, self._axes[0], *self._run)

    def stop_sequence(self) -> None:
        """Stop a run still going (its axis stops, as :meth:`stop`), then switch the
        trigger output off (``!trig 0``); a camera-triggered one as described above."""
        if self._camera:
            self._camera_steps().stop()
            return
        running = self._moves.stopping()
        for move in running:
            move.cancel()
        if running:
            self.controller.stop(*self._axes)
        self.controller.triggers.set_enabled(False)
