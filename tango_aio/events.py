"""Events pushed by a controller, and subscriptions to them.

Events are frozen dataclasses. :meth:`EventHub.subscribe` returns an async iterator with a
bounded buffer; several subscribers can exist at once and each sees every event published
after it subscribed.

Overflow policy (that of :class:`~tango_aio.stream.BoundedStream`, which every subscription
is): a subscriber that falls behind loses its *oldest* buffered events, never the newest,
and never blocks the connection. :attr:`Subscription.dropped` counts what it
lost. When the connection is lost, subscribers receive :class:`ConnectionLost` and then
their iteration ends, unless the controller was opened with ``reconnect=True``: then the
stream goes on, and :class:`Reconnected` follows once the link is back.
"""

from __future__ import annotations

import itertools
import time
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import TracebackType

from .stream import BoundedStream

__all__ = [
    "ConnectionLost",
    "ControllerFault",
    "ControllerRestarted",
    "EventHub",
    "InputsChanged",
    "JoystickMoved",
    "MoveAborted",
    "MoveFinished",
    "PositionUpdate",
    "Reconnected",
    "StatusReport",
    "Subscription",
    "TangoEvent",
    "UnsolicitedLine",
]


def _now() -> float:
    return time.monotonic()


@dataclass(frozen=True, slots=True)
class MoveFinished:
    """A move (``kind`` ``"move"``), calibration (``"cal"``) or range measure (``"rm"``)
    ended. ``statuses`` maps each present axis to its status letter (empty when the
    autostatus-3 bare CR carried none). ``ok`` is False if any axis reports E, S or T."""

    kind: str
    statuses: Mapping[str, str]
    ok: bool
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class MoveAborted:
    """Axes were stopped by an abort (``a`` or Ctrl+C), or by :meth:`Controller.stop
    <tango_aio.Controller.stop>` of some axes (``a x``)."""

    ctrl_c: bool
    #: The axes stopped (``()``: every axis).
    axes: tuple[str, ...] = ()
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class StatusReport:
    """A completion report that no move was waiting for (e.g. ``!joy 0`` disabling the
    joystick, manual L7124)."""

    statuses: Mapping[str, str]
    line: str
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class UnsolicitedLine:
    """A line the controller sent that no request was waiting for."""

    line: str
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class PositionUpdate:
    """Axis positions (dim units), from :meth:`Controller.watch_position`."""

    positions: Mapping[str, float]
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class InputsChanged:
    """Digital input levels changed, from the I/O family's ``watch_inputs()``."""

    #: Every input's level now (``?digin``: input 0 first).
    levels: tuple[bool, ...]
    #: The inputs whose level changed since the previous read.
    changed: tuple[int, ...]
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class JoystickMoved:
    """The stage moved while no move of this driver ran and the joystick was enabled,
    from the I/O family's ``watch_inputs()``: its positions (as :class:`PositionUpdate`,
    which is published with it)."""

    positions: Mapping[str, float]
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class ConnectionLost:
    """The link to the controller is gone; ``cause`` says why, when known."""

    cause: BaseException | None
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class Reconnected:
    """The driver connected again after a loss (automatic reconnect)."""

    attempt: int
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class ControllerFault:
    """The controller reports a persistent internal error (``number`` >= 20, manual
    L2853-2867) that no command caused; ``number`` 0 is never published. ``text`` is the
    manual's text for the number. See :class:`~tango_aio.errors.InternalControllerError`."""

    number: int
    text: str
    time: float = field(default_factory=_now)


@dataclass(frozen=True, slots=True)
class ControllerRestarted:
    """The controller restarted behind a link that stayed up (a power cycle, a reset),
    and the driver recovered: it found the controller in autostatus
    ``found`` (1 at power-on, L2069) instead of the mode it had set, ``autostatus``, which
    it selected again; it read its cached settings again, and ``settings`` maps each
    that the restart changed to its ``(before, after)`` values (a restart reloads the
    saved settings: what was set and not saved is gone). Position counters restart at 0,
    calibration is lost: a move that failed meanwhile may have run
    (:class:`~tango_aio.errors.MoveOutcomeUnknown`)."""

    found: int
    autostatus: int
    settings: Mapping[str, tuple[object, object]]
    time: float = field(default_factory=_now)


TangoEvent = (
    MoveFinished
    | ControllerFault
    | ControllerRestarted
    | MoveAborted
    | StatusReport
    | UnsolicitedLine
    | PositionUpdate
    | InputsChanged
    | JoystickMoved
    | ConnectionLost
    | Reconnected
)


class Subscription(BoundedStream[TangoEvent]):
    """An async iterator over events, with a bounded buffer (drops the oldest on overflow,
    :attr:`dropped` counts them; see :class:`~tango_aio.stream.BoundedStream`).

    Use it as ``async with controller.events() as events: async for event in events: ...``
    or iterate directly and call :meth:`aclose` when done. A subscription nobody refers to
    any more (``async for event in tango.events(): return``) is unregistered by itself:
    the hub only holds weak references, so forgetting to close one leaks nothing.

    Parameters
    ----------
    hub
        The hub it subscribes to.
    maxsize
        How many events it holds before it drops the oldest.
    """

    def __init__(self, hub: EventHub, maxsize: int) -> None:
        super().__init__(maxsize)
        self._hub = hub
        self._key = -1

    def close(self) -> None:
        """Stop receiving events; buffered ones are discarded and iteration ends."""
        self._hub._discard(self)
        super().close()

    async def aclose(self) -> None:
        """Stop receiving events (same as :meth:`close`)."""
        self.close()

    async def __aenter__(self) -> Subscription:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()


class EventHub:
    """Fans events out to every current :class:`Subscription`.

    Subscriptions are held weakly (in subscription order): one that its owner dropped
    without closing it is unregistered when it is collected (2000 abandoned
    ones held 7.9 MB and slowed every event down).
    """

    def __init__(self) -> None:
        self._subscribers: weakref.WeakValueDictionary[int, Subscription] = \
            weakref.WeakValueDictionary()
        self._keys = itertools.count()
        self._closed = False

    @property
    def subscribers(self) -> int:
        """Number of live subscriptions."""
        return len(self._subscribers)

    def subscribe(self, maxsize: int = 256) -> Subscription:
        """A new subscription buffering up to ``maxsize`` events.

        Parameters
        ----------
        maxsize
            How many events the subscription holds before it drops the oldest.

        Returns
        -------
        Subscription
            The new subscription.
        """
        subscription = Subscription(self, maxsize)
        if self._closed:
            subscription.end()
        else:
            subscription._key = next(self._keys)
            self._subscribers[subscription._key] = subscription
        return subscription

    def publish(self, event: TangoEvent) -> None:
        """Deliver ``event`` to every subscriber (never blocks).

        Parameters
        ----------
        event
            The event.
        """
        for subscription in list(self._subscribers.values()):
            subscription.offer(event)

    def close(self) -> None:
        """End every subscription (after the events already buffered)."""
        self._closed = True
        for subscription in list(self._subscribers.values()):
            subscription.end()
        self._subscribers.clear()

    def reopen(self) -> None:
        """Accept subscriptions again (after a reconnect)."""
        self._closed = False

    def _discard(self, subscription: Subscription) -> None:
        self._subscribers.pop(subscription._key, None)
