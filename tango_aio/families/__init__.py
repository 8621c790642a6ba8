"""The manual's families of instructions, each an object of its own on the controller.

Each family speaks to its controller through a :class:`FamilyPort` (read, proven write,
raw line) and never imports the controller; list transfers run at wire speed through
``ListTransfer``. The typed access of each chapter (``JoystickAccess``, ``IOAccess``...) is
generated from the catalog by ``tools/gen_families.py``; the families add their semantics
in subclasses.
"""

from __future__ import annotations

from ._access import ManualEnum
from ._base import Family, FamilyPort
from ._bulk import (
    MAX_TRIGGERS,
    Column,
    ListTransfer,
    Progress,
    UploadError,
    check_axis,
    check_resolution,
    snapshot_spec,
    trigger_spec,
    validate_rows,
    validate_trigger_positions,
)
from ._closed_loop import ClosedLoop, ClosedLoopMode
from ._encoders import Encoders
from ._generated import (
    ACCESS,
    HAND_MADE,
    AdjustmentsAccess,
    CalibrationAccess,
    ClosedLoopAccess,
    CommunicationAccess,
    ControllerInfoAccess,
    EncoderAccess,
    IOAccess,
    JoystickAccess,
    LimitSwitchAccess,
    MREncoderAccess,
    OperatingModesAccess,
    SnapshotAccess,
    SystemAccess,
    TriggerAccess,
)
from ._info import ControllerInfo, Info
from ._io import IO
from ._joystick import Joystick
from ._reach import DevicePort
from ._settings import RESTART_QUIET, Settings, convert_from, convert_to, reading_unit
from ._snapshot import SettingDifference, SettingsSnapshot
from ._snapshots import SnapshotConfig, SnapshotMode, Snapshots
from ._triggers import (
    MAX_TRIGGER_POSITION,
    TriggerConfig,
    TriggerMode,
    TriggerOutput,
    Triggers,
)

__all__ = [
    "ACCESS",
    "HAND_MADE",
    "IO",
    "MAX_TRIGGERS",
    "MAX_TRIGGER_POSITION",
    "RESTART_QUIET",
    "AdjustmentsAccess",
    "CalibrationAccess",
    "ClosedLoop",
    "ClosedLoopAccess",
    "ClosedLoopMode",
    "Column",
    "CommunicationAccess",
    "ControllerInfo",
    "ControllerInfoAccess",
    "DevicePort",
    "EncoderAccess",
    "Encoders",
    "Family",
    "FamilyPort",
    "IOAccess",
    "Info",
    "Joystick",
    "JoystickAccess",
    "LimitSwitchAccess",
    "ListTransfer",
    "MREncoderAccess",
    "ManualEnum",
    "OperatingModesAccess",
    "Progress",
    "SettingDifference",
    "Settings",
    "SettingsSnapshot",
    "SnapshotAccess",
    "SnapshotConfig",
    "SnapshotMode",
    "Snapshots",
    "SystemAccess",
    "TriggerAccess",
    "TriggerConfig",
    "TriggerMode",
    "TriggerOutput",
    "Triggers",
    "UploadError",
    "check_axis",
    "check_resolution",
    "convert_from",
    "convert_to",
    "reading_unit",
    "snapshot_spec",
    "trigger_spec",
    "validate_rows",
    "validate_trigger_positions",
]
