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

from dataclasses import dataclass

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
    "DIM_USTEPS",
    "MM_PER_INCH",
    "UnitScale",
    "accel_to_rev",
    "mm_per_rev",
    "user_per_rev",
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

# User units per millimetre of travel, for every dim except 0 (microsteps).
_USER_PER_MM: dict[int, float] = {
    DIM_UM: 1000.0,
    DIM_MM: 1.0,
    DIM_DEG: 360.0,
    DIM_REV: 1.0,
    DIM_CM: 0.1,
    DIM_M: 0.001,
    DIM_INCH: 1.0 / MM_PER_INCH,
    DIM_MIL: 1000.0 / MM_PER_INCH,
    DIM_MM_VEL: 1.0,
}


def mm_per_rev(pitch: float, gear: float) -> float:
    """Return the axis travel in mm per motor revolution (``pitch / gear``)."""
    if pitch <= 0.0 or gear <= 0.0:
        raise ValueError(f"pitch and gear must be positive, got {pitch!r} and {gear!r}")
    return pitch / gear


def user_per_rev(dim: int, pitch: float, gear: float, usteps: int) -> float:
    """Return how many user length units (per ``dim``) one motor revolution is."""
    if dim == DIM_USTEPS:
        return float(usteps)
    try:
        factor = _USER_PER_MM[dim]
    except KeyError:
        raise ValueError(f"dim must be 0..9, got {dim!r}") from None
    return mm_per_rev(pitch, gear) * factor


def accel_to_rev(accel_m_s2: float, pitch: float, gear: float) -> float:
    """Convert an acceleration in m/s² to motor rev/s²."""
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

    def pos_to_user(self, revs: float) -> float:
        """Convert a position or distance in motor revolutions to user units."""
        return revs * self.user_per_rev

    def pos_from_user(self, value: float) -> float:
        """Convert a position or distance in user units to motor revolutions."""
        return value / self.user_per_rev

    def vel_to_user(self, rev_per_s: float) -> float:
        """Convert rev/s to the user velocity unit (rev/s, or mm/s in dim 9)."""
        if self.dim == DIM_MM_VEL:
            return rev_per_s * self.mm_per_rev
        return rev_per_s

    def vel_from_user(self, value: float) -> float:
        """Convert a user velocity (rev/s, or mm/s in dim 9) to rev/s."""
        if self.dim == DIM_MM_VEL:
            return value / self.mm_per_rev
        return value

    def mm_to_rev(self, mm: float) -> float:
        """Convert a length (or mm/s velocity) to motor revolutions (or rev/s)."""
        return mm / self.mm_per_rev

    def rev_to_mm(self, revs: float) -> float:
        """Convert motor revolutions (or rev/s) to mm (or mm/s)."""
        return revs * self.mm_per_rev

    def accel_to_rev(self, accel_m_s2: float) -> float:
        """Convert an acceleration in m/s² to motor rev/s²."""
        return accel_to_rev(accel_m_s2, self.pitch, self.gear)
