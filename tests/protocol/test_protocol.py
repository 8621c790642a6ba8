"""Tier 2: :class:`TangoProtocol` (and :class:`Controller` input checks) on a fake transport.

No emulator: the fake transport records what the protocol writes, and each test feeds the
controller's bytes by hand, split at arbitrary points, byte by byte, delayed, interleaved
with completion reports and unsolicited lines.
"""

from __future__ import annotations

import asyncio
import logging
import random
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from helpers import FakeLink, done_within_ticks

import tango_aio.link._protocol as protocol_module
from tango_aio.catalog._instructions import parse
from tango_aio.controller._controller import Controller
from tango_aio.errors import (
    CommandRejectedError,
    ConnectionLostError,
    ControllerError,
    ControllerTimeoutError,
    InvalidCommandError,
    OutOfRangeError,
    ProtocolError,
    RequestAbortedError,
    UnknownControllerError,
)
from tango_aio.link._protocol import Submission
from tango_aio.sansio._core import AckReads, Completed, Dropped, Unsolicited

pytestmark = pytest.mark.timeout(30)

LinkFactory = Callable[..., FakeLink]
XYZ = {"x": "@", "y": "@", "z": "@"}


def reply_of(submission: Submission) -> tuple[str, ...]:
    """The data lines of a resolved request."""
    assert submission.reply is not None and submission.reply.done()
    return submission.reply.result().lines


# --------------------------------------------------------------------------------------
# Reassembly and routing


async def test_reply_fed_byte_by_byte_with_delays(fake_link: LinkFactory) -> None:
    link = fake_link()
    task = asyncio.create_task(link.protocol.request(parse("?pos"), timeout=2.0))
    await link.wait_written(b"?pos\r")
    assert link.transport.writes == [b"?pos\r"]
    await link.feed_bytewise(b"1.0000 2.0000 3.0000\r", delay=0.001)
    assert (await task).lines == ("1.0000 2.0000 3.0000",)


async def test_pipelined_replies_in_one_chunk_each_reach_their_request(
        fake_link: LinkFactory) -> None:
    link = fake_link()
    # Replies of different shapes (number, status letters, number) are pipelined.
    subs = [link.protocol.submit(parse(line)) for line in ("?vel x", "?statusaxis", "?err")]
    assert link.transport.sent == b"?vel x\r?statusaxis\r?err\r"
    link.feed(b"11.500\r@@@-.-\r0\r")
    assert [reply_of(s) for s in subs] == [("11.500",), ("@@@-.-",), ("0",)]


async def test_look_alike_replies_are_never_in_flight_together(
        fake_link: LinkFactory) -> None:
    """``?vel x`` and ``?vel y`` both answer one number: the second is written only when
    the first has its reply, so a lost reply can never shift them (tango_aio.sansio._patterns)."""
    link = fake_link()
    first, second = (link.protocol.submit(parse(line)) for line in ("?vel x", "?vel y"))
    assert link.transport.sent == b"?vel x\r"
    link.feed(b"11.500\r")
    assert link.transport.sent == b"?vel x\r?vel y\r"
    link.feed(b"12.250\r")
    assert [reply_of(s) for s in (first, second)] == [("11.500",), ("12.250",)]


async def test_lines_of_one_batch_are_pipelined_even_when_alike(
        fake_link: LinkFactory) -> None:
    link = fake_link()
    batch = object()
    subs = [link.protocol.submit(parse(line), batch=batch) for line in ("?vel x", "?vel y")]
    assert link.transport.sent == b"?vel x\r?vel y\r"
    link.feed(b"11.500\r12.250\r")
    assert [reply_of(s) for s in subs] == [("11.500",), ("12.250",)]


async def test_reply_of_the_wrong_shape_fails_and_resyncs(fake_link: LinkFactory) -> None:
    """A line that cannot be the reply (a garbled completion report while a read waits)
    fails that read with ProtocolError, the stream resyncs, later reads get their own."""
    link = fake_link()
    read = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=2.0))
    await link.wait_written(b"?vel x\r")
    link.feed(b"@@@-/\r")
    with pytest.raises(ProtocolError, match="cannot be the reply"):
        await read
    assert link.sent_lines()[-1].startswith(b"?help ")
    link.feed(b"11.500\r")  # the real reply, late: dropped
    link.answer_marker()
    assert (Dropped("11.500"), None) in link.events
    pos = link.protocol.submit(parse("?pos x"))
    link.feed(b"1.0000\r")
    assert reply_of(pos) == ("1.0000",)


STREAM = b"11.500 12.250 13.125\r@@@-.\r@@@-.-\r1.0000 2.0000 3.0000\r"


def _check_stream_results(vel: Submission, move: Submission, status: Submission,
                          pos: Submission) -> None:
    assert reply_of(vel) == ("11.500 12.250 13.125",)
    assert move.reply is None and move.completion is not None
    assert move.completion.result().letters == XYZ
    assert reply_of(status) == ("@@@-.-",)
    assert reply_of(pos) == ("1.0000 2.0000 3.0000",)


def _submit_stream_requests(link: FakeLink) -> tuple[Submission, ...]:
    return tuple(link.protocol.submit(parse(line))
                 for line in ("?vel", "!moa 1 2 3", "?statusaxis", "?pos"))


async def test_stream_split_at_every_point(fake_link: LinkFactory) -> None:
    for cut in range(len(STREAM) + 1):
        link = fake_link()
        subs = _submit_stream_requests(link)
        link.feed(STREAM[:cut])
        link.feed(STREAM[cut:])
        _check_stream_results(*subs)


