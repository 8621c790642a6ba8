"""Sans-IO motion model of a TANGO controller (the emulator's "physics").

:class:`MotionModel` simulates 1..4 axes (x, y, z, a) in virtual time.  It never looks at
a clock: the caller moves time forward with :meth:`MotionModel.advance` and issues
commands in between; every command acts at :attr:`MotionModel.now` (the time of the last
``advance``).  :meth:`MotionModel.next_event_time` tells a scheduler when the next state
change happens, so it can sleep exactly until then.

Exactness
    All motion is piecewise constant acceleration (linear ramps, no s-curve) and is
    evaluated in closed form.  A trajectory is only replaced at a command or at an event
    time, and events (end of a ramp, switch reached, trigger position passed, timeout) are
    solved analytically on whole segments.  Advancing in one step or in many steps
    therefore yields bit-identical positions and events.

Units and frames
    Lengths are motor revolutions, velocities rev/s (see :mod:`tango_aio.units` for
    the conversion to ``dim`` units).  Three frames exist per axis:

    * physical: where the limit switches are (:class:`AxisConfig`); trajectories live here.
    * counter: the controller's internal position counter, ``physical - origin``.  ``cal``
      and ``zero``/``clearpos`` redefine the origin.  Soft limits are stored here, so
      ``zero`` does not move them ("internal limits will apply", manual L7012).
    * user: ``counter + offset``; ``!pos`` sets the offset, ``posclr`` clears it (L6900-6996).
      Every position that crosses the public API (positions, targets, limits, trigger
      positions) is in the user frame, in revolutions.

    At power-on the counter reads 0 at :attr:`AxisConfig.start_position`.

Decisions where the manual is silent (each is repeated next to its code):

* A move/cal/rm command for an axis that is still moving (or reserved by a pending
  ``delay``/``pause``) is refused with error 2 (the manual only allows ``go`` to be
  overwritten while travelling, L6606).  ``go`` and ``speed`` may replace each other.
  Firmware switch ``move_during_move`` (:attr:`MotionModel.move_during_move`): a move
  for busy axes may instead wait for them (``queue``) or take over the target of the axes
  that travel in a move (``retarget``); see :meth:`MotionModel._submit_move`.
* Firmware switches that the command layer sets: :attr:`MotionModel.abort_letter`
  (``E``, L6832-6834, or ``@`` of the older edition, old L1917) and
  :attr:`MotionModel.zero_move_report` (a move where no axis travels reports or not).
* Closed-loop settling: an axis with ``settle`` > 0 (closed loop on, the command layer
  sets it from ``ctrd``) delays its move's report by that time: "In closed loop mode the
  position reached reply is delayed until the specified criteria are fulfilled"
  (L11616-11631); the emulated axis has no deviation, so the ±twi window holds at once
  and the delay is exactly ``ctrd``.
* A target outside the soft limits is refused with error 5 ("number is not inside allowed
  range"; the manual names no number).  When the axis already is outside, targets between
  the axis and the allowed range are accepted (L4585-4589).
* A move that would drive deeper into an actuated, enabled limit switch is refused with
  error 12.  ``calrequired`` axes that are not calibrated refuse moves with error 22.
* Reaching an enabled switch stops only that axis (``stopaccel``), its letter is ``S``;
  the other axes of a vector move continue to their targets.  There is no mechanical end
  stop behind a switch.
* Disabled axes (``axis 0``/``-1``) are skipped by commands and report ``@`` in a
  completion string (manual cal example ``A@A-.``, L5336); ``status_letters`` shows ``-``
  for them (L2711).  Absent axes show ``-`` everywhere.
* ``delay`` and ``pause`` apply to moa/mor/m/moc only (L6845-6899), not to mol/cal/rm.
  An axis reads ``M`` during the delay and during the pause.  An aborted job reports as
  soon as its axes stand still (no pause); ``abort`` during a pause changes nothing.
* Abort sets the sticky status letter ``E`` also for go/speed axes.
* cal/rm run on all requested axes at the same time.  See :meth:`MotionModel.calibrate`.
* ``moc`` goes to the centre of the soft limits and does not require cal/rm (the manual
  only recommends them, L6518).  ``mol`` needs cal and a lock position
  (:attr:`AxisConfig.lock_position`); other axes report ``E`` and do not move.
* ``mor`` stores the distance only for the axes it names; ``m`` moves all enabled axes
  with a non-zero distance.
* scanmode 2 uses ``scanvel`` when at least two axes actually travel.
* ``statuslimit`` shows ``L`` only for limits set by ``!lim`` (L5175).
* ``modulomode``, ``accelfunc`` (s-curves), ``velfac``, joystick/HDI, encoders and closed
  loop are not modelled.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Literal

from tango_aio.units import DEFAULT_USTEPS, UnitScale

from .lists import MAX_TRIGGERS

__all__ = [
    "AXIS_NAMES",
    "ERR_INVALID_AXIS",
    "ERR_LIMIT_SWITCH",
    "ERR_MOVE_NOT_ALLOWED",
    "ERR_NOT_EXECUTABLE",
    "ERR_OUT_OF_RANGE",
    "AxisConfig",
    "AxisRef",
    "AxisSettings",
    "GlobalSettings",
    "JobKind",
    "MotionConfig",
    "MotionEvent",
    "MotionModel",
    "MotionRefused",
    "MoveFinished",
    "Phase",
    "Segment",
    "Trajectory",
    "TriggerFired",
    "plan_stop",
    "plan_to_target",
    "plan_velocity",
]

AXIS_NAMES = "xyza"
"""Axis letters in controller order; an axis index is the position in this string."""

ERR_INVALID_AXIS = 1
"""Controller error 1: no valid axis name (axis not present)."""
ERR_NOT_EXECUTABLE = 2
"""Controller error 2: no executable instruction (axis busy, vrm without cal)."""
ERR_OUT_OF_RANGE = 5
"""Controller error 5: number not inside allowed range (soft limits, bad values)."""
ERR_LIMIT_SWITCH = 12
"""Controller error 12: limit switch active (move deeper into an actuated switch)."""
ERR_MOVE_NOT_ALLOWED = 22
"""Controller error 22: move not allowed (``calrequired`` and not calibrated)."""

AxisRef = int | str
"""An axis given as index 0..3 or as letter ``x``/``y``/``z``/``a``."""

JobKind = Literal["move", "cal", "rm"]
"""What produced a completion string: a move (``@``), cal (``A``) or rm (``D``)."""

_Mode = Literal["idle", "move", "go", "speed", "cal", "rm", "halt"]
_CalPhase = Literal["approach", "brake", "release", "settle"]

_PLAN_TOL = 1e-12  # relative tolerance for "stopping distance equals remaining distance"
_LIMIT_TOL = 1e-9  # relative tolerance for soft-limit checks (unit round trips)
_MAX_EVENTS_PER_ADVANCE = 10_000_000

# Event priorities when several things happen at exactly the same time.  A switch reached
# at the very end of a move wins over the normal stop, so the axis reports 'S'.
_P_START = 0
_P_CROSS = 1
_P_TRIGGER = 2
_P_STOP = 3
_P_REPORT = 4


class MotionRefused(Exception):
    """A command was not executed; ``code`` is the controller error number to report."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(f"error {code}: {message}")
        self.code = code
        self.message = message


# --------------------------------------------------------------------------------------
# Events
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MoveFinished:
    """A move, cal or rm job finished; ``letters`` holds one status letter per axis X Y Z A.

    Letters: ``@`` done, ``A`` calibrated, ``D`` range measured, ``E`` aborted/not executed,
    ``S`` stopped by a limit switch, ``T`` cal/rm timeout, ``-`` axis not present.  The
    command layer appends the ``.`` of the autostatus string.
    """

    time: float
    kind: JobKind
    letters: str
    job_id: int


@dataclass(frozen=True, slots=True)
class TriggerFired:
    """The trigger axis passed entry ``index`` (1-based) of the trigger list."""

    time: float
    axis: int
    index: int
    position: float


MotionEvent = MoveFinished | TriggerFired
"""Any event returned by :meth:`MotionModel.advance`."""


