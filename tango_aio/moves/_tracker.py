"""The move tracker without I/O: what a move does next, driven by events, answering intents.

* **Planning** (:meth:`MoveTracker.start`): where a ``move_by``'s start comes from. The
  position the driver read last is its start only while nothing but this driver's own
  lines can have moved the stage since: the HDI was turned off on this link (``!joy 0``;
  a joystick moves the axes, L6318-6323, and ``a`` cannot stop it, L6826), the snapshot
  and the pulse/direction inputs move nothing (L14520-14530, L9914-9930), the position
  was read by the confirmation of this link's last move of that axis, and no other ``!``
  line went out since. Otherwise ``?pos`` is read: in the same write as the line when
  the unit's per-axis replies are exact, else first. These per-connection facts
  (:attr:`MoveTracker.hdi_off`, :attr:`MoveTracker.inputs_idle`,
  :attr:`MoveTracker.start_known`) are the tracker's state; :meth:`MoveTracker.written`,
  :meth:`MoveTracker.accepted`, :meth:`MoveTracker.inputs_read`,
  :meth:`MoveTracker.power_cycled` and :meth:`MoveTracker.confirmed` keep them.
* **Following** (:class:`Follow`): a state enum (:class:`Phase`) and one transition
  table (:data:`FOLLOW`). The adapter waits until :attr:`Follow.wake` (or a hint: a
  completion report, a stop, a lost link), reads the state, and hands the read to
  :meth:`Follow.read` (or :meth:`Follow.read_lost`); the answer is an :class:`Intent`:
  wait again, the move arrived, it failed, an axis cut it short, its budget is spent, or
  the driver stopped it. Success needs a state read showing every moved axis standing at
  its target without a failure letter (:func:`~tango_aio.moves._timing.failed_axes`); a
  stop by this driver is never a success.
* **Acceptance**: the proof that a move line whose acknowledgement did not come where
  owed arrived (:func:`acceptance_shown`), and the proof that a ``speed`` or ``go`` line
  answered by ``?err`` 0 alone arrived (:class:`StartProof`: which read next, judged by
  :func:`~tango_aio.moves._timing.acceptance` and
  :func:`~tango_aio.moves._timing.speed_shown`, until it is proven or not).
* **Letters of a failure** (:func:`failed_letters`): the letters a failed move reports,
  no axis that did not end well reading an arrival, so that a caller that looks at one
  axis of a merged move (the IOC, by ``ARRIVED_LETTERS``) judges as the verdict did.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Final

from ..catalog import Command
from ..status import ARRIVED_LETTERS, MOVING, AxisStatus
from ._timing import (
    POLL_GRACE,
    Acceptance,
    Budget,
    acceptance,
    cut_short,
    failed_axes,
    moved_axes,
    polled_during,
    speed_shown,
    too_early,
    verdict,
)

__all__ = ["FOLLOW", "POLL_MAX", "POLL_MIN", "Confirmation", "Follow", "FollowStateError", "Intent",
           "MoveTracker", "Next", "Phase", "ProofStep", "Prove", "Start", "StartProof",
           "acceptance_shown", "failed_letters", "optional_axes"]

#: First and longest interval between two state polls once the expected end has passed.
POLL_MIN: Final = 0.05
POLL_MAX: Final = 0.5

#: ``!`` lines after which the HDI is on again (until a ``!joy 0`` is accepted).
_HDI_ON_AGAIN: Final = frozenset({"joy", "reset", "restore"})
#: ``!`` lines after which whether the inputs are idle is read again.
_INPUT_CHANGES: Final = _HDI_ON_AGAIN | {"snsm", "tvr"}


@dataclass(frozen=True, slots=True)
class Confirmation:
    """The state read that confirms a move (:meth:`MoveTracker.confirmation`)."""

    #: Whether the letters are read with ``sa`` (else ``?statusaxis``).
    short: bool
    #: The one axis whose position is read (``?pos x``); ``None``: ``?pos``, every axis.
    single: str | None


class Start(enum.Enum):
    """Where a move's start comes from (:meth:`MoveTracker.start`)."""

    NONE = "none"  #: the line has no targets (``cal``, ``rm``, ``moc``)
    KNOWN = "known"  #: the position the driver read last (a ``move_to``: for its budget)
    BATCH = "batch"  #: ``?pos`` written right before the line, in the same write
    READ = "read"  #: ``?pos`` read first


