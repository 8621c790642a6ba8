"""The link session's state and its answers: :class:`LinkState`, the events that change it
and the one table of transitions (:data:`TRANSITIONS`), and the enums the session answers
with (:class:`Outcome`, :class:`ModeVerdict`, :class:`Overdue`, :class:`Silence`,
:class:`Barrier`) for :class:`~tango_aio.sansio._session.LinkSession`."""

from __future__ import annotations

import enum
from typing import Final

__all__ = [
    "REPLY_WAITS",
    "TRANSITIONS",
    "Barrier",
    "LinkEvent",
    "LinkState",
    "ModeVerdict",
    "Outcome",
    "Overdue",
    "SessionStateError",
    "Silence",
]


class LinkState(enum.Enum):
    """Where the reply stream stands."""

    IN_STEP = "in step"  #: lines are routed to the requests that owe them
    RESYNC = "resync"  #: a marker is written; the core drops lines up to its reply
    QUIET_RESYNC = "quiet resync"  #: ``help`` is written; lines dropped until quiet
    EXCHANGE = "exchange"  #: an exchange's lines are written; the core drops every line
    LOST = "lost"  #: closed, or declared dead: nothing leaves this state


class LinkEvent(enum.Enum):
    """What changes the :class:`LinkState` (see :data:`TRANSITIONS`)."""

    MARKER_WRITTEN = "marker written"  #: :meth:`LinkSession.begin_resync` with a marker
    HELP_WRITTEN = "help written"  #: :meth:`LinkSession.begin_resync` without one
    EXCHANGE_WRITTEN = "exchange written"  #: :meth:`LinkSession.begin_exchange`
    MARKER_ANSWERED = "marker answered"  #: :meth:`LinkSession.replied` for the marker
    QUIET = "quiet"  #: :meth:`LinkSession.quiet_elapsed` ended a quiet resync
    EXCHANGE_ENDED = "exchange ended"  #: :meth:`LinkSession.end_exchange` (or timed out)
    DEAD = "dead"  #: :meth:`LinkSession.unanswered` declared the link dead
    CLOSED = "closed"  #: :meth:`LinkSession.closed`


_S, _E = LinkState, LinkEvent
#: Every transition: (state, event) -> next state. Resyncs may start in any live state (a
#: newer marker supersedes an older one; Ctrl+C may overtake an exchange); the marker's
#: reply may come after an exchange that was overtaken has ended (the core still owes it);
#: an exchange overtaken by a resync ends it when it ends in step (as the core does).
TRANSITIONS: Final[dict[tuple[LinkState, LinkEvent], LinkState]] = {
    (_S.IN_STEP, _E.MARKER_WRITTEN): _S.RESYNC,
    (_S.IN_STEP, _E.HELP_WRITTEN): _S.QUIET_RESYNC,
    (_S.IN_STEP, _E.EXCHANGE_WRITTEN): _S.EXCHANGE,
    (_S.IN_STEP, _E.MARKER_ANSWERED): _S.IN_STEP,
    (_S.IN_STEP, _E.EXCHANGE_ENDED): _S.IN_STEP,
    (_S.RESYNC, _E.MARKER_WRITTEN): _S.RESYNC,
    (_S.RESYNC, _E.HELP_WRITTEN): _S.QUIET_RESYNC,
    (_S.RESYNC, _E.EXCHANGE_WRITTEN): _S.EXCHANGE,
    (_S.RESYNC, _E.MARKER_ANSWERED): _S.IN_STEP,
    (_S.RESYNC, _E.EXCHANGE_ENDED): _S.IN_STEP,
    (_S.QUIET_RESYNC, _E.MARKER_WRITTEN): _S.RESYNC,
    (_S.QUIET_RESYNC, _E.HELP_WRITTEN): _S.QUIET_RESYNC,
    (_S.QUIET_RESYNC, _E.EXCHANGE_WRITTEN): _S.EXCHANGE,
    (_S.QUIET_RESYNC, _E.QUIET): _S.IN_STEP,
    (_S.QUIET_RESYNC, _E.EXCHANGE_ENDED): _S.IN_STEP,
    (_S.EXCHANGE, _E.MARKER_WRITTEN): _S.RESYNC,
    (_S.EXCHANGE, _E.HELP_WRITTEN): _S.QUIET_RESYNC,
    (_S.EXCHANGE, _E.EXCHANGE_ENDED): _S.IN_STEP,
    **{(state, event): _S.LOST for state in _S if state is not _S.LOST
       for event in (_E.DEAD, _E.CLOSED)},
    # Lost is final. (The session reports neither quiet nor a dead link once lost.)
    **{(_S.LOST, event): _S.LOST for event in _E if event not in (_E.QUIET, _E.DEAD)},
}


