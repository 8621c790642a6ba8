"""Trigger/snapshot list transfers through the write-credit limiter, end to end."""

from __future__ import annotations

import asyncio
import dataclasses
import math
import random
from collections.abc import Iterator, Sequence

import pytest
from helpers import EmulatorFactory

from tango_aio import InvalidCommandError, TangoError
from tango_aio.catalog._instructions import Command, parse
from tango_aio.families._bulk import Column, UploadError, trigger_spec
from tango_aio.sim.lists import ListError

pytestmark = pytest.mark.virtual_clock

REALTIME = "sim://?baud=57600&latency=0.002&processing=0.0005"


def ramp(count: int, start: float = 0.5, step: float = 0.0137) -> list[float]:
    return [round(start + i * step, 4) for i in range(count)]


async def test_upload_reads_back_identical_in_instant_mode(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    values = ramp(1500)
    seen: list[tuple[int, int]] = []
    await emu.tango.triggers.upload_positions(values, axis="y", progress=lambda d, n:
                                             seen.append((d, n)))
    assert await emu.tango.triggers.read_positions() == values
    assert await emu.tango.get("triga") == "y"
    assert seen[-1] == (1500, 1500) and len(seen) == math.ceil(1500 / 200)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)


@pytest.mark.parametrize("autostatus", [0, 1, 2, 3, 4])
async def test_upload_in_every_mode(emulator: EmulatorFactory, autostatus: int) -> None:
    # In modes 0, 1 and 3 the entries go as bytes (no Command each, #19); in modes 2 and
    # 4 every entry owes an acknowledgement or an echo and goes as a command.
    emu = await emulator(autostatus=autostatus)
    values = ramp(450)
    await emu.tango.triggers.upload_positions(values)
    assert await emu.tango.triggers.read_positions() == values
    rows = [[float(i), -float(i), 0.5] for i in range(1, 250)]
    await emu.tango.snapshots.upload_positions(rows)
    assert await emu.tango.snapshots.read_positions() == rows


@pytest.mark.parametrize("seed", [1, 2, 3])
async def test_random_stalls_never_lose_a_byte(emulator: EmulatorFactory, seed: int) -> None:
    """Real-time wire, slowed interpreter, random stalls during the upload: the buffer
    never overflows and the list reads back identical."""
    rng = random.Random(seed)
    emu = await emulator(REALTIME + f"&stall_every={rng.randint(50, 150)}&stall=0.03")
    values = ramp(400, step=0.011)
    upload = asyncio.create_task(emu.tango.triggers.upload_positions(values))
    while not upload.done():
        await asyncio.sleep(rng.uniform(0.05, 0.2))
        emu.wire.stall(rng.uniform(0.01, 0.08))
    await upload
    assert emu.wire.lost_bytes == 0
    assert emu.tango.protocol.credit.peak <= 255
    assert await emu.tango.triggers.read_positions() == values


async def test_blasting_without_the_limiter_does_lose_bytes(emulator: EmulatorFactory) -> None:
    """The control experiment: the same upload with the credit limit lifted overflows the
    input buffer; lost bytes garble lines and queries, and the upload fails."""
    emu = await emulator(REALTIME.replace("processing=0.0005", "processing=0.005"),
                         reply_timeout=1.0)
    emu.tango.protocol.credit.limit = 10**9
    emu.tango.protocol.credit.chunk = 10**8
    with pytest.raises(TangoError):
        await emu.tango.triggers.upload_positions(ramp(300))
    assert emu.wire.lost_bytes > 0


