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
from collections.abc import Callable, Iterable, Mapping, Sequence

from tango_aio.units import UnitScale

from .engine import (
    AXIS_NAMES,
    ERR_INVALID_AXIS,
    ERR_LIMIT_SWITCH,
    ERR_MOVE_NOT_ALLOWED,
    ERR_NOT_EXECUTABLE,
    ERR_OUT_OF_RANGE,
    AxisConfig,
    AxisRef,
    AxisSettings,
    GlobalSettings,
    JobKind,
    MotionConfig,
    MotionEngine,
    MotionEvent,
    MotionRefused,
    MoveFinished,
    TriggerFired,
    _AxisState,
    _TriggerList,
)
from .lists import MAX_TRIGGERS
from .trajectory import (
    Phase,
    Segment,
    Trajectory,
    plan_stop,
    plan_to_target,
    plan_velocity,
)
from .trigtrack import Grid, Source

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


# --------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------


class MotionModel(MotionEngine):
    """Deterministic virtual-time motion model of a TANGO controller (see module doc)."""

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
        """``mol``: move to the transport lock position (needs cal and a lock position)."""
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
        """``speed``: constant signed velocity (rev/s); 0 stops speed or go; no report."""
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
        """``cal``: find E0 on the axes (all enabled when None); returns the job id."""
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
        tl = self._trigger
        return tl.index + 1 if isinstance(tl, _TriggerList) else 0

    def set_trigger_grid(self, axis: AxisRef, start: float, step: float, *,
                         shifted: bool, neighbours: bool = False) -> None:
        """Bidirectional distance modes: a level every ``step`` revolutions from ``start``
        (user frame, the compared position where ``!trig 1`` ran), half a step off it when
        ``shifted``; each fires when the axis reaches it either way, or only next to the
        last one that fired (``neighbours``; :class:`~tango_aio.sim.trigtrack.Grid`)."""
        ax = self._axis(axis)
        origin = start + ax.origin - ax.offset
        self._trigger = Grid(ax.index, origin + step / 2, step, cell=-0.5, pending=False,
                             neighbours=neighbours) \
            if shifted else Grid(ax.index, origin, step, neighbours=neighbours)

    def set_trigger_source(self, axis: AxisRef, *, lead: float = 0.0, scale: float = 1.0,
                           offset: float = 0.0) -> None:
        """What position triggers compare: ``scale * (user + lead * v) + offset`` of the
        motor's user-frame position (revolutions) and velocity; ``lead`` in seconds
        (:class:`~tango_aio.sim.trigtrack.Source`)."""
        ax = self._axis(axis)
        frame = ax.origin - ax.offset
        self.trigger_source = Source(lead, scale, (1.0 - scale) * frame + offset)
        if isinstance(self._trigger, Grid):
            grid = self._trigger
            grid.place(self.trigger_source.at(self._phys(self._axes[grid.axis])))

    def compared_position(self, axis: AxisRef) -> float:
        """Where the compared position of ``axis`` stands now (user frame, revolutions)."""
        ax = self._axis(axis)
        return self._user_frame(ax, self.trigger_source.at(self._phys(ax)))

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