@dataclass(slots=True)
class MoveTracker:
    """A connection's facts about its moves (see the module)."""

    #: ``!joy 0`` was accepted on this link (the HDI is off, L7101-7144).
    hdi_off: bool = False
    #: ``?snsm`` read 0 and ``?tvr`` 0 for every axis since (``None``: not read yet).
    inputs_idle: bool | None = None
    #: Axes whose remembered position was read after their last move while nothing could
    #: move the stage; emptied by every other ``!`` line.
    start_known: set[str] = field(default_factory=set)
    #: ``!`` lines written (not counting moves).
    executed: int = 0
    #: Whether a confirmation may read the letters with ``sa``: cleared for good once an
    #: ``sa`` went unanswered (a firmware that does not know it).
    short_status: bool = True

    @property
    def still(self) -> bool:
        """Whether nothing but this driver's own lines can move the stage."""
        return self.hdi_off and self.inputs_idle is True

    def written(self, name: str) -> None:
        """A ``!`` line other than a move went out: it may move the stage or change what
        ``?pos`` prints, so no remembered position is a start until a move confirms it."""
        self.executed += 1
        self.start_known.clear()
        if name in _INPUT_CHANGES:
            if name in _HDI_ON_AGAIN:
                self.hdi_off = False  # until a !joy 0 is accepted
            self.inputs_idle = None  # read again once the HDI is off

    def accepted(self, command: Command) -> bool:
        """A ``!`` line was accepted: whether the inputs are to be read now."""
        # (The adapter reads ?snsm and ?tvr and hands the answer to inputs_read.)
        if command.is_read:
            return False
        if command.name == "joy":
            self.hdi_off = [float(v) for v in command.values
                            if isinstance(v, int | float)] == [0.0]
        return self.hdi_off and self.inputs_idle is None and \
            command.name in ("joy", "snsm", "tvr")

    def inputs_read(self, idle: bool) -> None:
        """Whether neither input moves the stage (``False`` also when unreadable)."""
        self.inputs_idle = idle

    def power_cycled(self) -> None:
        """The controller may have restarted: the HDI is on again, no start is known."""
        self.hdi_off, self.inputs_idle = False, None
        self.start_known.clear()

    def start(self, moved: Sequence[str], targets: Collection[str] | None, *,
              relative: bool, last: Mapping[str, str] | None, exact_replies: bool) -> Start:
        """Where the start of a move of ``targets`` comes from (see the module)."""
        # A move_to's start sizes its budget only. ``last``: the positions the driver read
        # last. The moved axes are no known start until confirmed() (this move ended).
        remembered = set(self.start_known)
        self.start_known.difference_update(moved)
        if targets is None:
            return Start.NONE
        known = last if not relative or set(targets) <= remembered else None
        if relative and known is None and last is not None and exact_replies:
            return Start.BATCH
        if known is None or not set(targets) <= set(known):
            return Start.READ
        return Start.KNOWN

    def confirmation(self, axes: Sequence[str], present: Sequence[str], *, family: str,
                     autostatus: int, exact_replies: bool) -> Confirmation:
        """The state read that confirms a move of ``axes`` (none: a read of every axis).

        The letters are read with ``sa``, the alias the 1.71 manual gives ``?statusaxis``
        (L2663: "?statusaxis or statusaxis or sa"), 3 bytes on the wire instead of 12;
        ``?statusaxis`` where the alias is not known to work: a unit of the older
        edition's family (its section has no alias, old L733), one that left an ``sa``
        unanswered (:meth:`alias_unanswered`), and modes 2 and 4, whose acknowledgements
        and echoes the manual describes for ``!`` lines and reads but not for a bare
        alias (L2099-2117). The position of a move of one axis is read alone
        (``?pos x``) on a unit whose per-axis reads answer one value (``exact_replies``)."""
        short = bool(axes) and self.short_status and family == "1.71" \
            and autostatus in (0, 1, 3)
        single = len(axes) == 1 and len(present) > 1 and axes[0] in present \
            and exact_replies
        return Confirmation(short, axes[0] if single else None)

    def alias_unanswered(self) -> None:
        """An ``sa`` went unanswered (or met the position's reply): never again."""
        self.short_status = False

    def confirmed(self, name: str, moved: Sequence[str], executed: int) -> None:
        """A move ended confirmed where it stands; ``executed``: :attr:`executed` when it
        was called (another line meanwhile leaves its start unknown)."""
        if name in ("moa", "mor") and self.still and executed == self.executed:
            self.start_known.update(moved)


