"""The sans-IO protocol core: line reassembly and reply routing. No I/O, no asyncio.

Theory of operation
===================
The TANGO interpreter executes one CR-terminated command line at a time, strictly in the
order received, and everything it sends back is a CR-terminated line. A line is one of:

1. a **data reply** to a read (``?pos`` → ``1.0000 2.0000``), one or more lines, in the
   order of the reads;
2. an **acknowledgement** ``OK...`` / ``ERR n`` of every ``!`` line in autostatus 2, sent
   after the line was executed (``save`` and ``?restore`` answer like this in every mode);
3. an **echo** of every executed set/move line in autostatus 4, sent before executing it;
4. a **completion report** of a move, ``cal`` or ``rm``: ``@@@-.`` (modes 1, 2, 4) or an
   empty line (mode 3). It is pushed when the axes stop, so it may fall between any two
   other lines, and it is matched to the oldest move still waiting for one;
5. anything else: unsolicited (``!joy 0`` reports ``@@@-.`` when it disables the joystick).

Because the interpreter is sequential, items 1-3 arrive in the order the lines were
written. :class:`ProtocolCore` therefore keeps a FIFO of *expectations*: for each line
written, the items it still owes (echo, data, ack, in that order), computed from the
instruction catalog and the autostatus mode in force when the line reaches the controller.
The core tracks that mode from the ``!autostatus`` lines it encodes itself. Completion
reports have a shape no reply has, so they are recognised by pattern first.

When the stream can no longer be trusted (a reply was lost, or Ctrl+C made the controller
discard its input buffer) the core *resynchronises*: every pending request is reported
lost, a marker query ``?help N`` is sent, and every line up to its unique reply
``ERROR N,...`` is dropped (or, on firmware whose ``help`` takes no number, every line
until the protocol sees the link quiet after the reply of ``help``: :class:`HelpStyle`).
Completion reports keep flowing during a resync.

Where the manual is silent on whether a line comes at all (a read echoed in mode 4, a
read or a mode change acknowledged in mode 2), the line is an *optional* item: consumed
when the next line fits it, skipped otherwise (:func:`_owed_items`).

Some lines come *late* on some firmware, and the core tells from the stream:

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

A line is also judged by its timing where the protocol gives it (arrival times with the
bytes): a data line whose first byte (blanks aside) was read before its request was
written is not its reply, nor, on a paced wire (:attr:`ProtocolCore.wire_seconds`,
:attr:`ProtocolCore.write_time`), one that started while the request's bytes were still
on the wire (:func:`~tango_aio.sansio._linktiming.earliest_reply`): stray bytes without a CR
glued in front of the reply. Which came first, the chunk or the write, is known by the
order they were handled in, not by a clock. Such a line is a :class:`Mismatched` with its
reason, like a line of the wrong shape.

The core is fed raw bytes with :meth:`ProtocolCore.receive_data` and yields events from
:meth:`ProtocolCore.next_event`, like h11. Only :class:`~tango_aio.errors.ProtocolError` is
ever raised for bad input; the core stays usable afterwards.
"""

from __future__ import annotations

import contextlib
import enum
import itertools
import math
import random
import re
from collections import deque
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field
from typing import Final, NoReturn

from ..catalog import (
    Command,
    Completion,
    Context,
    Form,
    Instruction,
    LineRule,
    ModeEffect,
    Shape,
    encode,
    parse,
    reply_rule,
)
from ..errors import ERROR_DESCRIPTIONS, ProtocolError
from ..status import ABSENT, LETTERS
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

#: Longest line the assembler buffers before it gives up on it. The controller's lines are
#: far shorter; ``service`` output is the longest.
DEFAULT_MAX_LINE: Final = 1024
#: Most lines and bytes one multi-line reply (``service``, ``detext``) may hold before the
#: request fails (a reply whose end never comes must not grow for ever). The
#: manual's ``service`` print is a few dozen lines (L2929-2943).
MAX_REPLY_LINES: Final = 1024
MAX_REPLY_BYTES: Final = 65536

