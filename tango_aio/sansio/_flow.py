"""Write-credit accounting: never overrun the controller's 256-byte input buffer.

Theory of operation
===================
The controller buffers received bytes until its interpreter has processed the line they
belong to; bytes that arrive while 256 are buffered are lost without notice (manual
L129-131, L14093). The driver therefore counts every byte it writes as *outstanding* until
it knows the controller has processed it, and never lets the outstanding bytes exceed the
*limit* (255 by default).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Final

__all__ = ["DEFAULT_CHUNK", "DEFAULT_LIMIT", "MARKER", "CreditWindow"]

#: At most this many bytes written and not yet confirmed (the buffer holds 256).
DEFAULT_LIMIT: Final = 255
#: Reply-less bytes after which a marker is appended. With 160, a marker costs 2.5 % of the
#: bytes, and when its reply frees the credit about 90 bytes (16 ms at 57600 Bd) are still
#: in flight, which covers the reply latency of USB adapters (benchmarks/upload.py).
DEFAULT_CHUNK: Final = 160
#: The marker line: the bare read form of ``err`` (manual L2824), 4 bytes.
MARKER: Final = b"err\r"


@dataclass(slots=True)
class _Written:
    size: int
    tag: Hashable | None  # the request whose reply confirms this line, if any


class CreditWindow:
    """Counts outstanding bytes and says when a marker is needed."""

    def __init__(self, limit: int = DEFAULT_LIMIT, chunk: int = DEFAULT_CHUNK,
                 reserve: int = 0) -> None:
        if limit < len(MARKER) + 1:
            raise ValueError(f"credit limit {limit} is too small")
        self.limit = limit
        self.chunk = max(1, min(chunk, limit - len(MARKER) - reserve))
        self._written: deque[_Written] = deque()
        self.outstanding = 0
        #: Reply-less bytes written since the last line that owes a reply.
        self.unmarked = 0
        #: Highest number of outstanding bytes seen (for tests and benchmarks).
        self.peak = 0

    def fits(self, size: int, has_reply: bool) -> bool:
        """Whether a line of ``size`` bytes may be written now."""
        reserve = 0 if has_reply else len(MARKER)
        if size + reserve > self.limit:
            return self.outstanding == 0
        return self.outstanding + size + reserve <= self.limit

    def marker_due(self, next_size: int | None, next_has_reply: bool) -> bool:
        """Whether a marker should be written before the next line (``None``: the queue
        is empty)."""
        if self.unmarked == 0:
            return False
        if self.unmarked >= self.chunk:
            return True
        if next_size is None:
            return False
        if not next_has_reply and self.unmarked + next_size > self.chunk:
            return True
        # The next line would not fit even once everything confirmable is confirmed:
        # only a marker can ever confirm the tail.
        reserve = 0 if next_has_reply else len(MARKER)
        return self.unmarked + next_size + reserve > self.limit

    def marker_fits(self) -> bool:
        """Whether a marker may be written now."""
        if self.outstanding + len(MARKER) <= self.limit:
            return True
        return all(item.tag is None for item in self._written)

    def wrote(self, size: int, tag: Hashable | None) -> None:
        """Record ``size`` bytes written; ``tag`` is the request whose reply confirms them
        (``None`` for a reply-less line)."""
        written = self._written
        if tag is None and written and written[-1].tag is None:
            # Reply-less lines in a row are confirmed together: one entry (a list upload
            # keeps one per run between markers, not one per line).
            written[-1].size += size
        else:
            written.append(_Written(size, tag))
        self.outstanding += size
        self.peak = max(self.peak, self.outstanding)
        self.unmarked = 0 if tag is not None else self.unmarked + size

    def wrote_run(self, ends: Sequence[int], first: int) -> int:
        """Record reply-less lines of a run (``ends``: where each line ends in the run's
        bytes): line ``first``, which the caller found may go, and the lines after it
        while each :meth:`fits` and no marker is due (:meth:`marker_due`) before it.
        Returns the index after the last line taken."""
        start = ends[first - 1] if first else 0
        self.wrote(ends[first] - start, None)
        unmarked, outstanding = self.unmarked, self.outstanding
        chunk, room = self.chunk, self.limit - len(MARKER)
        index, count = first + 1, len(ends)
        while index < count:
            size = ends[index] - ends[index - 1]
            grown = unmarked + size
            # marker_due(size, False) (unmarked > 0 here), then fits(size, False) with
            # something outstanding.
            if unmarked >= chunk or grown > chunk or grown > room or size > room \
                    or outstanding + size > room:
                break
            unmarked, outstanding = grown, outstanding + size
            index += 1
        if index > first + 1:
            self.wrote(ends[index - 1] - ends[first], None)
        return index

    def confirm(self, tag: Hashable, *, inclusive: bool = True) -> None:
        """The reply of ``tag`` arrived: its line (with ``inclusive``) and all before it
        are processed. Unknown tags confirm nothing."""
        if not any(item.tag == tag for item in self._written):
            return
        while self._written:
            head = self._written[0]
            if head.tag == tag and not inclusive:
                return
            self._written.popleft()
            self.outstanding -= head.size
            if head.tag == tag:
                break
        if not any(item.tag is None for item in self._written):
            self.unmarked = 0

    def cleared(self) -> None:
        """The controller discarded its input buffer (Ctrl+C): nothing is outstanding."""
        self._written.clear()
        self.outstanding = 0
        self.unmarked = 0
