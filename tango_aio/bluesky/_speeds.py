"""Speeds and accelerations between the controller's units and the devices' EGU."""

from __future__ import annotations

import math

from ..catalog import INSTRUCTIONS
from ..units import DIM_MM_VEL, UnitScale


def _vel_bounds() -> tuple[float, float]:
    """The upper bound of ``vel``: rev/s in dims 0-8, mm/s in dim 9 (manual L3452-3525,
    read from the catalog)."""
    param = INSTRUCTIONS["vel"].write[0].per_axis[0]
    assert param.hi is not None
    return float(param.hi), float(param.hi_dim9 if param.hi_dim9 is not None else param.hi)


def egu_velocity(controller_value: float, scale: UnitScale) -> float:
    """A ``vel`` as the controller prints it (rev/s, mm/s in dim 9: L189, L3452) in the
    axis's position unit per second (EGU/s), through :mod:`tango_aio.units`.

    Parameters
    ----------
    controller_value
        The velocity as ``?vel`` prints it.
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The velocity in EGU/s.
    """
    return scale.pos_to_user(scale.vel_from_user(controller_value))


def controller_velocity(egu_per_s: float, scale: UnitScale) -> float:
    """The inverse of :func:`egu_velocity`: EGU/s to what ``!vel`` takes.

    Parameters
    ----------
    egu_per_s
        A velocity in EGU/s.
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The value to write with ``!vel``.
    """
    return scale.vel_to_user(scale.pos_from_user(egu_per_s))


def egu_acceleration(m_per_s2: float, scale: UnitScale) -> float:
    """An ``accel`` (always m/s², L3298-3329) in EGU/s².

    Parameters
    ----------
    m_per_s2
        The acceleration as ``?accel`` prints it (m/s²).
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The acceleration in EGU/s².
    """
    return scale.pos_to_user(scale.accel_to_rev(m_per_s2))


def max_velocity(scale: UnitScale) -> float:
    """The highest velocity ``!vel`` accepts, in EGU/s (its catalog bound converted).

    Parameters
    ----------
    scale
        The axis's unit conversion.

    Returns
    -------
    float
        The highest velocity, in EGU/s.
    """
    rev_per_s, mm_per_s = _vel_bounds()
    if scale.dim == DIM_MM_VEL:
        return mm_per_s
    return scale.pos_to_user(rev_per_s)


def run_up_distance(speed: float, acceleration: float) -> float:
    """Distance (EGU) to reach ``speed`` (EGU/s) from rest at ``acceleration`` (EGU/s²):
    v² / 2a, the linear ramp the controller's ``accel`` describes (L3298).

    Parameters
    ----------
    speed
        The speed to reach, in EGU/s.
    acceleration
        The ramp's acceleration, in EGU/s² (positive).

    Returns
    -------
    float
        The distance, in EGU.

    Raises
    ------
    ValueError
        ``acceleration`` is not positive.
    """
    if not acceleration > 0:
        raise ValueError(f"acceleration must be positive, got {acceleration!r}")
    return 0.0 if math.isinf(acceleration) else speed * speed / (2.0 * acceleration)
