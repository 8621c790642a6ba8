"""One bounded, drop-oldest stream: what every subscription of tango_aio is built on.

A :class:`BoundedStream` is an async iterator over items that a producer :meth:`offers
<BoundedStream.offer>` without ever waiting. Its buffer holds at most ``maxsize`` items;
when it is full, the *oldest* buffered item is dropped (never the newest, and the producer
never blocks) and :attr:`~BoundedStream.dropped` counts the loss. :meth:`end` lets the
consumer drain what is buffered and then stops the iteration; :meth:`close` stops it at
once and discards the buffer.

Both :class:`tango_aio.events.Subscription` (one controller's events) and
:class:`tango_aio.GroupSubscription` (a group's merged events) are such streams;
they add only where their items come from.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator
from typing import Generic, TypeVar

__all__ = ["BoundedStream", "check_maxsize"]

T = TypeVar("T")


def check_maxsize(maxsize: object) -> int:
    """``maxsize`` if it is an integer of at least 1, else :class:`ValueError`."""
    if isinstance(maxsize, bool) or not isinstance(maxsize, int) or maxsize < 1:
        raise ValueError(f"maxsize must be an integer of at least 1, got {maxsize!r}")
    return maxsize


class BoundedStream(Generic[T]):
    """An async-iterable buffer of at most ``maxsize`` items that drops its oldest item
    on overflow (see the module documentation)."""

    def __init__(self, maxsize: int) -> None:
        self._maxsize = check_maxsize(maxsize)
        self._buffer: deque[T] = deque()
        self._ready = asyncio.Event()
        self._ended = False
        self._dropped = 0

    @property
    def dropped(self) -> int:
        """Number of items lost because the buffer was full."""
        return self._dropped

    @property
    def pending(self) -> int:
        """Number of items buffered and not yet received."""
        return len(self._buffer)

    @property
    def ended(self) -> bool:
        """Whether no more items will be accepted (:meth:`end` or :meth:`close`)."""
        return self._ended

    def offer(self, item: T) -> None:
        """Buffer ``item`` (never blocks); drop the oldest item if the buffer is full.
        Ignored once the stream has ended."""
        if self._ended:
            return
        if len(self._buffer) >= self._maxsize:
            self._buffer.popleft()
            self._dropped += 1
        self._buffer.append(item)
        self._ready.set()

    def end(self) -> None:
        """No more items: iteration ends once the buffer is drained."""
        self._ended = True
        self._ready.set()

    def close(self) -> None:
        """Stop at once: buffered items are discarded and iteration ends."""
        self._buffer.clear()
        self.end()

    def get_nowait(self) -> T | None:
        """The next buffered item, or ``None`` if there is none."""
        return self._buffer.popleft() if self._buffer else None

    def __aiter__(self) -> AsyncIterator[T]:
        return self

    async def __anext__(self) -> T:
        while not self._buffer:
            if self._ended:
                raise StopAsyncIteration
            self._ready.clear()
            await self._ready.wait()
        return self._buffer.popleft()
