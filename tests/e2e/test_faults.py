"""Reliability: faults injected into the emulated link, through the real driver.

Each fault is run many times with different seeds; every outcome is counted in
:data:`COUNTS`, printed at the end of the module (``pytest -s``) and written as JSON to
``$TANGO_AIO_RELIABILITY_DIR/tango_aio_reliability_faults.json`` (default: the temp dir).
``RELIABILITY.md`` quotes those numbers.

What a "wrong caller" is: every read goes to a (parameter, axis) whose value is distinct
from every other one (:data:`DISTINCT`), and the truth is read from the emulator's own
store. A reply is *own* when it equals the caller's truth, *garbled own* when it differs
from it in one character (a one-bit fault), and *misdelivered* otherwise.

The second half fuzzes the protocol: bounded memory of the sans-IO core under megabytes of
noise, and random bytes into :meth:`TangoProtocol.data_received` with requests pending.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import random
import re
import tempfile
import time
import tracemalloc
from collections import Counter, defaultdict
from collections.abc import Awaitable, Callable, Iterator, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from fuzzkit import CONTEXT, REQUESTS, TOKENS, noise, plausible_answer
from helpers import (
    Emulated,
    FakeLink,
    FakeTransport,
    as_axes,
    assert_fails_fast,
    done_within_ticks,
    wait_lost,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.controller._connection import connect
from tango_aio.errors import (
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    ProtocolError,
    RequestAbortedError,
    TangoError,
)
from tango_aio.events import UnsolicitedLine
from tango_aio.link._protocol import Response, Submission, TangoProtocol
from tango_aio.sansio._core import Completed, ProtocolCore, Replied, is_completion_line
from tango_aio.sim.wire import flip_one_bit

pytestmark = [pytest.mark.timeout(300), pytest.mark.virtual_clock]

#: outcome counters per fault, reported at the end of the module
COUNTS: defaultdict[str, Counter[str]] = defaultdict(Counter)

#: Distinct values: no two (parameter, axis) replies can be mistaken for each other.
DISTINCT = {
    "vel": {"x": 95.5, "y": 96.25, "z": 97.125},
    "accel": {"x": 18.5, "y": 19.25, "z": 17.75},
}
def seeds_of(quick: int, full: int) -> list[Any]:
    """Seed counts of a fuzz test: the first ``quick`` seeds in the default run, all
    ``full`` (the counts of RELIABILITY.md) in the slow one."""
    return [pytest.param(quick, id="quick"),
            pytest.param(full, id="full", marks=pytest.mark.slow)]


#: Reads whose replies are all different from each other.
READS = ["?vel x", "?vel y", "?vel z", "?accel x", "?accel y", "?accel z", "?vel", "?accel"]
#: Travel between the limit switches of the shortened axes (mm).
TRAVEL = 4.0


def _report_path() -> Path:
    folder = Path(os.environ.get("TANGO_AIO_RELIABILITY_DIR", tempfile.gettempdir()))
    return folder / "tango_aio_reliability_faults.json"


@pytest.fixture(scope="module", autouse=True)
def _report_counts() -> Iterator[None]:
    """After the module: print the counts and write them as JSON."""
    yield
    data = {fault: dict(sorted(counter.items())) for fault, counter in sorted(COUNTS.items())}
    path = _report_path()
    path.write_text(json.dumps(data, indent=2) + "\n")
    print(f"\n--- fault injection counts (also in {path}) ---")
    for fault, counter in data.items():
        print(f"{fault}: " + ", ".join(f"{k}={v}" for k, v in counter.items()))


# --------------------------------------------------------------------------------------
# Helpers


async def open_emu(url: str, *, mode: int = 1, travel: float | None = None,
                   reply_timeout: float = 2.0) -> Emulated:
    """Connect to a fresh emulator and give every (parameter, axis) a distinct value.

    ``reply_timeout`` holds from then on: connecting (several exchanges) keeps the default,
    so that a short timeout meant for the faults does not fail the connect itself on a
    loaded machine."""
    tango = await connect(url, autostatus=mode)
    tango.reply_timeout = tango.protocol.reply_timeout = reply_timeout
    emu = Emulated(tango)
    try:
        if travel is not None:
            await emu.shorten(travel, mode)
        await tango.set("secvel", x=100, y=100, z=100)
        await tango.set("stopaccel", x=20, y=20, z=20)
        for name, values in DISTINCT.items():
            await tango.set(name, **as_axes(values))
    except BaseException:
        await tango.aclose()
        raise
    return emu


def truth(emu: Emulated, line: str) -> str:
    """What the emulator answers to ``line`` right now (its own formatter)."""
    model = emu.model
    return model.params.read(parse(line, model.context()), model.axes)



def tally(counts: Counter[str], emu: Emulated, lines: list[str],
          results: Sequence[object]) -> None:
    """Count the outcome of each pipelined request (own, garbled, misdelivered, error)."""
    for line, result in zip(lines, results, strict=True):
        counts[classify(emu, line, result) if isinstance(result, str)
               else outcome(result)] += 1

def classify(emu: Emulated, line: str, reply: str) -> str:
    """``own``, ``garbled own`` (one character differs) or ``MISDELIVERED``."""
    expected = truth(emu, line)
    if reply == expected:
        return "own"
    if len(reply) == len(expected) and sum(a != b for a, b in zip(reply, expected,
                                                                  strict=True)) == 1:
        return "garbled own"
    return "MISDELIVERED"


async def check_in_step(emu: Emulated) -> None:
    """The stream is in step: every read gets its own reply, nothing is left pending."""
    tango = emu.tango
    for line in READS:
        assert await tango.query(line) == truth(emu, line), line
    assert tango.protocol.core.pending_tags == []


def drop_at(index: int) -> Callable[[int, bytes], bytes]:
    """A fault for :func:`script_replies`: the ``index``-th reply is dropped."""
    return lambda i, data: b"" if i == index else data


def flip_at(index: int, rng: random.Random) -> Callable[[int, bytes], bytes]:
    """A fault for :func:`script_replies`: one bit of the ``index``-th reply flips."""
    return lambda i, data: flip_one_bit(data, rng) if i == index else data


def _record_end(ended: dict[asyncio.Task[Any], float], start: float,
                task: asyncio.Task[Any]) -> None:
    ended.setdefault(task, asyncio.get_running_loop().time() - start)


def script_replies(emu: Emulated, fault: Callable[[int, bytes], bytes], count: int) -> None:
    """Pass the next ``count`` replies through ``fault(index, data)`` (index from 1); an
    empty result drops the reply. Built on :attr:`Faults.garbler`."""
    index = 0

    def garbler(data: bytes, rng: random.Random) -> bytes:
        nonlocal index
        index += 1
        return fault(index, data)

    emu.wire.faults.garbler = garbler
    emu.wire.faults.garble_replies = count


def outcome(result: object) -> str:
    """The class of an exception (or ``value``)."""
    if isinstance(result, BaseException):
        return type(result).__name__
    return "value"


async def settle(emu: Emulated) -> None:
    """Let the emulator deliver whatever is in flight."""
    for _ in range(3):
        await asyncio.sleep(0.002)
    emu.wire.faults.garble_replies = 0
    emu.wire.faults.drop_replies = 0


# --------------------------------------------------------------------------------------
# Dropped replies


async def _one_request(emu: Emulated, rng: random.Random, timeout: float
                       ) -> tuple[str, Awaitable[Any]]:
    tango = emu.tango
    kind = rng.choice(["query", "get", "status", "position", "set"])
    axis = rng.choice("xyz")
    if kind == "query":
        return kind, tango.query(rng.choice(READS), timeout=timeout)
    if kind == "get":
        return kind, tango.get("accel", axis=axis, timeout=timeout)
    if kind == "status":
        return kind, tango.get("statusaxis", timeout=timeout)
    if kind == "position":
        return kind, tango.get("pos", timeout=timeout)
    value = DISTINCT["vel"][axis]  # the same value again: the truth does not move
    return kind, tango.command(f"!vel {axis} {value}", timeout=timeout)


@pytest.mark.parametrize("seeds", seeds_of(6, 40))
async def test_dropped_reply_times_out_then_the_next_request_gets_its_own(seeds: int) -> None:
    """A lost reply: ControllerTimeoutError, the stream is resynchronised, and every later
    request gets its own reply. Every autostatus mode, every kind of request."""
    counts = COUNTS["dropped reply (one request in flight)"]
    for seed in range(seeds):
        rng = random.Random(seed)
        mode = rng.choice([0, 1, 2, 3, 4])
        emu = await open_emu(f"sim://?baud=0&fragment=0.5&seed={seed}", mode=mode)
        try:
            for _ in range(5):
                kind, call = await _one_request(emu, rng, timeout=0.02)
                emu.wire.faults.drop_replies = 1
                async with asyncio.timeout(5.0):  # a hang guard; the request's own is 0.02 s
                    # The dropped reply is the request's own (timeout), or that of the
                    # separator written before it (#14 item 1): its own reply then
                    # arrives where the separator's was due, and the resync aborts it;
                    # a set aborted so is read back, and returns if the value holds.
                    try:
                        await call
                    except (ControllerTimeoutError, RequestAbortedError) as caught:
                        counts[type(caught).__name__] += 1
                    else:
                        assert kind == "set", kind
                        counts["set aborted, then proven by its read-back"] += 1
                counts[f"mode {mode}: {kind}"] += 1
                assert emu.wire.faults.drop_replies == 0  # the reply really was dropped
                await check_in_step(emu)
                counts["next requests got their own reply"] += 1
        finally:
            await emu.tango.aclose()
        counts["connections"] += 1


async def test_dropped_completion_report_falls_back_to_statusaxis(
        caplog: pytest.LogCaptureFixture) -> None:
    """A lost completion report: the move returns at its time limit from statusaxis."""
    counts = COUNTS["dropped completion report"]
    for seed in range(5):
        emu = await open_emu(f"sim://?baud=0&seed={seed}", travel=TRAVEL)
        try:
            tango = emu.tango
            target = round(random.Random(seed).uniform(-1.0, 1.0), 3)
            script_replies(emu, lambda _i, data: b"" if is_completion_line(
                data.decode("latin-1").strip()) else data, 1000)
            async with asyncio.timeout(5.0):
                letters = await tango.move_to(x=target, timeout=0.3)
            assert letters == {"x": "@", "y": "@", "z": "@"}
            await settle(emu)
            assert (await tango.position())["x"] == target
            assert tango.protocol.core.awaiting_completion == []
            await check_in_step(emu)
            counts["move returned its letters from statusaxis"] += 1
        finally:
            await emu.tango.aclose()
    assert any("no completion report" in r.getMessage() for r in caplog.records)


async def test_dropped_reply_among_pipelined_requests_is_never_misdelivered() -> None:
    """Four reads at once, one reply lost: reads whose replies look alike are never in
    flight together, so the lost one times out and the others get their own (or, when the
    next line does not fit, a ProtocolError and a resync); nobody gets another's reply."""
    counts = COUNTS["dropped reply (pipelined requests)"]
    for seed in range(10):
        rng = random.Random(seed)
        emu = await open_emu(f"sim://?baud=0&seed={seed}", reply_timeout=0.1)
        try:
            lines = rng.sample(READS, 4)
            lost = rng.randint(1, len(lines))
            script_replies(emu, drop_at(lost), len(lines))
            results = await asyncio.gather(*(emu.tango.query(line) for line in lines),
                                           return_exceptions=True)
            tally(counts, emu, lines, results)
            await settle(emu)
            await check_in_step(emu)
        finally:
            await emu.tango.aclose()
    assert counts["MISDELIVERED"] == 0


