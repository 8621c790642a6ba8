"""Automatic reconnection: the backoff policy and what a reconnect needs.

Opt in with ``connect(url, reconnect=True)``. After the link is lost the
:class:`~tango_aio.controller.Controller` keeps its identity as an object and, in a
background task, waits, opens the same URL again, sets the new link up like the first one
(resync, identity check, the autostatus mode in force when the link was lost) and swaps
it in; see :meth:`Controller.wait_connected <tango_aio.controller.Controller.wait_connected>`.

Choices:

* The first attempt also waits :attr:`ReconnectPolicy.initial`: right after a loss the
  other end is usually still going away (a TCP server restarting, a USB adapter being
  re-enumerated), so an immediate attempt mostly fails.
* Nothing that was in flight is retried: a move may or may not have run, and only the
  caller can decide whether to send it again. Its await raises
  :class:`~tango_aio.errors.ConnectionLostError`.
* A different controller answering (model, firmware or number of axes changed) is not a
  transient error: the driver's cached settings and the caller's assumptions no longer
  hold, so reconnecting stops with :class:`IdentityMismatchError`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass

from .errors import ConnectionLostError
from .protocol import TangoProtocol

__all__ = ["Closer", "IdentityMismatchError", "Opener", "Reconnect", "ReconnectPolicy"]

#: Shuts down what an opener started besides the transport (the ``sim://`` emulator).
Closer = Callable[[], Awaitable[None]]

#: Opens the URL again: returns a connected protocol and its closer, or raises
#: :class:`~tango_aio.errors.ConnectionLostError` (the URL cannot be opened now).
Opener = Callable[[], Awaitable[tuple[TangoProtocol, Closer | None]]]


class IdentityMismatchError(ConnectionLostError):
    """After a reconnect a different controller answered (model, firmware or axes changed);
    the driver stopped reconnecting."""


@dataclass(frozen=True, slots=True)
class ReconnectPolicy:
    """Bounded exponential backoff: wait ``initial`` seconds before the first attempt,
    twice as long before each next one, at most ``maximum``; give up after ``attempts``
    failed attempts (``None``: never give up; :meth:`Controller.aclose` stops it)."""

    initial: float = 0.1
    maximum: float = 5.0
    attempts: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.initial) and self.initial > 0):
            raise ValueError(f"reconnect_initial must be a positive number, got {self.initial}")
        if not (math.isfinite(self.maximum) and self.maximum >= self.initial):
            raise ValueError(f"reconnect_max must be at least reconnect_initial "
                             f"({self.initial}), got {self.maximum}")
        if self.attempts is not None and self.attempts < 1:
            raise ValueError(f"reconnect_attempts must be None or at least 1, "
                             f"got {self.attempts}")

    def delays(self) -> Iterator[float]:
        """The wait before each attempt, one per attempt (endless without a bound)."""
        counter = itertools.count() if self.attempts is None else range(self.attempts)
        delay = self.initial
        for _ in counter:
            yield delay
            delay = min(2.0 * delay, self.maximum)


@dataclass(frozen=True, slots=True)
class Reconnect:
    """What a :class:`~tango_aio.controller.Controller` needs to reconnect on its own."""

    policy: ReconnectPolicy
    opener: Opener
    #: Whether to identify the controller again (as ``connect(identify=...)``).
    identify: bool = True
