"""families."""

from __future__ import annotations

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
