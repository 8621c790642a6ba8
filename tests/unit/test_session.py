"""Sans-IO tests of the link session (tango_aio.sansio._session), driven synchronously.

Every transition of :data:`~tango_aio.sansio._linkstate.TRANSITIONS` is reached through the
session's own methods (the calls the protocol makes), with time passed in. The exchanges
run against the emulator's interpreter (``ControllerModel``, no event loop), its replies
split at every point hypothesis picks on the way back.
"""

from __future__ import annotations

import collections
from collections.abc import Hashable
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.errors import ProtocolError
from tango_aio.sansio._core import (
    AckReads,
    Dropped,
    HelpStyle,
    Mismatched,
    ProtocolCore,
    Replied,
)
from tango_aio.sansio._exchange import STATUS_READ, Until, nothing_trails_help, status_tail
from tango_aio.sansio._linkstate import (
    REPLY_WAITS,
    TRANSITIONS,
    Barrier,
    LinkEvent,
    LinkState,
    ModeVerdict,
    Outcome,
    Overdue,
    SessionStateError,
    Silence,
)
from tango_aio.sansio._linktiming import BITS_PER_BYTE, QUIET_BYTES, byte_time
from tango_aio.sansio._session import QUIET_INTERVAL, LinkSession
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import PROFILES, Firmware

S, E = LinkState, LinkEvent


@dataclass
class Link:
    """A session, its core and what the adapter would do with their answers."""

    session: LinkSession = field(init=False)
    written: list[bytes] = field(default_factory=list)
    outcomes: list[Outcome] = field(default_factory=list)
    markers_answered: list[Hashable] = field(default_factory=list)
    tags: int = 0

    def __post_init__(self) -> None:
        self.session = LinkSession(ProtocolCore(marker_seed=0), dead_after=2,
                                   keepalive=10.0)

    @property
    def core(self) -> ProtocolCore:
        return self.session.core

    def state(self) -> LinkState:
        """The session's state, read afresh (not narrowed by an earlier check)."""
        return self.session.state

    def help_style(self) -> HelpStyle:
        """The core's help style, read afresh."""
        return self.core.help_style

    def tag(self) -> int:
        self.tags += 1
        return self.tags

    def resync(self, style: HelpStyle = HelpStyle.NUMBER, *, ctrl_c: bool = False) -> int:
        self.core.help_style = style
        tag = self.tag()
        self.written.append(self.session.begin_resync(tag, ctrl_c=ctrl_c))
        return tag

    def exchange(self, lines: list[str] | None = None, until: Until = Until.NUMBER,
                 marker: str | None = None) -> None:
        self.written.append(self.session.begin_exchange(lines or ["?err"], until, marker))

    def feed(self, data: bytes, now: float = 0.0) -> None:
        """Bytes from the controller, handled as the protocol does."""
        for event in self.core.events(data):
            self.session.line_received()
            if isinstance(event, Dropped):
                self.outcomes.append(self.session.line_dropped(event.line, now))
            elif isinstance(event, Replied) and self.session.replied(event.tag):
                self.markers_answered.append(event.tag)

    def marker_reply(self) -> bytes:
        """The reply of the marker written last (``?help N`` -> ``ERROR N,...``)."""
        for data in reversed(self.written):
            if b"?help " in data:
                code = data.split(b"?help ")[-1].split(b"\r")[0].decode()
                return f"ERROR {code},text\r".encode()
        raise AssertionError("no marker written")


# -- every transition of the table --------------------------------------------------------

def _reach(link: Link, state: LinkState, event: LinkEvent) -> None:
    """Bring ``link`` into ``state`` the way the protocol does, on the path from which
    ``event`` can happen."""
    if state is S.IN_STEP:
        if event in (E.MARKER_ANSWERED, E.EXCHANGE_ENDED):
            # Ctrl+C overtook an exchange, whose end brought the stream in step: the core
            # still owes the marker's reply, and the exchange has not ended yet.
            link.exchange()
            link.resync(ctrl_c=True)
            if event is E.MARKER_ANSWERED:
                link.session.end_exchange(in_step=True)
            else:
                link.feed(link.marker_reply())
    elif state is S.RESYNC:
        if event is E.EXCHANGE_ENDED:
            link.exchange()
        link.resync()
    elif state is S.QUIET_RESYNC:
        if event is E.EXCHANGE_ENDED:
            link.exchange()
        link.resync(HelpStyle.NONE)
    elif state is S.EXCHANGE:
        link.exchange()
    else:
        if event is E.MARKER_ANSWERED:
            link.resync()
        elif event is E.EXCHANGE_ENDED:
            link.exchange()
        link.session.closed()
    assert link.session.state is state


