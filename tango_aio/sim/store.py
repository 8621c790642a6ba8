"""The emulated controller's state: its settings (the parameter store mirrored into the
motion model), the saved parameters, and the trigger list handed to the motion model."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
    Kind,
    Shape,
)
from ..errors import ERROR_DESCRIPTIONS
from .config import SimConfig
from .devices import TAKT_OUT, Devices, Drift, Pulse
from .lists import MAX_TRIGGERS, TriggerList
from .motion import MotionModel, MotionRefused
from .outputs import Clock, OutputSettings, compensation_step, event_pulses, precise
from .params import ParamStore
from .profiles import Firmware
from .state import StateFileError, load_state, save_state


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
#: Instructions that change the trigger list, whether or how it fires, or the clocks of
#: the periodic outputs (re-armed lazily; "Before enabling the trigger function by '!trig
#: 1', please ensure that all trigger settings have been made", L12529-12530).
_TRIGGER_LIST = frozenset({"trig", "trigm", "triga", "trigp", "trigc", "trigi", "trigr",
                           "trigd", "trigf", "trigo", "trigbf", "trigcomp", "trigenc"})
#: The one-way distance modes (L12595-12836): the sense of travel (+1 forward, -1
#: backward) and the shift in distances.
_DISTANCE_MODES = {0: (1, 0.0), 3: (1, 0.0), 2: (-1, 0.0), 5: (-1, 0.0),
                   6: (1, 0.5), 9: (1, 0.5), 8: (-1, 0.5), 11: (-1, 0.5)}
#: The bidirectional distance modes (L12632, L12707) and whether they are shifted by
#: half a distance (7, 10: L12689-12717).
_BIDIRECTIONAL = {1: False, 4: False, 7: True, 10: True}
#: The periodic modes, "Does not depend on position" (L12754-12784).
_PERIODIC = (100, 101)


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
    #: Job ids of the moves snapshot steps started (switch ``snapshot_step_report``).
    snapshot_jobs: set[int] = field(default_factory=set)
    #: A change of the snapshot input before this time is not detected (``snsf``).
    snapshot_quiet_until: float = float("-inf")


def _bits_read(command: Command) -> bool:
    entry = command.instruction
    return bool(entry.write) and bool(entry.write[0].lead) and \
        entry.write[0].lead[0].kind is Kind.BITS


class ModelStore:
    """The settings, the saved parameters and the trigger list of an emulated controller."""

    config: SimConfig
    firmware: Firmware
    motion: MotionModel
    params: ParamStore
    session: _Session
    triggers: TriggerList
    devices: Devices
    _eeprom: tuple[dict[str, list[Any]], dict[str, Any]] | None
    _triggers_dirty: bool
    _trigger_base: int
    #: When the last trigger instruction ran: where the periodic clocks start.
    _trigger_time: float
    #: The periodic mode's clock (100, 101) and the secondary output's own (trigo 12-15).
    _periodic: Clock | None
    _wave: Clock | None

    @property
    def axes(self) -> int:
        """Number of configured axes."""
        return self.config.axes

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
        power on), and the ±twi window is met at once (no deviation is modelled)."""
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
        """Persist the saved parameters to :attr:`SimConfig.state_file` atomically."""
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
        positions, moves, lists and the autostatus mode stay as they are."""
        factory = ParamStore()
        for name in self._saved_names():
            if name in factory.axis_values:
                self.params.axis_values[name] = list(factory.axis_values[name])
            else:
                self.params.global_values[name] = factory.global_values[name]
        self._load_saved()
        self._sync_all()

    # -- trigger list ----------------------------------------------------------------------

    def _prepare_triggers(self, command: Command) -> None:
        """Arm the trigger list in the motion model lazily."""
        if command.name in _TRIGGER_LIST and command.executes:
            self._triggers_dirty = True
            self._trigger_time = self.motion.now
            self._periodic = self._wave = None  # until re-armed, from this line's time
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
        on = int(self.params.first("trig")) == 1
        self._arm_clocks(on, mode)
        self._arm_source()
        if on and mode in _DISTANCE_MODES:
            self._arm_distance(*_DISTANCE_MODES[mode])
            return
        if on and mode in _BIDIRECTIONAL:
            axis = self._distance_axis()
            self.motion.set_trigger_grid(
                axis, self.motion.compared_position(axis),
                self.motion.from_user(axis, float(self.params.first("trigd")))
                - self.motion.from_user(axis, 0.0), shifted=_BIDIRECTIONAL[mode],
                neighbours=self.firmware.bidirectional_next == "neighbours")
            return
        entries = self.triggers.entries
        enabled = on and mode in (20, 21)
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
        axis = self._distance_axis()
        units = self.motion.units(axis)
        start = self.motion.to_user(axis, self.motion.compared_position(axis))
        step = float(self.params.first("trigd")) * sense
        # The first level a hair beyond the start: the move's first step crosses it.
        first = max(shift, 1e-9 / abs(step)) if step else shift
        levels = [start + (k + (first if k == 0 else shift)) * step
                  for k in range(MAX_TRIGGERS)]
        self._trigger_base = 0
        self.motion.set_trigger_positions(axis, [units.pos_from_user(p) for p in levels])

    def _distance_axis(self) -> int:
        return min(AXES.index(str(self.params.first("triga"))), self.axes - 1)

    def _arm_clocks(self, on: bool, mode: int) -> None:
        """The periodic mode's pulses every ``1/trigf`` (L12754-12770, L13223-13278), the
        first at ``!trig 1`` or a period later (switch ``periodic_first``); the secondary
        output's own square wave at ``trigbf`` (trigo 14, 15: "fixed width of 50%",
        L14444-14476) while the trigger is enabled (L12578-12580)."""
        start = self._trigger_time
        if on and mode in _PERIODIC and self._periodic is None:
            period = 1.0 / float(self.params.first("trigf"))
            first = start if self.firmware.periodic_first == "enable" else start + period
            self._periodic = Clock(first, period)
        outputs = int(self.params.first("trigo"))
        if on and outputs >= 12 and outputs & 2 and self._wave is None:
            self._wave = Clock(start, 1.0 / float(self.params.first("trigbf")))
        self.run_clocks(self.motion.now)

    def start_clocks(self) -> None:
        """Start the periodic outputs a trigger instruction enabled, at once (the
        position triggers wait for the next other instruction, :meth:`arm_triggers`)."""
        if self._triggers_dirty:
            self._arm_clocks(int(self.params.first("trig")) == 1,
                             int(self.params.first("trigm")))

    def run_clocks(self, now: float) -> None:
        """Record the periodic outputs' pulses up to ``now`` (the last :attr:`Devices.limit`
        of them when more are due; ``trigcount`` counts every periodic event, L13387-13389,
        but not the precise frequency's, L13368)."""
        devices, high = self.devices, self._active_high()
        if self._periodic is not None:
            first, count = self._periodic.due(now)
            self.motion.set_trigger_count(self.motion.trigger_count + count)
            settings = self._output_settings()
            shown = min(count, devices.limit)
            devices.dropped += (count - shown) * len(event_pulses(0.0, high, settings))
            times = [self._periodic.time(k) for k in range(first + count - shown, first + count)]
            devices.record(p for t in times for p in event_pulses(t, high, settings))
        if self._wave is not None:
            first, count = self._wave.due(now)
            shown = min(count, devices.limit)
            devices.dropped += count - shown
            half = self._wave.period / 2
            devices.record(Pulse(self._wave.time(k), TAKT_OUT, half, high)
                           for k in range(first + count - shown, first + count))

    def _arm_source(self) -> None:
        """What position triggers compare: ``trigcomp`` looks ahead by its time at the
        current velocity (L13057-13167, in its 10 µs steps); ``trigenc 1`` compares the
        encoder position where the axis' encoder is active, else the motor's
        (L13168-13210)."""
        axis = self._distance_axis() if int(self.params.first("trigm")) not in (20, 21) \
            else self.trigger_axis()
        lead = compensation_step(int(self.params.first("trigcomp"))) / 1e6
        drift = Drift()
        if int(self.params.first("trigenc")) == 1 and self.encoder_active(axis):
            drift = self.devices.drift.get(axis, Drift())
        self.motion.set_trigger_source(axis, lead=lead, scale=1.0 - drift.slip,
                                       offset=drift.offset)

    def encoder_active(self, axis: int) -> bool:
        """``?enc``: active where ``encmask`` is set and an encoder is fitted (the
        controller activates encoders, L10485-10545), or where ``!enc 1`` forced it (the
        manual advises against it, L10527-10545, but allows it)."""
        return int(self.params.first("enc", axis)) == 1 or (
            axis in self.devices.encoders and int(self.params.first("encmask", axis)) == 1)

    def encoder_position(self, axis: int) -> float:
        """The encoder's position of ``axis`` (user frame, revolutions): the motor's, as
        :attr:`Devices.drift` deviates it."""
        drift = self.devices.drift.get(axis, Drift())
        return self.motion.position(axis) * (1.0 - drift.slip) + drift.offset

    def _output_settings(self) -> OutputSettings:
        trigs = self.params.global_values["trigs"]
        # '!trigs w d w2' gives OUT2 a delay and width in the 1:1 mode (L12973-13001);
        # '!trigs w' and the power-on values (read as 0 0) leave it a copy of OUT1.
        out2 = (int(trigs[1]) / 1e6, int(trigs[2]) / 1e6) \
            if len(trigs) == 3 and (int(trigs[1]), int(trigs[2])) != (0, 0) else None
        return OutputSettings(int(self.params.first("trigo")), int(trigs[0]) / 1e6, out2,
                              precise(self.params.number("trigbwidth")),
                              precise(self.params.number("trigbdelay")))

    def _active_high(self) -> bool:
        """The polarity: ``trigl``'s in the list modes 20 and 21 (L14177-14212), the
        mode's own otherwise: modes 3-5, 9-11 and the odd ones from 101 are active low
        (L12595-12836)."""
        mode = int(self.params.first("trigm"))
        if mode in (20, 21):
            return int(self.params.first("trigl")) == 1
        return mode % 2 == 0 if mode >= 100 else mode % 6 < 3

    def trigger_pulses(self, time: float, count: int, position: float | None = None) -> None:
        """Record ``count`` trigger events, spaced by ``1/trigf`` (L13414-13440), on the
        outputs ``trigo`` selects (L12860-12949: bit 0 TRIGGER_OUT, bit 1 TAKT_OUT), OUT1
        ``trigs`` µs long (L12950-12970), OUT2 as its function says
        (:func:`~tango_aio.sim.outputs.event_pulses`, chapter 22)."""
        settings, high = self._output_settings(), self._active_high()
        period = 1.0 / float(self.params.first("trigf"))
        self.devices.record(pulse for n in range(count) for pulse in
                            event_pulses(time + n * period, high, settings, position))

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
