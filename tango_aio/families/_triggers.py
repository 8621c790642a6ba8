"""The trigger output: its configuration as one typed object, its counter, pulses forced by
hand, and the trigger position list (uploads at wire speed through ``ListTransfer``)."""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from ..catalog import AXES, Command, build, wire_number
from ..errors import InvalidCommandError
from ._bulk import (
    Column,
    Progress,
    check_axis,
    check_resolution,
    trigger_spec,
    validate_trigger_positions,
)
from ._generated import TriggerAccess
from ._reach import DevicePort

__all__ = ["MAX_TRIGGER_POSITION", "TriggerConfig", "TriggerMode", "TriggerOutput", "Triggers"]

#: The largest trigger position magnitude :meth:`Triggers.set_range` accepts, in any
#: ``dim`` unit: far beyond any stage's travel.
MAX_TRIGGER_POSITION = 1e9

E = TypeVar("E", bound=enum.IntEnum)


class TriggerMode(enum.IntEnum):
    """``trigm``: how and when pulses are generated (the manual's table, L12595-12836).

    Modes 0-11 pulse every ``distance`` from where ``!trig 1`` ran; 6-11 shifted by half a
    distance; 100/101 periodically at ``frequency``; 102/103 by hand (:meth:`Triggers.fire`);
    104/105 when a move of the trigger axis has completed. ``LIST_RISING`` and
    ``LIST_FALLING`` (20, 21) are set by the controller for a position list and read only.
    """

    FORWARD = 0
    BIDIRECTIONAL = 1
    BACKWARD = 2
    FORWARD_LOW = 3
    BIDIRECTIONAL_LOW = 4
    BACKWARD_LOW = 5
    FORWARD_SHIFTED = 6
    BIDIRECTIONAL_SHIFTED = 7
    BACKWARD_SHIFTED = 8
    FORWARD_SHIFTED_LOW = 9
    BIDIRECTIONAL_SHIFTED_LOW = 10
    BACKWARD_SHIFTED_LOW = 11
    LIST_RISING = 20
    LIST_FALLING = 21
    PERIODIC = 100
    PERIODIC_LOW = 101
    MANUAL = 102
    MANUAL_LOW = 103
    ARRIVAL = 104
    ARRIVAL_LOW = 105

    @property
    def active_high(self) -> bool:
        """Whether the pulse is active high (the table's "Trigger Signal" column; in the
        list modes ``trigl`` decides, L14177-14212, and this reads ``True``)."""
        if self in (TriggerMode.LIST_RISING, TriggerMode.LIST_FALLING):
            return True
        return self % 2 == 0 if self >= 100 else self % 6 < 3


class TriggerOutput(enum.IntEnum):
    """``trigo``: which outputs carry the pulse, and the secondary output's extended
    function (the manual's table, L12860-12949). Bit 0: TRIGGER_OUT; bit 1: TAKT_OUT."""

    NONE = 0
    PRIMARY = 1
    SECONDARY = 2
    BOTH = 3
    WIDTH_NONE = 4
    WIDTH_PRIMARY = 5
    WIDTH_SECONDARY = 6
    WIDTH_BOTH = 7
    DELAY_NONE = 8
    DELAY_PRIMARY = 9
    DELAY_SECONDARY = 10
    DELAY_BOTH = 11
    FREQUENCY_NONE = 12
    FREQUENCY_PRIMARY = 13
    FREQUENCY_SECONDARY = 14
    FREQUENCY_BOTH = 15


