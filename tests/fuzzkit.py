"""Shared pieces of the fuzz tests (tests/unit/test_core_fuzz.py, tests/e2e/test_faults.py):
requests that reach every routing path, fragments of controller output, and plausible
answers computed from the core's state."""

from __future__ import annotations

import random

from tango_aio.catalog._instructions import Context
from tango_aio.sansio._core import ProtocolCore
from tango_aio.sansio._patterns import ReplyKind, ReplyPattern

#: Requests covering every routing path: reads, multi-line reads (terminator, count,
#: continuation + follow-up), sets, moves, ``save``, mode switches and a list entry.
REQUESTS = [
    "?pos", "?vel x", "statusaxis", "sa x", "?err", "service", "?mrt x 3", "?mrt 2", "detext",
    "?lim", "!vel 10", "!pos 0", "!moa 1", "moa 2", "!mor x 1", "m", "cal", "!rm", "save",
    "!save", "!autostatus 0", "!autostatus 1", "!autostatus 2", "!autostatus 3",
    "!autostatus 4", "reset", "!trigp -1 2.5",
]
CONTEXT = Context(extmode=0, axes=3)

#: Fragments of realistic controller output, glued at random with random bytes.
TOKENS = [
    b"\r", b"\r", b"\r", b"\n", b"\r\n", b"\x03", b"\x00", b"\xff", b" ",
    b"@@@-.", b"AAA-.", b"D@D-.", b"@@@-.-", b"M", b"OK...", b"ERR 5", b"ERR", b"ERR -1",
    b"ERROR 0,no error", b"ERROR 1,", b"ERROR 5,number outside range",
    b"END_SERVICE_PRINT.", b"= MR Encoder", b"02832", b"-2600 2600,", b"-800 800",
    b"0", b"12", b"1.0000 2.0000 3.0000", b"!vel 10", b"!MOA 1", b"moa 2", b"save",
    b"!autostatus 2", b"x" * 40, b"y" * 70, b"z" * 200,
]


def noise(rng: random.Random, size: int, token_share: float = 0.7) -> bytes:
    """About ``size`` bytes of tokens (share ``token_share``) and random bytes."""
    parts: list[bytes] = []
    total = 0
    while total < size:
        part = (rng.choice(TOKENS) if rng.random() < token_share
                else rng.randbytes(rng.randint(1, 16)))
        parts.append(part)
        total += len(part)
    return b"".join(parts)


def plausible_answer(core: ProtocolCore, rng: random.Random) -> bytes:
    """A line for what the oldest request owes, so that every path is reached: mostly one
    that fits what it expects, sometimes one that does not."""
    if not core._pending:
        return rng.choice([b"@@@-.", b"", b"R"]) + b"\r"
    head = core._pending[0]
    item = head.items[0].value
    if item == "echo":
        echo = head.echo.text if head.echo is not None else ""
        text = rng.choice([echo, echo.upper(), "  " + echo])
    elif item == "ack":
        text = rng.choice(["OK...", "OK...", "OK", "ERR 5", "ERR", "ERR -1", "ERR 12"])
    elif head.marker is not None:
        text = head.marker + "no error"
    elif head.rule.terminator is not None:
        text = rng.choice(["line", "", head.rule.terminator])
    elif rng.random() < 0.8:
        text = fitting_line(head.pattern, rng)
    else:
        text = rng.choice(["0", "R", "= F", "-1 1,", "1 2 3", "@@@-.-"])
    return text.encode("latin-1") + b"\r"


def fitting_line(pattern: ReplyPattern, rng: random.Random) -> str:
    """A line that ``pattern`` accepts."""
    count = rng.randint(pattern.low, min(pattern.high, 4))
    line = {
        ReplyKind.NUMBERS: " ".join(str(rng.choice([0, 12, -1, 2.5])) for _ in range(count)),
        ReplyKind.WORDS: " ".join(rng.choice(["0", "e", "1"]) for _ in range(count)),
        ReplyKind.STATUS: rng.choice(["@@@-.-", "M", "@"]),
        ReplyKind.HELP: "ERROR 5,number outside range",
        ReplyKind.ACK: "OK...",
        ReplyKind.ECHO: pattern.text,
        ReplyKind.MARKER: pattern.text + "text",
        ReplyKind.ANY: rng.choice(["R", "= F", "-1 1,", "1 2 3", "0"]),
    }[pattern.kind]
    assert pattern.accepts(line), (pattern, line)
    return line