def _fire(link: Link, event: LinkEvent) -> None:
    """Make ``event`` happen through the session's methods."""
    session = link.session
    if event is E.MARKER_WRITTEN:
        link.resync()
    elif event is E.HELP_WRITTEN:
        link.resync(HelpStyle.NONE)
    elif event is E.EXCHANGE_WRITTEN:
        link.exchange()
    elif event is E.MARKER_ANSWERED:
        link.feed(link.marker_reply())
        assert link.markers_answered
    elif event is E.QUIET:
        link.feed(b"ERROR 0,no error\r", now=1.0)
        assert link.outcomes[-1] is Outcome.WAIT_QUIET
        assert session.quiet_deadline == 1.0 + session.quiet_interval
        assert session.quiet_elapsed() is Outcome.IN_STEP
    elif event is E.EXCHANGE_ENDED:
        session.end_exchange(in_step=True)
    elif event is E.DEAD:
        assert session.unanswered(1, 1) is Silence.ALIVE
        assert session.unanswered(2, 2) is Silence.DEAD
    else:
        session.closed()


def _agrees_with_the_core(link: Link) -> None:
    """The state says what the core does with a line (the core is the one that drops)."""
    state, core = link.session.state, link.core
    if state is S.IN_STEP:
        assert not core.resyncing
    elif state is S.RESYNC:
        assert core.resyncing and not core.quiet
    elif state in (S.QUIET_RESYNC, S.EXCHANGE):
        assert core.quiet
    if state is S.EXCHANGE:
        assert link.session.exchange is not None


@pytest.mark.parametrize(("state", "event"), sorted(TRANSITIONS, key=str))
def test_every_transition_of_the_table(state: LinkState, event: LinkEvent) -> None:
    link = Link()
    _reach(link, state, event)
    _agrees_with_the_core(link)
    _fire(link, event)
    assert link.session.state is TRANSITIONS[state, event]
    _agrees_with_the_core(link)


def test_every_state_has_its_transitions_and_lost_is_final() -> None:
    assert {state for state, _ in TRANSITIONS} == set(LinkState)
    assert all(after is S.LOST for (before, _), after in TRANSITIONS.items()
               if before is S.LOST)
    assert all(TRANSITIONS[state, event] is S.LOST for state in LinkState
               for event in (E.DEAD, E.CLOSED) if state is not S.LOST)


def test_an_event_the_table_does_not_list_raises() -> None:
    link = Link()
    link.exchange()
    with pytest.raises(SessionStateError, match="exchange written"):
        link.exchange()  # one exchange at a time (the protocol's barrier lock)


def test_events_that_change_nothing_leave_the_state_alone() -> None:
    link = Link()
    assert not link.session.replied(None) and not link.session.replied(99)
    assert link.session.quiet_elapsed() is Outcome.NONE  # not quiet: nothing to end
    assert link.session.line_dropped("7", 0.0) is Outcome.NONE
    assert link.session.state is S.IN_STEP


# -- resync and quiet resync --------------------------------------------------------------

def test_a_marker_resync_ends_at_its_reply_and_not_before() -> None:
    link = Link()
    tag = link.resync()
    assert link.core.resyncing and link.written[-1].startswith(b"?help ")
    link.feed(b"12.5\rERROR 0,no error\r")
    assert link.session.state is S.RESYNC and not link.markers_answered
    link.feed(link.marker_reply())
    assert link.markers_answered == [tag] and link.state() is S.IN_STEP
    assert not link.core.resyncing


def test_a_newer_marker_supersedes_the_older() -> None:
    link = Link()
    first = link.resync()
    second = link.resync()
    link.feed(link.marker_reply())
    assert link.markers_answered == [second] and first not in link.markers_answered


