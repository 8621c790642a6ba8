"""Decoding for people: status letters, error numbers, replies, events, exceptions and
instructions in words."""

from __future__ import annotations

import contextlib
import functools
import re
from collections.abc import Mapping
from typing import Any

from ..catalog import AXES, Form, Instruction, Signature
from ..catalog import Command as CommandLine
from ..errors import (
    ERROR_DESCRIPTIONS,
    MoveError,
    ProtocolError,
    parse_error_reply,
)
from ..events import (
    ConnectionLost,
    ControllerRestarted,
    MoveAborted,
    MoveFinished,
    Reconnected,
    StatusReport,
    TangoEvent,
    UnsolicitedLine,
)
from ..sansio import is_completion_line
from ..status import ABSENT, AxisStatus
from ._output import (
    _escaped,
)

# -- decoding of replies and events -----------------------------------------------------

#: Each status letter (:mod:`tango_aio.status`) in the shell's short words.
LETTER_MEANINGS: dict[str, str] = {
    AxisStatus.READY: "ok", AxisStatus.MOVING: "moving", AxisStatus.JOYSTICK: "ok, joystick",
    AxisStatus.LIMIT_SWITCH: "limit switch", AxisStatus.CALIBRATED: "ok, calibrated",
    AxisStatus.RANGE_MEASURED: "ok, range measured", AxisStatus.ERROR: "error/aborted",
    AxisStatus.TIMEOUT: "timeout", AxisStatus.CLOSED_LOOP: "closed loop",
    AxisStatus.MANUAL_ADJUSTMENT: "manual adjustment", ABSENT: "absent",
}

_KIND_NAMES = {"move": "move", "cal": "calibration", "rm": "range measure"}


def describe_letters(statuses: Mapping[str, str]) -> str:
    """``{"x": "@", "y": "E"}`` → ``"x=@ (ok) y=E (error/aborted)"``."""
    return " ".join(f"{axis}={letter} ({LETTER_MEANINGS.get(letter, 'unknown')})"
                    for axis, letter in statuses.items())


def letters_of_line(line: str) -> dict[str, str]:
    """The per-axis letters of a completion or statusaxis line (``@@E-.``, ``@@@-.-``);
    absent axes (``-``) are left out."""
    head = line.strip().split(".", 1)[0]
    return {axis: letter for axis, letter in zip(AXES, head, strict=False) if letter != ABSENT}


def describe_error(code: int | None) -> str:
    """An error number in words, from the manual's error table."""
    if code is None:
        return "error (the controller gave no number)"
    if code == 0:
        return "no error"
    return f"error {code}: {ERROR_DESCRIPTIONS.get(code, 'undocumented error number')}"


def describe_reply(command: CommandLine, reply: str) -> str:
    """The reply text, with error numbers, ``ERR n`` and status letters decoded."""
    return "\n".join(_describe_reply_line(command, line) for line in reply.split("\n"))


def _describe_reply_line(command: CommandLine, line: str) -> str:
    text = line.strip()
    if command.name == "err" or text.startswith("ERR"):
        try:
            code, _ = parse_error_reply(text)
        except ProtocolError:
            return line
        return f"{line}  → {describe_error(code)}"
    if command.name == "statusaxis" and text:
        letters = {command.axis: text} if command.axis else letters_of_line(text)
        return f"{line}  → {describe_letters(letters)}"
    return line


def describe_line(line: str) -> str:
    """An unsolicited line from the controller in words."""
    text = line.strip()
    if is_completion_line(text):
        return f"status report: {describe_letters(letters_of_line(text))}"
    if text.startswith("ERR"):
        with contextlib.suppress(ProtocolError):
            return f"controller reports {describe_error(parse_error_reply(text)[0])}"
    return f"unsolicited line: {line!r}"


def describe_event(event: TangoEvent) -> str | None:
    """An event of :meth:`Controller.events` in words (``None``: not worth showing)."""
    if isinstance(event, MoveFinished):
        what = _KIND_NAMES.get(event.kind, event.kind)
        letters = describe_letters(event.statuses) or "no status letters (autostatus 3)"
        return f"{what} finished: {letters}"
    if isinstance(event, StatusReport):
        return f"status report: {describe_letters(event.statuses)}"
    if isinstance(event, MoveAborted):
        if event.axes:
            lines = ", ".join(f"a {axis}" for axis in event.axes)
            return f"stop sent ({lines}): {' '.join(event.axes).upper()} stop"
        return f"abort sent ({'Ctrl+C' if event.ctrl_c else 'a'}): all axes stop"
    if isinstance(event, UnsolicitedLine):
        return describe_line(event.line)
    if isinstance(event, ConnectionLost):
        return f"connection lost: {event.cause or 'closed'}"
    if isinstance(event, Reconnected):
        return f"reconnected (attempt {event.attempt})"
    if isinstance(event, ControllerRestarted):
        changed = ", ".join(event.settings) or "none changed"
        return (f"the controller restarted (it was in autostatus {event.found}): "
                f"autostatus {event.autostatus} selected again, settings read again "
                f"({changed}); positions restart at 0")
    return None