@dataclass(frozen=True, slots=True)
class TriggerConfig:
    """The trigger output's configuration, read and written as a whole
    (:meth:`Triggers.read_config`, :meth:`Triggers.write_config`).

    A field ``None`` is not written (and reads ``None`` on a firmware without its
    instruction: ``trigo``, ``trigcomp``, ``trigenc``, ``trigl`` and the secondary
    output's ``trigbwidth``, ``trigbdelay`` and ``trigbf`` are not in the older edition of
    the manual). The secondary output's fields are ``None`` unless given, as not every
    controller has that output (L12925-12934). Every value is checked when the object is
    made, before any byte goes out.
    """

    #: ``trigm`` (L12595-12836).
    mode: TriggerMode = TriggerMode.FORWARD
    #: ``triga``: the axis positions count on (L12837-12859).
    axis: str = "x"
    #: ``trigs``: the pulse width in µs, 0..2500000; the controller keeps the nearest
    #: multiple of 40 (L12950-12970).
    width_us: int = 0
    #: ``trigd``: the distance between pulses in the axis' dim unit, above 0 up to
    #: 5000000 (L13027-13056).
    distance: float = 1.0
    #: ``trigf``: the frequency of the periodic modes and of forced pulses in Hz,
    #: 0.01..25000 (L13223-13278).
    frequency_hz: float = 1000.0
    #: ``trigo`` (L12860-12949).
    output: TriggerOutput | None = TriggerOutput.PRIMARY
    #: ``trigcomp``: the compensation of the pulse position in µs, -10000..10000
    #: (L13057-13167).
    compensation_us: int | None = 0
    #: ``trigenc``: count on the encoder (``True``) or the motor position (L13168-13222).
    encoder: bool | None = False
    #: ``trigl``: the pulse polarity of the list modes, ``True`` active high
    #: (L14177-14212).
    list_active_high: bool | None = True
    #: ``trigbwidth``: the secondary output's precise pulse width in µs, 0..32500000, in
    #: force with ``output`` 4-7 (L13318-13350, L14334-14345).
    secondary_width_us: float | None = None
    #: ``trigbdelay``: the secondary output's precise delay after the primary's edge in
    #: µs, 0..32500000, in force with ``output`` 8-11 (L13279-13316, L14377-14394).
    secondary_delay_us: float | None = None
    #: ``trigbf``: the secondary output's own frequency in Hz, 0.01..66000000, in force
    #: with ``output`` 12-15 (L13353-13386, L14444-14476).
    secondary_frequency_hz: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", _member(TriggerMode, self.mode, "trigm"))
        if self.output is not None:
            object.__setattr__(self, "output", _member(TriggerOutput, self.output, "trigo"))
        check_axis(self.axis)
        for name, value in (("encoder", self.encoder),
                            ("list_active_high", self.list_active_high)):
            if value is not None and not isinstance(value, bool):
                raise InvalidCommandError(f"{name} must be True, False or None, got {value!r}",
                                          parameter=name, number=5)
        _checked("trigs", self.width_us, 0, 2_500_000, integer=True)
        _checked("trigd", self.distance, 0.0, 5_000_000.0, above=True)
        _checked("trigf", self.frequency_hz, 0.01, 25_000.0)
        if self.compensation_us is not None:
            _checked("trigcomp", self.compensation_us, -10_000, 10_000, integer=True)
        for name, precise, low, high in (
                ("trigbwidth", self.secondary_width_us, 0.0, 32_500_000.0),
                ("trigbdelay", self.secondary_delay_us, 0.0, 32_500_000.0),
                ("trigbf", self.secondary_frequency_hz, 0.01, 66_000_000.0)):
            if precise is not None:
                _checked(name, precise, low, high)

    def lines(self) -> list[Command]:
        """The set lines that write this configuration, the axis first (``trigd``'s unit
        is that axis' dim, L13037-13040).

        Returns
        -------
        list[Command]
            The lines, in the order they are written.

        Raises
        ------
        InvalidCommandError
            The mode is a list mode, which only the controller sets.
        """
        if self.mode in (TriggerMode.LIST_RISING, TriggerMode.LIST_FALLING):
            raise InvalidCommandError(
                f"trigm: {int(self.mode)} is set by the controller for a position list "
                "(L12595-12836); upload the list instead", instruction="trigm", number=5)
        values: list[tuple[str, Any]] = [
            ("triga", self.axis.lower()), ("trigm", int(self.mode)),
            ("trigo", _int_or_none(self.output)), ("trigbwidth", self.secondary_width_us),
            ("trigbdelay", self.secondary_delay_us), ("trigbf", self.secondary_frequency_hz),
            ("trigs", self.width_us),
            ("trigd", self.distance), ("trigf", self.frequency_hz),
            ("trigcomp", self.compensation_us), ("trigenc", _int_or_none(self.encoder)),
            ("trigl", _int_or_none(self.list_active_high))]
        return [build(name, value) for name, value in values if value is not None]


def _member(kind: type[E], value: object, name: str) -> E:
    if isinstance(value, int) and not isinstance(value, bool):
        try:
            return kind(value)
        except ValueError:
            pass
    raise InvalidCommandError(f"{name}: {value!r} is not one of the manual's values "
                              f"({', '.join(str(int(m)) for m in kind)})", instruction=name,
                              number=5)


