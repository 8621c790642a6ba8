"""Move timing without I/O: how long a move may take and what counts as its target.

* :meth:`MoveTiming.travel` converts a distance in the axis's user unit (``dim``,
  ``pitch``) to motor revolutions and times a trapezoid profile (:func:`travel_time`) at
  the slowest plausible speed: ``vel`` capped by the security speed ``secvel``, with the
  acceleration ``accel``. The waits around a move, ``delay`` before it (L6845-6868),
  ``pause`` after it (L6873-6899) and the closed-loop settling ``ctrt`` (L11616-11631),
  are cached with it; the controller adds them to the travel to size a move's budget.
* :func:`move_budget` sizes one motion line's :class:`Budget`: the expected end (delay,
  travel, pause and settling) and the limit at which it is given up (twice the travel and
  :data:`MARGIN`, or the caller's timeout; fixed limits for ``cal``/``rm`` and ``moc``,
  whose distance is not known); :func:`rest_budget` sizes once more what a move may still
  take from where its axes stand (a budget sized from stale positions is extended once).
* :func:`moved_axes` says which axes a motion line moves, so that only those are
  confirmed.
* :func:`position_tolerance` says how far a printed position may stand from its target
  and still be "at" it: the controller prints positions rounded (L4080-4100), so the
  tolerance follows the printed digits.
* :func:`verdict` judges one state read (status letters and positions) of a move that
  stopped: ``None`` if every moved axis ended well, else in words what went wrong
  (:func:`describe_stop`); :func:`too_early` says when a failed verdict may still be read
  too early (``!delay``, closed-loop settling) and so does not stand yet.
* :func:`cut_short` judges a read of a move of several axes while some still move: an
  axis that reads a failure letter has ended the move already (a limit switch stops
  that axis alone, and the report waits for the others), and :func:`polled_during` says
  when such a read is made during the travel.
* :func:`err_verdict` and :func:`ack_verdict` judge the reply that judges a line (its
  ``?err``, its acknowledgement): accepted, refused, or garbled (it proves nothing);
  :func:`contest` says whether the state read behind a refusal or a garbled verdict on a
  motion line contradicts it (the line's axes move: the line ran).
* :func:`acceptance` judges the state read behind a ``speed`` or ``go`` line that owes
  no answer (autostatus 0, 1, 3), whose ``?err`` 0 a lost line gets too: an axis it sets
  running moves, or the result it asks for holds; :func:`stop_time` bounds the wait
  for an axis it stops, :func:`speed_shown` reads the speed in force of one that ran
  before it.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from ..catalog import AXES, Command, Completion
from ..errors import ERROR_DESCRIPTIONS
from ..status import ABSENT, FAILED_LETTERS, MOVING, AxisStatus
from ..units import UnitScale

__all__ = [
    "CAL_LIMIT",
    "MARGIN",
    "MAX_SPEED",
    "MOC_LIMIT",
    "POLL_GRACE",
    "UNKNOWN_TRAVEL",
    "Acceptance",
    "Budget",
    "Contest",
    "MoveTiming",
    "Verdict",
    "acceptance",
    "ack_verdict",
    "contest",
    "cut_short",
    "describe_stop",
    "err_verdict",
    "move_budget",
    "moved_axes",
    "polled_during",
    "position_tolerance",
    "report_shows_run",
    "rest_budget",
    "shifted_axes",
    "speed_shown",
    "stop_time",
    "too_early",
    "travel_time",
    "verdict",
]

#: Seconds :func:`travel_time` gives a move whose speed or acceleration is unknown.
UNKNOWN_TRAVEL = 60.0

#: Seconds a move's limit adds to twice its travel (report latency, a loaded host).
MARGIN = 2.0

#: Limit (s) of a ``cal`` or ``rm`` line: ``caltimeout`` is at most 120 s per axis (L5251).
CAL_LIMIT = 150.0

#: Limit (s) of a ``moc`` line, whose distance the driver does not know.
MOC_LIMIT = 120.0

#: Extra time after the expected end before the state is read (report latency on the wire).
POLL_GRACE = 0.05

#: The lines ``!delay`` and ``!pause`` apply to (L6856, L6887).
_DELAYED = frozenset({"moa", "mor", "m", "moc"})

#: Letters of a moved axis that end a move at once (:func:`too_early`): the failure
#: letters, and ``-`` for an axis that is disabled (L2711).
_FINAL = FAILED_LETTERS | {ABSENT}


@dataclass(slots=True)
class MoveTiming:
    """Per-axis and global settings the driver caches to time moves."""

    dims: list[int] = field(default_factory=lambda: [2, 2, 2, 2])
    pitch: list[float] = field(default_factory=lambda: [1.0] * 4)
    vel: list[float] = field(default_factory=lambda: [10.0] * 4)
    accel: list[float] = field(default_factory=lambda: [1.0] * 4)
    secvel: list[float] = field(default_factory=lambda: [10.0] * 4)
    extmode: int = 0
    #: ``!delay`` (ms) before a moa/mor/m/moc starts (L6845-6868).
    delay_ms: float = 0.0
    #: ``!pause`` (ms) after the axes reached their target, before the report (L6873-6899).
    pause_ms: float = 0.0
    #: ``!ctrt`` (ms): longest closed-loop settling before the report (L11616-11631).
    settle_ms: float = 0.0

    def travel(self, axis: str, distance: float) -> float:
        """How long a single-axis move takes at the slowest plausible speed."""
        index = AXES.index(axis)
        scale = UnitScale(dim=self.dims[index], pitch=self.pitch[index])
        return travel_time(abs(scale.pos_from_user(distance)),
                           min(scale.vel_from_user(self.vel[index]),
                               scale.mm_to_rev(self.secvel[index])),
                           scale.accel_to_rev(self.accel[index]))


def travel_time(revs: float, speed: float, accel: float) -> float:
    """How long a trapezoid move of ``revs`` motor revolutions takes."""
    if speed <= 0 or accel <= 0 or not math.isfinite(speed + accel):
        return UNKNOWN_TRAVEL
    ramp = speed / accel
    if revs < speed * ramp:
        return 2.0 * math.sqrt(revs / accel)
    return revs / speed + ramp


def moved_axes(command: Command, present: Sequence[str]) -> tuple[str, ...]:
    """The axes a motion line moves."""
    if command.axis is not None:
        return (command.axis,)
    if command.values:
        return tuple(AXES[: len(command.values)])
    return tuple(present)


def position_tolerance(text: str) -> float:
    """How far a position read as ``text`` may be from its target.

    The controller prints positions rounded to its ``resolution`` (L4080-4100), and a
    ``move_by`` target carries the rounding of the start position too."""
    digits = len(text.rsplit(".", 1)[1]) if "." in text else 0
    return 1.5 * 10.0 ** -digits


@dataclass(frozen=True, slots=True)
class Budget:
    """How long one motion line may take, in seconds counted from writing it."""

    #: ``!delay`` before the move starts (L6845-6868).
    delay: float
    #: The travel itself (the slowest moved axis, trapezoid at the slowest plausible speed).
    travel: float
    #: ``!pause`` after the axes arrived (L6873-6899) and closed-loop settling.
    after: float
    #: Closed-loop settling (``ctrt``, L11616-11631), part of ``after``.
    settle: float
    #: When the move is given up (the caller's timeout, or the computed limit).
    limit: float

    @property
    def expected(self) -> float:
        """When the move should have ended: delay, travel, pause and settling."""
        return self.delay + self.travel + self.after

    @property
    def fallback(self) -> float:
        """What :func:`rest_budget` gives when a position was not read: the limit without
        the delay (the move has started by then)."""
        return self.limit - self.delay


def _travel(timing: MoveTiming, distances: Mapping[str, float]) -> float:
    """Seconds the slowest of ``distances`` (per axis, user units) takes."""
    return max((timing.travel(axis, abs(d)) for axis, d in distances.items()), default=0.0)


def move_budget(timing: MoveTiming, command: Command, distances: Mapping[str, float] | None,
                timeout: float | None = None) -> Budget:
    """The budget of one motion line."""
    delayed = command.name in _DELAYED
    delay = timing.delay_ms / 1000.0 if delayed else 0.0
    settle = timing.settle_ms / 1000.0
    after = (timing.pause_ms / 1000.0 if delayed else 0.0) + settle
    if command.instruction.completion in (Completion.CAL, Completion.RM):
        travel, limit = 0.0, CAL_LIMIT
    elif distances is None:
        travel, limit = 0.0, MOC_LIMIT
    else:
        travel = _travel(timing, distances)
        limit = 2.0 * travel + MARGIN
    return Budget(delay, travel, after, settle, timeout or delay + limit + after)


def rest_budget(timing: MoveTiming, targets: Mapping[str, float], now: Mapping[str, str],
                fallback: float) -> float:
    """How long a move may still take from where its axes stand."""
    if not set(targets) <= set(now):
        return fallback
    travel = _travel(timing, {a: t - float(now[a]) for a, t in targets.items()})
    return 2.0 * travel + MARGIN + (timing.pause_ms + timing.settle_ms) / 1000.0


def failed_axes(moved: Sequence[str], targets: Mapping[str, float] | None,
                tolerance: Mapping[str, float], letters: Mapping[str, str],
                texts: Mapping[str, str], *, optional: Collection[str] = ()
                ) -> tuple[str, ...]:
    """The moved axes that did not end well, in the order of ``moved``.

    An axis ended well when it reads no failure letter (``E``, ``S``, ``T``, L2689-2711),
    is not disabled or absent (``-``, L2711: it did not move at all; unless it is in
    ``optional``, the axes an all-axes ``cal``, ``rm`` or ``moc`` takes in only when
    enabled) and stands within :func:`position_tolerance` (or its ``tolerance``) of its
    target. The one rule of a move's end: the driver, the shell and the IOC judge by it."""
    bad = []
    for axis in moved:
        letter = letters.get(axis, ABSENT)
        target = None if targets is None else targets.get(axis)
        text = texts.get(axis)
        if letter in FAILED_LETTERS or (letter == ABSENT and axis not in optional) or (
                target is not None and (text is None or abs(float(text) - target) > max(
                    position_tolerance(text), tolerance.get(axis, 0.0)))):
            bad.append(axis)
    return tuple(bad)


