"""The emulated controller's interpreter: parses lines with the catalog and answers them.

:class:`ControllerModel` implements the :class:`~tango_aio.sim.wire.LineHandler` protocol:
the wire hands it one command line at a time, and it answers through ``emit``. It is
sans-IO and time comes from the wire, so it runs in virtual time in tests and in real
time in the servers.

How it answers. These are the emulator's own reading of the manual; it never asks the
driver (nothing of ``tango_aio.sansio._core``, ``protocol``, ``patterns`` or ``controller`` is
imported). Where the manual is silent, the choice is a switch of
:class:`~tango_aio.sim.profiles.Firmware` (``SimConfig.firmware``); the ``manual`` profile's
choice is named first below:

* autostatus 4 echoes executing lines (``!`` lines and executing bare forms such as
  ``moa 1``, L2117), before executing them (switch ``echo``), with the exact text
  (``echo_text``); reads only with ``echo_all``;
* autostatus 2 acknowledges ``!`` lines after running them (``OK...`` / ``ERR n``,
  L2099-2103, L2150-2152; ``err_number``, ``move_ok``), a mode change per the new mode
  (``ack_mode_change``), reads never (``ack_reads``);
* ``save`` answers in every mode (L2081), completion reports follow the mode in force when
  the move ends;
* every line is parsed by :func:`tango_aio.catalog._instructions.parse`; a line the catalog rejects
  sets the error number the catalog names (1-7) and executes nothing;
* each executed instruction overwrites the error state (manual L2853), except the reads
  ``?err``, ``?status`` and ``help`` themselves;
* a read that fails for a semantic reason (``?trigp 99`` beyond the list) still answers
  with a zero value and sets the error, so a host waiting for a line never hangs; a line
  rejected by the parser answers nothing (a real interpreter cannot know its shape);
* a read whose catalog reply is "none" (``?flash``, "Response: None") answers nothing;
* an empty line is ignored without touching the error state;
* ``restore`` reloads the saved parameters only; ``reset`` and ``restore -1`` restart
  (autostatus 1, moves stopped, counters 0 at the power-on position); without a state
  file, ``save`` keeps the saved parameters in memory, where reset, power cycles and
  ``restore`` find them (``restore -1`` deletes them, L1803-1808);
* the trigger list is handed to the motion model lazily, before the next instruction that
  is not a trigger-list instruction (see :meth:`ControllerModel.arm_triggers`);
* an unexpected exception in a handler (an emulator bug) does not stop the controller:
  the line sets error 2 and the exception is kept in ``internal_errors`` for tests;
* a refused move, cal or rm sends nothing in mode 1 and its axes show ``E`` in ``sa``
  (L2705; switch ``refused_move_report`` adds a report);
* :meth:`ControllerModel.inject_internal_error` raises an internal error (>= 20) that
  ``?err`` shows while the last instruction was fine (L2853-2867);
* ``reset`` and ``restore -1`` reboot for ``reset_time`` seconds, during which the wire
  loses all input (:meth:`ControllerModel.reboots`, L1837-1857);
* the joystick is on at power-on and ``!joy 0`` then reports, also during a move
  (L2093, L7142-7154); closed loop delays a move's report by ``ctrd`` (L11616-11631).
"""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path
from typing import Any

from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
    Context,
    Form,
    Kind,
    Shape,
    parse,
)
from ..errors import ERROR_DESCRIPTIONS, InvalidCommandError
from .clock import host_now
from .devices import TAKT_OUT, TRIGGER_OUT, Devices, Pulse
from .handlers import build_handlers
from .lists import MAX_TRIGGERS, ListError, SnapshotList, TriggerList
from .motion import MotionConfig, MotionModel, MotionRefused, MoveFinished, TriggerFired
from .params import ParamStore
from .profiles import Firmware
from .state import StateFileError, load_state, save_state
from .wire import Emit

__all__ = ["ControllerModel", "Refused", "SimConfig"]


class Refused(Exception):
    """An instruction was not executed; ``code`` is the error number to set.

    Parameters
    ----------
    code
        The error number.
    message
        What was refused; empty for the error's description.
    """

    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(message or ERROR_DESCRIPTIONS.get(code, "error"))
        self.code = code


#: Option bits of ``?det``: trigger out and snapshot (manual L1119-1185).
DEFAULT_OPTIONS = 0x2800


@dataclass(frozen=True)
class SimConfig:
    """Identity and static configuration of an emulated controller.

    ``firmware`` is the behaviour where the manual is silent (the ``manual`` profile by
    default, see :mod:`tango_aio.sim.profiles`); ``version`` is the version number
    ``?version`` shows.
    """

    axes: int = 3
    model: str = "TANGO-DT"
    firmware: Firmware = field(default_factory=Firmware)
    version: str = "1.71"
    build: str = "Jun  4 2019 , 12:00:00"
    serial: str = "190604001"
    options: int = DEFAULT_OPTIONS
    #: Where ``save`` persists the saved parameters (JSON, written atomically); ``None``:
    #: in memory, for the life of this model.
    state_file: Path | None = None
    #: Extra interpreter time of blocking instructions, in seconds.
    reset_time: float = 1.0
    motion: MotionConfig | None = None
    #: Instructions this unit lacks (an optional module, a smaller model): like any
    #: instruction it does not know, each answers nothing and sets error 4 ("invalid
    #: instruction", L970); the manual does not list which units lack which.
    lacks: frozenset[str] = frozenset()

    @property
    def det(self) -> int:
        """The ``?det`` value: options plus the axis count in bits 4-7."""
        return self.options | (self.axes << 4)


Handler = Callable[[Command], list[str] | None]

