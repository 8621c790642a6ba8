"""The controller facade: identity, connection, moves and events.

``connect`` opens a link (serial, ``socket://``, ``sim://``) and sets the controller up;
``Controller`` checks each call's input before a byte is written, runs moves through
``Motion`` (which sees it through ``MotionPort``), publishes events, and holds the family
objects; ``RestartWatch`` notices a controller that restarted behind a live link.
"""

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
)
from ._motion import (
    STOP_WAIT,
)
from ._reads import (
    Identity,
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
