"""The sans-IO protocol core: line reassembly and reply routing. No I/O, no asyncio.

* Mode 2 may acknowledge a move only when it completes, next to its report (switch
  ``move_ok=completion``; L2099-2103 do not say when). So the core writes an ``?err``
  behind every mode-2 move: its reply arriving where the move's ``OK...`` is owed shows
  that the ``OK...`` is deferred, and its number is the move's verdict. While a deferred
  ``OK...`` may still come, every acknowledged line gets such an ``?err`` too, and the
  acknowledgement lines that arrive for it are held until a line that is not one: a
  deferred acknowledgement is always ``OK...`` (a refused move is refused at once), so
  an ``ERR`` among them is the line's own, and among ``OK...`` only the count matters.
  No acknowledgement is ever credited to the wrong request.
* Mode 4 may echo a move line only when it completes (switch ``echo=completion``; L2117):
  a line that is not its echo where a move's echo is owed (the reply of the ``?err``
  probe behind it) shows that; the echo is consumed by its text when it comes.
* ``!save`` may be acknowledged a second time in mode 2 (switch ``save_ack``): an
  optional acknowledgement, with an ``?err`` behind it so that it cannot be taken for the
  next line's.
* ``OK``, ``ERR`` and ``ERROR`` may come in another case (switches ``ack_case``,
  ``help_case``): :func:`canonical_case` puts them in capitals before routing.
* A read answered by its own text means the link echoes what is sent (local echo of an
  adapter; switch ``local_echo``): a :class:`Mismatched` with :data:`LOCAL_ECHO`, and
  :attr:`ProtocolCore.local_echo` is set; the controller refuses the link at connect.
"""

from __future__ import annotations

import contextlib
import enum
import random
import re
from collections import deque
from collections.abc import Hashable
from typing import Final

from ..catalog import (
    Command,
    Context,
    Instruction,
    encode,
)
from ..errors import ERROR_DESCRIPTIONS
from ..status import ABSENT
from ._events import (
    Acknowledged,
    Completed,
    Dropped,
    Echoed,
    Event,
    Mismatched,
    Replied,
    RequestLost,
    Unsolicited,
)
from ._expect import (
    _FOLLOW_UP,
    _FOLLOW_UP_COMMAND,
    _FOLLOW_UP_ECHO,
    _OPTIONAL,
    AckReads,
    Expectation,
    _acks_itself,
    _edge,
    _front,
    _has_data,
    _Item,
    _item_pattern,
    _owed_items,
    _Pending,
    _read_items,
    _rear,
    _specific,
    _sure,
    expectation,
    owed_edge,
    wire_size,
)
from ._lines import (
    _CASED_LEADS,
    DEFAULT_MAX_LINE,
    LineAssembler,
    canonical_case,
    is_completion_line,
)
from ._linktiming import ARRIVAL_MARGIN, earliest_reply
from ._patterns import (
    ACK_PATTERN,
    ONE_NUMBER,
    Edge,
    ReplyKind,
    ReplyPattern,
    echo_pattern,
    marker_pattern,
    normal_line,
    reply_pattern,
)

__all__ = [
    "LOCAL_ECHO",
    "AckReads",
    "Acknowledged",
    "Completed",
    "Dropped",
    "Echoed",
    "Event",
    "HelpStyle",
    "LineAssembler",
    "Mismatched",
    "ProtocolCore",
    "Replied",
    "RequestLost",
    "Unsolicited",
    "canonical_case",
    "is_completion_line",
    "owed_edge",
    "wire_size",
]
#: Most lines and bytes one multi-line reply (``service``, ``detext``) may hold before the
#: request fails (a reply whose end never comes must not grow for ever). The
#: manual's ``service`` print is a few dozen lines (L2929-2943).
MAX_REPLY_LINES: Final = 1024
MAX_REPLY_BYTES: Final = 65536


#: Why a read answered by its own text fails (:attr:`ProtocolCore.local_echo`).
LOCAL_ECHO: Final = ("a read came back as itself: the link echoes every byte sent (local "
                     "echo of a serial adapter or RS-485 converter), which the driver does "
                     "not support; turn the adapter's echo off")


#: What a read line owes: its bytes, the items owed, its echo's and its data's pattern,
#: and the front and rear edges of its reply (:func:`owed_edge`, :func:`_rear`).
_Facts = tuple[bytes, tuple[_Item, ...], ReplyPattern | None, ReplyPattern, Edge | None,
               Edge | None]
#: Distinct read lines a core keeps at most (reads with many values are forgotten, not
#: hoarded).
_LINE_FACTS_MAX: Final = 1024


#: Separators that need no marker number: ``err`` answers one number, ``help`` its text
#: ``ERROR n,...`` (see :meth:`ProtocolCore.separate`).
_SEPARATORS: Final = ((b"?err\r", ONE_NUMBER), (b"?help\r", ReplyPattern(ReplyKind.HELP)))

def _echo_of(line: str) -> ReplyPattern:
    """The mode-4 echo of a line the core writes itself."""
    return ReplyPattern(ReplyKind.ECHO, text=normal_line(line))


