"""The link session: what a link decides about its own state. No I/O, no asyncio.

* **resync and quiet resync**: a resync writes the marker ``?help N`` and the core drops
  every line up to its unique reply; on firmware without ``?help N``
  (:attr:`~tango_aio.sansio._core.HelpStyle.NONE`) ``help`` is written and the stream is in step
  once the reply of ``help`` (``ERROR n,text``, L2915-2919, old L805-819) was the last
  line and the link has been quiet for :attr:`LinkSession.quiet_interval`;
* **exchanges**: lines written with the core dropping every line, the lines that come
  back collected up to what ends them (:class:`Until`): the mode exchange
  (:meth:`LinkSession.mode_lines`, :meth:`LinkSession.mode_read`) and the detection at
  connect (:meth:`LinkSession.numbered_marker_lines`, :meth:`LinkSession.help_read`);
* **the mode**: when a mode change may go (:meth:`LinkSession.barrier`), and the verdict
  on what its exchange read back: the change failed (:meth:`LinkSession.mode_changed`),
  or the controller restarted and the driver's mode is restored
  (:meth:`LinkSession.mode_verified`), as :class:`ModeVerdict`;
* **liveness**: what an overdue reply calls for (wait once more, withdraw the line, count
  it, or resync behind a lost reply nobody awaits: :meth:`LinkSession.reply_overdue`,
  :class:`Overdue`), dead-link counting and
  a new marker for an overdue one (:meth:`LinkSession.unanswered`,
  :meth:`LinkSession.marker_overdue`, :class:`Silence`), and the keepalive's schedule
  (:meth:`LinkSession.keepalive_wait`);
* **link timing**: the quiet interval grows with the link's byte time
  (:meth:`LinkSession.baud_known`) and the round trips of its exchanges, measured from the
  times the adapter passes in (:meth:`LinkSession.bytes_received`); quiet means no byte,
  not no line (:mod:`tango_aio.sansio._linktiming`).
"""

from __future__ import annotations

import collections
from collections.abc import Container, Hashable, Sequence
from typing import Final

from ..catalog import encode
from ..errors import ProtocolError
from ._core import HelpStyle, ProtocolCore
from ._exchange import (
    _INTEGER,
    STATUS_READ,
    Exchange,
    Until,
    _is_help_reply,
    nothing_trails_help,
    reads_acknowledged,
    status_tail,
)
from ._linkstate import (
    REPLY_WAITS,
    TRANSITIONS,
    Barrier,
    LinkEvent,
    LinkState,
    ModeVerdict,
    Outcome,
    Overdue,
    SessionStateError,
    Silence,
)
from ._linktiming import MIN_QUIET, LinkTiming
from ._patterns import ACK_PATTERN, ReplyPattern, normal_line

__all__ = [
    "DEAD_AFTER",
    "QUIET_INTERVAL",
    "LinkSession",
]

#: Consecutive unanswered requests after which a link that stays open is declared lost.
#: Two: a request's own timeout, then the resync marker written after it.
DEAD_AFTER: Final = 2
#: Seconds of silence after the reply of ``help`` that end a quiet resync, before the
#: link's timing is known (:data:`~tango_aio.sansio._linktiming.MIN_QUIET`).
QUIET_INTERVAL: Final = MIN_QUIET
#: The step-0 marker numbers of this process's latest detections
#: (:meth:`LinkSession.begin_detect`); fewer than there are marker numbers. Process-wide,
#: not per session: the detection it guards against is another session's, one abandoned
#: (cancelled, timed out) within its step 0 on the same port, whose replies are still on
#: the link when the next connect of this process starts; that session is gone by then.
_RECENT_DETECT_CODES: collections.deque[int] = collections.deque(maxlen=4)


