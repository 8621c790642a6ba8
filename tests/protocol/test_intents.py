"""The intent API of :class:`TangoProtocol` (what the Controller asks for), against the
emulator: query, checked execute, moves with their check and report, stops, the mode."""

from __future__ import annotations

import asyncio

import pytest
from helpers import INSTANT

from tango_aio import connect
from tango_aio.catalog._instructions import parse
from tango_aio.errors import ControllerError, OutOfRangeError
from tango_aio.link._protocol import TangoProtocol

pytestmark = pytest.mark.timeout(30)


async def test_query_and_checked_execute() -> None:
    async with connect(INSTANT) as tango:
        link = tango.protocol
        await link.execute(parse("!vel x 12.5"), timeout=2.0)
        assert (await link.query(parse("?vel x"), timeout=2.0)).lines == ("12.500",)
        with pytest.raises(OutOfRangeError):
            await link.execute(parse("!lim x 5 1"), timeout=2.0)
        # Unchecked: the error stays in ?err, nothing is raised.
        await link.execute(parse("!lim x 5 1"), timeout=2.0, check=False)
        assert (await link.query(parse("?err"), timeout=2.0)).lines == ("5",)


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
async def test_move_handle_confirms_and_reports(mode: int) -> None:
    async with connect(INSTANT, autostatus=mode) as tango:
        link = tango.protocol
        assert link.autostatus == mode
        handle = link.start_move(parse("!moa x 0.01"))
        await handle.confirm(2.0)
        assert handle.expects_report == (mode != 0)
        if handle.expects_report:
            report = await handle.report()
            assert report.tag is not None
            assert (handle.reported_letters is None) == (mode == 3)
        await link.execute(parse("!lim x -1 1"), timeout=2.0)
        refused = link.start_move(parse("!moa x 5"))
        with pytest.raises(ControllerError):
            await refused.confirm(2.0)
        assert link.moves_awaiting == ()


async def test_stop_axes_hard_keeps_the_mode_known() -> None:
    async with connect(INSTANT, autostatus=2) as tango:
        link = tango.protocol
        link.start_move(parse("!moa x 5"))
        await link.stop_hard(timeout=2.0)
        assert link.autostatus == 2
        assert await link.read_autostatus(timeout=2.0) == 2
        await link.stop_soft()
        letters = await tango.wait_idle(timeout=5.0)
        assert "M" not in letters.values()


class _DuckTransport(asyncio.BaseTransport):
    """Like uvloop's TCP transport: it writes, but is no asyncio.WriteTransport (#19)."""

    def __init__(self) -> None:
        super().__init__()
        self.sent = bytearray()

    def write(self, data: bytes) -> None:
        self.sent += data

    def is_closing(self) -> bool:
        return False

    def close(self) -> None:
        pass


async def test_a_transport_that_is_no_write_transport_subclass_works() -> None:
    protocol = TangoProtocol(separators=False)
    transport = _DuckTransport()
    assert not isinstance(transport, asyncio.WriteTransport)
    protocol.connection_made(transport)
    task = asyncio.create_task(protocol.query(parse("?vel x"), timeout=1.0))
    await asyncio.sleep(0)
    assert bytes(transport.sent) == b"?vel x\r"
    protocol.data_received(b"11.500\r")
    assert (await task).lines == ("11.500",)
