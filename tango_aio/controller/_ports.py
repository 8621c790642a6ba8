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
from ..families import (
    ListTransfer,
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
    writes (:class:`~tango_aio.families.DevicePort`): the controller is their port."""

    @property
    def axes(self) -> tuple[str, ...]:
        """The letters of the present axes (``("x", "y", "z")``)."""
        known = self._identity
        return tuple(AXES[: known.axes if known else self.context.axes])

    async def read_if_known(self, name: str) -> Any:
        """Read the global setting ``name``, or ``None`` where this controller does not
        know it (older firmware, a unit without the module), without waiting a timeout.

        Parameters
        ----------
        name
            The instruction (``"trigcomp"``).

        Returns
        -------
        Any
            The parsed reply, or ``None``.
        """
        known = self._identity
        if known is not None and known.family == "older" \
                and not INSTRUCTIONS[name].in_older_manual:
            return None
        try:
            return await self._read_or_absent(name)
        except (InvalidInstructionError, ProtocolError):
            return None

    async def state(self) -> tuple[dict[str, str], dict[str, str]]:
        """The status letters and the positions (as printed) of every present axis, read
        in one round trip; the positions become :attr:`last_positions`.

        Returns
        -------
        tuple[dict[str, str], dict[str, str]]
            The letters and the positions, by axis.
        """
        return await self._status_and_positions()

    async def user_positions(self, texts: Mapping[str, str]) -> dict[str, float]:
        """Positions as :meth:`state` gives them, converted as :meth:`position`
        converts its reads.

        Parameters
        ----------
        texts
            The printed position of each axis.

        Returns
        -------
        dict[str, float]
            Each axis' position in the connection's unit (``units``), else the dim unit.
        """
        return await self._from_controller(
            texts, self._reading_unit(None, Measure.POSITION), Measure.POSITION)

    def publish(self, event: TangoEvent) -> None:
        """Hand ``event`` to every subscription of :meth:`events` (never blocks).

        Parameters
        ----------
        event
            What the subscribers receive.
        """
        self._hub.publish(event)

    def moving(self) -> bool:
        """Whether a move of this driver is in flight (no read: see :meth:`is_busy`).

        Returns
        -------
        bool
            ``True`` while one is.
        """
        return self._motion.busy or bool(self._motion_calls)

    def list_transfer(self) -> ListTransfer:
        """The list transfer of this connection (one upload or download at a time).

        Returns
        -------
        ListTransfer
            The transfer.
        """
        return self._transfer()

    async def resolution(self) -> list[float]:
        """Per present axis, one unit of the last digit ``?pos`` prints.

        Returns
        -------
        list[float]
            The resolution of each present axis, X first.
        """
        return await self._resolution()

    def check_axes(self, command: Command) -> None:
        """Refuse a line for an axis this controller does not have, before any byte.

        Parameters
        ----------
        command
            The line.

        Raises
        ------
        InvalidCommandError
            The line names an axis this controller does not have.
        """
        self._check_axes(command)
