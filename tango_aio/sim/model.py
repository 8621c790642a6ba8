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

from collections.abc import Callable
from typing import Any

from ..catalog import (
    AXES,
    Command,
    Context,
    Shape,
    parse,
)
from ..errors import InvalidCommandError
from .clock import host_now
from .config import SimConfig
from .devices import Devices, Drift
from .handlers import build_handlers
from .lists import ListError, SnapshotList, TriggerList
from .motion import MotionConfig, MotionModel, MotionRefused, MoveFinished, TriggerFired
from .params import ParamStore
from .profiles import Firmware
from .replies import ReplyStyle
from .snapshot import active_level, input_changed
from .store import (
    ModelStore,
    Refused,
    _Session,
)
from .wire import Emit

__all__ = ["ControllerModel", "Refused", "SimConfig"]


Handler = Callable[[Command], list[str] | None]

#: Reads/writes of these instructions never change the error state (manual L2837).
_ERROR_NEUTRAL = frozenset({"err", "status", "help"})


class ControllerModel(ModelStore, ReplyStyle):
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
        self._trigger_time = now
        self._periodic = self._wave = None
        self._load_saved()
        self._sync_all()

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
                stepped = event.job_id in self.session.snapshot_jobs
                self.session.snapshot_jobs.discard(event.job_id)
                if not stepped or self.firmware.snapshot_step_report == "yes":
                    self._report_completion(event.letters, event.job_id)
                self._arrival_pulse(event.time)
            elif isinstance(event, TriggerFired):
                self.trigger_pulses(event.time, 1,
                                    self.motion.to_user(event.axis, event.position))
        self.start_clocks()
        self.run_clocks(now)
        self._send_stop_report()

    def set_encoder_drift(self, axis: str, slip: float = 0.0, offset: float = 0.0) -> None:
        """Let the encoder of ``axis`` deviate from the motor position: it reads
        ``motor * (1 - slip) + offset`` (``offset`` in the axis' dim unit now). ``?pos``
        shows it with ``!encpos`` 1 (L11193-11247), ``?ctrdiff`` in closed loop
        (L12396-12443), and triggers compare it with ``trigenc 1`` (L13168-13210), where
        the encoder is active.

        Parameters
        ----------
        axis
            The axis letter.
        slip
            The fraction of the motor's travel the encoder does not see, below 1.
        offset
            A constant deviation, in the axis' dim unit.

        Raises
        ------
        ValueError
            ``slip`` is 1 or more.
        """
        if not slip < 1.0:
            raise ValueError(f"a slip is below 1, not {slip}")
        index = AXES.index(axis)
        revs = self.motion.from_user(index, offset) - self.motion.from_user(index, 0.0)
        self.devices.drift[index] = Drift(slip, revs)
        self._arm_source()

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

    def set_input(self, group: str, index: int, level: bool,
                  now: float | None = None) -> None:
        """Drive input ``index`` (from 0) of ``group`` (``digin``, ``edigin``,
        ``adigin``) to ``level``. A change of an AUX input with the snapshot function
        (``adiginfunc`` 2, input 3 by default, L9203-9218) to its active level is a
        snapshot event (:mod:`tango_aio.sim.snapshot`).

        Parameters
        ----------
        group
            The input group.
        index
            The input, from 0.
        level
            The new level.
        now
            The time (default: the host clock).

        Raises
        ------
        ValueError
            No such input.
        """
        levels = self.devices.inputs.get(group)
        if levels is None or not 0 <= index < len(levels):
            raise ValueError(f"no input {group} {index}")
        now = host_now() if now is None else now
        self.poll(now)
        before = levels[index]
        self.devices.set_input(group, index, level)
        if group == "adigin" and before != int(level):
            input_changed(self, index, bool(level), now)

    def pulse_snapshot_input(self, index: int = 3, now: float | None = None) -> None:
        """One pulse on AUX input ``index`` (3, the SnapShot pin, by default): to its
        active level (``snsl``) and back, as a camera's trigger output drives it; from
        the active level, it first goes inactive.

        Parameters
        ----------
        index
            The AUX input, from 0.
        now
            The time (default: the host clock).
        """
        now = host_now() if now is None else now
        active = active_level(self)
        for level in (not active, active, not active):
            self.set_input("adigin", index, level, now)

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
        ``version_value=line`` a value for ``version`` is ignored instead."""
        if self.firmware.instruction_set != "older":
            return False
        entry = command.instruction
        ignored = entry.name == "version" and self.firmware.version_value == "line"
        return not entry.in_older_manual or (entry.older_without_values and not ignored
                                             and bool(command.values))

    def _rejected(self, text: str, code: int) -> None:
        """A line the parser refused: nothing runs, the error is set."""
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
