"""The fast move path of #19 against the plain one, and no false success with it.

Since #19 a ``move_to`` sizes its timeout from the positions of the driver's latest state
read instead of reading ``?pos`` first, and a ``move_by`` writes its start ``?pos`` in the
same write as its line; the confirmation reads ``?statusaxis`` and ``?pos`` back to back.
The *plain* path (forced here by forgetting the known positions before every move) is the
one before #19: ``?pos`` read first, then the line.

* the two paths give the same outcomes (letters, errors, where the axes end) on random
  move sequences under the firmware profiles;
* a move whose stage is stopped behind the driver's back still raises, with the fast
  sizing and on the very first move after connect (no known position);
* a known position that is stale (the stage moved by other means) does not fail a good
  move: the provisional budget is extended once from where the axes are;
* the separator between a confirming ``?pos`` and the next move's ``?err`` probe goes out
  with the ``?pos`` (ahead of need), not in front of the next move, and ``aclose`` waits
  for its reply.
"""

from __future__ import annotations

import asyncio
import logging
import random
from typing import Any

import pytest
from helpers import EmulatorFactory, as_axes
from test_matrix import (
    BOUND,
    TRAVEL,
    assert_arrived,
    assert_stopped_short,
    bounded,
    moving,
    open_variant,
    sim_axes,
)

from tango_aio.errors import MoveError, TangoError
from tango_aio.link._protocol import TangoProtocol

pytestmark = [pytest.mark.timeout(180), pytest.mark.virtual_clock]

# The default run takes one instant run (6 s); the other profile, seed and baud rate are
# slow.
PROFILE_RUNS = [
    pytest.param(profile, baud, seed, id=f"{profile}-{baud}-{seed}",
                 marks=[pytest.mark.slow] if baud or seed > 1 or profile != "manual" else [])
    for profile in ("manual", "legacy") for baud in (0, 57600) for seed in (1, 2)
]


def random_moves(seed: int, count: int = 10) -> list[tuple[str, dict[str, float]]]:
    """A random sequence of ``move_to``/``move_by`` calls on X, Y or both, with moves of
    zero length among them and one move beyond a limit switch (at ±TRAVEL/2)."""
    rng = random.Random(seed)
    out: list[tuple[str, dict[str, float]]] = []
    where = {"x": 0.0, "y": 0.0}
    beyond = rng.randrange(1, count)
    for index in range(count):
        axes = rng.choice((("x",), ("y",), ("x", "y")))
        kind = rng.choice(("to", "to", "by"))
        values = {}
        for axis in axes:
            roll = rng.random()
            if index == beyond and axis == axes[0]:
                target = TRAVEL  # beyond the switch: ends on it
            elif roll < 0.25:
                target = where[axis]  # no distance
            else:
                target = round(rng.uniform(-3.0, 3.0), 2)
            values[axis] = round(target - where[axis], 4) if kind == "by" else target
            if abs(target) < TRAVEL / 2:
                where[axis] = target
        out.append((kind, values))
    return out


async def run_sequence(emulator: EmulatorFactory, profile: str, baud: int,
                       moves: list[tuple[str, dict[str, float]]], plain: bool) -> list[Any]:
    """Each move's outcome and where the axes stand after it."""
    emu = await open_variant(emulator, profile, baud)
    tango = emu.tango
    outcomes: list[Any] = []
    for kind, values in moves:
        if plain:
            tango._motion.positions = None  # the pre-#19 sizing: ?pos read first
        call = tango.move_to if kind == "to" else tango.move_by
        try:
            result: Any = ("ok", await bounded(call(**as_axes(values))))
        except MoveError as error:
            result = ("MoveError", {a: s for a, s in error.statuses.items() if a in values})
        except TangoError as error:
            result = (type(error).__name__,)
        state = sim_axes(emu)
        # An axis the driver stopped because another of the move stopped at its switch
        # stands wherever the stop found it (when the state was polled): E, or @ where
        # aborted axes report @ (legacy).
        cut = {a for a, s in result[1].items() if s != "S"} \
            if result[0] == "MoveError" else set()
        outcomes.append((kind, values, result,
                         {a: round(p, 3) for a, (p, _) in state.items() if a not in cut}))
        if result[0] != "ok":
            # Leave the limit switch the way any caller would: back inside the travel.
            await bounded(tango.move_to(**as_axes({a: 0.0 for a in values})))
    return outcomes


