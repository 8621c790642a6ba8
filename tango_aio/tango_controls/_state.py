"""What an axis device's ``State`` and ``Status`` say, decided from what the server knows
(sans-IO: no pytango, no event loop).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

__all__ = ["AxisView", "Shown", "shown"]


class Shown(enum.Enum):
    """The Tango Controls device states an axis device uses (names as ``tango.DevState``)."""

    ON = "ON"
    MOVING = "MOVING"
    ALARM = "ALARM"
    FAULT = "FAULT"
    INIT = "INIT"


@dataclass(frozen=True, slots=True)
class AxisView:
    """What the server knows about one axis, enough to decide its ``State``.

    Each method returns the view after one thing happened; the device keeps the newest.
    """

    #: The link to the controller is up.
    link_up: bool = False
    #: The axis's settings (unit, limits) have been read since the link came up.
    ready: bool = False
    #: Motions this server started that have no verdict yet.
    busy: int = 0
    #: The latest state read (with none of ours in flight) showed the axis moving.
    stray_moving: bool = False
    #: Why the latest motion ended short (``None``: it arrived, or there was none).
    alarm: str | None = None
    #: What the latest motion was (``"move to 3.5"``), for the status text.
    last: str = ""

    def started(self, what: str) -> AxisView:
        """A motion was accepted (the device shows ``MOVING`` from now on).

        Parameters
        ----------
        what
            The motion, in words (``"move to 3.5"``).

        Returns
        -------
        AxisView
            The view with the motion in flight.
        """
        return replace(self, busy=self.busy + 1, last=what)

    def ended(self, reason: str | None) -> AxisView:
        """A motion had its verdict: ``reason`` is ``None`` if it arrived, else why not.

        Parameters
        ----------
        reason
            Why it ended short, or ``None`` when it arrived.

        Returns
        -------
        AxisView
            The view with one motion fewer in flight and the verdict kept.
        """
        return replace(self, busy=max(self.busy - 1, 0), alarm=reason, stray_moving=False)

    def read(self, moving: bool) -> AxisView:
        """A state read showed the axis ``moving`` or standing.

        Parameters
        ----------
        moving
            The axis's status letter was ``M``.

        Returns
        -------
        AxisView
            The view with the read applied.
        """
        return replace(self, stray_moving=moving)

    def link(self, up: bool) -> AxisView:
        """The link went down or came back (the settings are to be read again).

        Parameters
        ----------
        up
            Whether the link is up.

        Returns
        -------
        AxisView
            The view with the link's state; not ready until :meth:`settings_read`.
        """
        return replace(self, link_up=up, ready=False, stray_moving=False)

    def settings_read(self) -> AxisView:
        """The axis's settings were read.

        Returns
        -------
        AxisView
            The view, ready.
        """
        return replace(self, ready=True)


def shown(view: AxisView) -> tuple[Shown, str]:
    """The ``State`` and ``Status`` of an axis device.

    Parameters
    ----------
    view
        What the server knows about the axis.

    Returns
    -------
    tuple[Shown, str]
        The state and its status text.
    """
    after = f" (after: {view.alarm})" if view.alarm else ""
    if not view.link_up:
        return Shown.FAULT, "the link to the controller is lost; reconnecting" + after
    if not view.ready:
        return Shown.INIT, "reading the axis settings"
    if view.busy:
        return Shown.MOVING, f"{view.last}: under way"
    if view.stray_moving:
        return Shown.MOVING, "moving (not started by this server)"
    if view.alarm is not None:
        return Shown.ALARM, f"{view.last} ended short: {view.alarm}"
    if view.last:
        return Shown.ON, f"{view.last}: arrived"
    return Shown.ON, "standing"