@pytest.mark.parametrize(("lines", "ends"), [
    (["ERROR 0,no error"], True),
    (["ERROR 0,no error", "help"], True),  # help's echo (mode 4)
    (["ERROR 0,no error", "OK..."], True),  # an acknowledgement (mode 2)
    (["ERROR 0,no error", "12.5"], False),  # another line after help's reply
    (["12.5"], False),
    (["12.5", "ERROR 0,no error"], True),
])
def test_a_quiet_resync_ends_when_helps_reply_was_the_last_line(
        lines: list[str], ends: bool) -> None:
    link = Link()
    link.resync(HelpStyle.NONE)
    assert link.written[-1] == b"help\r" and link.core.quiet
    for now, line in enumerate(lines):
        link.feed(f"{line}\r".encode(), now=float(now))
    assert link.outcomes == [Outcome.WAIT_QUIET] * len(lines)
    assert link.session.quiet_deadline == len(lines) - 1 + link.session.quiet_interval
    assert link.session.quiet_elapsed() is (Outcome.IN_STEP if ends else Outcome.NONE)
    assert link.session.state is (S.IN_STEP if ends else S.QUIET_RESYNC)
    assert link.core.quiet is not ends


def test_a_quiet_resync_does_not_end_once_the_link_is_lost() -> None:
    link = Link()
    link.resync(HelpStyle.NONE)
    link.feed(b"ERROR 0,no error\r")
    link.session.closed()
    assert link.session.quiet_elapsed() is Outcome.NONE


def test_a_completion_report_is_not_dropped_and_so_does_not_rearm_the_quiet_wait() -> None:
    link = Link()
    link.resync(HelpStyle.NONE)
    link.feed(b"ERROR 0,no error\r@@@-.\r")
    assert link.outcomes == [Outcome.WAIT_QUIET]


# -- exchanges ---------------------------------------------------------------------------

def _run(link: Link, firmware: Firmware, lines: list[str], until: Until,
         marker: str | None, cuts: list[int], *, mode: int = 1,
         before: bytes = b"") -> list[Outcome]:
    """An exchange against the emulator in ``mode``; its replies (after ``before``) reach
    the session cut at ``cuts``. Returns the outcomes, up to the first COLLECTED."""
    out = bytearray()
    model = ControllerModel(out.extend, SimConfig(firmware=firmware), now=0.0)
    if mode != 1:
        model.handle_line(f"!autostatus {mode}".encode(), 0.0)
        out.clear()
    link.exchange(lines, until, marker)
    for line in link.written[-1].split(b"\r")[:-1]:
        model.handle_line(line, 0.0)
    data = before + bytes(out)
    start = 0
    for cut in sorted({0, *(c % (len(data) + 1) for c in cuts), len(data)}):
        link.feed(data[start:cut])
        start = cut
        if Outcome.COLLECTED in link.outcomes:
            break
    return link.outcomes


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 400), max_size=8), st.sampled_from([0, 1, 3]),
       st.sampled_from(["no", "before", "after"]))
def test_a_mode_read_ends_at_helps_reply_where_nothing_trails_it(
        cuts: list[int], mode: int, ack_reads: str) -> None:
    link = Link()
    sent = link.session.mode_lines([])
    outcomes = _run(link, Firmware(ack_reads=ack_reads), sent, Until.HELP, None, cuts,
                    mode=mode)
    assert outcomes[-1] is Outcome.COLLECTED
    exchange = link.session.exchange
    assert exchange is not None
    assert link.session.mode_read(sent, exchange.lines) == mode == link.core.autostatus
    assert link.session.end_exchange(in_step=True) is Outcome.IN_STEP
    assert link.session.state is S.IN_STEP and not link.core.resyncing


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 400), max_size=8),
       st.sampled_from(["no", "before", "after"]), st.booleans())
def test_a_mode_change_to_2_finds_how_reads_are_acknowledged(
        cuts: list[int], ack_reads: str, from_2: bool) -> None:
    link = Link()
    sent = link.session.mode_lines(["!autostatus 2"])
    outcomes = _run(link, Firmware(ack_reads=ack_reads), sent, Until.HELP, None, cuts,
                    mode=2 if from_2 else 1)
    # Mode 2 may add a line after help's reply: the exchange waits for quiet.
    assert Outcome.COLLECTED not in outcomes and outcomes[-1] is Outcome.WAIT_QUIET
    assert link.session.quiet_elapsed() is Outcome.COLLECTED
    exchange = link.session.exchange
    assert exchange is not None
    assert link.session.mode_read(sent, exchange.lines) == 2
    assert link.core.ack_reads is AckReads(ack_reads)
    assert link.session.detected == {"ack_reads": ack_reads}


