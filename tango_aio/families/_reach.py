"""What the device families (joystick, I/O, encoders, closed loop, triggers, snapshots)
need of their controller beyond a :class:`FamilyPort`: the present axes, the state read
that keeps ``last_positions()`` current, the event hub, and the list transfers. The
controller is the port: it has these intents itself, private but for ``axes`` (the
families are its parts, not its users)."""

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

    async def _read_if_known(self, name: str) -> Any:
        """The global setting ``name``, or ``None`` where this controller does not know it
        (older firmware, a unit without the module), without waiting a timeout."""
        ...

    async def _status_and_positions(self) -> tuple[dict[str, str], dict[str, str]]:
        """The status letters and the printed positions of every present axis, read
        together; the positions become ``last_positions()``."""
        ...

    async def _user_positions(self, texts: Mapping[str, str]) -> dict[str, float]:
        """Printed positions in the connection's unit (as ``position()`` gives them)."""
        ...

    def _publish_event(self, event: TangoEvent) -> None:
        """Hand an event to every subscriber of ``events()``."""
        ...

    def _in_motion(self) -> bool:
        """Whether a move of this driver is in flight."""
        ...

    def _transfer(self) -> ListTransfer:
        """The controller's list transfer (one upload or download at a time)."""
        ...

    async def _resolution(self) -> list[float]:
        """Per present axis, one unit of the last digit ``?pos`` prints."""
        ...

    def _check_axes(self, command: Command) -> None:
        """Refuse a line for an axis the controller does not have, before any byte."""
        ...
