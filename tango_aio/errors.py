"""Exception hierarchy of tango_aio.

Every exception raised by the driver derives from :class:`TangoError`, and the class says
who failed:

* :class:`InvalidCommandError` (also a :class:`ValueError`): the caller's input was wrong.
  It is raised before a single byte is written.
* :class:`ControllerError`: the controller reported an error number (``.number``, with the
  manual's ``.text`` and the ``.command`` line). There is one subclass per number
  documented in the manual (chapter 5), registered automatically, so callers can
  ``except LimitSwitchActiveError``, and each is in one category:
  :class:`CommandRejectedError` (1-7), :class:`StateError` (8-30) or
  :class:`HardwareFaultError` (70-86). Unknown numbers map to
  :class:`UnknownControllerError`.
* :class:`MoveError`: a move ended, but not at its target (per-axis status letters).
* :class:`MoveOutcomeUnknown`: a motion call failed after its line was written and the
  controller may have executed it (a timeout, a lost answer or link); read the position
  before repeating the move.
* :class:`SettingNotAppliedError`: a set line got no error, but the read behind it shows
  another value (autostatus 0, 1, 3: the line may have been lost).
* :class:`ProtocolError`: the byte stream made no sense (over-long line, unexpected reply;
  :class:`GarbledVerdictError`: the reply that judges a line was garbled).
* :class:`ConnectionLostError`: a working link went away; the cause is chained
  (:class:`IdentityMismatchError`: a different controller answered after a reconnect).
* :class:`ConnectError`: a link could not be set up at all, one subclass per reason with
  the next step in its message: :class:`PortNotFoundError`, :class:`PortPermissionError`,
  :class:`PortBusyError`, :class:`NoControllerError`.
* The errors of one surface, each defined here and re-exported by its module:
  :class:`UploadError` (list uploads, :mod:`tango_aio.families._bulk`), :class:`ProbeError`
  (``tango-aio probe``), :class:`MotorRefusedError` and :class:`MoveStoppedError` (the
  EPICS IOC), :class:`StageLimitsError` and :class:`MissingAxisError` (the Bluesky
  devices).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, ClassVar, cast

__all__ = [
    "CATEGORIES",
    "ERROR_DESCRIPTIONS",
    "INTERNAL_ERRORS",
    "AmplifiersDisabledError",
    "Aux24VOverloadError",
    "AuxSupplyOverloadError",
    "AxisCorrectionError",
    "BrakeVoltageError",
    "ClosedLoopOffError",
    "ClosedLoopPreconditionError",
    "CommandRejectedError",
    "ConnectError",
    "ConnectionLostError",
    "ControllerError",
    "ControllerTimeoutError",
    "CpldDataError",
    "EmergencyStopError",
    "EncoderDetectedError",
    "EncoderIsrError",
    "EncoderSupplyOverloadError",
    "EtsError",
    "GarbledVerdictError",
    "HardwareFaultError",
    "HdiDeviceError",
    "HdiIsrError",
    "IdentityMismatchError",
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
    "MissingAxisError",
    "MissingPrefixError",
    "MotorRefusedError",
    "MotorSupplyOverloadError",
    "MoveAbortedUnknownError",
    "MoveError",
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
    "ProbeError",
    "ProtocolError",
    "RequestAbortedError",
    "SafetyCircuitError",
    "SettingNotAppliedError",
    "SettingsRestoreError",
    "SnapshotMismatchError",
    "StageLimitsError",
    "StateError",
    "TangoError",
    "TvrActiveError",
    "TvrAxisActiveError",
    "UnknownControllerError",
    "UploadError",
    "WriteProtectedError",
    "WrongEventLoopError",
    "WrongParameterCountError",
    "XposModuleError",
    "controller_error",
    "error_class",
    "outcome_unknown",
    "parse_error_reply",
]


class TangoError(Exception):
    """Base class of every error raised by tango_aio."""


class InvalidCommandError(TangoError, ValueError):
    """The caller's command is invalid; nothing was sent to the controller.

    Parameters
    ----------
    message
        What was wrong, in words.
    instruction
        The instruction it concerns (``None``: the line could not be attributed).
    parameter
        The parameter it concerns (``None``: not one parameter).
    number
        The error number a real controller would set for the same line (1-7), which the
        emulator uses.
    """

    def __init__(
        self,
        message: str,
        *,
        instruction: str | None = None,
        parameter: str | None = None,
        number: int = 4,
    ) -> None:
        super().__init__(message)
        self.instruction = instruction
        self.parameter = parameter
        self.number = number


class ProtocolError(TangoError):
    """The controller's byte stream violated the protocol (e.g. an over-long line)."""