#: Settings mirrored from the parameter store into the motion model's AxisSettings.
_AXIS_SETTINGS: dict[str, str] = {
    "axis": "enable", "dim": "dim", "pitch": "pitch", "gear": "gear", "accel": "accel",
    "stopaccel": "stopaccel", "secvel": "secvel", "calbspeed": "calbspeed",
    "caltimeout": "caltimeout", "nosetlimit": "nosetlimit", "calmode": "calmode",
    "calrequired": "calrequired", "limctr": "limctr", "modulomode": "modulomode",
}
_GLOBAL_SETTINGS: dict[str, str] = {
    "usteps": "usteps", "scanmode": "scanmode", "scanvel": "scanvel", "pause": "pause_ms",
    "delay": "delay_ms", "extmode": "extmode",
}
#: Instructions that change the trigger list or whether it fires (re-armed lazily).
_TRIGGER_LIST = frozenset({"trig", "trigm", "triga", "trigp", "trigc", "trigi", "trigr",
                           "trigd"})
#: The distance modes the emulator generates (L12595-12836): the sense of travel (+1
#: forward, -1 backward) and the shift in distances; the bidirectional modes (1, 4, 7,
#: 10) are not modelled (they arm nothing).
_DISTANCE_MODES = {0: (1, 0.0), 3: (1, 0.0), 2: (-1, 0.0), 5: (-1, 0.0),
                   6: (1, 0.5), 9: (1, 0.5), 8: (-1, 0.5), 11: (-1, 0.5)}
#: Reads/writes of these instructions never change the error state (manual L2837).
_ERROR_NEUTRAL = frozenset({"err", "status", "help"})


@dataclass
class _Session:
    """Volatile state that a reset clears."""

    autostatus: int = 1
    err: int = 0
    booted: float = 0.0
    keys_latched: list[int] = field(default_factory=lambda: [0, 0, 0, 0])
    #: ``?drop``: drops counted since ``!drop 0``.
    drops: int = 0
    #: ``clim``: centre X, centre Y, radius in user units, and whether it is active.
    clim: tuple[float, float, float] = (0.0, 0.0, 0.0)
    clim_active: bool = False
    #: An internal error (>= 20) that ``?err`` shows while the last instruction was fine
    #: (L2853-2867), and whether ``!err`` cannot clear it (like 29, L2824-2881).
    internal_err: int = 0
    internal_permanent: bool = False
    #: Job ids of moves whose mode-2 ``OK...`` comes with their report (``move_ok``).
    ok_owed: set[int] = field(default_factory=set)
    #: Mode-4 echoes of move lines owed at their completion (``echo=completion``), by job.
    echo_owed: dict[int, str] = field(default_factory=dict)
    #: ``a``/Ctrl+C owe a report of their own once the axes stand (``abort_report``,
    #: ``ctrl_c=stop_report``).
    stop_report_owed: bool = False


