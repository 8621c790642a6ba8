"""What an exchange of the link session collects and how its lines are read: what ends the
collection (:class:`Until`), the lines collected (:class:`Exchange`), whether anything can
trail ``help``'s reply, and how a unit ends its ``?statusaxis`` reply."""

from __future__ import annotations

import enum
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from ..status import LETTERS
from ._core import AckReads, is_completion_line
from ._patterns import ACK_PATTERN

__all__ = [
    "STATUS_READ",
    "Exchange",
    "Until",
    "nothing_trails_help",
    "reads_acknowledged",
    "status_tail",
]

_INTEGER: Final = re.compile(r"\s*-?\d+\s*$")


class Until(enum.Enum):
    """What ends an exchange's collection."""

    NUMBER = "number"  #: one number (the reply of the last line, ``?err``)
    HELP = "help"  #: ``help``'s reply, then quiet (unless nothing can trail it)
    MARKER = "marker"  #: the marker's reply twice and then a number; or quiet


@dataclass(slots=True)
class Exchange:
    """The lines an exchange collected (:meth:`LinkSession.begin_exchange`)."""

    until: Until
    marker: str | None = None
    #: The normal forms of the lines written: their echoes (mode 4) are not replies.
    echoes: frozenset[str] = frozenset()
    lines: list[str] = field(default_factory=list)
    #: Marker replies in a row (at most 2), then 3 once the number followed.
    run: int = 0

    @property
    def numbered(self) -> bool:
        """Whether a marker exchange saw the marker's reply twice and then a number."""
        return self.run == 3


def nothing_trails_help(lines: Sequence[str]) -> bool:
    """In a mode exchange (``...``, ``?autostatus``, ``?help``) whose lines so far hold
    the reply of ``?help``: whether no line of ``?help``'s own can follow its reply, so
    that the exchange may end without waiting for a quiet link.

    The first number is the mode ``?help`` runs in (``?autostatus``'s reply; later lines
    wait). Only two modes add lines to a read: mode 2 acknowledges (L2099-2103; reads
    too, on some firmware: the ``ack_reads`` switch of the emulator) and mode 4 echoes
    (L2117; "all input instructions", old L717-725), either before or after the reply.
    Modes 0, 1 and 3 answer a read with its reply alone (L2079-2113: their only other
    lines are move reports), and ``help``'s reply is one line in both editions (L2915-
    2919, old L805-819). In modes 2 and 4 the exchange waits for quiet."""
    for line in lines:
        if _INTEGER.match(line):
            return int(line) in (0, 1, 3)
    return False


def reads_acknowledged(kept: Sequence[str], number: int, help_reply: int) -> AckReads:
    """Whether, and where, mode 2 acknowledges reads, from the stripped lines of a mode
    exchange (``?autostatus`` then ``?help``): ``kept[number]`` is the reply of
    ``?autostatus``, ``kept[help_reply]`` that of ``?help``. An ``OK...`` after the help
    reply is an acknowledgement after the data; one between the two replies (and none
    after), before it. A move acknowledged only at its completion (switch ``move_ok``;
    L2099-2103 do not say when) sends its ``OK...`` with its report, right before it or
    behind it: an ``OK...`` after the help reply next to a report may be that one, so it
    counts only if the ``?autostatus`` reply was not acknowledged before its data."""
    def ack(index: int) -> bool:
        return 0 <= index < len(kept) and ACK_PATTERN.accepts(kept[index])

    def by_report(index: int) -> bool:
        return any(0 <= i < len(kept) and is_completion_line(kept[i])
                   for i in (index - 1, index + 1))

    after = [i for i in range(help_reply + 1, len(kept)) if ack(i)]
    if after and not (all(map(by_report, after)) and ack(number - 1)):
        return AckReads.AFTER
    if any(ack(i) for i in range(number + 1, help_reply)):
        return AckReads.BEFORE
    return AckReads.NO


#: The read a mode exchange may carry to see how ``?statusaxis`` ends (:func:`status_tail`).
STATUS_READ: Final = "?statusaxis"

#: The all-axes ``?statusaxis`` reply without a tail: one letter per axis.
_BARE_LETTERS: Final = re.compile(f"[{re.escape(''.join(sorted(LETTERS)))}]{{1,4}}$")


def status_tail(lines: Sequence[str]) -> str | None:
    """How a unit ends its all-axes ``?statusaxis`` reply, from the lines an exchange
    that wrote it brought back: ``"yes"`` (``.-``, as the manual says and prints:
    "an additional '-' after the dot (.- instead of .)", L2668-2670, ``@@@-.-`` L2715),
    ``"no"`` (the letters alone), or ``"dot"`` (``@@@-.``: the completion report's own
    shape, L2087-2089, which a read then cannot be told from). A completion report that
    came meanwhile does not count: a line with ``.-`` or the bare letters decides first."""
    texts = [line.strip() for line in lines]
    if any(text.endswith(".-") and is_completion_line(text[:-1]) for text in texts):
        return "yes"
    if any(_BARE_LETTERS.match(text) for text in texts):
        return "no"
    if any(is_completion_line(text) for text in texts):
        return "dot"
    return None


def _is_help_reply(text: str) -> bool:
    """Whether ``text`` (stripped) looks like the reply of ``help``."""
    return text.startswith("ERROR")
