"""tango_aio: an asyncio driver and emulator for Märzhäuser TANGO stepper-motor controllers.

This is the TANGO motion controller made by Märzhäuser Wetzlar (microscope stages,
positioning axes), not the "Tango Controls" SCADA toolkit.

Every error, event, group and upload class is importable from here
(``from tango_aio import MoveError, MoveFinished, GroupError, UploadError``). The blocking
API is :mod:`tango_aio.sync`, physical units are in :mod:`tango_aio.units`, the pytest
fixture in :mod:`tango_aio.testing`.
"""

# Theory of operation: the names below are imported on first use (PEP 562), not when the
# package is imported. ``import tango_aio.sim`` or the ``tango-aio`` command then pays only
# for what it uses, and the command line installs its Ctrl+C handling before the heavy
# modules load (an interrupt during start-up ends quietly). Type checkers and
# IDEs read the explicit imports in the TYPE_CHECKING block; a test keeps that block,
# ``__all__`` and ``_HOMES`` in step.

from __future__ import annotations

import importlib
import sys
from typing import TYPE_CHECKING, Any

if getattr(sys, "argv", None) and \
        sys.argv[0].replace("\\", "/").rpartition("/")[2].startswith("tango-aio"):
    # This process is the ``tango-aio`` command (its console script, tango-aio.exe on
    # Windows): quiet Ctrl+C from here on, before anything heavy loads.
    from . import _startup

    _startup.install()

if TYPE_CHECKING:
    from .controller import (
        Connecting,
        ConnectOptions,
        Controller,
        Identity,
        connect,
    )
    from .errors import (
        AmplifiersDisabledError,
        Aux24VOverloadError,
        AuxSupplyOverloadError,
        AxisCorrectionError,
        BrakeVoltageError,
        ClosedLoopOffError,
        ClosedLoopPreconditionError,
        CommandRejectedError,
        ConnectError,
        ConnectionLostError,
        ControllerError,
        ControllerTimeoutError,
        CpldDataError,
        EmergencyStopError,
        EncoderDetectedError,
        EncoderIsrError,
        EncoderSupplyOverloadError,
        EtsError,
        GarbledVerdictError,
        HardwareFaultError,
        HdiDeviceError,
        HdiIsrError,
        IdentityMismatchError,
        InternalControllerError,
        InternalDataError,
        InvalidAxisNameError,
        InvalidCommandError,
        InvalidInstructionError,
        IoExtensionBusError,
        IoExtensionOverloadError,
        JoystickEnabledError,
        LimitSwitchActiveError,
        LineTooLongError,
        MissingAxisError,
        MissingPrefixError,
        MotorRefusedError,
        MotorSupplyOverloadError,
        MoveAbortedUnknownError,
        MoveError,
        MoveLinkLostUnknownError,
        MoveNotAllowedError,
        MoveOutcomeUnknown,
        MoveProtocolUnknownError,
        MoveStoppedError,
        MoveTimeoutUnknownError,
        MultiAxisMoveForbiddenError,
        NoControllerError,
        NoError,
        NotConfiguredError,
        NotExecutableError,
        NotSupportedByFirmwareError,
        OutOfRangeError,
        PortBusyError,
        PortNotFoundError,
        PortPermissionError,
        ProbeError,
        ProtocolError,
        RequestAbortedError,
        SafetyCircuitError,
        SettingNotAppliedError,
        SettingsRestoreError,
        SnapshotMismatchError,
        StageLimitsError,
        StateError,
        TangoError,
        TvrActiveError,
        TvrAxisActiveError,
        UnknownControllerError,
        UploadError,
        WriteProtectedError,
        WrongEventLoopError,
        WrongParameterCountError,
        XposModuleError,
    )
    from .events import (
        ConnectionLost,
        ControllerFault,
        ControllerRestarted,
        InputsChanged,
        JoystickMoved,
        MoveAborted,
        MoveFinished,
        PositionUpdate,
        Reconnected,
        StatusReport,
        Subscription,
        TangoEvent,
        UnsolicitedLine,
    )
    from .families import (
        ClosedLoopMode,
        SnapshotConfig,
        SnapshotMode,
        TriggerConfig,
        TriggerMode,
        TriggerOutput,
    )
    from .group import (
        ControllerGroup,
        DiscoveredController,
        GroupError,
        GroupEvent,
        GroupSubscription,
        PortProbe,
        discover,
        probe_ports,
    )
    from .link import ReconnectPolicy
    from .status import AxisStatus