class GarbledVerdictError(ProtocolError):
    """The reply that judges a line (the ``?err`` behind it, its autostatus-2
    acknowledgement) is neither a clean error number the manual documents nor a clean
    acknowledgement (e.g. ``07``, ``ERR 35``): it proves nothing about the line, which
    may or may not have been executed. ``command`` is the line, ``reply`` that reply.

    Parameters
    ----------
    command
        The line the reply judges.
    reply
        The reply, as received.
    message
        The message (``None``: says what the reply was).
    """

    def __init__(self, command: str, reply: str, message: str | None = None) -> None:
        super().__init__(message or (
            f"the verdict on {command!r} was {reply!r}, neither a documented error number "
            "nor an acknowledgement: it says nothing of the line"))
        self.command = command
        self.reply = reply

    def __reduce__(self) -> tuple[Any, ...]:
        # As MoveError's: BaseException pickles as ``cls(*self.args)``.
        return type(self), (self.command, self.reply, str(self)), self.__dict__


class ConnectionLostError(TangoError):
    """The connection to the controller is gone. ``__cause__`` holds the original error."""


class IdentityMismatchError(ConnectionLostError):
    """After a reconnect a different controller answered (model, firmware or axes changed);
    the driver stopped reconnecting."""


class ControllerTimeoutError(TangoError, TimeoutError):
    """The controller did not answer within the allowed time."""


class WrongEventLoopError(TangoError, RuntimeError):
    """A connection was used from another event loop than the one it was opened on
    (re-exported by :mod:`tango_aio.link._protocol`)."""


class ConnectError(TangoError):
    """:func:`~tango_aio.connect` could not set up a link (as opposed to
    :class:`ConnectionLostError`, a working link that went away). The message says what
    to do next; ``__cause__`` holds the operating system's error, if any.

    Parameters
    ----------
    message
        What went wrong and what to do next.
    url
        What was being opened.
    """

    def __init__(self, message: str, url: str = "") -> None:
        super().__init__(message)
        self.url = url

    def __reduce__(self) -> tuple[Any, ...]:
        return type(self), (str(self), self.url), self.__dict__


class PortNotFoundError(ConnectError):
    """The serial port does not exist (unplugged, or a mistyped name)."""


class PortPermissionError(ConnectError):
    """This user may not open the serial port (on Linux: not in the ``dialout`` group)."""


class PortBusyError(ConnectError):
    """Another program (or another :func:`~tango_aio.connect`) holds the serial port."""


class NoControllerError(ConnectError, ControllerTimeoutError):
    """The link opened, but no TANGO answered on it (switched off, wrong port, wrong baud
    rate). Also a :class:`ControllerTimeoutError`, which is what nothing answering is."""


class RequestAbortedError(TangoError):
    """The request was discarded by the controller (Ctrl+C cleared its input buffer), or
    its reply was lost while the driver resynchronised the reply stream."""


class MoveError(TangoError):
    """A move, calibration or range measure ended with an error on at least one axis.

    Parameters
    ----------
    message
        Which axis failed, where it stopped and why.
    statuses
        Each present axis (``"x"``, ``"y"``, ...) and its status letter: ``E``
        error/aborted, ``S`` limit switch, ``T`` timeout, ``@``/``A``/``D`` success.
    """

    def __init__(self, message: str, statuses: Mapping[str, str]) -> None:
        super().__init__(message)
        self.statuses: dict[str, str] = dict(statuses)

    def __reduce__(self) -> tuple[Any, ...]:
        # BaseException pickles as ``cls(*self.args)``, which lacks ``statuses``; the
        # instance dict (``statuses``, ``__notes__``...) is restored as the state.
        return type(self), (str(self), self.statuses), self.__dict__


class MoveOutcomeUnknown(TangoError):
    """A motion call failed after its line was written, and the controller may have
    executed it: the stage may have moved. Do not retry blindly: read the position first.
    The driver stopped the axes the line addressed where it could.

    Never raised as such: the error raised is also the class that says what went wrong
    (:class:`MoveTimeoutUnknownError`, :class:`MoveAbortedUnknownError`,
    :class:`MoveProtocolUnknownError`, :class:`MoveLinkLostUnknownError`), so that
    ``except ControllerTimeoutError`` still catches a timeout. ``command`` is the line
    (e.g. ``'!mor 0.5'``); the message is the original error's, with what it means; its
    ``__cause__`` is the original error's cause (e.g. a link's reset)."""

    command: str = ""


