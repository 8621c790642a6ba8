"""The sans-IO move tracker (tango_aio.moves._tracker), driven synchronously: where a
move's start comes from, and one move followed to its end by the reads fed to it."""

from __future__ import annotations

from collections.abc import Mapping

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.moves import (
    Follow,
    FollowStateError,
    Intent,
    MoveTracker,
    Next,
    Phase,
    Prove,
    Start,
    StartProof,
    failed_axes,
    failed_letters,
    moved_axes,
    optional_axes,
    position_tolerance,
    verdict,
)
from tango_aio.moves._timing import Budget
from tango_aio.status import ARRIVED_LETTERS, FAILED_LETTERS, MOVING

BUDGET = Budget(delay=0.0, travel=1.0, after=0.0, settle=0.0, limit=4.0)
TARGETS = {"x": 10.0, "y": -2.5}


def _follow(budget: Budget = BUDGET, *, reports: bool = True,
            targets: Mapping[str, float] | None = None, extend: float | None = None,
            moved: tuple[str, ...] = ("x", "y")) -> Follow:
    return Follow(moved, TARGETS if targets is None else targets, {}, budget, 0.0,
                  reports=reports, extend=None if extend is None else (lambda _t: extend))


def _read(follow: Follow, letters: Mapping[str, str], texts: Mapping[str, str],
          now: float, **kw: object) -> Intent:
    follow.reading()
    return follow.read(letters, texts, now, **kw)  # type: ignore[arg-type]


AT = {"x": "10.000", "y": "-2.500"}


def test_a_read_of_both_axes_at_their_targets_arrives() -> None:
    follow = _follow()
    intent = _read(follow, {"x": "@", "y": "@", "z": "@"}, AT, 1.1)
    assert intent.next is Next.ARRIVED and intent.letters == {"x": "@", "y": "@", "z": "@"}
    assert follow.phase is Phase.ENDED


def test_an_axis_short_of_its_target_fails_and_reads_e_in_the_letters() -> None:
    intent = _read(_follow(), {"x": "@", "y": "@"}, {"x": "9.000", "y": "-2.500"}, 1.1)
    assert intent.next is Next.FAILED and "X stopped short" in intent.message
    assert intent.letters == {"x": "E", "y": "@"}


def test_a_moving_axis_waits_and_the_polls_grow_after_the_expected_end() -> None:
    follow = _follow()
    waits = [_read(follow, {"x": "M", "y": "@"}, AT, now).until
             for now in (1.2, 1.3, 1.4)]
    assert waits[0] == pytest.approx(1.25) and waits[1] - 1.3 > waits[0] - 1.2


def test_the_budget_spent_with_an_axis_moving_times_out() -> None:
    intent = _read(_follow(), {"x": "M", "y": "@"}, AT, 4.0)
    assert intent.next is Next.TIMED_OUT


def test_a_provisional_budget_is_extended_once_then_times_out() -> None:
    follow = _follow(extend=2.0)
    assert _read(follow, {"x": "M", "y": "@"}, AT, 4.0).next is Next.WAIT
    assert follow.deadline == 6.0
    assert _read(follow, {"x": "M", "y": "@"}, AT, 6.0).next is Next.TIMED_OUT


def test_a_limit_switch_while_the_other_axis_moves_cuts_the_move_short() -> None:
    intent = _read(_follow(), {"x": "S", "y": "M"}, AT, 0.5)
    assert intent.next is Next.CUT_SHORT and intent.ended == ("x",)


def test_a_stop_by_the_driver_is_never_a_success() -> None:
    assert _read(_follow(), {"x": "@", "y": "@"}, AT, 1.1, stopped=True).next is Next.ABORTED
    follow = _follow()
    follow.reading()
    assert follow.read_lost(1.1, stopped=True).next is Next.ABORTED


def test_a_delayed_move_read_before_its_delay_waits() -> None:
    budget = Budget(delay=2.0, travel=1.0, after=0.0, settle=0.0, limit=6.0)
    follow = _follow(budget)
    follow.check_came(0.1)
    intent = _read(follow, {"x": "@", "y": "@"}, {"x": "0.000", "y": "0.000"}, 0.5)
    assert intent.next is Next.WAIT and intent.until == pytest.approx(2.15)


def test_a_missing_report_is_said_when_the_move_arrives_by_polling() -> None:
    intent = _read(_follow(), {"x": "@", "y": "@"}, AT, 1.1, report_owed=True)
    assert intent.next is Next.ARRIVED and intent.unreported


