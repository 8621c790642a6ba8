"""Fuzzing the sans-IO protocol core with arbitrary bytes.

Whatever the controller (or line noise) sends, :class:`~tango_aio.sansio._core.ProtocolCore` must
raise nothing but :class:`~tango_aio.errors.ProtocolError`, keep working after it, and keep
its memory bounded: the assembler holds at most ``max_line`` bytes between reads (plus the
chunk being processed), and received data never adds requests or moves to wait for.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Hashable, Iterable

import pytest
from fuzzkit import CONTEXT, REQUESTS, TOKENS, noise, plausible_answer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.errors import ProtocolError
from tango_aio.sansio._core import (
    Acknowledged,
    Completed,
    Dropped,
    Echoed,
    Event,
    Mismatched,
    ProtocolCore,
    Replied,
    RequestLost,
    Unsolicited,
)

MAX_LINE = 64


def _noise(seed: int, size: int, token_share: float) -> bytes:
    """``size``-ish bytes of tokens and random bytes (large inputs hypothesis rarely makes)."""
    return noise(random.Random(seed), size, token_share)


_BYTES = st.one_of(
    st.binary(max_size=8192),
    st.binary(min_size=2048, max_size=8192),
    st.lists(st.sampled_from(TOKENS) | st.binary(max_size=6), max_size=400).map(b"".join),
    st.builds(_noise, st.integers(0, 2**32), st.integers(0, 20_000), st.sampled_from([0.0, 0.5,
                                                                                  0.9])),
)

_EVENT_TYPES = (Replied, Acknowledged, Echoed, Completed, Unsolicited, Dropped, RequestLost,
                Mismatched)


def chunked(data: bytes, sizes: Iterable[int]) -> list[bytes]:
    """Cut ``data`` into pieces of the given sizes (cycled), the rest in one piece."""
    out: list[bytes] = []
    start = 0
    for size in sizes:
        if start >= len(data):
            break
        out.append(data[start : start + size])
        start += size
    if start < len(data):
        out.append(data[start:])
    return out


class Harness:
    """Feeds a core and checks the invariants after every chunk."""

    def __init__(self, core: ProtocolCore, max_line: int) -> None:
        self.core = core
        self.max_line = max_line
        self.events: list[Event] = []
        self.errors = 0
        self.tags: set[Hashable] = set()

    def send(self, line: str, tag: Hashable) -> bytes:
        self.tags.add(tag)
        data, _ = self.core.send(parse(line, CONTEXT), tag)
        return data

    def resync(self, tag: Hashable, ctrl_c: bool = False) -> bytes:
        self.tags.add(tag)
        return self.core.resync(tag, ctrl_c=ctrl_c)

    def drain(self) -> None:
        while True:
            try:
                event = self.core.next_event()
            except ProtocolError:
                self.errors += 1
                continue
            if event is None:
                return
            assert isinstance(event, _EVENT_TYPES)
            tag = getattr(event, "tag", None)
            # Internal follow-ups never surface; every tag is one the caller registered.
            assert tag is None or tag in self.tags, event
            self.events.append(event)

    def feed(self, chunk: bytes) -> None:
        core = self.core
        pending, moves = len(core._pending), len(core._moves)
        core.receive_data(chunk)
        assert core._assembler.buffered <= self.max_line + len(chunk)
        self.drain()
        assert core._assembler.buffered <= self.max_line
        assert len(core._pending) <= pending  # received data never adds expectations
        assert len(core._moves) <= moves
        assert not core._events


#: A conversation step: send a request, start a resync, let the controller answer what the
#: oldest request owes (reaches echo/ack/multi-line states), or receive arbitrary bytes.
_ACTIONS = st.one_of(
    st.tuples(st.just("send"), st.sampled_from(REQUESTS)),
    st.tuples(st.just("resync"), st.booleans()),
    st.tuples(st.just("answer"), st.integers(0, 2**16)),
    st.tuples(st.just("bytes"), st.binary(max_size=64) | st.sampled_from(TOKENS)),
)


def _play(mode: int, actions: list[tuple[str, object]], data: bytes,
          cut: Callable[[bytes], list[bytes]], answers: list[bytes] | None = None,
          check: bool = True) -> tuple[Harness, list[bytes]]:
    """Run ``actions`` then ``data`` through a fresh core (checking replies or not);
    ``answer`` bytes are computed from the core's state, or replayed from ``answers``.
    Returns the harness and answers."""
    core = ProtocolCore(autostatus=mode, context=CONTEXT, max_line=MAX_LINE,
                        check_replies=check, marker_seed=0)
    harness = Harness(core, MAX_LINE)
    given_answers = iter(answers or [])
    made: list[bytes] = []
    for index, (kind, arg) in enumerate(actions):
        if kind == "send":
            assert isinstance(arg, str)
            harness.send(arg, index)
            continue
        if kind == "resync":
            harness.resync(("resync", index), ctrl_c=bool(arg))
            continue
        if kind == "answer":
            assert isinstance(arg, int)
            piece = (next(given_answers) if answers is not None
                     else plausible_answer(harness.core, random.Random(arg)))
            made.append(piece)
        else:
            assert isinstance(arg, bytes)
            piece = arg
        for chunk in cut(piece):
            harness.feed(chunk)
    for chunk in cut(data):
        harness.feed(chunk)
    return harness, made


_ARBITRARY_RUNS = given(
    mode=st.integers(0, 4),
    actions=st.lists(_ACTIONS, max_size=60),
    data=_BYTES,
    sizes=st.lists(st.integers(1, 700), max_size=40),
    check=st.booleans(),
)
_TOLERATE = [HealthCheck.too_slow, HealthCheck.data_too_large]


@settings(max_examples=150, deadline=None, suppress_health_check=_TOLERATE)
@_ARBITRARY_RUNS
def test_fuzz_arbitrary_bytes(mode: int, actions: list[tuple[str, object]], data: bytes,
                              sizes: list[int], check: bool) -> None:
    _check_arbitrary_run(mode, actions, data, sizes, check)


@pytest.mark.slow
@settings(max_examples=2000, deadline=None, suppress_health_check=_TOLERATE)
@_ARBITRARY_RUNS
def test_fuzz_arbitrary_bytes_long(mode: int, actions: list[tuple[str, object]],
                                   data: bytes, sizes: list[int], check: bool) -> None:
    _check_arbitrary_run(mode, actions, data, sizes, check)


def _check_arbitrary_run(mode: int, actions: list[tuple[str, object]], data: bytes,
                         sizes: list[int], check: bool) -> None:
    """Whatever the bytes, the core's events do not depend on how they were cut."""
    harness, answers = _play(mode, actions, data, lambda piece: chunked(piece, sizes),
                             check=check)
    # Replayed in tiny pieces on a fresh core, the same bytes give the same events.
    tiny = [1, 2, 1, 3, 5, 1, 8, 13]
    again, _ = _play(mode, actions, data,
                     lambda piece: chunked(piece, tiny * (len(piece) // 4 + 1)), answers,
                     check)
    assert again.events == harness.events
    assert again.errors == harness.errors


@settings(max_examples=50, deadline=None)
@given(data=st.binary(min_size=1, max_size=4096), size=st.integers(1, 64))
def test_fuzz_default_limit_without_requests(data: bytes, size: int) -> None:
    core = ProtocolCore()
    harness = Harness(core, 1024)
    for chunk in chunked(data, [size] * (len(data) // size + 1)):
        harness.feed(chunk)
    assert all(isinstance(e, Unsolicited | Completed) for e in harness.events)


def test_long_random_run() -> None:
    """A fixed-seed soak test: requests, resyncs, plausible replies and noise interleaved."""
    rng = random.Random(0x7A6C0)
    core = ProtocolCore(autostatus=1, context=CONTEXT, max_line=MAX_LINE)
    harness = Harness(core, MAX_LINE)
    tag = 0
    fed = 0
    while fed < 1_000_000:
        action = rng.random()
        if action < 0.2 and len(core._pending) < 40:
            harness.send(rng.choice(REQUESTS), tag)
            tag += 1
        elif action < 0.21:
            harness.resync(("resync", tag), ctrl_c=rng.random() < 0.5)
            tag += 1
        elif action < 0.215:
            core.drop_completions()
        else:
            if action < 0.8:
                data = b"".join(plausible_answer(core, rng) for _ in range(rng.randint(1, 4)))
            else:
                data = _noise(rng.getrandbits(32), rng.randint(1, 300), 0.8)
            fed += len(data)
            for chunk in chunked(data, [rng.randint(1, 50) for _ in range(20)]):
                harness.feed(chunk)
    assert harness.errors > 0  # over-long lines did occur and were survived
    kinds = {type(event) for event in harness.events}
    assert kinds == set(_EVENT_TYPES), kinds  # the run reached every routing path
    assert core._assembler.buffered <= MAX_LINE
