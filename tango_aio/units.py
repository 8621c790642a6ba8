"""Unit conversion between motor revolutions and the `dim` units (pure functions).

Shared by the emulator and the driver (move-timeout estimates).

The motion model keeps every length in **motor revolutions** and every velocity in
**motor revolutions per second**: that is what a stepper controller really counts, and it
keeps positions unchanged when the user switches ``dim``.  This module converts between
those internal units and the user units selected by ``dim`` (manual L3061-3144).

Conventions (the manual is vague on some of them; the choices are written down here):

* Travel per motor revolution is ``pitch / gear`` mm.  ``pitch`` is "mm per motor (or
  gear) revolution" (L3154) and ``gear`` is the ratio 1:n (L3245), so a 1:10 gearbox needs
  ten motor turns for one spindle turn.
* ``dim 0`` counts microsteps: ``usteps`` (one global value, default 40000, L4106) per
  *motor* revolution; gear and pitch do not enter.
* ``dim 3`` (360°) and ``dim 4`` (revolutions) are derived from the travel in mm, one
  "revolution" per mm.  The manual recommends a spindle pitch of 1 mm for these dims
  (L3104), which only makes sense if they are computed from mm.  With that recommended
  pitch they are exactly revolutions of the gear output shaft (motor revs / gear).
* ``dim 5`` cm, ``6`` m, ``7`` inch (25.4 mm), ``8`` mil (0.0254 mm), ``1`` µm, ``2`` and
  ``9`` mm.
* Velocities (``vel``, ``speed``, ``calvel`` ...) are motor rev/s in dims 0-8 and mm/s in
  dim 9 (L189).  ``secvel`` and ``scanvel`` are always mm/s, ``accel``/``stopaccel``
  always m/s², ``calbspeed`` always 1/100 rev/s (L226).

All conversions are pure scale factors (no offsets), so they apply equally to positions
and to distances.
"""

from __future__ import annotations

import enum
import numbers
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, NamedTuple, Protocol

__all__ = [
    "DEFAULT_USTEPS",
    "DIM_CM",
    "DIM_DEG",
    "DIM_INCH",
    "DIM_M",
    "DIM_MIL",
    "DIM_MM",
    "DIM_MM_VEL",
    "DIM_REV",
    "DIM_UM",
    "DIM_UNITS",
    "DIM_USTEPS",
    "LENGTH_UNITS",
    "MM_PER_INCH",
    "MOTOR_UNITS",
    "DimUnit",
    "Measure",
    "Quantity",
    "UnitScale",
    "accel_to_rev",
    "check_unit",
    "from_controller",
    "mm_per_rev",
    "plain",
    "split_unit",
    "to_controller",
    "user_per_rev",
    "velocity_unit",
]

DIM_USTEPS = 0
DIM_UM = 1
DIM_MM = 2
DIM_DEG = 3
DIM_REV = 4
DIM_CM = 5
DIM_M = 6
DIM_INCH = 7
DIM_MIL = 8
DIM_MM_VEL = 9

DEFAULT_USTEPS = 40000
"""Default microsteps per motor revolution for dim 0 (manual example ``!usteps 40000``)."""

MM_PER_INCH = 25.4
"""Millimetres per inch (dim 7); a mil (dim 8) is 1/1000 inch."""

# Millimetres per dim unit for every dim except 0 (dims 3 and 4 are derived from mm, see
# the module docstring; dim 9 is mm for positions).
_MM_PER_DIM: dict[int, Fraction] = {
    DIM_UM: Fraction(1, 1000), DIM_MM: Fraction(1), DIM_DEG: Fraction(1, 360),
    DIM_REV: Fraction(1), DIM_CM: Fraction(10), DIM_M: Fraction(1000),
    DIM_INCH: Fraction(254, 10), DIM_MIL: Fraction(254, 10_000), DIM_MM_VEL: Fraction(1),
}

