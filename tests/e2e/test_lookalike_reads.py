"""Look-alike reads in flight together under one fault, in every autostatus mode: each
read returns its own value (the emulator's own store) or a typed error, and the stream
comes back into step. Mode 4 used to write them back to back (its reads' optional echo
hid their numbers from the separator rule): one dropped reply, lost line or extra line
then handed every later reply to the wrong caller.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

import pytest
from helpers import Emulated, as_axes, serve_pty

from tango_aio.catalog._instructions import parse
from tango_aio.controller._connection import connect
from tango_aio.controller._controller import Controller
from tango_aio.errors import TangoError
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.wire import Emit

pytestmark = [pytest.mark.timeout(120), pytest.mark.virtual_clock]

#: Distinct values: no two reads below can answer the same text.
VALUES = {
    "vel": {"x": 95.5, "y": 96.25, "z": 97.125},
    "accel": {"x": 18.5, "y": 19.25, "z": 17.75},
}
#: The reads of the issue, all one number each.
READS = ["?accel z", "?vel y", "?accel x", "?vel z"]
#: An extra line the controller sends unasked: a number like the reads' replies, and
#: none of theirs (a read that takes it got the stray line, not another read's value).
EXTRA = "92.25"


def truth(model: ControllerModel, line: str) -> str:
    """What the emulator answers to ``line`` now (its own store and formatter)."""
    return model.params.read(parse(line, model.context()), model.axes)


async def prepare(tango: Controller) -> None:
    for name, values in VALUES.items():
        await tango.set(name, **as_axes(values))


async def round_of_reads(tango: Controller, timeout: float | None = None
                         ) -> list[str | BaseException]:
    return await asyncio.gather(*(tango.query(line, timeout=timeout) for line in READS),
                                return_exceptions=True)


def judge(model: ControllerModel, results: Sequence[str | BaseException],
          allowed: Sequence[str] = ()) -> list[str]:
    """What each read got: ``own``, ``stray`` (one of ``allowed``), a typed error's
    class, or ``MISDELIVERED: ...``."""
    verdicts = []
    for line, result in zip(READS, results, strict=True):
        if isinstance(result, TangoError):
            verdicts.append(type(result).__name__)
        elif isinstance(result, BaseException):
            raise result
        elif result == truth(model, line):
            verdicts.append("own")
        elif result in allowed:
            verdicts.append("stray")
        else:
            verdicts.append(f"MISDELIVERED: {line} -> {result}")
    return verdicts


async def assert_in_step(tango: Controller, model: ControllerModel, rounds: int = 3) -> None:
    """Later reads, with no fault, each get their own value."""
    for _ in range(rounds):
        results = await round_of_reads(tango)
        assert judge(model, results) == ["own"] * len(READS), results


@pytest.mark.parametrize("fault", ["drop", "lose_line"])
@pytest.mark.parametrize("mode", [4, 0, 1, 2, 3])
async def test_one_fault_among_lookalike_reads_hands_no_reply_over(
        mode: int, fault: str) -> None:
    """Four look-alike reads at once, the first reply dropped or the first line lost."""
    tango = await connect("sim://?baud=0", autostatus=mode)
    try:
        emu = Emulated(tango)
        await prepare(tango)
        for _ in range(3):
            if fault == "drop":
                emu.wire.faults.drop_replies = 1
            else:
                emu.wire.faults.lose_line = READS[0].encode()
            verdicts = judge(emu.model, await round_of_reads(tango, timeout=1.0))
            assert not [v for v in verdicts if v.startswith("MISDELIVERED")], verdicts
            assert verdicts[0] != "own"  # the fault hit the first read
            # (The fault really happened: the emulator used it up.)
            assert emu.wire.faults.drop_replies == 0 and not emu.wire.faults.lose_line
            await assert_in_step(tango, emu.model, rounds=1)
    finally:
        await tango.aclose()


async def _extra_line_rounds(tango: Controller, model: ControllerModel,
                             emit: Emit, rounds: int) -> None:
    """Rounds of four reads, each with one extra line sent while they are in flight
    (after 0, 1, 2... turns of the loop: at another place among the replies each time),
    then faultless rounds: none misdelivered, and the later ones all own."""
    for index in range(rounds):
        tasks = [asyncio.ensure_future(tango.query(line, timeout=2.0)) for line in READS]
        for _ in range(index % 4):
            await asyncio.sleep(0)
        emit(f"{EXTRA}\r".encode())
        results = await asyncio.gather(*tasks, return_exceptions=True)
        verdicts = judge(model, results, allowed=[EXTRA])
        assert not [v for v in verdicts if v.startswith("MISDELIVERED")], verdicts
        await assert_in_step(tango, model)


@pytest.mark.parametrize("mode", [4, 1])
async def test_an_extra_line_among_lookalike_reads_is_caught_in_process(mode: int) -> None:
    """One extra well-formed line while four look-alike reads are in flight (in-process
    emulator, no pacing): no read gets another's value, later reads are their own."""
    tango = await connect("sim://?baud=0", autostatus=mode)
    try:
        emu = Emulated(tango)
        await prepare(tango)
        await _extra_line_rounds(tango, emu.model, emu.wire.emit, rounds=4)
    finally:
        await tango.aclose()


def _model(emit: Emit) -> ControllerModel:
    return ControllerModel(emit, SimConfig())


@pytest.mark.slow
@pytest.mark.parametrize("mode", [4, 0, 1, 2, 3])
async def test_an_extra_line_among_lookalike_reads_is_caught_at_57600_baud(mode: int) -> None:
    """The same over a pty at 57600 Bd: the line arrives wherever the link's timing puts
    it among the replies."""
    async with await serve_pty(_model) as server:
        tango = await connect(server.path, autostatus=mode)
        try:
            await prepare(tango)
            model = server.wire.handler
            assert isinstance(model, ControllerModel)
            await _extra_line_rounds(tango, model, server.wire.emit, rounds=12)
        finally:
            await tango.aclose()
