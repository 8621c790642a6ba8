"""A garbled or unparseable verdict proves nothing about the motion line before it.

The reply that judges a motion line (the ``?err`` behind it in autostatus 0, 1, 3 and 4,
its ``OK...`` in mode 2, its echo in mode 4) is garbled on the emulated link: one bit
flipped (``0`` becomes ``1``, ``2``, ``4`` or ``8``, clean-looking refusals, or a blank,
a control byte, ``p``), or stray bytes glued onto it. Every outcome is checked against
the emulator's own state: a call that raises a refusal (a ``ControllerError``) moved
nothing; a call that raises anything else leaves no axis of its line moving unless its
error says so ("axes X may still move"); a call that returns did its work.
"""

from __future__ import annotations

import random
import re
from collections.abc import Awaitable, Callable, Collection, Iterable
from typing import Any

import pytest
from helpers import settled_position

import tango_aio
from tango_aio import (
    Controller,
    ControllerError,
    MoveOutcomeUnknown,
    MoveProtocolUnknownError,
    NotExecutableError,
    OutOfRangeError,
    TangoError,
)
from tango_aio.testing import Faults, faults

pytestmark = pytest.mark.virtual_clock

#: Autostatus modes in which an ``?err`` probe follows a motion line (mode 2 acknowledges
#: it instead).
ERR_MODES = [0, 1, 3, 4]
#: Bits a flip of the ``?err`` reply ``0`` may touch (low 7, as the emulator's garbler).
BITS = range(7)


def sample(values: Iterable[Any], default: Collection[Any]) -> list[Any]:
    """``values``, those outside ``default`` run only in the slow tier."""
    return [value if value in default else
            pytest.param(*(value if isinstance(value, tuple) else (value,)),
                         marks=pytest.mark.slow)
            for value in values]


def flip(bit: int) -> Callable[[bytes, random.Random], bytes]:
    """A garbler flipping ``bit`` of the reply's first byte."""
    def garbler(data: bytes, rng: random.Random) -> bytes:
        return bytes([data[0] ^ (1 << bit)]) + data[1:]
    return garbler


def target(fault: Faults, prefix: str, garbler: Callable[[bytes, random.Random], bytes]
           ) -> None:
    """Garble the first reply to the next line that starts with ``prefix``."""
    fault.wire.faults.garble_reply_to = (prefix.encode("ascii"), garbler)


def moving(fault: Faults, axis: str) -> bool:
    return fault.model.motion.is_moving(axis) or fault.axes()[axis][1] != 0.0


async def honest(call: Awaitable[Any], fault: Faults, axis: str = "x"
                 ) -> TangoError | None:
    """Run ``call``; check its outcome against the emulator (see the module doc) and
    return what it raised (``None``: it returned)."""
    start = fault.axes()[axis][0]
    try:
        await call
    except TangoError as exc:
        error = exc
    else:
        return None
    text = str(error)
    name = axis.upper()
    if isinstance(error, ControllerError):
        assert not moving(fault, axis), f"refused, yet {name} moves: {text}"
        assert fault.axes()[axis][0] == pytest.approx(start, abs=1e-6), \
            f"refused, yet {name} moved: {text}"
    elif moving(fault, axis):
        assert re.search(rf"axes [A-Z ]*{name}[A-Z ]* may still move", text), \
            f"{name} still moves, and the error does not say so: {text}"
    if re.search(rf"axes [A-Z ]*{name}[A-Z ]* stopped", text):
        assert not moving(fault, axis), text
    return error


def motion_call(tango: Controller, call: str) -> Awaitable[Any]:
    if call == "move_to":
        return tango.move_to(x=-16)
    if call == "move_by":
        return tango.move_by(x=-16)
    if call == "go":
        return tango.go(x=-16)
    if call == "calibrate":
        return tango.calibrate("x")
    return tango.command("!moa -16")


async def opened(mode: int, url: str = "sim://?baud=0") -> Controller:
    return await tango_aio.connect(url, autostatus=mode, reply_timeout=2.0)


@pytest.mark.parametrize("call", ["move_to", "command"])
@pytest.mark.parametrize("bit", sample(BITS, {1, 6}))  # 0 -> 2 (clean), 0 -> p
@pytest.mark.parametrize("mode", ERR_MODES)
async def test_one_bit_flipped_in_the_err_after_a_move_line(mode: int, bit: int,
                                                            call: str) -> None:
    """The issue's case: ``move_to(x=-16)`` raised ``NotExecutableError`` while X ran on
    (the ``0`` read as ``2``). Every flip now raises, and X stands or the error says
    that it may still move; none is taken for a refusal."""
    async with await opened(mode) as tango:
        fault = faults(tango)
        target(fault, "?err", flip(bit))
        error = await honest(motion_call(tango, call), fault)
        assert isinstance(error, MoveOutcomeUnknown), error
        assert fault.wire.faults.garble_reply_to is None  # the ?err reply was garbled
        # The link is in step: the next move works.
        await tango.move_to(x=0.5)
        assert fault.axes()["x"][0] == pytest.approx(0.5, abs=1e-3)


@pytest.mark.parametrize("call", ["move_by", "go", "calibrate"])
async def test_a_clean_looking_refusal_of_other_motion_lines_is_checked(call: str
                                                                        ) -> None:
    async with await opened(1) as tango:
        fault = faults(tango)
        target(fault, "?err", flip(1))  # 0 -> 2
        error = await honest(motion_call(tango, call), fault)
        assert isinstance(error, MoveProtocolUnknownError), error
        assert "X moving" in str(error) and "axes X stopped" in str(error)


