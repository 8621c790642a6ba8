"""#13 section 3 at the protocol level: resync, mode changes, echoes and acknowledgements
hold on every firmware variant of the emulator (tango_aio.sim.profiles).

The protocol is driven through its intents directly (no Controller), so that what the
Controller does on top (identity, settings) does not hide a protocol failure; the
emulator's own state is the truth.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable

import pytest

from tango_aio.catalog._instructions import parse
from tango_aio.controller import _connection
from tango_aio.errors import ControllerError
from tango_aio.link._protocol import TangoProtocol
from tango_aio.link._reconnect import Closer
from tango_aio.sim.model import ControllerModel
from tango_aio.sim.wire import Wire

pytestmark = [pytest.mark.timeout(60), pytest.mark.virtual_clock]

#: (switches, what ?help N detection must find).
VARIANTS = [
    ("", "yes"),
    ("profile=legacy", "none"),
    ("instruction_set=older", "none"),
    ("help_number=no", "no"),
    ("echo=after", "yes"),
    ("echo_all=yes", "yes"),
    ("echo_text=normalized", "yes"),
    ("ack_reads=before", "yes"),
    ("ack_reads=after", "yes"),
    ("err_number=no", "yes"),
    ("ack_mode_change=old", "yes"),
    ("line_end=crlf", "yes"),
    ("profile=legacy&ack_reads=after&echo=after&line_end=crlf", "none"),
]


class Link:
    def __init__(self, protocol: TangoProtocol, closer: Closer | None) -> None:
        self.protocol = protocol
        self.closer = closer

    @property
    def model(self) -> ControllerModel:
        transport = self.protocol.transport
        assert transport is not None
        wire = transport.get_extra_info("wire")
        assert isinstance(wire, Wire) and isinstance(wire.handler, ControllerModel)
        return wire.handler

    async def query(self, line: str) -> tuple[str, ...]:
        return (await self.protocol.query(parse(line), timeout=5.0)).lines


#: The ``open_link`` fixture: ``await open_link("echo=after")``.
LinkOpener = Callable[[str], Awaitable[Link]]


@pytest.fixture
async def open_link() -> AsyncIterator[LinkOpener]:
    opened: list[Link] = []

    async def make(switches: str) -> Link:
        url = f"sim://?baud=0&{switches}" if switches else "sim://?baud=0"
        protocol, closer = await _connection.open_link(
            url, lambda: TangoProtocol(detect=True, reply_timeout=5.0), {})
        link = Link(protocol, closer)
        opened.append(link)
        return link

    yield make
    for link in opened:
        link.protocol.close()
        if link.closer is not None:
            await link.closer()


@pytest.mark.parametrize(("switches", "help_number"), VARIANTS)
async def test_detect_resync_and_mode_barrier_on_every_variant(
        open_link: LinkOpener, switches: str, help_number: str) -> None:
    link = await open_link(switches)
    protocol = link.protocol
    await protocol.resync(timeout=5.0)  # the first one detects
    assert protocol.detected["help_number"] == help_number
    assert await protocol.read_autostatus(timeout=5.0) == link.model.autostatus == 1
    for mode in (4, 2, 0, 3, 4, 1, 2, 4, 2, 1):
        await protocol.execute(parse(f"!autostatus {mode}"), timeout=5.0)
        # The driver knows the mode for certain, and it is the controller's.
        assert protocol.autostatus == link.model.autostatus == mode
        await protocol.execute(parse("!vel x 11.50"), timeout=5.0)
        assert await link.query("?vel x") in (("11.500",), ("+11.500",))
        with pytest.raises(ControllerError):
            await protocol.execute(parse("!lim x 5 1"), timeout=5.0)
        await protocol.resync(timeout=5.0)  # whether ?help repeats its number or not
        assert await link.query("?vel x") in (("11.500",), ("+11.500",))
        assert protocol.core.pending_tags == []
    if "ack_reads=after" in switches:
        assert protocol.detected["ack_reads"] == "after"


@pytest.mark.parametrize("switches", ["", "help_number=no", "profile=legacy"])
async def test_each_session_starts_at_another_marker(open_link, switches: str  # type: ignore[no-untyped-def]
                                                     ) -> None:
    codes = set()
    for _ in range(12):
        link = await open_link(switches)
        await link.protocol.resync(timeout=5.0)
        codes.add(link.protocol.core.pick_marker_code())
    assert len(codes) > 1


async def test_a_restart_behind_the_adapter_is_noticed_and_the_mode_restored(
        open_link: LinkOpener) -> None:
    link = await open_link("ack_reads=after")
    protocol = link.protocol
    await protocol.resync(timeout=5.0)
    await protocol.execute(parse("!autostatus 2"), timeout=5.0)
    link.model.reboot()  # back at power-on mode 1; the link stays up
    assert await protocol.verify_autostatus(timeout=5.0)
    assert link.model.autostatus == 2 == protocol.autostatus
    await protocol.execute(parse("!vel x 12.25"), timeout=5.0)
    assert await link.query("?vel x") == ("12.250",)