#: Error numbers used for markers: ``?help N`` answers ``ERROR N,...`` (L2899-2919). Only
#: the encoder and ETS numbers 70-86 (L1001-1034): the ``help`` separator's reply holds the
#: current error state, so a marker number the state is likely to hold (0, the instruction
#: errors 1-13, a persistent internal error such as 29) could end a resync early.
_MARKER_CODES: Final = tuple(code for code in sorted(ERROR_DESCRIPTIONS) if code >= 70)


class _Resync(enum.Enum):
    """What the core drops lines until."""

    NONE = "in step"  #: nothing: lines are routed
    MARKER = "marker"  #: the reply of the resync marker (``_resync_marker``)
    QUIET = "quiet"  #: :meth:`ProtocolCore.end_resync` (a quiet resync, an exchange)


class HelpStyle(enum.Enum):
    """How this controller answers ``?help N`` (detected at connect: the editions differ,
    L2919, old L805-819)."""

    NUMBER = "yes"  #: ``ERROR N,text`` (L2919): markers hold a number of the session's
    TEXT = "no"  #: the text alone: markers use one number whose text was learned
    NONE = "none"  #: not at all (older firmware, old L805-819): resyncs wait for quiet


def _too_early(line: str, head: _Pending) -> str:
    """Why ``line`` that started too early is not the reply of ``head``."""
    shown = repr(line) if len(line) <= 60 else repr(line[:60]) + "..."
    request = f"{head.sent!r}" if head.sent else "its request"
    return (f"{shown} cannot be the reply to {request}: it started before the request "
            "could have been answered (stray bytes without a CR in front of the reply)")


def _is_ok(text: str) -> bool:
    """Whether an acknowledgement line is ``OK...`` (in any case: switch ``ack_case``)."""
    return text[:2].upper() == "OK"


