"""Mode 2: a move acknowledged only at its completion on firmware that acknowledges reads.

Two switches of the emulator that a real unit may combine (L2099-2103 say neither when a
move's ``OK...`` comes nor whether reads get one): ``move_ok=completion`` (the move's
``OK...`` comes with its report) and ``ack_reads`` (reads get an ``OK...`` before or after
their data). The core writes an ``?err`` behind each mode-2 move; where reads are
acknowledged before their data, that ``?err`` answers ``OK...`` and then its number, so
the first ``OK...`` after the move may be the move's own or the ``?err``'s. Taken for the
move's, the number met the ``?err``'s owed ``OK...`` and every move put the stream out of
step (a resync and a check for a restart per move; after a fault, the call after it
failed). These tests run such a unit behind a scheduler and its core: each move's
``OK...`` and report come at a point drawn among the later replies.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.sansio._core import (
    Acknowledged,
    AckReads,
    Completed,
    Mismatched,
    ProtocolCore,
    Replied,
)
from tango_aio.sansio._exchange import reads_acknowledged
from tango_aio.sansio._scheduler import Line, WriteScheduler

REPORT = "@@@-."
POSITION = "1.0000 2.0000 0.0000"


@dataclass
class DeferringUnit:
    """A mode-2 controller whose moves are acknowledged at completion, reads per
    ``ack_reads``, behind a scheduler and its core."""

    ack_reads: AckReads
    core: ProtocolCore = field(init=False)
    scheduler: WriteScheduler = field(init=False)
    events: list[object] = field(default_factory=list)
    #: A move under way: its OK... and report are still to come.
    moving: bool = False

    def __post_init__(self) -> None:
        self.core = ProtocolCore(autostatus=2, marker_seed=0)
        self.core.ack_reads = self.ack_reads
        self.scheduler = WriteScheduler(self.core)

    def call(self, text: str, ends_after: int | None) -> Line:
        """Submit and write ``text``, answer every line written; a move under way ends
        (its ``OK...`` and report) after the ``ends_after``-th reply line, if given."""
        command = parse(text)
        tag, mode, expect = self.scheduler.plan(command)
        line = Line(command, tag, expect, mode)
        self.scheduler.submit(line)
        data = self.scheduler.next_write()
        assert line.written, f"{text!r} was not written (the core owes {self.core.tail})"
        replies: list[str] = []
        earliest = 0  # a move written now ends once the ?err behind it is answered
        for written in data.decode().split("\r")[:-1]:
            replies += self.answer(written)
            if written.startswith("!moa") or (written == "?err" and earliest == -1):
                earliest = -1 if written.startswith("!moa") else len(replies)
        if self.moving and ends_after is not None:
            at = max(earliest, min(ends_after, len(replies)))
            replies[at:at] = ["OK...", REPORT]
            self.moving = False
        self.core.receive_data("".join(reply + "\r" for reply in replies).encode())
        while (event := self.core.next_event()) is not None:
            self.events.append(event)
            if isinstance(event, Replied | Acknowledged):
                self.scheduler.replied(event.tag, getattr(event, "lines", None))
        return line

    def answer(self, written: str) -> list[str]:
        if written.startswith("!moa"):
            self.moving = True
            return []  # OK... with the report
        if written.startswith("!"):
            return ["OK..."]
        data = {"?err": "0", "?pos": POSITION}.get(written)
        if data is None:  # a separator or a marker
            assert written.startswith("?help"), written
            code = written.removeprefix("?help").strip() or "0"
            data = f"ERROR {code},no error" if code == "0" else f"ERROR {code},a marker"
        if self.ack_reads is AckReads.NO:
            return [data]
        return [data, "OK..."] if self.ack_reads is AckReads.AFTER else ["OK...", data]


@st.composite
def histories(draw: st.DrawFn) -> list[tuple[str, int | None]]:
    """Calls, each with where a move under way ends among its replies (or not yet)."""
    calls = draw(st.lists(st.sampled_from(["!moa 1 2", "!vel x 5", "?pos"]), min_size=1,
                          max_size=8))
    return [(text, draw(st.none() | st.integers(0, 6))) for text in calls]


@given(ack_reads=st.sampled_from(list(AckReads)), history=histories())
@settings(max_examples=200, deadline=None)
def test_moves_acknowledged_at_completion_keep_the_stream_in_step(
        ack_reads: AckReads, history: list[tuple[str, int | None]]) -> None:
    unit = DeferringUnit(ack_reads)
    lines = []
    for text, ends_after in history:
        if text.startswith("!moa") and unit.moving:
            text = "?pos"  # one move at a time (another would be refused, error 2)
        lines.append(unit.call(text, ends_after))
    unit.call("?pos", 0)  # the last move ends
    assert not [e for e in unit.events if isinstance(e, Mismatched)]
    assert unit.core.tail is None and unit.core.pending_tags == []
    for line in lines:
        got = [e for e in unit.events if getattr(e, "tag", None) == line.tag]
        if line.command.line == "?pos":
            assert [e.lines for e in got if isinstance(e, Replied)] == [(POSITION,)]
        else:  # a set's OK..., a move's deferred verdict (the ?err behind it: 0)
            assert [e.code for e in got if isinstance(e, Acknowledged)] == [0]


@pytest.mark.parametrize(("replies", "deferred"), [
    # 'OK...' '0': the ?err's acknowledgement and number; the move's OK... comes with its
    # report (not the move's OK... and a number where the ?err's OK... is owed).
    (b"OK...\r0\r", True),
    # The move's OK... at once, then the ?err's.
    (b"OK...\rOK...\r0\r", False)])
def test_a_move_where_reads_are_acknowledged_before_their_data(replies: bytes,
                                                               deferred: bool) -> None:
    core = ProtocolCore(autostatus=2)
    core.ack_reads = AckReads.BEFORE
    core.send(parse("!moa 1 2"), "move")
    events = core.events(replies)
    assert not [e for e in events if isinstance(e, Mismatched)]
    assert [(e.code, e.deferred) for e in events if isinstance(e, Acknowledged)] == \
        [(0, deferred)]
    report = b"OK...\r@@@-.\r" if deferred else b"@@@-.\r"
    assert [e.tag for e in core.events(report) if isinstance(e, Completed)] == ["move"]
    assert core.pending_tags == []


def test_a_lost_move_line_still_puts_the_stream_out_of_step() -> None:
    # Nothing but the ?err's number: its OK... is missing too, so a line was lost.
    core = ProtocolCore(autostatus=2)
    core.ack_reads = AckReads.BEFORE
    core.send(parse("!moa 1 2"), "move")
    assert [e for e in core.events(b"0\r") if isinstance(e, Mismatched)]


def test_a_deferred_ok_after_the_help_reply_is_no_acknowledgement_of_reads() -> None:
    # The mode read after a resync, while a move acknowledged at completion ends:
    # ?autostatus 'OK...' '2', ?help 'OK...' 'ERROR 0,...', then the move's OK... and its
    # report. Reads are acknowledged before their data, not after.
    kept = ["OK...", "2", "OK...", "ERROR 0,no error", "OK...", "@@@-."]
    assert reads_acknowledged(kept, 1, 3) is AckReads.BEFORE
    # The same unit acknowledging after the data: an OK... right after the number.
    kept = ["2", "OK...", "ERROR 0,no error", "OK...", "OK...", "@@@-."]
    assert reads_acknowledged(kept, 0, 2) is AckReads.AFTER
    assert reads_acknowledged(["2", "OK...", "ERROR 0,x", "OK..."], 0, 2) is AckReads.AFTER
    assert reads_acknowledged(["OK...", "2", "OK...", "ERROR 0,x"], 1, 3) is AckReads.BEFORE
    assert reads_acknowledged(["2", "ERROR 0,x"], 0, 1) is AckReads.NO