@pytest.mark.parametrize(("profile", "baud", "seed"), PROFILE_RUNS)
async def test_fast_path_gives_the_outcomes_of_the_plain_path(
        emulator: EmulatorFactory, profile: str, baud: int, seed: int) -> None:
    moves = random_moves(seed)
    fast = await run_sequence(emulator, profile, baud, moves, plain=False)
    plain = await run_sequence(emulator, profile, baud, moves, plain=True)
    assert fast == plain
    assert any(outcome[2][0] == "ok" for outcome in fast)
    assert any(outcome[2][0] != "ok" for outcome in fast)  # the sequence has failures too


@pytest.mark.parametrize("first", [True, False], ids=["first-move", "known-position"])
@pytest.mark.parametrize("profile", ["manual", "legacy"])
async def test_a_move_stopped_behind_the_drivers_back_raises(
        emulator: EmulatorFactory, profile: str, first: bool) -> None:
    emu = await open_variant(emulator, profile, 0)
    tango = emu.tango
    if first:
        tango._motion.positions = None  # nothing known: as right after connect
    else:
        await bounded(tango.move_to(x=-1.0))
        assert tango._motion.positions is not None  # the fast sizing is used
    await tango.set("vel", 5.0, axis="x")
    task = asyncio.create_task(tango.move_to(x=4.0))
    await moving(emu, "x", task=task)
    emu.model.motion.abort("x")  # e.g. a stop button: no line of the driver's
    with pytest.raises(MoveError):
        await bounded(task)
    assert_stopped_short(emu, {"x": 4.0})
    await bounded(tango.move_to(x=0.5))
    assert_arrived(emu, {"x": 0.5})


@pytest.mark.parametrize("profile", ["manual", pytest.param("legacy", marks=pytest.mark.slow)])
async def test_a_move_cut_short_by_a_limit_switch_raises_on_the_first_move(
        emulator: EmulatorFactory, profile: str) -> None:
    emu = await open_variant(emulator, profile, 0)
    emu.tango._motion.positions = None  # as right after connect
    with pytest.raises(MoveError):
        await bounded(emu.tango.move_by(x=TRAVEL))
    with pytest.raises(MoveError):
        await bounded(emu.tango.move_to(y=TRAVEL))  # now with a known position


async def test_a_stale_known_position_does_not_fail_a_good_move(
        emulator: EmulatorFactory) -> None:
    emu = await open_variant(emulator, "manual", 0)
    tango = emu.tango
    await bounded(tango.move_to(x=0.0))
    assert tango._motion.positions is not None
    await tango.go(x=4.5)  # moved by other means: the driver's known X stays 0
    await bounded(tango.wait_idle(timeout=BOUND))
    assert float(tango._motion.positions["x"]) == 0.0
    # 4.5 mm at 1.25 mm/s: about 3.6 s, more than the budget of a move of no distance
    # (2 s and the emulator's 1 s of closed-loop settling, ctrt).
    await tango.set("vel", 1.25, axis="x")
    assert await bounded(tango.move_to(x=0.0)) is not None
    assert_arrived(emu, {"x": 0.0})


async def test_the_separator_a_move_needs_goes_out_with_the_confirmation(
        emulator: EmulatorFactory, caplog: pytest.LogCaptureFixture) -> None:
    tango = (await emulator("sim://?baud=57600")).tango
    await tango.move_to(x=0.5)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        for target in (0.25, 0.5, 0.25):
            await tango.move_to(x=target)
        await tango.aclose()
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records
             if r.name == "tango_aio.wire"]
    moves = [i for i, line in enumerate(lines) if line.startswith("-> b'!moa")]
    assert len(moves) == 3
    # Nothing written in front of a move line: before it, the confirmation's replies.
    assert all(lines[i - 1].startswith("<- ") for i in moves), lines
    # Every ?help is written right behind a ?pos, before any of their replies came.
    helps = [i for i, line in enumerate(lines) if line == "-> b'?help'"]
    # (#28: only the moved axis' position, ?pos x, see the test below).
    assert helps and all(lines[i - 1] == "-> b'?pos x'" for i in helps), lines
    # aclose waited for the last separator's reply (the next program on the port would
    # read it otherwise).
    assert lines[-1].startswith("<- b'ERROR"), lines