class MoveTimeoutUnknownError(MoveOutcomeUnknown, ControllerTimeoutError):
    """A motion line's answer did not come in time; it may have been executed (a
    controller that restarted behind the link answers in another mode)."""


class MoveAbortedUnknownError(MoveOutcomeUnknown, RequestAbortedError):
    """A motion line's answer was lost in a resync; the line may have been executed."""


class MoveProtocolUnknownError(MoveOutcomeUnknown, ProtocolError):
    """A motion line's answer made no sense; the line may have been executed."""


class MoveLinkLostUnknownError(MoveOutcomeUnknown, ConnectionLostError):
    """The link went away after a motion line was written; it may have been executed."""


_OUTCOME_UNKNOWN: tuple[tuple[type[TangoError], type[MoveOutcomeUnknown]], ...] = (
    (ControllerTimeoutError, MoveTimeoutUnknownError),
    (RequestAbortedError, MoveAbortedUnknownError),
    (ProtocolError, MoveProtocolUnknownError),
    (ConnectionLostError, MoveLinkLostUnknownError),
)


def outcome_unknown(error: TangoError, command: str) -> TangoError:
    """``error`` (raised for the motion line ``command`` after it was written) as the
    :class:`MoveOutcomeUnknown` class of its kind, the same message with what it means
    appended; ``error`` itself if it is of none of those kinds or says so already. Raise
    the result ``from error.__cause__``.

    Parameters
    ----------
    error
        What the motion call raised.
    command
        The motion line.

    Returns
    -------
    TangoError
        The error to raise.
    """
    if isinstance(error, MoveOutcomeUnknown):
        return error
    for kind, unknown in _OUTCOME_UNKNOWN:
        if isinstance(error, kind):
            wrapped = unknown(f"{error} (the controller may have executed {command!r}: "
                              f"read the position before repeating the move)")
            wrapped.command = command
            return wrapped
    return error


class SettingNotAppliedError(TangoError):
    """A set line was answered without an error, but the read behind it shows that the
    controller does not hold the value written: the setting may not have been applied
    (the line was lost on the way, or the controller clamped or rounded the value).

    Raised in the autostatus modes whose set lines owe no answer of their own (0, 1 and
    3), where only a read-back proves a set (:mod:`tango_aio.sansio._readback`).

    Parameters
    ----------
    command
        The set line (``'!vel x 55.5'``).
    instruction
        Its instruction (``'vel'``).
    axis
        The one axis the line named (``None``: none, or several in order).
    sent
        The values written, as text (``'55.5'``).
    read
        The read-back (``'?vel x'``).
    held
        Its reply, as the controller printed it (``'10.000'``).
    """

    def __init__(self, command: str, *, instruction: str, axis: str | None, sent: str,
                 read: str, held: str) -> None:
        where = f"{instruction} {axis.upper()}" if axis else instruction
        super().__init__(
            f"the setting may not have been applied: {command!r} sent {sent} for {where}, "
            f"but {read!r} reads {held!r} (the line was lost on the way, or the "
            f"controller clamped or rounded the value)")
        self.command = command
        self.instruction = instruction
        self.axis = axis
        self.sent = sent
        self.read = read
        self.held = held

    def __reduce__(self) -> tuple[Any, ...]:
        return _rebuild_setting_error, (type(self), self.command, self.instruction,
                                        self.axis, self.sent, self.read, self.held), \
            self.__dict__


def _rebuild_setting_error(cls: type[SettingNotAppliedError], command: str,
                           instruction: str, axis: str | None, sent: str, read: str,
                           held: str) -> SettingNotAppliedError:
    return cls(command, instruction=instruction, axis=axis, sent=sent, read=read, held=held)


# -- the errors of one surface (each module re-exports its own) --------------------------


