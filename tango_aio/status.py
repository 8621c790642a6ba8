"""What the letters of ``statusaxis`` and of autostatus completion reports mean.

:class:`AxisStatus` is a :class:`~enum.StrEnum`, so a member compares equal to its letter
(``AxisStatus.MOVING == "M"``) and the driver's plain letter dictionaries keep working.
Source: manual L2693-2711 (firmware 1.71); older firmware adds ``C`` and ``U``
(old L747-767). ``-`` (axis not enabled or not present) never reaches the caller: such
axes are left out of the per-axis dictionaries.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from typing import Final

__all__ = ["ABSENT", "ARRIVED_LETTERS", "CALIBRATED_FLAG", "FAILED_LETTERS", "LETTERS",
           "MOVING", "AxisStatus", "axis_statuses", "switch_states"]


class AxisStatus(enum.StrEnum):
    """The state of one axis, by its ``statusaxis`` letter."""

    #: ``@``: not moving and ready (L2693).
    READY = "@"
    #: ``M``: moving (L2695).
    MOVING = "M"
    #: ``J``: ready, and may also be moved by hand with the joystick (L2697).
    JOYSTICK = "J"
    #: ``S``: limit switches are actuated and prevent further automatic moves (L2699).
    LIMIT_SWITCH = "S"
    #: ``A``: the ok report after ``cal`` (L2701).
    CALIBRATED = "A"
    #: ``D``: the ok report after ``rm`` (L2703).
    RANGE_MEASURED = "D"
    #: ``E``: error: move aborted or not executed (cal/rm error, stop input) (L2705-2707).
    ERROR = "E"
    #: ``T``: timeout (see ``caltimeout``) (L2709).
    TIMEOUT = "T"
    #: ``C``: in closed loop (older firmware, old L753).
    CLOSED_LOOP = "C"
    #: ``U``: manual adjustment, e.g. first setup (older firmware, old L763).
    MANUAL_ADJUSTMENT = "U"

    @property
    def meaning(self) -> str:
        """A short human-readable meaning of the letter."""
        return _MEANINGS[self]

    @property
    def is_moving(self) -> bool:
        """Whether the axis is moving (the manual's test is ``!= 'M'`` for "done",
        L2685)."""
        return self is AxisStatus.MOVING

    @property
    def is_failure(self) -> bool:
        """Whether a move that ended with this letter did not reach its target (E, S, T)."""
        return self in (AxisStatus.ERROR, AxisStatus.LIMIT_SWITCH, AxisStatus.TIMEOUT)

    @classmethod
    def of(cls, letter: str) -> AxisStatus:
        """The member for ``letter``; ``ValueError`` for a letter the manuals do not
        document.

        Parameters
        ----------
        letter
            A status letter (``"@"``, ``"M"``...).

        Returns
        -------
        AxisStatus
            Its member.

        Raises
        ------
        ValueError
            The letter is not documented.
        """
        try:
            return cls(letter)
        except ValueError:
            raise ValueError(f"unknown axis status letter {letter!r}") from None



_MEANINGS: dict[AxisStatus, str] = {
    AxisStatus.READY: "ready",
    AxisStatus.MOVING: "moving",
    AxisStatus.JOYSTICK: "ready, joystick enabled",
    AxisStatus.LIMIT_SWITCH: "limit switch actuated",
    AxisStatus.CALIBRATED: "calibration done",
    AxisStatus.RANGE_MEASURED: "range measure done",
    AxisStatus.ERROR: "error, move aborted or not executed",
    AxisStatus.TIMEOUT: "timeout",
    AxisStatus.CLOSED_LOOP: "closed loop",
    AxisStatus.MANUAL_ADJUSTMENT: "manual adjustment",
}


#: The only letter that means "still moving" (L2676-2681: "every response except of 'M'
#: means the axis has stopped").
MOVING: Final = AxisStatus.MOVING.value

#: The letters of a move that did not end where it should (E, S, T; L2699, L2705-2709).
FAILED_LETTERS: Final = frozenset(status.value for status in AxisStatus if status.is_failure)

#: The letters of an axis that reached its target (``@``), was calibrated (``A``) or had its
#: range measured (``D``); any other letter ends a move short (L2676-2720).
ARRIVED_LETTERS: Final = frozenset(
    status.value for status in (AxisStatus.READY, AxisStatus.CALIBRATED,
                                AxisStatus.RANGE_MEASURED))

#: The place-holder letter of an axis that is not enabled or not present (L2711); not an
#: :class:`AxisStatus`, since such an axis is left out of the per-axis dictionaries.
ABSENT: Final = "-"

#: Every letter a status read or a completion report may hold: the documented letters of
#: both editions and :data:`ABSENT`.
LETTERS: Final = frozenset({*(status.value for status in AxisStatus), ABSENT})

#: The character of ``?statuslimit`` (one per axis, characters 0-3) for an axis calibrated
#: since power-on (L5136-5191); not a ``statusaxis`` letter.
CALIBRATED_FLAG: Final = "A"


def axis_statuses(letters: Mapping[str, str]) -> dict[str, AxisStatus]:
    """``{"x": "@", "y": "M"}`` → ``{"x": AxisStatus.READY, "y": AxisStatus.MOVING}``.

    Parameters
    ----------
    letters
        The status letter of each axis, by axis letter.

    Returns
    -------
    dict[str, AxisStatus]
        The member of each axis, by axis letter.
    """
    return {axis: AxisStatus.of(letter) for axis, letter in letters.items()}


def switch_states(readsw: str, axis: str) -> tuple[bool, bool, bool] | None:
    """The (lower, reference, upper) limit switches of ``axis`` in a ``?readsw`` reply:
    12 characters, E0 (lower, ``cal``'s) of X Y Z A, then Ref of X Y Z A ("not available
    with TANGO, always 0"), then EE (upper, ``rm``'s) of X Y Z A, ``1`` for actuated
    (L5027-5078).

    Parameters
    ----------
    readsw
        The ``?readsw`` reply.
    axis
        The axis letter (``"x"``...).

    Returns
    -------
    tuple[bool, bool, bool] | None
        Whether each switch is actuated; ``None`` for a reply that is not 12 switch
        states (the caller decides what that means).
    """
    text = readsw.strip()
    if len(text) != 12 or set(text) - {"0", "1"}:
        return None
    index = "xyza".index(axis)
    return text[index] == "1", text[4 + index] == "1", text[8 + index] == "1"