async def test_stream_split_at_random_points_with_delays(fake_link: LinkFactory) -> None:
    rng = random.Random(1)
    for _ in range(100):
        link = fake_link()
        subs = _submit_stream_requests(link)
        cuts = sorted(rng.sample(range(1, len(STREAM)), rng.randint(1, 8)))
        for start, end in zip([0, *cuts], [*cuts, len(STREAM)], strict=True):
            link.feed(STREAM[start:end])
            if rng.random() < 0.3:
                await asyncio.sleep(0)
        _check_stream_results(*subs)


@pytest.mark.parametrize("position", [0, 1, 2, 3])
async def test_completion_report_between_any_two_replies(fake_link: LinkFactory,
                                                        position: int) -> None:
    link = fake_link()
    move = link.protocol.submit(parse("!moa 1 2 3"))
    subs = [link.protocol.submit(parse(line)) for line in ("?err", "?vel x", "?pos x")]
    replies = [b"0\r", b"11.500\r", b"1.0000\r"]
    replies.insert(position, b"@@E-.\r")
    await link.feed_bytewise(b"".join(replies))
    assert move.completion is not None
    assert move.completion.result().letters == {"x": "@", "y": "@", "z": "E"}
    assert [reply_of(s) for s in subs] == [("0",), ("11.500",), ("1.0000",)]
    completed = [event for event, _ in link.events if isinstance(event, Completed)]
    assert [event.tag for event in completed] == [move.tag]


async def test_delayed_completion_resolves_the_move(fake_link: LinkFactory) -> None:
    link = fake_link()
    move = link.protocol.submit(parse("moa x 5"))
    assert move.completion is not None
    waiter = asyncio.ensure_future(move.completion)
    await asyncio.sleep(0.02)
    assert not waiter.done()
    await link.feed_bytewise(b"@@@-.\r", delay=0.002)
    assert (await waiter).letters == XYZ


async def test_unsolicited_lines_go_to_the_event_callback(fake_link: LinkFactory) -> None:
    link = fake_link()
    link.feed(b"hello\r@@@-.\r")
    sub = link.protocol.submit(parse("?vel x"))
    link.feed(b"10.000\r")
    assert reply_of(sub) == ("10.000",)
    kinds = [(type(event).__name__, submission) for event, submission in link.events]
    assert kinds == [("Unsolicited", None), ("Completed", None)]
    assert link.events[0][0] == Unsolicited("hello")
    completed = link.events[1][0]
    assert isinstance(completed, Completed) and completed.tag is None


async def test_over_long_line_is_logged_and_the_stream_recovers(
        fake_link: LinkFactory, caplog: pytest.LogCaptureFixture) -> None:
    link = fake_link()
    sub = link.protocol.submit(parse("?vel x"))
    with caplog.at_level(logging.WARNING, logger="tango_aio.link._protocol"):
        link.feed(b"x" * 3000)
        link.feed(b"\r10.000\r")
    assert reply_of(sub) == ("10.000",)
    assert any("exceeds" in record.getMessage() for record in caplog.records)


async def test_a_separator_behind_reads_goes_in_their_write(fake_link: LinkFactory) -> None:
    link = fake_link(separators=True)
    status, pos = link.protocol.submit_together((parse("?statusaxis"), parse("?pos")),
                                                separate_after=True)
    assert link.transport.writes == [b"?statusaxis\r?pos\r?help\r"]
    link.feed(b"@@@-.-\r1.0 2.0 3.0\rERROR 0,no error\r")
    assert reply_of(status) == ("@@@-.-",) and reply_of(pos) == ("1.0 2.0 3.0",)
    # The next number read needs no separator of its own.
    err = link.protocol.submit(parse("?err"))
    assert link.transport.writes[-1] == b"?err\r"
    link.feed(b"0\r")
    assert reply_of(err) == ("0",)


async def test_list_lines_as_bytes_are_checked_for_framing(fake_link: LinkFactory) -> None:
    link = fake_link()
    template = parse("!trigp -1 1.0")
    run = link.protocol.pack_lines(template, [b"!trigp -1 1.0\r", b"!trigp -1 2.0\r"])
    assert run is not None and len(run) == 2
    for smuggled in (b"!trigp -1 2.0\x03\r", b"!trigp -1 2\r!moa x 5\r",
                     b"!trigp -1 2.0\n\r", b"!trigp -1 2.0", b"!trigp -1 2.0\xe9\r"):
        with pytest.raises(InvalidCommandError):
            link.protocol.pack_lines(template, [b"!trigp -1 1.0\r", smuggled])
    assert link.transport.writes == []


async def test_settle_waits_for_the_drivers_own_lines_only(fake_link: LinkFactory) -> None:
    link = fake_link(separators=True)
    link.protocol.submit_together((parse("?statusaxis"), parse("?pos")), separate_after=True)
    link.feed(b"@@@-.-\r1.0 2.0 3.0\r")
    settle = asyncio.create_task(link.protocol.settle(5.0))
    await asyncio.sleep(0.01)
    assert not settle.done()  # the separator's reply is still due
    link.feed(b"ERROR 0,no error\r")
    await asyncio.wait_for(settle, 30.0)  # a bound on a hang only
    # Unanswered: it gives up at its bound (one loop turn when the bound is spent).
    link.protocol.submit_together((parse("?pos"),), separate_after=True)
    link.feed(b"1.0 2.0 3.0\r")
    spent = asyncio.ensure_future(link.protocol.settle(0.0))
    await done_within_ticks(spent)
    # A caller's request in flight: no wait (closing fails it anyway).
    link.feed(b"ERROR 0,no error\r")
    link.protocol.submit(parse("?vel"))
    in_flight = asyncio.ensure_future(link.protocol.settle(5.0))
    await done_within_ticks(in_flight)