def test_the_reports_letters_fill_in_the_other_axes() -> None:
    intent = _read(_follow(), {"x": "@", "y": "@", "z": "D"}, AT, 1.1,
                   report={"x": "@", "y": "@", "z": "@"})
    assert intent.letters == {"x": "@", "y": "@", "z": "@"}


def test_the_table_refuses_a_read_not_written_and_anything_after_the_end() -> None:
    follow = _follow()
    with pytest.raises(FollowStateError):
        follow.read({"x": "@", "y": "@"}, AT, 1.0)
    _read(follow, {"x": "@", "y": "@"}, AT, 1.1)
    with pytest.raises(FollowStateError):
        follow.reading()
    with pytest.raises(FollowStateError):
        _follow().read_lost(1.0, stopped=False)


# -- the one verdict: the driver, the shell and the IOC ----------------------------------

def test_a_disabled_axis_fails_unless_an_all_axes_line_took_it_in() -> None:
    assert failed_axes(("x",), None, {}, {"x": "-"}, {}) == ("x",)
    assert failed_axes(("x",), None, {}, {}, {}) == ("x",)
    assert failed_axes(("x", "y"), None, {}, {"x": "A", "y": "-"}, {},
                       optional=("x", "y")) == ()
    assert optional_axes(parse("!cal"), ("x", "y")) == ("x", "y")
    assert optional_axes(parse("!cal x"), ("x",)) == ()
    assert optional_axes(parse("!moa 1 2"), ("x", "y")) == ()
    assert verdict(("x",), {"x": 1.0}, {}, {"x": "-"}, {"x": "1.000"}) is not None


def test_failed_letters_mark_each_failed_axis_and_keep_other_letters() -> None:
    assert failed_letters({"x": "@", "y": "S", "z": "@", "a": "D"}, ("x", "y", "a")) == {
        "x": "E", "y": "S", "z": "@", "a": "E"}
    assert failed_letters({"x": "-", "y": "M"}, ("x", "y")) == {"x": "-", "y": "M"}
    assert failed_letters({}, ("x",)) == {}


# -- where a start comes from ------------------------------------------------------------

def test_a_move_by_takes_the_remembered_start_only_while_it_is_known() -> None:
    tracker = MoveTracker()
    last = {"x": "1.000"}
    assert tracker.start(("x",), {"x"}, relative=True, last=last,
                         exact_replies=True) is Start.BATCH
    assert tracker.start(("x",), {"x"}, relative=True, last=None,
                         exact_replies=True) is Start.READ
    assert tracker.accepted(parse("!joy 0")) and not tracker.still
    tracker.inputs_read(True)
    tracker.confirmed("mor", ("x",), tracker.executed)
    assert tracker.start(("x",), {"x"}, relative=True, last=last,
                         exact_replies=False) is Start.KNOWN
    # The start is no longer known: it is being moved.
    assert tracker.start(("x",), {"x"}, relative=True, last=last,
                         exact_replies=False) is Start.READ
    tracker.confirmed("mor", ("x",), tracker.executed)
    tracker.written("vel")
    assert tracker.start(("x",), {"x"}, relative=True, last=last,
                         exact_replies=True) is Start.BATCH


def test_a_line_in_between_or_the_hdi_on_again_leave_the_start_unknown() -> None:
    tracker = MoveTracker()
    tracker.accepted(parse("!joy 0"))
    tracker.inputs_read(True)
    executed = tracker.executed
    tracker.written("pos")
    tracker.confirmed("moa", ("x",), executed)
    assert not tracker.start_known
    tracker.written("restore")
    assert not tracker.hdi_off and tracker.inputs_idle is None
    tracker.accepted(parse("!joy 0"))
    tracker.inputs_read(True)
    tracker.power_cycled()
    assert not tracker.still


def test_a_move_to_reads_first_only_without_a_known_position() -> None:
    tracker = MoveTracker()
    assert tracker.start(("x",), {"x"}, relative=False, last={"x": "0"},
                         exact_replies=False) is Start.KNOWN
    assert tracker.start(("x", "y"), {"x", "y"}, relative=False, last={"x": "0"},
                         exact_replies=False) is Start.READ
    assert tracker.start(("x",), None, relative=False, last=None,
                         exact_replies=False) is Start.NONE


# -- properties --------------------------------------------------------------------------

