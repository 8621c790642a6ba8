"""link."""

from __future__ import annotations

from ._protocol import (
    DEAD_AFTER,
    MoveHandle,
    Response,
    Submission,
    TangoProtocol,
    traced,
    wire_log,
)
from ._reconnect import (
    Closer,
    Reconnect,
    Reconnector,
    ReconnectPolicy,
    Signature,
)

__all__ = [
    "DEAD_AFTER",
    "Closer",
    "MoveHandle",
    "Reconnect",
    "ReconnectPolicy",
    "Reconnector",
    "Response",
    "Signature",
    "Submission",
    "TangoProtocol",
    "traced",
    "wire_log",
]
