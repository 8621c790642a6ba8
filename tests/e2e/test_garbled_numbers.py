"""A garbled number reply is refused by its shape, never handed to ``float()``.

One bit flipped in a ``?pos`` reply turns a decimal point into a comma (``.`` is 0x2E,
``,`` 0x2C): ``0,0000 0.0000 0.0000``. The only commas the controller prints end a value
(``?lim`` in extmode 0, manual L4619), so the line is no position reply: the read fails
with a :class:`~tango_aio.errors.ProtocolError` and the stream is resynchronised, and
nothing of it is remembered for the next move.
"""

from __future__ import annotations

import random

import pytest

import tango_aio
from tango_aio import ProtocolError
from tango_aio.testing import faults

pytestmark = pytest.mark.virtual_clock


def point_to_comma(data: bytes, rng: random.Random) -> bytes:
    """The first decimal point of the reply becomes a comma (one bit)."""
    return data.replace(b".", b",", 1)


@pytest.mark.parametrize(("mode", "read"), [
    *((mode, "move") for mode in range(5)),  # the start read of a move
    (1, "get"), (4, "get"),
])
async def test_a_comma_in_a_position_reply_is_a_protocol_error(mode: int, read: str
                                                               ) -> None:
    async with await tango_aio.connect("sim://?baud=0", autostatus=mode,
                                       reply_timeout=2.0) as tango:
        fault = faults(tango)
        fault.wire.faults.garble_reply_to = (b"?pos", point_to_comma)
        with pytest.raises(ProtocolError):
            await (tango.move_to(x=0.5) if read == "move" else tango.get("pos"))
        assert fault.wire.faults.garble_reply_to is None  # the ?pos reply was garbled
        assert fault.axes()["x"] == (0.0, 0.0)  # nothing moved
        assert await tango.get("pos", axis="x") == 0.0
        # Nothing garbled was remembered: the next moves start from true positions.
        await tango.move_to(x=0.5)
        assert fault.axes()["x"][0] == pytest.approx(0.5, abs=1e-3)
        await tango.move_by(x=0.25)
        assert fault.axes()["x"][0] == pytest.approx(0.75, abs=1e-3)
