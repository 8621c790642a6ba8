"""The Sardana trigger/gate controller: the TANGO's trigger output, loaded with the
positions of a position-domain synchronisation, for hardware-synchronised continuous
scans."""

from __future__ import annotations

import contextlib
import threading
from typing import Any, ClassVar

from sardana import State as SardanaState
from sardana.pool.controller import (
    Access,
    DefaultValue,
    Description,
    TriggerGateController,
    Type,
)
from sardana.pool.pooldefs import SynchDomain, SynchParam

import tango_aio.sync
from tango_aio.errors import TangoError
from tango_aio.families import TriggerConfig, TriggerMode
from tango_aio.units import Measure, to_controller

from ._controller import _SARDANA_STATES
from ._links import acquire, release
from ._state import State
from ._synch import Group, TriggerPlan, plan, trigger_state

_LIST_MODES = (TriggerMode.LIST_RISING, TriggerMode.LIST_FALLING)


def _groups(description: list[dict[Any, Any]]) -> list[Group]:
    """The position-domain groups of a Sardana synchronisation description."""
    groups = []
    for group in description:
        try:
            initial = group[SynchParam.Initial][SynchDomain.Position]
            total = group[SynchParam.Total][SynchDomain.Position]
        except (KeyError, TypeError):
            raise ValueError("the TANGO's trigger output synchronises in the position "
                             "domain only: every group needs Initial and Total "
                             "positions") from None
        active = group.get(SynchParam.Active, {})
        time = active.get(SynchDomain.Time) if isinstance(active, dict) else None
        groups.append(Group(float(initial), float(total), group[SynchParam.Repeats],
                            None if time is None else float(time)))
    return groups


