"""Reply patterns (tango_aio.sansio._patterns) and the core's reply check (tier 1, sans-IO)."""

from __future__ import annotations

import random

import pytest
from fuzzkit import fitting_line
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import INSTRUCTIONS, Context, LineRule, parse
from tango_aio.catalog._replies import reply_rule
from tango_aio.sansio._core import (
    AckReads,
    Completed,
    Dropped,
    Mismatched,
    ProtocolCore,
    Replied,
    RequestLost,
    Unsolicited,
)
from tango_aio.sansio._patterns import (
    ACK_PATTERN,
    ANY_PATTERN,
    Edge,
    ReplyKind,
    ReplyPattern,
    echo_pattern,
    reply_pattern,
)

CONTEXT = Context(axes=3)


def pattern(line: str) -> ReplyPattern:
    return reply_pattern(parse(line, CONTEXT), CONTEXT)


@pytest.mark.parametrize(("line", "kind", "low", "high"), [
    ("?vel x", ReplyKind.NUMBERS, 1, 1),
    ("?vel", ReplyKind.NUMBERS, 1, 4),
    ("?pos", ReplyKind.NUMBERS, 1, 4),
    ("?lim x", ReplyKind.NUMBERS, 2, 2),  # extmode 1: one line of a group of 2
    ("?err", ReplyKind.NUMBERS, 1, 1),
    ("err", ReplyKind.NUMBERS, 1, 1),
    ("?autostatus", ReplyKind.NUMBERS, 1, 1),
    ("?det", ReplyKind.NUMBERS, 1, 1),
    ("?statusaxis", ReplyKind.STATUS, 1, 1),
    ("sa x", ReplyKind.STATUS, 1, 1),
    ("?help 5", ReplyKind.HELP, 1, 1),
    ("?encerr", ReplyKind.WORDS, 1, 4),
    ("?ctrstatus 0", ReplyKind.WORDS, 2, 8),
    ("?swtyp", ReplyKind.NUMBERS, 1, 12),  # digits of one axis may run together
    ("?version", ReplyKind.ANY, 1, 1),  # '1.71' alone is a version too
    ("service", ReplyKind.ANY, 1, 1),
    ("save", ReplyKind.ACK, 1, 1),
])
def test_patterns_come_from_the_catalog(line: str, kind: ReplyKind, low: int,
                                        high: int) -> None:
    ctx = Context(axes=3, extmode=1)
    got = reply_pattern(parse(line, ctx), ctx)
    assert (got.kind, got.low, got.high) == (kind, low, high)


@pytest.mark.parametrize(("line", "good", "bad"), [
    ("?vel x", ["11.500", " -1", "2.5e3", "0"], ["", "@@@-/", "1.0 2.0", "1.0.0", "x",
                                                  "\x00ÿ95.500", "ERR 5"]),
    ("?pos", ["1.0000 2.0000 3.0000", "1 2,", "5"], ["1 2 3 4 5", "1 a", "@@@-.-"]),
    ("?statusaxis", ["@@@-.-", "@M@-.-", "M", "@---.-"], ["@@@-/", "1.5", "@ @", ""]),
    ("?help 5", ["ERROR 5,number outside range"], ["5", "OK..."]),
    ("?encerr", ["0 0 e", "0"], ["", "0 0 0 0 0"]),
    ("save", ["OK...", "OK", "ERR 5", "ERR", "ERR -1"], ["0", "OKAY!", "ERR x"]),
])
def test_accepts(line: str, good: list[str], bad: list[str]) -> None:
    got = pattern(line)
    assert [text for text in good if not got.accepts(text)] == []
    assert [text for text in bad if got.accepts(text)] == []


def test_echo_without_its_bang_is_the_echo_of_the_line() -> None:
    # Switch echo_text=nobang (#32): "!moa x 1" echoed as "moa x 1" (L2117).
    echo = echo_pattern(parse("!moa x 1"))
    assert echo.accepts("moa x 1") and echo.accepts("!moa x 1")
    assert not echo.accepts("moa x 2") and not echo.accepts("mor x 1")
    assert echo.overlaps(echo_pattern(parse("moa x 1")))
    assert not echo.overlaps(echo_pattern(parse("!moa x 2")))


def test_echo_pattern_is_case_and_space_insensitive() -> None:
    echo = echo_pattern(parse("!moa x 1"))
    assert echo.accepts("!MOA  x 1") and echo.accepts(" !moa x 1 ")
    assert not echo.accepts("!moa x 2")
    assert ANY_PATTERN.accepts("anything at all")


@pytest.mark.parametrize(("first", "second", "overlap"), [
    ("?vel x", "?accel y", True),  # one number each
    ("?vel x", "?vel", True),  # one to four numbers
    ("?vel x", "?lim x", False),  # one number, two numbers (extmode 1)
    ("?vel x", "?statusaxis", False),
    ("?statusaxis", "?help 3", False),
    ("?vel x", "?encerr x", True),  # a word may be a number
    ("?lim x", "?encerr x", False),  # two numbers, one word
    ("?statusaxis", "?encerr x", True),
    ("?vel x", "?version", True),  # free text overlaps everything
    ("?help 3", "save", False),
])
def test_overlaps_is_symmetric(first: str, second: str, overlap: bool) -> None:
    ctx = Context(axes=3, extmode=1)
    a, b = (reply_pattern(parse(line, ctx), ctx) for line in (first, second))
    assert a.overlaps(b) is overlap and b.overlaps(a) is overlap
    assert a.overlaps(a)


def test_echoes_overlap_only_when_equal() -> None:
    one, other = echo_pattern(parse("!vel x 5")), echo_pattern(parse("!vel y 5"))
    assert not one.overlaps(other) and one.overlaps(echo_pattern(parse("!VEL x 5")))
    assert not one.overlaps(ACK_PATTERN) and not one.overlaps(pattern("?vel x"))


