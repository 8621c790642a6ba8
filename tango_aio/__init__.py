"""tango_aio: an asyncio driver and emulator for Märzhäuser TANGO stepper-motor controllers.

This is the TANGO motion controller made by Märzhäuser Wetzlar (microscope stages,
positioning axes), not the "Tango Controls" SCADA toolkit.
"""

from .connection import connect
from .controller import Controller, Identity
from .errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    InvalidCommandError,
    MoveError,
    ProtocolError,
    RequestAbortedError,
    TangoError,
)
from .events import TangoEvent
from .group import ControllerGroup, discover

__all__ = [
    "ConnectionLostError",
    "Controller",
    "ControllerError",
    "ControllerGroup",
    "ControllerTimeoutError",
    "Identity",
    "InvalidCommandError",
    "MoveError",
    "ProtocolError",
    "RequestAbortedError",
    "TangoError",
    "TangoEvent",
    "connect",
    "discover",
]

__version__ = "0.1.0"