# --------------------------------------------------------------------------------------
# Garbled replies


@pytest.mark.parametrize("seeds", seeds_of(8, 60))
async def test_garbled_reply_stays_with_its_caller(seeds: int) -> None:
    """One-bit errors in a reply (data, ?err probe, acknowledgement or echo): the caller
    whose reply it was gets a garbled value, a ProtocolError (the line no longer fits its
    reply pattern), a ControllerError, or (a garbled acknowledgement or echo is not
    recognised) a timeout; nobody else is affected.
    """
    counts = COUNTS["garbled reply (one request in flight)"]
    for seed in range(seeds):
        rng = random.Random(seed)
        mode = rng.choice([0, 1, 2, 3, 4])
        emu = await open_emu(f"sim://?baud=0&fragment=0.5&seed={seed}", mode=mode)
        try:
            tango = emu.tango
            for _ in range(8):
                kind = rng.choice(["query", "get", "set"])
                emu.wire.faults.garbler = flip_one_bit
                emu.wire.faults.garble_replies = 1
                if kind == "query":
                    line = rng.choice(READS)
                    try:
                        text = await tango.query(line, timeout=0.05)
                    except (ProtocolError, RequestAbortedError) as exc:
                        # No number any more; or the separator's reply before it was
                        # garbled, and the resync aborted it.
                        result = type(exc).__name__
                    else:
                        result = classify(emu, line, text)
                        # own: the garbled reply was the separator's, still a status letter
                        assert result in ("garbled own", "own"), (line, text)
                elif kind == "get":
                    axis = rng.choice("xyz")
                    try:
                        value = await tango.get("vel", axis=axis, timeout=0.05)
                    except (ProtocolError, RequestAbortedError) as exc:
                        result = type(exc).__name__
                    else:
                        others = [v for (n, a), v in _flat().items() if (n, a) != ("vel", axis)]
                        assert value not in others, value
                        result = "own value" if value == DISTINCT["vel"][axis] else \
                            "garbled own value"
                else:
                    axis = rng.choice("xyz")
                    try:
                        await tango.command(f"!vel {axis} {DISTINCT['vel'][axis]}",
                                            timeout=0.05)
                        result = "set ok"
                    except (ProtocolError, ControllerError, ControllerTimeoutError,
                            RequestAbortedError) as exc:
                        result = type(exc).__name__
                counts[f"{kind}: {result}"] += 1
                await settle(emu)
                await check_in_step(emu)
            counts["runs"] += 8
        finally:
            await emu.tango.aclose()


