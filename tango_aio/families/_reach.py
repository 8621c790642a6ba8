"""What the device families (joystick, I/O, encoders, closed loop, triggers, snapshots)
need of their controller beyond a :class:`FamilyPort`: the present axes, the state read
that keeps ``last_positions()`` current, the event hub, and the list transfers. The
controller is the port: it has these intents itself."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

from ..catalog import Command
from ..events import TangoEvent
from ._base import FamilyPort
from ._bulk import ListTransfer


class DevicePort(FamilyPort, Protocol):
    """The intents of :class:`FamilyPort`, and those of the device families."""

    @property
    def axes(self) -> tuple[str, ...]:
        """The letters of the present axes."""
        ...

    async def read_if_known(self, name: str) -> Any:
        """Read the global setting ``name``, or ``None`` where this controller does not
        know it (older firmware, a unit without the module), without waiting a timeout.

        Parameters
        ----------
        name
            The instruction.

        Returns
        -------
        Any
            The parsed reply, or ``None``.
        """
        ...

    async def state(self) -> tuple[dict[str, str], dict[str, str]]:
        """The status letters and the positions (as printed) of every present axis, read
        together; the positions become ``last_positions()``.

        Returns
        -------
        tuple[dict[str, str], dict[str, str]]
            The letters and the positions.
        """
        ...

    async def user_positions(self, texts: Mapping[str, str]) -> dict[str, float]:
        """Printed positions in the connection's unit (as ``position()`` gives them).

        Parameters
        ----------
        texts
            The positions as printed, by axis.

        Returns
        -------
        dict[str, float]
            The positions.
        """
        ...

    def publish(self, event: TangoEvent) -> None:
        """Hand an event to every subscriber of ``events()``.

        Parameters
        ----------
        event
            The event.
        """
        ...

    def moving(self) -> bool:
        """Whether a move of this driver is in flight.

        Returns
        -------
        bool
            ``True`` while one is.
        """
        ...

    def list_transfer(self) -> ListTransfer:
        """The controller's list transfer (one upload or download at a time).

        Returns
        -------
        ListTransfer
            The transfer.
        """
        ...

    async def resolution(self) -> list[float]:
        """Per present axis, one unit of the last digit ``?pos`` prints.

        Returns
        -------
        list[float]
            The resolution of each present axis, X first.
        """
        ...

    def check_axes(self, command: Command) -> None:
        """Refuse a line for an axis the controller does not have, before any byte.

        Parameters
        ----------
        command
            The line.
        """
        ...
