"""Serial-port transports for asyncio (the network and the emulator use asyncio's own).

``FdTransport`` reads and writes a POSIX port's descriptor from the event loop;
``ThreadTransport`` runs pyserial's blocking calls in a reader and a writer thread on
Windows. Both share ``PortTransport``'s bookkeeping and close. They import only the leaves.
"""

from __future__ import annotations

from ._fdlink import (
    FdTransport,
)
from ._threadlink import (
    ThreadTransport,
)

__all__ = [
    "FdTransport",
    "ThreadTransport",
]