def _flat() -> dict[tuple[str, str], float]:
    return {(name, axis): value for name, values in DISTINCT.items()
            for axis, value in values.items()}


@pytest.mark.parametrize("seeds", seeds_of(10, 60))
async def test_garbled_reply_among_pipelined_requests_stays_with_its_caller(seeds: int) -> None:
    """Several requests in flight, one reply garbled: no caller gets another's reply."""
    counts = COUNTS["garbled reply (pipelined requests, no move)"]
    for seed in range(seeds):
        rng = random.Random(seed)
        mode = rng.choice([0, 1, 2, 3, 4])
        emu = await open_emu(f"sim://?baud=0&fragment=0.5&seed={seed}", mode=mode,
                             reply_timeout=0.1)
        try:
            tango = emu.tango
            calls: list[tuple[str, Awaitable[Any]]] = []
            for _ in range(rng.randint(2, 6)):
                if rng.random() < 0.7:
                    line = rng.choice(READS)
                    calls.append((line, tango.query(line)))
                else:
                    axis = rng.choice("xyz")
                    value = DISTINCT["accel"][axis]
                    calls.append(("set", tango.set("accel", value, axis=axis)))
            which = rng.randint(1, len(calls))
            wire_rng = random.Random(seed)
            script_replies(emu, flip_at(which, wire_rng), 3 * len(calls))
            results = await asyncio.gather(*(call for _, call in calls),
                                           return_exceptions=True)
            for (line, _), result in zip(calls, results, strict=True):
                if isinstance(result, str):
                    verdict = classify(emu, line, result)
                    assert verdict != "MISDELIVERED", (line, result, mode)
                else:
                    verdict = "set ok" if result is None else outcome(result)
                    assert result is None or isinstance(result, TangoError), result
                counts[verdict] += 1
            # The short timeout was for the fault (a garbled acknowledgement or echo is
            # waited for until it expires; any typed error is an outcome above). Whether
            # the stream is back in step does not depend on how busy the machine is.
            tango.reply_timeout = tango.protocol.reply_timeout = 2.0
            await settle(emu)
            await check_in_step(emu)
            counts["runs"] += 1
        finally:
            await emu.tango.aclose()


