"""The engine of the emulator's motion model: its vocabulary (axes, error numbers, events,
configuration and settings), the state of each axis, and :class:`MotionEngine`, which runs
the jobs (moves, ``go``/``speed``, aborts and halts, cal and rm) and the events that end
them in virtual time. :class:`~tango_aio.sim.motion.MotionModel` adds the commands and
queries on top; the decisions where the manual is silent are listed in
:mod:`tango_aio.sim.motion`."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import partial
from typing import Literal

from tango_aio.units import DEFAULT_USTEPS

from .trajectory import Phase, Trajectory, plan_stop, plan_to_target, plan_velocity
from .trigtrack import Grid, Source, view

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
    "MotionEngine",
    "MotionEvent",
    "MotionRefused",
    "MoveFinished",
    "TriggerFired",
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
    """A move, cal or rm job finished; ``letters`` holds one status letter per axis X Y Z A."""

    time: float
    kind: JobKind
    letters: str
    job_id: int


@dataclass(frozen=True, slots=True)
class TriggerFired:
    """The trigger axis passed entry ``index`` (1-based) of the trigger list, or a level
    of a bidirectional distance mode (``index`` 0); ``position`` is the motor's."""

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
    """Static physical description of one axis (motor revolutions, physical frame)."""

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
    """Per-axis parameters (mutable; the command layer writes them)."""

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
# The engine
# --------------------------------------------------------------------------------------


class MotionEngine:
    """The motion model's state and the jobs and events that change it in virtual time;
    :class:`~tango_aio.sim.motion.MotionModel` adds the commands and queries."""

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
        self._trigger: _TriggerList | Grid | None = None
        self.trigger_source = Source()
        """What position triggers compare (``trigcomp``, ``trigenc``)."""
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

    # ---------------------------------------------------------------- switches ------

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
        """Validate, then create a move job (delayed by ``delay`` when ``timed``)."""
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
        traj = view(self._axes[tl.axis].traj, self.trigger_source)
        if isinstance(tl, Grid):
            for key, (when, cell, fires) in enumerate(tl.candidates(traj, self._time)):
                yield _Action(when, _P_TRIGGER, key, partial(self._on_grid, cell, fires))
            return
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
        assert isinstance(tl, _TriggerList)
        level = tl.levels[tl.index]
        tl.index += 1
        self._fired(t, tl.axis, tl.index, level)

    def _on_grid(self, cell: float, fires: bool, t: float) -> None:
        grid = self._trigger
        assert isinstance(grid, Grid)
        # Reaching a level fires there; leaving one (the first move) fires where it was.
        level = grid.level(cell if cell == int(cell) else grid.cell)
        if not (grid.neighbours and fires and cell != int(cell)):
            grid.cell = cell  # (the first move of ``neighbours`` stays on the level it fired)
        if fires:
            grid.pending = False
            self._fired(t, grid.axis, 0, level)

    def _fired(self, t: float, axis: int, index: int, level: float) -> None:
        """A position trigger fired: at ``level`` itself, or where the motor is when the
        compared position reached it (:class:`~tango_aio.sim.trigtrack.Source`)."""
        ax = self._axes[axis]
        where = level if self.trigger_source.plain else ax.traj.position(t)
        self._trigger_count += 1
        self._out.append(TriggerFired(t, axis, index, self._user_frame(ax, where)))

    def _on_trigger_rearm(self, t: float) -> None:
        assert isinstance(self._trigger, _TriggerList)
        self._trigger.index = 0