class UploadError(TangoError):
    """An entry of a list upload was rejected by the controller.

    ``__cause__`` is the typed :class:`ControllerError`. The list on the controller then
    holds the entries before ``index``.

    Parameters
    ----------
    index
        The 0-based index of the first rejected entry.
    number
        The controller's error number.
    command
        The rejected line.
    """

    def __init__(self, index: int, number: int, command: str) -> None:
        super().__init__(f"entry {index} ({command!r}) was rejected with error {number}")
        self.index = index
        self.number = number
        self.command = command


class ProbeError(TangoError):
    """The probe could not go on (the controller stopped answering, or it answered in a
    way the probe cannot follow). Its text says what it saw; ``trace`` is the wire trace
    up to there (filled in by :func:`~tango_aio.fieldkit.probe`)."""

    trace: str = ""


class MotorRefusedError(TangoError, ValueError):
    """A motor-record request that was refused before anything was sent (a target
    outside the limits, SPMG in Stop or Pause, the link down)."""


class MoveStoppedError(TangoError):
    """The move was stopped (STOP, SPMG, or a newer VAL) before it reached its target:
    the put fails, but the record raises no alarm (a user's stop is not a fault)."""


class StageLimitsError(InvalidCommandError):
    """A target lies outside the axis's travel limits (``?lim``); nothing was moved."""


class MissingAxisError(TangoError, LookupError):
    """The controller does not have an axis the device was asked to provide."""


class ClosedLoopPreconditionError(TangoError):
    """Closed loop cannot be switched on for an axis: what it needs is missing (the
    encoder's enable mask ``encmask`` or an active encoder ``enc``; manual L11761-11800).
    Nothing was written.

    Parameters
    ----------
    message
        What is missing, in words.
    axis
        The axis.
    missing
        The instruction whose setting is missing (``"encmask"`` or ``"enc"``).
    """

    def __init__(self, message: str, *, axis: str, missing: str) -> None:
        super().__init__(message)
        self.axis = axis
        self.missing = missing


class ControllerError(TangoError):
    """The controller reported error number :attr:`number`.

    Three attributes, on every controller error:

    * ``number``: the controller's error number (the class attribute of the same name is
      the class's own number, -1 for a class that stands for several);
    * ``text``: the manual's text for the number (chapter 5, L961-1034);
    * ``command``: the command line that caused it (``None`` when unknown, e.g. for an
      internal error).

    The documented numbers fall into categories, each a class to catch (in the spirit of
    SQLSTATE classes): :class:`CommandRejectedError` (1-7, the line itself was refused),
    :class:`StateError` (8-30, an interlock or the controller's state forbids it) and
    :class:`HardwareFaultError` (70-86, hardware, configuration or firmware faults). Number
    0 (:class:`NoError`) and undocumented numbers (:class:`UnknownControllerError`) belong
    to none of them.

    Parameters
    ----------
    number
        The controller's error number (``None``: the class's own).
    command
        The line that caused it (``None``: not known).
    """

    number: int = -1
    text: str = "unknown error"
    _registry: ClassVar[dict[int, type[ControllerError]]] = {}

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        # Only a class that names its own number stands for it (not a category, and not
        # an internal variant that inherits the number, see InternalControllerError).
        if "number" in cls.__dict__ and cls.number >= 0:
            ControllerError._registry[cls.number] = cls

    def __init__(self, number: int | None = None, command: str | None = None) -> None:
        self.number: int = type(self).number if number is None else number
        self.text: str = _text_of(self.number, type(self).text)
        self.command = command
        where = f" (command {command!r})" if command else ""
        super().__init__(f"controller error {self.number}: {self.text}{where}")

    def __reduce__(self) -> tuple[object, ...]:
        return (type(self), (self.number, self.command))


class CommandRejectedError(ControllerError):
    """Category of controller errors 1-7: the command line itself was refused (no such
    axis or instruction, too long, a number out of range, wrong parameter count, no
    ``!``/``?``). Sending the same line again fails the same way."""


class StateError(ControllerError):
    """Category of controller errors 8-30: an interlock or the controller's state forbids
    the command (TVR active, joystick enabled, limit switch, emergency stop, amplifiers
    off, ...). The same line may work once the state has changed.

    Numbers 20 and above can also be persistent internal conditions that no command caused:
    those are raised as :class:`InternalControllerError`, which is then an instance of the
    number's class as well (``except AmplifiersDisabledError`` and ``except StateError``
    catch both).
    """


class HardwareFaultError(ControllerError):
    """Category of controller errors 70-86: hardware, configuration or firmware faults
    (CPLD data, ETS, write-protected parameter, eeprom, supply overloads, brake voltage).
    Usually these need a person, not a retry."""


