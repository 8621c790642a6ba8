"""Instructions of the emulator for hardware it does not model, and indexed settings.

The emulated controller has no encoders, no closed loop, no HDI device and no I/O
extension; the reads of such hardware answer plausible idle values, but always in the
*shape* the manual documents (number of values, digits, flag-string width), so that a host
never waits for a line that does not come or fails to parse one. The indexed settings
(``joyspeed 2 25``, ``anaout c 1 25.3``, ``adiginfunc 1 2``) keep one value per index
instead of storing the index as a value.

:class:`Peripherals` is a mixin of :class:`~tango_aio.sim.handlers.Handlers`; every
``i_<name>`` here handles one instruction like the methods there.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from ..catalog import AXES, Command
from .devices import TAKT_OUT, Pulse
from .params import INDEXED, format_value, position_digits
from .port import ModelPort

__all__ = ["Peripherals"]

Reply = list[str] | None



class Peripherals:
    """Reads of unmodelled hardware and indexed settings, and the helpers every handler
    uses to read and print positions (mixin of ``Handlers``)."""

    m: ModelPort

    def _per_axis(self, c: Command, value: str) -> str:
        return " ".join(value for _ in self.m.present(c))

    # -- helpers of every handler ------------------------------------------------------

    def to_revs(self, values: Mapping[int, float]) -> dict[int | str, float]:
        """Convert user-unit positions to motor revolutions."""
        return {axis: self.m.motion.from_user(axis, value) for axis, value in values.items()}

    def position_text(self, axis: int, revs: float) -> str:
        """Format a position (revolutions) in the axis' dim units with resolution digits."""
        digits = position_digits(int(self.m.params.first("resolution")),
                                 int(self.m.params.first("dim", axis)))
        return format_value(self.m.motion.to_user(axis, revs), digits)

    def axes_text(self, indices: Iterable[int], value: Callable[[int], str]) -> str:
        """Join per-axis texts."""
        return " ".join(value(index) for index in indices)

    def completion_letters(self) -> str:
        """A completion report with ``@`` for every present axis (``!joy 0``)."""
        return "".join("@" if i < self.m.axes else "-" for i in range(len(AXES)))

    # -- motor current and lock state -------------------------------------------------

    def i_iscur(self, c: Command) -> Reply:
        """Applied current: ``cur``, times ``reduction`` while the axis stands, 0 with the
        power stage off (``axis -1``) or the amplifiers off (``pa 0``) (L3024-3051)."""
        def current(axis: int) -> str:
            params = self.m.params
            if int(params.first("axis", axis)) == -1 or int(params.first("pa")) == 0:
                return "0.00"
            amps = params.number("cur", axis)
            if not self.m.motion.is_moving(axis):
                amps *= params.number("reduction", axis)
            return format_value(amps, 2)

        return [self.axes_text(self.m.present(c), current)]

    def i_lockstate(self, c: Command) -> Reply:
        """16 bits per axis: the ``lock`` bits on axes where ``lockaxis`` is 1 (L4323)."""
        bits = str(self.m.params.first("lock"))

        def state(axis: int) -> str:
            return bits if int(self.m.params.first("lockaxis", axis)) else "0" * len(bits)

        return [self.axes_text(self.m.present(c), state)]

    # -- HDI and keys ---------------------------------------------------------------------

    def i_key(self, c: Command) -> Reply:
        """No key is ever held down: ``0 0 0 0`` or one ``0`` (L7607-7630)."""
        return ["0"] if c.values else ["0 0 0 0"]

    def i_keyl(self, c: Command) -> Reply:
        """Latched keys (set by ``snse``), cleared by reading them or by ``!keyl``."""
        latched = self.m.session.keys_latched
        keys = [int(c.values[0]) - 1] if c.values else list(range(4))
        states = [str(latched[k]) for k in keys]
        for k in keys:
            latched[k] = 0
        return [" ".join(states)] if c.is_read else None

    def i_hdi(self, c: Command) -> Reply:
        """No HDI device: ID 16 "No device connected" (L8170-8207)."""
        return ["16 99 [No device connected]"] if c.values else ["16 99"]

    # -- digital and analogue I/O -----------------------------------------------------------

    def _inputs(self, c: Command) -> Reply:
        levels = "".join(str(level) for level in self.m.devices.inputs[c.name])
        return [levels[int(c.values[0])]] if c.values else [levels]

    i_digin = i_edigin = i_adigin = _inputs

    def i_anain(self, c: Command) -> Reply:
        """``c``: the 10-bit count; ``v``: the same with two decimals (L9448-9450)."""
        counts = self.m.devices.analog.get(int(c.values[1]), 0)
        return [str(counts)] if c.values[0] == "c" else [format_value(float(counts), 2)]

    def i_anaout(self, c: Command) -> Reply:
        """Three channel levels; ``c n`` addresses one channel, ``p n`` sets a power-on
        preset, which the emulator accepts and does not keep (L9453-9568)."""
        levels = list(self._indexed("anaout"))
        if c.is_read:
            chosen = [levels[int(c.values[1])]] if c.values else levels
            return [" ".join(format_value(float(v), 2) for v in chosen)]
        if c.values[0] == "p":
            return None
        if c.values[0] == "c":
            levels[int(c.values[1])] = float(c.values[2])
        else:
            levels[: len(c.values)] = [float(v) for v in c.values]
        self.m.params.put_global("anaout", tuple(levels))
        return None

    def i_flash(self, c: Command) -> Reply:
        """A pulse on TAKT_OUT, ``|ms|`` long, active high for a positive value, low for a
        negative one (L9861-9913); ``?flash`` answers nothing ("Response: None")."""
        if not c.is_read:
            ms = float(c.values[0])
            self.m.devices.record([Pulse(self.m.motion.now, TAKT_OUT, abs(ms) / 1000,
                                         ms > 0)])
        return None

    def i_trigger(self, c: Command) -> Reply:
        """Pulses forced by hand, in the manual trigger modes 102 and 103 only; none or 0
        sends one, ``n`` sends n (L13414-13440). Choice: in another mode it sends nothing
        and the line is accepted (the manual names no error)."""
        if int(self.m.params.first("trigm")) in (102, 103) \
                and int(self.m.params.first("trig")) == 1:
            count = max(1, int(c.values[0])) if c.values else 1
            self.m.trigger_pulses(self.m.motion.now, count)
            self.m.motion.set_trigger_count(self.m.motion.trigger_count + count)
        return None

    def i_adiginfunc(self, c: Command) -> Reply:
        """Four input functions, default ``0 0 1 2``; ``-1`` restores it (L9170-9263)."""
        functions = list(self._indexed("adiginfunc"))
        if c.is_read:
            return [str(functions[int(c.values[0])])] if c.values else \
                [" ".join(str(f) for f in functions)]
        if c.values == (-1,):
            functions = list(INDEXED["adiginfunc"])
        elif len(c.values) == 2:
            functions[int(c.values[0])] = int(c.values[1])
        else:
            functions = [int(v) for v in c.values]
        self.m.params.put_global("adiginfunc", tuple(functions))
        return None

    def i_drop(self, c: Command) -> Reply:
        """The dispenser delivers at once: ``?drop 0`` (still to go) is always 0, ``?drop``
        counts the drops since ``!drop 0`` (L10199-10280)."""
        session = self.m.session
        if c.is_read:
            return ["0"] if c.values else [str(session.drops)]
        count = int(c.values[0])
        session.drops = 0 if count == 0 else (session.drops + count) % 65536
        return None

    # -- indexed presets ------------------------------------------------------------------

    def _indexed(self, name: str) -> tuple[float | int | str, ...]:
        """The per-index values of ``name`` (see :data:`~tango_aio.sim.params.INDEXED`)."""
        return self.m.params.global_values[name]

    def _preset(self, c: Command, digits: int, every: bool) -> Reply:
        values = list(self._indexed(c.name))
        if c.is_read:
            if c.values:
                return [format_value(float(values[int(c.values[0]) - 1]), digits)]
            chosen = values if every else values[:1]
            return [" ".join(format_value(float(v), digits) for v in chosen)]
        values[int(c.values[0]) - 1] = float(c.values[1])
        self.m.params.put_global(c.name, tuple(values))
        return None

    def i_joyspeed(self, c: Command) -> Reply:
        """Speeds of the buttons 1-3; ``?joyspeed`` alone reads button 1, since the reply
        is one number (L7356-7384)."""
        return self._preset(c, 3, every=False)

    def i_zwtravel(self, c: Command) -> Reply:
        """Wheel travel of the presets 1-3; ``?zwtravel`` reads all three (L7845-7930)."""
        return self._preset(c, 3, every=True)

    # -- backward-compatible single-value reads ----------------------------------------

    def _compat(self, c: Command) -> Reply:
        """``?calbspeed`` / ``?ctrd`` answer one value (X) for backward compatibility, ``-1``
        every axis, an axis letter that axis (L5809-5890, L12053-12057); writes go to the
        generic store."""
        if not c.is_read:
            self.m.store(c)
            return None
        digits = 1 if c.name != "ctrd" else 0
        values = self.m.params.axis_values[c.name]
        every = c.values == (-1,)
        indices = list(range(self.m.axes)) if every else self.m.present(c)[:1]
        return [" ".join(format_value(values[i][0], digits) for i in indices)]

    i_calbspeed = i_calrefspeed = i_ctrd = _compat

    def i_clim(self, c: Command) -> Reply:
        """Circular limit: ``?clim`` → centre X, centre Y, radius; ``?clim 1`` → 0/1;
        ``!clim 0`` disables; ``!clim r`` centres on the current X Y (L4622-4671)."""
        session = self.m.session
        if c.is_read:
            if c.values:
                return ["1" if session.clim_active else "0"]
            cx, cy, radius = session.clim
            return [f"{self._xy_text(0, cx)} {self._xy_text(1, cy)} {self._xy_text(0, radius)}"]
        if len(c.values) == 1 and float(c.values[0]) == 0.0:
            session.clim_active = False
            return None
        if len(c.values) == 1:
            here = tuple(self.m.motion.to_user(i, self.m.motion.position(i))
                         if i < self.m.axes else 0.0 for i in range(2))
            session.clim = (here[0], here[1], float(c.values[0]))
        else:
            session.clim = (float(c.values[0]), float(c.values[1]), float(c.values[2]))
        session.clim_active = True
        return None

    def _xy_text(self, axis: int, value: float) -> str:
        axis = min(axis, self.m.axes - 1)
        return self.position_text(axis, self.m.motion.from_user(axis, value))

    # -- encoders and closed loop: none fitted -----------------------------------------

    def i_encamp(self, c: Command) -> Reply:
        """No signal: 0 per axis, one decimal with ``1`` (L11157-11192)."""
        return [self._per_axis(c, "0.0" if c.values else "0")]

    def i_enc(self, c: Command) -> Reply:
        """Active where ``encmask`` is set and an encoder is fitted (the controller
        activates encoders, L10485-10545), or where ``!enc 1`` forced it (the manual
        advises against it, L10527-10545, but allows it)."""
        if not c.is_read:
            self.m.store(c)
            return None
        return [" ".join(str(int(self.m.encoder_active(i))) for i in self.m.present(c))]

    def _masked(self, axis: int) -> bool:
        return int(self.m.params.first("encmask", axis)) == 1

    def _closed_loop(self, axis: int) -> bool:
        # An active encoder and ctr 1-4 ("Preconditions ... having ctr and encmask
        # set", L11761-11800).
        return axis in self.m.devices.encoders and self._masked(axis) \
            and int(self.m.params.first("ctr", axis)) != 0

    def i_encerr(self, c: Command) -> Reply:
        """No encoder error: ``0`` per axis; ``!encerr 0`` clears nothing (L11116-11151)."""
        return [self._per_axis(c, "0")] if c.is_read else None

    def i_encsync(self, c: Command) -> Reply:
        """Not synchronised: ``0`` per axis; ``-1`` gives three numbers per axis, groups
        separated by two spaces as printed (L11248-11293)."""
        return [("  " if c.values else " ").join(
            "0 0 0" if c.values else "0" for _ in self.m.present(c))]

    def i_ctrstatus(self, c: Command) -> Reply:
        """No closed loop runs: mode 0 and no state bits; ``0`` gives the pair
        ``mode bits`` per axis (L12285-12395)."""
        return [self._per_axis(c, "0 0" if c.values == (0,) else "0")]

    def i_ctrdiff(self, c: Command) -> Reply:
        """The difference between motor and encoder position, printed as a position
        (L12396-12443), on an axis in closed loop, else 0: the encoder's drift
        (``devices.drift``) plus what a test set in ``devices.position_error``."""
        def difference(axis: int) -> str:
            if not self._closed_loop(axis):
                return self.position_text(axis, 0.0)
            error = self.m.motion.from_user(axis, self.m.devices.position_error.get(axis, 0.0))
            drift = self.m.motion.position(axis) - self.m.encoder_position(axis)
            return self.position_text(axis, error + drift)
        return [self.axes_text(self.m.present(c), difference)]

    def i_mrt(self, c: Command) -> Reply:
        """``n`` lines (10 by default, ``-n`` the same) of sine/cosine pairs, one pair per
        addressed axis, all 0 without an MR encoder (L11474-11535)."""
        samples = abs(int(c.values[0])) if c.values else 10
        line = " ".join("0 0" for _ in self.m.present(c))
        return [line] * samples

    def i_calzeropos(self, c: Command) -> Reply:
        """Where the last cal of each axis completed (0 unless calmode 1) (L5970-6007)."""
        return [self.axes_text(self.m.present(c), lambda i: self.position_text(
            i, self.m.cal_zero[i]))]

    # -- flagged letters -------------------------------------------------------------------

    def swtyp_text(self, c: Command) -> str | None:
        """``?swtyp`` without an axis in extmode 0 prints the axis groups without the
        separating space, ``1 1 11 1 11 1 1`` (L4818-4822); None: the normal reply."""
        if c.axis is not None or int(self.m.params.first("extmode")) != 0:
            return None
        groups = self.m.params.axis_values["swtyp"][: self.m.axes]
        return "".join(" ".join(str(v) for v in group) for group in groups)