def _int_or_none(value: bool | int | None) -> int | None:
    return None if value is None else int(value)


def _checked(name: str, value: object, low: float, high: float, *, integer: bool = False,
             above: bool = False) -> None:
    try:
        number = float(wire_number(value))
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    whole = not integer or (isinstance(value, int) and not isinstance(value, bool))
    inside = low < number <= high if above else low <= number <= high
    if not (whole and inside):
        raise InvalidCommandError(
            f"{name}: {value!r} is not {'an integer ' if integer else ''}"
            f"{'above ' if above else ''}{low:g}{'' if above else '..'}"
            f"{' up to ' if above else ''}{high:g}", instruction=name, number=5)


class Triggers(TriggerAccess):
    """The trigger output (``tango.triggers``; manual chapter 21): the typed access of
    every trigger instruction (:class:`TriggerAccess`), the configuration as a whole, and
    the position list."""

    _port: DevicePort

    # -- the configuration as a whole ---------------------------------------------------

    async def read_config(self) -> TriggerConfig:
        """Read the whole configuration (``?triga ?trigm ?trigo ?trigs ?trigd ?trigf
        ?trigcomp ?trigenc ?trigl ?trigbwidth ?trigbdelay ?trigbf``); a field whose
        instruction this firmware does not know reads ``None``.

        Returns
        -------
        TriggerConfig
            The configuration the controller holds.
        """
        optional = self._port._read_if_known
        output, compensation = await optional("trigo"), await optional("trigcomp")
        encoder, level = await optional("trigenc"), await optional("trigl")
        precise = [await optional(name) for name in ("trigbwidth", "trigbdelay", "trigbf")]
        width_b, delay_b, frequency_b = (None if v is None else float(v) for v in precise)
        width = await self._port.get("trigs")
        return TriggerConfig(
            mode=TriggerMode(int(await self._port.get("trigm"))),
            axis=str(await self._port.get("triga")).strip().lower(),
            width_us=int(width[0] if isinstance(width, list | tuple) else width),
            distance=float(await self._port.get("trigd")),
            frequency_hz=float(await self._port.get("trigf")),
            output=None if output is None else TriggerOutput(int(output)),
            compensation_us=None if compensation is None else int(compensation),
            encoder=None if encoder is None else bool(int(encoder)),
            list_active_high=None if level is None else bool(int(level)),
            secondary_width_us=width_b, secondary_delay_us=delay_b,
            secondary_frequency_hz=frequency_b)

    async def write_config(self, config: TriggerConfig) -> None:
        """Write a whole configuration, each line proven like any set (its read-back);
        the axis first. Every line is built and checked before the first goes out (the
        trigger axis one the controller has). The trigger stays switched as it was
        (:meth:`set_enabled`).

        Parameters
        ----------
        config
            The configuration.

        Raises
        ------
        InvalidCommandError
            A value is not valid, before anything is written.
        SettingNotAppliedError
            A read-back shows another value (the lines before it were written).
        """
        if not isinstance(config, TriggerConfig):
            raise InvalidCommandError(f"a TriggerConfig is needed, not {config!r}",
                                      number=5)
        lines = config.lines()
        if AXES.index(config.axis.lower()) >= len(self._port.axes):
            raise InvalidCommandError(f"triga: this controller has no "
                                      f"{config.axis.upper()} axis", instruction="triga",
                                      parameter="axis", number=1)
        for line in lines:
            await self._port.set(line.name, *line.values)

    # -- switching, counting, forcing ---------------------------------------------------

    async def enabled(self) -> bool:
        """Whether the trigger output is switched on (``?trig``).

        Returns
        -------
        bool
            ``True`` if it is on.
        """
        return bool(await self._port.get("trig"))

    async def set_enabled(self, enabled: bool) -> None:
        """Switch the trigger output on or off (``!trig 1`` / ``!trig 0``); where
        ``!trig 1`` runs is the start of the distance modes (L12565-12594), so configure
        first.

        Parameters
        ----------
        enabled
            ``True`` switches the output on, ``False`` off.

        Raises
        ------
        TypeError
            ``enabled`` is not a bool.
        """
        if not isinstance(enabled, bool):
            raise TypeError(f"enabled must be True or False, got {enabled!r}")
        await self._port.set("trig", int(enabled))

    async def count(self) -> int:
        """The number of trigger events generated so far (``?trigcount``).

        Returns
        -------
        int
            The trigger counter.
        """
        return int(await self._port.get("trigcount"))

    async def set_count(self, count: int = 0) -> None:
        """Set (usually reset) the trigger event counter (``!trigcount``).

        Parameters
        ----------
        count
            The new value of the counter.
        """
        await self._port.set("trigcount", count)

    async def fire(self, pulses: int = 1) -> None:
        """Force ``pulses`` pulses now (``!trigger n``, 1..127, spaced by the frequency;
        the manual modes 102 and 103 only, L13414-13495).

        Parameters
        ----------
        pulses
            How many.

        Raises
        ------
        InvalidCommandError
            ``pulses`` is not 1..127, before anything is written.
        """
        _checked("trigger", pulses, 1, 127, integer=True)
        await self._port.command(build("trigger", pulses).line)

    # -- the position list ---------------------------------------------------------------

    async def upload_positions(self, positions: Sequence[float], axis: str = "x",
                               progress: Progress | None = None) -> None:
        """Replace the trigger position list of ``axis`` with ``positions`` at wire speed.

        Every entry is validated first (at most 10000 finite, strictly monotonic values the
        catalog accepts, none non-zero below the position resolution, which would read
        back as 0.0); only then is the list cleared with ``!trigp axis 0`` and every entry
        appended through the write-credit limiter, the count checked along the way. A bad
        entry raises :class:`~tango_aio.errors.InvalidCommandError` and leaves the list
        untouched. Uploads (and list reads) of one controller run one at a time.
        ``progress(done, total)`` is called at each checkpoint. An entry the controller
        rejects raises :class:`~tango_aio.UploadError` with its index and error code.
        Cancelling stops sending and leaves the driver in sync (the list then holds what
        was sent so far).

        Parameters
        ----------
        positions
            The trigger positions, in the controller's dim unit.
        axis
            The axis whose list is replaced.
        progress
            Called as ``progress(done, total)`` at each checkpoint.

        Raises
        ------
        InvalidCommandError
            An entry or the axis is not valid (the list is left untouched).
        UploadError
            The controller rejected an entry.
        """
        letter = check_axis(axis)
        values = validate_trigger_positions(positions)
        self._port._check_axes(build("trigp", 0, axis=letter))  # before any byte
        resolution = await self._port._resolution()
        rows = Column(values)
        check_resolution(rows, [resolution[AXES.index(letter)]], "trigp")
        await self._port._transfer().replace(
            trigger_spec(), lambda: self._port.command(f"!trigp {letter} 0"), rows, progress)

    async def read_positions(self) -> list[float]:
        """Read the whole trigger position list with pipelined ``?trigp n`` reads.

        Returns
        -------
        list[float]
            The trigger positions, in list order.
        """
        rows = await self._port._transfer().download(trigger_spec())
        return [row[0] for row in rows]

    async def set_range(self, start: float, end: float, count: int,
                        axis: str | None = None) -> None:
        """Set equidistant trigger positions (``!trigr [axis] start end count``); ``count``
        includes both ends. ``start`` above ``end`` triggers while the axis travels in the
        negative direction (L13529-13532), so both orders are accepted; a position whose
        magnitude exceeds :data:`MAX_TRIGGER_POSITION` (no stage travels that far in any
        ``dim`` unit) or a non-zero one below the position resolution (it would be stored
        as 0.0) is refused before anything is written, as is an axis the controller does
        not have.

        Parameters
        ----------
        start
            The first trigger position.
        end
            The last trigger position.
        count
            The number of positions, both ends included.
        axis
            The axis (``"x"``...); ``None``: the axis set before (``!triga`` or an earlier
            ``!trigr``, L13686-13688).

        Raises
        ------
        InvalidCommandError
            A value or the axis is not valid, before anything is written.
        ControllerError
            The controller refused the line.
        """
        command = build("trigr", start, end, count, axis=axis, context=self._port.context)
        self._port._check_axes(command)
        for value in (start, end):
            if abs(float(value)) > MAX_TRIGGER_POSITION:
                raise InvalidCommandError(
                    f"trigr: position {value!r} is beyond any stage's travel (at most "
                    f"{MAX_TRIGGER_POSITION:g} in the dim unit)", instruction="trigr",
                    parameter="position", number=5)
        quantum = min(await self._port._resolution())
        check_resolution([[float(start), float(end)]], [quantum], "trigr")
        await self._port.set("trigr", start, end, count, axis=axis)

