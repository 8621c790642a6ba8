"""What the controller hands over: :class:`_Port` (the controller as
:class:`~tango_aio.controller._motion.Motion` sees it, made of the controller's own
methods), :class:`_Relink` (the same for its reconnector), and :class:`_Devices`, the
controller's intents the device families need."""

from __future__ import annotations

from collections.abc import (
    Callable,
    Coroutine,
    Mapping,
    Sequence,
)
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
)
from ..errors import (
    ConnectionLostError,
    ControllerError,
    InvalidInstructionError,
    ProtocolError,
)
from ..events import (
    MoveFinished,
    TangoEvent,
)
from ..link import (
    Closer,
    MoveHandle,
    Signature,
    TangoProtocol,
)
from ..units import Measure
from ._setup import _Setup

#: The controller a reconnect stages (the :class:`Controller` itself).
StagedT = TypeVar("StagedT")
StagedT_contra = TypeVar("StagedT_contra", contravariant=True)


@dataclass(frozen=True, slots=True)
class _Port:
    """The controller as :class:`~tango_aio.controller._motion.Motion` sees it
    (``MotionPort``): the controller's own methods, handed over."""

    start: Callable[[Command, object | None], MoveHandle]
    accepted: Callable[[MoveHandle], Coroutine[Any, Any, ControllerError | None]]
    stop: Callable[[], Coroutine[Any, Any, None]]
    read_state: Callable[[Sequence[str]],
                         Coroutine[Any, Any, tuple[dict[str, str], dict[str, str]]]]
    finished: Callable[[MoveFinished], None]
    unreported: Callable[[], None]


class _Devices(_Setup):
    """The intents the device families send the controller beyond a family's reads and
    writes (:class:`~tango_aio.families.DevicePort`): the controller is their port. The
    status read, the list transfer, the resolution and the axis check are its own private
    methods already."""

    @property
    def axes(self) -> tuple[str, ...]:
        """The letters of the present axes (``("x", "y", "z")``)."""
        known = self._identity
        return tuple(AXES[: known.axes if known else self.context.axes])

    async def _read_if_known(self, name: str) -> Any:
        """The global setting ``name``, or ``None`` where this controller does not know it
        (older firmware, a unit without the module), without waiting a timeout."""
        known = self._identity
        if known is not None and known.family == "older" \
                and not INSTRUCTIONS[name].in_older_manual:
            return None
        try:
            return await self._read_or_absent(name)
        except (InvalidInstructionError, ProtocolError):
            return None

    async def _user_positions(self, texts: Mapping[str, str]) -> dict[str, float]:
        """Printed positions converted as :meth:`position` converts its reads."""
        return await self._from_controller(
            texts, self._reading_unit(None, Measure.POSITION), Measure.POSITION)

    def _publish_event(self, event: TangoEvent) -> None:
        """Hand ``event`` to every subscription of :meth:`events` (never blocks)."""
        self._hub.publish(event)

    def _in_motion(self) -> bool:
        """Whether a move of this driver is in flight (no read: see :meth:`is_busy`)."""
        return self._motion.busy or bool(self._motion_calls)


@dataclass(frozen=True, slots=True)
class _Relink(Generic[StagedT]):
    """The controller as its :class:`~tango_aio.link._reconnect.Reconnector` sees it
    (:class:`~tango_aio.link._reconnect.ReconnectPort`): the controller's own methods, handed
    over."""

    url_of: Callable[[], str]
    signature: _SignatureOf[StagedT]
    release_link: Callable[[], Coroutine[Any, Any, None]]
    stage: Callable[[TangoProtocol, Closer | None], StagedT]
    adopt: Callable[[StagedT, Closer | None], None]
    reconnected: Callable[[int], None]
    give_up: Callable[[ConnectionLostError], None]

    @property
    def url(self) -> str:
        """The URL that is opened again."""
        return self.url_of()


class _SignatureOf(Protocol[StagedT_contra]):
    def __call__(self, controller: StagedT_contra | None = None) -> Signature | None: ...


