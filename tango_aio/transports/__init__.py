"""transports."""

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