class LinkSession:
    """The link's state, resyncs, exchanges, detection and liveness (see the module)."""

    def __init__(self, core: ProtocolCore, *, dead_after: int = DEAD_AFTER,
                 keepalive: float | None = None, detect: bool = False,
                 quiet_interval: float = QUIET_INTERVAL) -> None:
        self.core = core
        #: Consecutive unanswered requests after which a link that stays open is lost.
        self.dead_after = dead_after
        #: Seconds of silence after which an idle link is probed (``None``: never).
        self.keepalive = keepalive
        #: Seconds without a byte after the reply of ``help`` that end a quiet resync
        #: and connect's exchanges (grown by :meth:`baud_known` and measured round trips).
        self.quiet_interval = quiet_interval
        #: The link's byte time (where the baud rate is known) and the longest round trip
        #: measured by an exchange (:class:`~tango_aio.sansio._linktiming.LinkTiming`).
        self.timing = LinkTiming()
        self._sent_at: float | None = None  # an exchange's write, until its first byte
        #: Whether the first resync runs the detection instead (:meth:`detects_first`).
        self.detect_at_connect = detect
        self.state = LinkState.IN_STEP
        #: The deadline the adapter arms after :attr:`Outcome.WAIT_QUIET`.
        self.quiet_deadline: float | None = None
        #: The exchange collecting lines (``None``: none).
        self.exchange: Exchange | None = None
        #: What :meth:`end_detect` and :meth:`mode_read` found out (``help_number``,
        #: ``ack_reads``).
        self.detected: dict[str, str] = {}
        #: Consecutive unanswered requests with no line in between.
        self.silent = 0
        #: Loop time of the last reply line (the keepalive waits from there).
        self.last_reply = 0.0
        self._counted_upto = 0  # lines written when the last unanswered one was counted
        self._help_last = False  # whether the reply of help was the last line dropped
        self._marker: Hashable | None = None  # the tag of the marker the core awaits

    def _go(self, event: LinkEvent) -> None:
        try:
            self.state = TRANSITIONS[self.state, event]
        except KeyError:
            raise SessionStateError(
                f"{event.value!r} cannot happen in state {self.state.value!r}") from None

    @property
    def lost(self) -> bool:
        """Whether the link is closed or declared dead."""
        return self.state is LinkState.LOST

    # -- resync -------------------------------------------------------------------------

    def begin_resync(self, tag: Hashable, *, ctrl_c: bool = False) -> bytes:
        """Start a resync whose marker (if this controller has markers) is registered
        under ``tag``; return the bytes to write (see
        :meth:`~tango_aio.sansio._core.ProtocolCore.resync`)."""
        data = self.core.resync(tag, ctrl_c=ctrl_c)
        quiet = self.core.quiet
        self._marker = None if quiet else tag
        self._go(LinkEvent.HELP_WRITTEN if quiet else LinkEvent.MARKER_WRITTEN)
        self._help_last = False
        return data

    def detects_first(self, *, ctrl_c: bool) -> bool:
        """Whether a resync asked for now runs the detection instead: the first one of a
        link opened by ``connect``, unless it is a Ctrl+C."""
        return self.detect_at_connect and not self.detected and not ctrl_c

    def marker_overdue(self, serial: int, written: int, *, newest: bool) -> Silence:
        """A resync's marker got no reply in time: count it unanswered (:meth:`unanswered`);
        if the link lives on, a new marker follows when the overdue one was the newest
        resync's and the stream is not in step yet, so lines held behind it are not held
        for ever."""
        silence = self.unanswered(serial, written)
        if silence is Silence.ALIVE and newest and self.core.resyncing:
            return Silence.MARKER_AGAIN
        return silence

    def replied(self, tag: Hashable) -> bool:
        """A :class:`~tango_aio.sansio._core.Replied` event for ``tag``: whether it is the reply
        of the marker the core awaited (then the stream is in step)."""
        if tag is None or tag != self._marker:
            return False
        self._marker = None
        self._go(LinkEvent.MARKER_ANSWERED)
        return True

    def line_dropped(self, line: str, now: float) -> Outcome:
        """A line the core dropped (a :class:`~tango_aio.sansio._core.Dropped` event) at loop time
        ``now``: collected by the exchange, or watched by a quiet resync."""
        exchange = self.exchange
        if exchange is not None:
            exchange.lines.append(line)
            if exchange.until is Until.MARKER:
                return self._marker_line(exchange, line, now)
            if exchange.until is Until.HELP:
                # Sticky: an acknowledgement of ?help itself may follow its reply.
                self._help_last = self._help_last or _is_help_reply(line.strip())
                if self._help_last and nothing_trails_help(exchange.lines):
                    return self._collected()
                return self._wait_quiet(now)
            return self._collected() if _INTEGER.match(line) else Outcome.NONE
        if not self.core.quiet:
            return Outcome.NONE
        text = line.strip()
        if _is_help_reply(text):
            self._help_last = True
        elif normal_line(text) != "help" and not ACK_PATTERN.accepts(text):
            # Anything but help's own echo (mode 4) or an acknowledgement (mode 2) after
            # its reply: that reply was not the last line yet.
            self._help_last = False
        return self._wait_quiet(now)

    def report_seen(self, line: str) -> None:
        """A line the core took for a completion report (it routes them even while it
        drops every other line): a mode exchange under way keeps it among its lines,
        where :func:`status_tail` may find it to be the reply of ``?statusaxis`` (the
        other exchanges take only their own replies)."""
        if self.exchange is not None and self.exchange.until is Until.HELP:
            self.exchange.lines.append(line)

    def _marker_line(self, exchange: Exchange, line: str, now: float) -> Outcome:
        """Count the marker replies in a row, then the number that ends them."""
        assert exchange.marker is not None
        text = line.strip()
        if normal_line(text) in exchange.echoes or ACK_PATTERN.accepts(text):
            pass  # an echo (mode 4) or an acknowledgement (mode 2): not a reply
        elif text.startswith(exchange.marker):
            exchange.run = min(exchange.run + 1, 2)
        elif exchange.run == 2 and _INTEGER.match(text):
            exchange.run = 3
            return self._collected()
        else:
            exchange.run = 0
        return self._wait_quiet(now)

    def _wait_quiet(self, now: float) -> Outcome:
        self.quiet_deadline = now + self.quiet_interval
        return Outcome.WAIT_QUIET

    def _collected(self) -> Outcome:
        self.quiet_deadline = None
        return Outcome.COLLECTED

    def quiet_elapsed(self) -> Outcome:
        """The quiet deadline armed last has passed with no line since: the exchange
        has what it waits for, or the quiet resync ends (the core is in step)."""
        self.quiet_deadline = None
        if not self.core.quiet or not self._help_last or self.lost:
            return Outcome.NONE
        if self.exchange is not None:
            return Outcome.COLLECTED
        self.core.end_resync()
        self._go(LinkEvent.QUIET)
        return Outcome.IN_STEP

    # -- link timing --------------------------------------------------------------------

    def baud_known(self, byte_seconds: float) -> None:
        """The link runs at a known baud rate (a serial port the driver opened): its
        quiet interval spans ``QUIET_BYTES`` byte times at least."""
        self.timing.byte_seconds = byte_seconds
        self.quiet_interval = max(self.quiet_interval, self.timing.quiet_interval)

    def bytes_received(self, now: float) -> Outcome:
        """Bytes arrived at loop time ``now`` (before the core splits them into lines).
        The first after an exchange's write measures the link's round trip, which may
        lengthen the quiet interval; and a quiet deadline already armed starts again, since
        quiet means no byte, not no line (on a slow link a line takes longer than the
        interval)."""
        if self._sent_at is not None:
            if self.timing.observe(now - self._sent_at):
                self.quiet_interval = max(self.quiet_interval, self.timing.quiet_interval)
            self._sent_at = None
        if self.quiet_deadline is None:
            return Outcome.NONE
        return self._wait_quiet(now)

    # -- exchanges ----------------------------------------------------------------------

    def begin_exchange(self, lines: Sequence[str], until: Until,
                       marker: str | None = None, *, now: float | None = None) -> bytes:
        """Start collecting what ``lines`` bring back, with the core dropping every line
        (only when nothing is owed); return the bytes to write. With ``marker``
        (:attr:`Until.MARKER`), quiet after any line ends the exchange too. With ``now``
        (the loop time of the write), the first byte back measures the link's round trip
        (:meth:`bytes_received`)."""
        self.core.drop_all()
        self._marker = None
        self._go(LinkEvent.EXCHANGE_WRITTEN)
        self._help_last = until is Until.MARKER
        self.quiet_deadline = None
        self._sent_at = now
        self.exchange = Exchange(until, marker, frozenset(normal_line(line) for line in lines))
        return b"".join(encode(line) for line in lines)

    def exchange_timed_out(self) -> None:
        """The exchange got no answer in time: stop collecting, the core routes again
        (the adapter counts the line unanswered and resyncs)."""
        self.exchange = None
        self.quiet_deadline = None
        self._sent_at = None
        self.core.end_resync()
        self._go(LinkEvent.EXCHANGE_ENDED)

    def end_exchange(self, *, in_step: bool) -> Outcome:
        """The exchange is over (``in_step``: it got what it waited for; else it was
        cancelled or timed out)."""
        self.exchange = None
        self.quiet_deadline = None
        self._sent_at = None
        if not in_step and not self.core.quiet:
            return Outcome.NONE
        self.core.end_resync()
        self._go(LinkEvent.EXCHANGE_ENDED)
        return Outcome.IN_STEP if in_step else Outcome.RESYNC

    # -- the mode -----------------------------------------------------------------------

    @staticmethod
    def mode_lines(lines: Sequence[str]) -> list[str]:
        """The lines of a mode exchange: ``lines`` (a mode change, or none), then
        ``?autostatus`` and ``?help``, whose reply ends it (:attr:`Until.HELP`)."""
        return [*lines, "?autostatus", "?help"]

    def mode_read(self, sent: Sequence[str], received: Sequence[str]) -> int:
        """From the lines a mode exchange (``sent``) brought back: the mode in force
        (adopted by the core), and in mode 2 whether reads are acknowledged, before or
        after their data (an ``OK...`` between the two replies, or after the last).
        Echoes (of any of the lines, mode 4) and acknowledgements of the lines are
        whatever they are: they are left out. Raises :class:`ProtocolError` when the
        lines hold no reply of ``?autostatus``."""
        normals = {normal_line(line) for line in sent}
        kept = [line.strip() for line in received if normal_line(line) not in normals]
        numbers = [index for index, line in enumerate(kept) if _INTEGER.match(line)]
        helps = [index for index, line in enumerate(kept) if _is_help_reply(line)]
        if not numbers or not helps:
            raise ProtocolError(f"{list(sent)!r}: no ?autostatus reply among {kept!r}")
        actual = int(kept[numbers[0]])
        self.core.autostatus = actual
        if STATUS_READ in sent and (tail := status_tail(kept)) is not None:
            self.detected["status_tail"] = tail
        if actual == 2:
            acks = reads_acknowledged(kept, numbers[0], helps[-1])
            self.core.ack_reads = acks
            self.detected["ack_reads"] = acks.value
        return actual

    def barrier(self, *, queued_before: bool, queue_dropped: bool) -> Barrier:
        """Where a barrier (a mode change, written once every line before it is answered)
        stands: lines before it still owed (by the core) or queued (``queued_before``), or
        a resync under way, hold it; Ctrl+C discarding the queue meanwhile
        (``queue_dropped``) aborts it, since a line it was meant to follow is gone.

        A resync marker whose reply came and which owes only the ``OK...`` behind it
        (the core's ``marker_acks_only``: mode 2 on firmware that acknowledges reads
        after their data) does not hold it. The stream is in step up
        to that reply; a controller that restarted is back in its power-on mode 1
        (L2062), which acknowledges nothing (L2099-2103), so that ``OK...`` never comes,
        and waiting for it would keep the read of the mode that finds the restart from
        ever being written. The exchange behind the barrier drops every line: an
        ``OK...`` that does come arrives before the exchange's own replies (the
        controller answers in order) and is dropped with the rest."""
        owed = bool(self.core.pending_tags) and not self.core.marker_acks_only
        if not (owed or self.core.resyncing or queued_before):
            return Barrier.CLEAR
        return Barrier.ABORTED if queue_dropped else Barrier.WAIT

    @staticmethod
    def barrier_overdue_resyncs(*, restore: bool) -> bool:
        """The lines before a barrier were not all answered within its timeout: whether
        the barrier resyncs the stream (its marker, the lines after the barrier still
        held) and goes on, instead of giving up. A read of the mode that checks for a
        restart (``restore``) resyncs: a controller back in its power-on mode 1 (L2062)
        never sends the ``OK...`` (L2099-2103) or the echo (L2117) that a line written
        before it owes in mode 2 or 4, and a line nobody awaits (a stop) would hold the
        barrier for ever; giving up would release the held lines, written then for a
        mode the controller no longer has. A mode change gives up (its caller sees the
        timeout)."""
        return restore

    @staticmethod
    def mode_changed(asked: int, actual: int) -> ModeVerdict:
        """The verdict on a mode change (``!autostatus asked``) from the mode its exchange
        read back (:meth:`mode_read`, which adopted it)."""
        return ModeVerdict.IN_FORCE if actual == asked else ModeVerdict.KEPT_ANOTHER

    @staticmethod
    def mode_verified(driver: int, actual: int) -> ModeVerdict:
        """The verdict on a read of the mode in force (:meth:`mode_read`) against the mode
        the driver had in force once every line before was answered: another mode means
        the controller restarted behind the link (power-on mode 1, L2062), and the driver's
        mode (``driver``) is selected again before any later line."""
        return ModeVerdict.IN_FORCE if actual == driver else ModeVerdict.RESTARTED

    # -- detection ----------------------------------------------------------------------

    def begin_detect(self, recent: collections.deque[int] | None = None) -> int:
        """Start the detection at connect: markers off until it ends; return the marker
        number for step 0 (:meth:`numbered_marker_lines`), one that no recent step 0 of
        this process used: a connect abandoned within its step 0 (cancelled, timed out)
        leaves its replies on the link, and a step 0 with the same number would take them
        for its own, then hand its own late replies to the next requests (a connect
        then fails with ``not a version reply: '1'``). The core's codes cycle through
        more numbers than ``recent`` holds."""
        if recent is None:
            recent = _RECENT_DETECT_CODES
        self.core.help_style = HelpStyle.NONE
        self.detected = {"help_number": "none"}
        code = self.core.pick_marker_code()
        while code in recent:
            code = self.core.pick_marker_code()
        recent.append(code)
        return code

    @staticmethod
    def numbered_marker_lines(code: int) -> tuple[list[str], str]:
        """Step 0 of the detection: ``help``, ``?help code`` twice and ``?err`` in one
        write, and the text the marker replies start with (an exchange
        :attr:`Until.MARKER`; :attr:`Exchange.numbered` tells whether they came in a row)."""
        return ["help", f"?help {code}", f"?help {code}", "?err"], f"ERROR {code},"

    def numbered_read(self, exchange: Exchange) -> bool:
        """Whether step 0 (``exchange``) found ``?help N`` answering ``ERROR N,...``
        (firmware 1.71, L2919): then the stream is in step and markers hold a number."""
        if exchange.numbered:
            self.core.help_style = HelpStyle.NUMBER
        return exchange.numbered

    @staticmethod
    def help_lines(code: int) -> list[str]:
        """Step 2 of the detection: ``?help code`` then ``?err`` (an exchange
        :attr:`Until.NUMBER`, read by :meth:`help_read`)."""
        return [f"?help {code}", "?err"]

    def help_read(self, code: int, sent: Sequence[str], received: Sequence[str]) -> None:
        """How ``?help code`` answered, from the lines step 2 brought back (the last is
        the ``?err`` number): ``ERROR code,...`` (firmware 1.71, L2919): markers hold a
        number; the text alone: the markers use ``code`` and wait for that text; nothing
        (older firmware, whose ``help`` takes no parameter): resyncs wait for quiet."""
        normals = {normal_line(line) for line in sent}
        kept = [line.strip() for line in received
                if not ACK_PATTERN.accepts(line.strip()) and normal_line(line) not in normals]
        # The ?err number is the last line that is neither an echo nor an acknowledgement,
        # not the last line received: in mode 4 the echo of a line may come after its
        # reply (L2117 does not say when; a unit may echo reads too, old L723), so the
        # exchange can end with the echo of ``?err`` itself.
        answers = kept[:-1]
        if any(f"ERROR {code}," in line for line in answers):
            self.core.help_style = HelpStyle.NUMBER
        elif answers and answers[-1]:
            self.core.help_style = HelpStyle.TEXT
            self.core.help_text = (code, answers[-1])

    def end_detect(self) -> None:
        """Record what the detection found (:attr:`detected`)."""
        self.detected = {"help_number": self.core.help_style.value}

    # -- liveness -----------------------------------------------------------------------

    def line_received(self) -> None:
        """Any line at all arrived (even one nobody can use): the link still forwards,
        so only silence counts towards a dead link."""
        self.silent = 0

    def reply_heard(self, now: float) -> None:
        """A reply line arrived at loop time ``now``: the link answers (the keepalive
        waits from here)."""
        self.last_reply = now

    def reply_overdue(self, *, queued: bool, written: bool, waits: int,
                      awaited: Container[Hashable] = ()) -> Overdue:
        """A request's reply did not come within its timeout: wait once more, withdraw it,
        or count it unanswered. A line still queued when the wait began (behind a resync,
        for credit) and written during it has had less than the timeout to be answered:
        its reply gets the time once more from then (at most :data:`REPLY_WAITS` timeouts
        in all), instead of being declared lost moments after its write, which would
        resync the stream under the lines written with it."""
        if not written:
            # Behind a line of the core's own (the ?err behind a move) nobody waits
            # either: it counts as owed when it is still sure to get a line (its tail).
            owed = self.core.pending_tags
            if self.state is LinkState.IN_STEP and not self.core.resyncing and (
                    owed[0] not in awaited if owed else self.core.tail is not None):
                return Overdue.STALLED
            return Overdue.WITHDRAW
        if queued and waits < REPLY_WAITS:
            return Overdue.WAIT_AGAIN
        return Overdue.UNANSWERED

    @staticmethod
    def acknowledgement_missing(expected: ReplyPattern) -> bool:
        """Whether a line that cannot be the reply it would be taken for (a
        :class:`~tango_aio.sansio._core.Mismatched` expecting ``expected``) came where an
        acknowledgement was owed: that acknowledgement went unanswered, as from a
        controller back in its power-on mode 1, which acknowledges nothing (L2062,
        L2099-2103). It tells the adapter's owner so, as an unanswered line does."""
        return expected is ACK_PATTERN

    def unanswered(self, serial: int, written: int) -> Silence:
        """Count a request (or marker) that got no reply in time; returns whether the link
        is now declared dead (:attr:`dead_after` in a row with no line at all in between:
        a link that stays open but no longer forwards, such as a serial-to-TCP adapter
        that stopped). ``serial`` numbers the line among those written, ``written`` is how
        many lines are written now: lines in flight together count once (they time out
        together when one reply is lost), so each count is a line written after the
        previous count."""
        if serial <= self._counted_upto:
            return Silence.ALIVE
        self._counted_upto = written
        self.silent += 1
        if self.silent < self.dead_after or self.lost:
            return Silence.ALIVE
        self._go(LinkEvent.DEAD)
        return Silence.DEAD

    def closed(self) -> None:
        """The link is gone (closed, lost or declared dead)."""
        self._go(LinkEvent.CLOSED)

    def keepalive_wait(self, now: float, *, busy: bool) -> float:
        """Seconds from ``now`` until the keepalive probes the link; ``0.0``: probe now.
        ``busy``: requests are in flight (they have their own deadlines)."""
        interval = self.keepalive
        if interval is None:
            raise ValueError("this session has no keepalive")
        wait = self.last_reply + interval - now
        if wait > 0:
            return wait
        return interval if busy else 0.0

    def keepalive_probed(self, now: float) -> None:
        """A keepalive probe ended at ``now`` (answered or not): the next one is due half
        an interval later at the earliest."""
        assert self.keepalive is not None
        self.last_reply = max(self.last_reply, now - self.keepalive / 2)