_CR: Final = 0x0D
#: The bytes ``str.strip`` removes from a Latin-1 line (a reply is matched stripped).
_BLANK_BYTES: Final = frozenset(code for code in range(256) if chr(code).isspace())

#: A completion report: one status letter per axis X Y Z A (``-`` = absent), then ``.``
#: (manual L2087-2089, L6337-6343). Firmware with fewer axes may send fewer letters.
_COMPLETION_RE: Final = re.compile(f"^[{re.escape(''.join(sorted(LETTERS)))}]{{1,4}}\\.$")


#: Why a read answered by its own text fails (:attr:`ProtocolCore.local_echo`).
LOCAL_ECHO: Final = ("a read came back as itself: the link echoes every byte sent (local "
                     "echo of a serial adapter or RS-485 converter), which the driver does "
                     "not support; turn the adapter's echo off")

#: The words the driver recognises lines by that some firmware may print in another case
#: (switches ``ack_case``, ``help_case``): the mode-2 acknowledgements ``OK...`` and
#: ``ERR n`` (L2099-2103, L2150-2152) and ``help``'s ``ERROR n,text`` (L2915-2919), which
#: the manual prints in capitals and nowhere says must be.
_CASED_RE: Final = re.compile(
    r"\s*(?:(error)(?=\s*-?\d+\s*,)|(ok)(?=\.*\s*$)|(err)(?=(?:\s+-?\d+)?\s*$))",
    re.IGNORECASE)


#: The first characters of a line :func:`canonical_case` may change.
_CASED_LEADS: Final = frozenset("oOeE ")


def canonical_case(line: str) -> str:
    """``line`` with the word it is recognised by in capitals (``ok...`` -> ``OK...``,
    ``Err 5`` -> ``ERR 5``, ``error 5,number outside range`` -> ``ERROR 5,number outside
    range``); every other line as it is."""
    if line[:1] not in _CASED_LEADS or line.startswith(("OK", "ERR")):
        return line
    match = _CASED_RE.match(line)
    if match is None:
        return line
    group = next(index for index in (1, 2, 3) if match.group(index) is not None)
    start, end = match.span(group)
    return line[:start] + line[start:end].upper() + line[end:]


def is_completion_line(line: str) -> bool:
    """Whether ``line`` is an autostatus completion report such as ``@@@-.``."""
    return bool(_COMPLETION_RE.match(line))