async def test_the_confirmation_reads_the_moved_axis_alone(
        emulator: EmulatorFactory, caplog: pytest.LogCaptureFixture) -> None:
    """#28: behind the report, ``?statusaxis`` (every axis, first) and the position of the
    one moved axis (``?pos x``: 7 reply bytes instead of 21 on three axes); a move of
    several axes still reads ``?pos``. ``last_positions`` holds what was read."""
    tango = (await emulator("sim://?baud=57600")).tango
    await tango.move_to(x=0.5)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.move_to(y=0.25)
        assert tango.last_positions == {"y": "0.2500"}
        await tango.move_to(x=0.25, y=0.5)
        assert tango.last_positions == {"x": "0.2500", "y": "0.5000", "z": "0.0000"}
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records
             if r.name == "tango_aio.wire" and "->" in r.getMessage()]
    reads = [line for line in lines if "statusaxis" in line or "?pos" in line
             or line == "-> b'sa'"]
    assert reads == ["-> b'sa'", "-> b'?pos y'", "-> b'sa'", "-> b'?pos'"], lines


@pytest.mark.parametrize("switches", ["profile=legacy", "instruction_set=older"])
async def test_the_confirmation_spells_statusaxis_out_on_older_firmware(
        emulator: EmulatorFactory, caplog: pytest.LogCaptureFixture, switches: str) -> None:
    """#28: ``sa`` is the 1.71 manual's alias (L2663); the older edition has none (old
    L733), so a unit of that family is asked ``?statusaxis``."""
    tango = (await emulator(f"sim://?baud=0&{switches}")).tango
    assert tango.identity is not None and tango.identity.family == "older"
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.move_to(x=0.5)
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records
             if r.name == "tango_aio.wire" and "->" in r.getMessage()]
    assert "-> b'?statusaxis'" in lines and "-> b'sa'" not in lines, lines


async def test_an_unanswered_sa_is_not_asked_again(
        emulator: EmulatorFactory, caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A unit that answers like the 1.71 manual but does not know ``sa`` (an unknown
    instruction: error 4, no reply): the confirmation is read again as ``?statusaxis``,
    ``sa`` is not written again, and the moves end where they should."""
    emu = await emulator("sim://?baud=0")  # the set-up's replies come: the default timeout
    tango, model = emu.tango, emu.model
    tango.reply_timeout = 0.3  # short for the unanswered sa
    handle_line = model.handle_line

    def without_sa(line: bytes, now: float) -> None:
        handle_line(b"sax" if line.strip() == b"sa" else line, now)

    monkeypatch.setattr(model, "handle_line", without_sa)
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        await tango.move_to(x=0.5)
        tango.reply_timeout = 5.0  # the replies from here on come
        assert tango.last_positions == {"x": "0.5000"}
        # The error 4 the unanswered sa left is not taken for the next move's (the resync
        # after the lost read reads the error state).
        await tango.move_to(x=0.25)
        await tango.move_to(x=0.75)
    assert (await tango.position())["x"] == 0.75
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records
             if r.name == "tango_aio.wire" and "->" in r.getMessage()]
    assert lines.count("-> b'sa'") == 1, lines


async def test_the_confirmation_goes_out_in_the_turn_the_report_arrived(
        emulator: EmulatorFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """#28: a move that waits for its report writes its confirmation (``sa``, ``?pos x``)
    while the report's bytes are being handled (``Motion.reported``), not a loop turn
    later once the move's task runs again; and the move still ends only when the read
    says so (the report stays a hint)."""
    tango = (await emulator("sim://?baud=57600")).tango
    await tango.move_to(x=0.5)
    handling: list[bytes | None] = [None]
    written_during: list[bytes | None] = []
    received = TangoProtocol.data_received
    stream = bytearray()

    def data_received(protocol: TangoProtocol, data: bytes) -> None:
        stream.extend(data)
        handling[0] = bytes(stream[-16:])  # what came last, up to this chunk's end
        try:
            received(protocol, data)
        finally:
            handling[0] = None

    class Writes(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().endswith("-> b'sa'"):
                written_during.append(handling[0])

    monkeypatch.setattr(TangoProtocol, "data_received", data_received)
    handler = Writes()
    wire = logging.getLogger("tango_aio.wire")
    wire.addHandler(handler)
    level = wire.level
    wire.setLevel(logging.DEBUG)
    try:
        for target in (0.25, 0.5, 0.25):
            assert await tango.move_to(x=target) is not None
    finally:
        wire.removeHandler(handler)
        wire.setLevel(level)
    assert len(written_during) == 3
    # Each was written while the chunk that ended the report (``@@@-.``) was handled.
    assert all(chunk is not None and chunk.endswith(b"@@@-.\r") for chunk in written_during), \
        written_during
    assert tango.last_positions == {"x": "0.2500"}
