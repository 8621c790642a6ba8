"""MoveCoalescer against the in-process emulator (``sim://?baud=0``)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Callable
from typing import Any

import pytest
from helpers import Emulated, EmulatorFactory, emulated_position, wait_moving

from tango_aio.errors import InvalidCommandError, MoveError, TangoError
from tango_aio.group._coalesce import MoveCoalescer, _lines


@pytest.fixture
async def emu(emulator: EmulatorFactory) -> Emulated:
    emulated = await emulator()
    await emulated.make_fast()
    return emulated


@pytest.fixture
async def coalescer(emu: Emulated) -> AsyncIterator[MoveCoalescer]:
    merger = MoveCoalescer(emu.tango, window=0.05)
    yield merger
    await merger.aclose()


def motion_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    """The ``!mo...`` lines in the ``tango_aio.wire`` trace, numbers normalised."""
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records
             if r.name == "tango_aio.wire"]
    return [_normalised(line[5:-1]) for line in lines if line.startswith("-> b'!mo")]


@pytest.fixture
def moves(caplog: pytest.LogCaptureFixture) -> Callable[[], list[str]]:
    """The motion lines written so far (from the ``tango_aio.wire`` trace)."""
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    return lambda: motion_lines(caplog)


def _normalised(line: str) -> str:
    """``!moa 1.0 -2.50`` -> ``!moa 1 -2.5`` (number formatting is not under test)."""
    return " ".join(f"{float(word):g}" if word[-1].isdigit() else word
                    for word in line.split())


async def test_concurrent_requests_become_one_line(
        emu: Emulated, coalescer: MoveCoalescer, moves: Callable[[], list[str]]) -> None:
    letters = await asyncio.gather(coalescer.move_to("x", 1.5), coalescer.move_to("y", -2))
    assert list(letters) == ["@", "@"]  # gather: a list (typed as a tuple)
    assert moves() == ["!moa 1.5 -2"]
    assert await emu.tango.position() == {"x": 1.5, "y": -2.0, "z": 0.0}
    assert emulated_position(emu, "x") == pytest.approx(1.5)
    assert emulated_position(emu, "y") == pytest.approx(-2)


async def test_callers_get_the_positions_the_confirmation_read(
        emu: Emulated, coalescer: MoveCoalescer) -> None:
    x: dict[str, str] = {}
    y: dict[str, str] = {}
    await asyncio.gather(coalescer.move_to("x", 1.5, positions=x),
                         coalescer.move_to("y", -2, positions=y))
    assert x == y == emu.tango.last_positions
    assert float(x["x"]) == pytest.approx(1.5) and float(x["y"]) == pytest.approx(-2)
    moved: dict[str, str] = {}
    await coalescer.move_to("z", 0.25, positions=moved)  # a line of its own
    assert float(moved["z"]) == pytest.approx(0.25)


async def test_requests_in_separate_windows_are_separate_moves(
        emu: Emulated, coalescer: MoveCoalescer, moves: Callable[[], list[str]]) -> None:
    assert await coalescer.move_to("x", 1) == "@"
    assert await coalescer.move_to("y", 2) == "@"
    assert moves() == ["!moa 1", "!moa y 2"]
    assert await emu.tango.position() == {"x": 1.0, "y": 2.0, "z": 0.0}


async def test_same_axis_request_starts_the_next_batch(
        emu: Emulated, coalescer: MoveCoalescer, moves: Callable[[], list[str]]) -> None:
    first = asyncio.ensure_future(coalescer.move_to("x", 1))
    await asyncio.sleep(0)
    second = asyncio.ensure_future(coalescer.move_to("x", 2))
    third = asyncio.ensure_future(coalescer.move_to("y", 3))
    assert list(await asyncio.gather(first, second, third)) == ["@", "@", "@"]
    assert moves() == ["!moa 1", "!moa 2 3"]
    assert await emu.tango.position() == {"x": 2.0, "y": 3.0, "z": 0.0}


async def test_axes_with_a_gap_run_as_separate_lines(
        emu: Emulated, coalescer: MoveCoalescer, moves: Callable[[], list[str]]) -> None:
    await asyncio.gather(coalescer.move_to("z", 3), coalescer.move_to("x", 1))
    assert moves() == ["!moa 1", "!moa z 3"]
    assert await emu.tango.position() == {"x": 1.0, "y": 0.0, "z": 3.0}


def test_lines_split_at_the_first_gap() -> None:
    assert _lines({"y": 2, "x": 1, "z": 3}) == [{"x": 1, "y": 2, "z": 3}]
    assert _lines({"y": 2, "z": 3}) == [{"y": 2}, {"z": 3}]
    assert _lines({"x": 1, "y": 2, "a": 4}) == [{"x": 1, "y": 2}, {"a": 4}]
    assert _lines({}) == []


async def test_move_error_reaches_every_caller(
        emu: Emulated, coalescer: MoveCoalescer) -> None:
    await emu.shorten(4.0, autostatus=1)  # limit switches at +-2 mm
    await emu.make_fast()
    results = await asyncio.gather(coalescer.move_to("x", 3), coalescer.move_to("y", 1),
                                   return_exceptions=True)
    assert all(isinstance(r, MoveError) for r in results)
    assert results[0] is results[1]
    assert isinstance(results[0], MoveError) and results[0].statuses["x"] == "S"
    # The next request works.
    assert await coalescer.move_to("y", 0) == "@"


async def test_invalid_request_fails_alone_before_anything_is_sent(
        emu: Emulated, moves: Callable[[], list[str]]) -> None:
    coalescer = MoveCoalescer(emu.tango)
    good = asyncio.ensure_future(coalescer.move_to("y", 1))
    with pytest.raises(InvalidCommandError):
        await coalescer.move_to("q", 1)
    with pytest.raises(InvalidCommandError):
        await coalescer.move_to("x", float("nan"))
    assert await good == "@"
    assert moves() == ["!moa y 1"]
    await coalescer.aclose()


async def test_cancelling_a_caller_stops_the_merged_move(
        emu: Emulated, coalescer: MoveCoalescer) -> None:
    await emu.tango.set("vel", x=1, y=1)  # slow: 1 mm/s
    mover_x = asyncio.ensure_future(coalescer.move_to("x", 20))
    mover_y = asyncio.ensure_future(coalescer.move_to("y", 20))
    await wait_moving(emu, "y")
    mover_x.cancel()
    with pytest.raises(asyncio.CancelledError):
        await mover_x
    # When the cancelled caller returns, every axis stands still.
    assert set((await emu.tango.status()).values()) <= {"@", "E"}
    with pytest.raises(MoveError) as info:
        await mover_y
    assert info.value.statuses == {"x": "E", "y": "E"}
    position = await emu.tango.position()
    assert 0 < position["x"] < 20 and 0 < position["y"] < 20
    # The next request works.
    await emu.tango.set("vel", x=100, y=100)
    assert await coalescer.move_to("x", 0) == "@"


async def test_cancelling_before_the_batch_is_sent_only_withdraws(
        emu: Emulated, coalescer: MoveCoalescer, moves: Callable[[], list[str]]) -> None:
    mover_x = asyncio.ensure_future(coalescer.move_to("x", 1))
    mover_y = asyncio.ensure_future(coalescer.move_to("y", 2))
    await asyncio.sleep(0)  # both joined the batch being collected
    mover_x.cancel()
    assert await mover_y == "@"
    assert mover_x.cancelled()
    assert moves() == ["!moa y 2"]
    assert await emu.tango.position() == {"x": 0.0, "y": 2.0, "z": 0.0}


async def test_cancelling_the_only_caller_before_sending_moves_nothing(
        emu: Emulated, coalescer: MoveCoalescer, moves: Callable[[], list[str]]) -> None:
    mover = asyncio.ensure_future(coalescer.move_to("x", 1))
    await asyncio.sleep(0)
    mover.cancel()
    with pytest.raises(asyncio.CancelledError):
        await mover
    assert await coalescer.move_to("y", 1) == "@"
    assert moves() == ["!moa y 1"]


async def test_aclose_stops_a_running_move_and_refuses_new_requests(
        emu: Emulated) -> None:
    await emu.tango.set("vel", x=1)
    coalescer = MoveCoalescer(emu.tango)
    mover = asyncio.ensure_future(coalescer.move_to("x", 20))
    await wait_moving(emu, "x")
    await coalescer.aclose()
    with pytest.raises(MoveError, match="closed"):
        await mover
    assert (await emu.tango.status())["x"] != "M"
    with pytest.raises(TangoError, match="closed"):
        await coalescer.move_to("x", 1)


async def test_window_must_be_valid(emu: Emulated) -> None:
    with pytest.raises(ValueError):
        MoveCoalescer(emu.tango, window=-1)


async def test_announced_single_request_waits_for_no_window(
        emu: Emulated, moves: Callable[[], list[str]]) -> None:
    # A window of an hour: only the announcements may make a batch wait (#28 target 3).
    merger = MoveCoalescer(emu.tango, window=3600, collect="announced")
    try:
        async with asyncio.timeout(30):
            assert await merger.move_to("x", 1.0) == "@"
        assert moves() == ["!moa 1"]
    finally:
        await merger.aclose()


async def test_announced_requests_join_the_batch_they_were_announced_to(
        emu: Emulated, moves: Callable[[], list[str]]) -> None:
    merger = MoveCoalescer(emu.tango, window=3600, collect="announced")
    try:
        arrived = merger.announce()  # Y is on its way (e.g. a set reading ?lim first)
        first = asyncio.create_task(merger.move_to("x", 1.0))
        for _ in range(20):  # loop turns pass: X's batch waits for Y
            await asyncio.sleep(0)
        assert moves() == []
        second = asyncio.create_task(merger.move_to("y", 2.0, arrived))
        async with asyncio.timeout(30):
            assert list(await asyncio.gather(first, second)) == ["@", "@"]
        assert moves() == ["!moa 1 2"]
        arrived()  # ending it again does nothing
        async with asyncio.timeout(30):  # and no later batch waits for it
            await merger.move_to("x", 0.0)
    finally:
        await merger.aclose()


async def test_an_announcement_given_up_releases_the_batch(emu: Emulated) -> None:
    merger = MoveCoalescer(emu.tango, window=3600, collect="announced")
    try:
        arrived = merger.announce()
        first = asyncio.create_task(merger.move_to("x", 1.0))
        await asyncio.sleep(0)
        arrived()  # the announced request failed before it was made
        async with asyncio.timeout(30):
            assert await first == "@"
        with pytest.raises(ValueError, match="collect"):
            MoveCoalescer(emu.tango, collect="sometimes")
    finally:
        await merger.aclose()


async def test_a_caller_resumes_in_the_loop_turn_after_its_line_returned(
        emu: Emulated, moves: Callable[[], list[str]],
        monkeypatch: pytest.MonkeyPatch) -> None:
    # #28 target 4: the batch settles its callers in the step its last line returned in,
    # not through the task's end and a shield (two more loop turns on every IOC put).
    merger = MoveCoalescer(emu.tango, collect="announced")
    turns = 0

    async def spin() -> None:
        nonlocal turns
        while True:
            await asyncio.sleep(0)
            turns += 1

    spinner: list[asyncio.Task[None]] = []
    original = emu.tango.move_to

    async def move_to(**axes: Any) -> dict[str, str]:
        letters = await original(**axes)
        spinner.append(asyncio.create_task(spin()))  # counts turns from here
        return letters

    monkeypatch.setattr(emu.tango, "move_to", move_to)
    try:
        assert await merger.move_to("x", 1.0) == "@"
        seen = turns
    finally:
        for task in spinner:
            task.cancel()
        await merger.aclose()
    assert moves() == ["!moa 1"]
    assert seen == 0  # before: 1 (the batch task's end, then the shield's callback)
