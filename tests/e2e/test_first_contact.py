"""Issue 30 (a new user's first hour): input that only looks valid is refused before any
byte is written (items 4 and 12), is_busy()/is_calibrated() (item 10), wait_idle() right
after a move was scheduled (item 12)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

import pytest

import tango_aio
from tango_aio import Controller, InvalidCommandError


@pytest.fixture
async def tango() -> AsyncIterator[Controller]:
    async with tango_aio.connect("sim://?baud=0") as controller:
        yield controller


def _watch_writes(tango: Controller, monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Every submission the protocol is asked to write from now on."""
    written: list[Any] = []
    protocol = tango._protocol
    for name in ("submit", "query"):
        real = getattr(protocol, name)

        def spy(*args: Any, _real: Any = real, **kwargs: Any) -> Any:
            written.append(args[0] if args else kwargs)
            return _real(*args, **kwargs)

        monkeypatch.setattr(protocol, name, spy)
    return written


@pytest.mark.parametrize(("call", "message"), [
    (lambda t: t.triggers.upload_positions([1.0, 2.0], axis="a"),
     "the controller has no A axis"),
    (lambda t: t.triggers.upload_positions("123"), "must be a sequence of numbers"),
    (lambda t: t.snapshots.upload_positions(["123"]), "must be a sequence of numbers"),
    (lambda t: t.snapshots.upload_positions("123"), "must be a sequence of rows"),
    (lambda t: t.triggers.upload_positions([False, True]), "entry 0 is not a number"),
    (lambda t: t.snapshots.upload_positions([[True, 1.0, 2.0]]), "entry 0 is not a number"),
    (lambda t: t.triggers.upload_positions([1.0], axis=1), "1 is not an axis"),
    (lambda t: t.triggers.upload_positions([None]), "entry 0 is not a number"),
    (lambda t: t.snapshots.upload_positions([[None, 1.0, 2.0]]), "entry 0 is not a number"),
    (lambda t: t.calibrate(""), "axis must be one of x, y, z, a, got ''"),
    (lambda t: t.measure_range(""), "axis must be one of"),
    (lambda t: t.set("vel", 5, axis=""), "axis must be one of"),
    (lambda t: t.get("vel", axis="y 5"), "got 'y 5'"),
    (lambda t: t.get("vel", axis=1), "got 1"),
    (lambda t: t.triggers.set_range(0, 10, 5, axis=""), "axis must be one of"),
    (lambda t: t.triggers.set_range(0, 10, 5, axis="a"), "no A axis"),
    (lambda t: t.triggers.set_range(0, 1e200, 5), "beyond any stage's travel"),
    (lambda t: t.triggers.set_range(0, 0.0000001, 2), "below the position resolution"),
    (lambda t: t.command("!trigp x 0.0000001"), "below the position resolution"),
    (lambda t: t.command("!trigp -1 0.00000001"), "below the position resolution"),
    (lambda t: t.is_calibrated("a"), "no A axis"),
])
async def test_input_that_only_looks_valid_is_refused_before_any_byte(
        tango: Controller, monkeypatch: pytest.MonkeyPatch, call: Any, message: str) -> None:
    before = await tango.get("trigc")
    written = _watch_writes(tango, monkeypatch)
    with pytest.raises(InvalidCommandError, match=message.replace("(", r"\(")):
        await call(tango)
    assert all(item.line == "?pos" for item in written), written  # reads the resolution
    monkeypatch.undo()
    assert await tango.get("trigc") == before


async def test_trigger_range_in_both_directions_is_accepted(tango: Controller) -> None:
    # start > end triggers while moving down (manual L13529-13532).
    await tango.triggers.set_range(10, 0, 5)
    assert await tango.query("?trigr") == "10.0000 0.0000 5"


async def test_an_axis_the_two_axis_controller_lacks_is_refused() -> None:
    async with tango_aio.connect("sim://?baud=0&axes=2") as tango:
        with pytest.raises(InvalidCommandError, match="no Z axis"):
            await tango.triggers.upload_positions([1.0, 2.0], axis="z")


async def test_wait_idle_waits_for_a_move_that_was_only_scheduled(tango: Controller) -> None:
    move = asyncio.ensure_future(tango.move_to(x=5.0))
    assert await tango.is_busy()
    letters = await tango.wait_idle()
    assert move.done() and letters["x"] == "@"
    assert (await tango.position())["x"] == pytest.approx(5.0, abs=1e-3)
    assert not await tango.is_busy()


async def test_is_calibrated_reads_statuslimit() -> None:
    async with tango_aio.connect("sim://?baud=0&speed=200") as tango:
        await _is_calibrated(tango)