# --------------------------------------------------------------------------------------
# Configuration and settings
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class AxisConfig:
    """Static physical description of one axis (motor revolutions, physical frame).

    With the default pitch of 1 mm/rev the defaults are a 100 mm axis with switches at
    -50 mm (E0, cal) and +50 mm (EE, rm) and the power-on position in the middle.
    ``lock_position`` is the transport lock position for ``mol`` in the counter frame
    (as stored in the ETS, relative to the cal origin); ``None`` means none stored.
    """

    e0_position: float = -50.0
    ee_position: float = 50.0
    start_position: float = 0.0
    lock_position: float | None = None


@dataclass(frozen=True, slots=True)
class MotionConfig:
    """Static configuration of the simulated controller."""

    n_axes: int = 3
    axes: tuple[AxisConfig, ...] = (AxisConfig(), AxisConfig(), AxisConfig(), AxisConfig())
    maxpos_mm: float = 2600.0
    """Maximum position range ±maxpos in mm (``?maxpos`` → 2600, L1586)."""


@dataclass(slots=True)
class AxisSettings:
    """Per-axis parameters (mutable; the command layer writes them).

    Units: lengths in motor revolutions, ``vel``/``calvel``/``rmvel`` in rev/s,
    ``accel``/``stopaccel`` in m/s², ``secvel`` in mm/s, ``calbspeed`` in 1/100 rev/s,
    ``caltimeout`` in s.  Change ``vel`` through :meth:`MotionModel.set_vel` so that a
    running ``go`` picks it up.  The manual gives no defaults for vel/accel/stopaccel/
    calbspeed; these match the emulator's parameter store (:mod:`tango_aio.sim.params`).
    """

    enable: int = 1
    """``axis``: 1 enabled, 0 disabled, -1 power stage off."""
    dim: int = 2
    pitch: float = 1.0
    gear: float = 1.0
    vel: float = 10.0
    accel: float = 1.0
    stopaccel: float = 1.0
    secvel: float = 10.0
    calbspeed: float = 32.0
    calvel: tuple[float, float] = (10.0, 0.5)
    rmvel: tuple[float, float] = (10.0, 0.5)
    caltimeout: float = 40.0
    swact: tuple[int, int, int] = (1, 0, 1)
    """Switch enables E0, REF (unused), EE."""
    nosetlimit: int = 0
    caliboffset: float = 0.0
    rmoffset: float = 0.0
    calmode: int = 0
    calrequired: int = 0
    limctr: int = 1
    distance: float = 0.0
    """Distance for ``m`` (also written by ``mor``)."""
    settle: float = 0.0
    """Closed-loop settling time in seconds added before a move's report (0: open loop)."""
    modulomode: int = 0
    """Stored for read-back only; modulo positioning is not modelled."""


@dataclass(slots=True)
class GlobalSettings:
    """Parameters with one value for all axes."""

    usteps: int = DEFAULT_USTEPS
    scanmode: int = 0
    scanvel: float = 10.0
    """Vector velocity in mm/s for scanmode 1/2 (no documented default)."""
    pause_ms: float = 0.0
    delay_ms: float = 0.0
    extmode: int = 0


# --------------------------------------------------------------------------------------
# Closed-form trajectories
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Phase:
    """A piece of constant acceleration: start velocity and acceleration for a duration."""

    duration: float
    v0: float
    accel: float

    def scaled(self, factor: float) -> Phase:
        """Return the phase with velocity and acceleration multiplied by ``factor``."""
        return Phase(self.duration, self.v0 * factor, self.accel * factor)


@dataclass(frozen=True, slots=True)
class Segment:
    """A timed phase.  Segments never reverse direction inside (they are monotonic)."""

    t0: float
    t1: float
    x0: float
    x1: float
    v0: float
    accel: float

    @property
    def direction(self) -> float:
        """+1 for increasing position, -1 for decreasing (0 for a standstill)."""
        if self.v0 != 0.0:
            return math.copysign(1.0, self.v0)
        return math.copysign(1.0, self.accel) if self.accel != 0.0 else 0.0

    def position(self, t: float) -> float:
        """Position at time ``t`` (``t0 <= t <= t1``)."""
        dt = t - self.t0
        return self.x0 + dt * (self.v0 + 0.5 * self.accel * dt)

    def velocity(self, t: float) -> float:
        """Velocity at time ``t`` (``t0 <= t <= t1``)."""
        return self.v0 + self.accel * (t - self.t0)

    def time_at(self, level: float) -> float:
        """Time at which the segment reaches ``level`` (which must lie on the segment)."""
        if level == self.x1:
            return self.t1
        sign = self.direction
        dist = max((level - self.x0) * sign, 0.0)
        u = self.v0 * sign
        root = math.sqrt(max(u * u + 2.0 * self.accel * sign * dist, 0.0))
        denom = u + root
        tau = 2.0 * dist / denom if denom > 0.0 else 0.0
        return min(self.t0 + tau, self.t1)


@dataclass(frozen=True, slots=True)
class Trajectory:
    """Position over time: monotonic segments, then rest at :attr:`end_pos`."""

    start_time: float
    start_pos: float
    segments: tuple[Segment, ...] = ()

    @staticmethod
    def rest(t: float, x: float) -> Trajectory:
        """A trajectory standing still at ``x`` from ``t`` on."""
        return Trajectory(t, x)

    @staticmethod
    def from_phases(
        t: float, x: float, phases: Iterable[Phase], end_pos: float | None = None
    ) -> Trajectory:
        """Chain ``phases`` starting at ``(t, x)``; snap the final position to ``end_pos``.

        Snapping removes rounding so a move ends exactly on its target."""
        segs: list[Segment] = []
        t_cur, x_cur = t, x
        for ph in phases:
            if not ph.duration > 0.0:
                continue
            t1 = t_cur + ph.duration
            if math.isinf(ph.duration):
                x1 = math.copysign(math.inf, ph.v0)
            else:
                x1 = x_cur + ph.duration * (ph.v0 + 0.5 * ph.accel * ph.duration)
            segs.append(Segment(t_cur, t1, x_cur, x1, ph.v0, ph.accel))
            t_cur, x_cur = t1, x1
        if end_pos is not None and segs and math.isfinite(segs[-1].t1):
            segs[-1] = replace(segs[-1], x1=end_pos)
        return Trajectory(t, x, tuple(segs))

    @property
    def end_time(self) -> float:
        """Time at which the motion ends (``inf`` for endless constant velocity)."""
        return self.segments[-1].t1 if self.segments else self.start_time

    @property
    def end_pos(self) -> float:
        """Final rest position."""
        return self.segments[-1].x1 if self.segments else self.start_pos

    def position(self, t: float) -> float:
        """Position at time ``t``."""
        for seg in self.segments:
            if t < seg.t1:
                return seg.position(t) if t > seg.t0 else seg.x0
        return self.end_pos

    def velocity(self, t: float) -> float:
        """Velocity at time ``t`` (0 after the end)."""
        for seg in self.segments:
            if t < seg.t1:
                return seg.velocity(max(t, seg.t0))
        return 0.0

    def first_entry(
        self, level: float, *, upward: bool, closed: bool, t_min: float
    ) -> float | None:
        """First time >= ``t_min`` at which the position enters a half line.

        The region is ``x >= level`` (``upward``, ``closed``), ``x > level`` (``upward``,
        open), ``x <= level`` or ``x < level``.  Entering means: the segment starts outside
        and ends inside, so touching the boundary from inside never counts twice."""

        def inside(x: float) -> bool:
            if upward:
                return x >= level if closed else x > level
            return x <= level if closed else x < level

        for seg in self.segments:
            if seg.t1 < t_min or inside(seg.x0) or not inside(seg.x1):
                continue
            t = seg.time_at(level)
            if t >= t_min:
                return t
        return None


def _forward(u: float, dist: float, vmax: float, amax: float) -> list[Phase]:
    """Phases covering ``dist >= 0`` forward from speed ``u >= 0``, ending at rest.

    The caller guarantees that the stopping distance ``u²/2a`` fits into ``dist``."""
    if u == 0.0 and dist <= 0.0:
        return []
    if u > vmax:  # slow down to vmax first, then cruise and stop
        cruise = max(dist - u * u / (2.0 * amax), 0.0) / vmax
        return [
            Phase((u - vmax) / amax, u, -amax),
            Phase(cruise, vmax, 0.0),
            Phase(vmax / amax, vmax, -amax),
        ]
    peak = max(u, min(vmax, math.sqrt(amax * dist + 0.5 * u * u)))
    cruise_dist = dist - (2.0 * peak * peak - u * u) / (2.0 * amax)
    return [
        Phase((peak - u) / amax, u, amax),
        Phase(max(cruise_dist, 0.0) / peak, peak, 0.0),
        Phase(peak / amax, peak, -amax),
    ]


