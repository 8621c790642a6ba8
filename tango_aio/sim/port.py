"""What the emulator's instruction handlers use of the emulated controller.

:class:`~tango_aio.sim.handlers.Handlers` (and its mixin
:class:`~tango_aio.sim.peripherals.Peripherals`) act on a :class:`ModelPort`, which
:class:`~tango_aio.sim.model.ControllerModel` satisfies structurally. So the model imports
the handlers and the handlers import nothing of the model: the two modules make no cycle,
counting ``TYPE_CHECKING`` imports too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from ..catalog import Command
from .devices import Devices
from .lists import SnapshotList, TriggerList
from .motion import MotionConfig, MotionModel
from .params import ParamStore
from .profiles import Firmware

__all__ = ["ConfigView", "ModelPort", "SessionView"]


class ConfigView(Protocol):
    """The identity and static configuration the handlers read (``SimConfig``'s fields)."""

    @property
    def model(self) -> str:
        """The model name ``?version`` shows."""

    @property
    def version(self) -> str:
        """The firmware version number."""

    @property
    def build(self) -> str:
        """The build date ``?version`` shows."""

    @property
    def serial(self) -> str:
        """The serial number."""

    @property
    def det(self) -> int:
        """The ``?det`` value."""

    @property
    def state_file(self) -> Path | None:
        """Where ``save`` persists the saved parameters."""

    @property
    def motion(self) -> MotionConfig | None:
        """The motion model's configuration."""


class SessionView(Protocol):
    """The volatile state (cleared by a reset) the handlers read and change."""

    #: When the controller booted (``?uptime``).
    booted: float
    #: Keys latched by ``snse`` (``?keyl``).
    keys_latched: list[int]
    #: ``?drop``: drops counted since ``!drop 0``.
    drops: int
    #: ``clim``: centre X, centre Y, radius in user units.
    clim: tuple[float, float, float]
    #: Whether the circular limit is active.
    clim_active: bool
    #: Job ids of the moves snapshot steps started.
    snapshot_jobs: set[int]
    #: A change of the snapshot input before this time is not detected (``snsf``).
    snapshot_quiet_until: float


class ModelPort(Protocol):
    """The emulated controller as its instruction handlers see it."""

    #: The behaviour where the manual is silent.
    firmware: Firmware
    #: The motion model, the settings store and the trigger and snapshot lists.
    motion: MotionModel
    params: ParamStore
    triggers: TriggerList
    snapshots: SnapshotList
    #: I/O levels, encoders fitted and the pulses sent.
    devices: Devices
    #: Where the last cal of each axis completed, user frame, revolutions.
    cal_zero: list[float]
    #: The job id of the move the current line started.
    last_job: int | None

    @property
    def config(self) -> ConfigView:
        """Identity and static configuration."""

    @property
    def session(self) -> SessionView:
        """Volatile state that a reset clears."""

    @property
    def axes(self) -> int:
        """Number of configured axes."""

    @property
    def autostatus(self) -> int:
        """The current autostatus mode."""

    @property
    def error(self) -> int:
        """The current error number."""

    def trigger_pulses(self, time: float, count: int, position: float | None = None) -> None:
        """Record ``count`` trigger pulses as the trigger settings shape them."""

    def follow_joystick(self) -> None:
        """Drive the deflected axes as the HDI settings allow."""

    def present(self, command: Command) -> list[int]:
        """Axis indices a command addresses."""

    def axis_map(self, command: Command, skip_lead: int = 0) -> dict[int, float]:
        """A command's values by axis index, in user units."""

    def joystick_letters(self, letters: str) -> str:
        """Status letters as ``sa`` shows them while the joystick is on."""

    def report(self, letters: str) -> None:
        """Send a report that is not a move's."""

    def owe_stop_report(self) -> None:
        """Report once the axes stand (``a``)."""

    def set_autostatus(self, mode: int) -> None:
        """Switch the autostatus mode."""

    def clear_error(self) -> None:
        """``!err``: clear the error state."""

    def store(self, command: Command) -> None:
        """Keep a plain set command's values in the settings store."""

    def save(self) -> None:
        """``save``: persist the saved parameters."""

    def restore(self) -> None:
        """``restore``: reload the saved parameters."""

    def forget_saved(self) -> None:
        """``restore -1``: delete the saved parameters."""

    def reboot(self) -> None:
        """Restart like a power cycle."""

    def encoder_active(self, axis: int) -> bool:
        """``?enc`` of axis index ``axis``."""

    def encoder_position(self, axis: int) -> float:
        """The encoder's position of ``axis`` (user frame, revolutions)."""

    def trigger_axis(self) -> int:
        """The trigger axis's index."""

    def trigger_pointer(self) -> int:
        """``?trigi``: the list pointer (1-based)."""
