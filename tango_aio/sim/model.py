"""The emulated controller's interpreter: parses lines with the catalog and answers them.

:class:`ControllerModel` implements the :class:`~tango_aio.sim.wire.LineHandler` protocol:
the wire hands it one command line at a time, and it answers through ``emit``. It is
sans-IO and time comes from the wire, so it runs in virtual time in tests and in real
time in the servers.

How it answers (the same decisions as the driver's core, by construction: both call
:func:`tango_aio.core.expectation`):

* every line is parsed by :func:`tango_aio.instructions.parse`; a line the catalog rejects
  sets the error number the catalog names (1-7) and executes nothing;
* each executed instruction overwrites the error state (manual L2853), except the reads
  ``?err``, ``?status`` and ``help`` themselves;
* autostatus 4 echoes executing lines before running them, autostatus 2 acknowledges ``!``
  lines after running them (``OK...`` / ``ERR n``, always with a number), ``save`` answers
  in every mode, completion reports follow the mode in force when the move ends;
* a read that fails for a semantic reason (``?trigp 99`` beyond the list) still answers
  with a zero value and sets the error, so a host waiting for a line never hangs; a line
  rejected by the parser answers nothing (a real interpreter cannot know its shape);
* a read whose catalog reply is "none" (``?flash``, "Response: None") answers nothing;
* an empty line is ignored without touching the error state;
* ``restore`` reloads the saved parameters only; ``reset`` and ``restore -1`` restart
  (autostatus 1, moves stopped, counters 0 at the power-on position);
* the trigger list is handed to the motion model lazily, before the next instruction that
  is not a trigger-list instruction (see :meth:`ControllerModel.arm_triggers`);
* an unexpected exception in a handler (an emulator bug) does not stop the controller:
  the line sets error 2 and the exception is kept in ``internal_errors`` for tests.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ..core import expectation
from ..errors import ERROR_DESCRIPTIONS, InvalidCommandError
from ..instructions import (
    AXES,
    INSTRUCTIONS,
    Command,
    Context,
    Form,
    Kind,
    Shape,
    parse,
)
from .clock import host_now
from .lists import ListError, SnapshotList, TriggerList
from .motion import MotionConfig, MotionModel, MotionRefused, MoveFinished
from .params import ParamStore, format_value, position_digits
from .state import StateFileError, load_state, save_state
from .wire import Emit

__all__ = ["ControllerModel", "Refused", "SimConfig"]


class Refused(Exception):
    """An instruction was not executed; ``code`` is the error number to set."""

    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(message or ERROR_DESCRIPTIONS.get(code, "error"))
        self.code = code


#: Option bits of ``?det``: trigger out and snapshot (manual L1119-1185).
DEFAULT_OPTIONS = 0x2800


@dataclass(frozen=True)
class SimConfig:
    """Identity and static configuration of an emulated controller."""

    axes: int = 3
    model: str = "TANGO-DT"
    firmware: str = "1.71"
    build: str = "Jun  4 2019 , 12:00:00"
    serial: str = "190604001"
    options: int = DEFAULT_OPTIONS
    #: Where ``save`` persists the saved parameters (JSON, written atomically).
    state_file: Path | None = None
    #: Extra interpreter time of blocking instructions, in seconds.
    reset_time: float = 1.0
    motion: MotionConfig | None = None

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
_TRIGGER_LIST = frozenset({"trig", "trigm", "triga", "trigp", "trigc", "trigi", "trigr"})
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


class ControllerModel:
    """An emulated TANGO controller (the interpreter behind the wire)."""

    def __init__(self, emit: Emit, config: SimConfig | None = None,
                 now: float | None = None) -> None:
        self.config = config or SimConfig()
        self._emit = emit
        #: Unexpected exceptions raised by handlers (bugs), as ``line: exception`` texts.
        self.internal_errors: list[str] = []
        self._handlers = self._build_handlers()
        # The servers run the wire on the running loop's clock (not time.monotonic()
        # under uvloop), so the default start time is that clock's now.
        self._boot(host_now() if now is None else now)

    # -- lifecycle -------------------------------------------------------------------------

    def _boot(self, now: float) -> None:
        motion_config = self.config.motion or MotionConfig(n_axes=self.config.axes)
        self.motion = MotionModel(motion_config, start_time=now)
        self.params = ParamStore()
        self.session = _Session(booted=now)
        self.triggers = TriggerList()
        self.snapshots = SnapshotList()
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
        """The current error number (what ``?err`` answers)."""
        return self.session.err

    @property
    def autostatus(self) -> int:
        """The current autostatus mode."""
        return self.session.autostatus

    def context(self) -> Context:
        """The parser context: dims, axes, extmode."""
        groups = self.params.axis_values["dim"]  # what params.first("dim", i) reads
        dims = tuple(int(groups[i][0]) for i in range(len(AXES)))
        return Context(dims, self.axes, int(self.params.first("extmode")))  # type: ignore[arg-type]

    # -- LineHandler protocol ----------------------------------------------------------------

    def handle_line(self, line: bytes, now: float) -> None:
        """Execute one command line (no CR)."""
        self.poll(now)
        text = line.decode("latin-1").strip()
        if not text:
            return
        context = self.context()
        try:
            command = parse(text, context)
        except InvalidCommandError as exc:
            self._rejected(text, exc.code)
            return
        self._run(command, text, context)

    def line_too_long(self, head: bytes, now: float) -> None:
        """A line over 255 characters: error 3, nothing executed."""
        self.poll(now)
        self._rejected(head.decode("latin-1"), 3)

    def ctrl_c(self, now: float) -> None:
        """Ctrl+C stops every axis (the wire already cleared the input buffer)."""
        self.poll(now)
        self.motion.emergency_stop()

    def processing_time(self, line: bytes) -> float:
        """Extra interpreter time: ``reset`` and ``restore -1`` take a second (L1837)."""
        words = line.decode("latin-1").lower().lstrip("!?").split()
        if words[:1] == ["reset"] or words[:2] == ["restore", "-1"]:
            return self.config.reset_time
        return 0.0

    def poll(self, now: float) -> None:
        """Advance the motion model and report finished moves."""
        for event in self.motion.advance(now):
            if isinstance(event, MoveFinished):
                if event.kind == "cal":
                    self._record_cal_zero(event.letters)
                self._report_completion(event.letters)

    def next_deadline(self) -> float | None:
        """When the motion model next changes state."""
        return self.motion.next_event_time()

    # -- execution -------------------------------------------------------------------------

    def _rejected(self, text: str, code: int) -> None:
        self.session.err = code
        mode = self.session.autostatus
        if mode == 4 and text.startswith("!"):
            self._send(text)
        if mode == 2 and text.startswith("!"):
            self._send(f"ERR {code}")

    def _run(self, command: Command, text: str, context: Context | None = None) -> None:
        # ``context``: what self.context() is now (handle_line computed it for parsing).
        expect = expectation(command, self.session.autostatus, context or self.context())
        if expect.echo:
            self._send(text)
        self._prepare_triggers(command)
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
        for reply in lines or ():
            self._send(reply)
        if expect.ack:
            self._send("OK..." if code == 0 else f"ERR {code}")

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
            return [f"ERR {code}"] if command.instruction.exec_reply is Shape.ACK else None
        return ["0"]

    def _send(self, text: str) -> None:
        self._emit(text.encode("latin-1") + b"\r")

    def _report_completion(self, letters: str) -> None:
        mode = self.session.autostatus
        if mode in (1, 2, 4):
            self._send(letters + ".")
        elif mode == 3:
            self._send("")

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
        """Keep the values of a plain set command in the settings store."""
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
                                               "caliboffset", "rmoffset", "lim"):
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
            vel = units.vel_from_user(self.params.number("vel", index))
            if vel != settings.vel:
                self.motion.set_vel(index, vel)

    # -- persistence -----------------------------------------------------------------------

    def _saved_names(self) -> list[str]:
        return [n for n, e in INSTRUCTIONS.items() if e.saved
                and (n in self.params.axis_values or n in self.params.global_values)]

    def _load_saved(self) -> None:
        load_state(self.config.state_file, self.params)  # choices: tango_aio/sim/state.py

    def save(self) -> None:
        """Persist the saved parameters to :attr:`SimConfig.state_file` atomically.

        A failed write is refused with error 73 ("internal error, e.g. eeprom data
        corruption"; the manual names no number for a failed save) and leaves the previous
        file intact.
        """
        path = self.config.state_file
        if path is None:
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

    # -- handlers --------------------------------------------------------------------------

    def _build_handlers(self) -> dict[str, Handler]:
        from .handlers import build_handlers

        return build_handlers(self)

    # Helpers used by the handlers module.

    def present(self, command: Command) -> list[int]:
        """Axis indices a command addresses: its axis letter, else every present axis."""
        if command.axis is not None:
            index = AXES.index(command.axis)
            if index >= self.axes:
                raise Refused(1, f"axis {command.axis} is not present")
            return [index]
        return list(range(self.axes))

    def axis_map(self, command: Command, skip_lead: int = 0) -> dict[int, float]:
        """Per-axis values of a command as ``{axis index: value}`` in user units."""
        values = [float(v) for v in command.values[skip_lead:]]
        if command.axis is not None:
            return {self.present(command)[0]: values[0]} if values else {}
        if len(values) > self.axes:
            raise Refused(1, "more values than axes")
        return dict(enumerate(values))

    def to_revs(self, values: Mapping[int, float]) -> dict[int | str, float]:
        """Convert user-unit positions to motor revolutions."""
        return {axis: self.motion.from_user(axis, value) for axis, value in values.items()}

    def position_text(self, axis: int, revs: float) -> str:
        """Format a position (revolutions) in the axis' dim units with resolution digits."""
        digits = position_digits(int(self.params.first("resolution")),
                                 int(self.params.first("dim", axis)))
        return format_value(self.motion.to_user(axis, revs), digits)

    def axes_text(self, indices: Iterable[int], value: Callable[[int], str]) -> str:
        """Join per-axis texts."""
        return " ".join(value(index) for index in indices)

    def completion_letters(self) -> str:
        """A completion report with ``@`` for every present axis (``!joy 0``)."""
        return "".join("@" if i < self.axes else "-" for i in range(len(AXES)))

    def report(self, letters: str) -> None:
        """Send a completion report in the current autostatus mode."""
        self._report_completion(letters)

    def set_autostatus(self, mode: int) -> None:
        """Switch the autostatus mode."""
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
        entries = self.triggers.entries
        enabled = int(self.params.first("trig")) == 1 and \
            int(self.params.first("trigm")) in (20, 21)
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

    def trigger_axis(self) -> int:
        """Index of the trigger axis (``triga``, or the axis the list was written for)."""
        letter = self.triggers.axis or str(self.params.first("triga"))
        return min(AXES.index(letter), self.axes - 1)

    def trigger_pointer(self) -> int:
        """``?trigi``: where the armed list is (1-based), else the stored pointer."""
        armed = self.motion.trigger_index()
        if self._triggers_dirty or armed == 0:
            return self.triggers.pointer
        return self._trigger_base + armed

    def _record_cal_zero(self, letters: str) -> None:
        for index, letter in enumerate(letters[: self.axes]):
            if letter == "A":
                self.cal_zero[index] = self.motion.position(index)

    def reboot(self, now: float | None = None) -> None:
        """Restart like a power cycle: settings reload from the state file."""
        self._boot(self.motion.now if now is None else now)

    def form_is_set(self, command: Command) -> bool:
        """Whether the command was sent with ``!`` (or an executing bare form)."""
        return command.form is Form.SET or command.executes


def _bits_read(command: Command) -> bool:
    entry = command.instruction
    return bool(entry.write) and bool(entry.write[0].lead) and \
        entry.write[0].lead[0].kind is Kind.BITS
