"""Exception hierarchy of tango_aio.

Every exception raised by the driver derives from :class:`TangoError`, and the class says
who failed:

* :class:`InvalidCommandError` (also a :class:`ValueError`): the caller's input was wrong.
  It is raised before a single byte is written.
* :class:`ControllerError`: the controller reported an error number. There is one subclass
  per number documented in the manual (chapter 5), registered automatically, so callers can
  ``except LimitSwitchActiveError``. Unknown numbers map to :class:`UnknownControllerError`.
* :class:`MoveError`: a move ended, but not at its target (per-axis status letters).
* :class:`ProtocolError`: the byte stream made no sense (over-long line, unexpected reply).
* :class:`ConnectionLostError`: the link went away; the cause is chained.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, ClassVar

__all__ = [
    "ERROR_DESCRIPTIONS",
    "INTERNAL_ERRORS",
    "AmplifiersDisabledError",
    "Aux24VOverloadError",
    "AuxSupplyOverloadError",
    "AxisCorrectionError",
    "BrakeVoltageError",
    "ClosedLoopOffError",
    "ConnectionLostError",
    "ControllerError",
    "ControllerTimeoutError",
    "CpldDataError",
    "EmergencyStopError",
    "EncoderDetectedError",
    "EncoderIsrError",
    "EncoderSupplyOverloadError",
    "EtsError",
    "HdiDeviceError",
    "HdiIsrError",
    "InternalControllerError",
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
    "MoveError",
    "MoveNotAllowedError",
    "MultiAxisMoveForbiddenError",
    "NoError",
    "NotConfiguredError",
    "NotExecutableError",
    "OutOfRangeError",
    "ProtocolError",
    "RequestAbortedError",
    "SafetyCircuitError",
    "TangoError",
    "TvrActiveError",
    "TvrAxisActiveError",
    "UnknownControllerError",
    "WriteProtectedError",
    "WrongParameterCountError",
    "XposModuleError",
    "controller_error",
    "error_class",
    "parse_error_reply",
]


class TangoError(Exception):
    """Base class of every error raised by tango_aio."""


class InvalidCommandError(TangoError, ValueError):
    """The caller's command is invalid; nothing was sent to the controller.

    ``instruction`` and ``parameter`` name what was wrong (either may be ``None`` when the
    line could not be attributed). ``code`` is the error number a real controller would set
    for the same line (1-7), which the emulator uses.
    """

    def __init__(
        self,
        message: str,
        *,
        instruction: str | None = None,
        parameter: str | None = None,
        code: int = 4,
    ) -> None:
        super().__init__(message)
        self.instruction = instruction
        self.parameter = parameter
        self.code = code


class ProtocolError(TangoError):
    """The controller's byte stream violated the protocol (e.g. an over-long line)."""


class ConnectionLostError(TangoError):
    """The connection to the controller is gone. ``__cause__`` holds the original error."""


class ControllerTimeoutError(TangoError, TimeoutError):
    """The controller did not answer within the allowed time."""


class RequestAbortedError(TangoError):
    """The request was discarded by the controller (Ctrl+C cleared its input buffer), or
    its reply was lost while the driver resynchronised the reply stream."""


class MoveError(TangoError):
    """A move, calibration or range measure ended with an error on at least one axis.

    ``statuses`` maps each present axis (``"x"``, ``"y"``, ...) to its status letter:
    ``E`` error/aborted, ``S`` limit switch, ``T`` timeout, ``@``/``A``/``D`` success.
    """

    def __init__(self, message: str, statuses: Mapping[str, str]) -> None:
        super().__init__(message)
        self.statuses: dict[str, str] = dict(statuses)

    def __reduce__(self) -> tuple[Any, ...]:
        # BaseException pickles as ``cls(*self.args)``, which lacks ``statuses``; the
        # instance dict (``statuses``, ``__notes__``...) is restored as the state.
        return type(self), (str(self), self.statuses), self.__dict__


class ControllerError(TangoError):
    """The controller reported error number ``code``.

    ``text`` is the manual's description of the number and ``command`` the command line
    that caused it (``None`` when unknown, e.g. for an internal error).
    """

    code: ClassVar[int] = -1
    description: ClassVar[str] = "unknown error"
    _registry: ClassVar[dict[int, type[ControllerError]]] = {}

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if cls.code >= 0:
            ControllerError._registry[cls.code] = cls

    def __init__(self, code: int | None = None, command: str | None = None) -> None:
        self.error_code: int = self.code if code is None else code
        self.command = command
        text = self.description
        where = f" (command {command!r})" if command else ""
        super().__init__(f"controller error {self.error_code}: {text}{where}")

    @property
    def text(self) -> str:
        """The manual's description of the error number."""
        return self.description

    def __reduce__(self) -> tuple[object, ...]:
        return (type(self), (self.error_code, self.command))