# --------------------------------------------------------------------------------------
# Autostatus modes


async def test_mode0_moves_owe_no_completion(fake_link: LinkFactory) -> None:
    link = fake_link(autostatus=0)
    move = link.protocol.submit(parse("!moa x 1"))
    assert move.completion is None and move.reply is None


async def test_mode2_acknowledges_sets_and_moves(fake_link: LinkFactory) -> None:
    link = fake_link(autostatus=2)
    vel = link.protocol.submit(parse("!vel x 5"))
    move = link.protocol.submit(parse("!moa x 1"))
    await link.feed_bytewise(b"OK...\rOK...\r@@@-.\r")
    assert vel.reply is not None and vel.reply.result().acked
    assert vel.reply.result().ack == 0
    assert move.completion is not None and move.completion.result().letters == XYZ


async def test_mode2_refused_move_fails_its_completion(fake_link: LinkFactory) -> None:
    link = fake_link(autostatus=2)
    link.protocol.core.ack_reads = AckReads.NO  # as found when mode 2 is entered
    move = link.protocol.submit(parse("!moa x 1"))
    after = link.protocol.submit(parse("!moa x 2"))
    # Each move's OK... may come only with its report (switch move_ok): the ?err behind
    # each is all it is sure to get, and the second waits for the first's reply.
    assert link.sent_lines() == [b"!moa x 1", b"?err"]
    link.feed(b"ERR 5\r5\r")
    assert link.sent_lines()[2:] == [b"!moa x 2", b"?err"]
    link.feed(b"OK...\r0\r@@@-.\r")
    assert move.reply is not None and move.reply.result().ack == 5
    assert move.completion is not None and move.completion.done()
    with pytest.raises(OutOfRangeError):
        move.completion.result()
    assert after.completion is not None and after.completion.result().letters == XYZ
    assert link.protocol.core.awaiting_completion == []


async def test_mode3_bare_cr_completes_a_move(fake_link: LinkFactory) -> None:
    link = fake_link(autostatus=3)
    move = link.protocol.submit(parse("!moa x 1"))
    err = link.protocol.submit(parse("?err"))
    link.feed(b"0\r\r")
    assert reply_of(err) == ("0",)
    assert move.completion is not None and move.completion.result().letters is None


async def test_mode4_echo_then_completion(fake_link: LinkFactory) -> None:
    link = fake_link(autostatus=4)
    move = link.protocol.submit(parse("!moa x 1"))
    err = link.protocol.submit(parse("?err"))
    await link.feed_bytewise(b"!moa x 1\r0\r@@@-.\r")
    assert move.reply is not None and move.reply.result().echo == "!moa x 1"
    assert reply_of(err) == ("0",)
    assert move.completion is not None and move.completion.result().letters == XYZ


async def test_switching_mode_changes_what_moves_owe(fake_link: LinkFactory) -> None:
    link = fake_link()
    link.protocol.submit(parse("!autostatus 3"))
    move = link.protocol.submit(parse("!moa x 1"))
    link.feed(b"\r")
    assert move.completion is not None and move.completion.result().letters is None


# --------------------------------------------------------------------------------------
# Cancellation


async def test_cancelled_request_late_reply_is_consumed(fake_link: LinkFactory) -> None:
    link = fake_link()
    task = asyncio.create_task(link.protocol.request(parse("?vel x")))
    await link.wait_written(b"?vel x\r")
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    pos = link.protocol.submit(parse("?pos x"))
    assert link.sent_lines() == [b"?vel x"]  # one number each: ?pos x waits
    link.feed(b"11.500\r")
    assert link.sent_lines() == [b"?vel x", b"?pos x"]
    link.feed(b"1.0000\r")
    assert reply_of(pos) == ("1.0000",)
    assert not any(isinstance(event, Unsolicited) for event, _ in link.events)


async def test_random_cancellation_never_desynchronises(fake_link: LinkFactory) -> None:
    """Requests are cancelled at random moments while their replies trickle in; every
    request that is not cancelled gets exactly its own reply."""
    rng = random.Random(7)
    link = fake_link()
    for round_ in range(150):
        count = rng.randint(1, 5)
        before = len(link.sent_lines())
        tasks = [asyncio.create_task(link.protocol.request(parse(f"?vel {axis}")))
                 for axis in rng.choices("xyz", k=count)]
        victims = set(rng.sample(range(count), rng.randint(0, count)))
        fed, written, stream = 0, 0, b""
        while fed < len(stream) or written < count:
            await asyncio.sleep(0)
            # The controller answers every line written so far (they go one at a time:
            # their replies look alike); the answers arrive in random pieces.
            written = len(link.sent_lines()) - before
            stream = b"".join(f"{round_}.{i:03d}\r".encode() for i in range(written))
            piece = rng.randint(0, len(stream) - fed)
            for index in list(victims):
                if rng.random() < 0.5:
                    tasks[index].cancel()
                    victims.discard(index)
            link.feed(stream[fed:fed + piece])
            fed += piece
        for index, task in enumerate(tasks):
            if task.cancelled():
                continue
            assert (await task).lines == (f"{round_}.{index:03d}",)
    assert link.protocol.core.pending_tags == []


