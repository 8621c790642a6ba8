"""Timing as evidence: a line that starts before its request could have been answered is
not its reply (:func:`tango_aio.sansio._linktiming.earliest_reply`, the core's arrival stamps)."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.sansio._core import LineAssembler, Mismatched, ProtocolCore, Replied
from tango_aio.sansio._linktiming import ARRIVAL_MARGIN, byte_time, earliest_reply

BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)  # !baud's rates (L1627)
times = st.floats(min_value=0.0, max_value=1e6, allow_nan=False)
gaps = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
rates = st.one_of(st.just(0.0), st.sampled_from(BAUDS).map(byte_time))


# -- the rule -------------------------------------------------------------------------


@given(sent_at=times, late=gaps, queued=gaps, size=st.integers(1, 300), byte_seconds=rates,
       after=gaps, early_stamp=st.floats(0.0, ARRIVAL_MARGIN))
def test_a_true_reply_is_never_rejected(sent_at: float, late: float, queued: float,
                                        size: int, byte_seconds: float, after: float,
                                        early_stamp: float) -> None:
    """Whenever the bytes really leave (at or after the stamp given, behind what was
    written before), a reply whose first byte comes after the line passed and one more
    byte time, stamped up to the margin early (never before the write), is accepted."""
    wire_free = sent_at + queued
    earliest, passed = earliest_reply(sent_at, wire_free, size, byte_seconds)
    really_sent = sent_at + late
    really_passed = max(really_sent, wire_free) + size * byte_seconds
    first_byte = really_passed + byte_seconds + after
    stamp = max(first_byte - early_stamp, really_sent)  # read after the write, always
    assert stamp >= earliest
    assert passed <= really_passed


@given(sent_at=times, wire_free=times, size=st.integers(1, 300), byte_seconds=rates,
       before=st.floats(min_value=1e-6, max_value=10.0))
def test_a_line_read_before_its_request_was_written_is_rejected(
        sent_at: float, wire_free: float, size: int, byte_seconds: float,
        before: float) -> None:
    earliest, passed = earliest_reply(sent_at, wire_free, size, byte_seconds)
    started = sent_at - before
    if started < sent_at:  # (not lost to rounding)
        assert started < earliest
    assert earliest >= sent_at
    assert passed >= max(sent_at, wire_free)


@given(sent_at=times, size=st.integers(1, 300), baud=st.sampled_from(BAUDS))
def test_the_wire_time_counts_beyond_the_margin(sent_at: float, size: int,
                                                baud: int) -> None:
    """On a paced wire, a line that starts while its request is still passing (more than
    the margin before it could be answered) is rejected."""
    bt = byte_time(baud)
    earliest, passed = earliest_reply(sent_at, 0.0, size, bt)
    assert math.isclose(passed, sent_at + size * bt)
    assert math.isclose(earliest, max(sent_at, passed + bt - ARRIVAL_MARGIN))


def test_an_unknown_rate_leaves_only_the_write() -> None:
    assert earliest_reply(10.0, 12.0, 50, 0.0) == (10.0, 12.0)
    # Behind 20 bytes still passing at 1 ms each: the line's own 7 bytes follow them.
    earliest, passed = earliest_reply(10.0, 10.020, 7, 0.001, margin=0.002)
    assert math.isclose(passed, 10.027)
    assert math.isclose(earliest, 10.026)


# -- the assembler's stamps -------------------------------------------------------------


@st.composite
def _chunked(draw: st.DrawFn) -> tuple[list[bytes], list[tuple[bytes, float]]]:
    lines = draw(st.lists(st.binary(max_size=12).map(lambda b: b.replace(b"\r", b"")),
                          min_size=1, max_size=8))
    stream = b"".join(line + b"\r" for line in lines)
    cuts = sorted(draw(st.sets(st.integers(1, max(1, len(stream) - 1)), max_size=10)))
    pieces = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    return lines, [(piece, 100.0 + index) for index, piece in enumerate(pieces) if piece]


@given(_chunked())
def test_each_line_is_stamped_with_the_chunk_of_its_first_byte_that_counts(
        case: tuple[list[bytes], list[tuple[bytes, float]]]) -> None:
    lines, chunks = case
    # Where each byte came in: the time of its chunk.
    at = [time for piece, time in chunks for _ in piece]
    number = [index for index, (piece, _) in enumerate(chunks, 1) for _ in piece]
    assembler = LineAssembler()
    got: list[tuple[str, float, float]] = []
    for piece, time in chunks:
        assembler.feed(piece, time)
        while (line := assembler.next_line()) is not None:
            got.append((line, assembler.started_feed, assembler.started))
    start = 0
    for raw, (line, feed, started) in zip(lines, got, strict=True):
        assert line == raw.replace(b"\n", b"").decode("latin-1")
        text = raw.decode("latin-1")
        lead = len(text) - len(text.lstrip())
        first = start + (lead if lead < len(raw) else 0)
        assert (feed, started) == (number[first], at[first])
        start += len(raw) + 1
    assembler.feed(b"x\r", 1000.0)
    assert assembler.next_line() == "x" and assembler.started == 1000.0
    assert len(assembler._stamps) == 1  # the chunks consumed are forgotten


def test_bytes_fed_without_a_time_are_never_stamped() -> None:
    assembler = LineAssembler()
    assembler.feed(b"1.0\r", 5.0)
    assert assembler.next_line() == "1.0" and assembler.started == 5.0
    assembler.feed(b"2.0\r")
    assert assembler.next_line() == "2.0" and assembler.started == math.inf


# -- the core -------------------------------------------------------------------------


def _core_with_read(sent_at: float, wire_seconds: float = 0.0,
                    line: str = "?pos x") -> ProtocolCore:
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.wire_seconds = wire_seconds
    core.write_time = sent_at
    core.send(parse(line), "read")
    return core


def test_noise_read_before_the_write_glued_to_a_reply_fails_the_read() -> None:
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.receive_data(b"1", 9.5)  # stray byte, no CR, before the read is written
    core.write_time = 10.0
    core.send(parse("?pos x"), "read")
    events = core.events()
    core.receive_data(b"91.125\r", 10.01)
    events = core.events()
    assert len(events) == 1 and isinstance(events[0], Mismatched)
    assert events[0].tag == "read" and events[0].line == "191.125"
    assert "started before the request could have been answered" in events[0].reason


def test_noise_read_at_the_same_clock_reading_as_the_write_is_caught_by_order() -> None:
    """uvloop's clock counts whole milliseconds: noise and the write may read the same
    time. Which came first is known by the order they were handled in."""
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.receive_data(b"1", 10.0)
    core.send(parse("?pos x"), "read")
    core.receive_data(b"91.125\r", 10.0)
    event, = core.events()
    assert isinstance(event, Mismatched) and event.tag == "read"


def test_the_same_reply_after_the_write_is_taken() -> None:
    core = _core_with_read(10.0)
    core.receive_data(b"91.125\r", 10.0)  # read in the same instant: not provably early
    assert core.events() == [Replied("read", ("91.125",))]


def test_blanks_and_lf_in_front_of_a_reply_do_not_count() -> None:
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.receive_data(b" \n", 9.5)
    core.write_time = 10.0
    core.send(parse("?pos x"), "read")
    core.receive_data(b"91.125\r", 10.01)
    assert core.events() == [Replied("read", (" 91.125",))]


def test_untimed_bytes_are_not_judged() -> None:
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.receive_data(b"1")
    core.write_time = 10.0
    core.send(parse("?pos x"), "read")
    core.receive_data(b"91.125\r")
    assert core.events() == [Replied("read", ("191.125",))]


def test_a_paced_wire_rejects_a_line_that_starts_while_the_request_passes() -> None:
    # 1 ms per byte: '?pos x\r' passes until 10.007, its reply's first byte is in at
    # 10.008 at the earliest, 10.006 with the margin.
    core = _core_with_read(10.0, wire_seconds=0.001)
    core.receive_data(b"1", 10.004)
    core.receive_data(b"91.125\r", 10.020)
    event, = core.events()
    assert isinstance(event, Mismatched) and event.tag == "read"
    core = _core_with_read(10.0, wire_seconds=0.001)
    core.receive_data(b"91.125\r", 10.0065)
    assert core.events() == [Replied("read", ("91.125",))]


def test_pipelined_lines_queue_on_the_wire() -> None:
    """The second read's bytes pass behind the first's: its earliest reply is later."""
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.wire_seconds = 0.001
    core.write_time = 10.0
    core.send(parse("?pos x"), "first")
    core.send(parse("?vel y"), "second")
    core.receive_data(b"1.0000\r", 10.0065)  # the first's, in time
    core.receive_data(b"2", 10.010)  # before 10.014 - 0.002 + 0.001: not the second's
    core.receive_data(b"5.5\r", 10.020)
    first, second = core.events()
    assert first == Replied("first", ("1.0000",))
    assert isinstance(second, Mismatched) and second.tag == "second"


def test_a_marker_reply_behind_stale_bytes_still_ends_the_resync() -> None:
    """The marker's reply is searched in its line (stale bytes may lead it): no timing."""
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.receive_data(b"stale", 9.0)
    core.write_time = 10.0
    data = core.resync("marker")
    code = data.decode().split()[-1]
    core.receive_data(f"ERROR {code},marker\r".encode(), 10.01)
    event, = core.events()
    assert isinstance(event, Replied) and event.tag == "marker"
    assert not core.resyncing


@given(noise=st.binary(min_size=1, max_size=20).filter(
    lambda b: b"\r" not in b and bool(b.decode("latin-1").strip())),
    reply=st.sampled_from([b"91.125", b"0.0000", b"-12.5", b"1", b"3.0000 4.0000"]))
def test_noise_before_the_write_never_becomes_a_reply(noise: bytes, reply: bytes) -> None:
    core = ProtocolCore(autostatus=1, marker_seed=0)
    core.receive_data(noise, 1.0)
    core.write_time = 2.0
    core.send(parse("?pos x"), "read")
    core.receive_data(reply + b"\r", 3.0)
    assert not any(isinstance(event, Replied) and event.tag == "read"
                   for event in core.events())