def verdict(moved: Sequence[str], targets: Mapping[str, float] | None,
            tolerance: Mapping[str, float], letters: Mapping[str, str],
            texts: Mapping[str, str], *, optional: Collection[str] = ()) -> str | None:
    """Judge one state read of a move whose axes stopped (:func:`failed_axes`)."""
    bad = failed_axes(moved, targets, tolerance, letters, texts, optional=optional)
    if not bad:
        return None
    return "did not end at its target: " + "; ".join(
        describe_stop(axis, letters.get(axis, ABSENT), texts.get(axis),
                      None if targets is None else targets.get(axis))
        for axis in bad)


def too_early(budget: Budget, moved: Sequence[str], letters: Mapping[str, str],
              checked: float, now: float, expected_end: float) -> float | None:
    """When a failed verdict may not be the move's end yet.

    * ``!delay`` (L6845-6868): the move has not started yet; until the delay is over
      (counted from the check, a bound on when the controller took the line);
    * closed-loop settling (``ctrt``, L11616-11631): an axis that stopped short of its
      target with a letter that does not say it failed (``@``) may still be settling;
      until the expected end. A failure letter (``E``, ``S``, ``T``) or ``-`` (the axis
      is disabled, L2711: it does not move at all) is final."""
    if budget.delay > 0:
        started_by = checked + budget.delay + POLL_GRACE
        if now < started_by:
            return started_by
    failed = any(letters.get(a, ABSENT) in _FINAL for a in moved)
    if budget.settle > 0 and not failed and now < expected_end:
        return expected_end + POLL_GRACE
    return None


