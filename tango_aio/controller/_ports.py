"""What the controller hands over: :class:`_Port` (the controller as
:class:`~tango_aio.controller._motion.Motion` sees it, made of the controller's own
methods), and :class:`_Devices`, the controller's intents the device families need."""

from __future__ import annotations

from collections.abc import (
    Callable,
    Coroutine,
    Mapping,
    Sequence,
)
from dataclasses import dataclass
from typing import Any

from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
)
from ..errors import (
    ControllerError,
    InvalidInstructionError,
    ProtocolError,
)
from ..events import (
    MoveFinished,
    TangoEvent,
)
from ..link import (
    MoveHandle,
)
from ..units import Measure
from ._setup import _Setup


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
