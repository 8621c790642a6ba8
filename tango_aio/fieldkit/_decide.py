"""The probe's rules: what the lines a unit sent show, decided without I/O."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..status import ABSENT, AxisStatus

#: The ``format`` field of a fingerprint file.
FINGERPRINT_FORMAT = "tango_aio.fingerprint/1"

#: Where the probe asks users to send fingerprints and traces.
REPORT_TO = "the project's issue tracker (a new issue titled 'fingerprint: <model> <firmware>')"

#: Every switch the probe knows (those of :mod:`tango_aio.sim.profiles`, by name: the
#: driver side does not import the emulator's rules; a test keeps the two lists equal).
SWITCH_NAMES: tuple[str, ...] = (
    "echo", "echo_report", "echo_all", "echo_text", "ack_reads", "err_number",
    "ack_mode_change", "move_ok", "ack_case", "save_ack", "refused_move_report",
    "move_during_move", "disable_during_move", "zero_move_report", "snapshot_pointer",
    "snapshot_step_report", "snapshot_while_moving", "report_width", "status_tail",
    "absent_axes", "joystick_letter", "abort_letter", "abort_report", "ctrl_c", "help_number",
    "help_case", "service_end", "lim_cr_bug", "version_format", "version_value", "line_end",
    "numbers", "instruction_set", "trigf_round", "periodic_first", "bidirectional_next",
    "trigcomp_read", "local_echo")

#: Switches only moves show (observed with ``--moves``). ``echo`` tells ``after`` from
#: the others without moves, ``before`` from ``completion`` only with a move; ``numbers``
#: tells ``plain`` from ``negzero`` only from a value just below zero (a move).
MOVE_SWITCHES = frozenset({
    "echo_report", "move_ok", "refused_move_report", "move_during_move", "disable_during_move",
    "zero_move_report", "report_width", "abort_letter", "abort_report", "ctrl_c"})

#: Switches only ``--save`` shows.
SAVE_SWITCHES = frozenset({"save_ack"})

#: Switches the probe does not observe: what a snapshot step does (a step moves the
#: stage, and the snapshot input may not be fitted; ``tango_aio.mm`` finds the pointer's
#: reading with a step of its own and works with each of the others), and the trigger
#: output's (the probe leaves the output alone).
UNPROBED_SWITCHES = frozenset({"snapshot_pointer", "snapshot_step_report",
                               "snapshot_while_moving", "trigf_round", "periodic_first",
                               "bidirectional_next", "trigcomp_read"})

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
    ``ERR``, ``ERR 5``)."""
    return _ACK.match(line) is not None


def exchange_end(got: Sequence[str], version: str) -> tuple[int, int] | None:
    """Where a mode-1 exchange that ends with ``?err`` and ``?version`` ends in ``got``:
    the index of the first ``version`` line whose last line before it, move reports
    aside, is a number (``?err``'s answer), and that number's index."""
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
    spaces, numbers without redundant zeros or ``+``."""
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
    is no echo of it)."""
    if line == sent:
        return "exact"
    if sent.startswith("!") and line == sent[1:]:
        return "nobang"
    if line == normalized(sent):
        return "normalized"
    return None


def decide_local_echo(first: Exchange) -> Observation:
    """``local_echo`` from the first ``?version`` in mode 1, where the controller echoes
    nothing (L2117): a copy of the line sent is the link's."""
    sent = first.sent[0]
    if first.got[:1] == [sent]:
        return _seen("yes", "the line sent in mode 1 came back first, the reply after it",
                     first)
    return _seen("no", "only the reply came back in mode 1", first)


def decide_line_end(lf_lines: list[str], exchange: Exchange) -> Observation:
    """``line_end``: ``crlf`` when the controller sent any LF."""
    if lf_lines:
        return Observation("crlf", "replies carry a LF after their CR",
                           [f"<- {line!r}" for line in lf_lines[:3]])
    return _seen("cr", "no LF in any reply", exchange)


def decide_version_format(exchange: Exchange, version: str) -> Observation:
    """``version_format`` from the ``?version`` line (L1063-1107, old L414-426)."""
    if _VERSION_NEW.match(version):
        return _seen("new", "a space before the comma ahead of the time", exchange)
    if _VERSION_OLD.match(version):
        return _seen("old", "no space before the comma ahead of the time", exchange)
    return _unknown("a ?version reply of neither known form", exchange)