class ControllerModel:
    """An emulated TANGO controller (the interpreter behind the wire).

    Parameters
    ----------
    emit
        Where the replies go.
    config
        The emulator's configuration; ``None`` for the default.
    now
        The start time; ``None`` for the running loop's clock
        (:func:`~tango_aio.sim.clock.host_now`).
    """

    def __init__(self, emit: Emit, config: SimConfig | None = None,
                 now: float | None = None) -> None:
        self.config = config or SimConfig()
        #: The behaviour where the manual is silent (:mod:`tango_aio.sim.profiles`).
        self.firmware: Firmware = self.config.firmware
        self._emit = emit
        self._line_end = b"\r\n" if self.firmware.line_end == "crlf" else b"\r"
        #: The link echoes every byte the host sends (switch ``local_echo``; the wire
        #: asks, like :attr:`ctrl_c_stops`).
        self.local_echo = self.firmware.local_echo == "yes"
        #: The job id of the move the current line started (set by the move handlers).
        self.last_job: int | None = None
        #: Unexpected exceptions raised by handlers (bugs), as ``line: exception`` texts.
        self.internal_errors: list[str] = []
        #: The saved parameters when there is no state file (the eeprom kept in memory:
        #: it outlives reset and power cycles of this model, not the process).
        self._eeprom: tuple[dict[str, list[Any]], dict[str, Any]] | None = None
        self._handlers: dict[str, Handler] = build_handlers(self)
        # The servers run the wire on the running loop's clock (not time.monotonic()
        # under uvloop), so the default start time is that clock's now.
        self._boot(host_now() if now is None else now)

    # -- lifecycle -------------------------------------------------------------------------

    def _boot(self, now: float) -> None:
        motion_config = self.config.motion or MotionConfig(n_axes=self.config.axes)
        self.motion = MotionModel(motion_config, start_time=now)
        firmware = self.firmware
        self.motion.abort_letter = firmware.abort_letter
        self.motion.move_during_move = firmware.move_during_move
        self.motion.zero_move_report = firmware.zero_move_report == "yes"
        self.params = ParamStore()
        self.session = _Session(booted=now)
        self.triggers = TriggerList()
        self.snapshots = SnapshotList()
        #: I/O levels, encoders fitted and the pulses sent (:mod:`tango_aio.sim.devices`).
        self.devices = Devices()
        #: Axes the joystick drives now.
        self._joystick_axes: set[int | str] = set()
        #: Where the last cal of each axis completed, user frame, revolutions.
        self.cal_zero = [0.0] * len(AXES)
        self._triggers_dirty = False
        self._trigger_base = 0
        self._load_saved()
        self._sync_all()

    @property
    def axes(self) -> int:
        """Number of configured axes."""
        return self.config.axes

    @property
    def error(self) -> int:
        """The current error number (what ``?err`` answers): the last instruction's, else
        an internal error (L2853-2867)."""
        return self.session.err or self.session.internal_err

    def inject_internal_error(self, code: int, *, permanent: bool = False) -> None:
        """Fault hook: raise internal error ``code`` (>= 20, e.g. 29 "servo amplifier off").

        Like the manual says (L2853-2867): "If the previously executed instruction
        returned no error, the 'err' response is either 0 or if an internal error state is
        active, the internal error is returned". So ``?err``, ``?status`` and ``help`` show
        it while the last instruction was fine, an instruction error hides it, ``!err``
        clears it unless ``permanent`` (like 29, L2824-2881), a reset clears it.

        Parameters
        ----------
        code
            The internal error number (20 or more).
        permanent
            ``!err`` does not clear it.

        Raises
        ------
        ValueError
            ``code`` is below 20.
        """
        if code < 20:
            raise ValueError(f"internal errors are numbered 20 and above, got {code}")
        self.session.internal_err = code
        self.session.internal_permanent = permanent

    def clear_error(self) -> None:
        """``!err``: clear the error state, except a permanent internal error."""
        self.session.err = 0
        if not self.session.internal_permanent:
            self.session.internal_err = 0

    @property
    def autostatus(self) -> int:
        """The current autostatus mode."""
        return self.session.autostatus

    def context(self) -> Context:
        """The parser context: dims, axes, extmode.

        Returns
        -------
        Context
            The context.
        """
        groups = self.params.axis_values["dim"]  # what params.first("dim", i) reads
        dims = [int(groups[i][0]) for i in range(len(AXES))]
        return Context.of(dims, self.axes, int(self.params.first("extmode")))

    # -- LineHandler protocol ----------------------------------------------------------------

    def handle_line(self, line: bytes, now: float) -> None:
        """Execute one command line (no CR).

        Parameters
        ----------
        line
            The line.
        now
            The time.
        """
        self.poll(now)
        text = line.decode("latin-1").strip()
        if not text:
            return
        context = self.context()
        try:
            command = parse(text, context)
        except InvalidCommandError as exc:
            self._rejected(text, exc.number)
            return
        if self._unknown_to_older(command) or command.instruction.name in self.config.lacks:
            self._rejected(text, 4)
            return
        self._run(command, text)

    def line_too_long(self, head: bytes, now: float) -> None:
        """A line over 255 characters: error 3, nothing executed.

        Parameters
        ----------
        head
            The line's start.
        now
            The time.
        """
        self.poll(now)
        self._rejected(head.decode("latin-1"), 3)

    @property
    def ctrl_c_stops(self) -> bool:
        """Whether Ctrl+C bypasses the parser (the wire asks; switch ``ctrl_c``).

        "Most TANGO controllers also provide the Ctrl+C (hex 0x03) special character stop"
        (L6808-6814): with ``ctrl_c=ignore`` this one does not, and 0x03 is an ordinary
        byte of the line.
        """
        return self.firmware.ctrl_c != "ignore"

    def ctrl_c(self, now: float) -> None:
        """Ctrl+C stops every axis (the wire already cleared the input buffer).

        Parameters
        ----------
        now
            The time.
        """
        self.poll(now)
        self.motion.emergency_stop()
        if self.firmware.ctrl_c == "stop_report":
            self.session.stop_report_owed = True
            self._send_stop_report()

    def processing_time(self, line: bytes) -> float:
        """Extra interpreter time: ``reset`` and ``restore -1`` take a second (L1837).

        Parameters
        ----------
        line
            The line.

        Returns
        -------
        float
            The seconds.
        """
        return self.config.reset_time if self.reboots(line) else 0.0

    def reboots(self, line: bytes) -> bool:
        """Whether ``line`` restarts the controller (``reset``, ``restore -1``).

        The wire loses the input that arrives while it reboots: "Rebooting from reset will
        take more than 1 second, where the controller is not responding", and the manual's
        resend-``?err`` loop (L1837-1857) only makes sense if input is lost meanwhile.

        Parameters
        ----------
        line
            The line.

        Returns
        -------
        bool
            Whether it restarts the controller.
        """
        words = line.decode("latin-1").lower().lstrip("!?").split()
        return words[:1] == ["reset"] or words[:2] == ["restore", "-1"]

    def poll(self, now: float) -> None:
        """Advance the motion model and report finished moves.

        Parameters
        ----------
        now
            The time.
        """
        for event in self.motion.advance(now):
            if isinstance(event, MoveFinished):
                if event.kind == "cal":
                    self._record_cal_zero(event.letters)
                self._report_completion(event.letters, event.job_id)
                self._arrival_pulse(event.time)
            elif isinstance(event, TriggerFired):
                self.trigger_pulses(event.time, 1,
                                    self.motion.to_user(event.axis, event.position))
        self._send_stop_report()

    def deflect(self, axis: str, fraction: float, now: float | None = None) -> None:
        """Hold the joystick deflected along ``axis`` (``fraction`` of full deflection,
        -1..1; 0 releases it). While the HDI is enabled (``joy`` not 0, L7101-7118) and the
        axis is assigned to it (``joydir`` not 0, L7175-7253), the axis travels at
        ``fraction`` times ``joyvel`` (L7319-7355), in ``joydir``'s sense, like ``speed``.

        Parameters
        ----------
        axis
            The axis letter.
        fraction
            The deflection, -1..1.
        now
            The time (default: the host clock).

        Raises
        ------
        ValueError
            ``fraction`` is not -1..1.
        """
        if not -1.0 <= fraction <= 1.0:
            raise ValueError(f"a deflection is -1..1, not {fraction}")
        self.poll(host_now() if now is None else now)
        index = AXES.index(axis)
        if fraction == 0.0:
            self.devices.deflection.pop(index, None)
        else:
            self.devices.deflection[index] = fraction
        self.follow_joystick()

    def follow_joystick(self) -> None:
        """Drive the deflected axes as the HDI settings allow (nothing while it is off)."""
        enabled = int(self.params.first("joy")) != 0
        velocities: dict[int | str, float] = {}
        for index in range(self.axes):
            fraction = self.devices.deflection.get(index, 0.0) if enabled else 0.0
            sense = int(self.params.first("joydir", index))
            if fraction == 0.0 and index not in self._joystick_axes:
                continue
            value = self.params.number("joyvel", index) * fraction * (1 if sense > 0 else
                                                                      -1 if sense < 0 else 0)
            velocities[index] = self.motion.vel_from_user(index, value)
        self._joystick_axes = {i for i, v in velocities.items() if v}
        if velocities:
            self.motion.speed(velocities)

    def next_deadline(self) -> float | None:
        """When the motion model next changes state.

        Returns
        -------
        float or None
            The time, or ``None`` if nothing moves.
        """
        return self.motion.next_event_time()

    # -- execution -------------------------------------------------------------------------

    def _unknown_to_older(self, command: Command) -> bool:
        """Switch ``instruction_set=older``: instructions the older edition lacks, and
        values for those that took none there (``help N``, ``version 1``; old L414,
        old L805-819), are unknown to it: error 4 ("invalid instruction"); with
        ``version_value=line`` a value for ``version`` is ignored instead.

        Returns
        -------
        bool
            Whether the older edition does not know the line.
        """
        if self.firmware.instruction_set != "older":
            return False
        entry = command.instruction
        ignored = entry.name == "version" and self.firmware.version_value == "line"
        return not entry.in_older_manual or (entry.older_without_values and not ignored
                                             and bool(command.values))

    def _rejected(self, text: str, code: int) -> None:
        """A line the parser refused: nothing runs, the error is set.

        Mode 4 echoes it when it looks like a set line (``!``), or always with
        ``echo_all``; mode 2 answers ``ERR`` for a ``!`` line (and a ``?`` line when reads
        are acknowledged).
        """
        self.session.err = code
        mode, firmware = self.session.autostatus, self.firmware
        if mode == 4 and (text.startswith("!") or firmware.echo_all == "yes"):
            self._send(self._echo_text(text))
        if mode == 2 and (text.startswith("!") or
                          (text.startswith("?") and firmware.ack_reads != "no")):
            self._send(self._ack_text(self._err_text(code)))

    def _run(self, command: Command, text: str) -> None:
        firmware = self.firmware
        before = self.session.autostatus
        echo = self._echo_text(text)
        # echo=completion: a move line's echo waits for the move (sent below, or with
        # its report); every other line is echoed like echo=before.
        moves = command.instruction.completion is not None and command.executes
        at_completion = firmware.echo == "completion" and moves
        if (firmware.echo == "before" or (firmware.echo == "completion" and not moves)) \
                and self._echoes(command, before):
            self._send(echo)
        self._prepare_triggers(command)
        self.last_job = None
        try:
            lines = self._execute(command)
            code = 0
        except (Refused, MotionRefused, ListError) as exc:
            code, lines = exc.code, self._fallback_reply(command, exc.code)
        except Exception as exc:
            # Safety net: a bug in a handler must not take the served controller down.
            # The line counts as not executable (error 2) and the bug is recorded for tests.
            self.internal_errors.append(f"{text!r}: {exc!r}")
            code, lines = 2, self._fallback_reply(command, 2)
        if command.name not in _ERROR_NEUTRAL:
            self.session.err = code
        after = self.session.autostatus
        ack = self._ack(command, code, before, after)
        if ack is not None and command.is_read and firmware.ack_reads == "before":
            self._send(ack)
            ack = None
        numeric = command.instruction.reply in _NUMERIC
        for reply in lines or ():
            self._send(self._restyle(reply, numeric))
        if ack is not None:
            if (code == 0 and firmware.move_ok == "completion" and self.last_job is not None
                    and self.motion.has_job(self.last_job)):
                # Switch move_ok=completion: the OK... comes with the report (a move that
                # reports nothing, zero_move_report=no, is acknowledged at once).
                self.session.ok_owed.add(self.last_job)
            else:
                self._send(ack)
        if at_completion and self._echoes(command, before):
            if (code == 0 and self.last_job is not None
                    and self.motion.has_job(self.last_job)):
                self.session.echo_owed[self.last_job] = echo
            else:
                self._send(echo)  # refused, or nothing to wait for
        if code and command.instruction.completion is not None and command.executes:
            self._refused_move(command)
        if firmware.echo == "after" and self._echoes(command, after):
            self._send(echo)
        self._send_stop_report()

    def _echoes(self, command: Command, mode: int) -> bool:
        """Mode 4 echoes "the instruction that was sent, in case of set or move
        instruction" (L2117): executing lines, ``!`` or bare (``moa 1``); with
        ``echo_all`` every line, reads included (old L723: "echoes all input").

        Returns
        -------
        bool
            Whether the line is echoed.
        """
        return mode == 4 and (command.executes or self.firmware.echo_all == "yes")

    def _echo_text(self, text: str) -> str:
        """The echo: the exact text, or (``echo_text=normalized``) re-printed."""
        if self.firmware.echo_text == "exact":
            return text
        if self.firmware.echo_text == "nobang":
            return text[1:] if text.startswith("!") else text
        return " ".join(_reprint(token) for token in text.lower().split())

    def _ack(self, command: Command, code: int, before: int, after: int) -> str | None:
        """The mode-2 acknowledgement a line owes, if any.

        Only ``!`` lines are acknowledged (L2099-2103; ``vel 10`` without ``!`` gets
        nothing, L2154), reads with ``ack_reads``. A line that answers ``OK...`` itself
        (``save``) is not acknowledged twice. A line that changes the mode is judged by
        the mode after it (``ack_mode_change=new``) or before it (``old``).

        Returns
        -------
        str or None
            The acknowledgement, or ``None``.
        """
        mode = after if self.firmware.ack_mode_change == "new" else before
        if mode != 2:
            return None
        if command.form is Form.SET and not command.is_read:
            if command.instruction.exec_reply is Shape.ACK and self.firmware.save_ack == "once":
                return None  # save_ack=twice: acknowledged after its own OK... as well
        elif not (command.form is Form.READ and self.firmware.ack_reads != "no"):
            return None
        return self._ack_text("OK..." if code == 0 else self._err_text(code))

    def _ack_text(self, text: str) -> str:
        """A mode-2 acknowledgement in the case of switch ``ack_case``."""
        case = self.firmware.ack_case
        if case == "lower":
            return text.lower()
        if case == "title":
            return text.capitalize()
        return text

    def _err_text(self, code: int) -> str:
        """``ERR 5`` (L2152), or bare ``ERR`` with ``err_number=no`` (L2099)."""
        return f"ERR {code}" if self.firmware.err_number == "yes" else "ERR"

    def _restyle(self, reply: str, numeric: bool) -> str:
        """Numbers of a data reply per switch ``numbers``: a value that rounds to zero from
        below prints ``0.0000`` (``plain``) or ``-0.0000`` (``negzero``); ``plus`` puts
        ``+`` before positive values of ``numeric`` replies (not in ``?version`` text).

        Returns
        -------
        str
            The reply.
        """
        style = self.firmware.numbers
        if style == "negzero":
            return reply
        if "-0" in reply:
            reply = _NEG_ZERO.sub(r"\1", reply)
        if style == "plus" and numeric:
            reply = _POSITIVE.sub(_plus, reply)
        return reply

    def _refused_move(self, command: Command) -> None:
        """A move, cal or rm that was refused (error set, nothing moved).

        Choice from L2705 ("E => error response, move aborted or not executed"): the
        status letter of the axes it named becomes ``E``, so a client polling ``sa``
        sees that the move was not executed; in mode 1 nothing is sent (no line of the
        manual shows a report for a move that never started). Switch
        ``refused_move_report=yes``: it also reports, ``E`` for those axes.
        """
        named = set(range(self.axes))
        if command.axis is not None:
            named = {AXES.index(command.axis)} if AXES.index(command.axis) < self.axes \
                else set()
        elif command.values and command.name in ("moa", "mor"):
            named = set(range(min(len(command.values), self.axes)))
        self.motion.mark_not_executed(named)
        if self.firmware.refused_move_report == "yes":
            letters = "".join("-" if i >= self.axes else "E" if i in named else "@"
                              for i in range(len(AXES)))
            self._report_completion(letters)

    def _execute(self, command: Command) -> list[str] | None:
        handler = self._handlers.get(command.name)
        if handler is not None:
            return handler(command)
        if command.is_read and command.instruction.reply is Shape.NONE:
            return None  # '?flash' is a legal form with "Response: None" (L9880)
        if command.is_read:
            return [self._generic_read(command)]
        self._generic_write(command)
        return None

    def _fallback_reply(self, command: Command, code: int) -> list[str] | None:
        if not command.is_read:
            if command.instruction.exec_reply is Shape.ACK:
                return [self._err_text(code)]
            return None
        return ["0"]

    def _send(self, text: str) -> None:
        self._emit(text.encode("latin-1") + self._line_end)

    def _report_completion(self, letters: str, job: int | None = None,
                           *, move: bool = True) -> None:
        """Send a completion report in the mode in force now.

        Modes 1, 2 and 4 send the letters and ``.`` (L2087-2117), mode 3 a bare CR
        (L2107-2113), mode 0 nothing. Mode 4 sends it after the echo (switch
        ``echo_report``); mode 2 sends an ``OK...`` owed by ``move_ok=completion`` first.
        ``report_width=axes`` keeps only the letters of the unit's axes.
        """
        mode = self.session.autostatus
        owed = job is not None and job in self.session.ok_owed
        if owed:
            self.session.ok_owed.discard(job)
            if mode == 2:
                self._send(self._ack_text("OK..."))
        echo = self.session.echo_owed.pop(job, None) if job is not None else None
        if echo is not None and mode == 4:
            self._send(echo)
        letters = self.joystick_letters(letters)
        if self.firmware.report_width == "axes":
            letters = letters[: self.axes]
        if mode == 4 and move and self.firmware.echo_report == "no":
            return
        if mode in (1, 2, 4):
            self._send(letters + ".")
        elif mode == 3:
            self._send("")

    def _send_stop_report(self) -> None:
        """Send the report ``a``/Ctrl+C owe once no axis moves (``abort_report``)."""
        if not self.session.stop_report_owed:
            return
        if any(self.motion.is_moving(i) for i in range(self.axes)):
            return
        self.session.stop_report_owed = False
        self._report_completion(self.stopped_letters())

    def joystick_letters(self, letters: str) -> str:
        """Switch ``joystick_letter=J``: ``@`` shows as ``J`` while the joystick is
        enabled (``joy`` not 0; L2697, L2721, L6341).

        Parameters
        ----------
        letters
            The status letters.

        Returns
        -------
        str
            The letters as shown.
        """
        if self.firmware.joystick_letter == "J" and int(self.params.first("joy")) != 0:
            return letters.replace("@", "J")
        return letters

    def stopped_letters(self) -> str:
        """Report letters of the axes as they stand: their last letter (``E``/``@`` after
        an abort), ``@`` for a disabled axis, ``-`` for an absent one.

        Returns
        -------
        str
            The letters.
        """
        letters = []
        for index in range(len(AXES)):
            if index >= self.axes:
                letters.append("-")
            else:
                letter = self.motion.status_letter(index)
                letters.append("@" if letter in "-S" else letter)
        return "".join(letters)

    # -- generic settings ------------------------------------------------------------------

    def _generic_read(self, command: Command) -> str:
        name = command.name
        digits = self._digits(command)
        if name in self.params.axis_values or name in self.params.global_values:
            if _bits_read(command):
                return self._read_bits(command)
            return self.params.read(command, self.axes, digits)
        return self._hardware_read(command)

    def _digits(self, command: Command) -> int | None:
        sig = command.instruction.read[0] if command.instruction.read else None
        if sig is not None and sig.precision is not None and command.values:
            return int(command.values[-1])
        return None

    def store(self, command: Command) -> None:
        """Keep the values of a plain set command in the settings store.

        Parameters
        ----------
        command
            The set command.
        """
        self._generic_write(command)

    def _generic_write(self, command: Command) -> None:
        first = command.instruction.write[0] if command.instruction.write else None
        if first is not None and first.lead and first.lead[0].kind is Kind.BITS:
            self._write_bits(command)
            return
        self.params.apply(command, self.axes)
        self._sync(command.name)

    def _read_bits(self, command: Command) -> str:
        bits = str(self.params.first(command.name))
        if command.values:
            return bits[int(command.values[0])]
        return bits

    def _write_bits(self, command: Command) -> None:
        bits = list(str(self.params.first(command.name)))
        if len(command.values) == 2:
            bits[int(command.values[0])] = str(command.values[1])
        else:
            given = str(command.values[0])
            bits[: len(given)] = given
        self.params.put_global(command.name, ("".join(bits),))

    def _hardware_read(self, command: Command) -> str:
        """Plausible values for reads of hardware state the emulator does not model."""
        shape = command.instruction.reply
        count = 1 if command.axis else self.axes
        if shape is Shape.AXES_INT:
            return " ".join(["0"] * count)
        if shape is Shape.AXES_FLOAT:
            return " ".join(["0.000"] * count)
        if shape is Shape.AXES_TEXT:
            return " ".join(["0"] * count)
        if shape is Shape.FLOAT:
            return "0.000"
        return "0"

    def _sync(self, name: str) -> None:
        if name in _AXIS_SETTINGS or name in ("vel", "calvel", "rmvel", "swact",
                                               "caliboffset", "rmoffset", "lim",
                                               "ctr", "ctrd", "encmask"):
            self._sync_axes()
        if name in _GLOBAL_SETTINGS:
            self._sync_globals()

    def _sync_all(self) -> None:
        self._sync_globals()
        self._sync_axes()

    def _sync_globals(self) -> None:
        settings = self.motion.global_settings
        for name, attr in _GLOBAL_SETTINGS.items():
            value = self.params.first(name)
            setattr(settings, attr, type(getattr(settings, attr))(value))

    def _sync_axes(self) -> None:
        for index in range(self.axes):
            settings = self.motion.settings(index)
            for name, attr in _AXIS_SETTINGS.items():
                value = self.params.first(name, index)
                setattr(settings, attr, type(getattr(settings, attr))(value))
            settings.swact = tuple(int(v) for v in self.params.axis("swact", index))  # type: ignore[assignment]
            units = self.motion.units(index)
            settings.caliboffset = units.pos_from_user(self.params.number("caliboffset", index))
            settings.rmoffset = units.pos_from_user(self.params.number("rmoffset", index))
            settings.calvel = tuple(units.vel_from_user(float(v))  # type: ignore[assignment]
                                    for v in self.params.axis("calvel", index))
            settings.rmvel = tuple(units.vel_from_user(float(v))  # type: ignore[assignment]
                                   for v in self.params.axis("rmvel", index))
            settings.settle = self._settle_time(index)
            vel = units.vel_from_user(self.params.number("vel", index))
            if vel != settings.vel:
                self.motion.set_vel(index, vel)

    def _settle_time(self, index: int) -> float:
        """Closed-loop settling of one axis in seconds: ``ctrd`` ms when closed loop is on
        (``ctr`` 1-4 and the encoder enabled by ``encmask``, "Preconditions for
        successfully entering closed loop are having ctr and encmask set", L11761-11800),
        else 0. Choice: ``encmask`` counts at once (the manual activates encoders at
        power on), and the ±twi window is met at once (no deviation is modelled).

        Returns
        -------
        float
            The seconds.
        """
        if int(self.params.first("encmask", index)) != 1 or \
                int(self.params.first("ctr", index)) == 0:
            return 0.0
        return float(self.params.first("ctrd", index)) / 1000.0

    # -- persistence -----------------------------------------------------------------------

    def _saved_names(self) -> list[str]:
        return [n for n, e in INSTRUCTIONS.items() if e.saved
                and (n in self.params.axis_values or n in self.params.global_values)]

    def _load_saved(self) -> None:
        if self.config.state_file is None:
            if self._eeprom is not None:
                axes, global_ = copy.deepcopy(self._eeprom)
                self.params.axis_values.update(axes)
                self.params.global_values.update(global_)
            return
        load_state(self.config.state_file, self.params)  # choices: tango_aio/sim/state.py

    def forget_saved(self) -> None:
        """Delete the saved parameters (``restore -1``, L1803-1808): the state file, or
        the ones kept in memory."""
        self._eeprom = None
        path = self.config.state_file
        if path is not None:
            path.unlink(missing_ok=True)

    def save(self) -> None:
        """Persist the saved parameters to :attr:`SimConfig.state_file` atomically.

        A failed write is refused with error 73 ("internal error, e.g. eeprom data
        corruption"; the manual names no number for a failed save) and leaves the previous
        file intact.

        Raises
        ------
        Refused
            The file could not be written (error 73).
        """
        path = self.config.state_file
        if path is None:
            names = self._saved_names()
            self._eeprom = copy.deepcopy((
                {n: v for n, v in self.params.axis_values.items() if n in names},
                {n: v for n, v in self.params.global_values.items() if n in names}))
            return
        try:
            save_state(path, self.params, self._saved_names())
        except (OSError, StateFileError) as exc:
            raise Refused(73, f"save failed: {exc}") from exc

    def restore(self) -> None:
        """Reload the saved parameters like at power-on, without a restart (L1791-1800):
        positions, moves, lists and the autostatus mode stay as they are.

        Choice: only the parameters ``save`` stores are reloaded (their factory value when
        nothing was saved); unsaved settings such as ``joy`` or ``trig`` keep their value.
        """
        factory = ParamStore()
        for name in self._saved_names():
            if name in factory.axis_values:
                self.params.axis_values[name] = list(factory.axis_values[name])
            else:
                self.params.global_values[name] = factory.global_values[name]
        self._load_saved()
        self._sync_all()

    # -- helpers of the handlers (tango_aio.sim.port.ModelPort) ------------------------------

    def present(self, command: Command) -> list[int]:
        """Axis indices a command addresses: its axis letter, else every present axis.

        Parameters
        ----------
        command
            The command.

        Returns
        -------
        list[int]
            The axis indices.

        Raises
        ------
        Refused
            The command's axis is not present (error 1).
        """
        if command.axis is not None:
            index = AXES.index(command.axis)
            if index >= self.axes:
                raise Refused(1, f"axis {command.axis} is not present")
            return [index]
        return list(range(self.axes))

    def axis_map(self, command: Command, skip_lead: int = 0) -> dict[int, float]:
        """Per-axis values of a command as ``{axis index: value}`` in user units.

        Parameters
        ----------
        command
            The command.
        skip_lead
            Lead values to skip.

        Returns
        -------
        dict[int, float]
            The values, by axis index.

        Raises
        ------
        Refused
            More values than axes (error 1), or an axis not present.
        """
        values = [float(v) for v in command.values[skip_lead:]]
        if command.axis is not None:
            return {self.present(command)[0]: values[0]} if values else {}
        if len(values) > self.axes:
            raise Refused(1, "more values than axes")
        return dict(enumerate(values))

    def hdi_deflect(self, axis: int, distance: float) -> bool:
        """A joystick deflection moving standing axis ``axis`` (0 = X) by ``distance``
        (its dim unit), honoured only while the HDI is enabled (``joy`` not 0,
        L7101-7144).

        Parameters
        ----------
        axis
            The axis index (0 = X).
        distance
            How far, in the axis's dim unit.

        Returns
        -------
        bool
            Whether the axis moved.
        """
        if int(self.params.first("joy")) == 0:
            return False
        revs = self.motion.from_user(axis, distance) - self.motion.from_user(axis, 0.0)
        return self.motion.displace(axis, revs)

    def report(self, letters: str) -> None:
        """Send a report that is not a move's (``!joy 0``) in the current autostatus mode.

        Parameters
        ----------
        letters
            The status letters.
        """
        self._report_completion(letters, move=False)

    def owe_stop_report(self) -> None:
        """``a`` with ``abort_report=yes``: report once the axes stand (old L725)."""
        self.session.stop_report_owed = True

    def set_autostatus(self, mode: int) -> None:
        """Switch the autostatus mode.

        Parameters
        ----------
        mode
            The new mode.
        """
        self.session.autostatus = mode

    # -- trigger list ----------------------------------------------------------------------

    def _prepare_triggers(self, command: Command) -> None:
        """Arm the trigger list in the motion model lazily.

        An executed trigger-list instruction marks the list changed, and the list is armed
        before the next other instruction runs (moves included), not after each edit:
        arming converts the whole list, and uploading 10000 ``!trigp`` entries one by one
        must stay linear. The positions are fixed in the physical frame when armed.
        """
        if command.name in _TRIGGER_LIST and command.executes:
            self._triggers_dirty = True
        elif self._triggers_dirty:
            self.arm_triggers()

    def arm_triggers(self) -> None:
        """Hand the list to the motion model from the list pointer on.

        Choices: list triggers fire only while ``trig`` is 1 and ``trigm`` is 20 or 21
        ("Trigcount increments on every executed trigger pulse", L13387; the trigger is
        globally disabled by ``!trig 0``, L12565). Every re-arm (any list instruction,
        ``!trig 1`` included) starts again at the stored pointer, which is 1 unless
        ``!trigi n`` moved it; the list then re-arms by travelling back behind that entry.
        """
        self._triggers_dirty = False
        mode = int(self.params.first("trigm"))
        if int(self.params.first("trig")) == 1 and mode in _DISTANCE_MODES:
            self._arm_distance(*_DISTANCE_MODES[mode])
            return
        entries = self.triggers.entries
        enabled = int(self.params.first("trig")) == 1 and mode in (20, 21)
        if not entries or not enabled:
            self.motion.clear_triggers()
            return
        axis = self.trigger_axis()
        units = self.motion.units(axis)
        self._trigger_base = self.triggers.pointer - 1
        try:
            self.motion.set_trigger_positions(
                axis, [units.pos_from_user(p) for p in entries[self._trigger_base:]])
        except MotionRefused:
            self.motion.clear_triggers()  # the lists module already refused bad orders

    def _arrival_pulse(self, time: float) -> None:
        """Modes 104 and 105: a pulse with the completion report, which autostatus 0 does
        not send (L12595-12836). Choice: every completed move counts, the trigger axis'
        or another's (the emulator does not tell the moves of one axis apart here)."""
        if int(self.params.first("trig")) == 1 and self.session.autostatus != 0 \
                and int(self.params.first("trigm")) in (104, 105):
            self.trigger_pulses(time, 1)
            self.motion.set_trigger_count(self.motion.trigger_count + 1)

    def _arm_distance(self, sense: int, shift: float) -> None:
        """Distance modes: a pulse every ``trigd`` from where the axis stands when they are
        armed (``!trig 1`` defines the start, L12565-12572), the first as the move starts
        ("First pulse when move starts") or half a distance on (modes 6-11), in the mode's
        sense; as many as a list holds at most."""
        axis = min(AXES.index(str(self.params.first("triga"))), self.axes - 1)
        units = self.motion.units(axis)
        start = self.motion.to_user(axis, self.motion.position(axis))
        step = float(self.params.first("trigd")) * sense
        # The first level a hair beyond the start: the move's first step crosses it.
        first = max(shift, 1e-9 / abs(step)) if step else shift
        levels = [start + (k + first) * step for k in range(MAX_TRIGGERS)]
        self._trigger_base = 0
        self.motion.set_trigger_positions(axis, [units.pos_from_user(p) for p in levels])

    def trigger_pulses(self, time: float, count: int, position: float | None = None) -> None:
        """Record ``count`` trigger pulses on the outputs ``trigo`` selects (L12860-12949:
        bit 0 TRIGGER_OUT, bit 1 TAKT_OUT; 0 and 4, 8, 12 send nothing), ``trigs`` µs long
        (L12950-12970), spaced by ``1/trigf`` (L13414-13440). The polarity is ``trigl``'s in
        the list modes 20 and 21 (L14177-14212) and the mode's own otherwise: modes 3-5,
        9-11 and the odd ones from 101 are active low (L12595-12836).

        Parameters
        ----------
        time
            When the first pulse begins.
        count
            How many pulses.
        position
            The trigger axis' position where they fired; ``None``: not by position.
        """
        outputs = int(self.params.first("trigo"))
        width = int(self.params.first("trigs")) / 1e6
        mode = int(self.params.first("trigm"))
        if mode in (20, 21):
            high = int(self.params.first("trigl")) == 1
        elif mode >= 100:
            high = mode % 2 == 0
        else:
            high = mode % 6 < 3
        period = 1.0 / float(self.params.first("trigf"))
        for n in range(count):
            for bit, output in ((1, TRIGGER_OUT), (2, TAKT_OUT)):
                if outputs & bit:
                    self.devices.pulses.append(
                        Pulse(time + n * period, output, width, high, position))

    def trigger_axis(self) -> int:
        """Index of the trigger axis (``triga``, or the axis the list was written for).

        Returns
        -------
        int
            The axis index.
        """
        letter = self.triggers.axis or str(self.params.first("triga"))
        return min(AXES.index(letter), self.axes - 1)

    def trigger_pointer(self) -> int:
        """``?trigi``: where the armed list is (1-based), else the stored pointer.

        Returns
        -------
        int
            The pointer.
        """
        armed = self.motion.trigger_index()
        if self._triggers_dirty or armed == 0:
            return self.triggers.pointer
        return self._trigger_base + armed

    def _record_cal_zero(self, letters: str) -> None:
        for index, letter in enumerate(letters[: self.axes]):
            if letter == "A":
                self.cal_zero[index] = self.motion.position(index)

    def reboot(self, now: float | None = None) -> None:
        """Restart like a power cycle: settings reload from the state file.

        Parameters
        ----------
        now
            The time; ``None`` for the motion model's.
        """
        self._boot(self.motion.now if now is None else now)