class LineAssembler:
    """Reassembles CR-terminated lines from arbitrary byte fragments.

    The buffer is bounded: a line longer than ``max_line`` bytes raises
    :class:`ProtocolError` once, and its bytes are discarded up to the next CR. Each byte
    is scanned once (the CR search resumes where the previous one stopped). LF bytes are
    dropped, so a terminal server that turns CR into CR LF does no harm; the controller
    itself never sends LF (manual L82). Bytes are decoded as Latin-1, one char per byte."""

    def __init__(self, max_line: int = DEFAULT_MAX_LINE) -> None:
        self._buffer = bytearray()
        self._scanned = 0
        self._discarding = False
        self._max_line = max_line
        # Where each timed chunk starts (counting every byte ever fed), its number and
        # when it was read, oldest first; only the chunks the buffer still holds (and the
        # one its first byte came in).
        self._stamps: deque[tuple[int, int, float]] = deque()
        self._offset = 0  # the count of bytes fed before the buffer's first
        #: Chunks fed with a time so far (and any after the first such).
        self.feeds = 0
        #: The number (:attr:`feeds`) of the chunk that brought the first byte of the line
        #: :meth:`next_line` returned last, and when it was read (the time given to
        #: :meth:`feed`): leading blanks and LF bytes do not count, they change no reply.
        #: ``inf`` when not known.
        self.started_feed: float = math.inf
        self.started = math.inf

    @property
    def buffered(self) -> int:
        """Number of bytes held for an incomplete line."""
        return len(self._buffer)

    def feed(self, data: bytes, at: float | None = None) -> None:
        """Add received bytes; collect the lines with :meth:`next_line`."""
        if data and (at is not None or self._stamps):
            self.feeds += 1
            self._stamps.append((self._offset + len(self._buffer), self.feeds,
                                 math.inf if at is None else at))
        self._buffer += data

    def next_line(self) -> str | None:
        """Return the next complete line (without CR), or ``None`` if there is none yet."""
        end = self._buffer.find(_CR, self._scanned)
        if end < 0:
            self._scanned = len(self._buffer)
            if self._scanned > self._max_line and not self._discarding:
                self._overflow()
            if self._discarding:
                self._consume(len(self._buffer))
                self._scanned = 0
            return None
        raw = bytes(self._buffer[:end])
        stamps = self._stamps
        if stamps:
            offset = self._offset
            while len(stamps) > 1 and stamps[1][0] <= offset:
                stamps.popleft()  # chunks that ended before this line
            if raw and raw[0] in _BLANK_BYTES:
                self.started_feed, self.started = self._started(raw)
            else:
                first, fed, at = stamps[0]
                if first <= offset:
                    self.started_feed = fed
                    self.started = at
                else:
                    self.started_feed = self.started = math.inf
        del self._buffer[: end + 1]
        self._offset += end + 1
        self._scanned = 0
        if self._discarding:
            self._discarding = False
            return self.next_line()
        if len(raw) > self._max_line:
            raise ProtocolError(f"reply line of {len(raw)} bytes exceeds {self._max_line}")
        return raw.replace(b"\n", b"").decode("latin-1")

    def _started(self, raw: bytes) -> tuple[float, float]:
        """The chunk that brought the first byte of ``raw`` (at the buffer's start, led by
        blanks) that is not blank (the line's own first if it is all blank)."""
        lead = len(raw) - len(raw.decode("latin-1").lstrip())
        position = self._offset + (lead if lead < len(raw) else 0)
        stamps = self._stamps
        while len(stamps) > 1 and stamps[1][0] <= position:
            stamps.popleft()
        first, fed, at = stamps[0]
        return (fed, at) if first <= position else (math.inf, math.inf)

    def _consume(self, size: int) -> None:
        """Drop the buffer's first ``size`` bytes, and the stamps of the chunks they
        ended."""
        del self._buffer[:size]
        self._offset += size
        stamps = self._stamps
        while len(stamps) > 1 and stamps[1][0] <= self._offset:
            stamps.popleft()

    def _overflow(self) -> NoReturn:
        size = len(self._buffer)
        self._consume(size)
        self._scanned = 0
        self._discarding = True
        raise ProtocolError(f"no CR within {size} bytes: line exceeds {self._max_line} bytes")

    def lines(self, data: bytes) -> list[str]:
        """Feed ``data`` and return every complete line (raises on an over-long line)."""
        self.feed(data)
        out: list[str] = []
        while (line := self.next_line()) is not None:
            out.append(line)
        return out


# --------------------------------------------------------------------------------------
# Events


@dataclass(frozen=True, slots=True)
class Replied:
    """The data reply of request ``tag``. ``done``: the request owes nothing more."""

    tag: Hashable
    lines: tuple[str, ...]
    done: bool = True


@dataclass(frozen=True, slots=True)
class Acknowledged:
    """``OK...`` (``code == 0``) or ``ERR n`` for request ``tag`` (``code`` None: no number).

    ``deferred``: the verdict is the reply of the ``?err`` written behind a mode-2 move,
    which arrived where the move's own ``OK...`` was owed (``line`` is that reply). It
    shows that no error was reported, not that the move line arrived: firmware that
    sends the ``OK...`` only with the completion report (switch ``move_ok``) and a lost
    move line look the same here (L2099-2103 do not say when the ``OK...`` comes).
    """

    tag: Hashable
    code: int | None
    line: str
    done: bool = True
    deferred: bool = False


@dataclass(frozen=True, slots=True)
class Echoed:
    """The autostatus-4 echo of request ``tag``.

    ``deferred``: no echo came where the move's was owed (``line`` is empty), the reply
    of the ``?err`` behind it came instead: the echo may come with the completion report
    (switch ``echo=completion``; L2115-2117 do not say when), or the line was lost.
    """

    tag: Hashable
    line: str
    done: bool = True
    deferred: bool = False


