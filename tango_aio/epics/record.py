"""Motor-record arithmetic for a TANGO axis (pure functions, no caproto).

* Positions: the controller's position unit (its ``dim``, manual L3061-3144) is the
  record's engineering unit (EGU); dial values are the controller's positions and user
  values are dial + OFF (the record's DIR field is not supported: always positive).
* Velocities: VELO is EGU/s. The controller's ``vel`` is motor rev/s in dims 0-8 and mm/s
  in dim 9 (L189, L3452), converted with :class:`~tango_aio.units.UnitScale`.
* Acceleration: ACCL is the seconds to reach VELO; the controller's ``accel`` is m/s²
  (L3298).
* Limit switches: ``?readsw`` gives 12 characters, E0 (lower, cal) of X Y Z A, the
  reference switches, then EE (upper, rm) of X Y Z A (L5027-5078).
* MSTA: the bits of the motor record's status word that a TANGO axis can fill.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..instructions import AXES
from ..status import CALIBRATED_FLAG
from ..units import DEFAULT_USTEPS, DIM_MM, DIM_UNITS, UnitScale

__all__ = [
    "EGU_BY_DIM",
    "AxisUnits",
    "LimitSwitches",
    "Msta",
    "calibrated",
    "limit_switches",
    "msta",
]

#: The engineering unit of each ``dim`` (L3061-3144): ASCII, as CA strings are latin-1.
EGU_BY_DIM: dict[int, str] = {dim: unit.ascii for dim, unit in DIM_UNITS.items()}


@dataclass(frozen=True, slots=True)
class AxisUnits:
    """The unit settings of one axis: converts controller values to record fields."""

    dim: int = DIM_MM
    pitch: float = 1.0
    gear: float = 1.0
    usteps: int = DEFAULT_USTEPS

    @property
    def scale(self) -> UnitScale:
        """The :class:`~tango_aio.units.UnitScale` of these settings."""
        return UnitScale(self.dim, self.pitch, self.gear, self.usteps)

    @property
    def egu(self) -> str:
        """The engineering unit (the ``dim`` unit)."""
        return EGU_BY_DIM.get(self.dim, "")

    def velo_from_vel(self, vel: float) -> float:
        """VELO (EGU/s) from the controller's ``vel`` (rev/s, or mm/s in dim 9).

        Parameters
        ----------
        vel
            The controller's ``vel``.

        Returns
        -------
        float
            VELO, in EGU/s.
        """
        scale = self.scale
        return scale.pos_to_user(scale.vel_from_user(vel))

    def vel_from_velo(self, velo: float) -> float:
        """The controller's ``vel`` from VELO (EGU/s).

        Parameters
        ----------
        velo
            VELO, in EGU/s.

        Returns
        -------
        float
            The controller's ``vel``.
        """
        scale = self.scale
        return scale.vel_to_user(scale.pos_from_user(velo))

    def _egu_per_m(self) -> float:
        scale = self.scale
        return 1000.0 * scale.user_per_rev / scale.mm_per_rev

    def accl_from_accel(self, velo: float, accel: float) -> float:
        """ACCL (seconds to VELO) from VELO (EGU/s) and ``accel`` (m/s²).

        Parameters
        ----------
        velo
            VELO, in EGU/s.
        accel
            The controller's ``accel``, in m/s².

        Returns
        -------
        float
            ACCL, in seconds.
        """
        if accel <= 0.0:
            return 0.0
        return abs(velo) / (accel * self._egu_per_m())

    def accel_from_accl(self, velo: float, accl: float) -> float:
        """The controller's ``accel`` (m/s²) that reaches VELO (EGU/s) in ACCL seconds.

        Parameters
        ----------
        velo
            VELO, in EGU/s.
        accl
            ACCL, in seconds (positive).

        Returns
        -------
        float
            The controller's ``accel``, in m/s².

        Raises
        ------
        ValueError
            ``accl`` is not a positive number.
        """
        if not (math.isfinite(accl) and accl > 0.0):
            raise ValueError(f"ACCL must be a positive number of seconds, got {accl!r}")
        return abs(velo) / accl / self._egu_per_m()


@dataclass(frozen=True, slots=True)
class LimitSwitches:
    """The actuated limit switches of one axis (``?readsw``)."""

    low: bool = False
    high: bool = False


def limit_switches(readsw: str, axis: str) -> LimitSwitches:
    """Read the E0 (lower) and EE (upper) switch of ``axis`` from a ``?readsw`` reply.

    A reply of unexpected length is read as "no switch actuated" (nothing is assumed).

    Parameters
    ----------
    readsw
        The ``?readsw`` reply.
    axis
        The axis letter.

    Returns
    -------
    LimitSwitches
        The state of the two switches.
    """
    text = readsw.strip()
    index = AXES.index(axis)
    if len(text) < 12:
        return LimitSwitches()
    return LimitSwitches(low=text[index] == "1", high=text[8 + index] == "1")


def calibrated(statuslimit: str, axis: str) -> bool:
    """Whether ``?statuslimit`` says ``axis`` was calibrated (``A`` in group 1, L5136).

    Parameters
    ----------
    statuslimit
        The ``?statuslimit`` reply.
    axis
        The axis letter.

    Returns
    -------
    bool
        Whether the axis was calibrated.
    """
    index = AXES.index(axis)
    return len(statuslimit) > index and statuslimit[index] == CALIBRATED_FLAG


class Msta:
    """Bits of the motor record's MSTA status word (motor record documentation)."""

    DIRECTION = 1 << 0
    DONE = 1 << 1
    PLUS_LS = 1 << 2
    PROBLEM = 1 << 9
    MOVING = 1 << 10
    COMM_ERR = 1 << 12
    MINUS_LS = 1 << 13
    HOMED = 1 << 14


def msta(*, moving: bool, switches: LimitSwitches, problem: bool, comm_error: bool,
         homed: bool, positive: bool) -> int:
    """The MSTA word of an axis from what the controller reported.

    Parameters
    ----------
    moving
        The axis moves (MOVING, else DONE).
    switches
        The state of its limit switches.
    problem
        Set PROBLEM (a move or command failed).
    comm_error
        Set COMM_ERR (the link is down).
    homed
        Set HOMED (the axis was calibrated).
    positive
        Set DIRECTION (the last move went the positive way).

    Returns
    -------
    int
        The MSTA bits.
    """
    word = Msta.MOVING if moving else Msta.DONE
    flags = ((positive, Msta.DIRECTION), (switches.high, Msta.PLUS_LS),
             (switches.low, Msta.MINUS_LS), (problem, Msta.PROBLEM),
             (comm_error, Msta.COMM_ERR), (homed, Msta.HOMED))
    for on, bit in flags:
        if on:
            word |= bit
    return word
