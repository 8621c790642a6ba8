"""Closed loop: switched on per axis once its preconditions are checked, its mode and its
settling settings."""

from __future__ import annotations

import enum

from ..catalog import AXES, build
from ..errors import ClosedLoopPreconditionError, InvalidCommandError
from ._generated import ClosedLoopAccess
from ._reach import DevicePort

__all__ = ["ClosedLoop", "ClosedLoopMode"]


class ClosedLoopMode(enum.IntEnum):
    """``ctr`` (L11761-11800); 3 and 4 are not supported and behave like 1 and 2."""

    OFF = 0
    #: Active until the position is reached.
    UNTIL_REACHED = 1
    #: Always active (the default, recommended).
    ALWAYS = 2


class ClosedLoop(ClosedLoopAccess):
    """Closed-loop position control (``tango.closed_loop``; manual chapter 20): the typed
    access of every closed-loop instruction (:class:`ClosedLoopAccess`), and closed loop
    switched on once its preconditions hold.

    A move in closed loop is reported arrived only when the controller says the position
    is in its target window (``twi``) for ``ctrd`` ms; the driver waits for that report as
    for any move.
    """

    _port: DevicePort

    async def enable(self, /, mode: ClosedLoopMode = ClosedLoopMode.ALWAYS,
                     **axes: bool) -> None:
        """Switch closed loop on (``True``) or off (``False``) per axis (``!ctr axis
        mode``), each proven by its read-back: ``enable(x=True)``.

        Before an axis is switched on, its preconditions are read (L11761-11800): the
        encoder enable mask (``?encmask``) and an active encoder (``?enc``); a missing one
        raises :class:`~tango_aio.ClosedLoopPreconditionError` naming it, and nothing is
        written.

        Parameters
        ----------
        mode
            The mode an axis switched on gets.
        **axes
            ``True`` switches an axis on, ``False`` off.

        Raises
        ------
        InvalidCommandError
            An axis the controller does not have, a value that is not a bool, or a mode
            that is not 1 or 2, before anything is written.
        ClosedLoopPreconditionError
            An axis to switch on lacks its encoder mask or an active encoder.
        """
        if mode not in (ClosedLoopMode.UNTIL_REACHED, ClosedLoopMode.ALWAYS):
            raise InvalidCommandError(f"ctr: the mode to switch on is 1 or 2, not {mode!r}",
                                      instruction="ctr", parameter="mode", number=5)
        lines = []
        for axis, on in axes.items():
            if not isinstance(on, bool):
                raise InvalidCommandError(f"ctr: {axis}= must be True or False, got {on!r}",
                                          instruction="ctr", number=5)
            line = build("ctr", int(mode) if on else 0, axis=axis.lower(),
                         context=self._port.context)
            self._port._check_axes(line)
            lines.append((axis.lower(), on, line))
        for axis, on, _ in lines:
            if on:
                await self._check_ready(axis)
        for axis, _, line in lines:
            await self._port.set("ctr", *line.values, axis=axis)

    async def _check_ready(self, axis: str) -> None:
        if int(await self._port.get("encmask", axis=axis)) != 1:
            raise ClosedLoopPreconditionError(
                f"closed loop on {axis.upper()} needs its encoder enable mask: encmask is "
                f"0 (set it with encoders.set_mask({axis}=True); the controller activates "
                "the encoder at the next cal or power-up, manual L10485-10526)",
                axis=axis, missing="encmask")
        if int(await self._port.get("enc", axis=axis)) != 1:
            raise ClosedLoopPreconditionError(
                f"closed loop on {axis.upper()} needs an active encoder: enc is 0 (none "
                "fitted, or not activated yet: run cal, manual L10527-10642)",
                axis=axis, missing="enc")

    async def mode(self) -> dict[str, ClosedLoopMode]:
        """The closed-loop mode of each axis (``?ctr``; 3 and 4 read as 1 and 2).

        Returns
        -------
        dict[str, ClosedLoopMode]
            The mode of each present axis.
        """
        values = await self._port.get("ctr")
        return {axis: ClosedLoopMode((int(v) - 1) % 2 + 1 if int(v) else 0)
                for axis, v in values.items() if axis in AXES}

    async def settle(self) -> tuple[dict[str, float], list[int]]:
        """The settling settings: the target window per axis (``?twi``, L12099-12149, dim
        unit) and the time the position must stay in it, in ms (``?ctrd``,
        L11986-12060).

        Returns
        -------
        tuple[dict[str, float], list[int]]
            The window of each axis, and the delays as the controller prints them.
        """
        windows = await self._port.get("twi")
        delays = await self._port.get("ctrd")
        return ({a: float(v) for a, v in windows.items()},
                [int(v) for v in (delays if isinstance(delays, list | tuple) else [delays])])
