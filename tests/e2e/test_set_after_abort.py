"""A set line in flight when a resync aborts it: its answer went with the stream, and the
line may have run. Its read-back, written once the stream is in step, decides: the value
held, the call returns; another value, the abort stands (never a false success).

The resync here follows a read whose reply went astray (lost, or garbled) while the set
was in flight behind it: in autostatus 2 the set's ``OK...`` then lands where the read's
number is owed (the mode-2 soak met it behind the settings read again after a restart).
"""

from __future__ import annotations

import asyncio
import random

import pytest

from tango_aio import connect
from tango_aio.errors import ProtocolError, RequestAbortedError
from tango_aio.testing import faults

pytestmark = pytest.mark.virtual_clock


async def test_a_set_aborted_by_a_resync_returns_when_its_read_back_shows_the_value(
        ) -> None:
    tango = await connect("sim://?baud=0&seed=1", autostatus=2, reply_timeout=3.0)
    try:
        wire = faults(tango).wire
        wire.faults.drop_replies = 1  # the number '?vel x' owes
        read = asyncio.ensure_future(tango.query("?vel x"))
        await asyncio.sleep(0)  # written first: the set goes behind it
        await tango.set("vel", 12.5, axis="y")
        with pytest.raises(ProtocolError):
            await read
        assert wire.dropped_replies == 1
        assert await tango.get("vel", axis="y") == pytest.approx(12.5)
    finally:
        await tango.aclose()


async def test_a_set_aborted_by_a_resync_still_fails_when_it_did_not_run() -> None:
    tango = await connect("sim://?baud=0&seed=1", autostatus=2, reply_timeout=3.0)
    try:
        before = await tango.get("vel", axis="y")
        wire = faults(tango).wire
        wire.faults.lose_line = b"!vel"  # the set never reaches the controller

        def junk(data: bytes, _rng: random.Random) -> bytes:
            return b"#%" + data

        wire.faults.garble_reply_to = (b"?vel x", junk)
        read = asyncio.ensure_future(tango.query("?vel x"))
        await asyncio.sleep(0)  # written first: the set goes behind it
        with pytest.raises(RequestAbortedError):
            await tango.set("vel", 12.5, axis="y")
        with pytest.raises(ProtocolError):
            await read
        assert await tango.get("vel", axis="y") == pytest.approx(before)
    finally:
        await tango.aclose()