_LETTER = st.sampled_from(["M", "@", "E", "S", "T", "-", "A", "D"])
_TEXT = st.sampled_from(["10.000", "9.000", "10.0004", "-2.500", "-2.6", "0.000"])
_READ = st.tuples(
    st.fixed_dictionaries({}, optional={"x": _LETTER, "y": _LETTER, "z": _LETTER}),
    st.fixed_dictionaries({}, optional={"x": _TEXT, "y": _TEXT}),
    st.floats(0.0, 2.0), st.booleans())


@settings(max_examples=120, deadline=None)
@given(reads=st.lists(_READ, min_size=1, max_size=12),
       delay=st.sampled_from([0.0, 0.5]), settle=st.sampled_from([0.0, 0.3]),
       reports=st.booleans(), extend=st.sampled_from([None, 1.0]))
def test_no_sequence_of_reads_arrives_unless_a_read_showed_every_axis_at_its_target(
        reads: list[tuple[dict[str, str], dict[str, str], float, bool]], delay: float,
        settle: float, reports: bool, extend: float | None) -> None:
    budget = Budget(delay=delay, travel=1.0, after=0.0, settle=settle, limit=4.0)
    follow = _follow(budget, reports=reports, extend=extend)
    now = 0.0
    for letters, texts, step, stopped in reads:
        now += step
        intent = _read(follow, letters, texts, now, stopped=stopped)
        if intent.next is Next.WAIT:
            assert intent.until >= now or intent.until == follow.deadline
            continue
        assert follow.phase is Phase.ENDED
        if intent.next is Next.ARRIVED:
            # The last read, and only it: not stopped, every moved axis standing, no
            # failure letter, at its target within the printed tolerance.
            assert not stopped
            for axis, target in TARGETS.items():
                letter = letters.get(axis, "-")
                assert letter != MOVING and letter not in FAILED_LETTERS and letter != "-"
                text = texts[axis]
                assert abs(float(text) - target) <= position_tolerance(text)
        elif intent.next is Next.FAILED:
            # Raised without a stop only when nothing of the move still moves; each
            # failed axis reads a failure letter.
            assert not any(letters.get(a) == MOVING for a in TARGETS)
            assert not all(intent.letters.get(a) in ARRIVED_LETTERS for a in TARGETS)
        elif intent.next in (Next.CUT_SHORT, Next.TIMED_OUT):
            # The adapter stops the axes: something of the move still moves.
            assert any(letters.get(a) == MOVING for a in TARGETS)
        else:
            assert intent.next is Next.ABORTED and stopped
        break


# -- the proof that a speed or go line arrived -------------------------------------------

def _proof(line: str, busy: tuple[str, ...] = ()) -> StartProof:
    return StartProof(parse(line), ("x", "y", "z"), busy=busy, deadline=1.0, poll=0.01)


def test_an_axis_a_speed_line_sets_running_that_moves_proves_it() -> None:
    proof = _proof("!speed 5 0")
    assert proof.begin().next is Prove.READ_STATUS
    assert proof.status({"x": "M", "y": "@"}, 0.0).next is Prove.PROVEN


def test_a_speed_line_whose_axes_stand_is_unproven_and_stops_nothing() -> None:
    step = _proof("!speed 5").status({"x": "@"}, 0.0)
    assert step.next is Prove.UNPROVEN and step.running == ()
    assert step.found is not None and "X standing (@)" in step.found.reason


def test_a_go_that_shows_nothing_reads_the_positions_and_a_done_go_is_proven() -> None:
    proof = _proof("!go 1 2")
    assert proof.status({"x": "@", "y": "@"}, 0.0).next is Prove.READ_POSITIONS
    assert proof.positions({"x": "1.000", "y": "2.000"}, 0.0).next is Prove.PROVEN
    proof = _proof("!go 1 2")
    proof.status({"x": "@", "y": "@"}, 0.0)
    assert proof.positions({"x": "1.000", "y": "0.000"}, 0.0).next is Prove.UNPROVEN


def test_an_axis_that_moved_before_must_show_the_speed_written_until_the_deadline() -> None:
    proof = _proof("!speed 5", busy=("x",))
    step = proof.status({"x": "M"}, 0.0)
    assert (step.next, step.axis) == (Prove.READ_SPEED, "x")
    step = proof.speed("x", "3.0", 0.1)
    assert (step.next, step.axis, step.wait) == (Prove.READ_SPEED, "x", 0.01)
    assert proof.speed("x", "5.0", 0.2).next is Prove.PROVEN
    proof = _proof("!speed 5", busy=("x",))
    proof.status({"x": "M"}, 0.0)
    step = proof.speed("x", "3.0", 1.0)
    assert step.next is Prove.UNPROVEN and step.running == ("x",)