async def test_garbled_zero_to_blank_stays_with_its_caller() -> None:
    """Regression (fixed in core.py): ``0`` garbled into `` `` was taken for the bare-CR
    completion report of autostatus 3, so the ``?err`` probe took the next request's
    reply and that request got the one after it. Now the blank is no number: the probe
    fails, the stream resyncs, and the reads (queued behind the look-alike probe) go out
    after the marker and get their own replies."""
    emu = await open_emu("sim://?baud=0", reply_timeout=0.2)
    try:
        tango = emu.tango
        blanked: list[bytes] = []

        def blank_first_zero(_index: int, data: bytes) -> bytes:
            if data == b"0\r" and not blanked:  # the ?err probe's reply
                blanked.append(data)
                return b" \r"
            return data

        script_replies(emu, blank_first_zero, 8)
        results = await asyncio.gather(tango.set("vel", 95.5, axis="x"),
                                       tango.query("?vel x"), tango.query("?vel y"),
                                       return_exceptions=True)
        assert blanked
        assert isinstance(results[0], ProtocolError)  # the blank went to the probe
        # The reads were written behind separators, in flight during the resync: aborted,
        # or (written after it) their own.
        for result, own in zip(results[1:], ("95.500", "96.250"), strict=True):
            assert result == own or isinstance(result, RequestAbortedError), result
        await check_in_step(emu)
    finally:
        await tango.aclose()


async def test_garbled_completion_report_is_not_a_reply() -> None:
    """A garbled report (``@@@-/``) while reads wait is no number: the read it reaches
    fails with ProtocolError, the stream resyncs, the move times out; nothing shifts."""
    counts = COUNTS["garbled completion report (reads pending)"]
    # A slow interpreter, so that reads are still unanswered when the report comes.
    emu = await open_emu("sim://?baud=0&processing=0.003", travel=TRAVEL,
                         reply_timeout=0.3)
    try:
        tango = emu.tango
        script_replies(emu, lambda _i, data: b"@@@-/\r" if data == b"@@@-.\r" else data,
                       10_000)
        move = asyncio.create_task(tango.move_to(x=0.2, timeout=0.5))
        reads: list[tuple[str, asyncio.Task[str]]] = []
        for index in range(300):
            line = READS[index % len(READS)]
            reads.append((line, asyncio.create_task(tango.query(line))))
            await asyncio.sleep(0.002)
            if move.done():
                break
        await asyncio.wait([move, *(task for _, task in reads)])
        # The move ends typed either way: confirmed by polling, or a timeout.
        assert move.exception() is None or isinstance(move.exception(), TangoError)
        for line, task in reads:
            result = task.exception() or task.result()
            counts[classify(emu, line, result) if isinstance(result, str)
                   else outcome(result)] += 1
        assert counts["MISDELIVERED"] == 0, counts
    finally:
        await tango.aclose()


# --------------------------------------------------------------------------------------
# Random stalls


@pytest.mark.parametrize("seeds", seeds_of(4, 12))
async def test_random_stalls_delay_requests_but_lose_nothing(seeds: int) -> None:
    """The interpreter stalls every few lines and at random moments: requests wait, each
    gets its own reply, nothing is lost."""
    counts = COUNTS["random stalls"]
    for seed in range(seeds):
        rng = random.Random(seed)
        url = (f"sim://?baud=0&fragment=0.3&seed={seed}&stall_every={rng.randint(3, 9)}"
               f"&stall={rng.uniform(0.001, 0.01):.4f}")
        emu = await open_emu(url, mode=rng.choice([1, 2, 4]), reply_timeout=2.0)
        stop = asyncio.Event()

        async def staller(rng: random.Random = rng, emu: Emulated = emu,
                          stop: asyncio.Event = stop) -> None:
            while not stop.is_set():
                await asyncio.sleep(rng.uniform(0.0, 0.02))
                if not emu.wire.busy:  # stall() extends a running stall: don't pile up
                    emu.wire.stall(rng.uniform(0.001, 0.03))
                    counts["random stalls injected"] += 1

        background = asyncio.create_task(staller())
        try:
            for _ in range(12):
                lines = [rng.choice(READS) for _ in range(rng.randint(1, 8))]
                start = time.monotonic()
                async with asyncio.timeout(10.0):
                    replies = await asyncio.gather(*(emu.tango.query(line)
                                                     for line in lines))
                counts["max burst latency (ms)"] = max(
                    counts["max burst latency (ms)"],
                    round(1000 * (time.monotonic() - start)))
                for line, reply in zip(lines, replies, strict=True):
                    verdict = classify(emu, line, reply)
                    assert verdict == "own", (line, reply)
                    counts[verdict] += 1
                axis = rng.choice("xyz")
                await emu.tango.set("vel", DISTINCT["vel"][axis], axis=axis)
                counts["sets ok"] += 1
        finally:
            stop.set()
            await background
            await emu.tango.aclose()
        assert emu.wire.lost_bytes == 0
        counts["connections"] += 1


