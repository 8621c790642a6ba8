"""Mode 2: a move whose acknowledgement was lost or garbled on the way looks deferred.

The reply of the ``?err`` written behind a mode-2 move arrives where the move's ``OK...``
is owed, so the core takes that ``OK...`` for one that comes with the completion report
(switch ``move_ok=completion``; L2099-2103 do not say when it comes), though on firmware
that acknowledges at once it never comes. The acknowledgements after it are then counted
against that deferred ``OK...`` (:meth:`ProtocolCore._resolve_held`). These tests run a
controller that acknowledges moves at once and answers every line, on both firmware
that acknowledges reads after their data and before it (``ack_reads``), and check that
once every line written is answered the core owes nothing: a line still owed keeps the
next line that looks like it from being written (the write scheduler waits for its
reply), and the call after the faulted one times out (the slow tier's mode-2 soak).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import example, given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.sansio._core import Acknowledged, AckReads, Mismatched, ProtocolCore, Replied
from tango_aio.sansio._scheduler import Line, WriteScheduler

#: What happens to a move line's ``OK...`` on the way (or to the line itself).
FATES = ("kept", "lost", "garbled")
REPORT = "@@@-."
POSITION = "1.0000 2.0000 0.0000"


@dataclass
class Unit:
    """A mode-2 controller that acknowledges moves at once (``move_ok=immediate``) and
    reads ``ack_reads``, behind a scheduler and its core; each move completes at once."""

    ack_reads: AckReads
    core: ProtocolCore = field(init=False)
    scheduler: WriteScheduler = field(init=False)
    events: list[object] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.core = ProtocolCore(autostatus=2, marker_seed=0)
        self.core.ack_reads = self.ack_reads
        self.scheduler = WriteScheduler(self.core)

    def call(self, text: str, fate: str = "kept") -> Line:
        """Submit ``text``; write it (it must go out: every line before is answered);
        answer every line written, the move line's ``OK...`` as ``fate`` says."""
        command = parse(text)
        tag, mode, expect = self.scheduler.plan(command)
        line = Line(command, tag, expect, mode)
        self.scheduler.submit(line)
        data = self.scheduler.next_write()
        assert line.written, (f"{text!r} was not written: a reply owed before it did not "
                              f"come (the core still owes {self.core.tail})")
        replies: list[str] = []
        for written in data.decode().split("\r")[:-1]:
            replies += self.answer(written, fate)
        if self.receive(replies):
            # A line that cannot be the reply it would be taken for: the driver resyncs
            # (tango_aio.link: its marker, then the stream is in step).
            tag = self.scheduler.next_tag()
            marker = self.core.resync(tag)
            self.scheduler.restarted(tag, len(marker))
            self.receive(self.answer(marker.decode().rstrip("\r"), "kept"))
            assert not self.core.resyncing
        return line

    def receive(self, replies: list[str]) -> bool:
        """Feed ``replies``; whether one was mismatched."""
        self.core.receive_data("".join(reply + "\r" for reply in replies).encode())
        mismatched = False
        while (event := self.core.next_event()) is not None:
            self.events.append(event)
            mismatched = mismatched or isinstance(event, Mismatched)
            if isinstance(event, Replied | Acknowledged):
                self.scheduler.replied(event.tag, getattr(event, "lines", None))
        return mismatched

    def answer(self, written: str, fate: str) -> list[str]:
        if written.startswith("!moa"):
            if fate == "lost":
                return []
            return ["\x15~OK..." if fate == "garbled" else "OK...", REPORT]
        if written.startswith("!"):
            return ["OK..."]
        data = {"?err": "0", "?pos": POSITION, "err": "0"}.get(written)
        if data is None:
            assert written.startswith("?help"), written
            code = written.removeprefix("?help").strip() or "0"
            data = f"ERROR {code},no error" if code == "0" else f"ERROR {code},a marker"
        if not written.startswith("?"):
            return [data]
        return [data, "OK..."] if self.ack_reads is AckReads.AFTER else ["OK...", data]


CALLS = st.sampled_from(["!moa 1 2", "!vel x 5", "?pos"])


@given(ack_reads=st.sampled_from([AckReads.AFTER, AckReads.BEFORE]),
       fate=st.sampled_from(FATES[1:]),
       before=st.lists(CALLS, max_size=3), after=st.lists(CALLS, min_size=1, max_size=6))
@settings(max_examples=300, deadline=None)
@example(ack_reads=AckReads.AFTER, fate="lost", before=[], after=["?pos", "!moa 1 2"])
@example(ack_reads=AckReads.BEFORE, fate="garbled", before=[],
         after=["?pos", "?pos", "!moa 1 2", "?pos"])
def test_a_move_whose_ok_went_astray_leaves_nothing_owed_once_all_is_answered(
        ack_reads: AckReads, fate: str, before: list[str], after: list[str]) -> None:
    unit = Unit(ack_reads)
    for text in before:
        unit.call(text)
    unit.call("!moa 1 2", fate)
    faulted = len(unit.events)
    lines = [unit.call(text) for text in after]  # each asserts that it was written
    assert unit.core.tail is None and unit.core.pending_tags == []
    # The fault's own replies may put the stream out of step (a garbled OK... where the
    # ?err's number is owed); the lines after them leave it in step.
    assert not [e for e in unit.events[faulted:] if isinstance(e, Mismatched)]
    # Every line after the fault got its own answer: each set and move its OK..., each
    # read its position (a move may be judged by the ?err behind it: 0, accepted).
    for line in lines:
        got = [e for e in unit.events if getattr(e, "tag", None) == line.tag]
        if line.command.line == "?pos":
            assert [e.lines for e in got if isinstance(e, Replied)] == [(POSITION,)]
        else:
            assert [e.code for e in got if isinstance(e, Acknowledged)] == [0]


def test_the_set_after_a_lost_move_and_a_read_is_written() -> None:
    # ack_reads=after: the last OK... in (the ?err behind the read) has nothing behind
    # it to tell it from the lost move's; the set behind it must still go out.
    unit = Unit(AckReads.AFTER)
    unit.call("!moa 1 2", "lost")
    unit.call("?pos")
    assert unit.core.tail is None
    assert unit.call("!vel x 5").written


def test_a_set_whose_line_was_lost_does_not_take_the_ok_of_the_read_behind_it() -> None:
    # Mode 2, reads acknowledged after their data: '!vel' lost on the way, a read
    # written behind it answers its number, then its OK.... The number where the set's
    # OK... is owed puts the stream out of step; passed over, the read's OK... would
    # have acknowledged the set (a false success).
    core = ProtocolCore(autostatus=2)
    core.ack_reads = AckReads.AFTER
    core.send(parse("!vel z 91.875"), "set")
    core.send(parse("?delay"), "read")
    events = core.events(b"0\rOK...\r")
    assert not [e for e in events if isinstance(e, Acknowledged)]
    assert isinstance(events[0], Mismatched) and events[0].tag == "set"