def test_a_mode_read_without_the_reply_of_autostatus_raises() -> None:
    link = Link()
    with pytest.raises(ProtocolError, match="no \\?autostatus reply"):
        link.session.mode_read(["?autostatus", "?help"], ["ERROR 0,no error"])


@pytest.mark.parametrize(("lines", "nothing"), [
    (["1", "ERROR 0,x"], True), (["0"], True), (["3"], True), (["2", "ERROR 0,x"], False),
    (["4"], False), (["ERROR 0,x"], False), (["?autostatus", "1"], True)])
def test_nothing_trails_help_only_in_modes_0_1_3(lines: list[str], nothing: bool) -> None:
    assert nothing_trails_help(lines) is nothing


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 400), max_size=8), st.sampled_from([1, 2, 4]),
       st.sampled_from([b"", b"7\r", b"ERROR 81,stale\r0\r", b"12.5 3.0\rERROR 81,x\r"]))
def test_step_0_of_the_detection_sees_two_marker_replies_and_a_number(
        cuts: list[int], mode: int, stale: bytes) -> None:
    """Firmware 1.71 answers ``?help N`` with ``ERROR N,...`` (L2919): the exchange ends
    at ``?err``'s number, whatever stale lines came first and however the bytes are cut."""
    link = Link()
    code = link.session.begin_detect()
    assert link.core.help_style is HelpStyle.NONE
    lines, marker = link.session.numbered_marker_lines(code)
    _run(link, PROFILES["manual"], lines, Until.MARKER, marker, cuts, mode=mode,
         before=stale)
    assert link.outcomes[-1] is Outcome.COLLECTED
    exchange = link.session.exchange
    assert exchange is not None and link.session.numbered_read(exchange)
    link.session.end_exchange(in_step=True)
    link.session.end_detect()
    assert link.help_style() is HelpStyle.NUMBER
    assert link.session.detected == {"help_number": "yes"}


@pytest.mark.parametrize("mode", [1, 2, 4])
def test_step_0_waits_for_quiet_when_help_n_has_no_number(mode: int) -> None:
    link = Link()
    code = link.session.begin_detect()
    lines, marker = link.session.numbered_marker_lines(code)
    outcomes = _run(link, PROFILES["legacy"], lines, Until.MARKER, marker, [], mode=mode)
    assert outcomes[-1] is Outcome.WAIT_QUIET
    assert link.session.quiet_elapsed() is Outcome.COLLECTED
    exchange = link.session.exchange
    assert exchange is not None and not link.session.numbered_read(exchange)
    assert link.core.help_style is HelpStyle.NONE


@pytest.mark.parametrize(("profile", "help_number", "style"), [
    ("manual", "yes", HelpStyle.NUMBER), ("manual", "no", HelpStyle.TEXT),
    ("legacy", "no", HelpStyle.NONE)])
@pytest.mark.parametrize("mode", [1, 2, 4])
@pytest.mark.parametrize("echo", ["before", "after"])
def test_step_2_of_the_detection_tells_how_help_n_answers(
        profile: str, help_number: str, style: HelpStyle, mode: int, echo: str) -> None:
    # echo=after in mode 4: the exchange ends with the echo of ?err, after its number.
    link = Link()
    link.session.begin_detect()
    code = link.core.pick_marker_code()
    sent = link.session.help_lines(code)
    firmware = Firmware(**{**PROFILES[profile].__dict__, "help_number": help_number,
                           "echo": echo})
    outcomes = _run(link, firmware, sent, Until.NUMBER, None, [], mode=mode)
    assert Outcome.COLLECTED in outcomes  # (an echo of ?err may trail its number)
    exchange = link.session.exchange
    assert exchange is not None
    link.session.help_read(code, sent, exchange.lines)
    link.session.end_exchange(in_step=True)
    link.session.end_detect()
    assert link.core.help_style is style
    assert link.session.detected == {"help_number": style.value}
    if style is HelpStyle.TEXT:
        assert link.core.help_text is not None and link.core.help_text[0] == code


def test_an_exchange_that_timed_out_routes_again() -> None:
    link = Link()
    link.exchange()
    link.session.exchange_timed_out()
    assert link.session.state is S.IN_STEP and not link.core.resyncing
    assert link.session.exchange is None
    # The adapter then resyncs; ending the exchange after that leaves a marker resync alone
    link.resync()
    assert link.session.end_exchange(in_step=False) is Outcome.NONE
    assert link.state() is S.RESYNC


