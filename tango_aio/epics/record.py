"""Motor-record arithmetic for a TANGO axis (pure functions, no caproto).

* Positions: the controller's position unit (its ``dim``, manual L3061-3144) is the
  record's engineering unit (EGU); dial values are the controller's positions and user
  values are dial + OFF (the record's DIR field is not supported: always positive).
* Velocities: VELO is EGU/s. The controller's ``vel`` is motor rev/s in dims 0-8 and mm/s
  in dim 9 (L189, L3452), converted with :class:`~tango_aio.units.UnitScale`.
* Acceleration: ACCL is the seconds to reach VELO; the controller's ``accel`` is m/s²
  (L3298), ACCS the same in EGU/s².
* Resolution: MRES is the user units per microstep, UREV per motor revolution, SREV the
  microsteps per revolution (``usteps``), the facts :class:`~tango_aio.units.UnitScale`
  gives every surface (the Bluesky device's ``motor_resolution`` too); RDBD is how far from
  its target a move still counts as arrived (the driver's tolerance for the decimals the
  controller prints, at least MRES).
* Limit switches: ``?readsw`` gives 12 characters, E0 (lower, cal) of X Y Z A, the
  reference switches, then EE (upper, rm) of X Y Z A (L5027-5078).
* MSTA: the bits of the motor record's status word that a TANGO axis can fill; MIP the
  motion in progress (a move, a home forward or reverse).
* Derived fields (:func:`derived_fields`): the raw values in microsteps (RVAL, RRBV, RMP,
  RDIF: dial / MRES, rounded as the motor record's NINT rounds), DIFF (DVAL - DRBV), the
  last desired values (LVAL, LDVL, LRVL: after processing, the record's current ones),
  and the speeds in revolutions per second (S, SMAX, SBAS: EGU/s over UREV).
* Alarms: one rule for every PV of an axis (:func:`fault_after`, :func:`shown_alarm`): a
  failed move raises the alarm, only a move that ends at its target clears it, and a stop
  (STOP, SPMG) leaves it as it was; while the link is down every PV shows INVALID/COMM.
* Soft limits: a target beyond them is refused as the motor record refuses it
  (:func:`limit_violation`: limits of 0 and 0 mean none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from ..catalog import AXES
from ..moves import position_tolerance
from ..status import CALIBRATED_FLAG
from ..units import DEFAULT_USTEPS, DIM_MM, DIM_UNITS, UnitScale

__all__ = [
    "EGU_BY_DIM",
    "NO_ALARM",
    "Alarm",
    "AxisUnits",
    "Ending",
    "LimitSwitches",
    "Mip",
    "Msta",
    "calibrated",
    "derived_fields",
    "fault_after",
    "limit_switches",
    "limit_violation",
    "msta",
    "nint",
    "revolution_speeds",
    "shown_alarm",
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
        """VELO (EGU/s) from the controller's ``vel`` (rev/s, or mm/s in dim 9)."""
        scale = self.scale
        return scale.pos_to_user(scale.vel_from_user(vel))

    def vel_from_velo(self, velo: float) -> float:
        """The controller's ``vel`` from VELO (EGU/s)."""
        scale = self.scale
        return scale.vel_to_user(scale.pos_from_user(velo))

    @property
    def mres(self) -> float:
        """MRES: user units (EGU) per microstep."""
        return self.scale.resolution

    @property
    def urev(self) -> float:
        """UREV: user units (EGU) per motor revolution."""
        return self.scale.user_per_rev

    @property
    def srev(self) -> int:
        """SREV: microsteps per motor revolution."""
        return self.usteps

    def rdbd(self, decimals: int) -> float:
        """RDBD: how far from its target a move counts as arrived, in EGU."""
        return max(self.mres, position_tolerance(f"{0:.{max(decimals, 0)}f}"))

    def accs_from_accel(self, accel: float) -> float:
        """ACCS (EGU/s²) from the controller's ``accel`` (m/s²)."""
        return max(accel, 0.0) * self._egu_per_m()

    def _egu_per_m(self) -> float:
        scale = self.scale
        return 1000.0 * scale.user_per_rev / scale.mm_per_rev

    def accl_from_accel(self, velo: float, accel: float) -> float:
        """ACCL (seconds to VELO) from VELO (EGU/s) and ``accel`` (m/s²)."""
        if accel <= 0.0:
            return 0.0
        return abs(velo) / (accel * self._egu_per_m())

    def accel_from_accl(self, velo: float, accl: float) -> float:
        """The controller's ``accel`` (m/s²) that reaches VELO (EGU/s) in ACCL seconds."""
        if not (math.isfinite(accl) and accl > 0.0):
            raise ValueError(f"ACCL must be a positive number of seconds, got {accl!r}")
        return abs(velo) / accl / self._egu_per_m()


