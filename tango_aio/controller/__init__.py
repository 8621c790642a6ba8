"""controller."""

from __future__ import annotations

from ._connection import (
    DEFAULT_BAUD,
    Connecting,
    ConnectOptions,
    check_url,
    connect,
    open_link,
    port_error,
)
from ._controller import (
    Controller,
    Identity,
)
from ._motion import (
    STOP_WAIT,
)

__all__ = [
    "DEFAULT_BAUD",
    "STOP_WAIT",
    "ConnectOptions",
    "Connecting",
    "Controller",
    "Identity",
    "check_url",
    "connect",
    "open_link",
    "port_error",
]
