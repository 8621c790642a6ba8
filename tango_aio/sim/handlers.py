"""Instructions of the emulator that do more than store a setting.

Each method ``i_<name>`` handles one instruction (``?`` reads and ``!`` writes alike) and
returns the reply lines, or ``None`` for no reply. Everything not listed here is a plain
setting handled generically by :class:`~tango_aio.sim.model.ControllerModel`.
"""

from __future__ import annotations

from collections.abc import Callable

from ..catalog import Command
from ..errors import ERROR_DESCRIPTIONS
from .lists import MAX_TRIGGERS, ListError
from .motion import ERR_NOT_EXECUTABLE, MotionConfig, MotionRefused
from .outputs import compensation_step, true_frequency
from .params import format_value
from .peripherals import Peripherals
from .port import ModelPort
from .snapshot import key_event

__all__ = ["Handlers", "build_handlers"]

Reply = list[str] | None

#: What ``sa`` prints after the letters, by the switch ``status_tail`` (L2668-2670, L2715).
_STATUS_TAILS = {"yes": ".-", "no": "", "dot": "."}


class Handlers(Peripherals):
    """The special instructions of one emulated controller."""

    def __init__(self, model: ModelPort) -> None:
        self.m = model

    # -- identity --------------------------------------------------------------------------

    def i_version(self, c: Command) -> Reply:
        """``?version``: ``TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00`` with the space
        before the last comma of the 1.71 examples (L1067, L1105); the older edition's
        example has none (old L426, switch ``version_format=old``). ``?version 1`` answers
        the number only (L1057-1059), or the whole line with ``version_value=line``."""
        cfg = self.m.config
        if c.values and self.m.firmware.version_value == "number":
            return [cfg.version]
        build = cfg.build
        if self.m.firmware.version_format == "old":
            build = build.replace(" , ", ", ")
        return [f"{cfg.model}, Version {cfg.version}, {build}"]

    def i_det(self, c: Command) -> Reply:
        return [str(self.m.config.det)]

    def i_detext(self, c: Command) -> Reply:
        det = self.m.config.det
        lines = [f"{det:05X}", f"= {self.m.axes} Axes"]
        if det & 0x800:
            lines.append("= Snapshot")
        if det & 0x2000:
            lines.append("= Trigger out")
        return lines

    def i_readsn(self, c: Command) -> Reply:
        return [self.m.config.serial]

    def i_ver(self, c: Command) -> Reply:
        return [f"Vers:LS{self.m.axes}2.00.038"]

    def i_iver(self, c: Command) -> Reply:
        return ["T04.35.020004"]

    def i_uptime(self, c: Command) -> Reply:
        return [str(int(self.m.motion.now - self.m.session.booted))]

    def i_temp(self, c: Command) -> Reply:
        return ["28.5"]

    def i_maxaxis(self, c: Command) -> Reply:
        return [str(self.m.axes)]

    def i_maxcur(self, c: Command) -> Reply:
        return [" ".join("1.25" for _ in self.m.present(c))]

    def i_etspresent(self, c: Command) -> Reply:
        return ["0000"]

    def i_stagesn(self, c: Command) -> Reply:
        if c.values and c.values[0] != -1:
            return ["---------"]
        return [" ".join(["---------"] * 4)] if not c.values else ["---------"]

    def i_maxpos(self, c: Command) -> Reply:
        mm = (self.m.config.motion or MotionConfig()).maxpos_mm
        return [self.axes_text(self.m.present(c), lambda i: self.position_text(
            i, self.m.motion.units(i).mm_to_rev(mm)))]

    def i_lockpos(self, c: Command) -> Reply:
        return [self.axes_text(self.m.present(c), lambda i: self.position_text(i, 0.0))]

    def i_pci(self, c: Command) -> Reply:
        return ["0"]

    # -- state and errors -------------------------------------------------------------------

    def i_autostatus(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.autostatus)]
        self.m.set_autostatus(int(c.values[0]))
        return None

    def i_err(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.error)]
        self.m.clear_error()
        return None

    def i_status(self, c: Command) -> Reply:
        return ["OK..." if self.m.error == 0 else f"ERR {self.m.error}"]

    def i_help(self, c: Command) -> Reply:
        """``help``: ``ERROR 5,number outside range`` (L2915-2919); ``?help N`` repeats N,
        or gives the text only with switch ``help_number=no``."""
        code = int(c.values[0]) if c.values else self.m.error
        texts = OLDER_HELP if self.m.firmware.instruction_set == "older" else HELP
        text = texts.get(code, ERROR_DESCRIPTIONS.get(code, "unknown error"))
        bare = c.values and self.m.firmware.help_number == "no"
        reply = text if bare else f"ERROR {code},{text}"
        return [reply.lower() if self.m.firmware.help_case == "lower" else reply]

    def i_service(self, c: Command) -> Reply:
        """``service``: several lines; ``END_SERVICE_PRINT.`` last from firmware
        1.60C/1.61 (L2937-2943), none before (switch ``service_end=no``)."""
        cfg = self.m.config
        lines = [f"{cfg.model} service print", f"Firmware {cfg.version}",
                 f"Serial {cfg.serial}", f"Axes {self.m.axes}", ""]
        if self.m.firmware.service_end == "yes":
            lines.append("END_SERVICE_PRINT.")
        return lines

    def i_save(self, c: Command) -> Reply:
        self.m.save()
        return ["OK..."]

    def i_restore(self, c: Command) -> Reply:
        if c.values == (-1,):
            # Factory reset: the saved set is deleted, then a software reset (L1805-1813).
            self.m.forget_saved()
            self.m.reboot()
            return None
        self.m.restore()
        return ["OK..."] if c.is_read else None

    def i_reset(self, c: Command) -> Reply:
        self.m.reboot()
        return None

    def i_pa(self, c: Command) -> Reply:
        if c.is_read:
            state = str(self.m.params.first("pa"))
            return [" ".join([state] * self.m.axes)] if c.values else [state]
        self.m.params.put_global("pa", (int(c.values[0]) if c.values else 1,))
        return None

    def i_encpos(self, c: Command) -> Reply:
        if not c.is_read:
            self.m.store(c)
            return None
        if c.axis is None:
            # '?encpos' reads the "ored" source of all axes: just one 0 or 1 (L11238-11240).
            values = self.m.params.read(c, self.m.axes).split()
            return ["1" if "1" in values else "0"]
        return [self.m.params.read(c, self.m.axes)]

    def i_axis(self, c: Command) -> Reply:
        """``!axis``/``?axis``: 1 enabled, 0 disabled, -1 power stage off (L3919-3960).
        What disabling or switching off a moving axis does to its move the manual does
        not say: switch ``disable_during_move``."""
        if c.is_read:
            return [self.m.params.read(c, self.m.axes)]
        motion = self.m.motion
        halted = [axis for axis, value in self.m.axis_map(c).items()
                  if int(value) != 1 and motion.is_moving(axis)]
        policy = self.m.firmware.disable_during_move
        if halted and policy == "refuse":
            raise MotionRefused(ERR_NOT_EXECUTABLE, "!axis: the axis moves")
        self.m.store(c)
        if policy == "stop":
            for axis in halted:
                motion.abort(axis)
        return None

    def i_swtyp(self, c: Command) -> Reply:
        if not c.is_read:
            self.m.store(c)
            return None
        return [self.swtyp_text(c) or self.m.params.read(c, self.m.axes)]

    # -- status of axes ---------------------------------------------------------------------

    def i_statusaxis(self, c: Command) -> Reply:
        """``sa``: one letter per axis and ``.-`` (L2662-2725).

        An absent or disabled axis: "Axis is not enabled, not available in hardware"
        (L2711) with no character printed, but the examples show ``-`` (``JM--.-`` on a
        2-axis unit, L2721). ``sa z`` on a 2-axis unit therefore answers ``-`` (not error
        1); the all-axes form shows ``-`` or leaves them out (switch ``absent_axes``).
        """
        letters = self.m.joystick_letters(self.m.motion.status_letters())
        if c.axis is not None:
            return [letters["xyza".index(c.axis)]]
        if self.m.firmware.absent_axes == "omit":
            letters = letters.replace("-", "")
        return [letters + _STATUS_TAILS[self.m.firmware.status_tail]]

    def i_calst(self, c: Command) -> Reply:
        return [self.axes_text(self.m.present(c), lambda i: str(self.m.motion.calst(i)))]

    def i_statuslimit(self, c: Command) -> Reply:
        return [self.m.motion.statuslimit()]

    def i_isvel(self, c: Command) -> Reply:
        digits = int(c.values[-1]) if c.values else 3
        return [self.axes_text(self.m.present(c), lambda i: format_value(
            self.m.motion.vel_to_user(i, self.m.motion.velocity(i)), digits))]

    def i_readsw(self, c: Command) -> Reply:
        # 12 characters: E0 of X Y Z A, then Ref of X Y Z A (always 0 on a TANGO), then
        # EE of X Y Z A (L5027-5078; the example "000000001000" is EE of X actuated).
        states = [self.m.motion.switch_state(index) if index < self.m.axes else (False, False)
                  for index in range(4)]
        e0 = "".join("1" if low else "0" for low, _ in states)
        ee = "".join("1" if high else "0" for _, high in states)
        return [e0 + "0000" + ee]

    def i_swin(self, c: Command) -> Reply:
        levels = []
        for index in range(4):
            e0, ee = self.m.motion.switch_state(index) if index < self.m.axes else (False, False)
            levels += ["0" if e0 else "1", "0" if ee else "1"]
        if c.values:
            return [levels[int(c.values[0])]]
        return ["".join(levels)]

    # -- positions ------------------------------------------------------------------------

    def i_pos(self, c: Command) -> Reply:
        """``?pos`` reads the encoder where ``!encpos`` 1 chose it and it is active, else
        the motor (L11193-11247)."""
        motion = self.m.motion

        def where(axis: int) -> float:
            if int(self.m.params.first("encpos", axis)) == 1 and self.m.encoder_active(axis):
                return self.m.encoder_position(axis)
            return motion.position(axis)

        if c.is_read:
            return [self.axes_text(self.m.present(c),
                                   lambda i: self.position_text(i, where(i)))]
        for axis, revs in self.to_revs(self.m.axis_map(c)).items():
            motion.set_position(axis, revs)
        return None

    def i_posclr(self, c: Command) -> Reply:
        motion = self.m.motion
        if c.is_read:
            return [self.axes_text(self.m.present(c),
                                     lambda i: self.position_text(i, motion.position_offset(i)))]
        for axis in self.m.present(c):
            motion.clear_position_offset(axis)
        return None

    def i_zero(self, c: Command) -> Reply:
        for axis in self.m.present(c):
            self.m.motion.zero(axis)
        return None

    i_clearpos = i_zero

    def i_distance(self, c: Command) -> Reply:
        motion = self.m.motion
        if c.is_read:
            return [self.axes_text(self.m.present(c), lambda i: self.position_text(
                i, motion.settings(i).distance))]
        for axis, revs in self.to_revs(self.m.axis_map(c)).items():
            motion.set_distance(axis, revs)
        return None

    def i_lim(self, c: Command) -> Reply:
        if c.is_read:
            return self._read_lim(c)
        values = [float(v) for v in c.values]
        indices = self.m.present(c) if c.axis else list(range((len(values) + 1) // 2))
        for slot, axis in enumerate(indices):
            if axis >= self.m.axes:
                raise ListError(1, "more values than axes")
            pair = values[2 * slot: 2 * slot + 2]
            lower = self.m.motion.from_user(axis, pair[0])
            upper = self.m.motion.from_user(axis, pair[1]) if len(pair) > 1 else None
            self.m.motion.set_limits(axis, lower, upper)
        return None

    def _read_lim(self, c: Command) -> Reply:
        def pair(axis: int) -> str:
            low, high = self.m.motion.limits(axis)
            return f"{self.position_text(axis, low)} {self.position_text(axis, high)}"

        indices = self.m.present(c)
        if c.axis is None and len(indices) > 1 and self._lim_cr_bug():
            # Firmware quirk (manual L4559-4619): an extra CR after the X pair.
            return [pair(indices[0]) + ",", ", ".join(pair(i) for i in indices[1:])]
        return [" ".join(pair(i) for i in indices)]

    def _lim_cr_bug(self) -> bool:
        """Whether ``?lim`` prints the extra CR: in extmode 0 only (L2196-2232,
        L4559-4621), or per switch ``lim_cr_bug`` never or in both extmodes."""
        bug = self.m.firmware.lim_cr_bug
        return bug == "both" or (bug == "extmode0" and int(self.m.params.first("extmode")) == 0)

    # -- motion ---------------------------------------------------------------------------
    # Each move handler records the job it started: its completion may owe an OK...
    # (switch move_ok=completion).

    def i_moa(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.move_absolute(self.to_revs(self.m.axis_map(c)))
        return None

    def i_mor(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.move_relative(self.to_revs(self.m.axis_map(c)))
        return None

    def i_m(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.move_repeat()
        return None

    def i_moc(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.move_center(self.m.present(c) if c.axis else None)
        return None

    def i_mol(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.move_lock(self.m.present(c) if c.axis else None)
        return None

    def i_cal(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.calibrate(self.m.present(c) if c.axis else None)
        return None

    def i_rm(self, c: Command) -> Reply:
        self.m.last_job = self.m.motion.range_measure(self.m.present(c) if c.axis else None)
        return None

    def i_vrm(self, c: Command) -> Reply:
        self.m.motion.virtual_range_measure(self.to_revs(self.m.axis_map(c)))
        return None

    def i_go(self, c: Command) -> Reply:
        if not c.values:
            self.m.motion.go_stop(self.m.present(c) if c.axis else None)
            return None
        self.m.motion.go(self.to_revs(self.m.axis_map(c)))
        return None

    def i_speed(self, c: Command) -> Reply:
        motion = self.m.motion
        if c.is_read:
            digits = int(c.values[-1]) if c.values else 3
            return [self.axes_text(self.m.present(c), lambda i: format_value(
                motion.vel_to_user(i, motion.velocity(i)), digits))]
        motion.speed({axis: motion.vel_from_user(axis, value)
                      for axis, value in self.m.axis_map(c).items()})
        return None

    def i_a(self, c: Command) -> Reply:
        """``a``: stop with stopaccel; aborted axes report ``E`` (L6832-6834; ``@`` in the
        older edition, switch ``abort_letter``). ``a`` itself answers nothing, or like a
        move once the axes stand (old L725, switch ``abort_report``)."""
        axis = self.m.present(c)[0] if c.axis else None
        self.m.motion.abort(axis, use_accel=-1 in c.values)
        if self.m.firmware.abort_report == "yes":
            self.m.owe_stop_report()
        return None

    def i_joy(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.params.first("joy"))]
        before = int(self.m.params.first("joy"))
        mode = int(c.values[0])
        self.m.params.put_global("joy", (mode,))
        self.m.follow_joystick()
        if mode == 0 and before != 0:
            # Disabling an enabled joystick sends a completion report (manual L7124-7154).
            self.m.report(self.completion_letters())
        return None

    # -- trigger list ---------------------------------------------------------------------
    # The model arms the list in the motion model lazily (ControllerModel.arm_triggers).

    def i_trigp(self, c: Command) -> Reply:
        triggers = self.m.triggers
        if c.is_read:
            index = int(c.values[0]) if c.values else self.m.trigger_pointer()
            return [self._trigger_text(triggers.read(index))]
        if c.values == (0,):
            triggers.clear(c.axis)  # '!trigp 0', '!trigp x 0' (L13835)
        elif len(c.values) == 1 and c.axis is not None:
            # '!trigp y 11.5' sets the axis and appends (L13971); a whole number is a
            # position here too, not an index without position.
            triggers.write(-1, float(c.values[0]), c.axis)
        elif len(c.values) == 1:
            raise ListError(6, "!trigp needs an index and a position")
        else:
            triggers.write(int(c.values[0]), float(c.values[1]), c.axis)
        self._list_written()
        return None

    def _trigger_text(self, value: float) -> str:
        axis = self.m.trigger_axis()
        return self.position_text(axis, self.m.motion.from_user(axis, value))

    def _list_written(self) -> None:
        """The list names the trigger axis and sets trigm 20/21 (L13767-13790)."""
        triggers = self.m.triggers
        if triggers.axis is not None:
            self.m.params.put_global("triga", (triggers.axis,))
        entries = triggers.entries
        if len(entries) >= 2:
            self.m.params.put_global("trigm", (20 if entries[1] > entries[0] else 21,))
        elif len(entries) == 1:
            # One entry: the direction follows from the current position (L13814).
            axis = self.m.trigger_axis()
            here = self.m.motion.to_user(axis, self.m.motion.position(axis))
            self.m.params.put_global("trigm", (20 if entries[0] >= here else 21,))

    def i_trigc(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.triggers.count())]
        self.m.triggers.shorten(int(c.values[0]) if c.values else 0)
        return None

    def i_trigi(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.trigger_pointer())]
        self.m.triggers.set_pointer(int(c.values[0]) if c.values else 1)
        return None

    def i_trigr(self, c: Command) -> Reply:
        triggers = self.m.triggers
        if c.is_read:
            start, end, count = triggers.span
            return [f"{self._trigger_text(start)} {self._trigger_text(end)} {count}"]
        start, end, count = float(c.values[0]), float(c.values[1]), int(c.values[2])
        if not 1 <= count <= MAX_TRIGGERS:
            raise ListError(5, f"trigger count {count} not in 1..{MAX_TRIGGERS}")
        # "!trigr internally writes its positions to the trigp list" (L13601-13603).
        step = (end - start) / (count - 1) if count > 1 else 0.0
        positions = [start + i * step for i in range(count)] if start != end else [start]
        triggers.fill(positions, c.axis)
        triggers.span = (start, end, count)
        self._list_written()
        if start != end:
            self.m.params.put_global("trigm", (20 if end > start else 21,))
        return None

    def i_trigs(self, c: Command) -> Reply:
        """Widths and delay in steps of 40 µs, each rounded to the nearest (90 → 80,
        100 → 120) and read back so (L12959-12967, the secondary ones L12976-12981)."""
        if c.is_read:
            # "The 2nd and 3rd parameter cannot be read back by ?trigs" (L13001-13003).
            return [self.m.params.read(c, self.m.axes).split()[0]]
        self.m.params.put_global("trigs", tuple((int(v) + 20) // 40 * 40 for v in c.values))
        return None

    def i_trigcomp(self, c: Command) -> Reply:
        """Kept as written, or on its 10 µs step (switch ``trigcomp_read``, L13057-13167);
        the trigger works with the step either way (``compensation_step``)."""
        if c.is_read:
            return [self.m.params.read(c, self.m.axes)]
        value = int(c.values[0])
        if self.m.firmware.trigcomp_read == "step":
            value = compensation_step(value)
        self.m.params.put_global("trigcomp", (value,))
        return None

    def i_trigf(self, c: Command) -> Reply:
        """The controller keeps the frequency its 40 µs ticks give and reads back "the
        true value" (L13234-13278; switch ``trigf_round``)."""
        if c.is_read:
            return [self.m.params.read(c, self.m.axes)]
        hz = true_frequency(float(c.values[0]), self.m.firmware.trigf_round)
        self.m.params.put_global("trigf", (hz,))
        return None

    def i_trigcount(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.motion.trigger_count)]
        self.m.motion.set_trigger_count(int(c.values[0]))
        return None

    # -- snapshot array -------------------------------------------------------------------

    def _row_text(self, row: tuple[float | None, ...], indices: list[int]) -> str:
        def one(axis: int) -> str:
            value = row[axis] if axis < len(row) else None
            value = 0.0 if value is None else value  # choice: an invalid entry reads 0
            return self.position_text(axis, self.m.motion.from_user(axis, value))

        return self.axes_text(indices, one)

    def i_snsa(self, c: Command) -> Reply:
        snapshots = self.m.snapshots
        if c.is_read:
            return [self._row_text(snapshots.read(int(c.values[0])), self.m.present(c))]
        index = int(c.values[0])
        if index == 0:
            snapshots.clear()
            return None
        values = self.m.axis_map(c, skip_lead=1)
        if c.axis is not None:
            (axis, value), = values.items()
            snapshots.write_axis(index, axis, value, self.m.axes)
            return None
        # The axes not given hold no position: a step leaves them (L15389-15390).
        snapshots.write(index, tuple(values.get(axis) for axis in range(self.m.axes)))
        return None

    def i_snsc(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.snapshots.count())]
        self.m.snapshots.shorten(int(c.values[0]) if c.values else 0)
        return None

    def i_snsi(self, c: Command) -> Reply:
        if c.is_read:
            return [str(self.m.snapshots.pointer)]
        self.m.snapshots.set_pointer(int(c.values[0]) if c.values else 0)
        return None

    def i_snsp(self, c: Command) -> Reply:
        snapshots = self.m.snapshots
        if c.is_read:
            return [self._row_text(snapshots.last, self.m.present(c))]
        values = self.m.axis_map(c)
        row = tuple(values.get(axis, 0.0) for axis in range(self.m.axes))
        snapshots.capture(row)
        return None

    def i_snse(self, c: Command) -> Reply:
        """Emulate key F1..F4 (L15392): the key is latched (``keyl``) and, with snapshots
        enabled (``sns 1``), does what the mode does with it (:mod:`.snapshot`)."""
        key_event(self.m, int(c.values[0]))
        return None

    def _snapshot_setting(self, c: Command) -> Reply:
        """``!sns`` and ``!snsm`` also clear the latched keys (L14650-14652,
        L14841-14843)."""
        if c.is_read:
            return [self.m.params.read(c, self.m.axes)]
        self.m.store(c)
        self.m.session.keys_latched[:] = [0] * len(self.m.session.keys_latched)
        return None

    i_sns = i_snsm = _snapshot_setting

    def i_snsv(self, c: Command) -> Reply:
        voltages = self.m.snapshots.voltages
        if c.is_read:
            return [str(voltages.get(abs(int(c.values[0])), 0))]
        voltages[int(c.values[0])] = int(c.values[1])
        return None


#: ``help`` texts documented by the manual (L2915-2919).
HELP: dict[int, str] = {0: "no error", 5: "number outside range", 29: "servo amplifier off"}
#: ... and by the older edition: ``help => ERROR 4,unknown keyword`` (old L819).
OLDER_HELP: dict[int, str] = {**HELP, 4: "unknown keyword"}


def build_handlers(model: ModelPort) -> dict[str, Callable[[Command], Reply]]:
    """Map instruction names to the bound ``i_<name>`` methods."""
    handlers = Handlers(model)
    return {name[2:]: getattr(handlers, name) for name in dir(Handlers)
            if name.startswith("i_")}
