"""The sans-IO link: what a line on the wire means, decided without any I/O.

Bytes go in (``ProtocolCore.receive_data``), lines come out stamped with their arrival and
matched against the FIFO of replies the written requests owe (``_core.py``, shapes from
``_patterns.py``). ``_scheduler.py`` decides which request may be written next (credit from
``_flow.py``, separators between look-alike reads), ``_session.py`` holds the link's state
(an enum and one transition table: resync, mode exchange, overdue replies, keepalive), and
``_readback.py`` the read that proves a set. Each decision is an answer the asyncio layer
carries out; nothing here awaits, sleeps or reads a clock.
"""

from __future__ import annotations

from ._core import (
    LOCAL_ECHO,
    Acknowledged,
    Completed,
    Dropped,
    Echoed,
    Event,
    Mismatched,
    ProtocolCore,
    Replied,
    RequestLost,
    Unsolicited,
    is_completion_line,
)
from ._exchange import (
    STATUS_READ,
    Exchange,
    Until,
)
from ._expect import (
    expectation,
)
from ._flow import (
    DEFAULT_CHUNK,
    DEFAULT_LIMIT,
    CreditWindow,
)
from ._linkstate import (
    Barrier,
    ModeVerdict,
    Outcome,
    Overdue,
    Silence,
)
from ._linktiming import (
    LinkTiming,
    byte_time,
)
from ._readback import (
    ReadBack,
    mismatch,
    read_back,
)
from ._scheduler import (
    Line,
    Run,
    WriteScheduler,
)
from ._session import (
    DEAD_AFTER,
    LinkSession,
)
from ._state import (
    CACHED_SETTINGS,
    DriverState,
)

__all__ = [
    "CACHED_SETTINGS",
    "DEAD_AFTER",
    "DEFAULT_CHUNK",
    "DEFAULT_LIMIT",
    "LOCAL_ECHO",
    "STATUS_READ",
    "Acknowledged",
    "Barrier",
    "Completed",
    "CreditWindow",
    "DriverState",
    "Dropped",
    "Echoed",
    "Event",
    "Exchange",
    "Line",
    "LinkSession",
    "LinkTiming",
    "Mismatched",
    "ModeVerdict",
    "Outcome",
    "Overdue",
    "ProtocolCore",
    "ReadBack",
    "Replied",
    "RequestLost",
    "Run",
    "Silence",
    "Unsolicited",
    "Until",
    "WriteScheduler",
    "byte_time",
    "expectation",
    "is_completion_line",
    "mismatch",
    "read_back",
]