async def test_rejected_entry_is_reported_with_its_index(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    values = ramp(1000)
    bad = 437
    triggers = emu.model.triggers
    original = triggers.write

    def refuse(index: int, position: float, axis: str | None = None) -> None:
        if position == values[bad]:
            raise ListError(5, "refused by the test")
        original(index, position, axis)

    triggers.write = refuse  # type: ignore[method-assign]
    with pytest.raises(UploadError) as caught:
        await emu.tango.triggers.upload_positions(values)
    assert caught.value.index == bad
    assert caught.value.number == 5
    assert str(values[bad]) in caught.value.command
    assert int(await emu.tango.get("trigc")) == bad
    assert await emu.tango.triggers.read_positions() == values[:bad]
    assert emu.tango.protocol.queued == 0


async def test_cancelling_an_upload_leaves_the_driver_in_sync(emulator: EmulatorFactory) -> None:
    emu = await emulator(REALTIME)
    await emu.tango.set("vel", x=1.25, y=2.5, z=3.75)
    under_way = asyncio.Event()  # cancelled once entries are confirmed, not after a time

    def progress(done: int, total: int) -> None:
        if done >= 100:
            under_way.set()

    upload = asyncio.create_task(emu.tango.triggers.upload_positions(ramp(2000),
                                                                    progress=progress))
    await under_way.wait()
    upload.cancel()
    with pytest.raises(asyncio.CancelledError):
        await upload
    assert emu.tango.protocol.queued == 0
    assert await emu.tango.get("vel") == {"x": 1.25, "y": 2.5, "z": 3.75}
    count = int(await emu.tango.get("trigc"))
    assert 100 <= count < 2000
    for _ in range(3):  # round trips, each behind whatever might still be written
        assert int(await emu.tango.get("trigc")) == count  # nothing still trickling in
    assert await emu.tango.triggers.read_positions() == ramp(2000)[:count]


async def test_concurrent_commands_share_the_credit(emulator: EmulatorFactory) -> None:
    emu = await emulator(REALTIME + "&processing=0.002")
    upload = asyncio.create_task(emu.tango.triggers.upload_positions(ramp(300)))
    for value in (1.5, 2.5, 3.5):
        await emu.tango.set("vel", value, axis="z")
        assert await emu.tango.get("vel", axis="z") == value
    await upload
    assert emu.wire.lost_bytes == 0
    assert emu.tango.protocol.credit.peak <= 255


async def test_invalid_lists_fail_before_a_byte(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    before = emu.wire.lines_processed
    for bad in ([1.0, 2.0, 1.5], [1.0, float("nan")], [1.0, 1.0], ramp(10001)):
        with pytest.raises(InvalidCommandError):
            await emu.tango.triggers.upload_positions(bad)
    with pytest.raises(InvalidCommandError):
        await emu.tango.triggers.upload_positions([1.0], axis="q")
    with pytest.raises(InvalidCommandError):
        await emu.tango.snapshots.upload_positions([[1.0, 2.0, 3.0, 4.0]])
    assert emu.wire.lines_processed == before


async def test_trigger_range_and_snapshot_round_trip(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    await emu.tango.triggers.set_range(0.0, 10.0, 11, axis="x")
    assert await emu.tango.triggers.read_positions() == [float(i) for i in range(11)]
    rows = [[round(i * 0.5, 4), round(-i * 0.25, 4), 1.0] for i in range(300)]
    await emu.tango.snapshots.upload_positions(rows)
    assert await emu.tango.snapshots.read_positions() == rows



async def test_a_short_snapshot_row_is_an_error_and_the_list_stays(
        emulator: EmulatorFactory) -> None:
    # #14 item 4: a row with fewer values than axes was padded with 0.0 silently.
    emu = await emulator()
    rows = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    await emu.tango.snapshots.upload_positions(rows)
    before = emu.wire.lines_processed
    with pytest.raises(InvalidCommandError, match="row 1 must hold 3"):
        await emu.tango.snapshots.upload_positions([[1.0, 2.0, 3.0], [2.0]])
    assert emu.wire.lines_processed == before
    assert await emu.tango.snapshots.read_positions() == rows


async def test_a_position_below_the_resolution_is_an_error(emulator: EmulatorFactory) -> None:
    # #14 item 4: 0.00001 (resolution 0.0001 mm) read back as 0.0.
    emu = await emulator()
    await emu.tango.triggers.upload_positions([1.0, 2.0])
    with pytest.raises(InvalidCommandError, match="below the position resolution"):
        await emu.tango.triggers.upload_positions([0.00001, 1.0])
    with pytest.raises(InvalidCommandError, match="below the position resolution"):
        await emu.tango.snapshots.upload_positions([[1.0, -0.00002, 0.0]])
    assert await emu.tango.triggers.read_positions() == [1.0, 2.0]


async def test_a_bad_entry_late_in_the_list_leaves_the_list_untouched(
        emulator: EmulatorFactory) -> None:
    # #14 item 4: a value the catalog refuses at index 1000 left a cleared, half-written
    # list; every line is now built before the list is cleared.
    emu = await emulator()
    await emu.tango.triggers.upload_positions([1.0, 2.0])
    values = ramp(1200)
    values[1000:] = [1e250 * (i + 1) for i in range(200)]
    with pytest.raises(InvalidCommandError, match="entry 1000"):
        await emu.tango.triggers.upload_positions(values)
    assert await emu.tango.triggers.read_positions() == [1.0, 2.0]


@pytest.mark.parametrize("url", ["sim://?baud=0", REALTIME])
async def test_concurrent_uploads_are_serialised(emulator: EmulatorFactory, url: str) -> None:
    # #14 item 4: one call reported success while the controller held the other list (or
    # an empty one); _locate_rejection raised IndexError.
    emu = await emulator(url)
    # At the wire's speed, shorter lists (still about 8 and 5 credit windows of 255 bytes).
    size = 450 if url == "sim://?baud=0" else 150
    first, second = ramp(size), ramp(size * 2 // 3, start=100.0)
    results = await asyncio.gather(emu.tango.triggers.upload_positions(first),
                                   emu.tango.triggers.upload_positions(second),
                                   return_exceptions=True)
    assert list(results) == [None, None]
    assert await emu.tango.triggers.read_positions() == second  # the later caller's list
    rows = [[float(i), 0.0, 1.0] for i in range(1, 40)]
    await asyncio.gather(emu.tango.snapshots.upload_positions(rows),
                         emu.tango.triggers.upload_positions(first))
    assert await emu.tango.snapshots.read_positions() == rows
    assert await emu.tango.triggers.read_positions() == first


async def test_marker_errors_are_attributed_to_the_lines_they_cover(
        emulator: EmulatorFactory) -> None:
    """With a marker after every reply-less line, the one the controller refused is
    marked with the error number and the others are not."""
    emu = await emulator()
    protocol = emu.tango.protocol
    protocol.credit.chunk = 1  # a marker after every reply-less line
    await emu.tango.command("!trigp x 0")
    lines = ["!trigp -1 1.0", "!trigp -1 2.0", "!trigp -1 1.5", "!trigp -1 3.0"]
    submissions = [protocol.submit(parse(line)) for line in lines]
    await emu.tango.query("?trigc")
    assert [s.chunk_error for s in submissions] == [None, None, 5, None]
    assert await emu.tango.triggers.read_positions() == [1.0, 2.0, 3.0]


async def test_mode_2_builds_each_chunk_when_it_is_queued(emulator: EmulatorFactory) -> None:
    """In autostatus 2 the entries owe acknowledgements and go as commands: each chunk's
    are built when it is queued, not all before the clear (64 uploads in one process
    started one list-build apart, with long full garbage collections)."""
    emu = await emulator(autostatus=2)
    spec = trigger_spec()
    built: list[int] = []

    def append(rows: Sequence[Sequence[float]]) -> Iterator[Command]:
        built.append(len(rows))
        return spec.append(rows)

    counted = dataclasses.replace(spec, append=append)
    at_clear: list[int] = []

    async def clear() -> None:
        at_clear.append(sum(built))
        await emu.tango.command("!trigp x 0")

    values = ramp(450)
    await emu.tango._transfer().replace(counted, clear, Column(values), None)
    assert at_clear == [0]
    assert built == [200, 200, 50]
    assert await emu.tango.triggers.read_positions() == values
    with pytest.raises(InvalidCommandError, match="entry 300"):
        await emu.tango._transfer().replace(
            counted, clear, Column([*values[:300], math.nan, *values[301:]]), None)
    assert await emu.tango.triggers.read_positions() == values