def polled_during(moved: Sequence[str], reports: bool) -> bool:
    """Whether a move's state is read during its travel (every ``POLL_MAX`` of
    :mod:`tango_aio.controller._motion`), not only at its report or its expected end.

    Without completion reports (autostatus 0, L2078) nothing else tells of an early
    end. A move of several axes sends its report only once all of them stand (one report
    per move line, L2085-2089); the manual does not say that an axis stopped by a limit
    switch or an error (L2699, L2705-2707) stops the others of the line, so the report
    may come only when they end, the whole planned travel later."""
    return not reports or len(moved) > 1


def cut_short(budget: Budget, moved: Sequence[str], letters: Mapping[str, str],
              checked: float, now: float, expected_end: float) -> tuple[str, ...]:
    """The axes that ended a move of several axes early, read while others still move.

    An axis that reads a failure letter (``E``, ``S``, ``T``) or ``-`` (disabled, L2711)
    has not reached its target and will not (:func:`too_early`: such a letter is final
    once any ``!delay`` is over): the move has failed, whatever the other axes do. The
    caller stops them and raises at once instead of waiting for them to end."""
    ended = tuple(a for a in moved if letters.get(a, ABSENT) in _FINAL)
    if not ended or not any(letters.get(a) == MOVING for a in moved):
        return ()
    if too_early(budget, moved, letters, checked, now, expected_end) is not None:
        return ()
    return ended