# --------------------------------------------------------------------------------------
# Timeouts and resynchronisation


async def test_timeout_resyncs_and_drops_the_late_reply(fake_link: LinkFactory) -> None:
    link = fake_link()
    task = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=0.05))
    await link.wait_written(b"?help ")
    assert link.sent_lines()[-1].startswith(b"?help ")
    link.feed(b"11.500\r")  # the late reply, written before the marker's
    link.answer_marker()
    with pytest.raises(ControllerTimeoutError):
        await task
    assert (Dropped("11.500"), None) in link.events
    pos = link.protocol.submit(parse("?pos x"))
    link.feed(b"1.0000\r")
    assert reply_of(pos) == ("1.0000",)


async def test_timeout_holds_requests_queued_behind_until_resynced(
        fake_link: LinkFactory) -> None:
    """#14 item 6: the caller gets its error at its own timeout, naming its own line; the
    resync goes on in the background, and the line queued behind it is written after the
    marker's reply and gets its own reply."""
    link = fake_link()
    first = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=0.05))
    await asyncio.sleep(0)
    behind = asyncio.create_task(link.protocol.request(parse("?vel y"), timeout=5.0))
    with pytest.raises(ControllerTimeoutError, match=r"no reply to '\?vel x' within 0.05"):
        await first
    # Raised before the marker is answered: the resync runs in the background.
    assert link.protocol.core.resyncing
    assert b"?vel y" not in link.transport.sent  # held behind the marker
    link.answer_marker()
    await link.wait_written(b"?vel y\r")
    link.feed(b"12.250\r")
    assert (await behind).lines == ("12.250",)


async def test_a_line_written_late_in_its_wait_gets_its_time_again(
        fake_link: LinkFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """A line held behind a resync goes out when the marker is answered; if its caller's
    timeout then runs out before the controller could answer, the reply still gets the
    time again from then, instead of the line being declared lost a moment after its
    write (which started another resync and dropped the replies of lines written with
    it). The first wait's expiry is simulated, so no clock decides the test."""
    real = protocol_module._until_done
    expire, again = asyncio.Event(), asyncio.Event()
    waits: list[str] = []

    async def until_done(future: asyncio.Future[object], timeout: float | None,
                         submission: Submission) -> None:
        line = submission.command.line
        waits.append(line)
        if line == "?vel y" and waits.count(line) == 2:
            again.set()
        if line == "?vel y" and waits.count(line) == 1:
            done: asyncio.Future[Any] = asyncio.ensure_future(asyncio.shield(future))
            expiry: asyncio.Future[Any] = asyncio.ensure_future(expire.wait())
            await asyncio.wait({done, expiry}, return_when=asyncio.FIRST_COMPLETED)
            for task in (done, expiry):
                task.cancel()
            return
        await real(future, timeout, submission)

    link = fake_link()
    first = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=0.05))
    with pytest.raises(ControllerTimeoutError):
        await first
    monkeypatch.setattr(protocol_module, "_until_done", until_done)
    behind = asyncio.create_task(link.protocol.request(parse("?vel y"), timeout=5.0))
    await asyncio.sleep(0)
    assert b"?vel y" not in link.transport.sent  # held behind the marker
    link.answer_marker()
    await link.wait_written(b"?vel y\r")
    markers = len(link.marker_codes())
    expire.set()  # the caller's time runs out just after the write
    waiting_again = asyncio.ensure_future(again.wait())
    async with asyncio.timeout(2.0):
        await asyncio.wait({waiting_again, behind}, return_when=asyncio.FIRST_COMPLETED)
    waiting_again.cancel()
    link.feed(b"12.250\r")
    assert (await behind).lines == ("12.250",)
    assert len(link.marker_codes()) == markers  # no new resync
    assert waits.count("?vel y") == 2


async def test_an_overdue_background_marker_is_written_again_until_answered(
        fake_link: LinkFactory) -> None:
    """The session's ``Silence.MARKER_AGAIN`` carried out: the background resync's marker
    got no reply in time and the link lives on, so a new marker follows (the line held
    behind them is not held for ever), and the newest one's reply ends the resync."""
    link = fake_link(dead_after=10)
    with pytest.raises(ControllerTimeoutError):
        await link.protocol.request(parse("?vel x"), timeout=0.05)
    behind = asyncio.create_task(link.protocol.request(parse("?vel y"), timeout=5.0))
    await link.wait_written(b"?help ", 2)
    assert link.protocol.core.resyncing and b"?vel y" not in link.transport.sent
    link.answer_marker()
    await link.wait_written(b"?vel y\r")
    link.feed(b"12.250\r")
    assert (await behind).lines == ("12.250",)
    assert link.protocol.is_connected


async def test_concurrent_timeouts_both_return_once_resynced(fake_link: LinkFactory) -> None:
    link = fake_link()
    tasks = [asyncio.create_task(link.protocol.request(parse(line), timeout=0.05))
             for line in ("?vel x", "?vel y")]
    async with asyncio.timeout(30.0):  # a bound on a hang only
        for task in tasks:
            with pytest.raises(ControllerTimeoutError, match="no reply"):
                await task
    # '?vel y' waited behind '?vel x' (look-alike replies) and was never written: only
    # the written one counts as unanswered, and one resync runs.
    assert b"?vel y" not in link.transport.sent
    assert len(link.marker_codes()) == 1
    link.answer_marker()
    assert not link.protocol.core.resyncing
    assert link.protocol.is_connected


