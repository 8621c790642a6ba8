"""The controller's identity and condition in one record: serial numbers, versions,
temperature, uptime, axes and maximum current (manual chapter 6)."""

from __future__ import annotations

import dataclasses
from collections.abc import Awaitable
from dataclasses import dataclass
from typing import Any, TypeVar

from ..errors import ControllerError
from ._generated import ControllerInfoAccess

__all__ = ["ControllerInfo", "Info"]

T = TypeVar("T")

_NO_ETS = "---------"


@dataclass(frozen=True)
class ControllerInfo:
    """What a controller says about itself; a field the unit does not answer is ``None``.

    Parameters
    ----------
    model
        The model from ``?version`` (``TANGO-DT``).
    firmware
        The firmware version from ``?version`` (``1.71``).
    serial_number
        ``?readsn``: ``YYWWTNXXX`` (manual L1236-1268).
    version
        ``?ver``: ``Vers:LSnm.xx.xxx`` (L1269-1303).
    internal_version
        ``?iver`` (L1304-1329).
    uptime
        ``?uptime``: seconds since power-on or reset (L1330-1350).
    temperature
        ``?temp``: the case temperature in °C (L1351-1371).
    axes
        ``?maxaxis``: the factory configured axes (L1372-1392), as printed (``"3"``, or
        ``"z"`` for a single-axis Z controller).
    max_current
        ``?maxcur``: the largest motor current in A, per axis as printed (L1393-1432).
    ets_present
        ``?etspresent``: an ETS identification circuit found at address 0-3 (L1433-1468).
    stage_serial_numbers
        ``?stagesn``: the serial number at each ETS address that has one (L1469-1562).
    """

    model: str | None = None
    firmware: str | None = None
    serial_number: str | None = None
    version: str | None = None
    internal_version: str | None = None
    uptime: int | None = None
    temperature: float | None = None
    axes: str | None = None
    max_current: tuple[float, ...] | None = None
    ets_present: tuple[bool, ...] | None = None
    stage_serial_numbers: dict[int, str] | None = None

    def as_dict(self) -> dict[str, Any]:
        """The fields as plain JSON values (``None`` kept).

        Returns
        -------
        dict[str, Any]
            Field name to value.
        """
        out = dataclasses.asdict(self)
        for name in ("max_current", "ets_present"):
            if out[name] is not None:
                out[name] = list(out[name])
        if self.stage_serial_numbers is not None:
            out["stage_serial_numbers"] = {str(k): v for k, v in
                                           self.stage_serial_numbers.items()}
        return out


async def _or_none(read: Awaitable[T]) -> T | None:
    """The value, or ``None`` where the unit does not know or cannot answer the read."""
    try:
        return await read
    except ControllerError:  # error 4 (NotSupportedByFirmwareError) and its kin
        return None


class Info(ControllerInfoAccess):
    """Controller information (manual chapter 6): the typed reads and one record of all."""

    __slots__ = ()

    async def read(self) -> ControllerInfo:
        """Read every information instruction this unit answers.

        Returns
        -------
        ControllerInfo
            The record; a field the unit lacks is ``None``.
        """
        version = await _or_none(self.version())
        ets_text = await _or_none(self.etspresent())
        ets = tuple(c == "1" for c in ets_text) if ets_text else None
        serials: dict[int, str] | None = None
        if ets is not None:
            serials = {}
            for address, present in enumerate(ets):
                if present:
                    text = await _or_none(self.stagesn(address))
                    if text and text.strip() != _NO_ETS:
                        serials[address] = text.strip()
        maxcur = await _or_none(self.maxcur())
        return ControllerInfo(
            model=getattr(version, "model", None),
            firmware=getattr(version, "firmware", None),
            serial_number=await _or_none(self.readsn()),
            version=await _or_none(self.ver()),
            internal_version=await _or_none(self.iver()),
            uptime=await _or_none(self.uptime()),
            temperature=await _or_none(self.temp()),
            axes=await _or_none(self.maxaxis()),
            max_current=tuple(maxcur) if maxcur is not None else None,
            ets_present=ets,
            stage_serial_numbers=serials,
        )