def acceptance_shown(reported: bool, letters: Mapping[str, str],
                     moved: Sequence[str]) -> bool:
    """Whether a move line whose acceptance was deferred (its autostatus-2 ``OK...`` or
    autostatus-4 echo did not come where owed, the ``?err`` behind it answered 0) is
    proven to have arrived, from what came by the reply of a ``?statusaxis`` read
    written behind it: its completion report, or a moved axis moving (``M``, L2695).
    Every moved axis standing with no report leaves it unproven: the line may have been
    lost."""
    return reported or any(letters.get(axis) == MOVING for axis in moved)


def optional_axes(command: Command, moved: Sequence[str]) -> tuple[str, ...]:
    """The moved axes that may read ``-``: an all-axes ``cal``, ``rm`` or ``moc``'s."""
    # (It moves the enabled axes; a disabled one takes no part.)
    return tuple(moved) if command.axis is None and not command.values else ()


def failed_letters(letters: Mapping[str, str], failed: Collection[str]) -> dict[str, str]:
    """``letters``, each failed axis that reads an arrival (``@``, ``A``, ``D``) as ``E``."""
    return {a: (AxisStatus.ERROR.value if a in failed and s in ARRIVED_LETTERS else s)
            for a, s in letters.items()}


class Phase(enum.Enum):
    """Where a followed move stands."""

    WAITING = "waiting"  #: until :attr:`Follow.wake` or a hint, then the state is read
    READING = "reading"  #: a state read is under way
    ENDED = "ended"  #: an end intent was given: nothing leaves this state


class _Event(enum.Enum):
    READ_SENT = "read sent"
    REPLIED = "read replied"
    ENDED = "ended"


_P, _V = Phase, _Event
#: Every transition of a followed move: (phase, event) -> next phase. A read is judged
#: in WAITING: it ends the move or sets the next wake.
FOLLOW: Final[dict[tuple[Phase, _Event], Phase]] = {
    (_P.WAITING, _V.READ_SENT): _P.READING,
    (_P.READING, _V.REPLIED): _P.WAITING,
    (_P.WAITING, _V.ENDED): _P.ENDED,
}


class FollowStateError(RuntimeError):
    """An event the follow table does not allow now (the adapter's bug)."""


class Next(enum.Enum):
    """What the adapter does next (:class:`Intent`)."""

    WAIT = "wait"  #: wait for a hint until ``until``, then read the state
    ARRIVED = "arrived"  #: publish the success and return ``letters``
    FAILED = "failed"  #: publish the failure, raise MoveError(``message``, ``letters``)
    CUT_SHORT = "cut short"  #: stop the others, wait until they stand, raise MoveError
    TIMED_OUT = "timed out"  #: stop the axes, wait, raise ControllerTimeoutError
    ABORTED = "aborted"  #: the driver stopped an axis: wait until they stand, MoveError


@dataclass(frozen=True, slots=True)
class Intent:
    """One answer of :class:`Follow`."""

    next: Next
    #: Loop time to wait until (``WAIT``).
    until: float = 0.0
    #: The letters to return or to report.
    letters: Mapping[str, str] = field(default_factory=dict)
    #: What went wrong, in words (``FAILED``).
    message: str = ""
    #: The axes that ended a move early (``CUT_SHORT``).
    ended: tuple[str, ...] = ()
    #: The completion report owed did not come (``ARRIVED``: settled by polling;
    #: ``FAILED``: the controller may have restarted).
    unreported: bool = False