class UnknownControllerError(ControllerError):
    """An error number that the manual does not document."""


#: Error numbers from here on may be persistent internal conditions rather than the
#: result of the last instruction (manual L2853-2867: "typically no. 20 and above").
INTERNAL_ERRORS = 20


class InternalControllerError(ControllerError):
    """The controller is in a persistent internal error state (``number`` >= 20, e.g.
    29 amplifiers off) that ``?err`` reports although the last instruction was fine
    (manual L2853-2867). It is not the fault of any command (``command`` is ``None``);
    raised by :meth:`Controller.check_fault <tango_aio.Controller.check_fault>`
    and announced by the :class:`~tango_aio.events.ControllerFault` event.

    ``InternalControllerError(29)`` builds an instance that is also of the number's own
    class, and so of its category (here :class:`AmplifiersDisabledError`, a
    :class:`StateError`); an undocumented number gives a plain
    :class:`InternalControllerError`. Whether an error is persistent or the line's own is
    a question of who caused it, not of the number, hence this class stands beside the
    categories rather than inside one.

    Parameters
    ----------
    number
        The controller's error number (``None``: the class's own).
    command
        Always ``None`` in the driver: no command caused it.
    """

    def __new__(cls, number: int | None = None, command: str | None = None
                ) -> InternalControllerError:
        if cls is InternalControllerError and number is not None:
            cls = _internal_class(number)
        return super().__new__(cls, number, command)

    def __init__(self, number: int | None = None, command: str | None = None) -> None:
        super().__init__(number, command)
        self.args = (f"controller reports internal error {self.number}: "
                     f"{self.text} (not caused by a command)",)

    def __reduce__(self) -> tuple[object, ...]:
        return (InternalControllerError, (self.number, self.command))


# -- generated by tools/gen_errors.py from reference/errors.json (do not edit) --
# One class per error number of the manual (firmware 1.71, chapter 5,
# L961-1034).


class NoError(ControllerError):
    """Controller error 0 (L962): no error."""
    number = 0
    text = "no error"


class InvalidAxisNameError(CommandRejectedError):
    """Controller error 1 (L964): no valid axis name."""
    number = 1
    text = "no valid axis name"


class NotExecutableError(CommandRejectedError):
    """Controller error 2 (L966): no executable instruction."""
    number = 2
    text = "no executable instruction"


class LineTooLongError(CommandRejectedError):
    """Controller error 3 (L968): too many characters in command line."""
    number = 3
    text = "too many characters in command line"


class InvalidInstructionError(CommandRejectedError):
    """Controller error 4 (L970): invalid instruction."""
    number = 4
    text = "invalid instruction"


class OutOfRangeError(CommandRejectedError):
    """Controller error 5 (L972): number is not inside allowed range."""
    number = 5
    text = "number is not inside allowed range"


class WrongParameterCountError(CommandRejectedError):
    """Controller error 6 (L974): wrong number of parameters."""
    number = 6
    text = "wrong number of parameters"


class MissingPrefixError(CommandRejectedError):
    """Controller error 7 (L976): either ! or ? is missing."""
    number = 7
    text = "either ! or ? is missing"


class TvrAxisActiveError(StateError):
    """Controller error 8 (L978): no TVR possible, while axis active."""
    number = 8
    text = "no TVR possible, while axis active"


class TvrActiveError(StateError):
    """Controller error 9 (L980): no ON or OFF of axis possible, while TVR active."""
    number = 9
    text = "no ON or OFF of axis possible, while TVR active"


class NotConfiguredError(StateError):
    """Controller error 10 (L982): function not configured."""
    number = 10
    text = "function not configured"


class JoystickEnabledError(StateError):
    """Controller error 11 (L984): no move instruction possible, while joystick enabled."""
    number = 11
    text = "no move instruction possible, while joystick enabled"


class LimitSwitchActiveError(StateError):
    """Controller error 12 (L986): limit switch active."""
    number = 12
    text = "limit switch active"


class EncoderDetectedError(StateError):
    """Controller error 13 (L988): function not executable, because encoder detected."""
    number = 13
    text = "function not executable, because encoder detected"


class MultiAxisMoveForbiddenError(StateError):
    """Controller error 21 (L990): multiple axis moves are forbidden (e.g. during
    initialization).
    """
    number = 21
    text = "multiple axis moves are forbidden (e.g. during initialization)"


