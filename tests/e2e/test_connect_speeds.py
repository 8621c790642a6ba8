"""Connect works at every baud rate the TANGO offers and through slow links, on every
firmware profile and into every autostatus mode (issue 32 item 5): every wait at connect
scales with the link (:mod:`tango_aio.sansio._linktiming`), 0 failures, 0 misrouted replies.

The emulator paces both directions at its ``baud`` (8N2, 11 bits per byte) and adds its
``latency`` to every reply byte (:mod:`tango_aio.sim.wire`): a slow adapter or a terminal
server. The driver is not told either (``sim://`` has no baud rate of its own): it
measures the link."""

from __future__ import annotations

import pytest

import tango_aio
from tango_aio.sansio._linktiming import BITS_PER_BYTE, LinkTiming, quiet_interval
from tango_aio.sim.profiles import PROFILES

pytestmark = [pytest.mark.timeout(600), pytest.mark.virtual_clock]

#: The rates ``!baud`` offers (L1624-1669), as the issue lists them.
BAUDS = (1200, 4800, 9600, 19200, 57600, 115200)
#: Reply latencies of slow links, seconds per byte.
LATENCIES = (0.002, 0.01, 0.03, 0.1)
#: Connects per combination in the slow sweep.
REPEATS = 20


async def _connect_and_check(url: str, autostatus: int) -> None:
    """Connect into ``autostatus`` and check that every reply went where it belongs: the
    identity, the mode and a position read are the emulator's."""
    async with tango_aio.connect(url, autostatus=autostatus) as tango:
        assert tango.autostatus == autostatus
        assert tango.identity.model == "TANGO-DT" and tango.identity.axes == 3
        assert set(await tango.position()) == {"x", "y", "z"}
        assert await tango.get("autostatus") == autostatus


# -- the default tier: a sample that failed before the link's timing was measured

@pytest.mark.parametrize(("profile", "baud", "autostatus"),
                         [("manual", 4800, 2), ("legacy", 4800, 4), ("manual", 9600, 4)])
async def test_connect_at_a_low_baud_rate(profile: str, baud: int, autostatus: int) -> None:
    await _connect_and_check(f"sim://?profile={profile}&baud={baud}", autostatus)


async def test_connect_through_a_slow_link() -> None:
    await _connect_and_check("sim://?profile=legacy&baud=57600&latency=0.03", 2)


# -- the slow tier: the whole sweep, 20 times each

@pytest.mark.slow
@pytest.mark.parametrize("baud", BAUDS)
@pytest.mark.parametrize("profile", sorted(PROFILES))
async def test_connect_at_every_baud_rate_twenty_times(profile: str, baud: int) -> None:
    for attempt in range(REPEATS):
        await _connect_and_check(f"sim://?profile={profile}&baud={baud}", attempt % 5)


@pytest.mark.slow
@pytest.mark.parametrize("latency", LATENCIES)
@pytest.mark.parametrize("profile", sorted(PROFILES))
async def test_connect_through_slow_links_twenty_times(profile: str, latency: float) -> None:
    for attempt in range(REPEATS):
        url = f"sim://?profile={profile}&baud=9600&latency={latency}"
        await _connect_and_check(url, attempt % 5)


# -- the rule itself (sans-IO)

def test_the_quiet_interval_spans_forty_byte_times_and_three_round_trips() -> None:
    assert quiet_interval(0.0, 0.0) == 0.05  # a fast link: as before
    at_1200 = BITS_PER_BYTE / 1200
    assert quiet_interval(at_1200, 0.0) == pytest.approx(40 * at_1200)
    assert quiet_interval(0.0, 0.1) == pytest.approx(0.3)
    assert quiet_interval(0.0, 10.0) == 2.0  # a busy controller's round trip is capped
    with pytest.raises(ValueError):
        quiet_interval(-1.0, 0.0)


def test_link_timing_only_grows_with_longer_round_trips() -> None:
    link = LinkTiming()
    assert not link.observe(0.001)  # still the floor
    assert link.observe(0.1) and link.quiet_interval == pytest.approx(0.3)
    assert not link.observe(0.05) and link.round_trip == 0.1
    assert not link.observe(float("nan"))