def decide_version_value(exchange: Exchange, version: str) -> Observation:
    """``version_value`` from ``?version 1``: the version number only (L1057-1059,
    L1107), or the whole ``?version`` line, the value ignored (as by a ``version`` that
    takes none, old L416-418)."""
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
    line (the value ignored), ``?help 5`` tells."""
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
    """``help_number`` from ``?help 5`` (L2915-2919)."""
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
    """``help_case`` from ``help`` (L2915-2919)."""
    if len(exchange.got) == 1:
        line = exchange.got[0]
        if line.startswith("ERROR ") and "," in line:
            return _seen("upper", "help answers 'ERROR n,...'", exchange)
        if line.startswith("error ") and "," in line and line == line.lower():
            return _seen("lower", "help answers 'error n,...' in lower case", exchange)
    return _unknown("help answered neither 'ERROR n,text' nor 'error n,text'", exchange)


def decide_service_end(exchange: Exchange) -> Observation:
    """``service_end`` from ``service`` (L2937-2943)."""
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
    where ``both`` and ``extmode0`` are the same."""
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
    """The letters of an all-axes ``?statusaxis`` line and how it ends."""
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
    (L2662-2725) on a unit with ``axes`` axes, the joystick setting ``joy``."""
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
    value just below zero (``-0.0000`` or ``0.0000``), when a move made one."""
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
    (``after``) the line."""
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
    """``echo_all`` from ``?version`` in mode 4 (L2117, old L723)."""
    echoes = [line for line in exchange.got if line == exchange.sent[0]]
    rest = [line for line in exchange.got if line != exchange.sent[0]]
    if rest == [version] and not echoes:
        return _seen("no", "a read is not echoed", exchange)
    if rest == [version] and len(echoes) == 1:
        return _seen("yes", "a read is echoed too", exchange)
    return _unknown("?version in mode 4 answered neither its line nor its line and echo",
                    exchange)


def decide_echo_text(exchange: Exchange) -> Observation:
    """``echo_text`` from a set line with a double space sent in mode 4 (L2168)."""
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
    """``ack_case`` from every mode-2 ``OK...`` seen (L2099-2103)."""
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
    ``!autostatus 1`` sent in mode 2, acknowledged per the mode after or before."""
    into = [line for line in into2.got if is_ack(line)]
    back = [line for line in back1.got if is_ack(line)]
    if len(into) == 1 and not back and len(into2.got) == 1 and not back1.got:
        return _seen("new", "acknowledged per the mode after the line", into2, back1)
    if not into and len(back) == 1 and not into2.got and len(back1.got) == 1:
        return _seen("old", "acknowledged per the mode before the line", into2, back1)
    return _unknown("the mode changes were acknowledged in no known way", into2, back1)


def decide_ack_reads(exchange: Exchange, version: str) -> Observation:
    """``ack_reads`` from ``?version`` in mode 2 (L2099-2103)."""
    got = exchange.got
    if got == [version]:
        return _seen("no", "a read is not acknowledged", exchange)
    if len(got) == 2 and got[1] == version and got[0].lower() == "ok...":
        return _seen("before", "a read is acknowledged before its data", exchange)
    if len(got) == 2 and got[0] == version and got[1].lower() == "ok...":
        return _seen("after", "a read is acknowledged after its data", exchange)
    return _unknown("?version in mode 2 answered in no known way", exchange)


def decide_err_number(exchange: Exchange) -> Observation:
    """``err_number`` from a refused set line in mode 2 (L2099, L2150-2152)."""
    if len(exchange.got) == 1:
        line = exchange.got[0]
        if re.match(r"(?i)^err \d+$", line):
            return _seen("yes", "refused with the error number", exchange)
        if re.match(r"(?i)^err$", line):
            return _seen("no", "refused with a bare ERR", exchange)
    return _unknown("the refused line got neither 'ERR n' nor 'ERR'", exchange)


def decide_save_ack(exchange: Exchange) -> Observation:
    """``save_ack`` from ``!save`` in mode 2 (L1738-1762, L2081)."""
    oks = [line for line in exchange.got if line.lower() == "ok..."]
    if len(oks) == len(exchange.got) == 1:
        return _seen("once", "!save answered one OK...", exchange)
    if len(oks) == len(exchange.got) == 2:
        return _seen("twice", "!save answered OK... twice", exchange)
    return _unknown("!save answered neither one OK... nor two", exchange)