class MoveNotAllowedError(StateError):
    """Controller error 22 (L992): automatic or manual move is not allowed (e.g. door open or
    initialization).
    """
    number = 22
    text = "automatic or manual move is not allowed (e.g. door open or initialization)"


class EmergencyStopError(StateError):
    """Controller error 27 (L994): emergency STOP is active."""
    number = 27
    text = "emergency STOP is active"


class AmplifiersDisabledError(StateError):
    """Controller error 29 (L996): servo amplifiers are disabled (switched OFF)."""
    number = 29
    text = "servo amplifiers are disabled (switched OFF)"


class SafetyCircuitError(StateError):
    """Controller error 30 (L998): safety circuit out of order."""
    number = 30
    text = "safety circuit out of order"


class CpldDataError(HardwareFaultError):
    """Controller error 70 (L1002): wrong CPLD data."""
    number = 70
    text = "wrong CPLD data"


class EtsError(HardwareFaultError):
    """Controller error 71 (L1004): ETS error."""
    number = 71
    text = "ETS error"


class WriteProtectedError(HardwareFaultError):
    """Controller error 72 (L1006): parameter is write protected (check lock bits)."""
    number = 72
    text = "parameter is write protected (check lock bits)"


class InternalDataError(HardwareFaultError):
    """Controller error 73 (L1008): internal error, e.g. eeprom data corruption."""
    number = 73
    text = "internal error, e.g. eeprom data corruption"


class ClosedLoopOffError(HardwareFaultError):
    """Controller error 74 (L1010): closed loop switched off due to parameter change."""
    number = 74
    text = "closed loop switched off due to parameter change"


class AxisCorrectionError(HardwareFaultError):
    """Controller error 75 (L1012): could not enable axis correction, or axis correction was
    disabled.
    """
    number = 75
    text = "could not enable axis correction, or axis correction was disabled"


class IoExtensionOverloadError(HardwareFaultError):
    """Controller error 76 (L1014): io extension error (output overload on IO1 or Multi-IO
    connector).
    """
    number = 76
    text = "io extension error (output overload on IO1 or Multi-IO connector)"


class IoExtensionBusError(HardwareFaultError):
    """Controller error 77 (L1016): io extension internal communication error (internal bus
    error).
    """
    number = 77
    text = "io extension internal communication error (internal bus error)"


class HdiDeviceError(HardwareFaultError):
    """Controller error 78 (L1018): HDI input device error."""
    number = 78
    text = "HDI input device error"


class XposModuleError(HardwareFaultError):
    """Controller error 79 (L1020): xPos module error."""
    number = 79
    text = "xPos module error"


class HdiIsrError(HardwareFaultError):
    """Controller error 80 (L1022): internal error: HDI ISR not running."""
    number = 80
    text = "internal error: HDI ISR not running"


class EncoderIsrError(HardwareFaultError):
    """Controller error 81 (L1024): internal error: Encoder ISR not running."""
    number = 81
    text = "internal error: Encoder ISR not running"


class MotorSupplyOverloadError(HardwareFaultError):
    """Controller error 82 (L1026): overload on motor connector +5V."""
    number = 82
    text = "overload on motor connector +5V"


class AuxSupplyOverloadError(HardwareFaultError):
    """Controller error 83 (L1028): overload on AUX I/O +5V supply."""
    number = 83
    text = "overload on AUX I/O +5V supply"


class EncoderSupplyOverloadError(HardwareFaultError):
    """Controller error 84 (L1030): overload on encoder +5V supply."""
    number = 84
    text = "overload on encoder +5V supply"


class Aux24VOverloadError(HardwareFaultError):
    """Controller error 85 (L1032): overload on AUX I/O +24V supply."""
    number = 85
    text = "overload on AUX I/O +24V supply"


class BrakeVoltageError(HardwareFaultError):
    """Controller error 86 (L1034): low brake output voltage."""
    number = 86
    text = "low brake output voltage"


# -- end of the generated error classes --


