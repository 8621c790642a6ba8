"""The HDI (joystick, trackball, handwheel): on and off around automated moves."""

from __future__ import annotations

from ._generated import JoystickAccess

__all__ = ["Joystick"]


class Joystick(JoystickAccess):
    """The controller's HDI device (``tango.joystick``; manual chapter 15): the typed
    access of every HDI instruction (speeds, directions, curves, key modes:
    :class:`JoystickAccess`) and the switch around automated moves.

    While it is enabled, a deflection moves the axes; the positions it leaves reach
    ``position()`` (always read), and ``watch_inputs()`` of ``tango.io`` publishes them
    as position events while no move of this driver runs.
    """

    async def enable(self) -> None:
        """Switch the HDI on (``!joy 2``; 1 has the same effect, L7101-7118), proven by
        its read-back."""
        await self._port.set("joy", 2)

    async def disable(self) -> None:
        """Switch the HDI off (``!joy 0``, L7101-7118), proven by its read-back.

        Switching it off from on sends a status report ``@@@-.`` with autostatus on, also
        during a move (L7124-7154): the driver takes it for no move's end, and a move in
        flight still ends on its own report.
        """
        await self._port.set("joy", 0)

    async def is_enabled(self) -> bool:
        """Whether the HDI is on (``?joy`` not 0).

        Returns
        -------
        bool
            ``True`` while a deflection moves the axes.
        """
        return int(await self._port.get("joy")) != 0
