"""``tango-aio probe``: learn what a controller's firmware does, from the wire.

The decisions from the observed lines are pure functions (``decide_*``), tested without
I/O; a value no switch has is recorded under ``unknown`` with its lines, and the command
asks the user to send the file. An instruction the unit answers with nothing and error 4
("invalid instruction", L970) is recorded under ``lacks``, and the probe goes on without
it: without ``?lim`` there is no ``lim_cr_bug`` to see, the moves stay within
``2 * 10**(4 - decimals)`` of where X stands (towards 0), and no move goes beyond a limit.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import json
import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ProbeError, TangoError
from ..sansio import CACHED_SETTINGS
from ..status import MOVING, AxisStatus
from ._decide import (
    _INT,
    _NUMBER,
    _REPORT,
    FINGERPRINT_FORMAT,
    MOVE_SWITCHES,
    SAVE_SWITCHES,
    SWITCH_NAMES,
    TRIGGER_SWITCHES,
    Exchange,
    Observation,
    _seen,
    _unknown,
    _unseen,
    decide_ack_case,
    decide_ack_mode_change,
    decide_ack_reads,
    decide_echo_all,
    decide_echo_text,
    decide_err_number,
    decide_help_case,
    decide_help_number,
    decide_instruction_set,
    decide_lim_cr_bug,
    decide_line_end,
    decide_local_echo,
    decide_mode_change_echo,
    decide_numbers,
    decide_save_ack,
    decide_service_end,
    decide_status,
    decide_version_format,
    decide_version_value,
    echo_form,
    exchange_end,
)
from ._rawlink import _Link

__all__ = [
    "ProbeOptions",
    "ProbeResult",
    "comparable",
    "probe",
    "write_fingerprint",
]

# ---------------------------------------------------------------------------------------
# The probe


@dataclass(frozen=True)
class ProbeOptions:
    """How the probe runs (see :func:`probe`)."""

    #: Also make small moves (``--moves``).
    moves: bool = False
    #: Also send ``!save`` once in mode 2 (``--save``).
    save: bool = False
    #: Seconds of silence that end an exchange in modes 2 and 4.
    settle: float = 0.3
    #: Longest wait for an answer, seconds.
    reply_timeout: float = 3.0
    #: About how long each test move should take, seconds.
    move_time: float = 0.3
    #: Serial line settings.
    baudrate: int = 57600
    rtscts: bool = False

    def __post_init__(self) -> None:
        for name in ("settle", "reply_timeout", "move_time"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")


@dataclass
class ProbeResult:
    """What :func:`probe` found."""

    #: Every switch's observation, by name.
    observations: dict[str, Observation]
    #: The identity: the ``?version`` line and what else the unit says of itself.
    identity: dict[str, Any]
    #: Number of axes.
    axes: int
    #: Raw replies of the setting reads, by instruction.
    settings: dict[str, list[str]]
    #: Move observations that are no switch (pause, ``!joy 0`` during a move), raw.
    extra: dict[str, Any]
    #: The options it ran with.
    options: ProbeOptions
    #: The URL probed.
    url: str
    #: The wire trace (:mod:`tango_aio.fieldkit._trace`'s format).
    trace: str
    #: The instructions the unit lacks: it answered them with nothing and error 4
    #: (L970), sorted.
    lacks: list[str] = field(default_factory=list)

    @property
    def switches(self) -> dict[str, str]:
        """The observed switch values (no entry for a switch not observed or unknown)."""
        return {name: obs.value for name, obs in self.observations.items()
                if obs.value is not None}

    @property
    def unknown(self) -> dict[str, Observation]:
        """Switches whose observed behaviour no value describes."""
        return {name: obs for name, obs in self.observations.items() if obs.unknown}

    def fingerprint(self) -> dict[str, Any]:
        """The fingerprint, as JSON data.

        Returns
        -------
        dict[str, Any]
            The fingerprint.
        """
        from .. import __version__

        return {
            "format": FINGERPRINT_FORMAT,
            "project_version": __version__,
            "written": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "url": self.url,
            "moves": self.options.moves,
            "save": self.options.save,
            "identity": self.identity,
            "axes": self.axes,
            "settings": self.settings,
            "lacks": self.lacks,
            "switches": self.switches,
            "unobserved": {name: obs.note for name, obs in self.observations.items()
                           if obs.value is None and not obs.unknown},
            "unknown": {name: obs.as_json() for name, obs in self.unknown.items()},
            "observations": {name: obs.as_json()
                             for name, obs in self.observations.items()},
            "extra": self.extra,
        }


def comparable(fingerprint: dict[str, Any]) -> dict[str, Any]:
    """The parts of a fingerprint that do not depend on timing or on when it was written:
    identity, axes, settings, the instructions it lacks, switch values, and each
    observation's value and note (not its lines, which hold positions a stop reached).
    Two probes of one unit give equal ones.

    Parameters
    ----------
    fingerprint
        A fingerprint, as written.

    Returns
    -------
    dict[str, Any]
        Its comparable parts.
    """
    return {
        "format": fingerprint.get("format"),
        "identity": fingerprint.get("identity"),
        "axes": fingerprint.get("axes"),
        "settings": fingerprint.get("settings"),
        "lacks": fingerprint.get("lacks"),
        "switches": fingerprint.get("switches"),
        "unobserved": fingerprint.get("unobserved"),
        "unknown": sorted(fingerprint.get("unknown") or {}),
        "observations": {name: [obs.get("value"), obs.get("note")] for name, obs in
                         (fingerprint.get("observations") or {}).items()},
    }


def write_fingerprint(result: ProbeResult, path: str | Path) -> Path:
    """Write ``result``'s fingerprint as JSON to ``path``.

    Parameters
    ----------
    result
        The probe's result.
    path
        The file to write.

    Returns
    -------
    Path
        ``path``, as a :class:`~pathlib.Path`.
    """
    target = Path(path)
    target.write_text(json.dumps(result.fingerprint(), indent=2) + "\n", encoding="utf-8")
    return target


async def probe(url: str, options: ProbeOptions | None = None) -> ProbeResult:
    """Probe the controller at ``url`` and return what it does (see the module text).

    Raises :class:`ProbeError` (or :class:`~tango_aio.errors.ConnectionLostError`) when it
    cannot go on; it restores what it changed on the way out as far as the link allows.

    Parameters
    ----------
    url
        The controller's URL, as for :func:`tango_aio.connect`.
    options
        What to probe (moves, ``!save``) and how long to wait; ``None`` for the defaults.

    Returns
    -------
    ProbeResult
        The identity, the settings and an observation per switch.

    Raises
    ------
    ProbeError
        The probe cannot go on.
    ConnectionLostError
        The link was lost.
    """
    options = options or ProbeOptions()
    link = _Link(options.reply_timeout)
    await link.open(url, baudrate=options.baudrate, rtscts=options.rtscts)
    try:
        prober = _Prober(link, options, url)
        return await prober.run()
    except ProbeError as exc:
        exc.trace = link.trace_text()
        raise
    finally:
        await link.close()


class _Prober:
    """One probe run: the steps, in order, and what they restore."""

    def __init__(self, link: _Link, options: ProbeOptions, url: str) -> None:
        self.link = link
        self.options = options
        self.url = url
        self.obs: dict[str, Observation] = {}
        self.version = ""
        self.axes = 0
        self.joy: int | None = None
        self.settings: dict[str, list[str]] = {}
        self.identity: dict[str, Any] = {}
        self.extra: dict[str, Any] = {}
        self.numeric: list[Exchange] = []
        #: Instructions the unit answered with nothing and error 4.
        self.lacks: set[str] = set()
        self.mode = 1
        self.initial_mode: int | None = None
        self.ack_reads = "no"
        self.echo_all = "no"
        #: The lines that set back what the run changed, in the order of the changes
        #: (sent in reverse by :meth:`restore`).
        self.undo: list[str] = []

    # -- exchanges --------------------------------------------------------------------------

    def leftovers(self) -> None:
        """Lines nobody asked for yet (kept in the fingerprint's ``extra``)."""
        stray = self.link.take()
        if stray:
            self.extra.setdefault("stray_lines", []).extend(stray)

    async def settled(self, *lines: str) -> Exchange:
        """Write ``lines``; everything that arrives until ``settle`` s of silence."""
        self.leftovers()
        self.link.send(*lines)
        await self.link.quiet(self.options.settle)
        return Exchange(list(lines), self.link.take())

    async def ask(self, *lines: str) -> Exchange:
        """Mode 1: write ``lines``, ``?err`` and ``?version``; the lines before the answer
        to ``?err`` are theirs (in mode 1 a read answers one line, L2087). The exchange
        ends at the ``?version`` line that follows a number (``?err``'s answer, move
        reports aside): a line of ``lines`` may be the ``?version`` line too (``?version
        1`` on firmware that ignores the value)."""
        self.leftovers()
        self.link.send(*lines, "?err", "?version")
        version = self.version
        try:
            await self.link.until(lambda got: exchange_end(got, version) is not None,
                                  self.options.reply_timeout)
        except TimeoutError:
            raise ProbeError(f"no answer to {list(lines)!r} and the ?err and ?version after "
                             f"them within {self.options.reply_timeout} s; received "
                             f"{self.link.inbox!r}") from None
        got = self.link.take()
        end = exchange_end(got, version)
        assert end is not None
        index, at = end
        err = int(got[at].strip())
        before = got[:at] + got[at + 1:index]
        self.link.inbox[:0] = got[index + 1:]  # e.g. a report that came right after
        return Exchange(list(lines), before, err)

    async def checked(self, line: str) -> Exchange:
        """:meth:`ask` for one instruction; one it answers with nothing and error 4
        ("invalid instruction", L970) is recorded among those the unit lacks."""
        exchange = await self.ask(line)
        if not exchange.got and exchange.err == 4:
            self.lacks.add(line.lstrip("?").split()[0].lower())
        return exchange

    async def read(self, line: str) -> Exchange:
        """A read in mode 1, kept among the settings (see :meth:`checked`)."""
        exchange = await self.checked(line)
        self.settings[line[1:]] = exchange.got if exchange.err == 0 else \
            [f"(error {exchange.err})"]
        return exchange

    async def wait_report(self, timeout: float) -> tuple[str | None, list[str]]:
        """Wait for a completion report; (report or None, every line up to it)."""
        with contextlib.suppress(TimeoutError):
            await self.link.until(lambda got: any(_REPORT.match(g) for g in got), timeout)
        got = self.link.take()
        for index, line in enumerate(got):
            if _REPORT.match(line):
                self.link.inbox[:0] = got[index + 1:]
                return line, got[:index + 1]
        return None, got

    async def set_mode(self, mode: int) -> Exchange:
        exchange = await self.settled(f"!autostatus {mode}")
        self.mode = mode
        return exchange

    # -- the run ------------------------------------------------------------------------------

    async def run(self) -> ProbeResult:
        try:
            await self.start()
            await self.mode1()
            await self.mode2()
            await self.mode4()
            if self.options.moves:
                await self.moves()
        finally:
            await self.restore()
        for name in SWITCH_NAMES:
            if name not in self.obs:
                reason = ("seen only with --moves" if name in MOVE_SWITCHES else
                          "seen only with --save" if name in SAVE_SWITCHES else
                          "the trigger output is not probed" if name in TRIGGER_SWITCHES else
                          "not observed")
                self.obs[name] = Observation(None, reason)
        return ProbeResult({name: self.obs[name] for name in SWITCH_NAMES}, self.identity,
                           self.axes, self.settings, self.extra, self.options, self.url,
                           self.link.trace_text(), sorted(self.lacks))

    async def restore(self) -> None:
        """Send the set-back lines (mode 1), then the mode the unit was found in."""
        if self.link._protocol is None or self.link._lost:
            return
        with contextlib.suppress(TangoError, TimeoutError, OSError):
            if self.mode != 1:
                await self.set_mode(1)
            for line in reversed(self.undo):
                await self.settled(line)
            if self.initial_mode is not None and self.initial_mode != 1:
                await self.settled(f"!autostatus {self.initial_mode}")

    async def start(self) -> None:
        """The mode the unit is in, mode 1, local echo, line end, identity."""
        first = await self.settled("?autostatus")
        numbers = [line for line in first.got if _INT.match(line.strip())]
        if not numbers and not first.got:
            first = await self.settled("?autostatus")  # woken from a break, try once more
            numbers = [line for line in first.got if _INT.match(line.strip())]
        if not numbers:
            raise ProbeError(f"no answer to ?autostatus within {self.options.settle} s "
                             f"of silence: got {first.got!r} (is it a TANGO, at this baud "
                             f"rate?)")
        self.initial_mode = int(numbers[-1].strip())
        self.identity["autostatus_found"] = self.initial_mode
        await self.set_mode(1)
        self.link.take()
        version = await self.settled("?version")
        self.obs["local_echo"] = decide_local_echo(version)
        got = list(version.got)
        if self.obs["local_echo"].value == "yes":
            got = got[1:]
            self.link.local_echo = True
        if len(got) != 1:
            raise ProbeError(f"?version in mode 1 answered {version.got!r}, not one line")
        self.version = got[0]
        self.identity["version"] = self.version
        self.obs["version_format"] = decide_version_format(version, self.version)
        parts = [part.strip() for part in self.version.split(",")]
        if len(parts) >= 2 and parts[1].startswith("Version "):
            self.identity["model"] = parts[0]
            self.identity["firmware"] = parts[1][len("Version "):]

    async def mode1(self) -> None:
        """Reads: identity, settings, help, service, ?lim, ?statusaxis."""
        link = self.link
        version1 = await self.ask("?version 1")
        self.obs["version_value"] = decide_version_value(version1, self.version)
        for line in ("?readsn", "?det", "?detext"):
            exchange = await self.checked(line)
            if exchange.err == 0:
                self.identity[line[1:]] = exchange.got
        pos = await self.read("?pos")
        if len(pos.got) != 1:
            raise ProbeError(f"?pos answered {pos.got!r}, not one line")
        self.axes = len(pos.got[0].split())
        self.numeric.append(pos)
        # The settings the driver reads at connect (ctrt among them, L11616-11631),
        # and the others the probe reports.
        cached = [f"?{entry.name}" for entry in CACHED_SETTINGS]
        for line in dict.fromkeys(["?vel", "?accel", "?secvel", "?pitch", "?dim", "?lim x",
                                   "?pause", "?delay", *cached]):
            if line == "?extmode":
                continue  # read below
            exchange = await self.read(line)
            if exchange.err == 0:
                self.numeric.append(exchange)
        joy = await self.read("?joy")
        self.joy = int(joy.got[0]) if joy.err == 0 and len(joy.got) == 1 and \
            _INT.match(joy.got[0].strip()) else None
        extmode = await self.read("?extmode")
        help5 = await self.ask("?help 5")
        self.obs["instruction_set"] = decide_instruction_set(version1, help5, self.version)
        self.obs["help_number"] = decide_help_number(help5)
        self.obs["help_case"] = decide_help_case(await self.checked("help"))
        self.obs["service_end"] = decide_service_end(await self.checked("service"))
        lim = await self.checked("?lim")
        self.settings["lim"] = lim.got
        if "lim" in self.lacks:
            self.obs["lim_cr_bug"] = _unseen("moot: the unit lacks ?lim (no reply, error 4)",
                                             (), lim)
        elif extmode.err == 0 and len(extmode.got) == 1 and extmode.got[0].strip() in "01":
            current = int(extmode.got[0])
            other = 1 - current
            self.undo.append(f"!extmode {current}")
            await self.ask(f"!extmode {other}")
            lim_other = await self.ask("?lim")
            await self.ask(f"!extmode {current}")
            self.undo.pop()
            pair = (lim, lim_other) if current == 0 else (lim_other, lim)
            self.obs["lim_cr_bug"] = decide_lim_cr_bug(self.axes, pair[0], pair[1])
        else:
            self.obs["lim_cr_bug"] = decide_lim_cr_bug(self.axes, lim, None)
        status = await self.ask("?statusaxis")
        self.obs.update(decide_status(status, self.axes, self.joy))
        self.obs["line_end"] = decide_line_end(link.lf_lines, status)
        self.obs["numbers"] = decide_numbers(self.numeric, None)

    async def mode2(self) -> None:
        """Acknowledgements: mode changes, reads, set lines, a refusal, ``!save``."""
        into2 = await self.set_mode(2)
        read = await self.settled("?version")
        self.obs["ack_reads"] = decide_ack_reads(read, self.version)
        self.ack_reads = self.obs["ack_reads"].value or "no"
        same = await self.settled("!autostatus 2")
        refused = await self.settled("!vel x -1")
        self.obs["err_number"] = decide_err_number(refused)
        acks = [into2, same, read]
        if self.options.save:
            saved = await self.settled("!save")
            self.obs["save_ack"] = decide_save_ack(saved)  # its OK... is its reply too
        back1 = await self.set_mode(1)
        self.obs["ack_mode_change"] = decide_ack_mode_change(into2, back1)
        self.obs["ack_case"] = decide_ack_case([*acks, back1])

    async def mode4(self) -> None:
        """Echoes: mode changes, a read, the echo's text."""
        into4 = await self.set_mode(4)
        read = await self.settled("?version")
        self.obs["echo_all"] = decide_echo_all(read, self.version)
        self.echo_all = self.obs["echo_all"].value or "no"
        text = await self.settled("!autostatus  4")
        self.obs["echo_text"] = decide_echo_text(text)
        back1 = await self.set_mode(1)
        self.obs["echo"] = decide_mode_change_echo(into4, back1)

    # -- moves ----------------------------------------------------------------------------------

    async def moves(self) -> None:
        """Small moves of X (see the module text); X returns to where it was."""
        start = await self.ask("?pos x")
        lim = await self.checked("?lim x")
        limits: tuple[float, float] | None = None
        try:
            p0_text = start.got[0].strip()
            p0 = float(p0_text)
            if "lim" not in self.lacks:
                lo, hi = (float(v) for v in lim.got[0].replace(",", " ").split()[:2])
                limits = (lo, hi)
        except (IndexError, ValueError):
            raise ProbeError(f"cannot read X's position and limits: {start.got!r} "
                             f"{lim.got!r}") from None
        decimals = len(p0_text.partition(".")[2]) or 4
        self.undo.append(f"!moa x {p0_text}")
        # Without ?lim the moves stay within 2 * 10**(4 - decimals) of where X stands
        # (2 mm with positions in mm to 4 decimals), towards 0 (up from 0).
        span = limits[1] - limits[0] if limits else 10.0 ** (5 - decimals)
        middle = (limits[0] + limits[1]) / 2 if limits else 0.0
        sign = 1.0 if p0 <= middle else -1.0
        # A first short move measures how far the axis goes in move_time.
        step0 = min(10.0 ** (3 - decimals), span / 100)
        began = time.monotonic()
        first = await self.move(f"!mor x {sign * step0:.{decimals}f}")
        took = max(time.monotonic() - began, 1e-3)
        back = await self.move(f"!mor x {-sign * step0:.{decimals}f}")
        scale = min(max(self.options.move_time / took, 1.0), 50.0)
        step = min(step0 * scale, span / 10)
        wait = self.options.move_time * 10 + self.options.reply_timeout
        self.obs["report_width"] = self.decide_width(first)
        self.extra["first_move"] = {"lines": first.transcript() + back.transcript(),
                                    "seconds": round(took, 3)}
        if self.joy:
            self.obs["joystick_letter"] = self.decide_move_letter(first)
        # A zero move.
        zero = await self.settled("!mor x 0")
        self.obs["zero_move_report"] = (
            _seen("yes", "a zero move reports", zero) if len(zero.got) == 1 and
            _REPORT.match(zero.got[0]) else _seen("no", "a zero move sends nothing", zero)
            if not zero.got else _unknown("a zero move answered more than a report", zero))
        # A refused move, beyond the limit.
        if limits is None:
            self.obs["refused_move_report"] = _unseen(
                "the unit lacks ?lim: no known limit to move beyond", ("no", "yes"), lim)
        else:
            lo, hi = limits
            beyond = hi + max(1.0, span / 10) if sign > 0 else lo - max(1.0, span / 10)
            refused = await self.settled(f"!moa x {beyond:.{decimals}f}")
            self.obs["refused_move_report"] = (
                _seen("no", "a refused move sends nothing", refused) if not refused.got else
                _seen("yes", "a refused move reports 'E'", refused)
                if len(refused.got) == 1 and refused.got[0][:1] == AxisStatus.ERROR
                else _unknown("a refused move answered more than one 'E' report", refused))
            await self.ask("?err")
        # A move during a move; 'a' and Ctrl+C during a move. Each needs the move to
        # still run when the next line arrives: when it had ended, the move is tried
        # again twice as long (up to three times, within a tenth of the travel).
        longest = span / 10
        attempts: list[Callable[[float, bool], Awaitable[bool]]] = [
            lambda length, last: self.during(p0, sign * length, decimals, wait, last),
            lambda length, last: self.abort(p0, sign * length, decimals, wait, b"a\r", "a",
                                            last),
            lambda length, last: self.abort(p0, sign * length, decimals, wait, b"\x03",
                                            "ctrl_c", last),
            lambda length, last: self.disable(p0, sign * length, decimals, wait, last)]
        for attempt in attempts:
            length = step
            for tries in range(3):
                last = tries == 2 or length >= longest
                done = await attempt(length, last)
                await self.back_to(p0_text, p0, decimals, wait)
                if done or last:
                    break
                length = min(length * 2, longest)
        # A pause before the report.
        await self.pause(sign * step, decimals, wait)
        # !joy 0 during a move.
        if self.joy:
            self.undo.append(f"!joy {self.joy}")
            self.link.take()
            self.link.send(f"!mor x {sign * step:.{decimals}f}", "!joy 0")
            _, lines = await self.wait_report(wait)
            await self.link.quiet(max(self.options.settle, self.options.move_time * 2))
            lines += self.link.take()
            await self.settled(f"!joy {self.joy}")
            self.undo.pop()
            self.extra["joy0_during_move"] = lines
            await self.move(f"!mor x {-sign * step:.{decimals}f}")
        # A value just below zero (numbers=negzero), when X stands near 0.
        below: Exchange | None = None
        tiny = 0.4 * 10.0 ** -decimals
        if abs(p0) <= step and limits is not None and limits[0] < -tiny:
            await self.move(f"!moa x {-tiny:.{decimals + 1}f}")
            below = await self.ask("?pos x")
            await self.back_to(p0_text, p0, decimals, wait, force=True)
        self.obs["numbers"] = decide_numbers(self.numeric, below)
        # Modes 2 and 4: a move with a read during it.
        await self.move_in_mode(2, sign * step, decimals, wait)
        await self.move_in_mode(4, sign * step, decimals, wait)
        await self.back_to(p0_text, p0, decimals, wait)
        self.undo.pop()

    async def move(self, line: str) -> Exchange:
        """A move in mode 1, to its report."""
        self.link.take()
        self.link.send(line)
        report, lines = await self.wait_report(self.options.move_time * 10 +
                                               self.options.reply_timeout)
        if report is None:
            raise ProbeError(f"no report for {line!r} (received {lines!r})")
        return Exchange([line], lines)

    def decide_width(self, move: Exchange) -> Observation:
        report = move.got[-1]
        letters = report[:-1]
        if self.axes >= 4:
            return _unseen("every axis is present", ("four", "axes"), move)
        if len(letters) == 4:
            return _seen("four", "reports carry four letters", move)
        if len(letters) == self.axes:
            return _seen("axes", "reports carry one letter per axis", move)
        return _unknown(f"a report of {len(letters)} letters on a {self.axes}-axis unit",
                        move)

    def decide_move_letter(self, move: Exchange) -> Observation:
        letter = move.got[-1][:1]
        if letter in (AxisStatus.READY, AxisStatus.JOYSTICK):
            return _seen(letter, f"a completed move reports {letter!r} with the joystick on",
                         move)
        return _unknown(f"a completed move reports {letter!r}", move)

    async def back_to(self, text: str, value: float, decimals: int, wait: float, *,
                      force: bool = False) -> None:
        """Move X back to ``value`` unless it reads so (``force``: move anyway)."""
        now = await self.ask("?pos x")
        with contextlib.suppress(IndexError, ValueError):
            if not force and abs(float(now.got[0]) - value) < 0.5 * 10.0 ** -decimals:
                return
        self.link.take()
        self.link.send(f"!moa x {text}")
        await self.wait_report(wait)
        await self.link.quiet(self.options.settle)
        self.link.take()

    async def during(self, p0: float, step: float, decimals: int, wait: float,
                     last: bool) -> bool:
        """``move_during_move``: a second move sent while the first runs (L6606). False
        (nothing recorded unless ``last``) when the first had ended before (its report
        came before the answers to the lines after them)."""
        first, second = p0 + step, p0 + 2 * step
        lines = (f"!moa x {first:.{decimals}f}", f"!moa x {second:.{decimals}f}")
        sent = await self.ask(*lines)
        reports = [g for g in sent.got if _REPORT.match(g)]
        ended = [g for g in reports if g[:1] != AxisStatus.ERROR]  # a refused second move's
        if ended:
            await self.wait_report(wait)
            await self.link.quiet(max(self.options.settle, self.options.move_time))
            self.link.take()
            if last:
                self.obs["move_during_move"] = _unseen(
                    "the first move ended before the second arrived",
                    ("refuse", "queue", "retarget"), Exchange(list(lines), sent.got, sent.err))
            return False
        got = list(sent.got)
        _, more = await self.wait_report(wait)
        got += more + self.link.take()  # the second report may have come with the first
        # Accepted, one report so far, and X not at the second target: the second move
        # was queued and still runs (or is about to), with a report of its own to come.
        now = await self.ask("?pos x")
        with contextlib.suppress(IndexError, ValueError):
            if sent.err == 0 and sum(bool(_REPORT.match(g)) for g in got) < 2 \
                    and abs(float(now.got[0]) - second) > abs(step) / 20:
                _, more = await self.wait_report(wait)
                got += more
        await self.link.quiet(self.options.settle)
        got += self.link.take()
        reports = [g for g in got if _REPORT.match(g)]
        where = await self.ask("?pos x")
        exchange = Exchange(list(lines), got, sent.err)
        try:
            at = float(where.got[0])
        except (IndexError, ValueError):
            self.obs["move_during_move"] = _unknown("no position after the moves", exchange,
                                                    where)
            return True
        tolerance = abs(step) / 20
        at_second = abs(at - second) <= tolerance
        at_first = abs(at - first) <= tolerance
        refused_reports = self.obs.get("refused_move_report")
        own = 1 if refused_reports is not None and refused_reports.value == "yes" else 0
        if sent.err == 2 and at_first and len(reports) == 1 + own:
            value, note = "refuse", "the second move was refused (error 2)"
        elif sent.err == 0 and at_second and len(reports) == 2:
            value, note = "queue", "the second move ran after the first, two reports"
        elif sent.err == 0 and at_second and len(reports) == 1:
            value, note = "retarget", "the second move took over, one report"
        else:
            self.obs["move_during_move"] = _unknown(
                f"error {sent.err}, {len(reports)} reports, X at {at}", exchange, where)
            return True
        self.obs["move_during_move"] = _seen(value, note, exchange, where)
        return True

    async def disable(self, p0: float, step: float, decimals: int, wait: float,
                      last: bool) -> bool:
        """``disable_during_move``: ``!axis x 0`` while X moves (L3919-3960 say nothing of
        a moving axis): refused (error 2), the move stopped, or the move going on to its
        target. X is enabled again afterwards. False (nothing recorded unless ``last``)
        when the move had ended before the line arrived."""
        target = p0 + step
        lines = (f"!moa x {target:.{decimals}f}", "!axis x 0")
        self.undo.append("!axis x 1")
        sent = await self.ask(*lines)
        early = [g for g in sent.got if _REPORT.match(g)]
        got = list(sent.got)
        if not early:
            _, more = await self.wait_report(wait)
            got += more
        await self.link.quiet(self.options.settle)
        got += self.link.take()
        where = await self.ask("?pos x")
        await self.settled("!axis x 1")
        self.undo.pop()
        exchange = Exchange(list(lines), got, sent.err)
        try:
            at = float(where.got[0])
        except (IndexError, ValueError):
            self.obs["disable_during_move"] = _unknown("no position after the move",
                                                       exchange, where)
            return True
        at_target = abs(at - target) <= abs(step) / 20
        if early and sent.err == 0 and at_target:  # the report came before ?err's answer
            if last:
                self.obs["disable_during_move"] = _unseen(
                    "the move ended before !axis x 0 arrived", ("continue", "stop", "refuse"),
                    exchange)
            return False
        if sent.err == 2:
            value, note = "refuse", "disabling a moving axis is refused (error 2)"
        elif sent.err == 0 and at_target:
            value, note = "continue", "the move went on to its target"
        elif sent.err == 0:
            value, note = "stop", f"the move stopped at {at}, short of its target"
        else:
            self.obs["disable_during_move"] = _unknown(f"error {sent.err}", exchange, where)
            return True
        self.obs["disable_during_move"] = _seen(value, note, exchange, where)
        return True

    async def abort(self, p0: float, step: float, decimals: int, wait: float, stop: bytes,
                    kind: str, last: bool) -> bool:
        """``a`` (``abort_letter``, ``abort_report``) or Ctrl+C (``ctrl_c``) during a
        move (L6808-6834). False (nothing recorded unless ``last``) when the move had
        ended before the stop arrived."""
        target = p0 + step
        line = f"!moa x {target:.{decimals}f}"
        self.link.take()
        self.link.send(line)
        self.link.write(stop)
        if stop == b"\x03":
            self.link.send("")  # ends the line 0x03 is part of where it is no stop
        first, got = await self.wait_report(wait)
        await self.link.quiet(max(self.options.settle, self.options.move_time))
        rest = self.link.take()
        got += rest
        reports = [g for g in got if _REPORT.match(g)]
        # Ctrl+C where it is no stop: "\x03" was a line of its own, refused (an error);
        # read before ?pos, which sets the error back to 0.
        err = await self.ask("?err")
        where = await self.ask("?pos x")
        sent = [line, stop.decode("latin-1").rstrip("\r") or "(Ctrl+C)"]
        exchange = Exchange(sent, got)
        try:
            at = float(where.got[0])
        except (IndexError, ValueError):
            at = math.nan
        stopped = abs(at - target) > abs(step) / 1000
        if kind == "a":
            if not stopped:
                if last:
                    self.obs["abort_letter"] = _unseen("the move ended before 'a' arrived",
                                                       ("E", "@"), exchange, where)
                    self.obs["abort_report"] = _unseen("the move ended before 'a' arrived",
                                                       ("no", "yes"), exchange, where)
                return False
            letter = first[:1] if first else None
            if letter in (AxisStatus.ERROR, AxisStatus.READY):
                self.obs["abort_letter"] = _seen(letter, f"the stopped axis reports "
                                                         f"{letter!r}", exchange, where)
            else:
                self.obs["abort_letter"] = _unknown(f"the stopped move reported {first!r}",
                                                    exchange, where)
            if len(reports) == 1:
                self.obs["abort_report"] = _seen("no", "'a' sends no report of its own",
                                                 exchange)
            elif len(reports) == 2:
                self.obs["abort_report"] = _seen("yes", "'a' sends a report of its own",
                                                 exchange)
            else:
                self.obs["abort_report"] = _unknown(f"{len(reports)} reports after 'a'",
                                                    exchange)
            return True
        refused = err.err not in (0, None)
        if not stopped and not refused:
            if last:
                self.obs["ctrl_c"] = _unseen("the move ended before Ctrl+C arrived",
                                             ("stop", "ignore", "stop_report"), exchange,
                                             where, err)
            return False
        if not stopped and len(reports) == 1:
            value, note = "ignore", ("the move ran to its target and 0x03 made a line of "
                                     "its own, refused: an ordinary byte")
        elif stopped and len(reports) == 1:
            value, note = "stop", "the move stopped, only its own report"
        elif stopped and len(reports) == 2:
            value, note = "stop_report", "the move stopped, and a report of Ctrl+C's own"
        else:
            self.obs["ctrl_c"] = _unknown(f"X at {at}, {len(reports)} reports, error "
                                          f"{err.err}", exchange, where, err)
            return True
        self.obs["ctrl_c"] = _seen(value, note, exchange, where, err)
        return True

    async def pause(self, step: float, decimals: int, wait: float) -> None:
        """A move with ``pause`` set: how long its report waits (L6845-6899)."""
        before = await self.ask("?pause")
        if before.err != 0 or len(before.got) != 1:
            self.extra["pause"] = {"note": "?pause not available", "lines":
                                   before.transcript()}
            return
        self.undo.append(f"!pause {before.got[0].strip()}")
        await self.ask("!pause 200")
        began = time.monotonic()
        move = await self.move(f"!mor x {step:.{decimals}f}")
        took = time.monotonic() - began
        await self.ask(f"!pause {before.got[0].strip()}")
        self.undo.pop()
        await self.move(f"!mor x {-step:.{decimals}f}")
        self.extra["pause"] = {"pause_ms": 200, "seconds_to_report": round(took, 3),
                               "lines": move.transcript()}

    async def move_in_mode(self, mode: int, step: float, decimals: int, wait: float) -> None:
        """Mode 2 (``move_ok``) or 4 (``echo``, ``echo_report``): a move and a read sent
        right after it; where the acknowledgement or echo comes tells."""
        await self.set_mode(mode)
        line = f"!mor x {step:.{decimals}f}"
        self.link.take()
        self.link.send(line, "?pos x")
        report, got = await self.wait_report(wait)
        if report is None:
            # No report (echo_report=no): wait until X stands.
            for _ in range(int(wait / 0.05) + 1):
                await asyncio.sleep(0.05)
                self.link.send("?statusaxis x")
                await self.link.quiet(self.options.settle)
                if not any(g[:1] == MOVING for g in self.link.inbox[-2:]):
                    break
        await self.link.quiet(self.options.settle)
        got += self.link.take()
        exchange = Exchange([line, "?pos x"], got)
        if mode == 2:
            self.obs["move_ok"] = self.decide_move_ok(exchange)
        else:
            self.decide_move_echo(exchange, report)
        await self.set_mode(1)
        await self.move(f"!mor x {-step:.{decimals}f}")

    def decide_move_ok(self, exchange: Exchange) -> Observation:
        got = [g for g in exchange.got if not g.lower().startswith("?statusaxis")]
        data = [i for i, g in enumerate(got) if _NUMBER.match(g.strip())]
        reports = [i for i, g in enumerate(got) if _REPORT.match(g)]
        if len(data) != 1 or len(reports) != 1:
            return _unknown("a move and a read in mode 2 answered in no known way", exchange)
        pos, report = data[0], reports[0]
        oks = [i for i, g in enumerate(got) if g.lower() == "ok..."]
        if self.ack_reads == "before":
            oks = [i for i in oks if i != pos - 1]
        elif self.ack_reads == "after":
            oks = [i for i in oks if i != pos + 1]
        if len(oks) == 1 and oks[0] < pos:
            return _seen("immediate", "the move's OK... came before the read's data",
                         exchange)
        if len(oks) == 1 and pos < oks[0] == report - 1:
            return _seen("completion", "the move's OK... came with its report", exchange)
        return _unknown("the move's OK... came in no known place", exchange)

    def decide_move_echo(self, exchange: Exchange, report: str | None) -> None:
        line = exchange.sent[0]
        got = [g for g in exchange.got if not g.lower().startswith("?statusaxis")
               and not (self.echo_all == "yes" and g in ("?pos x",))]
        echoes = [i for i, g in enumerate(got) if echo_form(g, line)]
        data = [i for i, g in enumerate(got) if _NUMBER.match(g.strip())]
        if len(echoes) != 1 or not data:
            self.obs["echo_report"] = _unknown("a move in mode 4 was echoed in no known way",
                                               exchange)
            return
        echo, pos = echoes[0], data[0]
        self.obs["echo_report"] = (_seen("yes", "the move's echo is followed by its report",
                                         exchange) if report is not None else
                                   _seen("no", "the move's echo is all it gets", exchange))
        seen = self.obs.get("echo")
        if seen is not None and seen.value == "after":
            return
        if echo < pos:
            self.obs["echo"] = Observation(
                "before", "mode changes echoed under the mode on arrival; the move's echo "
                "came at once", (seen.lines if seen else []) + exchange.transcript())
        else:
            self.obs["echo"] = Observation(
                "completion", "mode changes echoed under the mode on arrival; the move's "
                "echo came at its completion", (seen.lines if seen else []) +
                exchange.transcript())