class NotSupportedByFirmwareError(InvalidInstructionError):
    """The controller's firmware does not know an instruction the manual (1.71) documents:
    it answered error 4 (L970) to a line the catalog finds valid, or the older edition of
    the manual lacks the instruction and the unit runs that firmware.

    Parameters
    ----------
    instruction
        The instruction (``'extmode'``).
    command
        The line that was refused (``None``: not sent, known beforehand).
    """

    def __init__(self, instruction: str, command: str | None = None) -> None:
        super().__init__(4, command)
        self.instruction = instruction
        where = f" (command {command!r})" if command else ""
        self.args = (f"{instruction!r} is not supported by this firmware{where}",)

    def __reduce__(self) -> tuple[object, ...]:
        return (type(self), (self.instruction, self.command))


class SettingsRestoreError(TangoError):
    """A settings restore did not bring every setting to the snapshot's value.

    Parameters
    ----------
    failed
        Each setting that did not take (``'vel X'``, ``'joyspeed 2'``) and why.
    """

    def __init__(self, failed: dict[str, str]) -> None:
        self.failed = dict(failed)
        listed = "; ".join(f"{name}: {why}" for name, why in self.failed.items())
        super().__init__(f"{len(self.failed)} setting(s) did not take: {listed}")

    def __reduce__(self) -> tuple[object, ...]:
        return (type(self), (self.failed,))


class SnapshotMismatchError(TangoError, ValueError):
    """A settings snapshot does not fit this controller (another model, an axis or a
    setting this unit lacks); nothing was written."""



#: Documented error numbers and their manual texts.
ERROR_DESCRIPTIONS: dict[int, str] = {
    number: cls.text for number, cls in ControllerError._registry.items()
}

#: The error categories in the order of their numbers.
CATEGORIES: tuple[type[ControllerError], ...] = (
    CommandRejectedError, StateError, HardwareFaultError)


def _text_of(number: int, default: str) -> str:
    return ERROR_DESCRIPTIONS.get(number, default)


def error_class(number: int) -> type[ControllerError]:
    """The class of a controller error number.

    Parameters
    ----------
    number
        The controller's error number.

    Returns
    -------
    type[ControllerError]
        Its own class; :class:`UnknownControllerError` for an undocumented number.
    """
    return ControllerError._registry.get(number, UnknownControllerError)


def controller_error(number: int, command: str | None = None) -> ControllerError:
    """Build the typed exception for a controller error number.

    Parameters
    ----------
    number
        The controller's error number.
    command
        The line that caused it (``None``: not known).

    Returns
    -------
    ControllerError
        An instance of :func:`error_class` of ``number``.
    """
    return error_class(number)(number, command)


def _make_internal(number: int) -> type[InternalControllerError]:
    own = error_class(number)
    if own is UnknownControllerError:
        return InternalControllerError
    name = f"Internal{own.__name__}"
    namespace = {"__module__": __name__, "__qualname__": name,
                 "__doc__": f"Controller error {number} as a persistent internal condition."}
    return cast("type[InternalControllerError]",
                type(name, (InternalControllerError, own), namespace))


# The internal variant of each documented number from INTERNAL_ERRORS on, built once.
_INTERNAL: dict[int, type[InternalControllerError]] = {
    number: _make_internal(number) for number in ERROR_DESCRIPTIONS if number >= INTERNAL_ERRORS
}


def _internal_class(number: int) -> type[InternalControllerError]:
    return _INTERNAL.get(number, InternalControllerError)


_ERR_RE = re.compile(r"^\s*(?:ERR(?:OR)?\s*(-?\d+)?\s*(?:,\s*(.*))?|(-?\d+))\s*$")


def parse_error_reply(line: str) -> tuple[int | None, str | None]:
    """Parse an error report into ``(number, text)``.

    Accepts the three forms the controller uses: a bare number (``?err`` → ``5``), an
    acknowledgement (``ERR 5`` or plain ``ERR``, autostatus 2 and ``save``) and a ``help``
    line (``ERROR 5,number outside range``). ``OK...`` gives ``(0, None)``. The number is
    ``None`` when the controller sent ``ERR`` without one.

    Parameters
    ----------
    line
        The reply line.

    Returns
    -------
    tuple[int | None, str | None]
        The number (``None``: not given) and the text (``None``: not given).

    Raises
    ------
    ProtocolError
        The line is none of those forms.
    """
    stripped = line.strip()
    if stripped.startswith("OK"):
        return 0, None
    match = _ERR_RE.match(stripped)
    if match is None:
        raise ProtocolError(f"not an error report: {line!r}")
    number = match.group(1) if match.group(1) is not None else match.group(3)
    return (int(number) if number is not None else None), match.group(2)