@dataclass(frozen=True, slots=True)
class Completed:
    """A completion report. ``tag`` is the move it belongs to, ``None`` if unsolicited.

    ``letters`` maps each present axis to its status letter; it is ``None`` for the bare CR
    of autostatus 3, which carries no status.
    """

    tag: Hashable | None
    letters: dict[str, str] | None
    line: str


@dataclass(frozen=True, slots=True)
class Unsolicited:
    """A line that no request was waiting for."""

    line: str


@dataclass(frozen=True, slots=True)
class Dropped:
    """A line discarded while resynchronising."""

    line: str


@dataclass(frozen=True, slots=True)
class Mismatched:
    """A line arrived for request ``tag`` that cannot be its reply (see
    :mod:`tango_aio.sansio._patterns`): a reply went missing or a line was added. ``tag`` is
    ``None`` for the core's own follow-up query. The core drops every line (completion
    reports excepted) until :meth:`ProtocolCore.resync` is called.
    """

    tag: Hashable | None
    line: str
    expected: ReplyPattern
    #: Why, when the line itself would fit (a reply grown past its cap).
    reason: str = ""


@dataclass(frozen=True, slots=True)
class RequestLost:
    """Request ``tag`` will get no reply: its line was discarded, or the stream resynced."""

    tag: Hashable


Event = (Replied | Acknowledged | Echoed | Completed | Unsolicited | Dropped | RequestLost
         | Mismatched)


# --------------------------------------------------------------------------------------
# Expectations


class _Item(enum.Enum):
    """An item of a reply owed by a line."""

    # Hashed by identity, in C: Enum's own __hash__ is a Python function, and these
    # members are dict keys and set members on the per-line path. Members are
    # singletons compared by identity, so the two agree.
    __hash__ = object.__hash__

    ECHO = "echo"
    DATA = "data"
    ACK = "ack"
    #: A line that some firmware sends and some does not (see :meth:`ProtocolCore.send`):
    #: consumed when the next line fits it, skipped otherwise.
    ECHO_OPT = "echo?"
    ACK_OPT = "ack?"


_OPTIONAL: Final = frozenset({_Item.ECHO_OPT, _Item.ACK_OPT})


@dataclass(slots=True)
class _Pending:
    tag: Hashable
    items: deque[_Item]
    echo: ReplyPattern | None = None
    rule: LineRule = field(default_factory=LineRule)
    pattern: ReplyPattern = ACK_PATTERN  # of the data lines
    lines: list[str] = field(default_factory=list)
    size: int = 0  # bytes in lines
    internal: bool = False
    marker: str | None = None  # expected reply prefix of a resync marker
    #: A mode-2 move line: the internal ``?err`` written right behind it, whose reply
    #: stands in for the move's acknowledgement when that comes only at completion
    #: (:meth:`ProtocolCore._defer_ack`).
    follow: _Pending | None = None
    #: A mode-4 move line: its echo may come only with its completion report
    #: (:meth:`ProtocolCore._route_echo`).
    defers_echo: bool = False
    #: A read's line as written: no reply is ever the read itself (local echo).
    sent: str = ""
    #: On such a follow-up, once the move's acknowledgement proved deferred: the move
    #: whose verdict this reply's error number is.
    verdict: Hashable | None = None
    #: A data line whose first byte came in chunk :attr:`LineAssembler.feeds` ``<=
    #: fed`` was read before this line was written: not its reply (-1: not known).
    fed: int = -1
    #: A data line that starts earlier is not this line's reply either: its bytes were
    #: still on a paced wire (:func:`~tango_aio.sansio._linktiming.earliest_reply`); ``-inf``:
    #: not known.
    earliest: float = -math.inf
    #: The :func:`rear <_rear>` edge of what it owes (``None``: it is sure to get no
    #: line), set once its items are complete (:meth:`seal`).
    rear: Edge | None = None

    def done_after(self, item: _Item) -> bool:
        """Whether nothing but optional lines is owed once ``item`` (the head) is in."""
        return all(later in _OPTIONAL for later in itertools.islice(self.items, 1, None))

    @property
    def settled(self) -> bool:
        """Whether only optional lines are still owed."""
        return all(item in _OPTIONAL for item in self.items)

    @property
    def defers(self) -> bool:
        """Whether it is a move whose echo (mode 4) or acknowledgement (mode 2) may come
        only with its report."""
        return self.defers_echo or self.follow is not None

    def owes_sure(self) -> bool:
        """Whether a line it is sure to get is still owed."""
        defers = self.defers
        return any(_sure(item, defers) for item in self.items)

    def seal(self) -> _Pending:
        """Compute :attr:`rear` from the items owed; return the pending."""
        defers = self.defers
        owed = [(_item_pattern(self, item), _sure(item, defers)) for item in self.items]
        self.rear = _rear(_edge(owed), _edge(reversed(owed)))
        return self