#: Why an axis stopped, by the letter it reads (L2693-2711).
_WHY = {
    AxisStatus.ERROR: "stopped: its move was aborted or not executed (status E)",
    AxisStatus.TIMEOUT: "timed out (status T)",
    ABSENT: "is disabled or absent (status -) and did not move",
}


def describe_stop(axis: str, letter: str, text: str | None, target: float | None,
                  why: str | None = None) -> str:
    """One axis of a failed move in words.

    Which limit switch is told from the direction of travel: an axis that stopped below
    its target was moving up, towards its upper switch (EE), and the reverse (the
    manual's letter ``S`` does not say which, L2699)."""
    name = axis.upper()
    where = "position not read" if text is None else f"at {text}"
    aim = "" if target is None else f", target {target:g}"
    if why is not None:
        return f"{name} {why}, {where}{aim}"
    if letter == AxisStatus.LIMIT_SWITCH:
        side = "a limit switch"
        if text is not None and target is not None and float(text) != target:
            side = ("its upper limit switch (EE)" if float(text) < target
                    else "its lower limit switch (E0)")
        return f"{name} stopped at {side} (status S), {where}{aim}"
    reason = _WHY.get(letter, f"stopped short of its target (status {letter})")
    return f"{name} {reason}, {where}{aim}"


class Verdict(enum.Enum):
    """What the reply that judges a line (its ``?err``, its acknowledgement) says of it."""

    #: ``0`` or ``OK...``: the line was taken.
    ACCEPTED = "accepted"
    #: A documented error number (or a bare ``ERR``): the line was refused.
    REFUSED = "refused"
    #: Anything else: the reply proves nothing about the line.
    GARBLED = "garbled"


#: ``?err``: "Error number as decimal value" (L2847), blanks around it tolerated.
_ERR_REPLY = re.compile(r" *(0|[1-9][0-9]{0,5}) *")
#: Mode 2: ``OK...`` or ``ERR 5`` (L2099-2103, L2150-2152), a bare ``ERR`` (switch
#: ``err_number``), in any case (switch ``ack_case``).
_ACK_REPLY = re.compile(r" *(?:OK\.*|ERR(?: +(0|[1-9][0-9]{0,5}))?) *", re.IGNORECASE)


def _number_verdict(number: int) -> Verdict:
    if number == 0:
        return Verdict.ACCEPTED
    return Verdict.REFUSED if number in ERROR_DESCRIPTIONS else Verdict.GARBLED


def err_verdict(line: str) -> tuple[Verdict, int | None]:
    """Judge the reply of the ``?err`` written behind a line.

    Clean is the error number as a decimal value (L2847), one the manual documents
    (chapter 5, L961-1034), with no leading zero: a glued or flipped byte that still
    makes a number (``07``, ``50``) is garbled; ``0`` accepts."""
    match = _ERR_REPLY.fullmatch(line)
    if match is None:
        return Verdict.GARBLED, None
    number = int(match[1])
    return _number_verdict(number), number


def ack_verdict(line: str) -> tuple[Verdict, int | None]:
    """Judge an autostatus-2 acknowledgement: ``OK...`` accepts, ``ERR n`` with a
    documented non-zero ``n`` (or a bare ``ERR``) refuses, anything else is garbled."""
    match = _ACK_REPLY.fullmatch(line)
    if match is None:
        return Verdict.GARBLED, None
    if line.strip()[:2].upper() == "OK":
        return Verdict.ACCEPTED, 0
    if match[1] is None:
        return Verdict.REFUSED, None
    number = int(match[1])
    return (Verdict.GARBLED if number == 0 else _number_verdict(number)), number