class UnknownControllerError(ControllerError):
    """An error number that the manual does not document."""


#: Error numbers from here on may be persistent internal conditions rather than the
#: result of the last instruction (manual L2853-2867: "typically no. 20 and above").
INTERNAL_ERRORS = 20


class InternalControllerError(ControllerError):
    """The controller is in a persistent internal error state (``error_code`` >= 20, e.g.
    29 amplifiers off) that ``?err`` reports although the last instruction was fine
    (manual L2853-2867). It is not the fault of any command (``command`` is ``None``);
    raised by :meth:`Controller.check_fault <tango_aio.controller.Controller.check_fault>`
    and announced by the :class:`~tango_aio.events.ControllerFault` event."""

    @property
    def text(self) -> str:
        """The manual's description of the error number."""
        return error_class(self.error_code).description

    def __init__(self, code: int | None = None, command: str | None = None) -> None:
        super().__init__(code, command)
        self.args = (f"controller reports internal error {self.error_code}: "
                     f"{error_class(self.error_code).description} (not caused by a command)",)


# One class per error number of the manual (firmware 1.71, chapter 5, L961-1034).


class NoError(ControllerError):
    """Controller error 0: no error."""

    code = 0
    description = "no error"


class InvalidAxisNameError(ControllerError):
    """Controller error 1: no valid axis name."""

    code = 1
    description = "no valid axis name"


class NotExecutableError(ControllerError):
    """Controller error 2: no executable instruction."""

    code = 2
    description = "no executable instruction"


class LineTooLongError(ControllerError):
    """Controller error 3: too many characters in command line."""

    code = 3
    description = "too many characters in command line"


class InvalidInstructionError(ControllerError):
    """Controller error 4: invalid instruction."""

    code = 4
    description = "invalid instruction"


class OutOfRangeError(ControllerError):
    """Controller error 5: number is not inside allowed range."""

    code = 5
    description = "number is not inside allowed range"


class WrongParameterCountError(ControllerError):
    """Controller error 6: wrong number of parameters."""

    code = 6
    description = "wrong number of parameters"


class MissingPrefixError(ControllerError):
    """Controller error 7: either ! or ? is missing."""

    code = 7
    description = "either ! or ? is missing"


class TvrAxisActiveError(ControllerError):
    """Controller error 8: no TVR possible, while axis active."""

    code = 8
    description = "no TVR possible, while axis active"


class TvrActiveError(ControllerError):
    """Controller error 9: no ON or OFF of axis possible, while TVR active."""

    code = 9
    description = "no ON or OFF of axis possible, while TVR active"


class NotConfiguredError(ControllerError):
    """Controller error 10: function not configured."""

    code = 10
    description = "function not configured"


class JoystickEnabledError(ControllerError):
    """Controller error 11: no move instruction possible, while joystick enabled."""

    code = 11
    description = "no move instruction possible, while joystick enabled"


class LimitSwitchActiveError(ControllerError):
    """Controller error 12: limit switch active."""

    code = 12
    description = "limit switch active"


class EncoderDetectedError(ControllerError):
    """Controller error 13: function not executable, because encoder detected."""

    code = 13
    description = "function not executable, because encoder detected"


class MultiAxisMoveForbiddenError(ControllerError):
    """Controller error 21: multiple axis moves are forbidden (e.g. during initialization)."""

    code = 21
    description = "multiple axis moves are forbidden (e.g. during initialization)"


class MoveNotAllowedError(ControllerError):
    """Controller error 22: automatic or manual move is not allowed (door open, init)."""

    code = 22
    description = "automatic or manual move is not allowed (e.g. door open or initialization)"


class EmergencyStopError(ControllerError):
    """Controller error 27: emergency STOP is active."""

    code = 27
    description = "emergency STOP is active"


class AmplifiersDisabledError(ControllerError):
    """Controller error 29: servo amplifiers are disabled (switched OFF)."""

    code = 29
    description = "servo amplifiers are disabled (switched OFF)"


class SafetyCircuitError(ControllerError):
    """Controller error 30: safety circuit out of order."""

    code = 30
    description = "safety circuit out of order"