def _item_pattern(pending: _Pending, item: _Item) -> ReplyPattern:
    if item in (_Item.ECHO, _Item.ECHO_OPT) and pending.echo is not None:
        return pending.echo
    return pending.pattern if item is _Item.DATA else ACK_PATTERN


def _sure(item: _Item, defers: bool) -> bool:
    """Whether ``item`` is sure to come in its place (not optional, not deferrable)."""
    # ``defers``: the echo (mode 4) or acknowledgement (mode 2) of a move, which some
    # firmware sends only with its report (switches echo=completion, move_ok=completion;
    # L2099-2103 and L2117 do not say when).
    return item not in _OPTIONAL and not (defers and item in (_Item.ECHO, _Item.ACK))


def _edge(owed: Iterable[tuple[ReplyPattern, bool]]) -> Edge | None:
    """The edge of lines ``owed`` (pattern, sure; nearest the neighbour first)."""
    # Up to and with the first sure line; None when none is sure.
    patterns = []
    for pattern, sure in owed:
        patterns.append(pattern)
        if sure:
            return Edge(tuple(patterns))
    return None


def _rear(front: Edge | None, back: Edge | None) -> Edge | None:
    """What a line written after a request must not look like: both its edges."""
    # The back edge: one line lost or extra shifts its last sure line onto the next
    # request. The front edge: its own line lost, the next reply lands on its first items.
    if front is None or back is None:
        return None
    if front == back:
        return front
    return Edge(tuple(dict.fromkeys(front.patterns + back.patterns)))


def _specific(edge: Edge) -> Edge:
    """``edge`` without free text (which fits every line)."""
    return Edge(tuple(pattern for pattern in edge.patterns if pattern.kind is not ReplyKind.ANY))


def _defers(expect: Expectation) -> bool:
    """Whether a move's echo or acknowledgement may come only with its report."""
    return expect.completion is not None and (expect.echo or expect.ack)


def owed_edge(command: Command, expect: Expectation, mode: int,
              context: Context | None = None,
              ack_reads: AckReads | None = None) -> Edge | None:
    """The front :class:`~tango_aio.sansio._patterns.Edge` of what ``command`` owes when written
    in ``mode``: the lines it may get before the first one it is sure to get, and that
    one (``None``: it is sure to get none; a move's ``?err`` probe then guards it).

    A move whose acknowledgement may come with its report (mode 2) is sure of the reply
    of the ``?err`` the core writes behind it (:meth:`ProtocolCore.send`), which then
    ends the edge."""
    items = _owed_items(command, expect, mode, ack_reads)
    echo = echo_pattern(command)
    pattern = reply_pattern(command, context) if _has_data(expect.rule) else ACK_PATTERN
    return _front(items, echo, pattern, expect, mode, ack_reads)