@dataclass(frozen=True, slots=True)
class Contest:
    """What a state read behind a verdict that refused a motion line or made no sense
    shows (:func:`contest`)."""

    #: The line's axes that move (``M``): stop them, and say so.
    moving: tuple[str, ...]
    #: Whether a clean refusal stands: none of the line's axes moves and no report came.
    stands: bool
    #: What the read shows, in words (when the refusal stands: empty, or which of the
    #: line's axes still move as before it).
    reason: str


def report_shows_run(moved: Sequence[str], letters: Mapping[str, str] | None) -> bool:
    """Whether a motion line's completion report shows that the line ran: any report
    does, but one with ``E`` for every axis of the line, which some firmware sends for a
    refused move (switch ``refused_move_report``; the manual is silent: L2690-2705 name
    ``E`` "error response, move aborted or not executed")."""
    if letters is None or not moved:
        return True
    return any(letters.get(axis, AxisStatus.ERROR) != AxisStatus.ERROR for axis in moved)


def contest(moved: Sequence[str], letters: Mapping[str, str], *, clean: bool,
            reported: bool = False, busy: Collection[str] = (),
            shifted: Collection[str] = ()) -> Contest:
    """Whether the state read behind a refused or garbled verdict on a motion line
    contradicts it.

    A single flipped bit turns ``0`` into a documented number (``1``, ``2``, ``4``,
    ``8``), so even a clean refusal may be a garbled acceptance: the line's axes
    moving (``M``, L2695), or its completion report, show that it ran. A garbled
    verdict with nothing moving leaves the line's fate unknown (a short move may have
    ended already)."""
    moving = tuple(a for a in moved
                   if letters.get(a) == MOVING and not (clean and a in busy))
    named = " ".join(moving).upper()
    if moving:
        return Contest(moving, False, f"yet ?statusaxis shows {named} moving: the line ran")
    if reported:
        return Contest((), False, "yet its completion report came: the line ran")
    away = [a for a in moved if a in shifted and not (clean and a in busy)]
    if away:
        return Contest((), False, f"yet ?pos shows {' '.join(away).upper()} moved since "
                                  "before the line: it ran")
    if clean:
        before = " ".join(a for a in moved if letters.get(a) == MOVING).upper()
        return Contest((), True, f"{before} still moving as before the line" if before else "")
    standing = " ".join(moved).upper()
    return Contest((), False, f"the line's fate is unknown; ?statusaxis shows "
                              f"{standing or 'no axis of it'} standing: nothing of it moves")


def shifted_axes(axes: Sequence[str], before: Mapping[str, str] | None,
                 now: Mapping[str, str]) -> tuple[str, ...]:
    """The axes whose position, as printed, moved between two reads: by more than three
    times the larger :func:`position_tolerance` of the two (a count or two of encoder
    jitter is no move)."""
    if not before:
        return ()
    return tuple(a for a in axes if a in before and a in now and abs(
        float(now[a]) - float(before[a])) > 3.0 * max(position_tolerance(now[a]),
                                                       position_tolerance(before[a])))


#: The fastest ``!speed`` the manual documents: 100 rev/s, or 100 mm/s in dim 9 (L6718).
MAX_SPEED = 100.0


@dataclass(frozen=True, slots=True)
class Acceptance:
    """What the state read behind a motion line without a completion of its own
    (``speed``, ``go``) shows of its arrival (:func:`acceptance`)."""

    #: The line's axes it sets running that show nothing of it: standing, or moving as
    #: they did before the line.
    unshown: tuple[str, ...]
    #: The line's axes it stops (``!speed z 0``, ``go z``) that still move: a stop ramp,
    #: or a stop line that was lost; wait for them to stand (:func:`stop_time`).
    stopping: tuple[str, ...]
    #: The line's axes that move (``M``): stop them if the line stays unproven.
    moving: tuple[str, ...]
    #: The ``?statusaxis`` letters read behind the line.
    letters: Mapping[str, str] = field(default_factory=dict)

    @property
    def shown(self) -> bool:
        """Whether the read proves the line: every axis it sets running shows it, and
        every axis it stops stands."""
        return not self.unshown and not self.stopping

    @property
    def reason(self) -> str:
        """What the read shows of the axes that show nothing of the line, in words."""
        parts = [f"{a.upper()} moving as before the line" if a in self.moving else
                 f"{a.upper()} standing ({self.letters.get(a, '?')})" for a in self.unshown]
        parts += [f"{a.upper()} still moving" for a in self.stopping]
        return f"?statusaxis shows {', '.join(parts)}" if parts else ""