def test_a_cancelled_exchange_asks_for_a_resync() -> None:
    link = Link()
    link.exchange()
    assert link.session.end_exchange(in_step=False) is Outcome.RESYNC
    assert link.session.state is S.IN_STEP and not link.core.resyncing


def test_an_exchange_overtaken_by_ctrl_c_keeps_collecting_what_the_core_drops() -> None:
    link = Link()
    link.exchange(["?autostatus", "?help"], Until.HELP)
    link.resync(ctrl_c=True)
    assert link.session.state is S.RESYNC and link.written[-1].startswith(b"\x03")
    link.feed(b"1\rERROR 0,no error\r")
    assert link.outcomes[-1] is Outcome.COLLECTED


# -- liveness ----------------------------------------------------------------------------

def test_lines_in_flight_together_count_once_and_any_line_resets_the_count() -> None:
    session = Link().session
    assert session.unanswered(3, 5) is Silence.ALIVE  # lines 1-5 in flight: counted once
    assert session.unanswered(4, 5) is session.unanswered(5, 5) is Silence.ALIVE
    assert session.silent == 1
    session.line_received()
    assert session.unanswered(6, 6) is Silence.ALIVE and session.silent == 1
    assert session.unanswered(7, 7) is Silence.DEAD and session.lost
    assert session.unanswered(8, 8) is Silence.ALIVE  # dead once


@pytest.mark.parametrize(("now", "busy", "wait"), [
    (3.0, False, 7.0), (3.0, True, 7.0), (10.0, False, 0.0), (12.0, True, 10.0)])
def test_the_keepalive_probes_an_idle_link_after_its_interval(
        now: float, busy: bool, wait: float) -> None:
    session = Link().session
    session.reply_heard(0.0)
    assert session.keepalive_wait(now, busy=busy) == wait


def test_after_a_probe_the_next_comes_half_an_interval_later() -> None:
    session = Link().session
    session.reply_heard(0.0)
    session.keepalive_probed(20.0)
    assert session.keepalive_wait(20.0, busy=False) == 5.0
    session.reply_heard(24.0)
    session.keepalive_probed(25.0)  # a reply since: it counts
    assert session.keepalive_wait(25.0, busy=False) == 9.0


def test_no_keepalive_without_an_interval() -> None:
    session = LinkSession(ProtocolCore())
    with pytest.raises(ValueError, match="no keepalive"):
        session.keepalive_wait(0.0, busy=False)



def test_the_first_resync_of_a_connect_detects_unless_it_is_a_ctrl_c() -> None:
    session = LinkSession(ProtocolCore(), detect=True)
    assert session.detects_first(ctrl_c=False) and not session.detects_first(ctrl_c=True)
    session.begin_detect()
    assert not session.detects_first(ctrl_c=False)  # once
    assert not LinkSession(ProtocolCore()).detects_first(ctrl_c=False)


def test_an_overdue_marker_is_written_again_only_for_the_newest_resync_under_way() -> None:
    link = Link()
    link.session.dead_after = 10
    assert link.session.marker_overdue(1, 1, newest=True) is Silence.ALIVE  # in step
    link.resync()
    assert link.session.marker_overdue(2, 2, newest=True) is Silence.MARKER_AGAIN
    assert link.session.marker_overdue(3, 3, newest=False) is Silence.ALIVE
    assert link.session.silent == 3  # each counted


def test_an_overdue_marker_that_declares_the_link_dead_is_not_written_again() -> None:
    link = Link()
    link.resync()
    assert link.session.marker_overdue(1, 1, newest=True) is Silence.MARKER_AGAIN
    assert link.session.marker_overdue(2, 2, newest=True) is Silence.DEAD
    assert link.state() is S.LOST
    # Markers in flight with one already counted count once: a new one only.
    link = Link()
    link.resync()
    assert link.session.marker_overdue(4, 5, newest=True) is Silence.MARKER_AGAIN
    assert link.session.marker_overdue(5, 5, newest=True) is Silence.MARKER_AGAIN
    assert link.session.silent == 1