def _front(items: Iterable[_Item], echo: ReplyPattern | None, pattern: ReplyPattern,
           expect: Expectation, mode: int, ack_reads: AckReads | None) -> Edge | None:
    """:func:`owed_edge` from the items owed and the patterns of the echo and data."""
    defers = _defers(expect)

    def owed() -> Iterable[tuple[ReplyPattern, bool]]:
        for item in items:
            if item in (_Item.ECHO, _Item.ECHO_OPT) and echo is not None:
                yield echo, _sure(item, defers)
            else:
                yield (pattern if item is _Item.DATA else ACK_PATTERN), _sure(item, defers)
        if expect.ack and expect.completion is not None:  # its follow-up (see send)
            follow = _owed_items(_FOLLOW_UP_COMMAND, expectation(_FOLLOW_UP_COMMAND, mode),
                                 mode, ack_reads)
            for item in follow:
                yield ({_Item.DATA: ONE_NUMBER, _Item.ECHO: _FOLLOW_UP_ECHO,
                        _Item.ECHO_OPT: _FOLLOW_UP_ECHO}.get(item, ACK_PATTERN),
                       item not in _OPTIONAL)

    return _edge(owed())


@dataclass(frozen=True, slots=True)
class Expectation:
    """What a command line owes: which reply items and which completion report."""

    echo: bool
    rule: LineRule
    ack: bool
    completion: Completion | None
    mode_after: int

    @property
    def expects_reply(self) -> bool:
        """Whether any line comes back for this request (besides a completion)."""
        return self.echo or self.ack or _has_data(self.rule)


def _has_data(rule: LineRule) -> bool:
    return rule.count > 0 or rule.terminator is not None or rule.continuation is not None


def expectation(command: Command, mode: int, context: Context | None = None) -> Expectation:
    """What ``command`` owes when it reaches the controller in autostatus ``mode``.

    Decisions where the manual is silent (protocol_notes §5, open points); the emulator
    offers each of them as a firmware switch (``sim/profiles.py``), read on its own:

    * Mode 4 echoes every executing line (``!`` or an executing bare form such as
      ``moa``). Reads may be echoed too: optional (see :func:`_owed_items`).
    * Mode 2 acknowledges every ``!`` line. Reads may be acknowledged too: optional.
    * ``!autostatus n`` owes nothing for certain: its echo and acknowledgement depend on
      the firmware (optional, see :func:`_owed_items`).
    * A line that already answers with ``OK...``/``ERR`` (``save``) is not acknowledged a
      second time in mode 2.
    * Moves complete with a report in modes 1, 2, 4 and a bare CR in mode 3; mode 4 sends
      the echo first and the report when the move ends, as in mode 1."""
    entry = command.instruction
    # Most lines owe what their instruction, form and the mode say, whatever their values:
    # those expectations are computed once (the protocol asks twice per line written).
    # Not cached: lines that change the mode, and reads whose reply length depends on the
    # values or the context (entry.lines).
    key = (entry.name, command.form, mode)
    effect = entry.mode_effect
    cacheable = effect is ModeEffect.NONE and (entry.lines is None or command.executes)
    if cacheable:
        hit = _EXPECTATIONS.get(key)
        if hit is not None and hit[0] is entry:
            return hit[1]
    executes = command.executes
    after = effect.mode_after(command, mode)
    rule = reply_rule(command, context)
    owns_ack = entry.exec_reply is Shape.ACK and executes
    # A mode change owes no mandatory line: whether it is echoed and acknowledged depends
    # on the firmware (see _owed_items); the protocol reads ?autostatus behind it.
    changes_mode = effect.owes_nothing(command)
    result = Expectation(
        echo=mode == 4 and executes and not changes_mode,
        rule=rule,
        ack=after == 2 and command.form is Form.SET and not owns_ack and not changes_mode,
        completion=entry.completion if executes and after != 0 else None,
        mode_after=after,
    )
    if cacheable:
        _EXPECTATIONS[key] = (entry, result)
    return result


#: What a read line owes: its bytes, the items owed, its echo's and its data's pattern,
#: and the front and rear edges of its reply (:func:`owed_edge`, :func:`_rear`).
_Facts = tuple[bytes, tuple[_Item, ...], ReplyPattern | None, ReplyPattern, Edge | None,
               Edge | None]
#: Distinct read lines a core keeps at most (reads with many values are forgotten, not
#: hoarded).
_LINE_FACTS_MAX: Final = 1024
#: Cached expectations by (instruction name, form, mode), with the instruction they were
#: computed for (a hand-made Instruction of the same name does not share them). A memo of
#: the pure function :func:`expectation`, whose result depends on its key alone, so every
#: core may share it (what depends on a core's state is cached per core: _line_facts).
_EXPECTATIONS: dict[tuple[str, Form, int], tuple[Instruction, Expectation]] = {}