class MarzhauserTriggerGateController(TriggerGateController):  # type: ignore[misc]
    """The trigger output of a Märzhäuser TANGO stage controller as a Sardana
    trigger/gate (one axis), for continuous scans synchronised in the position domain.

    ``SynchOne`` turns the description's groups into trigger positions on the axis
    ``TriggerAxis`` (X unless set): one group of several pulses becomes one equidistant
    range (``!trigr``), anything else a position list (``!trigp``); the active time, if
    given, becomes the pulse width. Positions are dial positions in the ``Units``
    property's unit (as the motor controller reads them), converted to the axis' dim unit.
    ``StartOne`` resets the trigger counter and switches the output on; ``StateOne`` is
    ``Moving`` until the counter reaches the number of pulses loaded (then the output is
    switched off and the state is ``On``), ``Alarm`` if it passes it or the output was
    switched off elsewhere, ``Fault`` while the controller cannot be read. Give it the
    motor controller's ``URL``: both then share one link (a serial port opens once).

    See the how-to "Use TANGO stages in a Sardana pool" in the documentation.
    """

    MaxDevice = 1
    model = "Märzhäuser TANGO trigger output"
    organization = "tango_aio"

    ctrl_properties: ClassVar[dict[str, dict[Any, Any]]] = {
        "URL": {
            Type: str,
            Description: "Where the TANGO controller is (the motor controller's URL: "
                         "both share the link)",
        },
        "Units": {
            Type: str,
            Description: "The unit of the positions in the descriptions (the motor "
                         "controller's Units)",
            DefaultValue: "mm",
        },
        "Reconnect": {
            Type: bool,
            Description: "Reconnect by itself when the link is lost (as the motor "
                         "controller of the same URL)",
            DefaultValue: True,
        },
    }

    axis_attributes: ClassVar[dict[str, dict[Any, Any]]] = {
        "TriggerAxis": {
            Type: str,
            Access: "read_write",
            Description: "The axis whose positions the pulses follow (x, y, z or a)",
            DefaultValue: "x",
        },
    }

    def __init__(self, inst: str, props: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        super().__init__(inst, props, *args, **kwargs)
        self._lock = threading.Lock()
        self._axis_letter = "x"
        self._expected = 0
        self._loaded = self._started = self._stopped = False
        self._tango: tango_aio.sync.Controller | None = acquire(
            self.URL, self.Units, bool(self.Reconnect))

    @property
    def tango(self) -> tango_aio.sync.Controller:
        """The blocking driver object (shared with the motor controller of this URL).

        Raises
        ------
        TangoError
            The link is closed.
        """
        if self._tango is None:
            raise TangoError("the link to the TANGO controller is closed")
        return self._tango

    def close(self) -> None:
        """Let go of the link (closed with the last controller of this URL)."""
        tango, self._tango = self._tango, None
        if tango is not None:
            release(tango)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def AddDevice(self, axis: int) -> None:
        """The trigger/gate element was created (axis 1, the one trigger output).

        Raises
        ------
        ValueError
            Not axis 1.
        """
        if axis != 1:
            raise ValueError(f"the TANGO has one trigger output (axis 1), not {axis}")
        if self._tango is None:
            self._tango = acquire(self.URL, self.Units, bool(self.Reconnect))

    def DeleteDevice(self, axis: int) -> None:
        """The element was deleted: the link is let go."""
        self.close()

    # -- loading ---------------------------------------------------------------------------

    def SynchOne(self, axis: int, description: list[dict[Any, Any]]) -> None:
        """Load the trigger positions of a position-domain description (the output is
        switched off first, the trigger axis and pulse width written, then the range or
        list).

        Raises
        ------
        ValueError
            The description is not in the position domain, is empty, or its positions
            do not run one way (nothing is written).
        """
        trigger_plan = plan(_groups(description))
        tango, letter = self.tango, self._axis_letter
        scale = tango.settings.unit_scales()[letter]

        def dim(value: float) -> float:
            return to_controller(value, self.Units, Measure.POSITION, scale)

        with self._lock:
            self._loaded = self._started = False
        tango.triggers.set_enabled(False)
        current = tango.triggers.read_config()
        mode = TriggerMode.FORWARD if current.mode in _LIST_MODES else current.mode
        width = current.width_us if trigger_plan.width_us is None else trigger_plan.width_us
        config = TriggerConfig(mode=mode, axis=letter, width_us=width,
                               distance=current.distance, frequency_hz=current.frequency_hz,
                               output=current.output, compensation_us=current.compensation_us,
                               encoder=current.encoder,
                               list_active_high=current.list_active_high)
        tango.triggers.write_config(config)
        self._load(tango, trigger_plan, letter, dim)
        with self._lock:
            self._expected, self._loaded = len(trigger_plan.positions), True

    @staticmethod
    def _load(tango: tango_aio.sync.Controller, trigger_plan: TriggerPlan, letter: str,
              dim: Any) -> None:
        if trigger_plan.range is not None:
            start, end, count = trigger_plan.range
            tango.triggers.set_range(dim(start), dim(end), count, axis=letter)
        else:
            tango.triggers.upload_positions([dim(p) for p in trigger_plan.positions],
                                            axis=letter)

    # -- running ---------------------------------------------------------------------------

    def PreStartOne(self, axis: int, value: Any = None) -> bool:
        """Ready to start once a description is loaded."""
        return self._loaded

    def StartOne(self, axis: int) -> None:
        """Reset the trigger counter and switch the output on."""
        tango = self.tango
        tango.triggers.set_count(0)
        with self._lock:
            self._started, self._stopped = True, False
        tango.triggers.set_enabled(True)

    def StateOne(self, axis: int) -> tuple[Any, str]:
        """The state from the trigger counter against the pulses loaded (see the
        class)."""
        try:
            tango = self.tango
            enabled, count = tango.triggers.enabled(), tango.triggers.count()
        except TangoError as exc:
            return SardanaState.Fault, f"the trigger output cannot be read: {exc}"
        with self._lock:
            state, status = trigger_state(
                loaded=self._loaded, started=self._started, stopped=self._stopped,
                enabled=enabled, count=count, expected=self._expected)
        if state is not State.MOVING and enabled and self._started:
            with contextlib.suppress(TangoError):
                tango.triggers.set_enabled(False)  # no pulse beyond the scan's
        return _SARDANA_STATES[state], status

    def StopOne(self, axis: int) -> None:
        """Switch the output off."""
        with self._lock:
            self._stopped = True
        self.tango.triggers.set_enabled(False)

    def AbortOne(self, axis: int) -> None:
        """Switch the output off."""
        self.StopOne(axis)

    # -- the trigger axis ------------------------------------------------------------------

    def GetAxisExtraPar(self, axis: int, name: str) -> Any:
        """``TriggerAxis``: the axis the pulses follow.

        Raises
        ------
        ValueError
            Another parameter.
        """
        if name.lower() == "triggeraxis":
            return self._axis_letter
        raise ValueError(f"no axis parameter {name!r}")

    def SetAxisExtraPar(self, axis: int, name: str, value: Any) -> None:
        """``TriggerAxis``: x, y, z or a (one the controller has).

        Raises
        ------
        ValueError
            Another parameter, or an axis the controller does not have.
        """
        if name.lower() != "triggeraxis":
            raise ValueError(f"no axis parameter {name!r}")
        letter = str(value).strip().lower()
        if letter not in "xyza"[: self.tango.identity.axes] or not letter:
            raise ValueError(f"TriggerAxis: the controller has no axis {value!r}")
        with self._lock:
            self._axis_letter, self._loaded = letter, False