async def test_stalls_at_57600_baud_never_overflow_the_input_buffer() -> None:
    """Real-time link, slow interpreter and stalls, 200 requests in flight at once: the
    credit limiter keeps the 256-byte buffer from overflowing; every reply is its own."""
    counts = COUNTS["stalls at 57600 Bd, 200 requests in flight"]
    emu = await open_emu("sim://?baud=57600&processing=0.0005&stall_every=25&stall=0.02"
                         "&fragment=0.5&seed=7", reply_timeout=10.0)
    try:
        rng = random.Random(7)
        lines = [rng.choice(READS) for _ in range(200)]
        calls = [emu.tango.query(line) for line in lines]
        emu.wire.stall(0.05)
        replies = await asyncio.gather(*calls)
        for line, reply in zip(lines, replies, strict=True):
            verdict = classify(emu, line, reply)
            assert verdict == "own"
            counts[verdict] += 1
        assert emu.wire.lost_bytes == 0
        counts["lost bytes"] += emu.wire.lost_bytes
    finally:
        await emu.tango.aclose()


# --------------------------------------------------------------------------------------
# Disconnect in the middle of a line


@pytest.mark.parametrize("seeds", seeds_of(8, 30))
async def test_disconnect_mid_line_fails_every_waiter_quickly(seeds: int) -> None:
    """The link is cut halfway through a reply, with reads pipelined and (sometimes) a
    move running: every read fails with ConnectionLostError as soon as the driver notices
    the loss (within a few loop turns, no timer), a move at its next poll at the latest,
    the half line is delivered to nobody, and later calls fail at once."""
    counts = COUNTS["disconnect mid-line"]
    for seed in range(seeds):
        rng = random.Random(seed)
        emu = await open_emu(f"sim://?baud=0&fragment=0.5&seed={seed}",
                             mode=rng.choice([0, 1, 2, 3, 4]))
        tango = emu.tango
        try:
            move = None
            if rng.random() < 0.5:
                move = asyncio.create_task(tango.move_to(x=30))  # seconds at 95 mm/s
                await asyncio.sleep(0.01)
            emu.wire.disconnect(mid_reply=True)
            loop = asyncio.get_running_loop()
            start = loop.time()
            reads = [asyncio.create_task(tango.query(rng.choice(READS)))
                     for _ in range(rng.randint(1, 5))]
            waiters = [*reads, *([move] if move else [])]
            ended: dict[asyncio.Task[Any], float] = {}
            for task in waiters:
                task.add_done_callback(partial(_record_end, ended, start))
            await wait_lost(tango)  # the driver noticed the loss
            await done_within_ticks(*reads)  # ... and failed every read with it
            done, pending = await asyncio.wait(waiters, timeout=1.0)
            assert not pending
            for task in done:
                error = task.exception()
                assert isinstance(error, ConnectionLostError), error
                assert error.__cause__ is not None
                counts["waiter got ConnectionLostError"] += 1
            # Reported, not asserted: a move polling statusaxis (autostatus 0 and 3)
            # notices at its next poll.
            latest_read = max(ended[task] for task in reads)
            counts["slowest read failure (ms)"] = max(counts["slowest read failure (ms)"],
                                                      round(1000 * latest_read))
            if move is not None:
                counts["slowest move failure (ms)"] = max(counts["slowest move failure (ms)"],
                                                          round(1000 * ended[move]))
            counts["move running"] += move is not None
            await assert_fails_fast(partial(tango.query, "?vel"))
            counts["later call failed at once"] += 1
        finally:
            await tango.aclose()
        counts["runs"] += 1


# --------------------------------------------------------------------------------------
# Noise between lines


def _junk(rng: random.Random, cr: bool) -> bytes:
    """A noise line (printable junk, NUL and 0xFF) that is no completion report."""
    while True:
        size = rng.randint(1, 24)
        data = bytes(rng.choice([0x00, 0xFF, *range(0x20, 0x7F)]) for _ in range(size))
        text = data.decode("latin-1")
        if not is_completion_line(text.strip()):
            return data + (b"\r" if cr else b"")


async def test_noise_lines_between_replies_are_unsolicited_events() -> None:
    """Junk lines while no request waits become UnsolicitedLine events; every reply after
    them still reaches its own caller."""
    counts = COUNTS["noise lines between replies"]
    for seed in range(20):
        rng = random.Random(seed)
        emu = await open_emu(f"sim://?baud=0&fragment=0.5&seed={seed}",
                             mode=rng.choice([0, 1, 2, 3, 4]))
        tango = emu.tango
        try:
            async with tango.events() as events:
                for _ in range(10):
                    junk = _junk(rng, cr=True)
                    emu.wire.emit(junk)
                    async with asyncio.timeout(2.0):
                        event = await anext(events)
                    assert isinstance(event, UnsolicitedLine)
                    assert event.line == junk[:-1].decode("latin-1")
                    counts["junk lines -> UnsolicitedLine"] += 1
                    lines = [rng.choice(READS) for _ in range(rng.randint(1, 4))]
                    replies = await asyncio.gather(*(tango.query(line) for line in lines))
                    for line, reply in zip(lines, replies, strict=True):
                        verdict = classify(emu, line, reply)
                        assert verdict == "own"
                        counts[verdict] += 1
        finally:
            await tango.aclose()