@pytest.mark.parametrize("autostatus", [1, 4])
async def test_a_lost_reply_nobody_awaits_does_not_hold_the_next_call(
        fake_link: LinkFactory, autostatus: int) -> None:
    """A list upload whose check read was held for credit behind a reply that got lost:
    in autostatus 1 a credit marker's number, in autostatus 4 a list entry's echo (the
    echoes after it are not it, so the core still owes it). Nobody awaits those replies,
    so the check's timeout is the only one that covers them: it resyncs the stream, and
    the next read is written after the marker and gets its own reply (not held for
    credit, nor handed to the lost line's place)."""
    link = fake_link(autostatus=autostatus, credit_limit=64, marker_chunk=30)
    protocol = link.protocol
    values = [f"0.{5000 + 137 * i}" for i in range(8)]
    entries = [protocol.submit(parse(f"!trigp -1 {value}")) for value in values]
    check = protocol.submit(parse("?trigc"))
    written = link.sent_lines()
    assert b"?trigc" not in written  # held for credit
    if autostatus == 4:
        # Every entry written is echoed, but the first entry's echo is lost.
        link.feed(b"".join(line + b"\r" for line in written[1:] if line.startswith(b"!")))
    with pytest.raises(ControllerTimeoutError, match=r"no reply to '\?trigc'"):
        await protocol.wait_reply(check, 0.05)
    assert protocol.core.resyncing  # the background resync started at once
    protocol.withdraw(entries)  # as the failed upload does
    link.answer_marker()
    pos = asyncio.create_task(protocol.request(parse("?pos"), timeout=5.0))
    await link.wait_written(b"?pos\r")
    link.feed(b"1.0000 2.0000 3.0000\r")
    assert (await pos).lines == ("1.0000 2.0000 3.0000",)


async def test_resync_with_ctrl_c(fake_link: LinkFactory) -> None:
    link = fake_link()
    move = link.protocol.submit(parse("!moa x 1"))
    queued = [link.protocol.submit(parse(line)) for line in ("?vel x", "?pos")]
    task = asyncio.create_task(link.protocol.resync(ctrl_c=True))
    await link.wait_written(b"?help ")
    assert link.transport.writes[-1].startswith(b"\x03?help ")
    for sub in queued:
        assert sub.reply is not None
        with pytest.raises(RequestAbortedError):
            sub.reply.result()
    # A stale reply is dropped; the completion report still reaches the move; the marker
    # may follow stale bytes on the same line.
    code = link.marker_codes()[-1]
    link.feed(b"11.500\rE@@-.\rgarbage" + f"ERROR {code},x\r".encode())
    await task
    assert move.completion is not None
    assert move.completion.result().letters == {"x": "E", "y": "@", "z": "@"}
    assert (Dropped("11.500"), None) in link.events
    after = link.protocol.submit(parse("?vel z"))
    link.feed(b"13.125\r")
    assert reply_of(after) == ("13.125",)


async def test_resync_times_out_when_the_marker_never_answers(fake_link: LinkFactory) -> None:
    link = fake_link()
    with pytest.raises(ControllerTimeoutError, match="resync marker"):
        await link.protocol.resync(timeout=0.05)


# --------------------------------------------------------------------------------------
# Connection loss


async def test_connection_loss_fails_everything_pending(fake_link: LinkFactory) -> None:
    link = fake_link()
    move = link.protocol.submit(parse("!moa x 1"))
    resync = asyncio.create_task(link.protocol.resync())
    await link.wait_written(b"?help ")
    query = link.protocol.submit(parse("?vel x"))
    cause = OSError(5, "Input/output error")
    link.protocol.connection_lost(cause)
    for future in (query.reply, move.completion):
        assert future is not None
        with pytest.raises(ConnectionLostError) as info:
            future.result()
        assert info.value.__cause__ is cause
    with pytest.raises(ConnectionLostError):
        await resync
    assert link.lost == [cause]
    with pytest.raises(ConnectionLostError) as later:
        link.protocol.submit(parse("?vel x"))
    assert later.value.__cause__ is cause
    assert not link.protocol.is_connected


async def test_peer_close_without_error_still_has_a_cause(fake_link: LinkFactory) -> None:
    link = fake_link()
    task = asyncio.create_task(link.protocol.request(parse("?vel x")))
    await link.wait_written(b"?vel x\r")
    link.protocol.eof_received()
    link.protocol.connection_lost(None)
    with pytest.raises(ConnectionLostError) as info:
        await task
    assert info.value.__cause__ is not None
    with pytest.raises(ConnectionLostError):
        await link.protocol.request(parse("?pos"))


# --------------------------------------------------------------------------------------
# Wire tracing


async def test_wire_logger_traces_every_line(fake_link: LinkFactory,
                                             caplog: pytest.LogCaptureFixture) -> None:
    link = fake_link()
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        link.protocol.submit(parse("?pos"))
        link.protocol.submit(parse("!moa x 1"))
        await link.feed_bytewise(b"1.0000 2.0000 3.0000\r")
        link.feed(b"@@@-.\rhel")
        link.feed(b"lo\r")
    messages = [r.getMessage() for r in caplog.records if r.name == "tango_aio.wire"]
    out = [m for m in messages if "->" in m]
    received = [m for m in messages if "<-" in m]
    assert len(out) == 2 and "?pos" in out[0] and "!moa x 1" in out[1]
    assert len(received) == 3
    assert "1.0000 2.0000 3.0000" in received[0]
    assert "@@@-." in received[1] and "hello" in received[2]


