"""``tango-aio probe``: learn what a controller's firmware does, from the wire.

The manual leaves many details open (:mod:`tango_aio.sim.profiles` lists them as the
emulator's *switches*). The probe finds, on a real unit, the value of every switch that can
be observed from the wire, and writes a **fingerprint**: JSON with the switch values, the
lines behind each, the unit's identity, axes and settings, and the project's version.
``sim://?fingerprint=FILE`` then emulates that unit, and the wire trace
(``--trace FILE``, :mod:`tango_aio.fieldkit._trace`) replays as a test
(:func:`tango_aio.testing.replay`).

What it does to the controller:

* By default it only reads, and sets back what it changed: it selects autostatus modes
  1, 2 and 4 in turn (the mode it found is restored at the end), sets ``extmode`` to the
  other value for one ``?lim`` (restored at once), and sends a refused set line in mode 2
  (``!vel x -1``), which changes nothing. No move line is written.
* ``--save`` also sends ``!save`` once in mode 2, to see how it is acknowledged: that
  writes the present settings to the controller's memory as its power-on settings.
* ``--moves`` also moves one axis (X) by small distances inside its limits (a few
  tenths of a second of travel each): a move and its way back, a zero move, a move refused
  beyond the limit, a move sent during a move, ``a`` and Ctrl+C during a move, a move with
  a ``pause``, ``!joy 0`` during a move (the joystick setting is restored), and in modes 2
  and 4 a move with a read during it. At the end the axis returns to where it was (to the
  precision of ``?pos``).

The probe talks to the port below :class:`~tango_aio.Controller`: it writes
raw lines and reads every line the controller sends, since the driver's routing would hide
(or refuse) exactly what it needs to see. It opens the link with
:mod:`tango_aio.controller._connection`'s code. Reads in mode 1 are followed by ``?err`` and
``?version``, whose known answers end each exchange; in modes 2 and 4 an exchange ends after
``settle`` seconds of silence.

The decisions from the observed lines are pure functions (``decide_*``), tested without
I/O; a value no switch has is recorded under ``unknown`` with its lines, and the command
asks the user to send the file. An instruction the unit answers with nothing and error 4
("invalid instruction", L970) is recorded under ``lacks``, and the probe goes on without
it: without ``?lim`` there is no ``lim_cr_bug`` to see, the moves stay within
``2 * 10**(4 - decimals)`` of where X stands (towards 0), and no move goes beyond a limit.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime
import json
import math
import re
import sys
import time
from collections.abc import Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._argtypes import count_type, seconds_type, url_type, writable_path
from ..errors import ConnectionLostError, ProbeError, TangoError
from ..link import TangoProtocol
from ..sansio import CACHED_SETTINGS
from ..status import ABSENT, MOVING, AxisStatus
from ._trace import format_record, trace_header

__all__ = [
    "FINGERPRINT_FORMAT",
    "MOVE_SWITCHES",
    "SAVE_SWITCHES",
    "SWITCH_NAMES",
    "Exchange",
    "Observation",
    "ProbeError",
    "ProbeOptions",
    "ProbeResult",
    "add_probe_command",
    "comparable",
    "probe",
    "write_fingerprint",
]

#: The ``format`` field of a fingerprint file.
FINGERPRINT_FORMAT = "tango_aio.fingerprint/1"

#: Where the probe asks users to send fingerprints and traces.
REPORT_TO = "the project's issue tracker (a new issue titled 'fingerprint: <model> <firmware>')"

#: Every switch the probe knows (those of :mod:`tango_aio.sim.profiles`, by name: the
#: driver side does not import the emulator's rules; a test keeps the two lists equal).
SWITCH_NAMES: tuple[str, ...] = (
    "echo", "echo_report", "echo_all", "echo_text", "ack_reads", "err_number",
    "ack_mode_change", "move_ok", "ack_case", "save_ack", "refused_move_report",
    "move_during_move", "disable_during_move", "zero_move_report", "report_width",
    "status_tail", "absent_axes", "joystick_letter", "abort_letter", "abort_report",
    "ctrl_c", "help_number", "help_case", "service_end", "lim_cr_bug", "version_format",
    "version_value", "line_end", "numbers", "instruction_set", "local_echo")

#: Switches only moves show (observed with ``--moves``). ``echo`` tells ``after`` from
#: the others without moves, ``before`` from ``completion`` only with a move; ``numbers``
#: tells ``plain`` from ``negzero`` only from a value just below zero (a move).
MOVE_SWITCHES = frozenset({
    "echo_report", "move_ok", "refused_move_report", "move_during_move", "disable_during_move",
    "zero_move_report", "report_width", "abort_letter", "abort_report", "ctrl_c"})

#: Switches only ``--save`` shows.
SAVE_SWITCHES = frozenset({"save_ack"})

_REPORT = re.compile(r"^[A-Za-z@\-]{1,4}\.$")
_ACK = re.compile(r"^(ok\.\.\.|err( \d+)?)$", re.IGNORECASE)
_INT = re.compile(r"^[+-]?\d+$")
_NUMBER = re.compile(r"^[+-]?\d+(\.\d+)?$")
_VERSION_NEW = re.compile(r"^[^,]+, Version [^,]+, .*\S , \d\d:\d\d:\d\d$")
_VERSION_OLD = re.compile(r"^[^,]+, Version [^,]+, .*\S, \d\d:\d\d:\d\d$")
_NEG_ZERO = re.compile(r"^-0(\.0*)?$")


# ---------------------------------------------------------------------------------------
# What was seen (pure)


@dataclass
class Exchange:
    """Lines written and the lines that came back for them (``err``: the ``?err`` answer
    after them, in mode 1)."""

    sent: list[str]
    got: list[str]
    err: int | None = None

    def transcript(self) -> list[str]:
        """``-> line`` / ``<- line`` texts, and the error the ``?err`` after them showed.

        Returns
        -------
        list[str]
            The texts, in order.
        """
        out = [f"-> {line}" for line in self.sent] + [f"<- {line}" for line in self.got]
        if self.err is not None:
            out.append(f"(?err: {self.err})")
        return out


@dataclass
class Observation:
    """What the probe concluded about one switch, and from which lines."""

    #: The switch value (``None``: not observed, or unknown).
    value: str | None
    #: Why: what was seen, or why nothing could be.
    note: str
    #: The exchanges behind it (``-> written``, ``<- received``).
    lines: list[str] = field(default_factory=list)
    #: The unit did something no value of the switch describes.
    unknown: bool = False
    #: The values it could still be, when not observed.
    candidates: list[str] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        """The observation as a JSON object.

        Returns
        -------
        dict[str, Any]
            ``value``, ``note`` and ``lines``; ``unknown`` and ``candidates`` when set.
        """
        out: dict[str, Any] = {"value": self.value, "note": self.note, "lines": self.lines}
        if self.unknown:
            out["unknown"] = True
        if self.candidates:
            out["candidates"] = self.candidates
        return out


def _seen(value: str, note: str, *exchanges: Exchange) -> Observation:
    return Observation(value, note, _lines(exchanges))


def _unseen(note: str, candidates: Sequence[str] = (), *exchanges: Exchange) -> Observation:
    return Observation(None, note, _lines(exchanges), candidates=list(candidates))


def _unknown(note: str, *exchanges: Exchange) -> Observation:
    return Observation(None, note, _lines(exchanges), unknown=True)


def _lines(exchanges: Iterable[Exchange]) -> list[str]:
    return [line for exchange in exchanges for line in exchange.transcript()]


def is_ack(line: str) -> bool:
    """Whether ``line`` looks like a mode-2 acknowledgement in any case (``OK...``,
    ``ERR``, ``ERR 5``).

    Parameters
    ----------
    line
        A received line.

    Returns
    -------
    bool
        Whether it is an acknowledgement.
    """
    return _ACK.match(line) is not None


def exchange_end(got: Sequence[str], version: str) -> tuple[int, int] | None:
    """Where a mode-1 exchange that ends with ``?err`` and ``?version`` ends in ``got``:
    the index of the first ``version`` line whose last line before it, move reports
    aside, is a number (``?err``'s answer), and that number's index.

    Parameters
    ----------
    got
        The lines received so far.
    version
        The ``?version`` line.

    Returns
    -------
    tuple[int, int] or None
        The indices of the ``?version`` line and of ``?err``'s answer; ``None`` while
        the exchange has not ended.
    """
    for index, line in enumerate(got):
        if line != version:
            continue
        at = index - 1
        while at >= 0 and _REPORT.match(got[at]):
            at -= 1
        if at >= 0 and _INT.match(got[at].strip()):
            return index, at
    return None


def normalized(line: str) -> str:
    """``line`` re-printed the way ``echo_text=normalized`` describes: lower case, single
    spaces, numbers without redundant zeros or ``+``.

    Parameters
    ----------
    line
        A line as sent.

    Returns
    -------
    str
        The line re-printed.
    """
    words = []
    for word in line.lower().split():
        if _NUMBER.match(word):
            text = f"{float(word):f}".rstrip("0").rstrip(".")
            words.append(text or "0")
        else:
            words.append(word)
    return " ".join(words)


def echo_form(line: str, sent: str) -> str | None:
    """The ``echo_text`` value under which ``line`` is the echo of ``sent`` (``None``: it
    is no echo of it).

    Parameters
    ----------
    line
        A received line.
    sent
        The line sent.

    Returns
    -------
    str or None
        The ``echo_text`` value, or ``None``.
    """
    if line == sent:
        return "exact"
    if sent.startswith("!") and line == sent[1:]:
        return "nobang"
    if line == normalized(sent):
        return "normalized"
    return None


def decide_local_echo(first: Exchange) -> Observation:
    """``local_echo`` from the first ``?version`` in mode 1, where the controller echoes
    nothing (L2117): a copy of the line sent is the link's.

    Parameters
    ----------
    first
        The exchange of the first ``?version``.

    Returns
    -------
    Observation
        The value of ``local_echo``.
    """
    sent = first.sent[0]
    if first.got[:1] == [sent]:
        return _seen("yes", "the line sent in mode 1 came back first, the reply after it",
                     first)
    return _seen("no", "only the reply came back in mode 1", first)


def decide_line_end(lf_lines: list[str], exchange: Exchange) -> Observation:
    """``line_end``: ``crlf`` when the controller sent any LF.

    Parameters
    ----------
    lf_lines
        The lines that arrived with an LF.
    exchange
        An exchange to show as the evidence.

    Returns
    -------
    Observation
        The value of ``line_end``.
    """
    if lf_lines:
        return Observation("crlf", "replies carry a LF after their CR",
                           [f"<- {line!r}" for line in lf_lines[:3]])
    return _seen("cr", "no LF in any reply", exchange)


def decide_version_format(exchange: Exchange, version: str) -> Observation:
    """``version_format`` from the ``?version`` line (L1063-1107, old L414-426).

    Parameters
    ----------
    exchange
        The exchange of ``?version``.
    version
        Its answer.

    Returns
    -------
    Observation
        The value of ``version_format``.
    """
    if _VERSION_NEW.match(version):
        return _seen("new", "a space before the comma ahead of the time", exchange)
    if _VERSION_OLD.match(version):
        return _seen("old", "no space before the comma ahead of the time", exchange)
    return _unknown("a ?version reply of neither known form", exchange)


def decide_version_value(exchange: Exchange, version: str) -> Observation:
    """``version_value`` from ``?version 1``: the version number only (L1057-1059,
    L1107), or the whole ``?version`` line, the value ignored (as by a ``version`` that
    takes none, old L416-418).

    Parameters
    ----------
    exchange
        The exchange of ``?version 1``.
    version
        The ``?version`` answer.

    Returns
    -------
    Observation
        The value of ``version_value``.
    """
    if exchange.got == [version] and exchange.err == 0:
        return _seen("line", "?version 1 answered the whole ?version line", exchange)
    if len(exchange.got) == 1 and exchange.err == 0 and "," not in exchange.got[0]:
        return _seen("number", "?version 1 answered the version number only", exchange)
    if not exchange.got and exchange.err == 4:
        return _unseen("moot: ?version 1 is refused with error 4 (version takes no value, "
                       "as in the older edition)", (), exchange)
    return _unknown("?version 1 answered neither the number, nor the ?version line, nor "
                    "error 4", exchange)


def decide_instruction_set(version1: Exchange, help5: Exchange, version: str
                           ) -> Observation:
    """``instruction_set`` from ``?version 1`` and ``?help 5``, values the older
    edition's ``version`` and ``help`` did not take (old L416-418, old L805-811): error 4
    for ``?version 1`` is the older edition's; where ``?version 1`` answers the whole
    line (the value ignored), ``?help 5`` tells.

    Parameters
    ----------
    version1
        The exchange of ``?version 1``.
    help5
        The exchange of ``?help 5``.
    version
        The ``?version`` answer.

    Returns
    -------
    Observation
        The value of ``instruction_set``.
    """
    if not version1.got and version1.err == 4:
        return _seen("older", "?version 1 answered nothing and set error 4", version1)
    if version1.got == [version] and version1.err == 0:
        if not help5.got and help5.err == 4:
            return _seen("older", "?version 1 answered the whole ?version line (the value "
                         "ignored), ?help 5 nothing and error 4", version1, help5)
        if len(help5.got) == 1 and help5.err is not None:
            return _seen("full", "?version 1 answered the whole ?version line (the value "
                         "ignored), ?help 5 answered", version1, help5)
        return _unknown("?version 1 ignored its value and ?help 5 answered neither a line "
                        "nor error 4", version1, help5)
    if version1.got and version1.err == 0:
        return _seen("full", "?version 1 answered", version1)
    return _unknown("?version 1 answered neither a version nor error 4", version1)


def decide_help_number(exchange: Exchange) -> Observation:
    """``help_number`` from ``?help 5`` (L2915-2919).

    Parameters
    ----------
    exchange
        The exchange of ``?help 5``.

    Returns
    -------
    Observation
        The value of ``help_number``.
    """
    if not exchange.got and exchange.err == 4:
        return _unseen("moot: ?help N is refused with error 4 (help takes no value, as in "
                       "the older edition)", (), exchange)
    if len(exchange.got) == 1 and exchange.err is not None:
        line = exchange.got[0]
        if re.match(r"(?i)^error 5,", line):
            return _seen("yes", "?help 5 repeats the number", exchange)
        if not re.match(r"(?i)^error", line):
            return _seen("no", "?help 5 answers the text only", exchange)
    return _unknown("?help 5 answered neither 'ERROR 5,text' nor the text", exchange)


def decide_help_case(exchange: Exchange) -> Observation:
    """``help_case`` from ``help`` (L2915-2919).

    Parameters
    ----------
    exchange
        The exchange of ``help``.

    Returns
    -------
    Observation
        The value of ``help_case``.
    """
    if len(exchange.got) == 1:
        line = exchange.got[0]
        if line.startswith("ERROR ") and "," in line:
            return _seen("upper", "help answers 'ERROR n,...'", exchange)
        if line.startswith("error ") and "," in line and line == line.lower():
            return _seen("lower", "help answers 'error n,...' in lower case", exchange)
    return _unknown("help answered neither 'ERROR n,text' nor 'error n,text'", exchange)


def decide_service_end(exchange: Exchange) -> Observation:
    """``service_end`` from ``service`` (L2937-2943).

    Parameters
    ----------
    exchange
        The exchange of ``service``.

    Returns
    -------
    Observation
        The value of ``service_end``.
    """
    if exchange.err == 4 and not exchange.got:
        return _unseen("moot: service is refused with error 4", (), exchange)
    if exchange.got and exchange.got[-1] == "END_SERVICE_PRINT.":
        return _seen("yes", "service ends with END_SERVICE_PRINT.", exchange)
    if exchange.got and exchange.err == 0:
        return _seen("no", "service ends without END_SERVICE_PRINT.", exchange)
    return _unknown("service answered nothing", exchange)


def decide_lim_cr_bug(axes: int, extmode0: Exchange, extmode1: Exchange | None
                      ) -> Observation:
    """``lim_cr_bug`` from ``?lim`` in extmode 0 and 1 (L2196-2232, L4559-4621): an extra
    CR splits the reply in two. ``extmode1`` is ``None`` when the unit has no extmode,
    where ``both`` and ``extmode0`` are the same.

    Parameters
    ----------
    axes
        The unit's number of axes.
    extmode0
        The exchange of ``?lim`` in extmode 0.
    extmode1
        The exchange of ``?lim`` in extmode 1, or ``None``.

    Returns
    -------
    Observation
        The value of ``lim_cr_bug``.
    """
    if axes < 2:
        return _unseen("a 1-axis unit: the extra CR after the X pair cannot show",
                       ("extmode0", "none", "both"), extmode0)
    split0 = len(extmode0.got) == 2
    if len(extmode0.got) not in (1, 2):
        return _unknown("?lim answered neither one line nor two", extmode0)
    if extmode1 is None:
        value = "extmode0" if split0 else "none"
        return _seen(value, "the unit has no extmode (error 4): ?lim as in extmode 0 "
                     f"{'splits' if split0 else 'does not split'} (extmode0 and both are "
                     f"the same for it)", extmode0)
    if len(extmode1.got) not in (1, 2):
        return _unknown("?lim in extmode 1 answered neither one line nor two", extmode1)
    split1 = len(extmode1.got) == 2
    table = {(True, False): "extmode0", (False, False): "none", (True, True): "both"}
    found = table.get((split0, split1))
    if found is None:
        return _unknown("?lim splits in extmode 1 but not in extmode 0", extmode0, extmode1)
    return _seen(found, f"?lim splits in extmode 0: {split0}, in extmode 1: {split1}",
                 extmode0, extmode1)


def status_letters(line: str) -> tuple[str, str] | None:
    """The letters of an all-axes ``?statusaxis`` line and how it ends.

    Parameters
    ----------
    line
        A received line.

    Returns
    -------
    tuple[str, str] or None
        The letters and the ``status_tail`` value: ``"yes"`` (``.-``), ``"dot"`` (``.``
        alone, the completion report's shape) or ``"no"`` (the letters alone); ``None``
        if it is no such line.
    """
    if line.endswith(".-"):
        return line[:-2], "yes"
    if line.endswith(".") and "." not in line[:-1] and 1 <= len(line) - 1 <= 4:
        return line[:-1], "dot"
    if "." not in line and 1 <= len(line) <= 4:
        return line, "no"
    return None


def decide_status(exchange: Exchange, axes: int, joy: int | None
                  ) -> dict[str, Observation]:
    """``status_tail``, ``absent_axes`` and ``joystick_letter`` from ``?statusaxis``
    (L2662-2725) on a unit with ``axes`` axes, the joystick setting ``joy``.

    Parameters
    ----------
    exchange
        The exchange of ``?statusaxis``.
    axes
        The unit's number of axes.
    joy
        The joystick setting (``?joy``), or ``None`` if it is unknown.

    Returns
    -------
    dict[str, Observation]
        The observation of each of the three switches, by switch name.
    """
    out: dict[str, Observation] = {}
    parsed = status_letters(exchange.got[0]) if len(exchange.got) == 1 else None
    if parsed is None:
        note = "?statusaxis answered no line of letters (with or without '.-')"
        return {name: _unknown(note, exchange)
                for name in ("status_tail", "absent_axes", "joystick_letter")}
    letters, tail = parsed
    out["status_tail"] = _seen(tail, {"yes": "ends with '.-'", "dot": "ends with '.'",
                                      "no": "ends with the letters"}[tail], exchange)
    if axes >= 4:
        out["absent_axes"] = _unseen("every axis is present", ("dash", "omit"), exchange)
        present = letters
    elif len(letters) == 4 and set(letters[axes:]) <= {ABSENT}:
        out["absent_axes"] = _seen("dash", "absent axes show '-'", exchange)
        present = letters[:axes]
    elif len(letters) == axes:
        out["absent_axes"] = _seen("omit", "absent axes are left out", exchange)
        present = letters
    else:
        out["absent_axes"] = _unknown(f"{len(letters)} letters on a {axes}-axis unit",
                                      exchange)
        present = letters[:axes]
    if joy == 0 or joy is None:
        out["joystick_letter"] = _unseen("the joystick is off (or ?joy unknown): idle axes "
                                         "show '@' under either value", ("@", "J"), exchange)
    elif set(present) == {AxisStatus.READY}:
        out["joystick_letter"] = _seen("@", "idle axes show '@' with the joystick on",
                                       exchange)
    elif set(present) == {AxisStatus.JOYSTICK}:
        out["joystick_letter"] = _seen("J", "idle axes show 'J' with the joystick on",
                                       exchange)
    else:
        out["joystick_letter"] = _unseen("not every axis was idle", ("@", "J"), exchange)
    return out


def decide_numbers(exchanges: Sequence[Exchange], below_zero: Exchange | None
                   ) -> Observation:
    """``numbers`` (L66-70, L94-96) from numeric reads, and ``below_zero``: a read of a
    value just below zero (``-0.0000`` or ``0.0000``), when a move made one.

    Parameters
    ----------
    exchanges
        The exchanges of numeric reads.
    below_zero
        The read of a value just below zero, or ``None``.

    Returns
    -------
    Observation
        The value of ``numbers``.
    """
    words = [word for exchange in exchanges for line in exchange.got
             for word in line.replace(",", " ").split()]
    if any(word.startswith("+") for word in words):
        return _seen("plus", "positive values carry '+'", *exchanges)
    if below_zero is not None and len(below_zero.got) == 1:
        value = below_zero.got[0].strip()
        if _NEG_ZERO.match(value):
            return _seen("negzero", "a value just below zero reads '-0...'", below_zero)
        if re.match(r"^0(\.0*)?$", value):
            return _seen("plain", "a value just below zero reads '0...'", below_zero)
        return _unknown("a value just below zero read neither '0...' nor '-0...'",
                        below_zero)
    if any(_NEG_ZERO.match(word) for word in words):
        return _seen("negzero", "a value reads '-0...'", *exchanges)
    return _unseen("no '+'; plain and negzero differ only for a value just below zero "
                   "(seen with --moves when the axis stands near 0)", ("plain", "negzero"),
                   *exchanges)


def decide_mode_change_echo(into4: Exchange, back1: Exchange) -> Observation:
    """``echo`` from ``!autostatus 4`` sent in mode 1 and ``!autostatus 1`` sent in mode 4
    (L2117): echoed under the mode before (``before``, ``completion``) or after
    (``after``) the line.

    Parameters
    ----------
    into4
        The exchange of ``!autostatus 4`` sent in mode 1.
    back1
        The exchange of ``!autostatus 1`` sent in mode 4.

    Returns
    -------
    Observation
        The value of ``echo``.
    """
    echoed_into = [line for line in into4.got if echo_form(line, into4.sent[0])]
    echoed_back = [line for line in back1.got if echo_form(line, back1.sent[0])]
    if into4.got == [] and echoed_back and len(back1.got) == 1:
        return _unseen("echoed under the mode in force when the line arrives: before, or "
                       "completion (which only a move tells apart)",
                       ("before", "completion"), into4, back1)
    if echoed_into and len(into4.got) == 1 and back1.got == []:
        return _seen("after", "echoed under the mode in force after the line", into4, back1)
    return _unknown("the mode changes were echoed in no known way", into4, back1)


def decide_echo_all(exchange: Exchange, version: str) -> Observation:
    """``echo_all`` from ``?version`` in mode 4 (L2117, old L723).

    Parameters
    ----------
    exchange
        The exchange of ``?version`` in mode 4.
    version
        The ``?version`` answer of mode 1.

    Returns
    -------
    Observation
        The value of ``echo_all``.
    """
    echoes = [line for line in exchange.got if line == exchange.sent[0]]
    rest = [line for line in exchange.got if line != exchange.sent[0]]
    if rest == [version] and not echoes:
        return _seen("no", "a read is not echoed", exchange)
    if rest == [version] and len(echoes) == 1:
        return _seen("yes", "a read is echoed too", exchange)
    return _unknown("?version in mode 4 answered neither its line nor its line and echo",
                    exchange)


def decide_echo_text(exchange: Exchange) -> Observation:
    """``echo_text`` from a set line with a double space sent in mode 4 (L2168).

    Parameters
    ----------
    exchange
        The exchange of the set line.

    Returns
    -------
    Observation
        The value of ``echo_text``.
    """
    forms = {echo_form(line, exchange.sent[0]) for line in exchange.got}
    forms.discard(None)
    if len(exchange.got) == 1 and len(forms) == 1:
        (form,) = forms
        assert form is not None
        return _seen(form, f"the echo of {exchange.sent[0]!r} is {exchange.got[0]!r}",
                     exchange)
    return _unknown("the set line's echo is none of: the exact text, the text without '!', "
                    "the line re-printed", exchange)


def decide_ack_case(exchanges: Sequence[Exchange]) -> Observation:
    """``ack_case`` from every mode-2 ``OK...`` seen (L2099-2103).

    Parameters
    ----------
    exchanges
        The exchanges of mode 2.

    Returns
    -------
    Observation
        The value of ``ack_case``.
    """
    oks = {line for exchange in exchanges for line in exchange.got
           if line.lower() == "ok..."}
    table = {"OK...": "upper", "ok...": "lower", "Ok...": "title"}
    if len(oks) == 1 and next(iter(oks)) in table:
        ok = next(iter(oks))
        return _seen(table[ok], f"acknowledged {ok!r}", *exchanges)
    if not oks:
        return _unknown("no OK... seen in mode 2", *exchanges)
    return _unknown(f"acknowledgements {sorted(oks)} of no single known case", *exchanges)


def decide_ack_mode_change(into2: Exchange, back1: Exchange) -> Observation:
    """``ack_mode_change`` (L2060-2103): ``!autostatus 2`` sent in mode 1 and
    ``!autostatus 1`` sent in mode 2, acknowledged per the mode after or before.

    Parameters
    ----------
    into2
        The exchange of ``!autostatus 2`` sent in mode 1.
    back1
        The exchange of ``!autostatus 1`` sent in mode 2.

    Returns
    -------
    Observation
        The value of ``ack_mode_change``.
    """
    into = [line for line in into2.got if is_ack(line)]
    back = [line for line in back1.got if is_ack(line)]
    if len(into) == 1 and not back and len(into2.got) == 1 and not back1.got:
        return _seen("new", "acknowledged per the mode after the line", into2, back1)
    if not into and len(back) == 1 and not into2.got and len(back1.got) == 1:
        return _seen("old", "acknowledged per the mode before the line", into2, back1)
    return _unknown("the mode changes were acknowledged in no known way", into2, back1)


def decide_ack_reads(exchange: Exchange, version: str) -> Observation:
    """``ack_reads`` from ``?version`` in mode 2 (L2099-2103).

    Parameters
    ----------
    exchange
        The exchange of ``?version`` in mode 2.
    version
        The ``?version`` answer of mode 1.

    Returns
    -------
    Observation
        The value of ``ack_reads``.
    """
    got = exchange.got
    if got == [version]:
        return _seen("no", "a read is not acknowledged", exchange)
    if len(got) == 2 and got[1] == version and got[0].lower() == "ok...":
        return _seen("before", "a read is acknowledged before its data", exchange)
    if len(got) == 2 and got[0] == version and got[1].lower() == "ok...":
        return _seen("after", "a read is acknowledged after its data", exchange)
    return _unknown("?version in mode 2 answered in no known way", exchange)


def decide_err_number(exchange: Exchange) -> Observation:
    """``err_number`` from a refused set line in mode 2 (L2099, L2150-2152).

    Parameters
    ----------
    exchange
        The exchange of the refused set line.

    Returns
    -------
    Observation
        The value of ``err_number``.
    """
    if len(exchange.got) == 1:
        line = exchange.got[0]
        if re.match(r"(?i)^err \d+$", line):
            return _seen("yes", "refused with the error number", exchange)
        if re.match(r"(?i)^err$", line):
            return _seen("no", "refused with a bare ERR", exchange)
    return _unknown("the refused line got neither 'ERR n' nor 'ERR'", exchange)


def decide_save_ack(exchange: Exchange) -> Observation:
    """``save_ack`` from ``!save`` in mode 2 (L1738-1762, L2081).

    Parameters
    ----------
    exchange
        The exchange of ``!save``.

    Returns
    -------
    Observation
        The value of ``save_ack``.
    """
    oks = [line for line in exchange.got if line.lower() == "ok..."]
    if len(oks) == len(exchange.got) == 1:
        return _seen("once", "!save answered one OK...", exchange)
    if len(oks) == len(exchange.got) == 2:
        return _seen("twice", "!save answered OK... twice", exchange)
    return _unknown("!save answered neither one OK... nor two", exchange)


# ---------------------------------------------------------------------------------------
# The link: raw lines over connection.py's transports


class _RawProtocol(TangoProtocol):
    """A :class:`TangoProtocol` that hands every received byte to the probe instead of
    routing it (so that ``connection.open_link`` opens it like the driver's own)."""

    def __init__(self, sink: Callable[[bytes], None], lost: Callable[[], None],
                 reply_timeout: float) -> None:
        super().__init__(reply_timeout=reply_timeout)
        self._sink = sink
        self._lost_cb = lost

    def data_received(self, data: bytes) -> None:
        """Bytes from the controller, to the probe (and the ``tango_aio.wire`` log)."""
        self._trace_received(data)
        self._sink(data)

    def connection_lost(self, exc: Exception | None) -> None:
        """The link is gone: wake the probe."""
        super().connection_lost(exc)
        self._lost_cb()


class _Link:
    """Raw lines to and from the controller, with the wire trace."""

    def __init__(self, reply_timeout: float) -> None:
        self.reply_timeout = reply_timeout
        self.records: list[tuple[float, str, bytes]] = []
        self.inbox: list[str] = []
        self.lf_lines: list[str] = []
        self.local_echo = False
        self._rx = b""
        self._tx = b""
        self._echo_pending = bytearray()
        self._arrived = asyncio.Event()
        self._lost = False
        self._protocol: _RawProtocol | None = None
        self._closer: Callable[[], Awaitable[None]] | None = None

    async def open(self, url: str, *, baudrate: int, rtscts: bool) -> None:
        from ..controller import open_link

        def make() -> TangoProtocol:
            return _RawProtocol(self._feed, self._on_lost, self.reply_timeout)

        protocol, self._closer = await open_link(url, make, {"baudrate": baudrate,
                                                             "rtscts": rtscts})
        assert isinstance(protocol, _RawProtocol)
        self._protocol = protocol

    async def close(self) -> None:
        protocol, self._protocol = self._protocol, None
        if protocol is None:
            return
        protocol.close()
        if self._closer is not None:
            await self._closer()
        else:
            wait_closed = getattr(protocol.transport, "wait_closed", None)
            if wait_closed is not None:
                with contextlib.suppress(Exception):
                    await wait_closed()

    def _on_lost(self) -> None:
        self._lost = True
        self._arrived.set()

    def _feed(self, data: bytes) -> None:
        now = time.monotonic()
        *lines, self._rx = (self._rx + data).split(b"\r")
        for raw in lines:
            self.records.append((now, "<-", raw))
            bare = raw.lstrip(b"\n")
            text = raw.decode("latin-1")
            if raw.startswith(b"\n"):
                self.lf_lines.append(text)
            if self.local_echo and self._echo_pending.startswith(bare + b"\r"):
                del self._echo_pending[:len(bare) + 1]
                continue
            self.inbox.append(bare.decode("latin-1"))
        self._arrived.set()

    def write(self, data: bytes) -> None:
        """Write ``data`` (lines with their CR, or a bare Ctrl+C)."""
        if self._protocol is None or self._lost:
            raise ConnectionLostError("the link to the controller is gone")
        now = time.monotonic()
        *lines, self._tx = (self._tx + data).split(b"\r")
        for line in lines:
            self.records.append((now, "->", line))
        if self.local_echo:
            self._echo_pending += data
        self._protocol._write(data)

    def send(self, *lines: str) -> None:
        """Write command lines."""
        self.write(b"".join(line.encode("latin-1") + b"\r" for line in lines))

    def take(self) -> list[str]:
        """Every line received since the last take."""
        lines, self.inbox = self.inbox, []
        return lines

    async def until(self, done: Callable[[list[str]], bool], timeout: float) -> None:
        """Wait until ``done(lines received so far)``; TimeoutError after ``timeout``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not done(self.inbox):
            if self._lost:
                raise ConnectionLostError("the link to the controller was lost")
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise TimeoutError
            self._arrived.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), remaining)

    async def quiet(self, settle: float) -> None:
        """Wait until no line arrived for ``settle`` seconds.

        A few more loop turns after the silence let bytes already on their way in be read
        (a busy event loop can run a due timer before the I/O that came meanwhile).

        Raises
        ------
        ConnectionLostError
            The link was lost meanwhile.
        """
        while True:
            if self._lost:
                raise ConnectionLostError("the link to the controller was lost")
            self._arrived.clear()
            try:
                await asyncio.wait_for(self._arrived.wait(), settle)
                continue
            except TimeoutError:
                pass
            for _ in range(3):
                await asyncio.sleep(0)
            if not self._arrived.is_set():
                return

    def trace_text(self) -> str:
        """The wire trace (:mod:`tango_aio.fieldkit._trace`'s format)."""
        lines = [trace_header()]
        lines += [format_record(t, "->" if d == "->" else "<-", data)
                  for t, d, data in self.records]
        return "\n".join(lines) + "\n"


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
        1`` on firmware that ignores the value).

        Returns
        -------
        Exchange
            The lines sent and their answer.

        Raises
        ------
        ProbeError
            No answer came in time.
        """
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
        ("invalid instruction", L970) is recorded among those the unit lacks.

        Returns
        -------
        Exchange
            The line sent and its answer.
        """
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
        came before the answers to the lines after them).

        Returns
        -------
        bool
            Whether the second move was sent during the first.
        """
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
        when the move had ended before the line arrived.

        Returns
        -------
        bool
            Whether the line arrived during the move.
        """
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
        ended before the stop arrived.

        Returns
        -------
        bool
            Whether the stop arrived during the move.
        """
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


# ---------------------------------------------------------------------------------------
# The command


def add_probe_command(commands: Any) -> None:
    """Add ``tango-aio probe`` to the CLI's subcommands.

    Parameters
    ----------
    commands
        The CLI's subparsers (``argparse``'s ``add_subparsers()``).
    """
    parser = commands.add_parser(
        "probe", help="learn what a controller's firmware does, write a fingerprint",
        description="Learn from the wire what this controller does where the manual is "
                    "silent, and write a fingerprint (JSON) to send to the project. "
                    "Without --moves nothing moves: it reads, and sets back what it "
                    "changed (the autostatus mode, extmode for one read).")
    parser.add_argument("url", type=url_type,
                        help="controller URL, e.g. /dev/ttyUSB0 or sim://")
    parser.add_argument("-o", "--output", default="tango-fingerprint.json", metavar="FILE",
                        type=writable_path,
                        help="fingerprint file (default tango-fingerprint.json)")
    parser.add_argument("--trace", metavar="FILE", type=writable_path,
                        help="also write the whole wire trace, with timestamps")
    parser.add_argument("--moves", action="store_true",
                        help="also make small moves of X inside its limits (asks first)")
    parser.add_argument("--save", action="store_true",
                        help="also send !save once (stores the present settings as the "
                             "controller's power-on settings)")
    parser.add_argument("--yes", action="store_true",
                        help="do not ask before --moves or --save")
    parser.add_argument("--baudrate", type=count_type, default=57600, help="serial baud rate")
    parser.add_argument("--settle", type=seconds_type, default=0.3,
                        help="seconds of silence that end an exchange (default 0.3)")
    parser.add_argument("--move-time", type=seconds_type, default=0.3,
                        help="about how long each test move takes, s (default 0.3)")
    parser.set_defaults(run=_probe_command)


def _confirm(args: argparse.Namespace) -> bool:
    what = []
    if args.moves:
        what.append("moves axis X by small distances inside its limits and back")
    if args.save:
        what.append("sends !save (the present settings become the power-on settings)")
    print(f"The probe {' and '.join(what)} on the controller at {args.url}.",
          file=sys.stderr)
    if not sys.stdin.isatty():
        raise ValueError("confirm with --yes (stdin is not a terminal to ask)")
    try:
        answer = input("Continue? [y/N] ")
    except EOFError:
        answer = ""
    return answer.strip().lower() in ("y", "yes")


async def _probe_command(args: argparse.Namespace) -> int:
    """``tango-aio probe URL``: writes the fingerprint (0, also when it recorded unknown
    behaviour, which it asks to send), or fails with the error (1).

    Returns
    -------
    int
        The exit status.

    Raises
    ------
    ProbeError
        The probe failed (after the trace so far was written, if asked).
    """
    asks = (args.moves or args.save) and not args.yes and \
        not args.url.lower().startswith("sim://")
    if asks and not await asyncio.to_thread(_confirm, args):
        print("probe cancelled: nothing was sent", file=sys.stderr)
        return 1
    options = ProbeOptions(moves=args.moves, save=args.save, settle=args.settle,
                           move_time=args.move_time, baudrate=args.baudrate)
    try:
        result = await probe(args.url, options)
    except ProbeError as exc:
        if args.trace and exc.trace:
            await asyncio.to_thread(Path(args.trace).write_text, exc.trace, "utf-8")
            print(f"the wire trace so far is in {args.trace}: please send it with the "
                  f"error to {REPORT_TO}", file=sys.stderr)
        raise
    path = await asyncio.to_thread(write_fingerprint, result, args.output)
    if args.trace:
        await asyncio.to_thread(Path(args.trace).write_text, result.trace, "utf-8")
    ident = result.identity
    print(f"{ident.get('model', '?')} firmware {ident.get('firmware', '?')}, "
          f"{result.axes} axes")
    for name, obs in result.observations.items():
        shown = obs.value if obs.value is not None else (
            "UNKNOWN" if obs.unknown else "-")
        print(f"  {name:20} {shown:12} {obs.note}")
    print(f"fingerprint written to {path}" +
          (f", wire trace to {args.trace}" if args.trace else ""))
    if result.unknown:
        print(f"This controller does something no switch describes "
              f"({', '.join(result.unknown)}): the driver may not work with it yet. "
              f"Please send {path}{' and ' + args.trace if args.trace else ''} to "
              f"{REPORT_TO}.")
        return 0
    print(f"Please send {path}{' and ' + args.trace if args.trace else ''} to {REPORT_TO}: "
          f"every unit's fingerprint helps.")
    return 0