async def test_noise_bytes_without_cr_garble_only_the_next_reply() -> None:
    """Junk bytes without a CR (``\\x00\\xff``, line noise) join the next line: that
    caller gets its reply with the junk in front when that still fits its pattern
    (``5`` + ``95.500``), else a ProtocolError and the stream resyncs; the others get
    their own replies, or RequestAbortedError when they were in flight during the resync."""
    counts = COUNTS["noise bytes (no CR) before a reply"]
    for seed in range(20):
        rng = random.Random(seed)
        emu = await open_emu(f"sim://?baud=0&fragment=0.5&seed={seed}")
        tango = emu.tango
        try:
            for index in range(10):
                junk = b"\x00\xff" if index == 0 else _junk(rng, cr=False)
                emu.wire.emit(junk)
                lines = [rng.choice(READS) for _ in range(rng.randint(1, 4))]
                replies = await asyncio.gather(*(tango.query(line) for line in lines),
                                               return_exceptions=True)
                first = replies[0]
                if isinstance(first, ProtocolError | RequestAbortedError):
                    # RequestAbortedError: the junk joined the reply of the separator
                    # written before it.
                    counts[f"first caller: {type(first).__name__}"] += 1
                elif first == truth(emu, lines[0]):
                    # The junk joined the reply of the separator written before it, and
                    # still looked like status letters (e.g. 'DdCx@').
                    counts["first caller: own (junk absorbed by a separator)"] += 1
                else:
                    assert first == junk.decode("latin-1") + truth(emu, lines[0])
                    counts["first caller: junk + own reply"] += 1
                for line, reply in zip(lines[1:], replies[1:], strict=True):
                    if isinstance(reply, RequestAbortedError):
                        counts["other callers: RequestAbortedError"] += 1
                        continue
                    assert isinstance(reply, str) and classify(emu, line, reply) == "own"
                    counts["other callers: own"] += 1
                emu.wire.emit(junk)
                try:
                    await tango.get("vel", axis="x")
                except (ProtocolError, RequestAbortedError) as exc:
                    counts[f"typed get after junk: {type(exc).__name__}"] += 1
                else:  # e.g. '5' + '95.500': a garbled value, still its own reply
                    counts["typed get after junk: value"] += 1
                await check_in_step(emu)
        finally:
            await tango.aclose()


async def test_noise_line_while_reads_pending_is_not_a_reply() -> None:
    """A junk line while reads wait: the read it reaches rejects it (ProtocolError, then a
    resync), or takes it when the junk happens to fit (a number): never another's reply."""
    counts = COUNTS["noise line while reads pending"]
    for seed in range(10):
        rng = random.Random(seed)
        emu = await open_emu(f"sim://?baud=0&processing=0.002&seed={seed}",
                             reply_timeout=0.2)
        try:
            lines = rng.sample(READS, 3)
            calls = [asyncio.create_task(emu.tango.query(line)) for line in lines]
            await asyncio.sleep(0)
            # The interpreter is busy with the first read: the junk follows its reply,
            # ahead of the replies of the others.
            emu.wire.emit(_junk(rng, cr=True))
            results = await asyncio.gather(*calls, return_exceptions=True)
            tally(counts, emu, lines, results)
            await settle(emu)
            await check_in_step(emu)
        finally:
            await emu.tango.aclose()
    assert counts["MISDELIVERED"] == 0, counts



# --------------------------------------------------------------------------------------
# Fragmentation


@pytest.mark.parametrize("seeds", seeds_of(2, 30))
async def test_fragmented_replies_reach_their_callers(seeds: int) -> None:
    """Replies split into 2-4 pieces (``fragment=0.5`` and ``1.0``, pieces sometimes apart
    in time), with reads in flight, sets and moves whose completion reports are split too:
    every reply reaches its own caller, every move completes."""
    counts = COUNTS["fragmentation"]
    for seed in range(seeds):
        rng = random.Random(seed)
        fragment = 0.5 if seed % 2 else 1.0
        mode = rng.choice([0, 1, 2, 3, 4])
        emu = await open_emu(f"sim://?baud=0&fragment={fragment}&seed={seed}", mode=mode,
                             travel=TRAVEL)
        emu.wire.config.fragment_gap = rng.choice([0.0, 0.0005, 0.002])
        protocol = emu.tango.protocol
        deliver = protocol.data_received
        chunks = 0

        def counting(data: bytes, deliver: Callable[[bytes], None] = deliver) -> None:
            nonlocal chunks
            chunks += 1
            deliver(data)

        protocol.data_received = counting  # type: ignore[method-assign]
        lines_before = emu.wire.lines_processed
        try:
            tango = emu.tango
            for _ in range(8):
                lines = [rng.choice(READS) for _ in range(rng.randint(1, 6))]
                target = round(rng.uniform(-1.0, 1.0), 3)
                move = asyncio.ensure_future(tango.move_to(z=target))
                replies = await asyncio.gather(*(tango.query(line) for line in lines))
                for line, reply in zip(lines, replies, strict=True):
                    verdict = classify(emu, line, reply)
                    assert verdict == "own", (line, reply)
                    counts[verdict] += 1
                assert set((await move).values()) == {"@"}
                assert (await tango.position())["z"] == target
                counts["moves completed"] += 1
                axis = rng.choice("xyz")
                await tango.set("vel", DISTINCT["vel"][axis], axis=axis)
                counts["sets ok"] += 1
            await check_in_step(emu)
        finally:
            await emu.tango.aclose()
        counts[f"connections, fragment={fragment}"] += 1
        counts["chunks received"] += chunks
        counts["lines written"] += emu.wire.lines_processed - lines_before


