"""Where position triggers fire, without state of the engine: the position the trigger
compares (the motor's or the encoder's, looking ahead by ``trigcomp``), and the grid of
the bidirectional distance modes. Lengths in motor revolutions (the engine's physical
frame), times in seconds."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

from .trajectory import Segment, Trajectory

__all__ = ["Grid", "Source", "view"]


@dataclass(frozen=True, slots=True)
class Source:
    """The position a trigger compares: ``scale * (p + lead * v) + shift`` of the motor
    position ``p`` and velocity ``v``.

    ``lead`` is ``trigcomp`` in seconds: the trigger "releases ... at an earlier (+) or
    later (-) time", at a position the controller calculates "based on the current
    velocity" (L13064-13117), so it fires where ``p + lead * v`` reaches the level.
    ``scale`` and ``shift`` map the motor position to the encoder's with ``trigenc 1``
    and an active encoder (L13168-13210).
    """

    lead: float = 0.0
    scale: float = 1.0
    shift: float = 0.0

    @property
    def plain(self) -> bool:
        """Whether this is the motor position itself."""
        return self.lead == 0.0 and self.scale == 1.0 and self.shift == 0.0

    def at(self, position: float) -> float:
        """The compared position of the motor standing at ``position``."""
        return self.scale * position + self.shift


def view(traj: Trajectory, source: Source) -> Trajectory:
    """``traj`` as the trigger sees it (:class:`Source`): a trajectory of the compared
    position, each segment cut where that position turns (the look-ahead reverses while
    the axis brakes)."""
    if source.plain:
        return traj
    segments = [part for segment in traj.segments for part in _mapped(segment, source)]
    if segments and math.isfinite(segments[-1].t1):
        # A move ends at rest: exactly where the motor's end is seen (no rounding drift).
        segments[-1] = replace(segments[-1], x1=source.at(traj.end_pos))
    return Trajectory(traj.start_time, source.at(traj.start_pos), tuple(segments))


def _mapped(seg: Segment, source: Source) -> Iterator[Segment]:
    a, lead = source.scale, source.lead
    v0, acc = a * (seg.v0 + lead * seg.accel), a * seg.accel
    x0 = source.at(seg.x0 + lead * seg.v0)
    turn = seg.t0 - v0 / acc if acc else seg.t0
    cuts = [seg.t0] + ([turn] if seg.t0 < turn < seg.t1 else []) + [seg.t1]
    for t0, t1 in itertools.pairwise(cuts):
        start_v = v0 + acc * (t0 - seg.t0)
        start_x = x0 + (t0 - seg.t0) * (v0 + 0.5 * acc * (t0 - seg.t0))
        duration = t1 - t0
        end_x = start_x + duration * (start_v + 0.5 * acc * duration) \
            if duration != float("inf") else float("inf") if start_v > 0 else float("-inf")
        yield Segment(t0, t1, start_x, end_x, start_v, acc)


@dataclass(slots=True)
class Grid:
    """The levels ``origin + k * step`` (every integer ``k``) of a bidirectional distance
    mode (1, 4, 7, 10: L12595-12836), and where the compared position is among them.

    Where the trigger was enabled (``!trig 1``) is level 0 and "First pulse when move
    starts" (L12614-12632): the first move away from it, either way, fires there. The
    shifted modes put the levels half a distance off the start (L12689-12717) and fire
    nothing at the start. Leaving a level fires nothing, so an axis that stops on a level
    and turns back fires there once. Which level fires next the manual does not say
    (switch ``bidirectional_next``): each one the position reaches, from either side
    (``reach``: an axis that goes back and forth across a level fires each time), or only
    the neighbours of the last one that fired (``neighbours``: a comparator armed at one
    distance either way).
    """

    axis: int
    origin: float
    step: float
    #: Where the position is: ``k`` on level ``k``; ``k + 0.5`` between ``k`` and ``k + 1``.
    cell: float = 0.0
    #: The first move away from level 0 still fires (the non-shifted modes).
    pending: bool = True
    #: Only the neighbours of the last level that fired fire next.
    neighbours: bool = False

    def place(self, position: float) -> None:
        """Put the compared position at ``position`` (it jumped: a new encoder drift)."""
        index = (position - self.origin) / self.step
        if abs(index - round(index)) <= 1e-9:
            self.pending = self.pending and round(index) == self.cell
            self.cell = float(round(index))
        else:
            self.cell, self.pending = math.floor(index) + 0.5, False

    def level(self, index: float) -> float:
        """The position of level ``index``."""
        return self.origin + index * self.step

    def candidates(self, traj: Trajectory, t_min: float) -> Iterator[tuple[float, float, bool]]:
        """The next changes of :attr:`cell` on ``traj`` (the compared position): their
        time, the new cell and whether a pulse fires."""
        if self.cell == int(self.cell) and self.neighbours and not self.pending:
            for upward, target in ((True, self.cell + 1), (False, self.cell - 1)):
                t = traj.first_entry(self.level(target), upward=upward, closed=True,
                                     t_min=t_min)
                if t is not None:
                    yield t, target, True
            return
        if self.cell == int(self.cell):  # on a level: the departures
            here = self.level(self.cell)
            for upward, side in ((True, 0.5), (False, -0.5)):
                t = traj.first_entry(here, upward=upward, closed=False, t_min=t_min)
                if t is not None:
                    yield t, self.cell + side, self.pending
            return
        below = self.cell - 0.5
        for upward, target in ((True, below + 1), (False, below)):
            t = traj.first_entry(self.level(target), upward=upward, closed=True, t_min=t_min)
            if t is not None:
                yield t, target, True
