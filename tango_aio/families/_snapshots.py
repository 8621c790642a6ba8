"""The snapshot input: its configuration as one typed object, and the snapshot array
(uploads at wire speed through ``ListTransfer``)."""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass

from ..catalog import Command, build
from ..errors import InvalidCommandError
from ._bulk import Progress, check_resolution, snapshot_spec, validate_rows
from ._generated import SnapshotAccess
from ._reach import DevicePort

__all__ = ["SnapshotConfig", "SnapshotMode", "Snapshots"]


class SnapshotMode(enum.IntEnum):
    """``snsm``: what a snapshot event does (the manual's list, L14745-14861)."""

    #: Capture positions to the list with the joystick key F2.
    CAPTURE_KEY = 0
    #: Move forward through the list with F2 (wrapping).
    STEP_KEY = 1
    #: Move through the list with F1-F4 (back, forward, prehome, home).
    EXTENDED_KEYS = 2
    #: Continuous path through the preloaded list (dissection mode).
    PATH = 3
    #: As 0, the snapshot input instead of F2.
    CAPTURE_INPUT = 4
    #: As 1, the snapshot input instead of F2.
    STEP_INPUT = 5
    #: Moves wait for the snapshot input to start (axes set by ``snsaxis``).
    TRIGGERED_START = 6
    #: Custom HDI mode with prehome, home and auto increment.
    CUSTOM_HDI = 7
    #: A trigger-out event captures the positions and ANIN0.
    CAPTURE_ON_TRIGGER = 8
    #: Relative jumps of ``snsj`` with F2 (F1 back).
    RELATIVE_JUMPS = 9
    #: As 9, the snapshot input instead of F2.
    RELATIVE_JUMPS_INPUT = 10
    #: Z follows an X-Z position list (focus during a scan).
    Z_FOLLOWS_X = 11


@dataclass(frozen=True, slots=True)
class SnapshotConfig:
    """The snapshot input's configuration, read and written as a whole
    (:meth:`Snapshots.read_config`, :meth:`Snapshots.write_config`); every value is
    checked when the object is made, before any byte goes out."""

    #: ``sns``: snapshots enabled (L14637-14673; on at power-on).
    enabled: bool = True
    #: ``snsl``: ``True`` active high, rising edge (L14674-14702).
    active_high: bool = True
    #: ``snsf``: the debounce time in ms, 0..255 (L14703-14744).
    filter_ms: int = 10
    #: ``snsm`` (L14745-14861).
    mode: SnapshotMode = SnapshotMode.CAPTURE_KEY

    def __post_init__(self) -> None:
        for name, value in (("enabled", self.enabled), ("active_high", self.active_high)):
            if not isinstance(value, bool):
                raise InvalidCommandError(f"{name} must be True or False, got {value!r}",
                                          parameter=name, number=5)
        if isinstance(self.filter_ms, bool) or not isinstance(self.filter_ms, int) \
                or not 0 <= self.filter_ms <= 255:
            raise InvalidCommandError(f"snsf: {self.filter_ms!r} is not an integer 0..255",
                                      instruction="snsf", number=5)
        if isinstance(self.mode, bool) or self.mode not in list(SnapshotMode):
            raise InvalidCommandError(f"snsm: {self.mode!r} is not 0..11",
                                      instruction="snsm", number=5)
        object.__setattr__(self, "mode", SnapshotMode(self.mode))

    def lines(self) -> list[Command]:
        """The set lines that write this configuration, ``sns`` last (enabling clears a
        latched key and snsm 6's wait, L14645-14650).

        Returns
        -------
        list[Command]
            The lines, in the order they are written.
        """
        return [build("snsl", int(self.active_high)), build("snsf", self.filter_ms),
                build("snsm", int(self.mode)), build("sns", int(self.enabled))]


class Snapshots(SnapshotAccess):
    """The snapshot input and array (``tango.snapshots``; manual chapter 23): the typed
    access of every snapshot instruction (:class:`SnapshotAccess`), the configuration as a
    whole, and the array."""

    _port: DevicePort

    async def read_config(self) -> SnapshotConfig:
        """Read the whole configuration (``?sns ?snsl ?snsf ?snsm``).

        Returns
        -------
        SnapshotConfig
            The configuration the controller holds.
        """
        return SnapshotConfig(enabled=bool(int(await self._port.get("sns"))),
                              active_high=bool(int(await self._port.get("snsl"))),
                              filter_ms=int(await self._port.get("snsf")),
                              mode=SnapshotMode(int(await self._port.get("snsm"))))

    async def write_config(self, config: SnapshotConfig) -> None:
        """Write a whole configuration, each line proven like any set (its read-back).

        Parameters
        ----------
        config
            The configuration.

        Raises
        ------
        InvalidCommandError
            ``config`` is not a :class:`SnapshotConfig`, before anything is written.
        SettingNotAppliedError
            A read-back shows another value (the lines before it were written).
        """
        if not isinstance(config, SnapshotConfig):
            raise InvalidCommandError(f"a SnapshotConfig is needed, not {config!r}",
                                      number=5)
        for line in config.lines():
            await self._port.set(line.name, *line.values)

    async def count(self) -> int:
        """The number of entries in the snapshot array (``?snsc``).

        Returns
        -------
        int
            The count.
        """
        return int(await self._port.get("snsc"))

    async def upload_positions(self, rows: Sequence[Sequence[float]],
                               progress: Progress | None = None) -> None:
        """Replace the snapshot array with ``rows`` (at most 1024 rows, each with one
        position per axis, X first), like :meth:`Triggers.upload_positions`.

        Parameters
        ----------
        rows
            The snapshot rows: one position per axis, X first.
        progress
            Called as ``progress(done, total)`` at each checkpoint.

        Raises
        ------
        InvalidCommandError
            A row is not valid (the array is left untouched).
        UploadError
            The controller rejected an entry.
        """
        values = validate_rows(rows, len(self._port.axes))
        check_resolution(values, await self._port._resolution(), "snsa")
        await self._port._transfer().replace(
            snapshot_spec(), lambda: self._port.command("!snsa 0"), values, progress)

    async def read_positions(self) -> list[list[float]]:
        """Read every snapshot entry (``?snsc`` of them) with pipelined ``?snsa n`` reads;
        each row holds the positions of the present axes.

        Returns
        -------
        list[list[float]]
            The snapshot rows, in array order.
        """
        return await self._port._transfer().download(snapshot_spec())
