"""The manual's families of instructions, each an object of its own on the controller.

Each family speaks to its controller through a :class:`FamilyPort` (read, proven write,
raw line) and never imports the controller; list transfers run at wire speed through
``ListTransfer``.
"""

from __future__ import annotations

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
from ._io import IO
from ._joystick import Joystick
from ._reach import DevicePort
from ._snapshots import SnapshotConfig, SnapshotMode, Snapshots
from ._triggers import (
    MAX_TRIGGER_POSITION,
    TriggerConfig,
    TriggerMode,
    TriggerOutput,
    Triggers,
)

__all__ = [
    "IO",
    "MAX_TRIGGERS",
    "MAX_TRIGGER_POSITION",
    "ClosedLoop",
    "ClosedLoopMode",
    "Column",
    "DevicePort",
    "Encoders",
    "Family",
    "FamilyPort",
    "Joystick",
    "ListTransfer",
    "Progress",
    "SnapshotConfig",
    "SnapshotMode",
    "Snapshots",
    "TriggerConfig",
    "TriggerMode",
    "TriggerOutput",
    "Triggers",
    "UploadError",
    "check_axis",
    "check_resolution",
    "snapshot_spec",
    "trigger_spec",
    "validate_rows",
    "validate_trigger_positions",
]