def test_an_axis_a_speed_line_stops_is_waited_for_and_unproven_if_it_moves_on() -> None:
    assert _proof("!speed 5 0").status({"x": "M", "y": "M"}, 0.0).next is Prove.PROVEN
    proof = _proof("!speed 0 0")
    step = proof.status({"x": "M", "y": "@"}, 0.0)
    assert step.next is Prove.READ_STATUS and step.wait == 0.01
    assert proof.status({"x": "@", "y": "@"}, 0.1).next is Prove.PROVEN
    proof = _proof("!speed 0")
    proof.status({"x": "M"}, 0.0)
    step = proof.status({"x": "M"}, 1.0)
    assert step.next is Prove.UNPROVEN and step.running == ("x",)


def test_a_reply_the_proof_did_not_ask_for_is_refused() -> None:
    proof = _proof("!speed 5")
    with pytest.raises(FollowStateError):
        proof.positions({}, 0.0)
    proof = _proof("!speed 5 5", busy=("x", "y"))
    proof.status({"x": "M", "y": "M"}, 0.0)
    with pytest.raises(FollowStateError):
        proof.speed("y", "5", 0.0)


# -- the confirmation read ---------------------------------------------------------------

def test_the_confirmation_reads_sa_and_one_position_only_where_known_to_work() -> None:
    tracker = MoveTracker()
    xyz = ("x", "y", "z")
    read = tracker.confirmation(("x",), xyz, family="1.71", autostatus=1, exact_replies=True)
    assert (read.short, read.single) == (True, "x")
    assert tracker.confirmation(("x", "y"), xyz, family="1.71", autostatus=1,
                                exact_replies=True).single is None
    assert tracker.confirmation(("x",), ("x",), family="1.71", autostatus=1,
                                exact_replies=True).single is None
    assert tracker.confirmation(("x",), xyz, family="1.71", autostatus=1,
                                exact_replies=False).single is None
    for family, mode in (("1.71", 2), ("1.71", 4), ("old", 1)):
        assert not tracker.confirmation(("x",), xyz, family=family, autostatus=mode,
                                        exact_replies=True).short
    assert not tracker.confirmation((), xyz, family="1.71", autostatus=1,
                                    exact_replies=True).short
    tracker.alias_unanswered()
    assert not tracker.confirmation(("x",), xyz, family="1.71", autostatus=1,
                                    exact_replies=True).short


_LINE = st.sampled_from(["!speed 5 0", "!speed 0 0", "!speed 5 5", "!go 1 2", "!go 1",
                         "!speed 0 3"])


@settings(max_examples=150, deadline=None)
@given(line=_LINE, busy=st.sets(st.sampled_from(["x", "y"])),
       replies=st.lists(st.tuples(
           st.fixed_dictionaries({}, optional={"x": _LETTER, "y": _LETTER}),
           st.sampled_from(["0.0", "3.0", "5.0"]), st.floats(0.0, 0.4)),
           min_size=1, max_size=40))
def test_a_start_proof_ends_by_its_deadline_and_stops_only_what_moved(
        line: str, busy: set[str],
        replies: list[tuple[dict[str, str], str, float]]) -> None:
    proof = StartProof(parse(line), ("x", "y"), busy=busy, deadline=1.0, poll=0.01)
    step, now, moving = proof.begin(), 0.0, set()
    for letters, speed, dt in [*replies, *[({}, "0.0", 1.0)] * 8]:
        if step.found is not None:
            break
        now += dt + step.wait
        if step.next is Prove.READ_STATUS:
            moving |= {axis for axis, letter in letters.items() if letter == MOVING}
            step = proof.status(letters, now)
        elif step.next is Prove.READ_POSITIONS:
            step = proof.positions({"x": "0.000", "y": "0.000"}, now)
        else:
            step = proof.speed(step.axis, speed, now)
    assert step.found is not None, "the proof did not end after its deadline"
    # Only an axis of the line that a read showed moving is stopped.
    assert set(step.running) <= moving & set(moved_axes(parse(line), ("x", "y")))
    assert (step.next is Prove.PROVEN) == step.found.shown