@pytest.mark.parametrize(("queued", "written", "waits", "overdue"), [
    # Written before the wait began: counted at its first timeout.
    (False, True, 1, Overdue.UNANSWERED),
    # Queued when the wait began, written during it: once more, then counted.
    (True, True, 1, Overdue.WAIT_AGAIN),
    (True, True, REPLY_WAITS, Overdue.UNANSWERED),
    # Still queued, nothing owed ahead of it: taken back, never counted.
    (True, False, 1, Overdue.WITHDRAW),
    (True, False, REPLY_WAITS, Overdue.WITHDRAW),
])
def test_an_overdue_reply_waits_again_once_is_withdrawn_or_counted(
        queued: bool, written: bool, waits: int, overdue: Overdue) -> None:
    session = Link().session
    assert session.reply_overdue(queued=queued, written=written, waits=waits) is overdue
    assert session.silent == 0 and session.state is S.IN_STEP  # it decides, counts nothing


@pytest.mark.parametrize("autostatus", [1, 4])
def test_a_line_held_behind_a_reply_nobody_awaits_stalls_instead_of_being_withdrawn(
        autostatus: int) -> None:
    """A list upload's check read, held for credit behind lines whose replies no caller
    awaits: a credit marker ``err`` whose number was lost (autostatus 1), the echo of a
    list entry that was lost (autostatus 4: the echoes of the entries after it are not
    that echo, so the core keeps owing it). No deadline but the held line's covers that
    reply: its timeout resyncs the stream (STALLED). Behind a reply a caller awaits, or
    behind a resync, the line is only withdrawn."""
    link = Link()
    core, session = link.core, link.session
    core.autostatus = autostatus
    if autostatus == 4:
        for tag, value in (("entry 1", "0.5"), ("entry 2", "0.5137")):
            core.send(parse(f"!trigp -1 {value}"), tag)
        assert core.events(b"!trigp -1 0.5137\r")  # entry 1's echo was lost on the way
        assert core.pending_tags == ["entry 1", "entry 2"]
    else:
        core.send(parse("err"), "credit marker")
    head = core.pending_tags[0]
    assert session.reply_overdue(queued=True, written=False, waits=1) is Overdue.STALLED
    assert session.reply_overdue(queued=True, written=False, waits=1,
                                 awaited={head}) is Overdue.WITHDRAW
    assert session.silent == 0 and session.state is S.IN_STEP  # it decides, counts nothing
    link.resync()
    assert session.reply_overdue(queued=True, written=False, waits=1) is Overdue.WITHDRAW


def test_a_line_held_behind_the_err_the_core_wrote_behind_a_move_stalls() -> None:
    """Mode 2, reads acknowledged after their data: the ``?err`` the core writes behind a
    move got its number, then the power went (its ``OK...`` never comes; back in mode 1
    the controller acknowledges nothing, L2062, L2099-2103). No caller awaits that line,
    so only the held line's deadline covers it: STALLED (withdraw, count, resync; the
    restart is then found), not WITHDRAW, which would leave every later line held."""
    link = Link()
    core, session = link.core, link.session
    core.autostatus, core.ack_reads = 2, AckReads.AFTER
    assert core.send(parse("!moa 3.0"), "move")[0] == b"!moa 3.0\r?err\r"
    core.events(b"OK...\r0\r")
    assert core.pending_tags == [] and core.tail is not None  # the ?err's OK... is owed
    assert session.reply_overdue(queued=True, written=False, waits=1) is Overdue.STALLED
    core.events(b"OK...\r")
    assert session.reply_overdue(queued=True, written=False, waits=1) is Overdue.WITHDRAW


def test_a_line_where_an_acknowledgement_was_owed_counts_as_that_acknowledgement_missing(
        ) -> None:
    """Mode 2: a unit back in its power-on mode 1 acknowledges nothing (L2062,
    L2099-2103), so the next reply comes where an ``OK...`` is owed; the core puts the
    stream out of step, and the session says that acknowledgement went unanswered (the
    restart check follows, as after a timeout). A data reply that does not fit does not."""
    link = Link()
    core, session = link.core, link.session
    core.autostatus, core.ack_reads = 2, AckReads.AFTER
    core.send(parse("!vel x 5"), "set")
    core.send(parse("?pos"), "read")
    [mismatch] = core.events(b"0.0000 0.0000 0.0000\r")
    assert isinstance(mismatch, Mismatched) and mismatch.tag == "set"
    assert session.acknowledgement_missing(mismatch.expected)
    other = ProtocolCore(autostatus=2)
    other.ack_reads = AckReads.AFTER
    other.send(parse("?pos"), "read")
    [mismatch] = other.events(b"OK...\r")
    assert isinstance(mismatch, Mismatched)
    assert not session.acknowledgement_missing(mismatch.expected)