def plan_to_target(x0: float, v0: float, target: float, vmax: float, amax: float) -> list[Phase]:
    """Time-optimal linear-ramp profile from ``(x0, v0)`` to rest at ``target``.

    Trapezoidal (or triangular when short) from rest; from a moving start it first brakes
    when heading away or when it cannot stop in time (and comes back), or slows down to
    ``vmax`` when faster.  Used for moves (in normalised form), ``go`` and ``speed``."""
    if not (vmax > 0.0 and amax > 0.0):
        raise ValueError(f"vmax and amax must be positive, got {vmax!r}, {amax!r}")
    delta = target - x0
    # At the target but still moving: brake and come back.
    sign = math.copysign(1.0, delta) if delta != 0.0 else (-1.0 if v0 > 0.0 else 1.0)
    dist, u = abs(delta), v0 * sign
    norm: list[Phase] = []
    if u < 0.0:  # heading away: brake to a standstill first
        norm.append(Phase(-u / amax, u, amax))
        dist += u * u / (2.0 * amax)
        u = 0.0
    stop = u * u / (2.0 * amax)
    tol = _PLAN_TOL * max(1.0, dist)
    if stop > dist + tol:  # cannot stop in time: overshoot and come back
        norm.append(Phase(u / amax, u, -amax))
        back = _forward(0.0, stop - dist, vmax, amax)
        return [p.scaled(sign) for p in norm] + [p.scaled(-sign) for p in back]
    if u > 0.0 and stop >= dist - tol:  # just brake
        norm.append(Phase(u / amax, u, -amax))
    else:
        norm.extend(_forward(u, dist, vmax, amax))
    return [p.scaled(sign) for p in norm if p.duration > 0.0]


def plan_velocity(v0: float, v_target: float, amax: float) -> list[Phase]:
    """Ramp from ``v0`` to ``v_target`` at ``amax``; endless cruise if ``v_target != 0``."""
    phases: list[Phase] = []
    if v0 * v_target < 0.0:  # reverse: brake to zero first (keeps segments monotonic)
        phases.append(Phase(abs(v0) / amax, v0, -math.copysign(amax, v0)))
        v0 = 0.0
    if v_target != v0:
        phases.append(Phase(abs(v_target - v0) / amax, v0, math.copysign(amax, v_target - v0)))
    if v_target != 0.0:
        phases.append(Phase(math.inf, v_target, 0.0))
    return phases


def plan_stop(v0: float, decel: float) -> list[Phase]:
    """Brake from ``v0`` to a standstill at ``decel``."""
    return plan_velocity(v0, 0.0, decel)


# --------------------------------------------------------------------------------------
# Internal state
# --------------------------------------------------------------------------------------


@dataclass(eq=False)
class _Job:
    """A command that ends with one completion string (moa/mor/m/moc/mol, cal, rm)."""

    id: int
    kind: JobKind
    letters: dict[int, str] = field(default_factory=dict)
    targets: dict[int, float] = field(default_factory=dict)
    running: set[int] = field(default_factory=set)
    pause: float = 0.0
    start_time: float | None = None
    report_time: float | None = None
    aborted: bool = False
    #: Longest closed-loop settling time of its axes (seconds).
    settle: float = 0.0
    #: ``move_during_move=queue``: waiting for its axes to stop; ``relative`` distances
    #: are turned into targets when it starts.
    waiting: bool = False
    relative: dict[int, float] | None = None
    delay: float = 0.0


@dataclass(eq=False)
class _AxisState:
    index: int
    config: AxisConfig
    settings: AxisSettings
    traj: Trajectory
    origin: float
    mode: _Mode = "idle"
    phase: _CalPhase = "approach"
    job: _Job | None = None
    letter: str = "@"
    halt_letter: str = "@"
    go_target: float | None = None
    offset: float = 0.0
    lim_lo: float | None = None
    lim_hi: float | None = None
    lim_lo_set: bool = False
    lim_hi_set: bool = False
    cal_done: bool = False
    rm_done: bool = False
    cal_counter: float = 0.0
    deadline: float | None = None


@dataclass(eq=False)
class _TriggerList:
    axis: int
    levels: tuple[float, ...]
    increasing: bool
    index: int = 0


@dataclass(frozen=True, slots=True)
class _Action:
    time: float
    priority: int
    key: int
    run: Callable[[float], None]


# --------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------


