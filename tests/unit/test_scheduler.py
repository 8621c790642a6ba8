"""Sans-IO tests of the write scheduler (tango_aio.sansio._scheduler), driven synchronously.

A :class:`Link` joins a :class:`WriteScheduler` and its :class:`ProtocolCore` to the
emulator's interpreter (``ControllerModel``, no event loop): bytes written land in the
controller's input buffer, the test decides when the controller processes a line and how
its replies are split on the way back.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

from hypothesis import example, given, settings
from hypothesis import strategies as st

from tango_aio.catalog._encode import build_rows, encode_rows
from tango_aio.catalog._instructions import Command, parse
from tango_aio.sansio._core import Acknowledged, AckReads, Echoed, ProtocolCore, Replied, wire_size
from tango_aio.sansio._flow import MARKER
from tango_aio.sansio._patterns import ONE_NUMBER, Edge, ReplyKind, ReplyPattern, marker_pattern
from tango_aio.sansio._scheduler import Line, WriteScheduler
from tango_aio.sim.model import ControllerModel, SimConfig

#: The controller's input buffer (manual L129-131).
BUFFER = 256


@dataclass
class Link:
    """A scheduler, its core and an emulated controller, stepped by hand."""

    limit: int = 255
    chunk: int = 160
    core: ProtocolCore = field(init=False)
    scheduler: WriteScheduler = field(init=False)
    inbox: bytearray = field(default_factory=bytearray)  # at the controller, unprocessed
    outbox: bytearray = field(default_factory=bytearray)  # replies not yet delivered
    wire: list[str] = field(default_factory=list)  # every line written, in order
    outputs: list[str] = field(default_factory=list)  # per processed line: what it answered
    lines: list[Line] = field(default_factory=list)  # submitted, in order
    replies: dict[int, tuple[str, ...]] = field(default_factory=dict)
    answered: set[int] = field(default_factory=set)
    #: tag -> (index of the line on the wire, tags answered when it was written)
    writes: dict[int, tuple[int, frozenset[int]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.core = ProtocolCore(marker_seed=0)
        self.scheduler = WriteScheduler(self.core, credit_limit=self.limit,
                                        marker_chunk=self.chunk)
        self.model = ControllerModel(self.outbox.extend, SimConfig(), now=0.0)

    def submit(self, text: str, batch: object | None = None, *,
               separate_after: bool = False) -> Line:
        command = parse(text)
        tag, mode, expect = self.scheduler.plan(command)
        line = Line(command, tag, expect, mode, batch, separate_after=separate_after)
        self.scheduler.submit(line)
        self.lines.append(line)
        return line

    def flush(self) -> None:
        queued = [line for line in self.lines if not line.written]
        data = self.scheduler.next_write()
        self.inbox += data
        written = data.decode().split("\r")[:-1]
        start = len(self.wire)
        self.wire += written
        # Each request line is found after the one before it: a separator or marker of
        # the same text (``?err``) written ahead of it is not taken for it. A request
        # written out of order is then not found at all (ValueError fails the test).
        cursor = 0
        for line in queued:
            if line.written:
                found = written.index(line.command.line, cursor)
                self.writes[line.tag] = (start + found, frozenset(self.answered))
                cursor = found + 1
        assert self.scheduler.credit.outstanding <= self.limit
        assert len(self.inbox) <= BUFFER

    def process(self, count: int) -> None:
        """The controller interprets up to ``count`` buffered lines."""
        for _ in range(count):
            if b"\r" not in self.inbox:
                return
            line, _, rest = bytes(self.inbox).partition(b"\r")
            self.inbox[:] = rest
            before = len(self.outbox)
            self.model.handle_line(line, 0.0)
            self.outputs.append(bytes(self.outbox[before:]).decode())

    def deliver(self, count: int) -> None:
        """``count`` bytes of the replies reach the driver."""
        chunk, self.outbox[:] = bytes(self.outbox[:count]), self.outbox[count:]
        for event in self.core.events(chunk):
            if isinstance(event, Replied | Acknowledged | Echoed):
                lines = event.lines if isinstance(event, Replied) else None
                if self.scheduler.replied(event.tag, lines,
                                          confirms=not isinstance(event, Echoed)):
                    continue
                assert isinstance(event.tag, int)
                if isinstance(event, Replied):
                    self.replies[event.tag] = event.lines
                self.answered.add(event.tag)

    def drain(self) -> None:
        for _ in range(10_000):
            self.flush()
            if not self.inbox and not self.outbox and not self.scheduler.queued:
                return
            self.process(1)
            self.deliver(len(self.outbox))
        raise AssertionError("the link never drained")


#: Reads whose replies look alike (one number each) or not, and reply-less sets.
READS = ["?vel x", "?vel y", "?accel x", "?err", "?pos", "?statusaxis", "?dim"]
SETS = ["!vel x 12.5", "!vel y 3", "!accel x 1.5", "!trigp -1 2.5", "!trigp -1 100"]


def _own_edge(text: str) -> Edge:
    """The reply of a line the scheduler wrote itself (credit marker, separator), in
    mode 1."""
    if text in ("err", "?err"):
        return Edge((ONE_NUMBER,))
    if text == "?help":
        return Edge((ReplyPattern(ReplyKind.HELP),))
    return Edge((marker_pattern(f"ERROR {text.split()[1]},"),))  # ?help N


def _back(line: Line) -> Edge:
    """The back edge of ``line``'s reply, as a core registers it."""
    core = ProtocolCore(autostatus=line.written_mode)
    core.send(line.command, line.tag)
    assert core.sent is not None
    return core.sent[1]