# --------------------------------------------------------------------------------------
# Fuzz: bounded memory of the core, random bytes into the whole protocol

def _noise(rng: random.Random, size: int) -> bytes:
    """Random bytes (few CRs: over-long lines) or tokens and random bytes (many lines)."""
    return rng.randbytes(size) if rng.random() < 0.5 else noise(rng, size)


def _marker_reply(marker: bytes) -> bytes:
    """The controller's answer to the resync marker ``?help N``."""
    match = re.search(rb"\?help (\d+)\r", marker)
    assert match is not None
    return b"ERROR " + match.group(1) + b",marker\r"


@pytest.mark.slow
def test_core_memory_stays_bounded_under_megabytes_of_noise() -> None:
    """6 MiB of noise into the sans-IO core with requests pending: the memory allocated
    while feeding peaks under 1 MiB above where it started, whatever the amount fed (the
    assembler keeps at most one line of 1024 bytes; events are drained as they come). A
    warm-up fills the caches (regexes, parsed lines) first.

    A multi-line reply (``service``: up to its terminator) collects lines until it ends;
    the core has no cap of its own, the driver's reply timeout is the bound (its resync
    drops the request). So the core is resynchronised every 32 KiB here, which is what
    5 s of reply timeout at 57600 Bd can carry (26 KiB)."""
    counts = COUNTS["fuzz: core memory under noise"]
    rng = random.Random(0x5EED)
    core = ProtocolCore(autostatus=1, context=CONTEXT)
    tags = iter(range(10**9))

    def feed(size: int) -> int:
        fed = 0
        while fed < size:
            while len(core.pending_tags) < 8:
                core.send(parse(rng.choice(REQUESTS), CONTEXT), next(tags))
            if len(core.awaiting_completion) > 8:
                core.drop_completions()
            chunk = _noise(rng, rng.randint(1, 4096))
            if fed // 32768 != (fed + len(chunk)) // 32768 or rng.random() < 0.005:
                marker = core.resync(next(tags), ctrl_c=rng.random() < 0.5)
                chunk += _marker_reply(marker) if rng.random() < 0.9 else b""
            elif rng.random() < 0.3:
                chunk += plausible_answer(core, rng)
            fed += len(chunk)
            core.receive_data(chunk)
            while True:
                try:
                    event = core.next_event()
                except ProtocolError:
                    counts["ProtocolError (line too long)"] += 1
                    continue
                if event is None:
                    break
                counts[type(event).__name__] += 1
                if isinstance(event, Replied):
                    counts["most lines in one reply"] = max(
                        counts["most lines in one reply"], len(event.lines))
            assert core._assembler.buffered <= 1024
        return fed

    feed(256 * 1024)
    tracemalloc.start()
    try:
        baseline, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        fed = feed(6 * 2**20)
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    counts["bytes fed"] = fed
    counts["peak KiB above baseline"] = (peak - baseline) // 1024
    counts["retained KiB at the end"] = (current - baseline) // 1024
    assert peak - baseline < 2**20, peak - baseline
    assert current - baseline < 2**19, current - baseline


#: What the protocol may log at WARNING or above while fed noise.
_ALLOWED_LOG = re.compile(
    r"^(protocol error: |reply mismatch: |credit marker got a garbled reply |error -?\d+ after )")


class _Recorder(logging.Handler):
    """Checks each record as it comes and keeps counts only (so that a long soak holds
    no memory): ``bad`` lists the first few records that are not allowed."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.counts: Counter[str] = Counter()
        self.bad: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if not (record.name.startswith("tango_aio") and _ALLOWED_LOG.match(message)):
            if len(self.bad) < 5:
                self.bad.append(f"{record.name}: {message}")
            return
        self.counts["logged: " + message.split(":")[0]] += 1


@contextlib.contextmanager
def _recording() -> Iterator[_Recorder]:
    # The records do not propagate to pytest's log capture, which keeps every one of
    # them: in a long soak that alone would look like a leak.
    recorder = _Recorder()
    loggers = [logging.getLogger("tango_aio"), logging.getLogger("asyncio")]
    propagate = [logger.propagate for logger in loggers]
    for logger in loggers:
        logger.addHandler(recorder)
        logger.propagate = False
    try:
        yield recorder
    finally:
        for logger, flag in zip(loggers, propagate, strict=True):
            logger.removeHandler(recorder)
            logger.propagate = flag


def _valid_future(future: asyncio.Future[Any] | None, kind: type) -> str:
    """``pending``, ``resolved`` or the exception's class; anything else fails."""
    if future is None:
        return "none"
    assert not future.cancelled()
    if not future.done():
        return "pending"
    error = future.exception()
    if error is not None:
        assert isinstance(error, TangoError), repr(error)
        return type(error).__name__
    assert isinstance(future.result(), kind)
    return "resolved"