class Follow:
    """One motion line followed to its end (see the module)."""

    def __init__(self, moved: Sequence[str], targets: Mapping[str, float] | None,
                 tolerance: Mapping[str, float], budget: Budget, started: float, *,
                 reports: bool = True,
                 extend: Callable[[Mapping[str, str]], float] | None = None,
                 optional: Collection[str] = ()) -> None:
        self.moved = tuple(moved)
        self.targets = targets
        self.tolerance = tolerance
        self.budget = budget
        self.extend = extend
        self.optional = frozenset(optional)
        self.phase = Phase.WAITING
        #: When the line's check came back (the controller had taken the line by then).
        self.checked = started
        self.expected_end = started + budget.expected
        self.deadline = started + budget.limit
        self.extended = False
        # Without reports, or for a move of several axes (its report waits for all of
        # them), nothing tells of an early end: the state is polled during the move too.
        self._polled = polled_during(self.moved, reports)
        self._next_poll = (min(started + POLL_MAX, self.expected_end + POLL_GRACE)
                           if self._polled else self.expected_end + POLL_GRACE)
        self._interval = POLL_MIN

    def _go(self, event: _Event) -> None:
        try:
            self.phase = FOLLOW[self.phase, event]
        except KeyError:
            raise FollowStateError(
                f"{event.value!r} cannot happen in phase {self.phase.value!r}") from None

    @property
    def wake(self) -> float:
        """Loop time of the next state read, unless a hint comes first."""
        return min(self._next_poll, self.deadline)

    def check_came(self, now: float) -> None:
        """The line's check came back at ``now``: its ``!delay`` counts from there."""
        self.checked = now

    def reading(self) -> None:
        """The adapter writes a state read."""
        self._go(_Event.READ_SENT)

    def read_lost(self, now: float, *, stopped: bool) -> Intent:
        """The state read failed after a stop by this driver (else the adapter raises)."""
        if not stopped:
            raise FollowStateError("a lost read is the adapter's to raise")
        return self.read({}, {}, now, stopped=True)

    def read(self, letters: Mapping[str, str], texts: Mapping[str, str], now: float, *,
             stopped: bool = False, report: Mapping[str, str] | None = None,
             report_owed: bool = False) -> Intent:
        """A state read replied."""
        self._go(_Event.REPLIED)
        if stopped:
            return self._end(Intent(Next.ABORTED, letters=dict(letters)))
        if any(letters.get(axis) == MOVING for axis in self.moved):
            return self._moving(letters, texts, now)
        letters = _with_report(self.moved, letters, report)
        bad = failed_axes(self.moved, self.targets, self.tolerance, letters, texts,
                          optional=self.optional)
        if not bad:
            return self._end(Intent(Next.ARRIVED, letters=letters, unreported=report_owed))
        wait_until = too_early(self.budget, self.moved, letters, self.checked, now,
                               self.expected_end)
        if wait_until is not None:
            self._next_poll = wait_until
            return Intent(Next.WAIT, until=self.wake)
        message = verdict(self.moved, self.targets, self.tolerance, letters, texts,
                          optional=self.optional)
        return self._end(Intent(Next.FAILED, letters=failed_letters(letters, bad),
                                message=message or "", unreported=report_owed))

    def _moving(self, letters: Mapping[str, str], texts: Mapping[str, str],
                now: float) -> Intent:
        ended = cut_short(self.budget, self.moved, letters, self.checked, now,
                          self.expected_end)
        if ended:
            return self._end(Intent(Next.CUT_SHORT, letters=dict(letters), ended=ended))
        if now >= self.deadline:
            if self.extend is None or self.extended:
                return self._end(Intent(Next.TIMED_OUT, letters=dict(letters)))
            # The limit was sized from a position known before the move, which may be
            # stale (joystick, another program): once, size the rest from where the axes
            # are now (bounded: at most the limit and this budget).
            self.extended = True
            self.deadline = now + self.extend(texts)
        if now < self.expected_end:
            # A false hint (e.g. !joy 0): the real report or the expected end comes next
            # (without reports: the next poll of the move).
            self._next_poll = (min(now + POLL_MAX, self.expected_end + POLL_GRACE)
                               if self._polled else self.expected_end + POLL_GRACE)
        else:
            self._next_poll = now + self._interval
            self._interval = min(self._interval * 1.5, POLL_MAX)
        return Intent(Next.WAIT, until=self.wake)

    def _end(self, intent: Intent) -> Intent:
        self._go(_Event.ENDED)
        return intent


def _with_report(moved: Sequence[str], letters: Mapping[str, str],
                 report: Mapping[str, str] | None) -> dict[str, str]:
    """The letters to return: the read's for the moved axes, the report's for others."""
    # Only a report with one letter per present axis can be assigned (statusaxis keeps
    # e.g. the D of an earlier rm, which says nothing about this move, L2676-2711).
    if not report or set(report) != set(letters):
        return dict(letters)
    merged = dict(report)
    merged.update({axis: letters[axis] for axis in moved if axis in letters})
    return merged


class Prove(enum.Enum):
    """What :class:`StartProof` asks next."""

    READ_STATUS = "read ?statusaxis"  #: hand the letters to :meth:`StartProof.status`
    READ_POSITIONS = "read ?pos"  #: hand the positions to :meth:`StartProof.positions`
    READ_SPEED = "read ?speed"  #: of ``axis``; hand it to :meth:`StartProof.speed`
    PROVEN = "proven"  #: the line arrived
    UNPROVEN = "unproven"  #: stop ``found``'s moving axes; the line may not have arrived


