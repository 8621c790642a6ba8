"""tango_aio: an asyncio driver and emulator for Märzhäuser TANGO stepper-motor controllers.

This is the TANGO motion controller made by Märzhäuser Wetzlar (microscope stages,
positioning axes), not the "Tango Controls" SCADA toolkit.
"""

from .errors import (
    ConnectionLostError,
    ControllerError,
    InvalidCommandError,
    MoveError,
    ProtocolError,
    TangoError,
)

__all__ = [
    "ConnectionLostError",
    "ControllerError",
    "InvalidCommandError",
    "MoveError",
    "ProtocolError",
    "TangoError",
]

__version__ = "0.1.0"
