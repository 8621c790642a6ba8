"""What a reply line looks like, so that a line is never taken for a reply it is not."""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from typing import Final

from ..catalog import Command, Context, Shape, reply_group, reply_rule

__all__ = ["ACK_PATTERN", "ANY_PATTERN", "ONE_NUMBER", "Edge", "ReplyKind", "ReplyPattern",
           "echo_pattern", "marker_pattern", "reply_pattern"]

#: Most values a list reply (``NUMBERS``, ``INTS``) is expected to hold.
_MANY: Final = 1 << 16

_NUMBER_RE: Final = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$")
_STATUS_RE: Final = re.compile(r"[@A-Za-z\-]{1,8}(?:\.[@A-Za-z\-]*)?$")
_ACK_RE: Final = re.compile(r"(?:OK\.*|ERR(?:\s+-?\d+)?)$")


class ReplyKind(enum.Enum):
    """The families of reply lines."""

    # Hashed by identity, in C: Enum's own __hash__ is a Python function, and these
    # members are dict keys and set members on the per-line path. Members are
    # singletons compared by identity, so the two agree.
    __hash__ = object.__hash__

    NUMBERS = "numbers"  #: ``low``..``high`` numbers separated by blanks or commas
    WORDS = "words"  #: ``low``..``high`` blank-separated words of any kind
    STATUS = "status"  #: status letters (``@@@-.-`` or one letter)
    HELP = "help"  #: ``ERROR n,text``
    ACK = "ack"  #: ``OK...`` or ``ERR n``
    ECHO = "echo"  #: the autostatus-4 echo of one particular line
    MARKER = "marker"  #: a line holding one particular text (a marker's reply)
    ANY = "any"  #: free text: accepts every line


@dataclass(frozen=True, slots=True)
class ReplyPattern:
    """The lines a reply item may be. ``text`` is the expected line of an echo."""

    kind: ReplyKind
    low: int = 1
    high: int = 1
    text: str = ""

    def accepts(self, line: str) -> bool:
        """Whether ``line`` (CR removed) can be this reply."""
        kind = self.kind
        if kind is ReplyKind.NUMBERS:
            # A comma only ever ends a value ('?lim' in extmode 0: "-2600 2600,",
            # L4619); one inside a token ("0,0000") is a garbled number.
            tokens = line.split()
            return self.low <= len(tokens) <= self.high and \
                all(_NUMBER_RE.match(token.removesuffix(",")) for token in tokens)
        if kind is ReplyKind.WORDS:
            return self.low <= len(line.split()) <= self.high
        if kind is ReplyKind.STATUS:
            return _STATUS_RE.match(line.strip()) is not None
        if kind is ReplyKind.HELP:
            return line.lstrip().startswith("ERROR")
        if kind is ReplyKind.ACK:
            return _ACK_RE.match(line.strip()) is not None
        if kind is ReplyKind.ECHO:
            return _unbanged(normal_line(line)) == _unbanged(self.text)
        if kind is ReplyKind.MARKER:
            return self.text in line
        return True

    def overlaps(self, other: ReplyPattern) -> bool:
        """Whether some line fits both patterns (conservatively: ``True`` when unsure)."""
        # (As sorted() by _ORDER, stable; without its key function: a hot path. The
        # kinds' order: NUMBERS WORDS STATUS HELP ACK ECHO MARKER ANY.)
        a, b = (self, other) if _ORDER[self.kind] <= _ORDER[other.kind] else (other, self)
        low, high = a.kind, b.kind
        if high is ReplyKind.ANY:
            return True
        if low is high:
            if low is ReplyKind.ECHO:
                return _unbanged(a.text) == _unbanged(b.text)
            if low is ReplyKind.MARKER:
                return a.text == b.text
            return a.low <= b.high and b.low <= a.high
        if high is ReplyKind.ECHO or low is ReplyKind.ECHO:
            # An echo is one known text: it overlaps whatever accepts that text, with or
            # without its '!' (the echo of a bare read 'sa' or 'err' is status letters).
            echo, rest = (a, b) if low is ReplyKind.ECHO else (b, a)
            return rest.accepts(echo.text) or rest.accepts(_unbanged(echo.text))
        if high is ReplyKind.MARKER:
            # A marker's text is chosen to be unlike any reply (the HELP kind is the
            # conservative exception: ERROR n,text replies of ?help). Words fit any line
            # of their count, and a line holding the text has at least its words.
            return low is ReplyKind.HELP or (
                low is ReplyKind.WORDS and a.high >= len(b.text.split()))
        if low is ReplyKind.NUMBERS and high is ReplyKind.WORDS:
            return a.low <= b.high and b.low <= a.high
        # Words may be anything else; the specific kinds exclude each other.
        return low is ReplyKind.WORDS