__all__ = [
    "AmplifiersDisabledError",
    "Aux24VOverloadError",
    "AuxSupplyOverloadError",
    "AxisCorrectionError",
    "AxisStatus",
    "BrakeVoltageError",
    "ClosedLoopMode",
    "ClosedLoopOffError",
    "ClosedLoopPreconditionError",
    "CommandRejectedError",
    "ConnectError",
    "ConnectOptions",
    "Connecting",
    "ConnectionLost",
    "ConnectionLostError",
    "Controller",
    "ControllerError",
    "ControllerFault",
    "ControllerGroup",
    "ControllerRestarted",
    "ControllerTimeoutError",
    "CpldDataError",
    "DiscoveredController",
    "EmergencyStopError",
    "EncoderDetectedError",
    "EncoderIsrError",
    "EncoderSupplyOverloadError",
    "EtsError",
    "GarbledVerdictError",
    "GroupError",
    "GroupEvent",
    "GroupSubscription",
    "HardwareFaultError",
    "HdiDeviceError",
    "HdiIsrError",
    "Identity",
    "IdentityMismatchError",
    "InputsChanged",
    "InternalControllerError",
    "InternalDataError",
    "InvalidAxisNameError",
    "InvalidCommandError",
    "InvalidInstructionError",
    "IoExtensionBusError",
    "IoExtensionOverloadError",
    "JoystickEnabledError",
    "JoystickMoved",
    "LimitSwitchActiveError",
    "LineTooLongError",
    "MissingAxisError",
    "MissingPrefixError",
    "MotorRefusedError",
    "MotorSupplyOverloadError",
    "MoveAborted",
    "MoveAbortedUnknownError",
    "MoveError",
    "MoveFinished",
    "MoveLinkLostUnknownError",
    "MoveNotAllowedError",
    "MoveOutcomeUnknown",
    "MoveProtocolUnknownError",
    "MoveStoppedError",
    "MoveTimeoutUnknownError",
    "MultiAxisMoveForbiddenError",
    "NoControllerError",
    "NoError",
    "NotConfiguredError",
    "NotExecutableError",
    "NotSupportedByFirmwareError",
    "OutOfRangeError",
    "PortBusyError",
    "PortNotFoundError",
    "PortPermissionError",
    "PortProbe",
    "PositionUpdate",
    "ProbeError",
    "ProtocolError",
    "ReconnectPolicy",
    "Reconnected",
    "RequestAbortedError",
    "SafetyCircuitError",
    "SettingNotAppliedError",
    "SettingsRestoreError",
    "SnapshotConfig",
    "SnapshotMismatchError",
    "SnapshotMode",
    "StageLimitsError",
    "StateError",
    "StatusReport",
    "Subscription",
    "TangoError",
    "TangoEvent",
    "TriggerConfig",
    "TriggerMode",
    "TriggerOutput",
    "TvrActiveError",
    "TvrAxisActiveError",
    "UnknownControllerError",
    "UnsolicitedLine",
    "UploadError",
    "WriteProtectedError",
    "WrongEventLoopError",
    "WrongParameterCountError",
    "XposModuleError",
    "connect",
    "discover",
    "probe_ports",
]

#: The modules that define the names of ``__all__``, searched in this order (each module's
#: own ``__all__`` says what it exports).
_HOMES = ("errors", "events", "status", "link", "families", "controller", "group")

__version__ = "0.5.0"


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (PEP 562)."""
    if name in __all__:
        for home in _HOMES:
            module = importlib.import_module(f".{home}", __name__)
            if name in getattr(module, "__all__", ()):
                value = getattr(module, name)
                globals()[name] = value
                return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