#: Separators that need no marker number: ``err`` answers one number, ``help`` its text
#: ``ERROR n,...`` (see :meth:`ProtocolCore.separate`).
_SEPARATORS: Final = ((b"?err\r", ONE_NUMBER), (b"?help\r", ReplyPattern(ReplyKind.HELP)))

def _echo_of(line: str) -> ReplyPattern:
    """The mode-4 echo of a line the core writes itself."""
    return ReplyPattern(ReplyKind.ECHO, text=normal_line(line))


class AckReads(enum.Enum):
    """Whether reads are acknowledged in autostatus 2, and where (the manual names only
    lines "with a leading !", L2097-2101): found when mode 2 is entered
    (:meth:`tango_aio.sansio._session.LinkSession.mode_read`)."""

    NO = "no"  #: a read's reply comes alone
    BEFORE = "before"  #: ``OK...`` before the read's data
    AFTER = "after"  #: ``OK...`` after the read's data


def _read_acks(ack_reads: AckReads | None) -> tuple[list[_Item], list[_Item]]:
    """The acknowledgements a read owes in mode 2, before and after its data."""
    if ack_reads is None:
        return [_Item.ACK_OPT], [_Item.ACK_OPT]
    return ([_Item.ACK] if ack_reads is AckReads.BEFORE else []), \
        ([_Item.ACK] if ack_reads is AckReads.AFTER else [])


def _read_items(mode: int, ack_reads: AckReads | None) -> deque[_Item]:
    """What a one-line read of the core's own (marker, separator) owes in ``mode``."""
    if mode == 2:
        before, after = _read_acks(ack_reads)
        return deque([*before, _Item.DATA, *after])
    return deque([_Item.DATA] if mode != 4 else [_Item.ECHO_OPT, _Item.DATA, _Item.ECHO_OPT])


def _owed_items(command: Command, expect: Expectation, mode: int,
                ack_reads: AckReads | None = None) -> deque[_Item]:
    """The lines ``command`` owes when written in autostatus ``mode``, in order, with the
    ones the manual leaves open as optional items (each one a switch of the emulator's):

    * Mode 4 echoes "the instruction that was sent, in case of set or move instruction"
      (L2089-2095); the older edition "echoes all input instructions including
      parameters" (old L723): a read written in mode 4 may be echoed too (``echo_all``).
    * Whether the echo is written before or after executing is not said, so a line that
      enters or leaves mode 4 may or may not be echoed, and a read's echo may come after
      its data (``echo=before|after``).
    * Mode 2 acknowledges lines "with a leading !" (L2097-2101); whether reads are
      acknowledged too, before or after their data, is not said (``ack_reads``): the
      protocol finds out when it enters mode 2 (``ack_reads`` is then an
      :class:`AckReads`); until then both are optional. (Optional acks after a
      read cannot be told from the next ``!`` line's: hence the detection.)
    * Whether ``!autostatus n`` is acknowledged per the old or the new mode is not said
      (``ack_mode_change``): a line entering or leaving mode 2 may or may not be.

    A mode change is then a barrier: :meth:`TangoProtocol.execute
    <tango_aio.link._protocol.TangoProtocol.execute>` reads ``?autostatus`` right behind it."""
    items: deque[_Item] = deque()
    setter = command.name == "autostatus" and command.form is Form.SET
    after = expect.mode_after
    if expect.echo and not setter:
        items.append(_Item.ECHO)
    elif mode == 4 or (setter and after == 4):
        items.append(_Item.ECHO_OPT)
    # A read's echo, if any, comes before its data or (echo written after executing)
    # after it: optional on both sides; its text tells it from anything else.
    echo_after = [_Item.ECHO_OPT] if mode == 4 and not expect.echo and _has_data(expect.rule) \
        else []
    # Acknowledged reads: ``?`` reads as found (the form the protocol writes). A bare read
    # (``sa``, ``err``) has neither ``?`` nor the leading ``!`` that L2097-2101 names: never.
    acked = mode == 2 and command.is_read and command.to_bytes().startswith(b"?")
    before, trailing = _read_acks(ack_reads) if acked else ([], [])
    items.extend(before)
    if _has_data(expect.rule):
        items.append(_Item.DATA)
    if setter:
        if 2 in (mode, after):
            items.append(_Item.ACK_OPT)
    elif expect.ack:
        items.append(_Item.ACK)
    elif _acks_itself(command, after):
        items.append(_Item.ACK_OPT)
    items.extend(trailing)
    items.extend(echo_after)
    return items


