"""tango_aio: an asyncio driver and emulator for Märzhäuser TANGO stepper-motor controllers.

This is the TANGO motion controller made by Märzhäuser Wetzlar (microscope stages,
positioning axes), not the "Tango Controls" SCADA toolkit.

Every error, event, group and upload class is importable from here
(``from tango_aio import MoveError, MoveFinished, GroupError, UploadError``). The blocking
API is :mod:`tango_aio.sync`, physical units are in :mod:`tango_aio.units`, the pytest
fixture in :mod:`tango_aio.testing`.
"""

from .bulk import UploadError
from .connection import (
    Connecting,
    ConnectOptions,
    connect,
)
from .controller import Controller, Identity
from .errors import (
    AmplifiersDisabledError,
    Aux24VOverloadError,
    AuxSupplyOverloadError,
    AxisCorrectionError,
    BrakeVoltageError,
    ClosedLoopOffError,
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    CpldDataError,
    EmergencyStopError,
    EncoderDetectedError,
    EncoderIsrError,
    EncoderSupplyOverloadError,
    EtsError,
    HdiDeviceError,
    HdiIsrError,
    InternalDataError,
    InvalidAxisNameError,
    InvalidCommandError,
    InvalidInstructionError,
    IoExtensionBusError,
    IoExtensionOverloadError,
    JoystickEnabledError,
    LimitSwitchActiveError,
    LineTooLongError,
    MissingPrefixError,
    MotorSupplyOverloadError,
    MoveError,
    MoveNotAllowedError,
    MultiAxisMoveForbiddenError,
    NoError,
    NotConfiguredError,
    NotExecutableError,
    OutOfRangeError,
    ProtocolError,
    RequestAbortedError,
    SafetyCircuitError,
    TangoError,
    TvrActiveError,
    TvrAxisActiveError,
    UnknownControllerError,
    WriteProtectedError,
    WrongParameterCountError,
    XposModuleError,
)
from .events import (
    ConnectionLost,
    MoveAborted,
    MoveFinished,
    PositionUpdate,
    Reconnected,
    StatusReport,
    Subscription,
    TangoEvent,
    UnsolicitedLine,
)
from .group import (
    ControllerGroup,
    DiscoveredController,
    GroupError,
    GroupEvent,
    GroupSubscription,
    discover,
)
from .reconnect import IdentityMismatchError, ReconnectPolicy
from .status import AxisStatus

__all__ = [
    "AmplifiersDisabledError",
    "Aux24VOverloadError",
    "AuxSupplyOverloadError",
    "AxisCorrectionError",
    "AxisStatus",
    "BrakeVoltageError",
    "ClosedLoopOffError",
    "ConnectOptions",
    "Connecting",
    "ConnectionLost",
    "ConnectionLostError",
    "Controller",
    "ControllerError",
    "ControllerGroup",
    "ControllerTimeoutError",
    "CpldDataError",
    "DiscoveredController",
    "EmergencyStopError",
    "EncoderDetectedError",
    "EncoderIsrError",
    "EncoderSupplyOverloadError",
    "EtsError",
    "GroupError",
    "GroupEvent",
    "GroupSubscription",
    "HdiDeviceError",
    "HdiIsrError",
    "Identity",
    "IdentityMismatchError",
    "InternalDataError",
    "InvalidAxisNameError",
    "InvalidCommandError",
    "InvalidInstructionError",
    "IoExtensionBusError",
    "IoExtensionOverloadError",
    "JoystickEnabledError",
    "LimitSwitchActiveError",
    "LineTooLongError",
    "MissingPrefixError",
    "MotorSupplyOverloadError",
    "MoveAborted",
    "MoveError",
    "MoveFinished",
    "MoveNotAllowedError",
    "MultiAxisMoveForbiddenError",
    "NoError",
    "NotConfiguredError",
    "NotExecutableError",
    "OutOfRangeError",
    "PositionUpdate",
    "ProtocolError",
    "ReconnectPolicy",
    "Reconnected",
    "RequestAbortedError",
    "SafetyCircuitError",
    "StatusReport",
    "Subscription",
    "TangoError",
    "TangoEvent",
    "TvrActiveError",
    "TvrAxisActiveError",
    "UnknownControllerError",
    "UnsolicitedLine",
    "UploadError",
    "WriteProtectedError",
    "WrongParameterCountError",
    "XposModuleError",
    "connect",
    "discover",
]

# Error and event classes added to their modules later are exported too (their modules'
# own __all__ lists are the source); the explicit imports above are for readers and IDEs.
from . import errors as _errors
from . import events as _events
from .errors import *  # noqa: F403
from .events import *  # noqa: F403

__all__ += [name for name in (*_errors.__all__, *_events.__all__)
            if name[0].isupper() and name not in __all__ and name != "ERROR_DESCRIPTIONS"
            and name != "EventHub"]

__version__ = "0.1.0"