class SessionStateError(RuntimeError):
    """An event the transition table does not allow in the current state (the adapter's
    bug, never the controller's doing)."""


class Outcome(enum.Enum):
    """What the adapter does after a line was dropped, a quiet deadline passed or an
    exchange ended."""

    NONE = "none"  #: nothing
    WAIT_QUIET = "wait quiet"  #: (re)arm the quiet deadline (:attr:`LinkSession.quiet_deadline`)
    COLLECTED = "collected"  #: the exchange has what it waits for: wake it
    IN_STEP = "in step"  #: a quiet resync (or an exchange) ended: release the lines it held
    #: An exchange ended without what it waited for: its replies may still come, resync.
    RESYNC = "resync"


class ModeVerdict(enum.Enum):
    """What a mode exchange's reading means (:meth:`LinkSession.mode_changed`,
    :meth:`LinkSession.mode_verified`)."""

    IN_FORCE = "in force"  #: the mode asked for (or the driver's) is in force
    #: A mode change left the controller in another mode (adopted): the change failed.
    KEPT_ANOTHER = "kept another"
    #: A read found another mode than the driver's: the controller restarted (power-on
    #: mode 1, L2062); the driver's mode is selected again.
    RESTARTED = "restarted"


class Overdue(enum.Enum):
    """What the adapter does with a line whose reply did not come in time
    (:meth:`LinkSession.reply_overdue`)."""

    #: It went out during the wait (queued when the wait began): its reply gets the time
    #: once more, from now.
    WAIT_AGAIN = "wait again"
    #: Never written, held behind a resync (its marker has a deadline of its own), or
    #: behind a reply a caller still waits for (its caller's deadline covers it): take it
    #: back out of the queue, count nothing.
    WITHDRAW = "withdraw"
    #: Never written, held in step behind a reply owed to nobody who waits (a credit
    #: marker, a separator, a list's entry, a cancelled read, the ``?err`` the core
    #: writes behind a move, whose acknowledgement a restart lost): no deadline covers that
    #: reply but this one. Take the line back out of the queue, count the lines ahead
    #: of it (:meth:`LinkSession.unanswered`) and resync in the background.
    STALLED = "stalled"
    #: Written and unanswered: count it (:meth:`LinkSession.unanswered`), then resync in the
    #: background (its reply may be lost for good).
    UNANSWERED = "unanswered"


class Silence(enum.Enum):
    """What a line (or marker) left unanswered means for the link
    (:meth:`LinkSession.unanswered`, :meth:`LinkSession.marker_overdue`)."""

    ALIVE = "alive"  #: counted (or counted already, with the lines in flight with it)
    DEAD = "dead"  #: the link is now declared dead
    #: An overdue marker of the newest resync, the stream not in step yet: write a new
    #: one, so the lines held behind it are not held for ever.
    MARKER_AGAIN = "marker again"


class Barrier(enum.Enum):
    """Where a barrier (a mode change) stands (:meth:`LinkSession.barrier`)."""

    WAIT = "wait"  #: lines before it are still unwritten or unanswered, or a resync runs
    CLEAR = "clear"  #: every line before it is written and answered: go
    #: Ctrl+C discarded the queued lines: the barrier's line is not sent.
    ABORTED = "aborted"


#: Times a line's reply gets its timeout at most: once, and once more from its write when
#: it was still queued as the wait began (:meth:`LinkSession.reply_overdue`).
REPLY_WAITS: Final = 2