def _owes_reply(line: Line) -> bool:
    return line.owes is not None


ops = st.lists(
    st.one_of(
        st.tuples(st.just("read"), st.sampled_from(READS), st.booleans()),
        st.tuples(st.just("trail"), st.sampled_from(READS), st.booleans()),
        st.tuples(st.just("set"), st.sampled_from(SETS), st.booleans()),
        st.tuples(st.just("process"), st.integers(0, 6), st.booleans()),
        st.tuples(st.just("deliver"), st.integers(0, 40), st.booleans()),
        st.tuples(st.just("withdraw"), st.integers(0, 5), st.booleans()),
    ),
    min_size=5,
    max_size=80,
)


@settings(max_examples=150, deadline=None)
@given(ops, st.integers(60, 255), st.integers(10, 200))
@example([("read", "?vel x", False)] * 3 + [("read", "?statusaxis", False)] * 2
         + [("read", "?err", False)], 60, 10)  # a separator ?err ahead of the user's ?err
def test_random_traffic_keeps_every_rule(steps: list[tuple[str, object, bool]], limit: int,
                                         chunk: int) -> None:
    link = Link(limit=limit, chunk=chunk)
    batch = object()
    withdrawn: set[int] = set()
    for op, arg, flag in steps:
        if op in ("read", "set", "trail"):
            assert isinstance(arg, str)
            link.submit(arg, batch if flag else None, separate_after=op == "trail")
        elif op == "process":
            assert isinstance(arg, int)
            link.process(arg)
        elif op == "deliver":
            assert isinstance(arg, int)
            link.deliver(arg)
        else:
            assert isinstance(arg, int)
            queued = [line for line in link.lines
                      if not line.written and line.tag not in withdrawn]
            doomed = queued[-arg:] if flag else queued[:arg]
            removed = link.scheduler.withdraw(doomed)
            assert {id(x) for x in removed} == {id(x) for x in doomed}
            withdrawn |= {line.tag for line in removed}
            assert all(not line.written for line in removed)
        link.flush()
    link.drain()
    # All that is still outstanding: reply-less lines at the end, which no marker follows
    # until more traffic comes (a marker is due only when it is needed).
    assert link.scheduler.credit.outstanding == link.scheduler.credit.unmarked
    assert not link.model.internal_errors

    sent = [line for line in link.lines if line.tag not in withdrawn]
    assert all(line.written for line in sent)
    # FIFO: request lines are on the wire in submission order.
    indexes = [link.writes[line.tag][0] for line in sent]
    assert indexes == sorted(indexes)
    assert [link.wire[i] for i in indexes] == [line.command.line for line in sent]
    # Every request got the reply the controller gave to its own line.
    for line in sent:
        if line.expectation.rule.count or line.expectation.rule.terminator:
            own = link.outputs[link.writes[line.tag][0]].split("\r")[:-1]
            assert link.replies[line.tag] == tuple(own), line.command.line
    # Look-alike requests in a row: a separator between them, or the first was answered
    # before the second was written; unless both belong to the same batch.
    owing = [line for line in sent if _owes_reply(line)]
    requests = {link.writes[line.tag][0] for line in link.lines if line.written}
    for first, second in itertools.pairwise(owing):
        assert second.owes is not None
        back = _back(first)
        if not back.overlaps(second.owes):
            continue
        if first.batch is not None and first.batch is second.batch:
            continue
        start, end = link.writes[first.tag][0], link.writes[second.tag][0]
        own = [link.wire[i] for i in range(start + 1, end) if i not in requests]
        separated = any(not _own_edge(text).overlaps(back)
                        and not _own_edge(text).overlaps(second.owes) for text in own)
        assert separated or first.tag in link.writes[second.tag][1], (first.command.line,
                                                                      second.command.line)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.sampled_from(SETS[3:]), min_size=1, max_size=120),
       st.integers(1, 30))
