"""Line reassembly: CR-terminated lines from byte fragments, each stamped with its first
byte's arrival, and the shapes recognised before routing (case, completion reports)."""

from __future__ import annotations

import math
import re
from collections import deque
from typing import Final, NoReturn

from ..errors import ProtocolError
from ..status import LETTERS

#: Longest line the assembler buffers before it gives up on it. The controller's lines are
#: far shorter; ``service`` output is the longest.
DEFAULT_MAX_LINE: Final = 1024

_CR: Final = 0x0D
#: The bytes ``str.strip`` removes from a Latin-1 line (a reply is matched stripped).
_BLANK_BYTES: Final = frozenset(code for code in range(256) if chr(code).isspace())

#: A completion report: one status letter per axis X Y Z A (``-`` = absent), then ``.``
#: (manual L2087-2089, L6337-6343). Firmware with fewer axes may send fewer letters.
_COMPLETION_RE: Final = re.compile(f"^[{re.escape(''.join(sorted(LETTERS)))}]{{1,4}}\\.$")

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