def _acks_itself(command: Command, after: int) -> bool:
    """Whether ``command`` is a ``!`` line whose own answer is ``OK...`` (``save``,
    ``restore``: L1738-1762, L2081) written where mode 2 acknowledges ``!`` lines: that
    answer may be its acknowledgement, or a second ``OK...`` may follow (switch
    ``save_ack``; L2081 and L2099-2103 do not say). The core writes an ``?err`` behind it,
    so that the second is told from the next line's acknowledgement by what follows."""
    return after == 2 and command.form is Form.SET and command.executes \
        and command.instruction.exec_reply is Shape.ACK


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
_FOLLOW_UP: Final = encode("?err")
_FOLLOW_UP_COMMAND: Final = parse("?err")
_FOLLOW_UP_ECHO: Final = echo_pattern(_FOLLOW_UP_COMMAND)


def wire_size(command: Command, expect: Expectation) -> int:
    """Bytes :meth:`ProtocolCore.send` writes for ``command`` owing ``expect``: its line,
    and the internal ``?err`` follow-up of a read whose end only the next line shows."""
    size = len(command.to_bytes())
    # A line acknowledged in mode 2 may get a follow-up (see ProtocolCore.send): its
    # bytes are reserved whether or not it is written.
    follows = expect.rule.continuation is not None or expect.ack \
        or command.instruction.exec_reply is Shape.ACK
    return size + len(_FOLLOW_UP) if follows else size


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
    """Routes the controller's lines to requests, acknowledgements and events.

    Call :meth:`send` for every command line written (it returns the bytes to write) and
    :meth:`receive_data` with every chunk read; then drain :meth:`next_event`."""

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
        """Register ``command`` under ``tag`` and return the bytes to write.

        A read whose end can only be seen from the next line (``detext``) is followed by an
        internal ``?err`` whose reply closes it; its bytes are included. ``known`` is an
        expectation the caller already computed and the mode it computed it for: it is
        used when that is the mode in force (and the reply does not depend on the context)."""
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
        if self._held and not ACK_PATTERN.accepts(text):
            self._resolve_held()
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
            tag = self._moves.popleft() if self._moves else None
            self._events.append(Completed(tag, None, line) if tag is not None
                                else Unsolicited(line))
            return True
        if not is_completion_line(text):
            return False
        letters = dict(zip(("x", "y", "z", "a"), text[:-1], strict=False))
        present = {axis: letter for axis, letter in letters.items() if letter != ABSENT}
        tag = self._moves.popleft() if self._moves else None
        self._events.append(Completed(tag, present, line))
        return True

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
            self._events.append(Unsolicited(line))
            return
        if self._deferred:
            # An OK... of a deferred move may come before this line's acknowledgement
            # (its move ended first): hold the ack lines until it is known whose each is.
            self._held.append(line)
            if not _is_ok(text) or len(self._held) > len(self._deferred):
                self._resolve_held()
            return
        self._acknowledge(head, line, text)

    def _defer_ack(self, head: _Pending, line: str) -> None:
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
        self._route(line)

    def _resolve_held(self) -> None:
        """Hand the held ack lines out: the head's own acknowledgement and the OK...s of
        deferred moves. A deferred one is always ``OK...`` (a refused move is refused at
        once, with ``ERR``), so an ``ERR`` among them is the head's; among OKs it does
        not matter which is whose, only how many. A move at the head may have deferred
        its own: then the deferred moves take the OKs first."""
        held, self._held = self._held, []
        head = self._pending[0]
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