def test_replyless_runs_are_confirmed_by_markers(lines: list[str], split: int) -> None:
    link = Link()
    for text in lines:
        link.submit(text)
        link.flush()
        link.process(1)
        link.deliver(split)
    link.drain()
    assert link.scheduler.credit.outstanding == link.scheduler.credit.unmarked
    markers = link.wire.count(MARKER.decode().rstrip())
    assert markers >= sum(map(len, lines)) // (link.scheduler.credit.chunk + 20)
    assert link.scheduler.credit.peak <= 255


def test_a_held_line_waits_for_credit_and_keeps_order() -> None:
    link = Link(limit=40, chunk=20)
    first = link.submit("!trigp -1 2.5")
    second = link.submit("!trigp -1 3.5")
    third = link.submit("?vel x")
    link.flush()
    assert first.written and not third.written
    link.drain()
    assert link.writes[first.tag][0] < link.writes[second.tag][0] < link.writes[third.tag][0]
    assert link.replies[third.tag]


def test_look_alike_reads_get_a_separator_unless_batched() -> None:
    link = Link()
    link.submit("?vel x")
    link.submit("?accel x")
    link.flush()
    assert link.wire == ["?vel x", "?help", "?accel x"]  # ?err would look alike
    batched = Link()
    batch = object()
    batched.submit("?vel x", batch)
    batched.submit("?accel x", batch)
    batched.flush()
    assert batched.wire == ["?vel x", "?accel x"]


def test_a_separator_behind_a_line_spares_the_next_look_alike_one() -> None:
    # A move's confirming ?pos, then the next move's ?err probe (#19): the separator
    # goes out with the ?pos, not in front of the next line.
    link = Link()
    link.submit("?statusaxis")
    link.submit("?pos", separate_after=True)
    link.flush()
    assert link.wire == ["?statusaxis", "?pos", "?help"]  # ?err would look like ?pos
    link.drain()
    link.submit("?err")
    link.flush()
    assert link.wire[3:] == ["?err"]
    # Still in flight: the same, the ?err needs no separator of its own either.
    pipelined = Link()
    pipelined.submit("?pos", separate_after=True)
    pipelined.submit("?err")
    pipelined.flush()
    assert pipelined.wire == ["?pos", "?help", "?err"]


def test_no_separator_behind_a_line_when_the_credit_is_short_or_separators_are_off(
        ) -> None:
    # Skipping it never weakens rule 3: the next look-alike line gets its own.
    short = Link(limit=20, chunk=5)
    short.submit("?statusaxis")  # 12 bytes, ?pos 5: the 6 of ?help do not fit
    short.submit("?pos", separate_after=True)
    short.flush()
    assert short.wire == ["?statusaxis", "?pos"]
    short.drain()
    short.submit("?err")
    short.drain()
    assert short.wire[-2:] == ["?help", "?err"]
    off = Link()
    off.scheduler.separators = False
    off.submit("?pos", separate_after=True)
    off.submit("?err")
    off.flush()
    assert off.wire == ["?pos"]  # the ?err waits for the ?pos reply instead


def test_a_marker_error_marks_the_lines_it_covers() -> None:
    link = Link(chunk=1)  # a marker after every reply-less line
    link.submit("!trigp x 0")
    lines = [link.submit(text) for text in
             ["!trigp -1 1.0", "!trigp -1 2.0", "!trigp -1 1.5", "!trigp -1 3.0"]]
    link.drain()
    assert "err" in link.wire
    assert [line.chunk_error for line in lines] == [None, None, 5, None]