def _single_line_reads() -> list[str]:
    lines = []
    for name, entry in sorted(INSTRUCTIONS.items()):
        if not entry.read:
            continue
        for text in (f"?{name}", name, f"?{name} x"):
            try:
                lines.append(parse(text, CONTEXT).line)
                break
            except ValueError:
                continue
    return lines


READS = _single_line_reads()
#: Reads answered by exactly one line.
ONE_LINE = [line for line in READS
            if reply_rule(parse(line, CONTEXT), CONTEXT) == LineRule(count=1)]


@settings(max_examples=300)
@given(a=st.sampled_from(READS), b=st.sampled_from(READS), seed=st.integers(0, 2**16))
def test_lines_that_fit_both_only_where_overlapping(a: str, b: str, seed: int) -> None:
    """``overlaps`` is conservative: whenever a line fits both patterns, they overlap."""
    first, second = pattern(a), pattern(b)
    rng = random.Random(seed)
    for source in (first, second):
        line = fitting_line(source, rng)
        if first.accepts(line) and second.accepts(line):
            assert first.overlaps(second), (a, b, line)


# --------------------------------------------------------------------------------------
# The core's check


def _core(*requests: tuple[str, str]) -> ProtocolCore:
    core = ProtocolCore(context=CONTEXT)
    for line, tag in requests:
        core.send(parse(line, CONTEXT), tag)
    return core


def test_a_line_that_does_not_fit_is_a_mismatch_then_lines_are_dropped() -> None:
    core = _core(("?vel x", "v"), ("?statusaxis", "s"))
    events = core.events(b"@@@-.-\r11.500\r@@@-.\r")
    assert events[0] == Mismatched("v", "@@@-.-", pattern("?vel x"))
    assert events[1] == Dropped("11.500")
    # A completion report still gets through (unsolicited).
    assert isinstance(events[2], Completed) and events[2].tag is None
    assert core.pending_tags == ["v", "s"]
    marker = core.resync("m")
    code = marker.split()[-1].decode()
    assert core.events(f"ERROR {code},x\r0.5\r".encode()) == [
        RequestLost("v"), RequestLost("s"), Replied("m", (f"ERROR {code},x",)),
        Unsolicited("0.5")]
    assert not core.resyncing


def test_lines_that_fit_reach_their_requests() -> None:
    core = _core(("?vel x", "v"), ("?statusaxis", "s"), ("?help 3", "h"))
    assert core.events(b"11.500\r@@@-.-\rERROR 3,x\r") == [
        Replied("v", ("11.500",)), Replied("s", ("@@@-.-",)), Replied("h", ("ERROR 3,x",))]


def test_checking_can_be_turned_off() -> None:
    core = ProtocolCore(context=CONTEXT, check_replies=False)
    core.send(parse("?vel x"), "v")
    assert core.events(b"R_v\r") == [Replied("v", ("R_v",))]


def test_a_follow_up_mismatch_has_no_tag() -> None:
    """``detext`` ends where its internal ``?err`` follow-up answers; a line there that is
    no number is a mismatch of the core's own query."""
    core = _core(("detext", "d"))
    assert core.events(b"02830\r= 3 Axes\r@@@-.-\r") == [
        Replied("d", ("02830", "= 3 Axes")),
        Mismatched(None, "@@@-.-", ReplyPattern(ReplyKind.NUMBERS))]


def test_tail_names_the_last_line_owed() -> None:
    core = ProtocolCore(autostatus=2, context=CONTEXT)
    assert core.tail is None
    core.send(parse("?vel x"), "v")
    # Whether reads are acknowledged in mode 2 is not known yet: the line it is sure to
    # get is its number, and an acknowledgement may come before and after it.
    number, ack = Edge((pattern("?vel x"),)), Edge((ACK_PATTERN,))
    assert core.tail is not None and core.tail[0] == "v"
    assert core.tail[1].overlaps(number) and core.tail[1].overlaps(ack)
    core.ack_reads = AckReads.NO
    core.send(parse("?vel x"), "w")
    assert core.tail == ("w", Edge((pattern("?vel x"),)))  # its front and back: one line
    core.send(parse("!vel x 5"), "s")
    assert core.tail == ("s", Edge((ACK_PATTERN,)))
    assert not core.tail[1].overlaps(number)
    assert core.events(b"1.5\r1.5\r") == [Replied("v", ("1.5",)), Replied("w", ("1.5",))]
    # "v" may still get its optional acknowledgement: it is no longer sure of a line.
    assert core.tail is not None and core.tail[0] == "s"
    core.events(b"OK...\rOK...\r")
    assert core.tail is None


@settings(max_examples=200)
@given(reads=st.lists(st.sampled_from(ONE_LINE), min_size=1, max_size=8),
       cuts=st.lists(st.integers(0, 400), max_size=20), seed=st.integers(0, 2**16))
def test_fitting_replies_in_any_split_reach_their_requests(reads: list[str],
                                                           cuts: list[int],
                                                           seed: int) -> None:
    rng = random.Random(seed)
    replies = [fitting_line(pattern(line), rng) for line in reads]
    data = "".join(reply + "\r" for reply in replies).encode("latin-1")
    results = []
    for points in ([], sorted(cuts), list(range(len(data)))):
        core = _core(*((line, str(i)) for i, line in enumerate(reads)))
        events = []
        for start, end in zip([0, *points], [*points, len(data)], strict=False):
            events += core.events(data[start:end])
        results.append(events)
    assert results[0] == results[1] == results[2]
    assert results[0] == [Replied(str(i), (reply,)) for i, reply in enumerate(replies)]
