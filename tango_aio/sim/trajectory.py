"""Closed-form trajectories of the emulator's motion model: pieces of constant acceleration
(:class:`Phase`, :class:`Segment`) chained into a :class:`Trajectory`, and the time-optimal
linear-ramp profiles that moves, ``go``, ``speed`` and stops follow (:func:`plan_to_target`,
:func:`plan_velocity`, :func:`plan_stop`). Lengths in motor revolutions, velocities in rev/s."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace

__all__ = [
    "Phase",
    "Segment",
    "Trajectory",
    "plan_stop",
    "plan_to_target",
    "plan_velocity",
]

_PLAN_TOL = 1e-12  # relative tolerance for "stopping distance equals remaining distance"


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
        """Chain ``phases`` starting at ``(t, x)``; snap the final position to ``end_pos``."""
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
        """First time >= ``t_min`` at which the position enters a half line."""

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
    """Phases covering ``dist >= 0`` forward from speed ``u >= 0``, ending at rest."""
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
    """Time-optimal linear-ramp profile from ``(x0, v0)`` to rest at ``target``."""
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