async def test_wire_logger_is_quiet_above_debug(fake_link: LinkFactory,
                                                caplog: pytest.LogCaptureFixture) -> None:
    link = fake_link()
    with caplog.at_level(logging.INFO, logger="tango_aio.wire"):
        link.protocol.submit(parse("?pos"))
        link.feed(b"1.0000\r")
    assert not [r for r in caplog.records if r.name == "tango_aio.wire"]


# --------------------------------------------------------------------------------------
# Controller on the fake transport: input validation and error checks


INVALID_CALLS: dict[str, Callable[[Controller], Awaitable[object]]] = {
    "query unknown axis": lambda t: t.query("?vel q"),
    "query of a set": lambda t: t.query("!vel x 5"),
    "command of a read": lambda t: t.command("?vel"),
    "unknown instruction": lambda t: t.command("!frobnicate 1"),
    "vel out of range": lambda t: t.set("vel", x=500),
    "vel not finite": lambda t: t.set("vel", x=float("nan")),
    "axis gap": lambda t: t.set("vel", x=1, z=2),
    "get unknown axis": lambda t: t.get("vel", axis="q"),
    "move unknown axis": lambda t: t.move_to(q=1.0),
    "move not a number": lambda t: t.move_by(x="far"),  # type: ignore[arg-type]  # on purpose
    "cal unknown axis": lambda t: t.calibrate("q"),
}


@pytest.mark.parametrize("call", INVALID_CALLS.values(), ids=INVALID_CALLS.keys())
async def test_invalid_input_raises_before_a_byte_is_written(
        fake_link: LinkFactory, call: Callable[[Controller], Awaitable[object]]) -> None:
    link = fake_link()
    tango = Controller(link.protocol)
    with pytest.raises(InvalidCommandError):
        await call(tango)
    assert link.transport.writes == []


async def test_bad_set_raises_typed_error_from_err_probe(fake_link: LinkFactory) -> None:
    link = fake_link()
    tango = Controller(link.protocol)
    task = asyncio.create_task(tango.command("!lim x 10 5"))
    await link.wait_written(b"?lim x\r")
    # Back to back, and the read-back that proves the set behind them (readback.py).
    assert link.transport.sent == b"!lim x 10 5\r?err\r?lim x\r"
    link.feed(b"5\r")  # the refusal decides: the read-back's reply is not awaited
    with pytest.raises(OutOfRangeError) as info:
        await task
    assert info.value.number == 5 and isinstance(info.value, CommandRejectedError)
    assert info.value.command == "!lim x 10 5"


@pytest.mark.parametrize(("ack", "code"), [(b"ERR 5\r", 5), (b"ERR\r", None)])
async def test_mode2_err_ack_raises(fake_link: LinkFactory, ack: bytes,
                                    code: int | None) -> None:
    link = fake_link(autostatus=2)
    tango = Controller(link.protocol)
    task = asyncio.create_task(tango.command("!lim x 10 5"))
    await link.wait_written(b"!lim x 10 5\r")
    assert b"?err" not in link.transport.sent  # the acknowledgement is the check
    link.feed(ack)
    with pytest.raises(ControllerError) as info:
        await task
    if code is not None:
        assert isinstance(info.value, OutOfRangeError)
    assert info.value.command == "!lim x 10 5"


async def test_controller_query_timeout(fake_link: LinkFactory) -> None:
    link = fake_link()
    tango = Controller(link.protocol)
    task = asyncio.create_task(tango.query("?vel x", timeout=0.05))
    await link.wait_written(b"?help ")
    link.feed(b"11.500\r")
    link.answer_marker()
    with pytest.raises(ControllerTimeoutError):
        await task
    second = asyncio.create_task(tango.query("?vel y"))
    await link.wait_written(b"?vel y\r")
    link.feed(b"12.250\r")
    assert await second == "12.250"


async def test_stream_recovers_after_a_resync_that_timed_out(fake_link: LinkFactory) -> None:
    """The controller stalls past the marker's timeout, then catches up: its late lines
    are dropped up to the newest marker's reply, and the next request gets its own reply."""
    link = fake_link(dead_after=10)
    first = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=0.02))
    with pytest.raises(ControllerTimeoutError):
        await first
    link.protocol.reply_timeout = 0.02
    await link.wait_written(b"?help ", count=2)  # the first marker timed out: a second
    assert link.protocol.core.resyncing
    # Answered at once, but its clock starts now: not the markers' short deadline.
    task = asyncio.create_task(link.protocol.request(parse("?vel y"), timeout=5.0))
    old, code = link.marker_codes()[-2:]
    link.feed(f"11.500\rERROR {old},x\rERROR {code},x\r".encode())
    await link.wait_written(b"?vel y\r")
    link.feed(b"12.250\r")
    assert (await task).lines == ("12.250",)