@pytest.mark.parametrize(("stray", "before"), sample([
    (b"7", True),    # 70: a documented number (the line's own? ?err asked again says so)
    (b"7", False),   # 07: not a clean number
    (b"0", False),   # 00: not a clean number
    (b"9", True),    # 90: undocumented
    (b"\x15", True),  # not a number at all: the reply does not fit, a resync
    (b"x", False),
], {(b"7", True), (b"7", False)}))
@pytest.mark.parametrize("mode", ERR_MODES)
async def test_stray_bytes_glued_onto_the_err_after_speed(mode: int, stray: bytes,
                                                          before: bool) -> None:
    """The issue's case: ``speed()`` raised ``UnknownControllerError`` while the axis
    kept turning."""
    async with await opened(mode) as tango:
        fault = faults(tango)
        fault.glue(stray, reply_to="?err", before=before)
        error = await honest(tango.speed(x=2), fault)
        if error is None:
            assert moving(fault, "x")  # accepted, and it turns
        else:
            assert not isinstance(error, ControllerError), error
        await tango.speed(x=0)
        await tango.wait_idle(timeout=30.0)


@pytest.mark.parametrize("call", ["move_to", "command"])
@pytest.mark.parametrize("bit", sample(BITS, {1}))
async def test_the_deferred_err_verdict_of_mode_2(bit: int, call: str) -> None:
    """Mode 2 with the move's ``OK...`` sent only with its report (switch
    ``move_ok=completion``): the ``?err`` behind the move is its verdict."""
    async with await opened(2, "sim://?baud=0&move_ok=completion") as tango:
        fault = faults(tango)
        target(fault, "?err", flip(bit))
        assert isinstance(await honest(motion_call(tango, call), fault), TangoError)


@pytest.mark.parametrize("call", ["move_to", "command"])
@pytest.mark.parametrize("bit", sample(BITS, {1}))  # OK... -> MK..., !moa -> #moa
@pytest.mark.parametrize(("mode", "prefix"), [(2, "!moa"), (4, "!moa")])
async def test_a_garbled_acknowledgement_or_echo(mode: int, prefix: str, bit: int,
                                                 call: str) -> None:
    """Mode 2's ``OK...`` or mode 4's echo of the move line, one bit flipped: a call
    that raises leaves X standing or says that it may still move (a raw ``command()``
    used to leave it running with "may have executed" alone)."""
    async with await opened(mode) as tango:
        fault = faults(tango)
        target(fault, prefix, flip(bit))
        await honest(motion_call(tango, call), fault)


async def test_a_real_refusal_stays_a_typed_refusal() -> None:
    """A target outside the software limits: refused (error 5) with nothing moving; the
    state read behind the refusal confirms it."""
    async with await opened(1) as tango:
        fault = faults(tango)
        await tango.command("!lim x -1 1")
        assert isinstance(await honest(tango.move_to(x=5), fault), OutOfRangeError)
        assert isinstance(await honest(tango.command("!moa 5"), fault), OutOfRangeError)


async def test_a_refusal_on_an_axis_busy_with_this_drivers_motion_stands() -> None:
    """X runs a raw move of this driver (nobody follows it): ``speed(x=1)`` refused
    because X is busy is a refusal, and the move goes on."""
    async with await opened(1) as tango:
        fault = faults(tango)
        await tango.command("!moa -16")
        with pytest.raises(NotExecutableError, match="X still moving as before the line"):
            await tango.speed(x=1)
        assert moving(fault, "x")
        await tango.stop()
        # Once a status read shows X standing, its motion would contradict a refusal.
        assert tango._turning == set()


async def test_a_garbled_refusal_with_nothing_moving_says_the_fate_is_unknown() -> None:
    """``5`` with a byte glued on (``57``, undocumented): the line's fate is unknown,
    and nothing of it moves."""
    async with await opened(1) as tango:
        fault = faults(tango)
        await tango.command("!lim x -1 1")
        fault.glue(b"7", reply_to="?err")
        error = await honest(tango.move_to(x=5), fault)
        assert isinstance(error, MoveProtocolUnknownError), error
        assert "'57'" in str(error) and "fate is unknown" in str(error)
        assert "X standing" in str(error)


async def test_the_public_garble_targets_the_err_reply() -> None:
    """``Faults.garble(reply_to=...)``: one bit of that reply flips (seeded)."""
    async with await opened(1) as tango:
        fault = faults(tango)
        fault.garble(reply_to="?err")
        error = await honest(tango.move_to(x=-16), fault)
        assert isinstance(error, MoveOutcomeUnknown), error
        with pytest.raises(ValueError, match="reply_to"):
            fault.garble(reply_to="")
        with pytest.raises(ValueError, match="byte"):
            fault.glue(b"", reply_to="?err")


async def test_a_short_move_that_ended_before_the_state_read_still_contests() -> None:
    """The ``?err`` reply ``2`` (a flipped ``0``) comes late, after a short move has
    ended: nothing reads ``M`` any more, but X stands elsewhere than before the line."""
    async with await opened(0) as tango:
        fault = faults(tango)
        await tango.move_to(x=0.0)  # the driver knows where X stands
        target(fault, "?err", flip(1))
        fault.delay(0.5)  # the ?err reply (mode 0 sends no report)
        error = await honest(tango.move_to(x=0.05), fault)
        assert isinstance(error, MoveProtocolUnknownError), error
        assert "X moved since before the line" in str(error)
        assert await settled_position(fault) == pytest.approx(0.05, abs=1e-3)
