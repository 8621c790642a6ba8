"""#14 item 1: a stray line that looks like a reply never shifts later replies.

Replies carry no ids. A line too many that fits the waiting request's pattern (another
program writing to the port, noise that happens to look like a number) used to be taken
by that request, and its real reply by the next one, and so on for good. Now consecutive
look-alike requests are bracketed by a separator whose reply nothing else looks like: the
request the stray line reached may fail (typed) or take the stray value, but no later
request gets a wrong value.
"""

from __future__ import annotations

import asyncio
import random
from collections.abc import Callable

import pytest
from helpers import VELS, Axes, EmulatorFactory, FakeLink

from tango_aio.catalog._instructions import parse
from tango_aio.errors import RequestAbortedError, TangoError

LinkFactory = Callable[..., FakeLink]

pytestmark = [pytest.mark.timeout(60), pytest.mark.virtual_clock]

ACCELS: Axes = {"x": 1.5, "y": 2.25, "z": 3.75}
TRUTH = {("vel", a): v for a, v in VELS.items()} | {("accel", a): v for a, v in ACCELS.items()}
STRAY = 95.125


async def _trial(emulator: EmulatorFactory, separators: bool, seed: int
                 ) -> tuple[int, int, int]:
    """One connection: stray lines arrive while look-alike reads are in flight. Returns
    (wrong values after the reached request, wrong values of the reached request, typed
    failures)."""
    rng = random.Random(seed)
    # The default reply timeout where replies come; a late marker is written again.
    emu = await emulator("sim://?baud=0&processing=0.002", dead_after=10)
    tango = emu.tango
    await tango.set("vel", **VELS)
    await tango.set("accel", **ACCELS)
    tango.protocol.separators = separators
    later_wrong = reached_wrong = failed = 0
    for _ in range(6):
        keys = [rng.choice(list(TRUTH)) for _ in range(rng.randint(2, 5))]
        tango.reply_timeout = 0.5  # short: a shifted reply leaves the last one unanswered
        first = asyncio.create_task(tango.get(keys[0][0], axis=keys[0][1]))
        await asyncio.sleep(0)  # written; its reply takes 2 ms
        tango.protocol.data_received(f"{STRAY:.3f}\r".encode())  # the stray line
        rest = [asyncio.create_task(tango.get(name, axis=axis)) for name, axis in keys[1:]]
        results = await asyncio.gather(first, *rest, return_exceptions=True)
        tango.reply_timeout = 5.0
        for index, (key, result) in enumerate(zip(keys, results, strict=True)):
            if isinstance(result, BaseException):
                assert isinstance(result, TangoError), result
                failed += 1
            elif result != TRUTH[key]:
                if index == 0:
                    reached_wrong += 1
                else:
                    later_wrong += 1
        await asyncio.sleep(0.02)  # whatever was late has arrived
        # Afterwards every read is its own.
        for key in rng.sample(list(TRUTH), 3):
            if await tango.get(key[0], axis=key[1]) != TRUTH[key]:
                later_wrong += 1
    return later_wrong, reached_wrong, failed


async def test_a_stray_line_never_shifts_later_replies(emulator: EmulatorFactory) -> None:
    later = failed = 0
    for seed in range(4):
        wrong, _, typed = await _trial(emulator, True, seed)
        later += wrong
        failed += typed
    assert later == 0
    assert failed > 0  # the stray line was seen, not silently absorbed


async def test_without_separators_a_stray_line_shifts_replies(
        emulator: EmulatorFactory) -> None:
    """The same trial with the separators off (the wait rule alone): later requests get
    wrong values, so the test above can fail."""
    later = 0
    for seed in range(4):
        wrong, _, _ = await _trial(emulator, False, seed)
        later += wrong
    assert later > 0


async def test_separator_between_look_alike_reads_on_the_wire(fake_link: LinkFactory) -> None:
    """Hand-fed: ``?vel x``, separator, ``?vel y`` go out together; a stray number before
    the first reply is taken by ``?vel x``, its real reply then hits the separator, and
    ``?vel y`` fails typed instead of taking it. The separator is ``?help`` (``ERROR n,text``:
    nothing like a number)."""
    link = fake_link(separators=True)
    first = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=1.0))
    second = asyncio.create_task(link.protocol.request(parse("?vel y"), timeout=1.0))
    await link.wait_written(b"?vel y\r")
    assert link.transport.sent == b"?vel x\r?help\r?vel y\r"
    link.feed(b"95.125\r11.500\r")  # the stray, then ?vel x's own reply
    assert (await first).lines == ("95.125",)  # the request the stray line reached
    with pytest.raises(RequestAbortedError):
        await second
    link.answer_marker()  # the resync's marker
    third = asyncio.create_task(link.protocol.request(parse("?vel z"), timeout=1.0))
    await link.wait_written(b"?vel z\r")
    link.feed(b"13.125\r")
    assert (await third).lines == ("13.125",)


async def test_separator_reply_in_step_delivers_both(fake_link: LinkFactory) -> None:
    link = fake_link(separators=True)
    tasks = [asyncio.create_task(link.protocol.request(parse(line), timeout=1.0))
             for line in ("?vel x", "?vel y")]
    await link.wait_written(b"?vel y\r")
    link.feed(b"11.500\rERROR 0,no error\r12.250\r")
    assert [(await task).lines for task in tasks] == [("11.500",), ("12.250",)]


async def test_separator_choice_depends_on_the_neighbours(fake_link: LinkFactory) -> None:
    """Between two status reads the separator answers a number (``?err``); between two
    free-text reads, a marker whose reply holds a number of this session's."""
    link = fake_link(separators=True)
    for line in ("?statusaxis", "?statusaxis", "?version", "?version"):
        link.protocol.submit(parse(line))
    first, second = link.marker_codes()  # free text looks like anything
    assert link.transport.sent == (f"?statusaxis\r?err\r?statusaxis\r?help {first}\r"
                                   f"?version\r?help {second}\r?version\r").encode()