# -- the mode ----------------------------------------------------------------------------

@pytest.mark.parametrize(("asked", "actual", "verdict"), [
    (2, 2, ModeVerdict.IN_FORCE), (2, 1, ModeVerdict.KEPT_ANOTHER),
    (0, 4, ModeVerdict.KEPT_ANOTHER)])
def test_a_mode_change_failed_when_the_controller_kept_another_mode(
        asked: int, actual: int, verdict: ModeVerdict) -> None:
    assert LinkSession.mode_changed(asked, actual) is verdict


@pytest.mark.parametrize(("driver", "actual", "verdict"), [
    (2, 2, ModeVerdict.IN_FORCE), (2, 1, ModeVerdict.RESTARTED),
    (1, 1, ModeVerdict.IN_FORCE), (4, 1, ModeVerdict.RESTARTED)])
def test_another_mode_found_in_force_means_the_controller_restarted(
        driver: int, actual: int, verdict: ModeVerdict) -> None:
    assert LinkSession.mode_verified(driver, actual) is verdict


@pytest.mark.parametrize("restarted", [False, True])
def test_a_markers_owed_acknowledgement_does_not_hold_a_barrier(restarted: bool) -> None:
    """Mode 2 on firmware that acknowledges reads after their data: once the marker's
    reply came, the ``OK...`` behind it (never sent by a unit back in mode 1) holds no
    barrier; what the barrier's exchange then collects still reads the mode."""
    link = Link()
    session = link.session
    link.core.autostatus, link.core.ack_reads = 2, AckReads.AFTER
    link.resync()
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.WAIT
    link.feed(link.marker_reply())
    assert link.markers_answered and link.core.pending_tags  # its OK... still owed
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.CLEAR
    # Anything else still owed holds it as before: a line written behind the marker.
    link.core.send(parse("?pos x"), tag="pos")
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.WAIT
    # Restarted: the read's data alone; its own OK... still holds the barrier (the
    # read's caller has a deadline). Else both OK... come, and nothing is owed.
    link.feed(b"12.5\r" if restarted else b"OK...\r12.5\rOK...\r")
    expected = Barrier.WAIT if restarted else Barrier.CLEAR
    assert session.barrier(queued_before=False, queue_dropped=False) is expected
    assert bool(link.core.pending_tags) is restarted


def test_a_mode_change_waits_until_every_line_before_is_answered() -> None:
    link = Link()
    session = link.session
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.CLEAR
    # Ctrl+C dropped the queue, but nothing the change follows is left: it goes.
    assert session.barrier(queued_before=False, queue_dropped=True) is Barrier.CLEAR
    assert session.barrier(queued_before=True, queue_dropped=False) is Barrier.WAIT
    assert session.barrier(queued_before=True, queue_dropped=True) is Barrier.ABORTED
    link.core.send(parse("?pos x"), tag="pos")  # written, its reply owed
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.WAIT
    link.feed(b"12.5\r")
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.CLEAR
    link.resync()  # a resync under way holds it too
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.WAIT
    assert session.barrier(queued_before=False, queue_dropped=True) is Barrier.ABORTED
    link.feed(link.marker_reply())
    assert session.barrier(queued_before=False, queue_dropped=False) is Barrier.CLEAR


# -- link timing (sansio/_linktiming.py) and the step-0 marker number -------------------------

def test_the_first_byte_after_an_exchange_measures_the_round_trip() -> None:
    """Three round trips at least (the link may deliver in bursts): a 0.4 s round trip
    makes the quiet interval 1.2 s; later bytes of the same exchange measure nothing."""
    link = Link()
    link.session.begin_exchange(["?err"], Until.NUMBER, now=10.0)
    assert link.session.bytes_received(10.4) is Outcome.NONE  # no quiet deadline armed
    assert link.session.timing.round_trip == pytest.approx(0.4)
    assert link.session.quiet_interval == pytest.approx(1.2)
    assert link.session.bytes_received(30.0) is Outcome.NONE
    assert link.session.timing.round_trip == pytest.approx(0.4)