# User units per millimetre of travel, for every dim except 0 (microsteps): the same
# table inverted (each inverse rounds to the float it had when written as 1.0 / 25.4 etc.).
_USER_PER_MM: dict[int, float] = {dim: float(1 / mm) for dim, mm in _MM_PER_DIM.items()}


class DimUnit(NamedTuple):
    """The name of one ``dim``'s position unit, spelt two ways."""

    #: ASCII (``um``, ``ustep``, ``inch``): for Channel Access, whose strings are latin-1.
    ascii: str
    #: The short form with symbols (``µm``, ``µstep``, ``in``): for ophyd-async metadata.
    symbol: str


#: The position unit of each ``dim`` (L3061-3144); dim 9 is mm, with velocities in mm/s.
DIM_UNITS: dict[int, DimUnit] = {
    DIM_USTEPS: DimUnit("ustep", "µstep"), DIM_UM: DimUnit("um", "µm"),
    DIM_MM: DimUnit("mm", "mm"), DIM_DEG: DimUnit("deg", "deg"), DIM_REV: DimUnit("rev", "rev"),
    DIM_CM: DimUnit("cm", "cm"), DIM_M: DimUnit("m", "m"), DIM_INCH: DimUnit("inch", "in"),
    DIM_MIL: DimUnit("mil", "mil"), DIM_MM_VEL: DimUnit("mm", "mm"),
}


def velocity_unit(dim: int) -> str:
    """The unit of ``vel`` for an axis in ``dim``.

    Parameters
    ----------
    dim
        The axis's ``dim``.

    Returns
    -------
    str
        ``"rev/s"`` (motor revolutions), ``"mm/s"`` in dim 9 (L189, L3452).
    """
    return "mm/s" if dim == DIM_MM_VEL else "rev/s"


def mm_per_rev(pitch: float, gear: float) -> float:
    """Return the axis travel in mm per motor revolution (``pitch / gear``).

    Parameters
    ----------
    pitch
        The spindle pitch, in mm per spindle revolution.
    gear
        The gear ratio (motor revolutions per spindle revolution).

    Returns
    -------
    float
        mm per motor revolution.

    Raises
    ------
    ValueError
        ``pitch`` or ``gear`` is not positive.
    """
    if pitch <= 0.0 or gear <= 0.0:
        raise ValueError(f"pitch and gear must be positive, got {pitch!r} and {gear!r}")
    return pitch / gear


def user_per_rev(dim: int, pitch: float, gear: float, usteps: int) -> float:
    """Return how many user length units (per ``dim``) one motor revolution is.

    Parameters
    ----------
    dim
        The axis's ``dim`` (0-9).
    pitch
        The spindle pitch, in mm per spindle revolution.
    gear
        The gear ratio (motor revolutions per spindle revolution).
    usteps
        Microsteps per revolution (the unit of dim 0).

    Returns
    -------
    float
        User units per motor revolution.

    Raises
    ------
    ValueError
        ``dim`` is not 0-9, or ``pitch`` or ``gear`` is not positive.
    """
    if dim == DIM_USTEPS:
        return float(usteps)
    try:
        factor = _USER_PER_MM[dim]
    except KeyError:
        raise ValueError(f"dim must be 0..9, got {dim!r}") from None
    return mm_per_rev(pitch, gear) * factor


def accel_to_rev(accel_m_s2: float, pitch: float, gear: float) -> float:
    """Convert an acceleration in m/s² to motor rev/s².

    Parameters
    ----------
    accel_m_s2
        The acceleration, in m/s².
    pitch
        The spindle pitch, in mm per spindle revolution.
    gear
        The gear ratio (motor revolutions per spindle revolution).

    Returns
    -------
    float
        The acceleration, in rev/s².
    """
    return accel_m_s2 * 1000.0 / mm_per_rev(pitch, gear)