def test_mode_projection_follows_the_queue_and_withdraw() -> None:
    link = Link(limit=5, chunk=1)  # nothing fits: every line stays queued
    link.submit("?vel x")
    change = link.submit("!autostatus 2")
    _, mode, _ = link.scheduler.plan(parse("?pos"))
    assert mode == 2
    link.scheduler.withdraw([change])
    _, mode, _ = link.scheduler.plan(parse("?pos"))
    assert mode == 1


def test_hold_stops_lines_submitted_after_it() -> None:
    link = Link()
    before = link.submit("?vel x")
    link.scheduler.hold()
    after = link.submit("?pos")
    link.flush()
    assert before.written and not after.written
    assert link.scheduler.queued_up_to(before.tag) is False
    link.scheduler.release()
    link.flush()
    assert after.written


def test_wire_size_is_what_the_core_writes() -> None:
    core = ProtocolCore()
    for text in ["?pos", "!trigp -1 2.5", "?detext", "err"]:
        command: Command = parse(text)
        tag, mode, expect = WriteScheduler(core).plan(command)
        assert Line(command, tag, expect, mode).size == wire_size(command, expect)
        data, _ = core.send(command, tag)
        assert len(data) == wire_size(command, expect)


# -- runs of reply-less lines: one record, the same wire ---------------------------------

groups = st.lists(
    st.one_of(
        st.tuples(st.just("rows"), st.lists(st.integers(-50, 50), min_size=1, max_size=40)),
        st.tuples(st.just("read"), st.sampled_from(READS)),
        st.tuples(st.just("process"), st.integers(0, 8)),
        st.tuples(st.just("deliver"), st.integers(0, 60)),
    ),
    min_size=1, max_size=30,
)


@settings(max_examples=150, deadline=None)
@given(groups, st.integers(60, 255), st.integers(10, 200), st.booleans())
def test_a_run_writes_what_its_lines_would(steps: list[tuple[str, object]], limit: int,
                                           chunk: int, batched: bool) -> None:
    """The fast path (one Run per group of list entries) against the plain one (one Line
    per entry) on the same traffic: the same bytes on the wire in the same writes, the
    same replies and the same list on the controller."""
    plain, fast = Link(limit=limit, chunk=chunk), Link(limit=limit, chunk=chunk)
    writes: dict[int, list[bytes]] = {id(plain): [], id(fast): []}
    batch = object() if batched else None
    for link in (plain, fast):
        link.submit("!trigp x 0")
    for op, arg in steps:
        for link in (plain, fast):
            if op == "rows":
                assert isinstance(arg, list)
                commands = [parse(f"!trigp -1 {value / 4}") for value in arg]
                if link is plain:
                    for command in commands:
                        link.submit(command.line, batch)
                else:
                    run = link.scheduler.pack(commands, batch)
                    assert run is not None and len(run) == len(commands)
                    link.scheduler.submit(run)
            elif op == "read":
                assert isinstance(arg, str)
                link.submit(arg, batch)
            elif op == "process":
                assert isinstance(arg, int)
                link.process(arg)
            else:
                assert isinstance(arg, int)
                link.deliver(arg)
            before = len(link.inbox)
            link.flush()
            writes[id(link)].append(bytes(link.inbox[before:]))
    plain.drain()
    fast.drain()
    assert writes[id(plain)] == writes[id(fast)]
    assert plain.wire == fast.wire
    assert plain.outputs == fast.outputs
    assert sorted(plain.replies.values()) == sorted(fast.replies.values())
    assert plain.model.triggers.entries == fast.model.triggers.entries


def test_a_run_owing_replies_in_the_mode_in_force_goes_line_by_line() -> None:
    link = Link()
    run = link.scheduler.pack([parse("!trigp x 0"), parse("!trigp -1 1.0"),
                               parse("!trigp -1 2.0")])
    assert run is not None
    link.core.autostatus = 2  # adopted from the controller after the run was packed
    link.core.ack_reads = AckReads.NO  # as the protocol finds out when mode 2 is entered
    link.model.set_autostatus(2)
    link.scheduler.submit(run)
    link.drain()
    # Acknowledged lines in a row look alike: separators between them, as for any line.
    assert [text for text in link.wire if text.startswith("!")] == [
        "!trigp x 0", "!trigp -1 1.0", "!trigp -1 2.0"]
    assert "?err" in link.wire
    assert link.scheduler.credit.outstanding == 0  # each acknowledgement confirmed its line
    assert link.model.triggers.entries == [1.0, 2.0]