def test_an_exchange_over_before_its_first_byte_measures_nothing() -> None:
    link = Link()
    link.session.begin_exchange(["?err"], Until.NUMBER, now=0.0)
    link.session.exchange_timed_out()
    link.session.bytes_received(5.0)  # a late reply: not the link's round trip
    link.exchange()  # and one written without a time
    link.session.bytes_received(9.0)
    assert link.session.timing.round_trip == 0.0
    assert link.session.quiet_interval == QUIET_INTERVAL


def test_a_quiet_deadline_starts_again_at_every_byte_not_every_line() -> None:
    """At 1200 Bd a line takes longer on the wire than the quiet interval: bytes of a line
    still arriving keep the link from counting as quiet (#32 item 5)."""
    link = Link()
    link.resync(HelpStyle.NONE)
    link.feed(b"ERROR 3,help text\r", now=1.0)
    assert link.outcomes == [Outcome.WAIT_QUIET]
    interval = link.session.quiet_interval
    assert link.session.quiet_deadline == 1.0 + interval
    assert link.session.bytes_received(1.0 + interval / 2) is Outcome.WAIT_QUIET
    assert link.session.quiet_deadline == 1.0 + interval / 2 + interval
    assert link.session.quiet_elapsed() is Outcome.IN_STEP
    assert link.session.bytes_received(9.0) is Outcome.NONE  # nothing armed: nothing to do
    assert link.session.quiet_deadline is None


def test_a_known_baud_rate_lengthens_the_quiet_interval_and_nothing_shortens_it() -> None:
    link = Link()
    link.session.baud_known(byte_time(1200))
    assert link.session.quiet_interval == pytest.approx(QUIET_BYTES * BITS_PER_BYTE / 1200)
    longer = Link()
    longer.session.quiet_interval = 3600.0  # set by the caller: timing never shortens it
    longer.session.baud_known(byte_time(1200))
    longer.session.begin_exchange(["?err"], Until.NUMBER, now=0.0)
    longer.session.bytes_received(0.5)
    assert longer.session.quiet_interval == 3600.0


def test_step_0_avoids_the_numbers_recent_detections_used() -> None:
    """Sessions that would start at the same marker number (same seed) pick different
    step-0 numbers: an abandoned step 0's replies cannot pass for the next one's."""
    recent: collections.deque[int] = collections.deque(maxlen=4)
    codes = [Link().session.begin_detect(recent) for _ in range(4)]
    assert len(set(codes)) == 4 and list(recent) == codes
    first = ProtocolCore(marker_seed=0).pick_marker_code()
    assert codes[0] == first  # without recent ones, the core's own choice


@pytest.mark.parametrize(("lines", "tail"), [
    (["@@@-.-"], "yes"), (["JM.-"], "yes"), (["@@@-"], "no"), (["@@@-."], "dot"),
    (["M@."], "dot"),
    # A completion report that came meanwhile does not decide: the reply's tail does.
    (["@@@-.", "@@@-.-"], "yes"), (["@@@-.", "@@@-"], "no"), (["@@@-.", "E@@-."], "dot"),
    # Echoes, acknowledgements and the mode exchange's own replies are no letters.
    (["OK...", "1", "ERROR 0,no error"], None), (["ERR", "ERR 5"], None), ([], None)])
def test_how_statusaxis_ends_is_told_from_the_lines_of_its_exchange(
        lines: list[str], tail: str | None) -> None:
    assert status_tail(lines) == tail


def test_a_mode_exchange_with_statusaxis_records_its_tail_and_one_without_does_not() -> None:
    session = LinkSession(ProtocolCore())
    session.mode_read(["?autostatus", "?help"], ["@@@-.", "1", "ERROR 0,no error"])
    assert "status_tail" not in session.detected  # a report during a mode change
    assert session.mode_read([STATUS_READ, "?autostatus", "?help"],
                             ["@@@-.", "2", "ERROR 0,no error"]) == 2
    assert session.detected["status_tail"] == "dot"


@pytest.mark.parametrize("restore", [True, False])
def test_only_a_restart_check_resyncs_behind_lines_left_unanswered(restore: bool) -> None:
    """A restart check must not give up behind a stop's OK... that a unit back in mode 1
    never sends (and so release the held lines in the wrong mode); a mode change does."""
    assert LinkSession.barrier_overdue_resyncs(restore=restore) is restore