@dataclass(frozen=True, slots=True)
class UnitScale:
    """Conversion factors of one axis for a given ``dim``/``pitch``/``gear``/``usteps``."""

    dim: int = DIM_MM
    pitch: float = 1.0
    gear: float = 1.0
    usteps: int = DEFAULT_USTEPS

    @property
    def mm_per_rev(self) -> float:
        """Travel in mm per motor revolution."""
        return mm_per_rev(self.pitch, self.gear)

    @property
    def user_per_rev(self) -> float:
        """User length units per motor revolution."""
        return user_per_rev(self.dim, self.pitch, self.gear, self.usteps)

    @property
    def resolution(self) -> float:
        """User length units per microstep (the motor record's MRES, ophyd-async's
        ``motor_resolution``)."""
        return self.user_per_rev / self.usteps

    def pos_to_user(self, revs: float) -> float:
        """Convert a position or distance in motor revolutions to user units.

        Parameters
        ----------
        revs
            Motor revolutions.

        Returns
        -------
        float
            The same length, in user units.
        """
        return revs * self.user_per_rev

    def pos_from_user(self, value: float) -> float:
        """Convert a position or distance in user units to motor revolutions.

        Parameters
        ----------
        value
            A length, in user units.

        Returns
        -------
        float
            The same length, in motor revolutions.
        """
        return value / self.user_per_rev

    def vel_to_user(self, rev_per_s: float) -> float:
        """Convert rev/s to the user velocity unit (rev/s, or mm/s in dim 9).

        Parameters
        ----------
        rev_per_s
            A velocity, in rev/s.

        Returns
        -------
        float
            The same velocity, in the user velocity unit.
        """
        if self.dim == DIM_MM_VEL:
            return rev_per_s * self.mm_per_rev
        return rev_per_s

    def vel_from_user(self, value: float) -> float:
        """Convert a user velocity (rev/s, or mm/s in dim 9) to rev/s.

        Parameters
        ----------
        value
            A velocity, in the user velocity unit.

        Returns
        -------
        float
            The same velocity, in rev/s.
        """
        if self.dim == DIM_MM_VEL:
            return value / self.mm_per_rev
        return value

    def mm_to_rev(self, mm: float) -> float:
        """Convert a length (or mm/s velocity) to motor revolutions (or rev/s).

        Parameters
        ----------
        mm
            A length in mm (or a velocity in mm/s).

        Returns
        -------
        float
            The same, in motor revolutions (or rev/s).
        """
        return mm / self.mm_per_rev

    def rev_to_mm(self, revs: float) -> float:
        """Convert motor revolutions (or rev/s) to mm (or mm/s).

        Parameters
        ----------
        revs
            Motor revolutions (or rev/s).

        Returns
        -------
        float
            The same, in mm (or mm/s).
        """
        return revs * self.mm_per_rev

    def accel_to_rev(self, accel_m_s2: float) -> float:
        """Convert an acceleration in m/s² to motor rev/s².

        Parameters
        ----------
        accel_m_s2
            An acceleration, in m/s².

        Returns
        -------
        float
            The same, in rev/s².
        """
        return accel_to_rev(accel_m_s2, self.pitch, self.gear)


# --------------------------------------------------------------------------------------
# Physical units at the driver's public boundary (``move_to(x=1.5, unit="mm")``)
#
# What the controller's numbers mean (manual L3061-3144, L189, L3298): positions are in
# the axis' ``dim`` unit, velocities in motor rev/s (mm/s in dim 9) and accelerations in
# m/s² whatever the dim. A caller's unit names a length (``"mm"``), motor revolutions
# (``"rev"``) or microsteps (``"ustep"``); ``"/s"`` makes it a velocity and ``"/s2"``
# (also ``"/s^2"``, ``"/s**2"``, ``"/s²"``) an acceleration. Conversions go through exact
# rational factors so that ``1.5 mm`` is ``1500.0`` in dim 1, not ``1499.9999999999998``.

#: Millimetres per length unit a caller may name.
LENGTH_UNITS: dict[str, Fraction] = {
    "nm": Fraction(1, 1_000_000),
    "um": Fraction(1, 1000),
    "µm": Fraction(1, 1000),
    "mm": Fraction(1),
    "cm": Fraction(10),
    "m": Fraction(1000),
    "in": Fraction(254, 10),
    "inch": Fraction(254, 10),
    "mil": Fraction(254, 10_000),
}