async def _fuzz_protocol(mode: int, script: list[tuple[str, Any]],
                         counts: Counter[str]) -> None:
    loop = asyncio.get_running_loop()
    loop_errors: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, context: loop_errors.append(context))
    # Not declared dead however many markers time out (tests/e2e/test_reply_timeouts.py covers it).
    protocol = TangoProtocol(autostatus=mode, context=CONTEXT, dead_after=1 << 30)
    link = FakeLink(protocol, FakeTransport(protocol))
    events: Counter[str] = Counter()
    protocol.set_callbacks(lambda event, _sub: events.update([type(event).__name__]),
                           link.lost.append)
    protocol.connection_made(link.transport)
    submissions: list[Submission] = []
    resyncs: list[asyncio.Task[None]] = []

    def check_futures(final: bool = False) -> None:
        # Every future is pending, resolved, or failed with a TangoError; the ones that
        # ended are counted and forgotten (so that the harness holds no memory).
        keep = []
        for submission in submissions:
            states = (_valid_future(submission.reply, Response),
                      _valid_future(submission.completion, Completed))
            if final or "pending" not in states:
                counts["reply " + states[0]] += 1
                counts["completion " + states[1]] += 1
            else:
                keep.append(submission)
        submissions[:] = keep

    with _recording() as recorder:
        for step, (kind, arg) in enumerate(script):
            if kind == "submit":
                submissions.append(protocol.submit(parse(arg, CONTEXT)))
            elif kind == "resync":
                resyncs.append(asyncio.create_task(protocol.resync(ctrl_c=arg, timeout=0.01)))
            elif kind == "marker" and link.marker_codes():
                link.answer_marker()  # the reply that ends the latest resync
            elif kind == "answer":
                link.feed(plausible_answer(protocol.core, random.Random(arg)))
            elif kind == "bytes":
                link.feed(arg)  # must not raise
            await asyncio.sleep(0)
            if step % 100 == 99:
                check_futures()
                link.transport.writes.clear()
        results = await asyncio.gather(*resyncs, return_exceptions=True)
        for result in results:
            assert result is None or isinstance(result, ControllerTimeoutError), result
            counts["resync: " + ("ControllerTimeoutError" if result else "marker answered")] += 1
        check_futures(final=True)
        protocol.close()
        await asyncio.sleep(0)
    assert link.lost and not loop_errors, loop_errors
    assert not recorder.bad, recorder.bad
    counts.update(recorder.counts)
    for name, number in events.items():
        counts["event " + name] += number


_FUZZ_STEP = st.one_of(
    st.tuples(st.just("submit"), st.sampled_from(REQUESTS)),
    st.tuples(st.just("bytes"), st.binary(max_size=300)),
    st.tuples(st.just("bytes"),
              st.lists(st.sampled_from(TOKENS) | st.binary(max_size=6), max_size=40)
              .map(b"".join)),
    st.tuples(st.just("resync"), st.booleans()),
    st.tuples(st.just("marker"), st.none()),
    st.tuples(st.just("answer"), st.integers(0, 2**16)),
    st.tuples(st.just("answer"), st.integers(0, 2**16)),
)


@settings(max_examples=300, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(mode=st.integers(0, 4), script=st.lists(_FUZZ_STEP, max_size=80))
def test_fuzz_protocol_with_requests_pending(mode: int, script: list[tuple[str, Any]]) -> None:
    """Random bytes into :meth:`TangoProtocol.data_received` while requests, moves and
    resyncs are pending: no exception escapes, only protocol problems are logged, every
    future is pending, resolved or failed with a TangoError, and the protocol closes
    cleanly."""
    counts = COUNTS["fuzz: whole protocol (hypothesis)"]
    with asyncio.Runner() as runner:
        runner.run(_fuzz_protocol(mode, script, counts))
    counts["examples"] += 1
    counts["bytes fed"] += sum(len(arg) for kind, arg in script if kind == "bytes")


@pytest.mark.slow
def test_fuzz_protocol_soak_memory_bounded() -> None:
    """A seeded soak of the whole protocol: 3 MB of noise while requests keep coming;
    the memory allocated meanwhile stays bounded (resolved requests are forgotten)."""
    counts = COUNTS["fuzz: whole protocol soak"]
    rng = random.Random(0xB0B)
    script: list[tuple[str, Any]] = []
    fed = 0
    while fed < 3 * 2**20:
        roll = rng.random()
        if roll < 0.3:
            script.append(("submit", rng.choice(REQUESTS)))
        elif roll < 0.31:
            script.append(("resync", rng.random() < 0.5))
        elif roll < 0.33:
            script.append(("marker", None))
        elif roll < 0.6:
            script.append(("answer", rng.getrandbits(16)))
        else:
            chunk = _noise(rng, rng.randint(1, 2048))
            fed += len(chunk)
            script.append(("bytes", chunk))
    tracemalloc.start()
    try:
        baseline, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        with asyncio.Runner() as runner:
            runner.run(_fuzz_protocol(1, script, counts))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    counts["bytes fed"] = fed
    counts["peak KiB above baseline"] = (peak - baseline) // 1024
    assert peak - baseline < 2**20, peak - baseline
