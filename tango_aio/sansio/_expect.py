"""Expectations: the items of a reply each written line owes (echo, data, acknowledgement),
from the catalog and the autostatus mode, and the FIFO entry that holds them."""

from __future__ import annotations

import enum
import itertools
import math
from collections import deque
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field
from typing import Final

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
from ._patterns import (
    ACK_PATTERN,
    ONE_NUMBER,
    Edge,
    ReplyKind,
    ReplyPattern,
    echo_pattern,
    reply_pattern,
)


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
    one (``None``: it is sure to get none; a move's ``?err`` probe then guards it)."""
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
    """What ``command`` owes when it reaches the controller in autostatus ``mode``."""
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
#: Cached expectations by (instruction name, form, mode), with the instruction they were
#: computed for (a hand-made Instruction of the same name does not share them). A memo of
#: the pure function :func:`expectation`, whose result depends on its key alone, so every
#: core may share it (what depends on a core's state is cached per core: _line_facts).
_EXPECTATIONS: dict[tuple[str, Form, int], tuple[Instruction, Expectation]] = {}


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
      (``ack_mode_change``): a line entering or leaving mode 2 may or may not be."""
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