#: Units that count motor revolutions (``rev``) and microsteps (``ustep``, see ``usteps``).
MOTOR_UNITS = ("rev", "ustep")

_PER_SECOND = ("/s",)
_PER_SECOND2 = ("/s2", "/s^2", "/s**2", "/s²")


class Quantity(Protocol):
    """What is used of a pint ``Quantity`` (``tango-aio[pint]``): ``to()`` and
    ``magnitude``."""

    @property
    def magnitude(self) -> Any:
        """The number, in the quantity's own unit."""

    def to(self, unit: str) -> Quantity:
        """The same quantity in ``unit``.

        Parameters
        ----------
        unit
            The unit to convert to, as pint spells it.

        Returns
        -------
        Quantity
            The converted quantity.
        """


class Measure(enum.IntEnum):
    """What a value measures, numbered by the power of seconds its unit is divided by."""

    POSITION = 0
    VELOCITY = 1
    ACCELERATION = 2

    @property
    def suffix(self) -> str:
        """What a position unit gets to name this measure (``mm`` → ``mm/s2``)."""
        return ("", "/s", "/s2")[self]


def split_unit(unit: str) -> tuple[str, Measure]:
    """``"mm/s"`` → ``("mm", Measure.VELOCITY)``: the base unit and what the unit
    measures. ``ValueError`` for an unknown unit.

    Parameters
    ----------
    unit
        A unit such as ``"mm"``, ``"um/s"`` or ``"mm/s2"``.

    Returns
    -------
    tuple[str, Measure]
        The base unit and what the unit measures.

    Raises
    ------
    ValueError
        The unit is not known.
    """
    text = unit.strip()
    measure = Measure.POSITION
    for suffixes, level in ((_PER_SECOND2, Measure.ACCELERATION),
                            (_PER_SECOND, Measure.VELOCITY)):
        for suffix in suffixes:
            if text.endswith(suffix):
                text, measure = text[: -len(suffix)], level
                break
        if measure:
            break
    if text not in LENGTH_UNITS and text not in MOTOR_UNITS:
        known = ", ".join([*LENGTH_UNITS, *MOTOR_UNITS])
        raise ValueError(f"unknown unit {unit!r}: use one of {known}, optionally with /s "
                         "(velocity) or /s2 (acceleration)")
    return text, measure


def check_unit(unit: str) -> str:
    """``unit`` if it is a known position unit (a length, ``rev`` or ``ustep``).

    Parameters
    ----------
    unit
        The unit to check.

    Returns
    -------
    str
        ``unit`` itself.

    Raises
    ------
    TypeError
        ``unit`` is not a string.
    ValueError
        ``unit`` is not known, or is a velocity or acceleration unit.
    """
    if not isinstance(unit, str):
        raise TypeError(f"a unit is a string such as 'mm', got {unit!r}")
    if split_unit(unit)[1] is not Measure.POSITION:
        raise ValueError(f"{unit!r} is not a position unit (give the length, e.g. 'mm')")
    return unit


def _revs_per(base: str, scale: UnitScale) -> Fraction:
    """Motor revolutions in one ``base`` unit on an axis with ``scale``."""
    if base == "rev":
        return Fraction(1)
    if base == "ustep":
        return Fraction(1, scale.usteps)
    return LENGTH_UNITS[base] / Fraction(scale.mm_per_rev)


def _dim_units_per(base: str, scale: UnitScale) -> Fraction:
    """Controller position units (per ``scale.dim``) in one ``base`` unit."""
    if base in LENGTH_UNITS and scale.dim != DIM_USTEPS:
        return LENGTH_UNITS[base] / _MM_PER_DIM[scale.dim]  # exact: no pitch involved
    return _revs_per(base, scale) * Fraction(scale.user_per_rev)