def acceptance(command: Command, letters: Mapping[str, str], present: Sequence[str], *,
               busy: Collection[str] = (),
               positions: Mapping[str, str] | None = None) -> Acceptance:
    """Whether the state read behind a ``speed`` or ``go`` line shows that it arrived.

    In autostatus 0, 1 and 3 neither line owes an answer (``go``: "Response: None",
    L6662; ``speed`` does not report, L6760), and the ``?err`` 0 behind it is also what a
    lost line gets (each instruction overwrites the error state, L2853-2867). The
    interpreter executes lines in order, so ``?statusaxis`` read behind the line shows
    its effect. An axis the line sets running (a non-zero speed, a go target) that
    moves (``M``, L2695), and did not move before the line (``busy``), proves that the
    line arrived, and with it the rest of the line. Else each axis must show what the
    line asked: one it stops (speed 0, L6724; ``go`` without a target, L6624-6630)
    stands, or is still on its stop ramp (:attr:`Acceptance.stopping`: the caller waits
    for it, :func:`stop_time`); one a ``go`` sends stands at its target (``positions``,
    as printed: a short go may be done). An axis that stands where the line sets it
    running (at a switch or a soft limit in its direction, L6724, or not enabled), or
    moves as before it, shows nothing: the line may not have arrived."""
    moved = moved_axes(command, present)
    values = [float(v) for v in command.values if isinstance(v, int | float)]
    runs: dict[str, float] = {}
    stops: list[str] = []
    for index, axis in enumerate(moved):
        value = values[index] if index < len(values) else None
        if value is None or (command.name == "speed" and value == 0.0):
            stops.append(axis)
        else:
            runs[axis] = value
    moving = tuple(a for a in moved if letters.get(a) == MOVING)
    if any(a in moving and a not in busy for a in runs):
        return Acceptance((), (), moving, dict(letters))
    unshown = [a for a, value in runs.items()
               if not (command.name == "go" and a not in moving
                       and _at(value, (positions or {}).get(a)))]
    stopping = tuple(a for a in stops if a in moving)
    return Acceptance(tuple(unshown), stopping, moving, dict(letters))


def _at(target: float, printed: str | None) -> bool:
    """Whether a position as printed stands at ``target``."""
    try:
        return printed is not None and \
            abs(float(printed) - target) <= position_tolerance(printed)
    except ValueError:
        return False


def speed_shown(value: float, printed: str) -> bool:
    """Whether ``?speed`` of an axis, as printed, shows the speed ``value`` a line set:
    the speed in force (L6758), within one and a half units of its last digit."""
    return _at(value, printed.strip())


def stop_time(timing: MoveTiming, axes: Iterable[str]) -> float:
    """How long axes that a ``speed`` 0 or a ``go`` without target stops may still move:
    the ramp from the fastest speed (:data:`MAX_SPEED`, or ``vel`` if faster) down at
    ``accel`` (L6728), and :data:`MARGIN`."""
    longest = 0.0
    for axis in axes:
        index = AXES.index(axis)
        scale = UnitScale(dim=timing.dims[index], pitch=timing.pitch[index])
        top = scale.mm_to_rev(MAX_SPEED) if timing.dims[index] == 9 else MAX_SPEED
        top = max(top, scale.vel_from_user(timing.vel[index]))
        accel = scale.accel_to_rev(timing.accel[index])
        ramp = top / accel if accel > 0 and math.isfinite(accel + top) else UNKNOWN_TRAVEL
        longest = max(longest, ramp)
    return longest + MARGIN