@dataclass(frozen=True, slots=True)
class LimitSwitches:
    """The actuated limit switches of one axis (``?readsw``)."""

    low: bool = False
    high: bool = False


def limit_switches(readsw: str, axis: str) -> LimitSwitches:
    """Read the E0 (lower) and EE (upper) switch of ``axis`` from a ``?readsw`` reply."""
    text = readsw.strip()
    index = AXES.index(axis)
    if len(text) < 12:
        return LimitSwitches()
    return LimitSwitches(low=text[index] == "1", high=text[8 + index] == "1")


def calibrated(statuslimit: str, axis: str) -> bool:
    """Whether ``?statuslimit`` says ``axis`` was calibrated (``A`` in group 1, L5136)."""
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
    """The MSTA word of an axis from what the controller reported."""
    word = Msta.MOVING if moving else Msta.DONE
    flags = ((positive, Msta.DIRECTION), (switches.high, Msta.PLUS_LS),
             (switches.low, Msta.MINUS_LS), (problem, Msta.PROBLEM),
             (comm_error, Msta.COMM_ERR), (homed, Msta.HOMED))
    for on, bit in flags:
        if on:
            word |= bit
    return word


class Mip:
    """Bits of the motor record's MIP word (motion in progress)."""

    DONE = 0
    HOMF = 0x0008
    HOMR = 0x0010
    MOVE = 0x0020


def nint(value: float) -> int:
    """The nearest integer, halves away from zero (the motor record's NINT)."""
    return int(math.copysign(math.floor(abs(value) + 0.5), value))


def derived_fields(*, val: float, dval: float, drbv: float, mres: float
                   ) -> dict[str, float]:
    """The fields the motor record derives from VAL, DVAL, DRBV and MRES."""
    def raw(dial: float) -> int:
        return nint(dial / mres) if mres > 0 else 0

    diff = dval - drbv
    return {"RVAL": raw(dval), "RRBV": raw(drbv), "RMP": raw(drbv), "DIFF": diff,
            "RDIF": raw(diff), "LVAL": val, "LDVL": dval, "LRVL": raw(dval)}


def revolution_speeds(*, velo: float, vmax: float, urev: float) -> dict[str, float]:
    """S and SMAX (revolutions per second) from VELO and VMAX (EGU/s); SBAS is 0 (VBAS)."""
    per_rev = abs(urev)
    if per_rev == 0:
        return {"S": 0.0, "SMAX": 0.0, "SBAS": 0.0}
    return {"S": velo / per_rev, "SMAX": vmax / per_rev, "SBAS": 0.0}


class Alarm(NamedTuple):
    """An alarm as Channel Access names it (caproto's ``AlarmStatus`` and
    ``AlarmSeverity`` member names)."""

    status: str
    severity: str


#: No alarm.
NO_ALARM = Alarm("NO_ALARM", "NO_ALARM")

#: The link to the controller is down: nothing read stands.
LINK_DOWN = Alarm("COMM", "INVALID_ALARM")


class Ending(Enum):
    """How a motion request of an axis ended."""

    #: The move ended at its target.
    ARRIVED = "arrived"
    #: The move ended anywhere else (a status letter, a controller error, a refused line).
    FAILED = "failed"
    #: Refused before any motion: the target is above the high soft limit.
    ABOVE_LIMIT = "above limit"
    #: Refused before any motion: the target is below the low soft limit.
    BELOW_LIMIT = "below limit"
    #: STOP, SPMG Stop or Pause, or a newer request replaced it.
    STOPPED = "stopped"


def fault_after(fault: Alarm, ending: Ending) -> Alarm:
    """The fault alarm of an axis after a request ended as ``ending``."""
    if ending is Ending.ARRIVED:
        return NO_ALARM
    if ending is Ending.FAILED:
        return Alarm("STATE", "MAJOR_ALARM")
    if ending is Ending.ABOVE_LIMIT:
        return Alarm("HIGH", "MAJOR_ALARM")
    if ending is Ending.BELOW_LIMIT:
        return Alarm("LOW", "MAJOR_ALARM")
    return fault


def shown_alarm(fault: Alarm, *, link_up: bool) -> Alarm:
    """The alarm every PV of an axis shows."""
    return fault if link_up else LINK_DOWN


def limit_violation(dial: float, low: float, high: float) -> Ending | None:
    """Whether a dial target violates the soft limits ``[low, high]`` (dial units)."""
    if low == high == 0.0:
        return None
    if dial > high:
        return Ending.ABOVE_LIMIT
    if dial < low:
        return Ending.BELOW_LIMIT
    return None
