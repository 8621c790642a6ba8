"""The controller's settings as one family: the typed access of the configuration
chapters (7 communication, 8 system, 9 operating modes, 11 general adjustments, 12 limit
switches, 13 calibration), speeds and limits in physical units, and the settings as a
whole: snapshot, diff, restore, save, reload and the two restarts."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from decimal import Decimal
from fractions import Fraction
from typing import Any

from ..catalog import AXES, INSTRUCTIONS, Instruction, Shape
from ..errors import (
    ConnectionLostError,
    ControllerError,
    InvalidCommandError,
    NotSupportedByFirmwareError,
    ProtocolError,
    SettingNotAppliedError,
    SettingsRestoreError,
    SnapshotMismatchError,
    StateError,
)
from ..status import MOVING
from ..units import DEFAULT_USTEPS, Measure, UnitScale, from_controller, plain, to_controller
from ._access import supported
from ._generated import (
    AdjustmentsAccess,
    CalibrationAccess,
    CommunicationAccess,
    LimitSwitchAccess,
    OperatingModesAccess,
    SystemAccess,
)
from ._snapshot import (
    LINK,
    SettingDifference,
    SettingKey,
    SettingsSnapshot,
    differences,
    indices,
    is_indexed,
    label,
    read_per_axis,
    same,
    snapshot_entries,
)

__all__ = ["RESTART_QUIET", "Settings", "convert_from", "convert_to", "reading_unit",
           "unit_scales"]

#: Seconds a restarting controller does not answer: "more than 1 second" (L1837-1838).
RESTART_QUIET = 1.5


async def unit_scales(port: Any) -> dict[str, UnitScale]:
    """The unit conversion of every present axis, read now (four pipelined reads). The
    older edition has no ``usteps`` (its dim 0 counts microsteps, old L863-900, without
    saying how many per revolution): there the 1.71 default (40000, L4106) is taken."""
    try:
        older = port.identity.family == "older"
    except RuntimeError:  # not identified (connect(identify=False)): the 1.71 reading
        older = False
    dims, pitch, gear, usteps = await asyncio.gather(
        port.get("dim"), port.get("pitch"), port.get("gear"),
        _known(DEFAULT_USTEPS) if older else port.get("usteps"))
    return {axis: UnitScale(int(dims[axis]), float(pitch[axis]), float(gear[axis]),
                            int(usteps)) for axis in dims}


async def _known(value: int) -> int:
    return value


def _unit(port: Any, unit: str | None, measure: Measure) -> str | None:
    if unit is not None or port.units is None:
        return unit
    return str(port.units) + measure.suffix


def reading_unit(port: Any, unit: str | None, measure: Measure) -> str | None:
    """The unit a reading is given in (the caller's, else the connection's), checked
    before anything is read.

    Parameters
    ----------
    port
        The family port (its ``units``: the connection's unit of length).
    unit
        The caller's unit; ``None``: the connection's.
    measure
        What is read (position, velocity, acceleration).

    Returns
    -------
    str | None
        The unit; ``None``: the controller's own.

    Raises
    ------
    InvalidCommandError
        ``unit`` is not a unit of ``measure``.
    """
    chosen = _unit(port, unit, measure)
    if chosen is not None:
        try:
            plain(0.0, chosen, measure)
        except ValueError as exc:
            raise InvalidCommandError(f"{exc}", instruction=None, number=5) from exc
    return chosen


async def convert_to(port: Any, values: Mapping[str, Any], unit: str | None,
                     measure: Measure) -> dict[str, Any]:
    """Per-axis ``values`` of ``measure`` in the controller's unit, checked before
    anything is read or written (see :func:`tango_aio.units.to_controller`).

    Parameters
    ----------
    port
        The family port (the unit scales are read through it when a unit is given).
    values
        The value of each axis: numbers, or pint Quantities.
    unit
        Their unit; ``None``: the connection's, else the controller's own.
    measure
        What they are (position, velocity, acceleration).

    Returns
    -------
    dict[str, Any]
        The values by axis, in the controller's unit.

    Raises
    ------
    InvalidCommandError
        A value or the unit is not valid.
    """
    chosen = _unit(port, unit, measure)
    if chosen is None and not any(hasattr(v, "magnitude") for v in values.values()):
        return {axis: float(value) if isinstance(value, Decimal | Fraction) else value
                for axis, value in values.items()}
    try:  # checked before anything is read or written
        given = {axis: plain(value, chosen, measure) for axis, value in values.items()}
    except (TypeError, ValueError) as exc:
        raise InvalidCommandError(f"{exc}", instruction=None, number=5) from exc
    scales = await unit_scales(port)
    return {axis: to_controller(number, of, measure, scales[axis]) if axis in scales
            else number for axis, (number, of) in given.items()}


async def convert_from(port: Any, values: Mapping[str, Any], chosen: str | None,
                       measure: Measure) -> dict[str, Any]:
    """Per-axis readings (numbers or sequences) from the controller's unit to ``chosen``.

    Parameters
    ----------
    port
        The family port (the unit scales are read through it when a unit is chosen).
    values
        The reading of each axis, in the controller's unit.
    chosen
        The unit wanted (from :func:`reading_unit`); ``None``: the controller's own.
    measure
        What they are (position, velocity, acceleration).

    Returns
    -------
    dict[str, Any]
        The readings by axis, in ``chosen``.
    """
    scales = await unit_scales(port) if chosen is not None else {}

    def convert(axis: str, value: float) -> float:
        if chosen is None:
            return float(value)
        return from_controller(float(value), chosen, measure, scales[axis])

    return {axis: tuple(convert(axis, v) for v in value)
            if isinstance(value, list | tuple) else convert(axis, value)
            for axis, value in values.items()}


def _frozen(value: Any) -> Any:
    """A reply value as a snapshot holds it: sequences as tuples, enums as numbers."""
    if isinstance(value, list | tuple):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return int(value)
    return value


def _args(value: Any) -> tuple[Any, ...]:
    return tuple(value) if isinstance(value, list | tuple) else (value,)


class Settings(CommunicationAccess, SystemAccess, OperatingModesAccess, AdjustmentsAccess,
               LimitSwitchAccess, CalibrationAccess):
    """Every setting of the controller by name (``tango.settings.vel()``,
    ``tango.settings.set_vel(x=5)``), in physical units, and as a whole."""

    __slots__ = ()

    # -- speeds and limits in physical units ----------------------------------------------

    async def unit_scales(self) -> dict[str, UnitScale]:
        """The unit conversion of every present axis: its ``dim``, ``pitch``, ``gear`` and
        the global ``usteps``, read now (four pipelined reads).

        Returns
        -------
        dict[str, UnitScale]
            The unit scale of each present axis.
        """
        return await unit_scales(self._port)

    async def velocity(self, *, unit: str | None = None) -> dict[str, float]:
        """The ``vel`` of every present axis: rev/s (mm/s in dim 9), or in ``unit``
        (``"mm/s"``; default: the connection's ``units`` per second).

        Parameters
        ----------
        unit
            The unit of the speeds (``"mm/s"``); ``None``: the connection's ``units`` per
            second, else rev/s (mm/s in dim 9).

        Returns
        -------
        dict[str, float]
            The velocity of each present axis.

        Raises
        ------
        InvalidCommandError
            ``unit`` is not a unit of velocity.
        """
        return await self._read_in("vel", unit, Measure.VELOCITY)

    async def set_velocity(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Set ``vel`` per axis (``set_velocity(x=5, unit="mm/s")``), see :meth:`velocity`.

        Parameters
        ----------
        unit
            The unit of the speeds, as for :meth:`velocity`.
        **axes
            The velocity of each axis.
        """
        await self._port.set("vel", **await convert_to(self._port, axes, unit,
                                                        Measure.VELOCITY))

    async def acceleration(self, *, unit: str | None = None) -> dict[str, float]:
        """The ``accel`` of every present axis: m/s², or in ``unit`` (``"mm/s2"``;
        default: the connection's ``units`` per second squared).

        Parameters
        ----------
        unit
            The unit of the accelerations (``"mm/s2"``); ``None``: the connection's
            ``units`` per second squared, else m/s².

        Returns
        -------
        dict[str, float]
            The acceleration of each present axis.

        Raises
        ------
        InvalidCommandError
            ``unit`` is not a unit of acceleration.
        """
        return await self._read_in("accel", unit, Measure.ACCELERATION)

    async def set_acceleration(self, /, *, unit: str | None = None, **axes: float) -> None:
        """Set ``accel`` per axis, see :meth:`acceleration`.

        Parameters
        ----------
        unit
            The unit of the accelerations, as for :meth:`acceleration`.
        **axes
            The acceleration of each axis.
        """
        await self._port.set("accel", **await convert_to(self._port, axes, unit,
                                                          Measure.ACCELERATION))

    async def limits(self, *, unit: str | None = None) -> dict[str, tuple[float, float]]:
        """The software limits (``lim``) of every present axis as ``(lower, upper)``, in
        ``unit`` (default: the connection's ``units``, else the dim unit).

        Parameters
        ----------
        unit
            The unit of the limits (``"mm"``, ``"um"``...).

        Returns
        -------
        dict[str, tuple[float, float]]
            The ``(lower, upper)`` limits of each present axis.

        Raises
        ------
        InvalidCommandError
            ``unit`` is not a unit of length.
        """
        return await self._read_in("lim", unit, Measure.POSITION)

    async def _read_in(self, name: str, unit: str | None, measure: Measure
                       ) -> dict[str, Any]:
        """Read the per-axis ``name`` and convert it to ``unit`` (checked first)."""
        chosen = reading_unit(self._port, unit, measure)
        return await convert_from(self._port, await self._port.get(name), chosen, measure)

    async def set_limits(self, /, *, unit: str | None = None,
                         **axes: tuple[float, float]) -> None:
        """Set the software limits per axis (``set_limits(x=(0, 100), unit="mm")``).

        Parameters
        ----------
        unit
            The unit of the values (``"mm"``, ``"um"``...); ``None``: the connection's
            ``units``, else the controller's dim unit.
        **axes
            The ``(lower, upper)`` limits of each axis.
        """
        lower = await convert_to(self._port, {a: p[0] for a, p in axes.items()}, unit,
                                 Measure.POSITION)
        upper = await convert_to(self._port, {a: p[1] for a, p in axes.items()}, unit,
                                 Measure.POSITION)
        await self._port.set("lim", axis=None, check=True,
                             **{axis: [lower[axis], upper[axis]] for axis in axes})

    # -- the settings as a whole ----------------------------------------------------------

    async def snapshot(self) -> SettingsSnapshot:
        """Read every readable setting of this unit (global, per axis and per index) with
        its identity and firmware.

        Returns
        -------
        SettingsSnapshot
            The settings; those the unit does not answer are listed in ``absent``.
        """
        identity = self._port.identity
        values, absent = await self._read(snapshot_entries())
        serial: str | None
        try:
            serial = await self._serial()
        except ControllerError:
            serial = None
        return SettingsSnapshot(identity.model, identity.firmware, serial,
                                "".join(AXES[: self._port.context.axes]),
                                SettingsSnapshot.now(), values, absent)

    async def _serial(self) -> str:
        with supported(self._port, "readsn"):
            return str(await self._port.get("readsn"))

    async def diff(self, snapshot: SettingsSnapshot) -> list[SettingDifference]:
        """The settings whose value on the unit differs from ``snapshot``'s.

        Parameters
        ----------
        snapshot
            A snapshot (of this unit or another of its model).

        Returns
        -------
        list[SettingDifference]
            Each differing setting (setting, axis, index, the snapshot's and the unit's
            value), in restore order; a setting the unit lacks has the unit value ``None``.
        """
        names = {key[0] for key in snapshot.values}
        now, _ = await self._read([INSTRUCTIONS[name] for name in names])
        return differences(snapshot.values, now)

    async def restore(self, snapshot: SettingsSnapshot) -> list[SettingDifference]:
        """Write every setting that differs from ``snapshot``, in an order the manual
        allows (the units before the values, the limits and the write protection last;
        :mod:`tango_aio.families`), and read each back.

        The link's own settings (``baud``, ``cts``, ``ipreter``, ``configdisplay``) are
        not written: changing them would cut this connection. :meth:`diff` still shows
        them.

        Parameters
        ----------
        snapshot
            A snapshot of a controller of this model with the same axes.

        Returns
        -------
        list[SettingDifference]
            What was written.

        Raises
        ------
        SnapshotMismatchError
            The snapshot is of another model, or names an axis or a setting this unit
            lacks; nothing was written.
        SettingsRestoreError
            Settings did not take (each named, with why); the others were written.
        """
        self.check(snapshot)
        names = {key[0] for key in snapshot.values}
        now, _ = await self._read([INSTRUCTIONS[name] for name in names])
        lacking = sorted(label(key) for key in snapshot.values if key not in now)
        if lacking:
            raise SnapshotMismatchError(
                f"this controller lacks settings of the snapshot ({', '.join(lacking)}): "
                "nothing was written")
        todo = [d for d in differences(snapshot.values, now) if d.setting not in LINK]
        failed: dict[str, str] = {}
        for difference in todo:
            try:
                await self._write(difference.key, difference.snapshot)
            except ConnectionLostError as error:
                left = [label(d.key) for d in todo[todo.index(difference):]]
                raise SettingsRestoreError({name: f"not written: {error}" for name in left}
                                           ) from error
            except (ControllerError, SettingNotAppliedError, ProtocolError,
                    InvalidCommandError) as error:
                failed[label(difference.key)] = str(error)
        written = [d for d in todo if label(d.key) not in failed]
        after, _ = await self._read([INSTRUCTIONS[n] for n in {d.setting for d in written}])
        for difference in written:
            held = after.get(difference.key)
            if not same(difference.snapshot, held):
                failed[label(difference.key)] = (
                    f"reads {held!r} after the write, the snapshot holds "
                    f"{difference.snapshot!r}")
        if failed:
            raise SettingsRestoreError(failed)
        return written

    def check(self, snapshot: SettingsSnapshot) -> None:
        """Refuse a snapshot of another model, or with axes this controller lacks,
        without reading or writing anything.

        Parameters
        ----------
        snapshot
            The snapshot.

        Raises
        ------
        SnapshotMismatchError
            It does not fit this controller.
        """
        identity = self._port.identity
        if snapshot.model != identity.model:
            raise SnapshotMismatchError(
                f"the snapshot is of a {snapshot.model}, this controller is a "
                f"{identity.model}: nothing was written")
        present = AXES[: self._port.context.axes]
        extra = sorted({key[1] for key in snapshot.values if key[1] and key[1] not in present})
        if extra:
            raise SnapshotMismatchError(
                f"the snapshot has axes this controller lacks ({', '.join(extra).upper()}): "
                "nothing was written")

    async def _read(self, entries: list[Instruction]
                    ) -> tuple[dict[SettingKey, Any], dict[str, str]]:
        """The values of ``entries`` on the unit, and those it does not answer (why)."""
        values: dict[SettingKey, Any] = {}
        absent: dict[str, str] = {}
        present = AXES[: self._port.context.axes]
        for entry in entries:
            name = entry.name
            try:
                with supported(self._port, name):
                    if is_indexed(entry):
                        for index in indices(entry):
                            values[(name, None, index)] = _frozen(
                                await self._port.get(name, index))
                    elif read_per_axis(entry):
                        for axis in present:
                            values[(name, axis, None)] = _frozen(
                                await self._port.get(name, axis=axis))
                    elif entry.reply in (Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT):
                        by_axis = await self._port.get(name)
                        for axis, value in by_axis.items():
                            values[(name, axis, None)] = _frozen(value)
                    else:
                        values[(name, None, None)] = _frozen(await self._port.get(name))
            except (NotSupportedByFirmwareError, StateError) as error:
                absent[name] = str(error)
        return values, absent

    async def _write(self, key: SettingKey, value: Any) -> None:
        name, axis, index = key
        with supported(self._port, name):
            if index is not None:
                await self._port.set(name, index, *_args(value))
            else:
                await self._port.set(name, *_args(value), axis=axis)

    # -- saved settings and restarts ------------------------------------------------------

    async def save(self) -> None:
        """Store the settings in the controller's nonvolatile memory (``!save``); they
        are applied at every power-on and reset (manual L1723-1767). Returns once the
        controller has answered ``OK...``, when the memory is written (L1738).

        Raises
        ------
        StateError
            An axis moves: the manual asks to save only with the axes idle (L1744-1751);
            nothing was written.
        ControllerError
            The controller refused the save.
        """
        letters = await self._port.get("statusaxis")
        moving = sorted(a for a, s in letters.items() if s == MOVING)
        if moving:
            error = StateError(None, "!save")
            error.args = (f"axes {', '.join(moving).upper()} move: save only with the axes "
                          "idle (manual L1744-1751); nothing was written",)
            raise error
        await self._port.command("!save")

    async def reload(self) -> None:
        """Reload the saved settings (``!restore``), as at power-on but without a
        restart (L1791-1800); then read the driver's cached settings again.

        Raises
        ------
        ControllerError
            The controller refused it.
        """
        await self._port.command("!restore")
        await self._port.refresh_settings()

    async def factory_reset(self, *, confirm: bool, quiet: float = RESTART_QUIET) -> None:
        """Delete the saved settings and restart with the firmware's defaults
        (``!restore -1``). The manual warns that the defaults may not suit the hardware
        and can damage it (overcurrent, wrong pitch, limit switch types, L1803-1808):
        check and set them before moving. Returns once the controller answers again, in
        the driver's autostatus mode, with the cached settings read again.

        Parameters
        ----------
        confirm
            Must be ``True``: the explicit confirmation that the defaults may damage the
            hardware.
        quiet
            Seconds the controller takes to restart, before the first poll.

        Raises
        ------
        ValueError
            ``confirm`` is not ``True`` (nothing was written).
        """
        _confirmed(confirm, "factory_reset")
        await self._port.command("!restore -1", check=False)
        await self._port.wait_restarted(quiet=quiet)

    async def reset(self, *, confirm: bool, quiet: float = RESTART_QUIET) -> None:
        """Restart the controller (``!reset``), like a power cycle: positions and unsaved
        settings are lost (L1832-1860). Returns once it answers again (it polls as the
        manual says, L1845-1860), in the driver's autostatus mode, with the cached
        settings read again.

        Parameters
        ----------
        confirm
            Must be ``True``: the explicit confirmation that a restart is meant.
        quiet
            Seconds the controller takes to restart, before the first poll.

        Raises
        ------
        ValueError
            ``confirm`` is not ``True`` (nothing was written).
        """
        _confirmed(confirm, "reset")
        await self._port.command("!reset", check=False)
        await self._port.wait_restarted(quiet=quiet)


def _confirmed(confirm: object, what: str) -> None:
    if confirm is not True:
        raise InvalidCommandError(
            f"{what}() restarts the controller and can damage hardware (manual L1803-1808, "
            f"L1832-1860): pass confirm=True to mean it", instruction=None, number=5)