async def test_a_link_that_still_delivers_lines_is_not_declared_dead(
        fake_link: LinkFactory) -> None:
    """A request times out (one unanswered line), and its resync marker's reply arrives
    garbled, so the marker times out too: two in a row without a reply, but a line came in
    between, so the link is noisy, not dead. Only silence counts (dead_after=2)."""
    link = fake_link(dead_after=2)
    with pytest.raises(ControllerTimeoutError):
        await link.protocol.request(parse("?vel x"), timeout=0.02)
    link.protocol.reply_timeout = 0.02
    code = link.marker_codes()[-1]
    link.feed(f"ERROR {code}(x\r".encode())  # the marker's reply with one bit flipped
    assert link.protocol.core.resyncing
    await link.wait_written(b"?help ", count=2)  # its deadline passed: a second marker
    assert link.protocol.is_connected
    link.answer_marker()
    task = asyncio.create_task(link.protocol.request(parse("?vel y"), timeout=5.0))
    await link.wait_written(b"?vel y\r")
    link.feed(b"12.250\r")
    assert (await task).lines == ("12.250",)


async def test_silence_after_a_timeout_declares_the_link_dead(fake_link: LinkFactory) -> None:
    """The counterpart: the same two deadlines with nothing at all in between."""
    link = fake_link(dead_after=2)
    with pytest.raises(ControllerTimeoutError):
        await link.protocol.request(parse("?vel x"), timeout=0.02)
    link.protocol.reply_timeout = 0.02
    with pytest.raises(ConnectionLostError):
        await link.protocol.request(parse("?vel y"), timeout=5.0)
    assert not link.protocol.is_connected


# -- Mode exchanges: when they may end without waiting for a quiet link -----------------


@pytest.mark.parametrize("mode", [0, 1, 3])
async def test_a_mode_read_ends_at_helps_reply_where_nothing_can_trail_it(
        fake_link: LinkFactory, mode: int) -> None:
    """Modes 0, 1 and 3 add no line to a read (L2079-2113): the exchange ends at the reply
    of ``?help``, without the quiet interval (set here to an hour)."""
    link = fake_link()
    link.protocol.quiet_interval = 3600.0
    read = asyncio.create_task(link.protocol.read_autostatus(timeout=5.0))
    await link.wait_written(b"?help\r")
    link.feed(f"{mode}\rERROR 0,no error\r".encode())
    assert await asyncio.wait_for(read, 5.0) == mode


@pytest.mark.parametrize("mode", [2, 4])
async def test_a_mode_read_waits_for_quiet_where_a_line_can_trail_helps_reply(
        fake_link: LinkFactory, mode: int) -> None:
    """Modes 2 and 4 may acknowledge or echo ``?help`` after its reply (L2099-2117): the
    exchange waits until the link is quiet, and sees the line that came after."""
    link = fake_link()
    link.protocol.quiet_interval = 3600.0
    read = asyncio.create_task(link.protocol.read_autostatus(timeout=5.0))
    await link.wait_written(b"?help\r")
    link.feed(f"{mode}\rERROR 0,no error\r".encode())
    for _ in range(20):
        await asyncio.sleep(0)
    assert not read.done()
    link.protocol.quiet_interval = 0.01  # the trailing line re-arms the quiet timer
    link.feed(b"OK...\r" if mode == 2 else b"?help\r")
    assert await asyncio.wait_for(read, 5.0) == mode
    if mode == 2:
        assert link.protocol.core.ack_reads is AckReads.AFTER


async def test_a_mode_change_the_controller_did_not_make_fails_and_its_mode_is_adopted(
        fake_link: LinkFactory) -> None:
    """The session's verdict (``ModeVerdict.KEPT_ANOTHER``) carried out: the read behind
    ``!autostatus 2`` found mode 1 still in force."""
    link = fake_link()
    change = asyncio.create_task(
        link.protocol.execute(parse("!autostatus 2"), timeout=5.0))
    await link.wait_written(b"?help\r")
    assert link.transport.writes[-1] == b"!autostatus 2\r?autostatus\r?help\r"
    link.feed(b"1\rERROR 0,no error\r")
    with pytest.raises(UnknownControllerError):
        await asyncio.wait_for(change, 5.0)
    assert link.protocol.autostatus == 1
    link.protocol.submit(parse("?err"))  # the next line goes out at once
    assert link.transport.writes[-1] == b"?err\r"


async def test_a_read_that_finds_another_mode_restores_the_drivers(
        fake_link: LinkFactory) -> None:
    """The session's verdict (``ModeVerdict.RESTARTED``) carried out: the driver's mode 0
    is selected again and the owner told what was found."""
    link = fake_link(autostatus=0)
    restored: list[tuple[int, int]] = []
    link.protocol.on_restored = lambda found, mode: restored.append((found, mode))
    verify = asyncio.create_task(link.protocol.verify_autostatus(timeout=5.0))
    await link.wait_written(b"?help\r")
    link.feed(b"1\rERROR 0,no error\r")  # a restart: power-on mode 1 (L2062)
    await link.wait_written(b"!autostatus 0\r?autostatus\r?help\r")
    link.feed(b"0\rERROR 0,no error\r")
    assert await asyncio.wait_for(verify, 5.0) is True
    assert restored == [(1, 0)] and link.protocol.autostatus == 0


