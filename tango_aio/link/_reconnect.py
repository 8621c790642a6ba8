"""Automatic reconnection: the backoff policy and what a reconnect needs."""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from ..errors import ConnectionLostError, IdentityMismatchError, TangoError
from ._protocol import TangoProtocol

__all__ = [
    "Closer",
    "IdentityMismatchError",
    "Opener",
    "Reconnect",
    "ReconnectPolicy",
    "ReconnectPort",
    "Reconnector",
    "Signature",
    "Stageable",
]

log = logging.getLogger("tango_aio")

#: Shuts down what an opener started besides the transport (the ``sim://`` emulator).
Closer = Callable[[], Awaitable[None]]

#: Opens the URL again: returns a connected protocol and its closer, or raises
#: :class:`~tango_aio.errors.ConnectionLostError` (the URL cannot be opened now).
Opener = Callable[[], Awaitable[tuple[TangoProtocol, Closer | None]]]


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
        """The wait before each attempt, one per attempt (endless without a bound).

        Yields
        ------
        float
            The seconds to wait before the next attempt.
        """
        counter = itertools.count() if self.attempts is None else range(self.attempts)
        delay = self.initial
        for _ in counter:
            yield delay
            delay = min(2.0 * delay, self.maximum)


@dataclass(frozen=True, slots=True)
class Reconnect:
    """What a :class:`~tango_aio.Controller` needs to reconnect on its own."""

    policy: ReconnectPolicy
    opener: Opener
    #: Whether to identify the controller again (as ``connect(identify=...)``).
    identify: bool = True


#: What must not change across a reconnect: ``(model, firmware, number of axes)``.
Signature = tuple[str, str, int]


class Stageable(Protocol):
    """A controller that can be set up on a new link (a throw-away
    :class:`~tango_aio.Controller`)."""

    async def setup(self, *, autostatus: int | None = 1, identify: bool = True) -> None:
        """Bring the controller on the new link into a known state."""

    async def aclose(self) -> None:
        """Close the new link (the set-up failed)."""


StagedT = TypeVar("StagedT", bound=Stageable)


class ReconnectPort(Protocol[StagedT]):
    """The controller as its :class:`Reconnector` sees it."""

    @property
    def url(self) -> str:
        """The URL that is opened again (for messages)."""

    def signature(self, controller: StagedT | None = None) -> Signature | None:
        """The identity of ``controller`` (``None``: the owner), ``None`` if unknown."""

    async def release_link(self) -> None:
        """Shut down what the lost link started besides its transport (``sim://``)."""

    def stage(self, protocol: TangoProtocol, closer: Closer | None) -> StagedT:
        """A throw-away controller on the new link, not yet set up: calls made on the
        owner meanwhile still fail at once instead of reaching a half-set-up link."""

    def adopt(self, staged: StagedT, closer: Closer | None) -> None:
        """Take over the set-up link of ``staged`` (no await: atomic)."""

    def reconnected(self, attempt: int) -> None:
        """The link is up again after ``attempt`` attempts."""

    def give_up(self, lost: ConnectionLostError) -> None:
        """Reconnecting stopped for good; ``lost`` fails everything from now on."""


class Reconnector(Generic[StagedT]):
    """Reconnects one controller after a loss, in a background task, by :class:`Reconnect`."""

    def __init__(self, reconnect: Reconnect, port: ReconnectPort[StagedT]) -> None:
        self.reconnect = reconnect
        self._port = port
        self._armed = False
        self._task: asyncio.Task[None] | None = None
        #: Number of the current (or last) attempt of the latest outage (0: none yet).
        self.attempt = 0

    @property
    def running(self) -> bool:
        """Whether attempts are under way."""
        return self._task is not None and not self._task.done()

    def arm(self) -> None:
        """Reconnect after the next loss (called when the first set-up succeeded)."""
        self._armed = True

    def start(self, mode: int) -> bool:
        """Begin reconnecting after a loss, restoring autostatus ``mode``. Returns whether
        it started (not armed, or already running: no)."""
        if not self._armed or self.running:
            return False
        self.attempt = 0
        self._task = asyncio.get_running_loop().create_task(
            self._loop(mode), name=f"tango_aio reconnect {self._port.url}")
        return True

    async def stop(self) -> None:
        """Stop reconnecting; a link being set up is closed."""
        self._armed = False
        task, self._task = self._task, None
        if task is not None:
            task.cancel()  # _once closes a link it was setting up
            await asyncio.wait([task])

    async def _loop(self, mode: int) -> None:
        """Try again after each delay of the policy until a link is up or it gives up."""
        error: BaseException | None = None
        url = self._port.url
        for attempt, delay in enumerate(self.reconnect.policy.delays(), start=1):
            await asyncio.sleep(delay)
            self.attempt = attempt
            try:
                await self._once(mode)
            except IdentityMismatchError as exc:
                error = exc
                break  # not transient: see the module's docstring
            except (TangoError, OSError, TimeoutError) as exc:
                error = exc
                log.warning("reconnect attempt %d to %s failed: %s", attempt, url, exc)
                continue
            except Exception as exc:  # a bug: do not retry it forever
                log.exception("reconnect attempt %d to %s failed", attempt, url)
                error = exc
                break
            self._port.reconnected(attempt)
            return
        lost = ConnectionLostError(f"reconnecting to {url!r} gave up: {error}")
        lost.__cause__ = error
        self._port.give_up(lost)

    async def _once(self, mode: int) -> None:
        """Open the URL again, set the new link up like the lost one and swap it in."""
        await self._port.release_link()
        protocol, closer = await self.reconnect.opener()
        staged = self._port.stage(protocol, closer)
        try:
            await staged.setup(autostatus=mode, identify=self.reconnect.identify)
            self._check_identity(self._port.signature(staged))
            protocol.check()  # the new link may have dropped at the very end
        except BaseException:
            await staged.aclose()
            raise
        self._port.adopt(staged, closer)

    def _check_identity(self, found: Signature | None) -> None:
        known = self._port.signature()
        if known is None or found is None or found == known:
            return
        raise IdentityMismatchError(
            f"{self._port.url}: expected {known[0]} firmware {known[1]} with {known[2]} "
            f"axes, found {found[0]} firmware {found[1]} with {found[2]} axes; "
            f"not reconnecting")
