"""The wire's shortcuts for busy links give exactly what the plain byte-by-byte model gives.

* Input bytes that only go into the buffer are taken in runs (``Wire._plain_run``); the
  reference is the same wire with runs switched off, so every byte goes through
  ``Wire._receive`` one by one.
* A real-time driver polls at ``Wire.next_wakeup()`` instead of every
  ``Wire.next_deadline()`` (every input byte); the output, its timing, the handler calls
  and the counters must not change.

Both are checked on random traffic: lines, CR/LF, Ctrl+C, over-long lines, overflowing
input while the interpreter is busy, stalls and time-driven handler output.
"""

from __future__ import annotations

import random
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.sim.wire import Emit, Wire, WireConfig

CONFIGS = [
    WireConfig(),
    WireConfig(baud=9600, processing_time_per_line=0.0005),
    WireConfig(processing_time_per_line=0.002, stall_every_lines=7, stall_duration=0.01),
    WireConfig(input_buffer_size=16),
    WireConfig(reply_latency=0.002),
    WireConfig(baud=None),
]


class RandomHandler:
    """Answers some lines, sometimes later (a deadline), and records every call."""

    def __init__(self, emit: Emit, seed: int, log: list[Any]) -> None:
        self.emit = emit
        self.log = log
        self.rng = random.Random(seed)
        self.deadline: float | None = None

    def handle_line(self, line: bytes, now: float) -> None:
        self.log.append(("line", line, now))
        if self.rng.random() < 0.7:
            self.emit(b"R" + line[:5] + b"\r")
        if self.rng.random() < 0.1:
            self.deadline = now + self.rng.uniform(0.0, 0.01)

    def line_too_long(self, head: bytes, now: float) -> None:
        self.log.append(("too long", head, now))
        self.emit(b"E3\r")

    def ctrl_c(self, now: float) -> None:
        self.log.append(("ctrl-c", now))

    def processing_time(self, line: bytes) -> float:
        return 0.0005 if line.startswith(b"s") else 0.0

    def poll(self, now: float) -> None:
        if self.deadline is not None and now >= self.deadline:
            self.log.append(("report", self.deadline))
            self.emit(b"@@@.\r")
            self.deadline = None

    def next_deadline(self) -> float | None:
        return self.deadline


def script(seed: int) -> list[tuple[float, str, Any]]:
    """Random host activity: (time, "feed" | "stall" | "poll", argument)."""
    rng = random.Random(seed)
    t = 0.0
    steps: list[tuple[float, str, Any]] = []
    for _ in range(80):
        t += rng.choice([0.0, 1e-5, 1e-4, 0.0003, 0.001, 0.003, 0.02])
        r = rng.random()
        if r < 0.45:
            plain = b"abcs0123 .-!?" * 5 + b"\r"
            special = b"abcs0123 .-!?" * 3 + b"\r\r\n\x03"
            alphabet = special if rng.random() < 0.2 else plain
            data = bytes(rng.choice(alphabet) for _ in range(rng.randint(1, 300)))
            steps.append((t, "feed", data))
        elif r < 0.5:
            steps.append((t, "stall", rng.uniform(0.0, 0.01)))
        else:
            steps.append((t, "poll", None))
    return steps


def counters(wire: Wire) -> tuple[Any, ...]:
    return (wire.buffered, wire.lost_bytes, wire.lines_processed, wire.ctrl_c_count,
            wire.busy, wire.rx_pending, wire.tx_pending)


def run_script(seed: int, config: WireConfig, *, runs: bool) -> list[Any]:
    log: list[Any] = []
    wire = Wire(lambda emit: RandomHandler(emit, seed, log), config)
    if not runs:
        wire._plain_run = lambda *args: 0  # type: ignore[method-assign]
    out: list[Any] = []
    for t, action, argument in script(seed):
        if action == "feed":
            wire.feed(argument, t)
        elif action == "stall":
            wire.stall(argument, t)
        else:
            out.append((t, wire.poll_chunks(t)))
        out.append((counters(wire), wire.next_deadline(), wire.next_wakeup()))
    out.append(wire.poll_chunks(1e6))
    out.append(counters(wire))
    return [log, out]


@settings(max_examples=40)
@given(seed=st.integers(0, 2**32 - 1), config=st.sampled_from(CONFIGS))
def test_runs_of_input_bytes_change_nothing(seed: int, config: WireConfig) -> None:
    assert run_script(seed, config, runs=True) == run_script(seed, config, runs=False)


def drive(seed: int, config: WireConfig, *, wakeups: bool) -> list[Any]:
    """Poll like WireRunner: at each wake-up time (or deadline) and whenever input comes."""
    log: list[Any] = []
    wire = Wire(lambda emit: RandomHandler(emit, seed, log), config)
    steps = [step for step in script(seed) if step[1] != "poll"]
    out: list[Any] = []
    now, index, polls = 0.0, 0, 0
    while True:
        due = wire.next_wakeup() if wakeups else wire.next_deadline()
        arrival = steps[index][0] if index < len(steps) else None
        candidates = [t for t in (due, arrival) if t is not None]
        if not candidates:
            break
        now = max(now, min(candidates))
        if arrival is not None and arrival <= now:
            out.append((now, wire.poll_chunks(now)))
            _, action, argument = steps[index]
            index += 1
            if action == "feed":
                wire.feed(argument, now)
            else:
                wire.stall(argument, now)
        out.append((now, wire.poll_chunks(now)))
        polls += 1
        assert polls < 100_000, "the driver spins"
    return [log, [item for item in out if item[1]], counters(wire)]


@settings(max_examples=30)
@given(seed=st.integers(0, 2**32 - 1), config=st.sampled_from(CONFIGS))
def test_polling_at_wakeups_gives_what_polling_at_deadlines_gives(
        seed: int, config: WireConfig) -> None:
    log, out, final = drive(seed, config, wakeups=True)
    log_ref, out_ref, final_ref = drive(seed, config, wakeups=False)
    assert log == log_ref  # the same handler calls at the same times
    assert final == final_ref
    # The same output chunks; a chunk may be seen up to the wire's time tolerance (1 ns)
    # apart, because polling at every input byte sometimes sees it from a time within
    # that tolerance before its exact due time.
    assert [chunks for _, chunks in out] == [chunks for _, chunks in out_ref]
    assert all(abs(t - t_ref) <= 2e-9 for (t, _), (t_ref, _) in zip(out, out_ref, strict=True))


@pytest.mark.parametrize("busy", [False, True])
def test_wakeup_skips_bytes_that_only_fill_the_buffer(busy: bool) -> None:
    log: list[Any] = []
    wire = Wire(lambda emit: RandomHandler(emit, 1, log), WireConfig())
    bt = wire.config.byte_time
    if busy:
        wire.stall(1.0, 0.0)
    wire.feed(b"abcdef\rxyz", 0.0)
    assert wire.next_deadline() == pytest.approx(bt)  # every byte
    # The CR (7th byte) can run the handler; while the interpreter is busy only the last
    # byte in flight (for the counters) or the end of the stall matter.
    assert wire.next_wakeup() == pytest.approx(10 * bt if busy else 7 * bt)
