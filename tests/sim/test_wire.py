"""Tests of the sans-IO wire model: pacing, input buffer, Ctrl+C, faults."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.sim.wire import Emit, Wire, WireConfig, flip_one_bit

BT = 11 / 57600
"""One byte time at the default 57600 Bd, 8N2."""


class PingHandler:
    """Tiny controller logic for the tests.

    ``?ping`` -> ``pong``; ``echo TEXT`` -> ``TEXT``; ``wait S`` -> ``@`` after S seconds;
    an over-long line -> ``ERR3``. Everything it sees is recorded.
    """

    def __init__(self, emit: Emit, extra: float = 0.0) -> None:
        self.emit = emit
        self.extra = extra
        self.lines: list[tuple[bytes, float]] = []
        self.too_long: list[tuple[bytes, float]] = []
        self.ctrl_cs: list[float] = []
        self.deadline: float | None = None

    def handle_line(self, line: bytes, now: float) -> None:
        self.lines.append((line, now))
        if line.lower() == b"?ping":
            self.emit(b"pong\r")
        elif line.startswith(b"echo "):
            self.emit(line[5:] + b"\r")
        elif line.startswith(b"wait "):
            self.deadline = now + float(line[5:])

    def line_too_long(self, head: bytes, now: float) -> None:
        self.too_long.append((head, now))
        self.emit(b"ERR3\r")

    def ctrl_c(self, now: float) -> None:
        self.ctrl_cs.append(now)
        self.deadline = None

    def processing_time(self, line: bytes) -> float:
        return self.extra

    def poll(self, now: float) -> None:
        if self.deadline is not None and now >= self.deadline:
            self.deadline = None
            self.emit(b"@\r")

    def next_deadline(self) -> float | None:
        return self.deadline

    @property
    def texts(self) -> list[bytes]:
        return [line for line, _ in self.lines]


def make(extra: float = 0.0, **config: Any) -> tuple[Wire, PingHandler]:
    wire = Wire(lambda emit: PingHandler(emit, extra), WireConfig(**config))
    assert isinstance(wire.handler, PingHandler)
    return wire, wire.handler


def drain(wire: Wire, until: float, step: float) -> list[tuple[float, bytes]]:
    """Poll every ``step`` seconds up to ``until``; return (time, chunk) pairs."""
    out: list[tuple[float, bytes]] = []
    t = 0.0
    while t <= until + 1e-12:
        out += [(t, chunk) for chunk in wire.poll_chunks(t)]
        t += step
    return out


# ---------------------------------------------------------------------------- config


def test_default_byte_time_is_11_bits_at_57600() -> None:
    assert WireConfig().byte_time == pytest.approx(BT)
    assert WireConfig(baud=None).byte_time == 0.0
    assert WireConfig(baud=0).byte_time == 0.0
    assert WireConfig().max_line_length == 255


@pytest.mark.parametrize(
    "kwargs",
    [{"baud": -1}, {"input_buffer_size": 1}, {"fragment_probability": 2.0},
     {"reply_latency": -0.1}, {"stall_every_lines": -1}, {"bits_per_byte": 0}],
)
def test_config_rejects_nonsense(kwargs: dict[str, Any]) -> None:
    with pytest.raises(ValueError):
        WireConfig(**kwargs)


# ---------------------------------------------------------------------------- pacing


def test_request_bytes_arrive_one_byte_time_apart() -> None:
    wire, handler = make()
    wire.feed(b"?ping\r", 0.0)
    assert wire.next_deadline() == pytest.approx(BT)
    assert wire.poll(5.5 * BT) == b""
    assert handler.lines == []
    assert wire.rx_pending == 1
    wire.poll(6 * BT)
    assert handler.texts == [b"?ping"]
    assert handler.lines[0][1] == pytest.approx(6 * BT)


def test_reply_bytes_leave_one_byte_time_apart() -> None:
    wire, _ = make()
    wire.feed(b"?ping\r", 0.0)
    got = drain(wire, 11 * BT, BT)
    assert [chunk for _, chunk in got] == [b"p", b"o", b"n", b"g", b"\r"]
    assert [t for t, _ in got] == pytest.approx([k * BT for k in range(7, 12)])


def test_n_bytes_take_n_byte_times() -> None:
    wire, handler = make()
    wire.feed(b"?ping\r" * 50, 0.0)
    assert wire.poll(299.5 * BT).count(b"pong\r") == 49
    assert len(handler.lines) == 49
    rest = wire.poll(304.5 * BT)
    assert rest == b"pong"
    assert wire.poll(305 * BT) == b"\r"
    assert handler.lines[-1][1] == pytest.approx(300 * BT)
    assert wire.next_deadline() is None


def test_writes_queue_behind_each_other_on_the_line() -> None:
    wire, handler = make()
    wire.feed(b"echo a\r", 0.0)
    wire.feed(b"echo b\r", 1 * BT)  # written while the first is still on the line
    wire.poll(1.0)
    assert [t for _, t in handler.lines] == pytest.approx([7 * BT, 14 * BT])


def test_reply_latency_shifts_every_byte() -> None:
    wire, _ = make(reply_latency=0.002)
    wire.feed(b"?ping\r", 0.0)
    assert wire.poll(11 * BT) == b""
    assert wire.poll(0.002 + 7.5 * BT) == b"p"
    assert wire.poll(0.002 + 11 * BT) == b"ong\r"


def test_instant_mode_has_no_pacing() -> None:
    wire, handler = make(baud=None)
    wire.feed(b"?ping\r" * 100, 0.0)
    assert wire.poll(0.0) == b"pong\r" * 100
    assert len(handler.lines) == 100
    assert wire.next_deadline() is None


def test_time_never_runs_backwards() -> None:
    wire, _ = make(baud=None, processing_time_per_line=1.0)
    wire.feed(b"?ping\r", 5.0)
    assert wire.poll(1.0) == b""  # treated as 5.0
    assert wire.now == 5.0
    assert wire.poll(6.0) == b"pong\r"


# ---------------------------------------------------------------------------- processing


def test_reply_waits_for_processing_time() -> None:
    wire, handler = make(baud=None, processing_time_per_line=0.01)
    wire.feed(b"?ping\r", 0.0)
    assert handler.lines == [(b"?ping", 0.0)]  # executed when processing starts
    assert wire.poll(0.0099) == b""
    assert wire.next_deadline() == pytest.approx(0.01)
    assert wire.poll(0.01) == b"pong\r"


def test_handler_processing_time_adds_to_base() -> None:
    wire, _ = make(extra=0.02, baud=None, processing_time_per_line=0.01)
    wire.feed(b"?ping\r", 0.0)
    assert wire.poll(0.0299) == b""
    assert wire.poll(0.03) == b"pong\r"


def test_periodic_stall() -> None:
    wire, handler = make(baud=None, processing_time_per_line=0.001, stall_every_lines=3,
                         stall_duration=0.05)
    wire.feed(b"?ping\r" * 4, 0.0)
    wire.poll(1.0)
    assert [t for _, t in handler.lines] == pytest.approx([0.0, 0.001, 0.002, 0.053])


def test_lines_are_taken_one_at_a_time() -> None:
    wire, handler = make(baud=None, processing_time_per_line=0.1)
    wire.feed(b"echo 1\recho 2\recho 3\r", 0.0)
    assert handler.texts == [b"echo 1"]
    assert wire.buffered == 21
    assert wire.poll(0.1) == b"1\r"
    assert wire.buffered == 14  # bytes are freed when processing ends
    assert wire.poll(0.3) == b"2\r3\r"
    assert wire.buffered == 0


def test_case_is_passed_through_and_lf_is_skipped() -> None:
    wire, handler = make(baud=None)
    wire.feed(b"?PING\r\n?pi\nng\r\r", 0.0)
    assert handler.texts == [b"?PING", b"?ping", b""]
    assert wire.poll(0.0) == b"pong\rpong\r"


def test_lf_occupies_buffer_space() -> None:
    wire, _ = make(baud=None, processing_time_per_line=1.0)
    wire.feed(b"?ping\r" + b"\n" * 250 + b"x", 0.0)
    assert wire.buffered == 256
    assert wire.lost_bytes == 1


def test_handler_deadline_drives_poll() -> None:
    wire, _ = make(baud=None)
    wire.feed(b"wait 0.5\r", 0.0)
    assert wire.next_deadline() == 0.5
    assert wire.poll(0.49) == b""
    assert wire.poll(0.5) == b"@\r"
    assert wire.next_deadline() is None


def test_output_emitted_while_busy_is_held_in_order() -> None:
    wire, _ = make(baud=None, processing_time_per_line=0.2)
    wire.feed(b"wait 0.1\r?ping\r", 0.0)
    assert wire.poll(0.15) == b""  # '@' fired at 0.1 but the interpreter is busy
    assert wire.poll(0.2) == b"@\r"  # released when the first line ends
    assert wire.poll(0.4) == b"pong\r"


# ---------------------------------------------------------------------------- overflow


def test_overflow_loses_exactly_the_excess() -> None:
    wire, handler = make(baud=None, processing_time_per_line=1.0)
    wire.feed(b"abcdefghi\r" * 30, 0.0)
    assert wire.buffered == 256
    assert wire.lost_bytes == 44
    wire.poll(100.0)
    assert handler.texts == [b"abcdefghi"] * 25
    assert wire.buffered == 6  # "abcdef" of line 26 survived; its tail was lost
    wire.feed(b"\r", 100.0)
    assert handler.texts[-1] == b"abcdef"


def test_paced_blast_without_processing_time_loses_nothing() -> None:
    wire, handler = make()
    wire.feed(b"?ping\r" * 200, 0.0)
    wire.poll(1.0)
    assert wire.lost_bytes == 0
    assert handler.texts == [b"?ping"] * 200


def test_paced_blast_with_slow_processing_really_loses_data() -> None:
    wire, handler = make(processing_time_per_line=0.005)
    stream = b"?ping\r" * 200
    wire.feed(stream, 0.0)
    wire.poll(10.0)
    assert wire.rx_pending == 0
    assert wire.lost_bytes > 500
    handled = sum(len(line) + 1 for line in handler.texts)
    assert wire.lost_bytes + handled + wire.buffered == len(stream)
    assert any(line != b"?ping" for line in handler.texts)  # lines got spliced


def test_host_that_waits_for_replies_loses_nothing() -> None:
    wire, handler = make(processing_time_per_line=0.005)
    t = 0.0
    for _ in range(20):
        wire.feed(b"?ping\r", t)
        reply = b""
        while not reply.endswith(b"\r"):
            deadline = wire.next_deadline()
            assert deadline is not None
            t = deadline
            reply += wire.poll(t)
        assert reply == b"pong\r"
    assert wire.lost_bytes == 0
    assert len(handler.lines) == 20
    assert t == pytest.approx(20 * (11 * BT + 0.005))


# ---------------------------------------------------------------------------- Ctrl+C


def test_ctrl_c_clears_unprocessed_input() -> None:
    wire, handler = make(baud=None, processing_time_per_line=1.0)
    wire.feed(b"?ping\r?ping\r?pi", 0.0)
    assert wire.buffered == 15
    wire.feed(b"\x03", 0.5)
    assert handler.ctrl_cs == [0.5]
    assert wire.buffered == 6  # the line being processed stays until it ends
    assert wire.poll(10.0) == b"pong\r"  # ... and still replies
    assert handler.texts == [b"?ping"]
    wire.feed(b"ng\r", 10.0)
    assert handler.texts == [b"?ping", b"ng"]  # the partial line was gone


def test_ctrl_c_is_never_lost_with_a_full_buffer() -> None:
    wire, handler = make(baud=None, processing_time_per_line=1.0)
    wire.feed(b"abcdefghi\r" * 30 + b"\x03", 0.0)
    assert wire.lost_bytes == 44
    assert handler.ctrl_cs == [0.0]
    assert wire.ctrl_c_count == 1
    assert wire.buffered == 10
    wire.poll(10.0)
    assert handler.texts == [b"abcdefghi"]


def test_ctrl_c_acts_when_it_arrives_on_the_line() -> None:
    wire, handler = make()
    wire.feed(b"?pi\x03", 0.0)
    wire.poll(3.5 * BT)
    assert handler.ctrl_cs == []
    wire.poll(4 * BT)
    assert handler.ctrl_cs == [pytest.approx(4 * BT)]
    assert wire.buffered == 0


# ---------------------------------------------------------------------------- long lines


def test_line_of_255_characters_is_accepted() -> None:
    wire, handler = make(baud=None)
    wire.feed(b"echo " + b"x" * 250 + b"\r", 0.0)
    assert handler.too_long == []
    assert wire.poll(0.0) == b"x" * 250 + b"\r"


@pytest.mark.parametrize("baud", [None, 57600])
def test_overlong_line_is_flagged_once_and_skipped(baud: int | None) -> None:
    wire, handler = make(baud=baud)
    wire.feed(b"a" * 300 + b"\r?ping\r", 0.0)
    wire.poll(1.0)
    [(head, when)] = handler.too_long
    assert head == b"a" * 255
    assert when == pytest.approx(301 * (BT if baud else 0))  # flagged when its CR arrives
    assert handler.texts == [b"?ping"]
    assert wire.lost_bytes == 0  # skipped by the parser, not lost by the buffer


def test_overlong_line_reply_then_next_line() -> None:
    wire, _ = make(baud=None)
    wire.feed(b"a" * 300 + b"\r?ping\r", 0.0)
    assert wire.poll(0.0) == b"ERR3\rpong\r"


def test_ctrl_c_ends_skipping_of_an_overlong_line() -> None:
    wire, handler = make(baud=None)
    wire.feed(b"a" * 300 + b"\x03?ping\r", 0.0)
    assert handler.too_long == []
    assert handler.texts == [b"?ping"]


# ---------------------------------------------------------------------------- fragmentation


@settings(max_examples=50, deadline=None)
@given(
    payloads=st.lists(st.binary(min_size=1, max_size=40).map(
        lambda b: b.replace(b"\r", b"").replace(b"\x03", b"").replace(b"\n", b"")).filter(bool),
        min_size=1, max_size=8),
    seed=st.integers(0, 2**32 - 1),
    baud=st.sampled_from([None, 57600]),
    gap=st.sampled_from([0.0, 0.003]),
)
def test_fragmentation_keeps_content(payloads: list[bytes], seed: int, baud: int | None,
                                     gap: float) -> None:
    wire, _ = make(baud=baud, fragment_probability=1.0, fragment_gap=gap, seed=seed,
                   reply_latency=0.001)
    wire.feed(b"".join(b"echo " + p + b"\r" for p in payloads), 0.0)
    chunks = [chunk for _, chunk in drain(wire, 1.0, 0.0005)]
    assert b"".join(chunks) == b"".join(p + b"\r" for p in payloads)
    assert len(chunks) > len(payloads)  # probability 1: every reply was split


def test_fragmentation_is_reproducible_with_a_seed() -> None:
    def run() -> list[bytes]:
        wire, _ = make(baud=None, fragment_probability=1.0, seed=7)
        wire.feed(b"echo hello world\r", 0.0)
        return wire.poll_chunks(0.0)

    assert run() == run()
    assert len(run()) > 1


# ---------------------------------------------------------------------------- faults


def test_drop_replies() -> None:
    wire, _ = make(baud=None)
    wire.faults.drop_replies = 2
    wire.feed(b"echo 1\recho 2\recho 3\r", 0.0)
    assert wire.poll(0.0) == b"3\r"
    assert wire.dropped_replies == 2
    assert wire.faults.drop_replies == 0


def test_garble_reply_flips_one_bit_and_keeps_cr() -> None:
    wire, _ = make(baud=None, seed=1)
    wire.faults.garble_replies = 1
    wire.feed(b"?ping\r?ping\r", 0.0)
    out = wire.poll(0.0)
    first, second = out[:5], out[5:]
    assert second == b"pong\r"
    assert first != b"pong\r" and first.endswith(b"\r") and b"\r" not in first[:-1]
    diff = int.from_bytes(first, "big") ^ int.from_bytes(b"pong\r", "big")
    assert bin(diff).count("1") == 1


def test_custom_garbler() -> None:
    wire, _ = make(baud=None)
    wire.faults.garble_replies = 1
    wire.faults.garbler = lambda data, rng: b"#" * len(data)
    wire.feed(b"?ping\r", 0.0)
    assert wire.poll(0.0) == b"#####"


def test_garble_reply_to_one_line_only() -> None:
    """Faults.garble_reply_to: the first reply to the next line with that prefix, once;
    the replies before and after it pass untouched."""
    wire, _ = make(baud=None, extra=0.01)
    wire.faults.garble_reply_to = (b"?pi", lambda data, rng: b"7" + data)
    wire.feed(b"echo 1\r?ping\r?ping\r", 0.0)
    assert b"".join(chunk for _, chunk in drain(wire, 0.1, 0.005)) == b"1\r7pong\rpong\r"
    assert wire.faults.garble_reply_to is None


def test_garble_reply_to_may_drop_the_reply() -> None:
    wire, _ = make(baud=None)
    wire.faults.garble_reply_to = (b"?ping", lambda data, rng: b"")
    wire.feed(b"?ping\r?ping\r", 0.0)
    assert wire.poll(0.0) == b"pong\r"


def test_flip_one_bit_never_creates_cr() -> None:
    import random

    rng = random.Random(0)
    for _ in range(200):
        out = flip_one_bit(b"\x0c\x0f\x09", rng)
        assert b"\r" not in out and out != b"\x0c\x0f\x09"
    assert flip_one_bit(b"\r", rng) == b"\r"


def test_delay_reply_holds_back_later_output() -> None:
    wire, _ = make(baud=None)
    wire.faults.delay_replies = 1
    wire.faults.reply_delay = 0.1
    wire.feed(b"echo 1\r", 0.0)
    wire.feed(b"echo 2\r", 0.01)
    assert wire.poll(0.09) == b""
    assert wire.next_deadline() == pytest.approx(0.1)
    assert wire.poll(0.1) == b"1\r2\r"


def test_stall_when_idle() -> None:
    wire, handler = make(baud=None)
    wire.stall(0.5, now=0.0)
    assert wire.busy
    wire.feed(b"?ping\r", 0.1)
    assert handler.lines == []
    assert wire.poll(0.49) == b""
    assert wire.poll(0.5) == b"pong\r"
    assert handler.lines == [(b"?ping", 0.5)]


def test_stall_without_now_uses_the_clock() -> None:
    wire, _ = make(baud=None)
    wire.poll(0.0)
    wire.clock = lambda: 10.0
    wire.stall(0.5)
    wire.feed(b"?ping\r", 10.0)
    assert wire.poll(10.49) == b""
    assert wire.poll(10.5) == b"pong\r"


def test_stall_extends_current_processing() -> None:
    wire, _ = make(baud=None, processing_time_per_line=0.1)
    wire.feed(b"?ping\r", 0.0)
    wire.stall(0.2)
    assert wire.poll(0.29) == b""
    assert wire.poll(0.3) == b"pong\r"


def test_stall_makes_a_blasting_host_lose_data() -> None:
    wire, _ = make()
    wire.stall(0.1, now=0.0)
    wire.feed(b"?ping\r" * 100, 0.0)
    wire.poll(1.0)
    assert wire.lost_bytes == int(0.1 / BT) - 256  # arrived during the stall, minus 256


def test_disconnect_now() -> None:
    wire, _ = make()
    notified: list[int] = []
    wire.notify = lambda: notified.append(1)
    wire.feed(b"?ping\r", 0.0)
    wire.poll(8 * BT)
    wire.disconnect()
    assert wire.closed and notified
    assert wire.poll(1.0) == b""
    assert wire.next_deadline() is None
    wire.feed(b"?ping\r", 1.0)
    assert wire.rx_pending == 0


def test_disconnect_mid_reply() -> None:
    wire, _ = make(baud=None, reply_latency=0.01)
    wire.disconnect(mid_reply=True)
    assert not wire.closed
    wire.feed(b"echo 0123456789\r", 0.0)
    assert wire.poll(0.0) == b""
    assert wire.poll(0.01) == b"01234"
    assert wire.closed


def test_external_emit_is_sent_and_notifies() -> None:
    wire, _ = make(baud=None)
    notified: list[int] = []
    wire.notify = lambda: notified.append(1)
    wire.poll(1.0)
    wire.emit(b"hello\r")
    assert notified
    assert wire.poll(1.0) == b"hello\r"