@dataclass(frozen=True, slots=True)
class ProofStep:
    """One answer of :class:`StartProof`."""

    next: Prove
    #: Seconds to wait before the read.
    wait: float = 0.0
    #: The axis whose ``?speed`` to read (``READ_SPEED``).
    axis: str = ""
    #: What the reads showed (``PROVEN``, ``UNPROVEN``).
    found: Acceptance | None = None

    @property
    def running(self) -> tuple[str, ...]:
        """The line's axes to stop when it stays unproven (moving, or still stopping)."""
        if self.found is None:
            return ()
        return tuple(dict.fromkeys((*self.found.moving, *self.found.stopping)))


class _Proving(enum.Enum):
    FIRST = "first read"
    POSITIONS = "positions"
    SPEEDS = "speeds"
    STOPPING = "stopping"
    DONE = "done"


class StartProof:
    """The proof that a ``speed`` or ``go`` line answered by ``?err`` 0 alone arrived."""

    def __init__(self, command: Command, present: Sequence[str], *,
                 busy: Collection[str], deadline: float, poll: float) -> None:
        self.command = command
        self.present = tuple(present)
        self.busy = frozenset(busy)
        self.deadline = deadline
        self.poll = poll
        self._phase = _Proving.FIRST
        self._found = Acceptance((), (), ())
        self._left: list[str] = []
        self._round: list[str] = []
        self._letters: Mapping[str, str] = {}

    def begin(self) -> ProofStep:
        """The first read: ``?statusaxis`` behind the line."""
        return ProofStep(Prove.READ_STATUS)

    def _expect(self, *phases: _Proving) -> None:
        if self._phase not in phases:
            raise FollowStateError(f"a reply cannot come in phase {self._phase.value!r}")

    def status(self, letters: Mapping[str, str], now: float) -> ProofStep:
        """``?statusaxis`` replied at ``now``."""
        self._expect(_Proving.FIRST, _Proving.STOPPING)
        if self._phase is _Proving.STOPPING:
            stopping = tuple(a for a in self._found.stopping if letters.get(a) == MOVING)
            self._found = replace(self._found, stopping=stopping)
            return self._stopping(now)
        found = acceptance(self.command, letters, self.present, busy=self.busy)
        if found.unshown and self.command.name == "go":
            self._letters, self._phase = letters, _Proving.POSITIONS
            return ProofStep(Prove.READ_POSITIONS)
        return self._accepted(found, now)

    def positions(self, texts: Mapping[str, str], now: float) -> ProofStep:
        """``?pos`` replied at ``now`` (as printed, per axis)."""
        self._expect(_Proving.POSITIONS)
        found = acceptance(self.command, self._letters, self.present, busy=self.busy,
                           positions=texts)
        return self._accepted(found, now)

    def _accepted(self, found: Acceptance, now: float) -> ProofStep:
        self._found = found
        if found.unshown and set(found.unshown) <= self.busy:
            self._phase = _Proving.SPEEDS
            self._left = list(found.unshown)
            self._round = list(self._left)
            return ProofStep(Prove.READ_SPEED, axis=self._round[0])
        return self._stopping(now)

    def speed(self, axis: str, printed: str, now: float) -> ProofStep:
        """``?speed`` of ``axis`` replied at ``now``."""
        self._expect(_Proving.SPEEDS)
        if not self._round or self._round[0] != axis:
            raise FollowStateError(f"?speed of {axis!r} was not asked for")
        self._round.pop(0)
        values = dict(zip(moved_axes(self.command, self.present), self.command.values,
                          strict=False))
        if speed_shown(float(values[axis]), printed):
            self._left.remove(axis)
        if self._round:
            return ProofStep(Prove.READ_SPEED, axis=self._round[0])
        if self._left and now < self.deadline:
            self._round = list(self._left)
            return ProofStep(Prove.READ_SPEED, wait=self.poll, axis=self._round[0])
        self._found = replace(self._found, unshown=tuple(self._left))
        return self._stopping(now)

    def _stopping(self, now: float) -> ProofStep:
        if self._found.stopping and now < self.deadline:
            self._phase = _Proving.STOPPING
            return ProofStep(Prove.READ_STATUS, wait=self.poll)
        self._phase = _Proving.DONE
        return ProofStep(Prove.PROVEN if self._found.shown else Prove.UNPROVEN,
                         found=self._found)