def test_withdrawing_a_run_takes_back_its_lines_not_yet_written() -> None:
    link = Link(limit=60, chunk=20)
    run = link.scheduler.pack([parse(f"!trigp -1 {i}") for i in range(1, 30)])
    assert run is not None
    link.scheduler.submit(run)
    link.flush()
    assert 0 < run.next < len(run)
    assert link.scheduler.withdraw([run]) == [run]
    assert link.scheduler.queued == 0
    link.drain()
    assert len([text for text in link.wire if text.startswith("!trigp")]) == run.next


def test_only_reply_less_lines_make_a_run() -> None:
    scheduler = WriteScheduler(ProtocolCore())
    assert scheduler.pack([parse("!trigp -1 1.0"), parse("?trigc")]) is None
    assert scheduler.pack([]) is None
    scheduler.core.autostatus = 2  # every ! line is acknowledged
    assert scheduler.pack([parse("!trigp -1 1.0")]) is None


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1e4, 1e4).map(lambda v: round(v, 4)), min_size=1, max_size=40),
       st.sampled_from(["trigp", "snsa"]))
def test_a_run_from_bytes_is_the_run_from_commands(values: list[float], name: str) -> None:
    # The upload's row-value path (encode_rows, pack_lines) against the plain one.
    rows = [[v] * (1 if name == "trigp" else 3) for v in values]
    commands = list(build_rows(name, [-1], rows))
    lines = list(encode_rows(name, [-1], rows))
    scheduler = WriteScheduler(ProtocolCore())
    plain = scheduler.pack(commands)
    fast = scheduler.pack_lines(commands[0], lines)
    assert plain is not None and fast is not None
    assert (fast.blob, fast.ends, fast.mode, fast.expectation, fast.command) == (
        plain.blob, plain.ends, plain.mode, plain.expectation, plain.command)


def test_lines_owing_replies_or_of_another_instruction_make_no_run_from_bytes() -> None:
    scheduler = WriteScheduler(ProtocolCore())
    template = parse("!trigp -1 1.0")
    assert scheduler.pack_lines(template, [b"!trigp -1 1.0\r", b"!trigp -1 2.0\r"])
    assert scheduler.pack_lines(template, [b"!trigp -1 1.0\r", b"!snsa -1 1 2 3\r"]) is None
    assert scheduler.pack_lines(template, []) is None
    scheduler.core.autostatus = 2  # every ! line is acknowledged
    assert scheduler.pack_lines(template, [b"!trigp -1 1.0\r"]) is None


def test_an_exchange_written_outside_the_queue_counts_its_lines() -> None:
    link = Link()
    link.submit("?vel x")
    link.flush()
    assert link.scheduler.exchanged(3) == 4 == link.scheduler.written_lines


def _written(mode: int, *lines: str, ack_reads: AckReads | None = AckReads.NO) -> list[str]:
    """What a scheduler writes at once for ``lines`` in autostatus ``mode``."""
    core = ProtocolCore(autostatus=mode, marker_seed=0)
    core.ack_reads = ack_reads
    scheduler = WriteScheduler(core)
    for text in lines:
        command = parse(text)
        tag, planned, expect = scheduler.plan(command)
        scheduler.submit(Line(command, tag, expect, planned))
    return scheduler.next_write().decode().split("\r")[:-1]


def test_lookalike_reads_get_a_separator_in_every_mode() -> None:
    # Mode 4: a read's echo is optional (the manual's firmware sends none), so the
    # numbers it is sure to get are what meet (#37).
    reads = ("?accel z", "?vel y", "?accel x")
    for mode in range(5):
        assert _written(mode, *reads) == ["?accel z", "?help", "?vel y", "?help",
                                          "?accel x"], mode


def test_a_lost_request_line_cannot_hand_its_neighbours_reply_over() -> None:
    # Mode 2, reads acknowledged after their data: "1.5" "OK..." per read. The last sure
    # lines differ (an OK... then a number), but with the first line lost the second's
    # number and OK... would fit the first: a separator goes between.
    assert _written(2, "?vel x", "?accel x", ack_reads=AckReads.AFTER) == [
        "?vel x", "?help", "?accel x"]


def test_moves_in_mode_2_are_separated_by_their_probes_replies() -> None:
    # A move's OK... may come only with its report (switch move_ok): the ?err behind it
    # is what it is sure to get, and the next move's ?err looks like it.
    assert _written(2, "!moa x 1", "!moa x 2") == ["!moa x 1", "?err", "?help", "!moa x 2",
                                                   "?err"]