class ProtocolCore:
    """Routes the controller's lines to requests, acknowledgements and events."""

    def __init__(self, *, autostatus: int = 1, context: Context | None = None,
                 max_line: int = DEFAULT_MAX_LINE, check_replies: bool = True,
                 max_reply_lines: int = MAX_REPLY_LINES,
                 max_reply_bytes: int = MAX_REPLY_BYTES,
                 marker_seed: int | None = None) -> None:
        self._assembler = LineAssembler(max_line)
        self._pending: deque[_Pending] = deque()
        self._moves: deque[Hashable] = deque()
        self._events: deque[Event] = deque()
        self._autostatus = autostatus
        self.context = context or Context()
        self._resync = _Resync.NONE
        self._resync_marker = ""  # the text of the marker's reply (in _Resync.MARKER)
        #: How markers are made (see :class:`HelpStyle`); ``help_text`` is the reply of
        #: ``?help <code>`` learned at connect for :attr:`HelpStyle.TEXT`.
        self.help_style = HelpStyle.NUMBER
        self.help_text: tuple[int, str] | None = None
        #: Whether reads are acknowledged in mode 2, before or after their data
        #: (``None``: not known yet; both optional).
        self.ack_reads: AckReads | None = None
        # Each session starts at a random marker number, so that the reply to a marker an
        # earlier program (or session) left on the line is unlikely to be taken for ours
        # (``marker_seed`` fixes it, for reproducible tests).
        self._marker_index = random.randrange(len(_MARKER_CODES)) if marker_seed is None \
            else marker_seed
        self._desynced = False
        #: Whether each data reply is checked against its instruction's pattern
        #: (:mod:`tango_aio.sansio._patterns`); off, any line is taken in order.
        self.check_replies = check_replies
        self._max_reply = (max_reply_lines, max_reply_bytes)
        #: How many optional lines (``"echo?"``, ``"ack?"``) arrived and were consumed:
        #: what this firmware does where the manual is silent.
        self.tolerated: dict[str, int] = {}
        #: Whether a read came back as itself: the link echoes what is sent (see
        #: :data:`LOCAL_ECHO`).
        self.local_echo = False
        #: Mode-2 moves whose OK... proved to come with their completion report (switch
        #: ``move_ok``), oldest first; and ack lines held until it is known whose they
        #: are (:meth:`_resolve_held`).
        self._deferred: deque[Hashable] = deque()
        #: Deferred moves whose completion report came: once a line that is not an
        #: acknowledgement follows the report, their OK... no longer can
        #: (:meth:`_retire_reported`).
        self._reported: set[Hashable] = set()
        #: What each read line owes, by (line, mode, ack_reads), with the instruction and
        #: the expectation it was computed for (:meth:`_line_facts`); this core's own.
        self._facts: dict[tuple[str, int, AckReads | None],
                          tuple[Instruction, Expectation, _Facts]] = {}
        self._held: list[str] = []
        #: Echoes of mode-4 moves that come with their completion report (switch
        #: ``echo=completion``), oldest first.
        self._deferred_echoes: deque[ReplyPattern] = deque()
        #: Seconds per byte of a wire known to carry bytes at that rate (0: not known;
        #: see :func:`~tango_aio.sansio._linktiming.earliest_reply`), and how much earlier than
        #: their arrival the times given to :meth:`receive_data` may be.
        self.wire_seconds = 0.0
        self.arrival_margin = ARRIVAL_MARGIN
        #: On a paced wire (:attr:`wire_seconds`): when the lines registered from now on
        #: are handed to the transport (at this time or later; ``None``: not known), on
        #: the clock of the arrival times given to :meth:`receive_data`. Set it before
        #: registering the lines of each write; a time from before the write only makes
        #: the rule milder.
        self.write_time: float | None = None
        self._wire_free = 0.0  # when the bytes registered so far have passed
        self._sent: tuple[Hashable, Edge] | None = None
        #: The front and rear edges of each separator line, by (line, mode, ack_reads).
        self._separator_edges: dict[tuple[bytes, int, AckReads | None],
                                    tuple[Edge, Edge]] = {}
        #: The fixed separator chosen between two edges (see :meth:`separator`).
        self._separator_choice: dict[tuple[int, int, int, AckReads | None],
                                     tuple[Edge, Edge, tuple[bytes, ReplyPattern] | None]] = {}

    # -- state ------------------------------------------------------------------------

    @property
    def autostatus(self) -> int:
        """The autostatus mode in force after the last line sent."""
        return self._autostatus

    @autostatus.setter
    def autostatus(self, mode: int) -> None:
        self._autostatus = mode

    @property
    def pending_tags(self) -> list[Hashable]:
        """Tags of requests still owed a reply, oldest first (a request that only
        optional lines may still follow is answered)."""
        return [p.verdict if p.verdict is not None else p.tag for p in self._pending
                if (not p.internal and not p.settled) or p.verdict is not None]

    @property
    def marker_acks_only(self) -> bool:
        """Whether every request still owed a reply (:attr:`pending_tags`) is a resync
        marker whose reply came and which owes only the acknowledgement behind it (mode 2
        on firmware that acknowledges reads after their data)."""
        return all(p.marker is not None and _Item.DATA not in p.items
                   for p in self._pending
                   if (not p.internal and not p.settled) or p.verdict is not None)

    @property
    def awaiting_completion(self) -> list[Hashable]:
        """Tags of moves still waiting for their completion report, oldest first."""
        return list(self._moves)

    @property
    def resyncing(self) -> bool:
        """Whether lines are being dropped until the resync marker's reply."""
        return self._resync is not _Resync.NONE

    @property
    def tail(self) -> tuple[Hashable, Edge] | None:
        """Tag and rear edge (:class:`~tango_aio.sansio._patterns.Edge`: its front and back edges)
        of the newest request still sure to get a line; ``None`` when none is. A line
        whose front edge overlaps it should wait until the tail is answered
        (:mod:`tango_aio.sansio._patterns`). Requests that may only still get optional lines do
        not count. Internal lines (follow-ups, markers) have tags of their own."""
        for pending in reversed(self._pending):
            if pending.rear is not None and pending.owes_sure():
                return pending.tag, pending.rear
        return None

    @property
    def sent(self) -> tuple[Hashable, Edge] | None:
        """Tag and rear edge (see :attr:`tail`) of the last line the latest :meth:`send`
        or :meth:`separate` registered that is sure to get a line (a follow-up ``?err``
        behind the line itself); ``None`` when it registered none."""
        return self._sent

    # -- sending ------------------------------------------------------------------------

    def send(self, command: Command, tag: Hashable,
             known: tuple[int, Expectation] | None = None) -> tuple[bytes, Expectation]:
        """Register ``command`` under ``tag`` and return the bytes to write."""
        if known is not None and known[0] == self._autostatus \
                and command.instruction.lines is None:  # else it depends on the context
            expect = known[1]
        else:
            expect = expectation(command, self._autostatus, self.context)
        mode = self._autostatus
        self._autostatus = expect.mode_after
        data, template, echo, pattern, _, rear = self._line_facts(command, expect, mode)
        pending = None
        self._sent = None
        deferring = False
        if template:
            # (Checked before this line joins the queue: a move's own follow-up is below.)
            acked = _Item.ACK in template  # a ! line, or a read where reads are acked
            deferring = acked and self._deferring()
            pending = _Pending(tag, deque(template), echo, expect.rule, pattern,
                               sent=command.line if command.is_read else "")
            self._pending.append(pending)
        if expect.completion is not None:
            self._moves.append(tag)
        if pending is not None:
            pending.fed = self._assembler.feeds
        if self.write_time is not None:
            self._stamp(pending, len(data))
        if expect.rule.continuation is not None:
            data += self._register_follow_up(mode)
        elif pending is not None and ((expect.ack and expect.completion is not None)
                                      or deferring
                                      or (expect.mode_after == 2
                                          and _acks_itself(command, 2))):
            # Mode 2 (switch move_ok, L2099-2103 do not say when a move's OK... comes):
            # a move's acknowledgement may come only with its completion report, after
            # the replies of the lines written behind it. An ``?err`` right behind the
            # move tells: its reply before any acknowledgement means the OK... is
            # deferred, and its number is the move's verdict. While such an OK... is
            # owed, every acknowledged line gets one too, so that the ack lines that
            # arrive for it are counted up to a line that is not one (_resolve_held).
            data += self._register_follow_up(mode)
            if expect.completion is not None:
                pending.follow = self._pending[-1]
        if pending is not None and expect.completion is not None \
                and pending.items[0] is _Item.ECHO:
            pending.defers_echo = True
        if pending is not None:
            if pending.defers:
                pending.seal()
            else:
                pending.rear = rear
            if self._sent is None and pending.rear is not None:
                self._sent = pending.tag, pending.rear
            elif expect.rule.continuation is not None and self._sent is not None \
                    and rear is not None:
                # A stray line that ends the read early is taken by its follow-up, and
                # the read's further lines come after it: they face the next request.
                follow = self._pending[-1]
                follow.rear = Edge(tuple(dict.fromkeys(self._sent[1].patterns
                                                       + rear.patterns)))
                self._sent = follow.tag, follow.rear
        return data, expect

    def _deferring(self) -> bool:
        """Whether a move's OK... may still come with its completion report: one proved
        deferred, or a move line's acknowledgement not yet known."""
        return bool(self._deferred) or any(p.follow is not None for p in self._pending)

    def owed(self, command: Command, expect: Expectation, mode: int) -> Edge | None:
        """:func:`owed_edge` of ``command`` written in ``mode``, as reads are acknowledged
        here (cached for reads like what :meth:`send` registers)."""
        if not expect.expects_reply:
            return None  # nothing but optional lines (and not computed twice: a set)
        return self._line_facts(command, expect, mode)[4]

    def _line_facts(self, command: Command, expect: Expectation, mode: int
                     ) -> _Facts:
        """What a line written in ``mode`` owes: its bytes, the items owed, its echo's
        and its data's pattern. Pure for a given line text, instruction, expectation, mode
        and :attr:`ack_reads` when the reply does not depend on the context: those of
        reads (the per-request path) are cached (tests/unit/test_core_cache.py)."""
        entry = command.instruction
        cacheable = command.is_read and entry.lines is None
        if cacheable:
            key = (command.line, mode, self.ack_reads)
            hit = self._facts.get(key)
            if hit is not None and hit[0] is entry and hit[1] is expect:
                return hit[2]
        items = _owed_items(command, expect, mode, self.ack_reads)
        echo = echo_pattern(command) if _Item.ECHO in items or _Item.ECHO_OPT in items \
            else None
        pattern = reply_pattern(command, self.context) if _has_data(expect.rule) \
            else ACK_PATTERN
        front = back = None
        if expect.expects_reply:  # else it is sure to get no line (a set in mode 1)
            front = _front(items, echo, pattern, expect, mode, self.ack_reads)
            back = _edge((echo if item in (_Item.ECHO, _Item.ECHO_OPT) and echo is not None
                          else pattern if item is _Item.DATA else ACK_PATTERN,
                          _sure(item, False)) for item in reversed(items))
        facts = (command.to_bytes(), tuple(items), echo, pattern, front, _rear(front, back))
        if cacheable:
            if len(self._facts) >= _LINE_FACTS_MAX:
                self._facts.clear()
            self._facts[key] = (entry, expect, facts)
        return facts

    def _register_follow_up(self, mode: int) -> bytes:
        items = _owed_items(_FOLLOW_UP_COMMAND, expectation(_FOLLOW_UP_COMMAND, mode), mode,
                            self.ack_reads)
        follow = _Pending(object(), items, _FOLLOW_UP_ECHO, internal=True,
                          pattern=ONE_NUMBER, sent="?err").seal()
        self._pending.append(follow)
        follow.fed = self._assembler.feeds
        if self.write_time is not None:
            self._stamp(follow, len(_FOLLOW_UP))
        if follow.rear is not None:
            self._sent = follow.tag, follow.rear
        return _FOLLOW_UP

    # -- timing ---------------------------------------------------------------------------

    def _stamp(self, pending: _Pending | None, size: int) -> None:
        """Mark when the reply of a line of ``size`` bytes just registered may start."""
        at = self.write_time
        assert at is not None
        earliest, self._wire_free = earliest_reply(at, self._wire_free, size,
                                                   self.wire_seconds, self.arrival_margin)
        if pending is not None:
            pending.earliest = earliest

    def forget_completion(self, tag: Hashable) -> bool:
        """Stop waiting for the completion report of ``tag`` (e.g. the move was refused)."""
        try:
            self._moves.remove(tag)
        except ValueError:
            return False
        return True

    def drop_completions(self) -> list[Hashable]:
        """Stop waiting for every completion report; return the tags that were waiting."""
        tags = list(self._moves)
        self._moves.clear()
        return tags

    def resync(self, tag: Hashable, *, ctrl_c: bool = False) -> bytes:
        """Start a resynchronisation; return the bytes to write.

        Every pending request is reported lost (:class:`RequestLost` events). With
        ``ctrl_c`` the bytes start with 0x03, which stops all axes and makes the
        controller discard its input buffer (manual L6808-6814). The marker ``?help N`` is
        registered under ``tag``; its :class:`Replied` event ends the resync. Without
        markers (:attr:`HelpStyle.NONE`) ``help`` is written and every line dropped until
        :meth:`end_resync` (:attr:`quiet`)."""
        for pending in self._pending:
            if pending.verdict is not None:
                self._events.append(RequestLost(pending.verdict))
            elif not pending.internal and not pending.settled:
                self._events.append(RequestLost(pending.tag))
        self._pending.clear()
        self._forget_deferred()
        self._desynced = False
        stop = b"\x03" if ctrl_c else b""
        chosen = self._marker()
        if chosen is None:
            # No unique reply to wait for: drop every line; the protocol ends the resync
            # when the reply of ``help`` (ERROR n,text) was the last line and the link
            # has been quiet since (see tango_aio.sansio._session).
            self._resync = _Resync.QUIET
            return stop + b"help\r"
        code, text = chosen
        self._resync, self._resync_marker = _Resync.MARKER, text
        line = f"?help {code}"
        self._pending.append(_Pending(tag, _read_items(self._autostatus, self.ack_reads),
                                      _echo_of(line), pattern=marker_pattern(text),
                                      marker=text).seal())
        return stop + encode(line)

    def drop_all(self) -> None:
        """Drop every line (completion reports excepted) until :meth:`end_resync`; what is
        still owed is forgotten (only call it when no request waits)."""
        self._pending.clear()
        self._forget_deferred()
        self._resync = _Resync.QUIET

    def _forget_deferred(self) -> None:
        # After a resync an OK... still owed arrives before the marker's reply (dropped)
        # or, with no request waiting, as an unsolicited line.
        self._deferred.clear()
        self._reported.clear()
        self._held.clear()
        self._deferred_echoes.clear()

    def pick_marker_code(self) -> int:
        """A marker number for this session (see :data:`_MARKER_CODES`)."""
        return self._next_marker_code()

    @property
    def quiet(self) -> bool:
        """Whether a resync without a marker is under way (end it with
        :meth:`end_resync`)."""
        return self._resync is _Resync.QUIET

    def end_resync(self) -> None:
        """End a quiet resync: the stream is in step."""
        self._resync = _Resync.NONE
        self._desynced = False

    def _marker(self) -> tuple[int, str] | None:
        """A marker number and the text its reply holds (``None``: no marker exists)."""
        if self.help_style is HelpStyle.NUMBER:
            code = self._next_marker_code()
            return code, f"ERROR {code},"
        return self.help_text if self.help_style is HelpStyle.TEXT else None

    def _next_marker_code(self) -> int:
        code = _MARKER_CODES[self._marker_index % len(_MARKER_CODES)]
        self._marker_index += 1
        return code

    def separator(self, before: Edge, after: Edge) -> tuple[bytes, ReplyPattern] | None:
        """A *separator* for two requests in a row whose replies look alike: a short read
        whose reply cannot be taken for the replies of its neighbours (the rear edge of
        the request before it and the front edge of the one after it, facing the
        separator's own front and rear edges in the mode in force: its echo in mode 4
        too), with its reply's pattern; register it with :meth:`separate`. Written
        between the two, it turns a line too many (or too few) between them into a
        :class:`Mismatched` instead of a reply shifted onto the next request
        (:mod:`tango_aio.sansio._patterns`).

        Only reads that leave the error state alone qualify: "each instruction
        overwrites the error state" (L2853-2856), and a caller may read ``?err`` after an
        unchecked line. The cheapest that fits: ``?err`` (the error number, L2824-2850),
        else ``?help`` (``ERROR n,text`` of the current state, which "is not cleared",
        L2882-2919), else ``?help N``, whose reply holds a number of this session's (or
        the text learned for it) and looks like nothing else. ``None`` when none fits and
        this controller has no ``?help N``: the next line then waits for the reply."""
        # The edges are the cached ones of the lines' facts, so the choice among the fixed
        # separators is cached by their identity (kept alive, checked on a hit).
        key = (id(before), id(after), self._autostatus, self.ack_reads)
        hit = self._separator_choice.get(key)
        if hit is not None and hit[0] is before and hit[1] is after:
            fixed = hit[2]
        else:
            fixed = next(((line, fits) for line, fits in _SEPARATORS
                          if self._separates(line, fits, before, after)), None)
            if len(self._separator_choice) >= _LINE_FACTS_MAX:
                self._separator_choice.clear()
            self._separator_choice[key] = (before, after, fixed)
        if fixed is not None:
            return fixed
        marker = self._marker()
        if marker is None:
            return None
        line, fits = encode(f"?help {marker[0]}"), marker_pattern(marker[1])
        # Free text fits every line, a marker's reply too; but no other reply fits the
        # marker's, so it still stands between free-text replies (only the free-text read
        # itself takes whatever comes, tango_aio.sansio._patterns).
        if self._separates(line, fits, _specific(before), _specific(after)):
            return line, fits
        return None

    def _separates(self, line: bytes, fits: ReplyPattern, before: Edge, after: Edge
                   ) -> bool:
        """Whether separator ``line`` (reply ``fits``) faces neither edge in this mode."""
        key = (line, self._autostatus, self.ack_reads)
        edges = self._separator_edges.get(key)
        if edges is None:
            separator = _Pending(None, _read_items(self._autostatus, self.ack_reads),
                                 _echo_of(line.decode()), pattern=fits).seal()
            front = _edge((_item_pattern(separator, item), _sure(item, False))
                          for item in separator.items)
            assert front is not None and separator.rear is not None  # sure of its data
            edges = self._separator_edges[key] = front, separator.rear
        # Its front faces the rear edge before it; its rear edge (its own line lost, the
        # next request's reply lands on its first items) faces the front after it.
        return not edges[0].overlaps(before) and not edges[1].overlaps(after)

    def separate(self, tag: Hashable, separator: tuple[bytes, ReplyPattern]) -> bytes:
        """Register ``separator`` (from :meth:`separator`) under ``tag``; return its bytes."""
        data, pattern = separator
        pending = _Pending(tag, _read_items(self._autostatus, self.ack_reads),
                           _echo_of(data.decode()), pattern=pattern).seal()
        self._pending.append(pending)
        pending.fed = self._assembler.feeds
        if self.write_time is not None:
            self._stamp(pending, len(data))
        self._sent = (tag, pending.rear) if pending.rear is not None else None
        return data

    # -- receiving ------------------------------------------------------------------------

    def receive_data(self, data: bytes, at: float | None = None) -> None:
        """Feed bytes read from the controller."""
        self._assembler.feed(data, at)

    def next_event(self) -> Event | None:
        """Return the next event, or ``None`` when more bytes are needed."""
        while not self._events:
            line = self._assembler.next_line()
            if line is None:
                return None
            # (The test canonical_case starts with, made here: most lines are numbers.)
            self._route(canonical_case(line) if line[:1] in _CASED_LEADS else line)
        return self._events.popleft()

    def events(self, data: bytes = b"") -> list[Event]:
        """Feed ``data`` and return every event it completes (raises on an over-long
        line; use :meth:`next_event` to carry on past one)."""
        self.receive_data(data)
        out: list[Event] = []
        while (event := self.next_event()) is not None:
            out.append(event)
        return out

    # -- routing ------------------------------------------------------------------------

    def _route(self, line: str) -> None:
        text = line.strip()
        if self._route_completion(line, text):
            return
        if (self._held or self._reported) and not ACK_PATTERN.accepts(text):
            if self._held:
                self._resolve_held(complete=True)
            self._retire_reported()
        if self._desynced:
            self._events.append(Dropped(line))
            return
        # The marker may follow stale bytes on the same line (a partial line that was in
        # flight when the port was opened), so it is searched, not prefix-matched.
        resync = self._resync
        if resync is not _Resync.NONE and (
                resync is _Resync.QUIET or self._resync_marker not in text):
            self._events.append(Dropped(line))
            return
        if self._deferred_echoes and self._deferred_echo(text):
            return
        if self._deferred and _is_ok(text) and ACK_PATTERN.accepts(text) \
                and self._takes_deferred():
            self._deferred.popleft()  # a move's OK... that came with its report
            self.tolerated["ok@completion"] = self.tolerated.get("ok@completion", 0) + 1
            return
        if not self._pending:
            self._events.append(Unsolicited(line))
            return
        head = self._pending[0]
        if resync is _Resync.MARKER:
            # The marker's reply: an acknowledgement or echo it owed before it was lost.
            while head.items[0] is not _Item.DATA:
                head.items.popleft()
        item = head.items[0]
        if item in _OPTIONAL:
            self._route_optional(head, item, line, text)
        elif item is _Item.ECHO:
            self._route_echo(head, line, text)
        elif item is _Item.DATA:
            self._route_data(head, line, text)
        else:
            self._route_ack(head, line, text)

    def _route_optional(self, head: _Pending, item: _Item, line: str, text: str) -> None:
        """A line some firmware sends and some does not: consume it when it fits, else
        skip the item and route the line on."""
        self._advance(head)
        if _item_pattern(head, item).accepts(text):
            self.tolerated[item.value] = self.tolerated.get(item.value, 0) + 1
            return
        self._route(line)

    def _route_completion(self, line: str, text: str) -> bool:
        # Only a truly empty line is the bare CR of autostatus 3. A line of blanks is not:
        # a one-bit error turns the '0' of '?err' into ' ', and taking that for a
        # completion would leave the probe waiting, to take the *next* request's reply
        # (tests/e2e/test_faults.py::test_garbled_zero_to_blank_stays_with_its_caller).
        if line == "":
            # Autostatus 3 reports completion with a bare CR (manual L2107-2113, L2161);
            # inside a multi-line reply an empty line is data. It is accepted as a
            # completion in every mode: the mode that matters is the one in force when
            # the move ends, which may differ from the mode of the last line written.
            if self._in_multiline():
                return False
            tag = self._report_tag()
            self._events.append(Completed(tag, None, line) if tag is not None
                                else Unsolicited(line))
            return True
        if not is_completion_line(text):
            return False
        letters = dict(zip(("x", "y", "z", "a"), text[:-1], strict=False))
        present = {axis: letter for axis, letter in letters.items() if letter != ABSENT}
        tag = self._report_tag()
        self._events.append(Completed(tag, present, line))
        return True

    def _report_tag(self) -> Hashable | None:
        """The move a completion report belongs to (the oldest awaiting one), noted if its
        OK... is deferred (:meth:`_retire_reported`)."""
        tag = self._moves.popleft() if self._moves else None
        if tag is not None and tag in self._deferred:
            self._reported.add(tag)
        return tag

    def _retire_reported(self) -> None:
        """A line that is not an acknowledgement came after the completion report of a
        deferred move: a deferred OK... comes with the report, before it or right behind
        it, so one still counted now never comes. Its move's acknowledgement only looked
        deferred (lost or garbled on the way, the ``?err`` behind it answering in its
        place); counted on, it would take a later line's acknowledgement, and that line
        would wait for one that never comes."""
        for tag in self._reported:
            with contextlib.suppress(ValueError):
                self._deferred.remove(tag)
        self._reported.clear()

    def _in_multiline(self) -> bool:
        # Only a reply read by count or up to a terminator (service) can hold an empty
        # line. A continuation reply (detext, ?lim) never does: there an empty line is an
        # autostatus-3 completion, and ending the reply on it would desynchronise the
        # stream (the internal ?err follow-up would swallow the reply's next line).
        if not self._pending:
            return False
        head = self._pending[0]
        return bool(head.lines) and head.rule.continuation is None

    def _deferred_echo(self, text: str) -> bool:
        """Consume ``text`` if it is the echo of a move that came with its report, and
        not the echo the head waits for (the same text: then it does not matter whose)."""
        if self._pending:
            head = self._pending[0]
            if head.items[0] in (_Item.ECHO, _Item.ECHO_OPT) and head.echo is not None \
                    and head.echo.accepts(text):
                return False
        for echo in self._deferred_echoes:
            if echo.accepts(text):
                self._deferred_echoes.remove(echo)
                self.tolerated["echo@completion"] = \
                    self.tolerated.get("echo@completion", 0) + 1
                return True
        return False

    def _route_echo(self, head: _Pending, line: str, text: str) -> None:
        if head.echo is not None and not head.echo.accepts(text):
            if head.defers_echo:
                # Mode 4 (switch echo=completion; L2117 does not say when the echo
                # comes): the move's echo comes with its report; the line is the reply of
                # the ?err written behind it, which is its verdict.
                self._deferred_echoes.append(head.echo)
                done = head.done_after(_Item.ECHO)
                self._advance(head)
                self._emit(head, Echoed(head.tag, "", done, deferred=True))
                self._route(line)
                return
            self._events.append(Unsolicited(line))
            return
        done = head.done_after(_Item.ECHO)
        self._advance(head)
        self._emit(head, Echoed(head.tag, line, done))

    def _takes_deferred(self) -> bool:
        """Whether an ``OK...`` arriving now can only be a deferred one: no request waits
        for an acknowledgement at the head (none waits, or the head owes data or an
        optional line; only ``save``'s data is an ``OK...``)."""
        if not self._pending:
            return True
        head = self._pending[0]
        item = head.items[0]
        if item is _Item.ACK:
            return False
        return not (item is _Item.DATA and head.pattern is ACK_PATTERN and not head.lines)

    def _route_ack(self, head: _Pending, line: str, text: str) -> None:
        if not ACK_PATTERN.accepts(text):
            if head.follow is not None:
                self._defer_ack(head, line)
                return
            if not self.check_replies:
                self._events.append(Unsolicited(line))
                return
            # Not an acknowledgement where one is owed: the head's line or its OK... was
            # lost (the line is a reply owed behind it: the number of a read written
            # next, or of the ?err behind it), or the line is extra. Passed over, it
            # would leave the head to take the next line's OK... for its own: out of step.
            self._desynced = True
            self._events.append(Mismatched(None if head.internal else head.tag, line,
                                           ACK_PATTERN))
            return
        behind = self._acked_behind(head)
        if self._deferred or (head.follow is not None and behind):
            # An OK... of a deferred move may come before this line's acknowledgement
            # (its move ended first), and a move's own may be deferred while the ?err
            # behind it is acknowledged before its number (ack_reads=before): hold the
            # ack lines until it is known whose each is.
            self._held.append(line)
            if not _is_ok(text) or self._nothing_tells(head):
                self._resolve_held(complete=False)
            elif len(self._held) > len(self._deferred) + behind:
                self._resolve_held(complete=True)
            return
        self._acknowledge(head, line, text)

    def _acked_behind(self, head: _Pending) -> int:
        """1 if ``head`` owes only its acknowledgement and the ``?err`` written behind it
        owes an ``OK...`` before its number (reads acknowledged before their data): held
        ``OK...`` lines may include that one. Else 0."""
        if len(head.items) != 1 or len(self._pending) < 2:
            return 0
        behind = self._pending[1]
        return int(behind.internal and behind.items[0] is _Item.ACK
                   and behind.pattern is not ACK_PATTERN)

    def _nothing_tells(self, head: _Pending) -> bool:
        """Whether no line will come to tell whose a held ``OK...`` is: the head owes only
        the acknowledgement a read sends after its data (``ack_reads=after``) and nothing
        is owed behind it. That acknowledgement is no verdict (the data is in), so the
        head takes it; a deferred ``OK...`` arriving later is counted as one. Held, it
        would wait for a line that is written only once it is in: the next line that
        looks like it (a set's ``OK...``; no separator fits, each read is acknowledged
        after its data too) waits for the head's reply."""
        return len(self._pending) == 1 and len(head.items) == 1 \
            and head.pattern is not ACK_PATTERN

    def _defer_ack(self, head: _Pending, line: str | None) -> None:
        """A line that is not an acknowledgement came for a mode-2 move: its OK... comes
        with its completion report (switch ``move_ok=completion``). The reply of the
        ``?err`` written behind it (the line now, if nothing was lost) is its verdict."""
        follow, head.follow = head.follow, None
        assert follow is not None
        follow.verdict = head.tag
        self._deferred.append(head.tag)
        head.items.popleft()
        if not head.items:
            self._pending.remove(head)
        if line is not None:
            self._route(line)

    def _resolve_held(self, *, complete: bool) -> None:
        """Hand the held ack lines out: the head's own acknowledgement and the OK...s of
        deferred moves. A deferred one is always ``OK...`` (a refused move is refused at
        once, with ``ERR``), so an ``ERR`` among them is the head's; among OKs it does
        not matter which is whose, only how many. A move at the head may have deferred
        its own: then the deferred moves take the OKs first. ``complete``: a line that is
        not an acknowledgement follows (or every OK... that can come is in), so where the
        ``?err`` behind the head is acknowledged before its number, the last OK... is
        that acknowledgement, and a move at the head that got none deferred its own."""
        held, self._held = self._held, []
        head = self._pending[0]
        behind = None
        if complete and self._acked_behind(head) and held and _is_ok(held[-1].strip()):
            behind = held.pop()
        pick = next((i for i, line in enumerate(held) if not _is_ok(line.strip())), None)
        if pick is None:
            pick = len(self._deferred) if head.follow is not None else 0
        for index, line in enumerate(held):
            if index == pick:
                continue
            if self._deferred and _is_ok(line.strip()):
                self._deferred.popleft()
                self.tolerated["ok@completion"] = self.tolerated.get("ok@completion", 0) + 1
            else:
                self._events.append(Unsolicited(line))
        if pick < len(held):
            self._acknowledge(head, held[pick], held[pick].strip())
        elif behind is not None and head.follow is not None:
            self._defer_ack(head, None)
        if behind is None:
            return
        follow = self._pending[0] if self._pending else None
        if follow is not None and follow is not head and follow.items[0] is _Item.ACK:
            self._acknowledge(follow, behind, behind.strip())
        else:  # the head got no acknowledgement of its own: out of step, as it shows
            self._events.append(Unsolicited(behind))

    def _acknowledge(self, head: _Pending, line: str, text: str) -> None:
        if head.follow is not None:
            # Acknowledged at once: the ?err behind it is only a read now.
            head.follow = None
        number = re.search(r"-?\d+", text)
        code = 0 if _is_ok(text) else (int(number.group()) if number else None)
        if code != 0:
            self.forget_completion(head.tag)  # a refused move never completes
        done = head.done_after(_Item.ACK)
        self._advance(head)
        self._emit(head, Acknowledged(head.tag, code, line, done))

    def _route_data(self, head: _Pending, line: str, text: str) -> None:
        if head.marker is not None:
            self._resync = _Resync.NONE
        elif not head.lines and head.sent and text == head.sent:
            # A read answered by itself where no echo is owed (modes 0-3 echo nothing,
            # L2060-2117): the link returns the bytes the driver sends, like a serial
            # adapter or RS-485 converter with local echo (switch local_echo). Their
            # copies interleave with the controller's replies: not served.
            self.local_echo = True
            self._desynced = True
            tag = None if head.internal else head.tag
            self._events.append(Mismatched(tag, line, head.pattern, LOCAL_ECHO))
            return
        elif not head.lines and self.check_replies and (
                (early := self._assembler.started_feed <= head.fed
                 or self._assembler.started < head.earliest)
                or not head.pattern.accepts(text)):
            # Not this request's reply: its own was lost, or the line is extra, or it
            # started before the request could have been answered (bytes without a CR
            # glued in front of the reply). Handing it over would shift every later reply
            # by one request (tango_aio.sansio._patterns), or hand over a wrong value.
            self._desynced = True
            tag = None if head.internal else head.tag
            self._events.append(Mismatched(tag, line, head.pattern,
                                           _too_early(line, head) if early else ""))
            return
        rule = head.rule
        ended = rule.continuation is not None and not rule.continuation.match(text)
        if ended and head.lines and len(head.lines) >= rule.count:
            self._finish_data(head)
            self._route(line)
            return
        head.lines.append(line)
        head.size += len(line)
        if len(head.lines) > self._max_reply[0] or head.size > self._max_reply[1]:
            reason = (f"the reply exceeds {self._max_reply[0]} lines or "
                      f"{self._max_reply[1]} bytes")
            head.lines.clear()
            head.size = 0
            self._desynced = True
            tag = None if head.internal else head.tag
            self._events.append(Mismatched(tag, line, head.pattern, reason))
            return
        if rule.terminator is not None:
            if text == rule.terminator:
                self._finish_data(head)
        elif rule.continuation is None and len(head.lines) >= max(rule.count, 1):
            self._finish_data(head)

    def _finish_data(self, head: _Pending) -> None:
        done = head.done_after(_Item.DATA)
        lines = tuple(head.lines)
        head.lines.clear()
        head.size = 0
        self._advance(head)
        if head.verdict is not None:
            # The ?err behind a move whose OK... is deferred: its number is the move's
            # acknowledgement now (0: accepted, the OK... follows with the report).
            number = re.search(r"-?\d+", lines[0]) if lines else None
            code = int(number.group()) if number else None
            if code != 0:
                self.forget_completion(head.verdict)
                with contextlib.suppress(ValueError):
                    self._deferred.remove(head.verdict)
                self._reported.discard(head.verdict)
            self._events.append(Acknowledged(head.verdict, code, lines[0] if lines else "",
                                             deferred=True))
            return
        self._emit(head, Replied(head.tag, lines, done))

    def _advance(self, head: _Pending) -> None:
        head.items.popleft()
        if not head.items:
            self._pending.popleft()

    def _emit(self, head: _Pending, event: Event) -> None:
        if not head.internal:
            self._events.append(event)