async def _is_calibrated(tango: Controller) -> None:
    assert not await tango.is_calibrated()
    await tango.calibrate("x")
    assert await tango.is_calibrated("x") and await tango.is_calibrated("X")
    assert not await tango.is_calibrated()  # y and z are not
    await tango.calibrate()
    assert await tango.is_calibrated()


def test_the_blocking_twins() -> None:
    with tango_aio.sync.connect("sim://?baud=0") as tango:
        future = tango.start_move_to(x=2.0)
        assert tango.is_busy()
        tango.wait_idle()
        future.result()
        assert not tango.is_busy() and not tango.is_calibrated()


@pytest.mark.parametrize("seconds", [float("nan"), -1.0, float("inf"), True])
async def test_the_fault_api_refuses_times_that_are_no_times(tango: Controller,
                                                             seconds: float) -> None:
    faults = tango_aio.testing.faults(tango)
    with pytest.raises(ValueError, match="finite number >= 0"):
        faults.delay(seconds)
    with pytest.raises(ValueError, match="finite number >= 0"):
        faults.stall(seconds)
    assert await tango.get("trigc") == 0  # nothing changed: the next call works


@pytest.mark.parametrize("url", ["sim://?latency=nan", "sim://?processing=inf",
                                 "sim://?stall=nan"])
async def test_a_sim_url_with_a_time_that_is_no_time_is_refused(url: str) -> None:
    with pytest.raises(ValueError, match="finite"):
        await tango_aio.connect(url)


def _sent_lines(tango: Controller, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every set/run line the controller executes from now on."""
    lines: list[str] = []
    real = tango._execute

    async def spy(command: Any, **kwargs: Any) -> Any:
        lines.append(command.line)
        return await real(command, **kwargs)

    monkeypatch.setattr(tango, "_execute", spy)
    return lines


async def test_velocity_and_acceleration_for_one_move(monkeypatch: pytest.MonkeyPatch
                                                      ) -> None:
    async with tango_aio.connect("sim://?baud=0&speed=50") as tango:
        before = await tango.get("vel"), await tango.get("accel")
        lines = _sent_lines(tango, monkeypatch)
        letters = await tango.move_to(x=5.0, y=1.0, velocity={"x": 2.0}, acceleration=0.5)
        assert letters["x"] == "@" and (await tango.position())["x"] == pytest.approx(5.0)
        assert lines[:3] == ["!vel x 2.0", "!accel x 0.5", "!accel y 0.5"], lines
        assert lines[-3:] == ["!accel y 1.0", "!accel x 1.0", "!vel x 10.0"], lines
        assert (await tango.get("vel"), await tango.get("accel")) == before
        # In the move's unit per second: 2 mm/s is 2 rev/s at a pitch of 1 mm.
        lines.clear()
        await tango.move_by(x=-1.0, unit="mm", velocity=2.0)
        assert lines[0] == "!vel x 2.0" and lines[-1] == "!vel x 10.0", lines


async def test_a_cancelled_move_still_restores_its_velocity(
        monkeypatch: pytest.MonkeyPatch) -> None:
    async with tango_aio.connect("sim://?baud=0") as tango:
        lines = _sent_lines(tango, monkeypatch)
        moving = asyncio.Event()
        real_move = tango._move

        async def move_and_tell(*args: Any, **kwargs: Any) -> Any:
            moving.set()  # the velocity is set, the move's line is next
            return await real_move(*args, **kwargs)

        monkeypatch.setattr(tango, "_move", move_and_tell)
        move = asyncio.ensure_future(tango.move_to(x=50.0, velocity=1.0))
        await moving.wait()
        assert await tango.get("vel", axis="x") == 1.0 and lines == ["!vel x 1.0"]
        move.cancel()
        with pytest.raises(asyncio.CancelledError):
            await move
        assert await tango.get("vel", axis="x") == 10.0


@pytest.mark.parametrize(("options", "message"), [
    ({"velocity": {"y": 2.0}}, "y is not moved by this call"),
    ({"velocity": 1000.0}, "above"),
    ({"velocity": True}, "boolean"),
    ({"acceleration": float("nan")}, "finite"),
])
async def test_a_bad_per_move_speed_is_refused_before_any_byte(
        tango: Controller, monkeypatch: pytest.MonkeyPatch, options: dict[str, Any],
        message: str) -> None:
    lines = _sent_lines(tango, monkeypatch)
    with pytest.raises(InvalidCommandError, match=message):
        await tango.move_to(x=1.0, **options)
    assert lines == []