_ORDER: Final = {kind: index for index, kind in enumerate(ReplyKind)}


@dataclass(frozen=True, slots=True)
class Edge:
    """The lines at one end of a request's reply, where it meets its neighbour's on the
    wire: at the front, the lines before the first one it is sure to get and that one; at
    the back, the last line it is sure to get and the lines after it. "Sure" excludes the
    lines some firmware sends and some does not (a read's echo in mode 4, a read's
    acknowledgement in mode 2 before it is detected) and those that may come much later
    (a move's echo or acknowledgement that some firmware sends only with its report)."""

    patterns: tuple[ReplyPattern, ...]

    def overlaps(self, other: Edge) -> bool:
        """Whether some line may fit both edges."""
        for mine in self.patterns:  # (loops, not any(): a hot path)
            for theirs in other.patterns:
                if mine.overlaps(theirs):
                    return True
        return False

#: An acknowledgement of a ``!`` line (autostatus 2, ``save``).
ACK_PATTERN: Final = ReplyPattern(ReplyKind.ACK)
#: A reply of free text.
ANY_PATTERN: Final = ReplyPattern(ReplyKind.ANY)
#: One number (``?err``, ``?vel x``).
ONE_NUMBER: Final = ReplyPattern(ReplyKind.NUMBERS)

_SCALARS: Final = {
    Shape.INT: ONE_NUMBER,
    Shape.FLOAT: ONE_NUMBER,
    Shape.ERROR_NUMBER: ONE_NUMBER,
    Shape.DET: ONE_NUMBER,
    Shape.FLAGS: ReplyPattern(ReplyKind.WORDS),
    Shape.STATUS: ReplyPattern(ReplyKind.STATUS),
    Shape.HELP: ReplyPattern(ReplyKind.HELP),
    Shape.ACK: ACK_PATTERN,
    Shape.NUMBERS: ReplyPattern(ReplyKind.NUMBERS, 1, _MANY),
    Shape.INTS: ReplyPattern(ReplyKind.NUMBERS, 1, _MANY),
}
_PER_AXIS: Final = {
    Shape.AXES_FLOAT: ReplyKind.NUMBERS,
    Shape.AXES_INT: ReplyKind.NUMBERS,
    Shape.AXES_TEXT: ReplyKind.WORDS,
}


def normal_line(text: str) -> str:
    """The form in which a command line and its mode-4 echo are compared: the echo is
    matched by instruction, not by exact text (some firmware re-formats it, e.g.
    ``!MOA 1.50`` echoed as ``!moa 1.5``). Case, blanks and the way numbers are written
    do not count; the instruction, axis and values do."""
    return " ".join(_normal_token(token) for token in text.lower().split())


def _unbanged(text: str) -> str:
    """An echo without its leading ``!``: L2117 says only that mode 4 "echoes the
    instruction", and some firmware may print it without the prefix (switch
    ``echo_text=nobang``: ``!moa 1`` echoed as ``moa 1``). The bare form executes the
    same instruction (L2154), so the two echoes stand for the same line."""
    return text[1:] if text.startswith("!") else text


def _normal_token(token: str) -> str:
    if _NUMBER_RE.match(token):
        try:
            return repr(float(token))
        except ValueError:  # pragma: no cover - the pattern only lets numbers through
            return token
    return token


def marker_pattern(text: str) -> ReplyPattern:
    """The reply of a marker: any line that holds ``text``."""
    return ReplyPattern(ReplyKind.MARKER, text=text)


def echo_pattern(command: Command) -> ReplyPattern:
    """The autostatus-4 echo of ``command``."""
    return ReplyPattern(ReplyKind.ECHO, text=normal_line(command.line))


def reply_pattern(command: Command, context: Context | None = None) -> ReplyPattern:
    """The pattern of each data line ``command`` replies with (reads, and the ``OK``/``ERR``
    of ``save``); :data:`ANY_PATTERN` for free text and replies of several lines."""
    entry = command.instruction
    shape = entry.reply if command.is_read else entry.exec_reply
    rule = reply_rule(command, context)
    if rule.count != 1 or rule.terminator is not None or rule.continuation is not None:
        return ANY_PATTERN
    scalar = _SCALARS.get(shape)
    if scalar is not None:
        return scalar
    kind = _PER_AXIS.get(shape)
    if kind is None:
        return ANY_PATTERN  # TEXT, VERSION ('1.71' alone is a version), LINES
    group = reply_group(command)
    if command.axis is not None:
        return ReplyPattern(kind, group, group)
    # '1 1 11 1 11 1 1': one-digit values may run together (Instruction.digit_values).
    low = 1 if entry.digit_values else group
    return ReplyPattern(kind, low, 4 * group)