class CpldDataError(ControllerError):
    """Controller error 70: wrong CPLD data."""

    code = 70
    description = "wrong CPLD data"


class EtsError(ControllerError):
    """Controller error 71: ETS error."""

    code = 71
    description = "ETS error"


class WriteProtectedError(ControllerError):
    """Controller error 72: parameter is write protected (check lock bits)."""

    code = 72
    description = "parameter is write protected (check lock bits)"


class InternalDataError(ControllerError):
    """Controller error 73: internal error, e.g. eeprom data corruption."""

    code = 73
    description = "internal error, e.g. eeprom data corruption"


class ClosedLoopOffError(ControllerError):
    """Controller error 74: closed loop switched off due to parameter change."""

    code = 74
    description = "closed loop switched off due to parameter change"


class AxisCorrectionError(ControllerError):
    """Controller error 75: could not enable axis correction, or axis correction was disabled."""

    code = 75
    description = "could not enable axis correction, or axis correction was disabled"


class IoExtensionOverloadError(ControllerError):
    """Controller error 76: io extension error (output overload on IO1 or Multi-IO connector)."""

    code = 76
    description = "io extension error (output overload on IO1 or Multi-IO connector)"


class IoExtensionBusError(ControllerError):
    """Controller error 77: io extension internal communication error (internal bus error)."""

    code = 77
    description = "io extension internal communication error (internal bus error)"


class HdiDeviceError(ControllerError):
    """Controller error 78: HDI input device error."""

    code = 78
    description = "HDI input device error"


class XposModuleError(ControllerError):
    """Controller error 79: xPos module error."""

    code = 79
    description = "xPos module error"


class HdiIsrError(ControllerError):
    """Controller error 80: internal error: HDI ISR not running."""

    code = 80
    description = "internal error: HDI ISR not running"


class EncoderIsrError(ControllerError):
    """Controller error 81: internal error: Encoder ISR not running."""

    code = 81
    description = "internal error: Encoder ISR not running"


class MotorSupplyOverloadError(ControllerError):
    """Controller error 82: overload on motor connector +5V."""

    code = 82
    description = "overload on motor connector +5V"


class AuxSupplyOverloadError(ControllerError):
    """Controller error 83: overload on AUX I/O +5V supply."""

    code = 83
    description = "overload on AUX I/O +5V supply"


class EncoderSupplyOverloadError(ControllerError):
    """Controller error 84: overload on encoder +5V supply."""

    code = 84
    description = "overload on encoder +5V supply"


class Aux24VOverloadError(ControllerError):
    """Controller error 85: overload on AUX I/O +24V supply."""

    code = 85
    description = "overload on AUX I/O +24V supply"


class BrakeVoltageError(ControllerError):
    """Controller error 86: low brake output voltage."""

    code = 86
    description = "low brake output voltage"


#: Documented error numbers and their descriptions.
ERROR_DESCRIPTIONS: dict[int, str] = {
    number: cls.description for number, cls in ControllerError._registry.items()
}

def error_class(code: int) -> type[ControllerError]:
    """Return the :class:`ControllerError` subclass for error number ``code``."""
    return ControllerError._registry.get(code, UnknownControllerError)


def controller_error(code: int, command: str | None = None) -> ControllerError:
    """Build the typed exception for controller error number ``code``."""
    return error_class(code)(code, command)


_ERR_RE = re.compile(r"^\s*(?:ERR(?:OR)?\s*(-?\d+)?\s*(?:,\s*(.*))?|(-?\d+))\s*$")


def parse_error_reply(line: str) -> tuple[int | None, str | None]:
    """Parse an error report into ``(number, text)``.

    Accepts the three forms the controller uses: a bare number (``?err`` → ``5``), an
    acknowledgement (``ERR 5`` or plain ``ERR``, autostatus 2 and ``save``) and a ``help``
    line (``ERROR 5,number outside range``). ``OK...`` gives ``(0, None)``. The number is
    ``None`` when the controller sent ``ERR`` without one.

    Raises :class:`ProtocolError` for anything else.
    """
    stripped = line.strip()
    if stripped.startswith("OK"):
        return 0, None
    match = _ERR_RE.match(stripped)
    if match is None:
        raise ProtocolError(f"not an error report: {line!r}")
    number = match.group(1) if match.group(1) is not None else match.group(3)
    return (int(number) if number is not None else None), match.group(2)