class MotionModel:
    """Deterministic virtual-time motion model of a TANGO controller (see module doc)."""

    def __init__(self, config: MotionConfig | None = None, *, start_time: float = 0.0) -> None:
        self._config = config if config is not None else MotionConfig()
        n = self._config.n_axes
        if not 1 <= n <= 4 or len(self._config.axes) < n:
            raise ValueError(f"n_axes must be 1..4 with an AxisConfig each, got {n}")
        self._time = start_time
        self.global_settings = GlobalSettings()
        """Global parameters (scanmode, scanvel, pause, delay, usteps, extmode)."""
        self._axes = [
            _AxisState(i, cfg, AxisSettings(), Trajectory.rest(start_time, cfg.start_position),
                       origin=cfg.start_position)
            for i, cfg in enumerate(self._config.axes[:n])
        ]
        self._jobs: list[_Job] = []
        self._next_job_id = 1
        self._trigger: _TriggerList | None = None
        self._trigger_count = 0
        self._out: list[MotionEvent] = []
        self.abort_letter = "E"
        """Letter of axes stopped by ``a`` or Ctrl+C (firmware switch ``abort_letter``)."""
        self.move_during_move = "refuse"
        """``refuse``, ``queue`` or ``retarget`` a move for busy axes (firmware switch)."""
        self.zero_move_report = True
        """Whether a move where no axis travels reports (firmware switch)."""

    # ---------------------------------------------------------------- time ----------

    @property
    def now(self) -> float:
        """Current virtual time in seconds (time of the last :meth:`advance`)."""
        return self._time

    @property
    def n_axes(self) -> int:
        """Number of axes present."""
        return len(self._axes)

    def advance(self, now: float) -> list[MotionEvent]:
        """Move time forward to ``now``; return the events up to ``now`` in time order."""
        if now < self._time:
            raise ValueError(f"time must not go backwards ({now!r} < {self._time!r})")
        self._out = []
        for _ in range(_MAX_EVENTS_PER_ADVANCE):
            action = self._next_action()
            if action is None or action.time > now:
                break
            self._time = max(self._time, action.time)
            action.run(self._time)
        else:  # pragma: no cover - safety net against a handler that makes no progress
            raise RuntimeError("motion model made no progress")
        self._time = now
        return self._out

    def next_event_time(self) -> float | None:
        """Exact time of the next state change (move end, pause, trigger ...), or None."""
        action = self._next_action()
        return action.time if action is not None else None

    # ---------------------------------------------------------------- units ---------

    def settings(self, axis: AxisRef) -> AxisSettings:
        """Live per-axis parameters of ``axis``."""
        return self._axis(axis).settings

    def units(self, axis: AxisRef) -> UnitScale:
        """Unit conversion of ``axis`` for its current dim/pitch/gear and ``usteps``."""
        s = self._axis(axis).settings
        return UnitScale(s.dim, s.pitch, s.gear, self.global_settings.usteps)

    def to_user(self, axis: AxisRef, value: float) -> float:
        """Convert a position/distance in revolutions to the axis's ``dim`` unit."""
        return self.units(axis).pos_to_user(value)

    def from_user(self, axis: AxisRef, value: float) -> float:
        """Convert a position/distance in the axis's ``dim`` unit to revolutions."""
        return self.units(axis).pos_from_user(value)

    def vel_to_user(self, axis: AxisRef, value: float) -> float:
        """Convert rev/s to the axis's velocity unit (mm/s in dim 9)."""
        return self.units(axis).vel_to_user(value)

    def vel_from_user(self, axis: AxisRef, value: float) -> float:
        """Convert the axis's velocity unit (mm/s in dim 9) to rev/s."""
        return self.units(axis).vel_from_user(value)

    # ---------------------------------------------------------------- queries -------

    def position(self, axis: AxisRef) -> float:
        """User-frame position in revolutions (what ``?pos`` shows, before unit scaling)."""
        ax = self._axis(axis)
        return self._user_frame(ax, self._phys(ax))

    def velocity(self, axis: AxisRef) -> float:
        """Momentary signed velocity in rev/s (``?isvel``, ``?speed``)."""
        ax = self._axis(axis)
        return ax.traj.velocity(self._time) if ax.mode != "idle" else 0.0

    def observe(self, axis: AxisRef, t: float) -> tuple[float, float]:
        """Where the axis is at time ``t`` (not before the model's own time), without
        advancing the model: ``(position in its dim unit, velocity in rev/s)``. For an
        observer (a test's assertion) that must not change when the model steps."""
        ax = self._axis(axis)
        t = max(t, self._time)
        revs = self._user_frame(ax, ax.traj.position(t))
        return self.to_user(axis, revs), ax.traj.velocity(t)

    def is_moving(self, axis: AxisRef) -> bool:
        """True while the axis status letter is ``M`` (moving, delayed start or pause)."""
        return self._busy(self._axis(axis))

    def status_letter(self, axis: AxisRef) -> str:
        """Status letter of one axis for ``?statusaxis``."""
        ax = self._axis(axis)
        if ax.settings.enable != 1:
            return "-"
        if self._busy(ax):
            return "M"
        if ax.letter == "@" and self._switch_blocks(ax):
            return "S"
        return ax.letter

    def status_letters(self) -> str:
        """Four status letters X Y Z A (``-`` for absent or disabled axes)."""
        return "".join(self.status_letter(i) if i < self.n_axes else "-" for i in range(4))

    def calst(self, axis: AxisRef) -> int:
        """``calst`` bits: 1 = cal done, 2 = rm (or vrm) done."""
        ax = self._axis(axis)
        return (1 if ax.cal_done else 0) | (2 if ax.rm_done else 0)

    def statuslimit(self) -> str:
        """16 characters: cal ``A`` ×4, rm ``D`` ×4, lower ``L`` ×4, upper ``L`` ×4."""
        axes: list[_AxisState | None] = [*self._axes, *[None] * (4 - self.n_axes)]

        def group(char: str, test: Callable[[_AxisState], bool]) -> str:
            return "".join(char if ax is not None and test(ax) else "-" for ax in axes)

        return (
            group("A", lambda a: a.cal_done)
            + group("D", lambda a: a.rm_done)
            + group("L", lambda a: a.lim_lo_set)
            + group("L", lambda a: a.lim_hi_set)
        )

    def is_released(self, axis: AxisRef) -> bool:
        """True when ``secvel`` no longer caps the axis.

        Rule (L3627-3641, L4944): every *enabled* switch must have been used, E0 by cal and
        EE by rm/vrm.  No switch → never capped; only E0 → after cal; both → cal and rm.
        Only EE enabled (not covered by the manual) → after rm."""
        ax = self._axis(axis)
        e0, _, ee = ax.settings.swact
        return (not e0 or ax.cal_done) and (not ee or ax.rm_done)

    def switch_state(self, axis: AxisRef) -> tuple[bool, bool]:
        """Raw physical state of the (E0, EE) switches, ignoring ``swact``."""
        ax = self._axis(axis)
        x = self._phys(ax)
        return x <= ax.config.e0_position, x >= ax.config.ee_position

    def limits(self, axis: AxisRef) -> tuple[float, float]:
        """Soft limits (lower, upper) in the user frame; unset limits read ±maxpos."""
        ax = self._axis(axis)
        lo, hi = self._stored_limits(ax)
        return self._user_frame(ax, lo), self._user_frame(ax, hi)

    def position_offset(self, axis: AxisRef) -> float:
        """Offset added by ``!pos`` (``?posclr``): user position minus counter."""
        return self._axis(axis).offset

    # ---------------------------------------------------------------- settings ------

    def set_vel(self, axis: AxisRef, vel: float) -> None:
        """Set ``vel`` (rev/s).  A running ``go`` adopts it at once; 0 ends a go.

        ``vel 0`` is not stored (the documented range starts at 0.000001): it only stops a
        running go (L3495), and is refused with error 5 when no go runs."""
        ax = self._axis(axis)
        if vel < 0.0 or (vel == 0.0 and ax.mode != "go"):
            raise MotionRefused(ERR_OUT_OF_RANGE, f"vel {vel!r} out of range")
        if vel == 0.0:
            self._stop_continuous(ax)
            return
        ax.settings.vel = vel
        if ax.mode == "go" and ax.go_target is not None:
            self._plan_go(ax)

    def set_limits(self, axis: AxisRef, lower: float | None, upper: float | None) -> None:
        """``!lim``: set soft limits in the user frame (``None`` keeps that limit)."""
        ax = self._axis(axis)
        cur_lo, cur_hi = self.limits(axis)
        new_lo = cur_lo if lower is None else lower
        new_hi = cur_hi if upper is None else upper
        if new_lo > new_hi:
            raise MotionRefused(ERR_OUT_OF_RANGE, f"lower limit {new_lo} > upper {new_hi}")
        if lower is not None:
            ax.lim_lo, ax.lim_lo_set = lower - ax.offset, True
        if upper is not None:
            ax.lim_hi, ax.lim_hi_set = upper - ax.offset, True

    def set_position(self, axis: AxisRef, value: float) -> None:
        """``!pos``: redefine the current user position (changes only the offset)."""
        ax = self._axis(axis)
        ax.offset = value - (self._phys(ax) - ax.origin)

    def displace(self, axis: AxisRef, revs: float) -> bool:
        """Move a standing axis by ``revs`` at once, as a hand on the HDI would (joystick,
        handwheel)."""
        ax = self._axis(axis)
        if ax.mode != "idle":
            return False
        ax.traj = Trajectory.rest(self._time, self._phys(ax) + revs)
        return True

    def clear_position_offset(self, axis: AxisRef) -> None:
        """``!posclr``: remove the ``!pos`` offset."""
        self._axis(axis).offset = 0.0

    def zero(self, axis: AxisRef) -> None:
        """``!zero``/``!clearpos``: counter and position become 0 here; limits stay numeric."""
        ax = self._axis(axis)
        ax.origin = self._phys(ax)
        ax.offset = 0.0

    def set_distance(self, axis: AxisRef, distance: float) -> None:
        """``!distance``: set the ``m`` distance of one axis (revolutions)."""
        self._axis(axis).settings.distance = distance

    # ---------------------------------------------------------------- moves ---------

    def move_absolute(self, targets: Mapping[AxisRef, float]) -> int:
        """``moa``: vector move to user-frame targets; returns the job id."""
        phys = {}
        for ref, target in targets.items():
            ax = self._axis(ref)
            phys[ax.index] = target + ax.origin - ax.offset
        return self._submit_move(phys, timed=True)

    def move_relative(self, distances: Mapping[AxisRef, float]) -> int:
        """``mor``: vector move by distances; stores them as ``m`` distances."""
        resolved = {self._axis(ref).index: d for ref, d in distances.items()}
        phys = {i: self._end_pos(self._axes[i]) + d for i, d in resolved.items()}
        job_id = self._submit_move(phys, timed=True, relative=resolved)
        # Choice: only the named axes get a new distance; the others keep theirs.
        for i, d in resolved.items():
            self._axes[i].settings.distance = d
        return job_id

    def move_repeat(self) -> int:
        """``m``: relative vector move by the stored distances of all enabled axes."""
        distances = {ax.index: ax.settings.distance for ax in self._axes
                     if ax.settings.enable == 1 and ax.settings.distance != 0.0}
        phys = {i: self._end_pos(self._axes[i]) + d for i, d in distances.items()}
        return self._submit_move(phys, timed=True, relative=distances)

    def move_center(self, axes: Iterable[AxisRef] | None = None) -> int:
        """``moc``: move to the centre between the soft limits (cal+rm recommended)."""
        phys = {}
        for ax in self._select(axes):
            lo, hi = self._stored_limits(ax)
            phys[ax.index] = 0.5 * (lo + hi)
        return self._submit_move(phys, timed=True)

    def move_lock(self, axes: Iterable[AxisRef] | None = None) -> int:
        """``mol``: move to the transport lock position (needs cal and a lock position).

        Axes without cal or without a lock position do not move and report ``E``; mol has
        no delay and no pause (the manual lists moa/mor/m/moc only)."""
        phys: dict[int, float] = {}
        failed: list[int] = []
        for ax in self._select(axes):
            lock = ax.config.lock_position
            if ax.cal_done and lock is not None and lock > 0.0:
                phys[ax.index] = ax.origin + lock
            else:
                failed.append(ax.index)
        return self._submit_move(phys, timed=False, failed=failed)

    def go(self, targets: Mapping[AxisRef, float]) -> None:
        """``go``: independent absolute moves (own vel/accel), re-targetable, no report."""
        plan: list[tuple[_AxisState, float]] = []
        for ref, target in targets.items():
            ax = self._axis(ref)
            if ax.settings.enable != 1:
                continue
            phys = target + ax.origin - ax.offset
            self._check_continuous(ax)
            self._check_target(ax, phys)
            self._check_switch(ax, phys - self._phys(ax))
            plan.append((ax, phys))
        for ax, phys in plan:
            self._begin_continuous(ax, "go")
            ax.go_target = phys
            self._plan_go(ax)

    def go_stop(self, axes: Iterable[AxisRef] | None = None) -> None:
        """``go`` without target: stop go/speed motion of the axes at normal accel."""
        for ax in self._select(axes):
            self._stop_continuous(ax)

    def speed(self, velocities: Mapping[AxisRef, float]) -> None:
        """``speed``: constant signed velocity (rev/s); 0 stops speed or go; no report.

        The axis brakes so that it stops exactly at the soft limit ahead (or travels on
        without limit when ``limctr`` is 0); an enabled switch stops it with ``S``."""
        plan: list[tuple[_AxisState, float]] = []
        for ref, vel in velocities.items():
            ax = self._axis(ref)
            if ax.settings.enable != 1:
                continue
            if vel != 0.0:
                self._check_continuous(ax)
                self._check_switch(ax, vel)
            plan.append((ax, vel))
        for ax, vel in plan:
            if vel == 0.0:
                self._stop_continuous(ax)
            else:
                self._begin_continuous(ax, "speed")
                self._plan_speed(ax, vel)

    def abort(self, axis: AxisRef | None = None, *, use_accel: bool = False) -> None:
        """``a`` / ``a x`` / ``a -1``: stop with stopaccel (or accel); letters become ``E``
        (:attr:`abort_letter`). Queued moves of the stopped axes are cancelled: they
        report :attr:`abort_letter` for their axes at once."""
        chosen = self._select(None if axis is None else [axis], enabled_only=False)
        for ax in chosen:
            self._abort_axis(ax, use_accel)
        stopped = {ax.index for ax in chosen}
        for job in [j for j in self._jobs if j.waiting and stopped & set(j.targets)]:
            job.waiting = False
            job.aborted = True
            job.letters = {i: self.abort_letter for i in job.targets}
            job.targets = {}
            job.report_time = self._time

    def mark_not_executed(self, axes: Iterable[AxisRef]) -> None:
        """A move for ``axes`` was refused: idle axes show ``E`` ("not executed", L2705)."""
        for ref in axes:
            ax = self._axis(ref)
            if not self._busy(ax) and ax.settings.enable == 1:
                ax.letter = "E"

    def has_job(self, job_id: int) -> bool:
        """Whether job ``job_id`` still owes its report."""
        return any(job.id == job_id for job in self._jobs)

    def emergency_stop(self) -> None:
        """Ctrl+C (0x03): abort all axes with stopaccel."""
        self.abort()

    # ---------------------------------------------------------------- cal / rm ------

    def calibrate(self, axes: Iterable[AxisRef] | None = None) -> int:
        """``cal``: find E0 on the axes (all enabled when None); returns the job id.

        Sequence per axis (all axes at the same time): travel towards E0 at ``vel``
        (extmode 1: ``calvel[0]``), capped by ``secvel`` unless released; at the switch brake
        with ``stopaccel``; leave it at ``calbspeed``/100 rev/s (extmode 1: ``calvel[1]``);
        once free travel on to ``max(caliboffset, stopping distance)`` beyond the switch
        point at the approach speed and stop.  That stop becomes the origin (calmode 0/2,
        the ``!pos`` offset is cleared) and, with ``nosetlimit`` 0, the lower soft limit.
        Letter ``A``; ``T`` when ``caltimeout`` (counted from the command) runs out first;
        ``E`` when aborted.  With E0 disabled by ``swact`` nothing happens and the axis
        reports ``@``.  Cal/rm flags change only on success."""
        return self._submit_cal("cal", axes)

    def range_measure(self, axes: Iterable[AxisRef] | None = None) -> int:
        """``rm``: like :meth:`calibrate` towards EE; sets the upper limit, letter ``D``."""
        return self._submit_cal("rm", axes)

    def virtual_range_measure(self, lengths: Mapping[AxisRef, float]) -> None:
        """``vrm``: declare axis lengths without moving (needs cal, else error 2).

        Marks rm as done (releases secvel, statuslimit ``D``) and, with ``nosetlimit`` 0,
        sets the upper limit to the cal position plus the length (manual example 2, L5518)."""
        resolved = [(self._axis(ref), length) for ref, length in lengths.items()]
        for ax, _ in resolved:
            if not ax.cal_done:
                raise MotionRefused(ERR_NOT_EXECUTABLE, f"vrm: axis {ax.index} not calibrated")
        for ax, length in resolved:
            ax.rm_done = True
            if not ax.settings.nosetlimit:
                ax.lim_hi = ax.cal_counter + length

    # ---------------------------------------------------------------- triggers ------

    @property
    def trigger_count(self) -> int:
        """``?trigcount``: number of trigger positions passed so far."""
        return self._trigger_count

    def set_trigger_count(self, value: int = 0) -> None:
        """``!trigcount n``: set (usually clear) the trigger counter."""
        self._trigger_count = value

    def trigger_index(self) -> int:
        """``?trigi``: 1-based index of the next trigger entry (N+1 when all passed; 0 = none)."""
        return self._trigger.index + 1 if self._trigger is not None else 0

    def set_trigger_positions(self, axis: AxisRef, positions: Sequence[float]) -> None:
        """``trigp`` list: user-frame positions, monotonic; an empty list disarms.

        Positions are fixed in the physical frame when set (a later ``!pos`` does not move
        them).  An entry fires when the axis reaches it travelling in list direction; the
        list re-arms when the axis goes back strictly behind the first entry.  With one
        entry the direction follows from the current position (L13814)."""
        ax = self._axis(axis)
        if not positions:
            self._trigger = None
            return
        levels = tuple(p + ax.origin - ax.offset for p in positions)
        steps = [b - a for a, b in itertools.pairwise(levels)]
        if any(s < 0 for s in steps) and any(s > 0 for s in steps):
            raise MotionRefused(ERR_OUT_OF_RANGE, "trigger positions must be monotonic")
        first_step = next((s for s in steps if s != 0.0), None)
        increasing = first_step > 0 if first_step is not None else levels[0] >= self._phys(ax)
        self._trigger = _TriggerList(ax.index, levels, increasing)

    def set_trigger_range(self, axis: AxisRef, start: float, end: float, count: int) -> None:
        """``trigr``: ``count`` equidistant triggers from ``start`` to ``end`` inclusive."""
        if not 1 <= count <= MAX_TRIGGERS:
            raise MotionRefused(ERR_OUT_OF_RANGE, f"trigger count {count} not in 1..{MAX_TRIGGERS}")
        if count == 1 or start == end:
            self.set_trigger_positions(axis, [start])
            return
        step = (end - start) / (count - 1)
        self.set_trigger_positions(axis, [start + i * step for i in range(count)])

    def clear_triggers(self) -> None:
        """Disarm the trigger list (the counter keeps its value)."""
        self._trigger = None

    # ================================================================ internals =====

    def _axis(self, ref: AxisRef) -> _AxisState:
        if isinstance(ref, str):
            index = AXIS_NAMES.find(ref.lower()) if len(ref) == 1 else -1
        else:
            index = ref
        if not 0 <= index < self.n_axes:
            raise MotionRefused(ERR_INVALID_AXIS, f"no axis {ref!r}")
        return self._axes[index]

    def _select(
        self, axes: Iterable[AxisRef] | None, *, enabled_only: bool = True
    ) -> list[_AxisState]:
        chosen = list(self._axes) if axes is None else [self._axis(ref) for ref in axes]
        return [ax for ax in chosen if ax.settings.enable == 1 or not enabled_only]

    @staticmethod
    def _user_frame(ax: _AxisState, phys: float) -> float:
        """A physical position (revolutions) in the user frame: what ``?pos`` shows."""
        return phys - ax.origin + ax.offset

    def _phys(self, ax: _AxisState) -> float:
        return ax.traj.position(self._time)

    def _end_pos(self, ax: _AxisState) -> float:
        """Where the axis will stop (where it is, for an endless ``speed``): the base of a
        relative move (a queued or retargeted one starts from there)."""
        end = ax.traj.end_pos
        return end if math.isfinite(end) else self._phys(ax)

    def _mm_per_rev(self, ax: _AxisState) -> float:
        return ax.settings.pitch / ax.settings.gear

    def _accel(self, ax: _AxisState) -> float:
        return ax.settings.accel * 1000.0 / self._mm_per_rev(ax)

    def _stop_accel(self, ax: _AxisState) -> float:
        return ax.settings.stopaccel * 1000.0 / self._mm_per_rev(ax)

    def _cap(self, ax: _AxisState, vel: float) -> float:
        """Limit a velocity (rev/s) by secvel until the axis is released."""
        if self.is_released(ax.index):
            return vel
        return min(vel, ax.settings.secvel / self._mm_per_rev(ax))

    def _stored_limits(self, ax: _AxisState) -> tuple[float, float]:
        """Physical soft limits; unset ones are ±maxpos in the user frame."""
        maxpos = self._config.maxpos_mm / self._mm_per_rev(ax)
        base = ax.origin - ax.offset
        lo = ax.origin + ax.lim_lo if ax.lim_lo is not None else base - maxpos
        hi = ax.origin + ax.lim_hi if ax.lim_hi is not None else base + maxpos
        return lo, hi

    def _effective_limits(self, ax: _AxisState) -> tuple[float, float]:
        """Limits a move may use: ignores them with limctr 0, widened to the axis position.

        Choice (L4585): an axis beyond a limit may travel back towards the allowed range."""
        if not ax.settings.limctr:
            return -math.inf, math.inf
        lo, hi = self._stored_limits(ax)
        x = self._phys(ax)
        return min(lo, x), max(hi, x)

    def _in_running_job(self, ax: _AxisState) -> bool:
        return ax.job is not None and ax.index in ax.job.running

    def _reserved(self, ax: _AxisState) -> bool:
        job = ax.job
        return job is not None and (job.start_time is not None or job.report_time is not None)

    def _busy(self, ax: _AxisState) -> bool:
        return ax.mode != "idle" or self._reserved(ax)

    def _switch_blocks(self, ax: _AxisState) -> bool:
        e0_on, ee_on = self.switch_state(ax.index)
        return (bool(ax.settings.swact[0]) and e0_on) or (bool(ax.settings.swact[2]) and ee_on)

    # ------------------------------------------------------------- checks ----------

    def _check_idle(self, ax: _AxisState) -> None:
        if self._busy(ax):
            # Choice: only go may be overwritten while travelling (L6606); error 2.
            raise MotionRefused(ERR_NOT_EXECUTABLE, f"axis {ax.index} is busy")
        if ax.settings.calrequired and not ax.cal_done:
            raise MotionRefused(ERR_MOVE_NOT_ALLOWED, f"axis {ax.index} requires cal")

    def _check_continuous(self, ax: _AxisState) -> None:
        """go/speed may replace go/speed (and a go/speed halt), not jobs."""
        free = ax.mode in ("idle", "go", "speed") or (
            ax.mode == "halt" and not self._in_running_job(ax)
        )
        if not free or self._reserved(ax):
            raise MotionRefused(ERR_NOT_EXECUTABLE, f"axis {ax.index} is busy")
        if ax.settings.calrequired and not ax.cal_done:
            raise MotionRefused(ERR_MOVE_NOT_ALLOWED, f"axis {ax.index} requires cal")

    def _check_target(self, ax: _AxisState, target: float) -> None:
        lo, hi = self._effective_limits(ax)
        tol = _LIMIT_TOL * max(1.0, abs(target))
        if target < lo - tol or target > hi + tol:
            raise MotionRefused(ERR_OUT_OF_RANGE, f"axis {ax.index}: target outside limits")

    def _check_switch(self, ax: _AxisState, direction: float) -> None:
        """Refuse (error 12) travel deeper into an actuated, enabled switch."""
        x = self._phys(ax)
        e0, _, ee = ax.settings.swact
        if (direction < 0 and e0 and x <= ax.config.e0_position) or (
            direction > 0 and ee and x >= ax.config.ee_position
        ):
            raise MotionRefused(ERR_LIMIT_SWITCH, f"axis {ax.index}: limit switch active")

    # ------------------------------------------------------------- jobs ------------

    def _new_job(self, kind: JobKind) -> _Job:
        job = _Job(self._next_job_id, kind)
        self._next_job_id += 1
        self._jobs.append(job)
        return job

    def _submit_move(
        self, targets: dict[int, float], *, timed: bool, failed: Iterable[int] = (),
        relative: dict[int, float] | None = None,
    ) -> int:
        """Validate, then create a move job (delayed by ``delay`` when ``timed``).

        Axes still busy: refused with error 2 (``move_during_move=refuse``); with
        ``queue`` the job waits until none of its axes is busy, then starts (relative
        moves from where the axes stopped) and reports on its own; with ``retarget`` axes
        travelling in a move leave that move (which reports without them, or not at all
        when none is left) and head for the new target from where they are, each with its
        own vel/accel (no vector move). Targets are checked against the limits at once,
        for a queued relative move from where the axes will stop."""
        active = {i: t for i, t in targets.items() if self._axes[i].settings.enable == 1}
        policy = self.move_during_move
        busy = [i for i in active if self._busy(self._axes[i])]
        retarget = policy == "retarget" and bool(busy) and all(
            self._axes[i].mode == "move" for i in busy)
        queue = policy == "queue" and bool(busy)
        for i, target in active.items():
            ax = self._axes[i]
            if not ((queue or retarget) and i in busy):
                self._check_idle(ax)
            elif ax.settings.calrequired and not ax.cal_done:
                raise MotionRefused(ERR_MOVE_NOT_ALLOWED, f"axis {ax.index} requires cal")
            self._check_target(ax, target)
            origin = self._end_pos(ax) if queue else self._phys(ax)
            self._check_switch(ax, target - origin)
        job = self._new_job("move")
        job.targets = active
        job.letters = {i: "E" for i in failed}
        job.pause = self.global_settings.pause_ms / 1000.0 if timed else 0.0
        job.delay = self.global_settings.delay_ms / 1000.0 if timed else 0.0
        for i in failed:
            self._axes[i].letter = "E"
        if queue:
            job.waiting = True
            job.relative = None if relative is None else \
                {i: d for i, d in relative.items() if i in active}
            return job.id
        if retarget:
            self._take_over(job, busy)
        self._reserve(job)
        return job.id

    def _reserve(self, job: _Job) -> None:
        """Give the job its axes and start it, or schedule its start after ``delay``."""
        for i in job.targets:
            self._axes[i].job = job
            self._axes[i].letter = "@"
        if job.delay > 0.0:
            job.start_time = self._time + job.delay
        else:
            self._start_job(job, self._time)

    def _take_over(self, job: _Job, axes: Iterable[int]) -> None:
        """``retarget``: the axes leave their moves; a move left without axes is dropped
        without a report (the new move reports for them)."""
        for i in axes:
            ax = self._axes[i]
            old = ax.job
            if old is None:
                continue
            old.running.discard(i)
            old.targets.pop(i, None)
            old.letters.pop(i, None)
            ax.job = None
            if not old.running and not old.targets and old in self._jobs:
                self._jobs.remove(old)
            elif not old.running and old.start_time is None:
                old.report_time = self._time + old.pause
        job.delay = 0.0  # the axes are travelling: no delayed start

    def _start_waiting(self) -> None:
        """``queue``: start the waiting moves whose axes are all free, oldest first."""
        for job in [j for j in self._jobs if j.waiting]:
            if not job.waiting or any(self._busy(self._axes[i]) for i in job.targets):
                continue  # started meanwhile (a nested call), or still waiting
            job.waiting = False
            if job.relative is not None:
                job.targets = {i: self._phys(self._axes[i]) + d
                               for i, d in job.relative.items()}
                for i, d in job.relative.items():
                    self._axes[i].settings.distance = d
            self._reserve(job)

    def _start_job(self, job: _Job, t: float) -> None:
        """Start the motion of a move job (at command time or after ``delay``)."""
        job.start_time = None
        moving = {}
        for i, target in job.targets.items():
            delta = target - self._axes[i].traj.position(t)
            if delta != 0.0:
                moving[i] = delta
        in_motion = any(self._axes[i].mode == "move" for i in moving)
        if moving and (self.global_settings.scanmode == 3 or in_motion):
            self._start_independent(job, moving, t)
        elif moving:
            self._start_vector(job, moving, t)
        if not job.running and not job.letters and not self.zero_move_report:
            # Switch zero_move_report=no: nothing travelled, nothing is reported.
            self._drop(job)
        elif not job.running:
            job.report_time = t + job.pause

    def _start_independent(self, job: _Job, moving: dict[int, float], t: float) -> None:
        """scanmode 3 (and retargeted axes): every axis with its own vel/accel from where
        it is at its current velocity; they finish individually."""
        for i in moving:
            ax = self._axes[i]
            x, v = ax.traj.position(t), ax.traj.velocity(t)
            target = job.targets[i]
            phases = plan_to_target(x, v, target, max(self._cap(ax, ax.settings.vel), abs(v)),
                                    self._accel(ax))
            self._launch(ax, job, Trajectory.from_phases(t, x, phases, end_pos=target))

    def _start_vector(self, job: _Job, moving: dict[int, float], t: float) -> None:
        """All axes follow one normalised profile s(t) in [0, 1]: x_i = x0_i + d_i·s."""
        for i, phases in self._vector_phases(moving).items():
            ax = self._axes[i]
            x = ax.traj.position(t)
            self._launch(ax, job, Trajectory.from_phases(t, x, phases, end_pos=job.targets[i]))

    def _vector_phases(self, moving: dict[int, float]) -> dict[int, list[Phase]]:
        """Scale a common profile so that no axis exceeds its (capped) vel and accel.

        scanmode 1 (and 2 with >= 2 travelling axes): the path speed in mm space is
        ``scanvel`` (L2375-2403), still limited per axis by secvel (L2467) and accel."""
        gs = self.global_settings
        use_scanvel = gs.scanmode == 1 or (gs.scanmode == 2 and len(moving) >= 2)
        v_lim = a_lim = math.inf
        if use_scanvel:
            path_mm = math.hypot(*(d * self._mm_per_rev(self._axes[i]) for i, d in moving.items()))
            v_lim = gs.scanvel / path_mm
        for i, d in moving.items():
            ax = self._axes[i]
            own = math.inf if use_scanvel else ax.settings.vel
            v_lim = min(v_lim, self._cap(ax, own) / abs(d))
            a_lim = min(a_lim, self._accel(ax) / abs(d))
        norm = plan_to_target(0.0, 0.0, 1.0, v_lim, a_lim)
        return {i: [p.scaled(d) for p in norm] for i, d in moving.items()}

    def _launch(self, ax: _AxisState, job: _Job, traj: Trajectory) -> None:
        ax.traj = traj
        ax.mode = "move"
        ax.job = job
        job.running.add(ax.index)

    def _report(self, job: _Job, t: float) -> None:
        letters = "".join(
            job.letters.get(i, "@") if i < self.n_axes else "-" for i in range(4)
        )
        self._out.append(MoveFinished(t, job.kind, letters, job.id))
        self._drop(job)

    def _drop(self, job: _Job) -> None:
        """Forget a finished job and start the moves waiting for its axes."""
        self._jobs.remove(job)
        for ax in self._axes:
            if ax.job is job:
                ax.job = None
        self._start_waiting()

    def _axis_finished(self, ax: _AxisState, t: float, letter: str) -> None:
        """The axis stands still: record its letter and complete its job if it was last."""
        ax.traj = Trajectory.rest(t, ax.traj.end_pos)
        ax.mode = "idle"
        ax.go_target = None
        ax.deadline = None
        ax.letter = letter
        job = ax.job
        if job is None or ax.index not in job.running:
            self._start_waiting()  # a go/speed ended
            return
        job.running.discard(ax.index)
        job.letters[ax.index] = letter
        if job.kind == "move":
            job.settle = max(job.settle, ax.settings.settle)
        if not job.running and job.start_time is None:
            job.report_time = t + (0.0 if job.aborted else job.pause + job.settle)

    # ------------------------------------------------------------- go / speed ------

    def _begin_continuous(self, ax: _AxisState, mode: _Mode) -> None:
        ax.mode = mode
        ax.job = None
        ax.letter = "@"
        ax.go_target = None

    def _plan_go(self, ax: _AxisState) -> None:
        target = ax.go_target
        assert target is not None
        t = self._time
        x, v = ax.traj.position(t), ax.traj.velocity(t)
        phases = plan_to_target(x, v, target, self._cap(ax, ax.settings.vel), self._accel(ax))
        ax.traj = Trajectory.from_phases(t, x, phases, end_pos=target)

    def _plan_speed(self, ax: _AxisState, vel: float) -> None:
        t = self._time
        x, v = ax.traj.position(t), ax.traj.velocity(t)
        cap = self._cap(ax, abs(vel))
        lo, hi = self._effective_limits(ax)
        stop_at = hi if vel > 0 else lo
        if math.isfinite(stop_at):
            phases = plan_to_target(x, v, stop_at, cap, self._accel(ax))
            ax.traj = Trajectory.from_phases(t, x, phases, end_pos=stop_at)
        else:
            phases = plan_velocity(v, math.copysign(cap, vel), self._accel(ax))
            ax.traj = Trajectory.from_phases(t, x, phases)

    def _stop_continuous(self, ax: _AxisState) -> None:
        """End a go/speed at normal accel; the axis reports ``@`` once it stands."""
        if ax.mode not in ("go", "speed"):
            return
        t = self._time
        x, v = ax.traj.position(t), ax.traj.velocity(t)
        ax.go_target = None
        ax.traj = Trajectory.from_phases(t, x, plan_stop(v, self._accel(ax)))

    # ------------------------------------------------------------- abort / halt ----

    def _abort_axis(self, ax: _AxisState, use_accel: bool) -> None:
        job = ax.job
        if ax.mode == "idle":
            if job is not None and job.start_time is not None and ax.index in job.targets:
                self._abort_pending(ax, job)
            return  # nothing moves (also during a pause): no effect
        if ax.mode == "halt":
            return  # already braking (switch, timeout or earlier abort)
        if job is not None and ax.index in job.running:
            job.aborted = True
        decel = self._accel(ax) if use_accel else self._stop_accel(ax)
        self._halt(ax, self.abort_letter, decel)

    def _abort_pending(self, ax: _AxisState, job: _Job) -> None:
        """Abort during ``delay``: the axis never starts and reports ``E``."""
        del job.targets[ax.index]
        job.letters[ax.index] = self.abort_letter
        job.aborted = True
        ax.letter = self.abort_letter
        ax.job = None
        if not job.targets:
            job.start_time = None
            job.report_time = self._time

    def _halt(self, ax: _AxisState, letter: str, decel: float, at: float | None = None) -> None:
        """Brake to a standstill; the axis (and its job) will report ``letter``."""
        t = self._time
        x = ax.traj.position(t) if at is None else at
        v = ax.traj.velocity(t)
        ax.traj = Trajectory.from_phases(t, x, plan_stop(v, decel))
        ax.mode = "halt"
        ax.halt_letter = letter
        ax.deadline = None
        if ax.job is not None and ax.index in ax.job.running:
            ax.job.letters[ax.index] = letter

    # ------------------------------------------------------------- cal / rm --------

    def _submit_cal(self, kind: Literal["cal", "rm"], axes: Iterable[AxisRef] | None) -> int:
        chosen = self._select(axes)
        for ax in chosen:
            if self._busy(ax):
                raise MotionRefused(ERR_NOT_EXECUTABLE, f"axis {ax.index} is busy")
        job = self._new_job(kind)
        switch = 0 if kind == "cal" else 2
        for ax in chosen:
            ax.letter = "@"
            if ax.settings.swact[switch]:  # choice: disabled switch → skipped, reports '@'
                self._start_cal_axis(ax, job, kind)
        if not job.running:
            job.report_time = self._time
        return job.id

    def _cal_params(self, ax: _AxisState, kind: _Mode) -> tuple[float, float, float, float]:
        """(direction, switch position, approach speed, release speed) for cal or rm."""
        s = ax.settings
        if kind == "cal":
            sign, level, pair = -1.0, ax.config.e0_position, s.calvel
        else:
            sign, level, pair = 1.0, ax.config.ee_position, s.rmvel
        if self.global_settings.extmode:
            approach, release = pair
        else:
            approach, release = s.vel, s.calbspeed / 100.0
        return sign, level, self._cap(ax, approach), self._cap(ax, release)

    def _start_cal_axis(self, ax: _AxisState, job: _Job, kind: Literal["cal", "rm"]) -> None:
        t = self._time
        ax.mode = kind
        ax.job = job
        ax.deadline = t + ax.settings.caltimeout
        job.running.add(ax.index)
        sign, level, approach, _ = self._cal_params(ax, kind)
        x = self._phys(ax)
        if (x - level) * sign >= 0.0:  # already on the switch: only release it
            self._cal_release(ax, t)
            return
        ax.phase = "approach"
        ax.traj = Trajectory.from_phases(t, x, plan_velocity(0.0, sign * approach,
                                                             self._accel(ax)))

    def _cal_on_switch(self, ax: _AxisState, t: float) -> None:
        """Approach reached the switch: brake with stopaccel (L3417)."""
        _, level, _, _ = self._cal_params(ax, ax.mode)
        v = ax.traj.velocity(t)
        ax.traj = Trajectory.from_phases(t, level, plan_stop(v, self._stop_accel(ax)))
        ax.phase = "brake"

    def _cal_release(self, ax: _AxisState, t: float) -> None:
        """Leave the switch slowly in the opposite direction."""
        sign, _, _, release = self._cal_params(ax, ax.mode)
        x, v = ax.traj.position(t), ax.traj.velocity(t)
        ax.traj = Trajectory.from_phases(t, x, plan_velocity(v, -sign * release,
                                                             self._accel(ax)))
        ax.phase = "release"

    def _cal_released(self, ax: _AxisState, t: float) -> None:
        """Switch is free: travel to the offset point (at least the stopping distance)."""
        sign, level, approach, _ = self._cal_params(ax, ax.mode)
        s = ax.settings
        offset = s.caliboffset if ax.mode == "cal" else s.rmoffset
        v = ax.traj.velocity(t)
        acc = self._accel(ax)
        target = level - sign * max(offset, v * v / (2.0 * acc))
        phases = plan_to_target(level, v, target, max(approach, abs(v)), acc)
        ax.traj = Trajectory.from_phases(t, level, phases, end_pos=target)
        ax.phase = "settle"

    def _cal_finished(self, ax: _AxisState, t: float) -> None:
        x = ax.traj.end_pos
        s = ax.settings
        if ax.mode == "cal":
            if s.calmode != 1:  # calmode 1 keeps the power-on zero (L5562)
                ax.origin, ax.offset = x, 0.0
            ax.cal_counter = x - ax.origin
            if not s.nosetlimit:
                ax.lim_lo = ax.cal_counter
            ax.cal_done = True
            self._axis_finished(ax, t, "A")
        else:
            if not s.nosetlimit:
                ax.lim_hi = x - ax.origin
            ax.rm_done = True
            self._axis_finished(ax, t, "D")

    def _cal_timeout(self, ax: _AxisState, t: float) -> None:
        self._halt(ax, "T", self._stop_accel(ax))

    # ------------------------------------------------------------- events ----------

    def _next_action(self) -> _Action | None:
        best: _Action | None = None
        for action in self._candidates():
            if best is None or (action.time, action.priority, action.key) < (
                best.time, best.priority, best.key
            ):
                best = action
        return best

    def _candidates(self) -> Iterator[_Action]:
        for job in self._jobs:
            if job.start_time is not None:
                yield _Action(job.start_time, _P_START, job.id, partial(self._start_job, job))
            if job.report_time is not None:
                yield _Action(job.report_time, _P_REPORT, job.id, partial(self._report, job))
        for ax in self._axes:
            yield from self._axis_candidates(ax)
        yield from self._trigger_candidates()

    def _axis_candidates(self, ax: _AxisState) -> Iterator[_Action]:
        if ax.mode == "idle":
            return
        key = ax.index
        if ax.deadline is not None:
            yield _Action(ax.deadline, _P_CROSS, key, partial(self._cal_timeout, ax))
        if ax.mode in ("cal", "rm"):
            yield from self._cal_candidates(ax)
            return
        if ax.mode != "halt":
            yield from self._switch_candidates(ax)
        end = ax.traj.end_time
        if math.isfinite(end):
            yield _Action(end, _P_STOP, key, partial(self._on_traj_end, ax))

    def _switch_candidates(self, ax: _AxisState) -> Iterator[_Action]:
        e0, _, ee = ax.settings.swact
        for enabled, level, upward in (
            (e0, ax.config.e0_position, False),
            (ee, ax.config.ee_position, True),
        ):
            if not enabled:
                continue
            t = ax.traj.first_entry(level, upward=upward, closed=True, t_min=self._time)
            if t is not None:
                yield _Action(t, _P_CROSS, ax.index, partial(self._on_switch, ax, level))

    def _cal_candidates(self, ax: _AxisState) -> Iterator[_Action]:
        sign, level, _, _ = self._cal_params(ax, ax.mode)
        if ax.phase in ("brake", "settle"):
            yield _Action(ax.traj.end_time, _P_STOP, ax.index, partial(self._on_traj_end, ax))
            return
        if ax.phase == "approach":
            t = ax.traj.first_entry(level, upward=sign > 0, closed=True, t_min=self._time)
            handler = self._cal_on_switch
        else:
            t = ax.traj.first_entry(level, upward=sign < 0, closed=False, t_min=self._time)
            handler = self._cal_released
        if t is not None:
            yield _Action(t, _P_CROSS, ax.index, partial(handler, ax))

    def _trigger_candidates(self) -> Iterator[_Action]:
        tl = self._trigger
        if tl is None:
            return
        traj = self._axes[tl.axis].traj
        if tl.index < len(tl.levels):
            t = traj.first_entry(tl.levels[tl.index], upward=tl.increasing, closed=True,
                                 t_min=self._time)
            if t is not None:
                yield _Action(t, _P_TRIGGER, 0, self._on_trigger_fire)
        if tl.index > 0:
            t = traj.first_entry(tl.levels[0], upward=not tl.increasing, closed=False,
                                 t_min=self._time)
            if t is not None:
                yield _Action(t, _P_TRIGGER, 1, self._on_trigger_rearm)

    def _on_traj_end(self, ax: _AxisState, t: float) -> None:
        if ax.mode in ("cal", "rm"):
            if ax.phase == "brake":
                self._cal_release(ax, t)
            else:
                self._cal_finished(ax, t)
            return
        letter = ax.halt_letter if ax.mode == "halt" else "@"
        if ax.mode == "move" and ax.job is not None:
            letter = ax.job.letters.get(ax.index, "@")
        self._axis_finished(ax, t, letter)

    def _on_switch(self, ax: _AxisState, level: float, t: float) -> None:
        """Unexpected limit switch: brake with stopaccel (L3419), letter ``S``."""
        self._halt(ax, "S", self._stop_accel(ax), at=level)

    def _on_trigger_fire(self, t: float) -> None:
        tl = self._trigger
        assert tl is not None
        ax = self._axes[tl.axis]
        level = tl.levels[tl.index]
        tl.index += 1
        self._trigger_count += 1
        self._out.append(TriggerFired(t, tl.axis, tl.index, self._user_frame(ax, level)))

    def _on_trigger_rearm(self, t: float) -> None:
        assert self._trigger is not None
        self._trigger.index = 0
