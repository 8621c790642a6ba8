"""The asyncio link: one protocol per connection, carrying out the sans-IO decisions.

``TangoProtocol`` feeds received bytes to the core, resolves each request's future with
its reply, arms the timers the session asks for and writes what the scheduler releases;
it holds no rule of its own. ``Reconnector`` reopens a lost link under a
``ReconnectPolicy``, seeing the controller only through its ``ReconnectPort``.
"""

from __future__ import annotations

from ._protocol import (
    DEAD_AFTER,
    MoveHandle,
    Response,
    Submission,
    TangoProtocol,
)
from ._reconnect import (
    Closer,
    Reconnect,
    Reconnector,
    ReconnectPolicy,
    Signature,
)
from ._router import traced, wire_log

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