def _factor(unit: str, measure: Measure, scale: UnitScale) -> Fraction:
    """Controller units per caller unit for a quantity of ``measure``."""
    base = _kind(unit, measure)
    if measure is Measure.POSITION:
        return _dim_units_per(base, scale)
    if measure is Measure.VELOCITY:  # rev/s in dims 0-8, mm/s in dim 9 (L189)
        revs = _revs_per(base, scale)
        if scale.dim == DIM_MM_VEL:
            return LENGTH_UNITS[base] if base in LENGTH_UNITS else revs * Fraction(
                scale.mm_per_rev)
        return revs
    # accelerations: m/s² always (L3298)
    mm = LENGTH_UNITS[base] if base in LENGTH_UNITS else (
        _revs_per(base, scale) * Fraction(scale.mm_per_rev))
    return mm / 1000


def plain(value: object, unit: str | None, measure: Measure) -> tuple[float, str | None]:
    """``value`` as a plain number and the unit it is in, checked without any controller
    settings: a pint Quantity is converted to mm-based units (or revolutions, for angles)
    and its magnitude taken; ``unit`` must be of the kind ``measure`` asks for.
    ``TypeError`` for a non-number, ``ValueError`` for a wrong unit.

    Parameters
    ----------
    value
        A number, or a pint Quantity.
    unit
        The unit of a plain number; ``None`` for the controller's unit.
    measure
        What the value measures (a position, a velocity, an acceleration).

    Returns
    -------
    tuple[float, str | None]
        The number and its unit (``None``: the controller's unit).

    Raises
    ------
    TypeError
        ``value`` is not a number.
    ValueError
        The unit (or the Quantity's dimension) is not of the kind ``measure`` asks for.
    """
    if hasattr(value, "magnitude") and hasattr(value, "to"):
        quantity: Any = value
        suffix = ("", "/s", "/s**2")[measure]
        for ours, pints in (("mm", "mm"), ("rev", "revolution")):
            try:
                return float(quantity.to(pints + suffix).magnitude), ours + suffix
            except Exception:  # pint's DimensionalityError, without importing pint
                continue
        raise ValueError(f"{value!r} is not a length or an angle"
                         + " per second" * measure)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"not a number: {value!r}")
    if unit is not None:
        _kind(unit, measure)
    return float(value), unit


def _kind(unit: str, measure: Measure) -> str:
    """The base of ``unit``; ``ValueError`` unless it is of the kind ``measure`` asks for."""
    base, given = split_unit(unit)
    if given != measure:
        raise ValueError(f"{unit!r} is a {given.name.lower()} unit where a "
                         f"{measure.name.lower()} goes")
    return base


def to_controller(value: object, unit: str | None, measure: Measure,
                  scale: UnitScale) -> float:
    """Convert ``value`` (a number in ``unit``, or a pint Quantity) to the controller's
    unit on an axis with ``scale``: its dim unit (a position), rev/s or mm/s in dim 9 (a
    velocity), m/s² (an acceleration). ``unit=None`` and a plain number: already in the
    controller's unit.

    Parameters
    ----------
    value
        A number, or a pint Quantity.
    unit
        The unit of a plain number; ``None`` for the controller's unit.
    measure
        What the value measures (a position, a velocity, an acceleration).
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The value in the controller's unit.
    """
    number, given = plain(value, unit, measure)
    if given is None:
        return number
    return float(Fraction(number) * _factor(given, measure, scale))


def from_controller(value: float, unit: str | None, measure: Measure,
                    scale: UnitScale) -> float:
    """The inverse of :func:`to_controller` for a plain number (a reading).

    Parameters
    ----------
    value
        A reading, in the controller's unit.
    unit
        The unit wanted; ``None`` for the controller's unit.
    measure
        What the value measures (a position, a velocity, an acceleration).
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The reading in ``unit``.
    """
    if unit is None:
        return value
    return float(Fraction(value) / _factor(unit, measure, scale))