@pytest.mark.parametrize("mode", [0, 2, 3, 4])
async def test_lines_held_behind_a_read_that_finds_a_restart_go_out_in_the_drivers_mode(
        fake_link: LinkFactory, mode: int) -> None:
    """#37 item 4: a move submitted while the mode read runs was submitted for the
    driver's mode (in mode 2 it waits for its ``OK...``). It goes out only after that
    mode is selected again, not in the power-on mode 1 the read found."""
    link = fake_link(autostatus=mode)
    verify = asyncio.create_task(link.protocol.verify_autostatus(timeout=5.0))
    await link.wait_written(b"?help\r")
    move = link.protocol.start_move(parse("!moa x 1"))  # held behind the read
    link.feed(b"1\rERROR 0,no error\r")  # a restart: power-on mode 1 (L2062)
    await link.wait_written(b"!autostatus %d\r?autostatus\r?help\r" % mode)
    assert b"!moa" not in link.transport.sent
    link.feed(b"%d\rERROR 0,no error\r" % mode)
    assert await asyncio.wait_for(verify, 5.0) is True
    # The move goes out once the driver's mode is in force again, encoded for it: in
    # mode 2 it owes its OK... (and the ?err the core writes behind it).
    await link.wait_written(b"!moa x 1\r")
    assert link.protocol.autostatus == mode
    link.feed(b"OK...\r0\r" if mode == 2 else b"!moa x 1\r0\r" if mode == 4 else b"0\r")
    assert await asyncio.wait_for(move.error(5.0), 5.0) is None


async def test_a_mode_change_waiting_for_the_lines_before_it_is_not_sent_after_ctrl_c(
        fake_link: LinkFactory) -> None:
    """The session's ``Barrier.ABORTED`` carried out: Ctrl+C discarded a line the change
    was to follow, so the change is not written."""
    link = fake_link()
    link.protocol.submit(parse("?pos"))
    queued = link.protocol.submit(parse("?pos"))  # a look-alike: held until the first
    assert not queued.written
    change = asyncio.create_task(link.protocol.execute(parse("!autostatus 2"), timeout=5.0))
    for _ in range(20):
        await asyncio.sleep(0)
    assert not change.done()
    resync = asyncio.create_task(link.protocol.resync(ctrl_c=True, timeout=5.0))
    with pytest.raises(RequestAbortedError, match="mode change was not sent"):
        await asyncio.wait_for(change, 5.0)
    link.answer_marker()
    await asyncio.wait_for(resync, 5.0)
    assert b"autostatus" not in link.transport.sent


# -- Detecting how ?help N answers (TangoProtocol.detect) --------------------------------


async def _written_help_code(link: FakeLink, count: int = 1) -> int:
    await link.wait_written(b"?help ", count)
    return link.marker_codes()[count - 1]


async def test_detect_is_quick_when_help_n_answers_with_its_number(
        fake_link: LinkFactory) -> None:
    """``ERROR N,`` twice then ``?err``'s number end the detection at once (the quiet
    interval is an hour here), whatever an earlier session left in the stream before them:
    its markers and separators take the codes in turn, so this session's code may be
    among them, but never twice in a row."""
    link = fake_link()
    link.protocol.quiet_interval = 3600.0
    detect = asyncio.create_task(link.protocol.detect(timeout=5.0))
    code = await _written_help_code(link)
    assert link.transport.sent == f"help\r?help {code}\r?help {code}\r?err\r".encode()
    stale = f"7\r12.5000 3.0000\rERROR {code},stale\r0\rERROR {code + 1},\r@@@-.\r".encode()
    link.feed(stale + f"ERROR 0,no error\rERROR {code},text\rERROR {code},text\r0\r".encode())
    assert await asyncio.wait_for(detect, 5.0) == {"help_number": "yes"}
    request = asyncio.create_task(link.protocol.request(parse("?vel x"), timeout=2.0))
    await link.wait_written(b"?vel x\r")
    link.feed(b"10.000\r")
    assert (await request).lines == ("10.000",)


@pytest.mark.parametrize(("answer", "style"), [("servo amplifier off\r", "no"), ("", "none")])
async def test_detect_falls_back_to_a_quiet_resync_when_help_n_has_no_number(
        fake_link: LinkFactory, answer: str, style: str) -> None:
    """Firmware that answers ``?help N`` with the text alone, or not at all: after a
    quiet link, a quiet resync (``help``) and the exchange of ``?help N`` and ``?err``."""
    link = fake_link()
    link.protocol.quiet_interval = 0.01
    detect = asyncio.create_task(link.protocol.detect(timeout=5.0))
    await _written_help_code(link)
    link.feed(f"ERROR 0,no error\r{answer}0\r".encode())
    await link.wait_written(b"help\r", 2)  # the quiet resync
    link.feed(b"ERROR 0,no error\r")
    await _written_help_code(link, 3)
    link.feed(f"{answer}0\r".encode())
    assert await asyncio.wait_for(detect, 5.0) == {"help_number": style}


async def test_detect_without_the_number_after_the_marker_falls_back(
        fake_link: LinkFactory) -> None:
    """Marker replies whose ``?err`` reply never comes prove nothing: the quiet path."""
    link = fake_link()
    link.protocol.quiet_interval = 0.01
    detect = asyncio.create_task(link.protocol.detect(timeout=5.0))
    code = await _written_help_code(link)
    link.feed(f"ERROR 0,no error\rERROR {code},text\rERROR {code},text\r".encode())
    await link.wait_written(b"help\r", 2)
    link.feed(b"ERROR 0,no error\r")
    code = await _written_help_code(link, 3)
    link.feed(f"ERROR {code},text\r0\r".encode())
    assert await asyncio.wait_for(detect, 5.0) == {"help_number": "yes"}
