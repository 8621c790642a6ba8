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

__all__ = [
    "MAX_TRIGGERS",
    "Column",
    "Family",
    "FamilyPort",
    "ListTransfer",
    "Progress",
    "UploadError",
    "check_axis",
    "check_resolution",
    "snapshot_spec",
    "trigger_spec",
    "validate_rows",
    "validate_trigger_positions",
]