def describe_exception(exc: BaseException) -> str:
    """An error as one line for the user: the message, with a move's status letters in
    words, and each member of an exception group."""
    if isinstance(exc, BaseExceptionGroup):
        return "; ".join(dict.fromkeys(describe_exception(e) for e in exc.exceptions))
    text = _escaped(" ".join(str(exc).split()) or type(exc).__name__)
    if isinstance(exc, MoveError) and exc.statuses:
        text = re.sub(r" with status \{[^{}]*\}", "", text)  # said in words below
        text = re.sub(r"\{([^{}]*)\}", _pairs, text)
        text = f"{text}: {describe_letters(exc.statuses)}"
    return text


def _pairs(match: re.Match[str]) -> str:
    """``{'x': '0.5000', 'y': 1.0}`` (a dict in a message) as ``x=0.5000 y=1.0``."""
    pairs = re.findall(r"'([^']*)': '?([^',]*)'?", match.group(1))
    return " ".join(f"{key}={value}" for key, value in pairs) if pairs else match.group(0)


_FORM_ORDER = [Form.SET, Form.READ, Form.BARE]


def describe_instruction(entry: Instruction) -> str:
    """Help text of one instruction from the catalog (the shell's ``help NAME``)."""
    first, *more = _summary_parts(entry.summary)
    lines = [f"{entry.name}: {first}", *(f"  {part}" for part in more)]
    if entry.aliases:
        lines.append(f"  also written: {', '.join(entry.aliases)}")
    for form in sorted(entry.forms, key=_FORM_ORDER.index):
        prefix = form.value
        what = ("reads" if entry.is_read(form) else "sets or runs")
        for sig in entry.signatures(form) or (Signature(),):
            usage = " ".join((f"{prefix}{entry.name}", *_usage(sig))).rstrip()
            lines.append(f"  {usage:<40} {what}")
    if entry.completion is not None:
        lines.append("  sends a completion report when the axes have stopped (autostatus)")
    if entry.section:
        lines.append(f"  manual section {entry.section}, line {entry.line}")
    return "\n".join(lines)


@functools.lru_cache(maxsize=1)
def _summary_split() -> re.Pattern[str]:
    """Where a catalog summary runs two of the manual's example lines together: before a
    verb that starts summaries (``... 10 10 10 Move Y axis to ...``)."""
    from ..catalog import INSTRUCTIONS

    verbs = {entry.summary.split()[0] for entry in INSTRUCTIONS.values() if entry.summary}
    verbs = {verb for verb in verbs if len(verb) > 2 and verb.isalpha() and verb.istitle()
             and verb not in _NOT_VERBS}
    alternatives = "|".join(sorted(verbs))
    return re.compile(rf"(?<=[a-z0-9)\]]) (?=(?:{alternatives}) )")


#: Words that start some summaries but do not start a sentence of their own.
_NOT_VERBS = frozenset({"Maximum", "Closed", "Multi", "One", "Only", "Liquid", "Trigger",
                        "Virtual", "Power", "Dummy"})


def _summary_parts(summary: str) -> list[str]:
    """A catalog summary as its sentences (see :func:`_summary_split`)."""
    return [part.strip() for part in _summary_split().split(summary) if part.strip()]


def _usage(sig: Signature) -> list[str]:
    words = [] if sig.axis.value == "none" else [
        "AXIS" if sig.axis.value == "required" else "[AXIS]"]
    for param in sig.lead:
        words.append(_param_word(param))
    if sig.per_axis:
        group = " ".join(_param_word(p) for p in sig.per_axis)
        words.append(group if sig.axis.value == "all" else f"{group}...")
    if sig.precision is not None:
        words.append("[digits]")
    return words


def _param_word(param: Any) -> str:
    if param.choices:
        text = f"{param.name}={'|'.join(str(c) for c in param.choices)}"
    elif param.lo is not None and param.hi is not None:
        text = f"{param.name}({param.lo:g}..{param.hi:g}{' ' + param.unit if param.unit else ''})"
    else:
        text = f"{param.name}{'(' + param.unit + ')' if param.unit else ''}"
    return f"[{text}]" if param.optional else text
