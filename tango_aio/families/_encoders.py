"""Encoders: their enable mask, whether each is active, the position source of ``?pos``,
and the difference between motor and encoder position."""

from __future__ import annotations

from typing import Any, ClassVar

from ._generated import EncoderAccess, MREncoderAccess
from ._reach import DevicePort

__all__ = ["Encoders"]


def _by_axis(values: Any) -> dict[str, int]:
    return {axis: int(value) for axis, value in values.items()}


class Encoders(EncoderAccess, MREncoderAccess):
    """The stage's encoders (``tango.encoders``; manual chapters 18 and 19): the typed
    access of every encoder and MR encoder instruction (:class:`EncoderAccess`,
    :class:`MREncoderAccess`), and the mask, activity and position error by axis."""

    #: The instructions of both chapters and the methods that reach them.
    ROUTES: ClassVar[dict[str, tuple[str, ...]]] = {**EncoderAccess.ROUTES,
                                                    **MREncoderAccess.ROUTES}

    _port: DevicePort

    async def mask(self) -> dict[str, bool]:
        """The encoder enable mask per axis (``?encmask``, L10485-10526): the controller
        activates an encoder whose bit is set at the next ``cal`` or power-up.

        Returns
        -------
        dict[str, bool]
            ``True`` where the mask is set.
        """
        return {a: v == 1 for a, v in _by_axis(await self._port.get("encmask")).items()}

    async def set_mask(self, /, **axes: bool) -> None:
        """Set or clear the enable mask of some axes (``!encmask``), proven by its
        read-back.

        Parameters
        ----------
        **axes
            ``True`` sets an axis' bit (``x=True``).
        """
        values: dict[str, Any] = {a: int(bool(v)) for a, v in axes.items()}
        await self._port.set("encmask", **values)

    async def active(self) -> dict[str, bool]:
        """Whether each axis' encoder is active (``?enc``, L10527-10642): activated by the
        controller (a ``cal``, or power-up in calmode 1 or 2) where ``encmask`` is set.

        Returns
        -------
        dict[str, bool]
            ``True`` where the encoder is active.
        """
        return {a: v == 1 for a, v in _by_axis(await self._port.get("enc")).items()}

    async def set_position_source(self, axis: str, encoder: bool) -> None:
        """Make ``?pos`` (and so ``position()``) read the encoder (``True``, where it is
        active) or the motor position of ``axis`` (``!encpos axis``, L11193-11247; not
        kept by ``save``).

        Parameters
        ----------
        axis
            The axis.
        encoder
            ``True``: the encoder position.
        """
        await self._port.command(f"!encpos {axis.lower()} {int(bool(encoder))}")

    async def position_error(self) -> dict[str, float]:
        """The difference between motor and encoder position per axis, in the dim unit
        (``?ctrdiff``, L12396-12481).

        Returns
        -------
        dict[str, float]
            The difference of each present axis.
        """
        return {a: float(v) for a, v in (await self._port.get("ctrdiff")).items()}