#: Reply shapes whose values are numbers (switch ``numbers`` applies to them).
_NUMERIC = frozenset({Shape.FLOAT, Shape.AXES_FLOAT, Shape.NUMBERS})
#: A number that printed as minus zero (``-0.0000``), as its own token.
_NEG_ZERO = re.compile(r"(?<![\w.])-(0(?:\.0+)?)(?![\w.])")
#: A positive decimal number with a fraction, as its own token.
_POSITIVE = re.compile(r"(?<![\w.+-])(\d+\.\d+)(?![\w.])")
_NUMBER_TOKEN = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)")


def _plus(match: re.Match[str]) -> str:
    text = match.group(1)
    return "+" + text if float(text) != 0.0 else text


def _reprint(token: str) -> str:
    """A token as a re-formatting firmware prints it: numbers shortest (``1.50`` -> ``1.5``,
    ``+2.0`` -> ``2``), other words as they are.

    Returns
    -------
    str
        The token as printed.
    """
    if not _NUMBER_TOKEN.fullmatch(token):
        return token
    text = format(Decimal(token).normalize(), "f")
    return "0" if text in ("-0", "+0") else text


def _bits_read(command: Command) -> bool:
    entry = command.instruction
    return bool(entry.write) and bool(entry.write[0].lead) and \
        entry.write[0].lead[0].kind is Kind.BITS
