"""The Sardana controller's state decisions (tango_aio.sardana._state), without Sardana:
a move in flight reads Moving whatever else is read, a failed move Alarm with its reason,
an unreadable controller Fault, and ``?readsw`` read per axis."""

from __future__ import annotations

import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

import tango_aio.sardana
from tango_aio.sardana._state import (
    HOME,
    LOWER,
    UPPER,
    Outcome,
    State,
    axis_state,
    describe_switches,
    switch_bits,
)
from tango_aio.status import LETTERS

letters = st.sampled_from(sorted(LETTERS)) | st.none()
outcomes = st.builds(Outcome, running=st.booleans(), error=st.none() | st.text(min_size=1),
                     stopped_on_request=st.booleans()) | st.none()


@given(letter=letters, switches=st.integers(0, 7), unreadable=st.none() | st.text(min_size=1),
       error=st.none() | st.text(min_size=1), stopped=st.booleans())
def test_a_move_in_flight_reads_moving_whatever_else_is_read(
        letter: str | None, switches: int, unreadable: str | None, error: str | None,
        stopped: bool) -> None:
    running = Outcome(running=True, error=error, stopped_on_request=stopped)
    found = axis_state(running, letter=letter, switches=switches, unreadable=unreadable)
    assert found.state is State.MOVING


@given(outcome=outcomes, letter=letters, switches=st.integers(0, 7))
def test_on_only_without_a_failure_a_switch_or_motion(
        outcome: Outcome | None, letter: str | None, switches: int) -> None:
    found = axis_state(outcome, letter=letter, switches=switches)
    if found.state is State.ON:
        assert outcome is None or not outcome.running
        assert outcome is None or outcome.error is None or outcome.stopped_on_request
        assert letter != "M" and not switches & (LOWER | UPPER)


def test_a_failed_move_reads_alarm_with_its_reason_until_the_next_move() -> None:
    failed = Outcome(running=False, error="X stopped at its upper limit switch (EE)")
    found = axis_state(failed, letter="S", switches=UPPER)
    assert found.state is State.ALARM
    assert "X stopped at its upper limit switch" in found.status
    assert "upper limit switch" in found.status.rpartition(";")[2]
    assert found.switches == UPPER
    # the same axis, later: still the failure, though the letter reads idle
    assert axis_state(failed, letter="@").state is State.ALARM


def test_a_move_stopped_on_request_reads_on_once_its_verdict_is_in() -> None:
    stopped = Outcome(running=False, error="stopped on request", stopped_on_request=True)
    found = axis_state(stopped, letter="E")
    assert (found.state, found.status) == (State.ON, "stopped on request")
    # ... unless the axis moves again (a line written after the stop)
    assert axis_state(stopped, letter="M").state is State.MOVING


@pytest.mark.parametrize(("letter", "state"), [
    ("@", State.ON), ("J", State.ON), ("A", State.ON), ("D", State.ON),
    ("M", State.MOVING), ("E", State.ALARM), ("S", State.ALARM), ("T", State.ALARM),
    ("?", State.ALARM), ("-", State.ALARM),
])
def test_without_a_move_of_the_pool_the_letter_decides(letter: str, state: State) -> None:
    found = axis_state(None, letter=letter)
    assert found.state is state
    if state is State.ALARM:
        assert letter in found.status


def test_an_unreadable_controller_reads_fault_with_the_reason() -> None:
    found = axis_state(Outcome(running=False), unreadable="the link is lost")
    assert (found.state, found.status) == (State.FAULT, "the link is lost")


def test_an_actuated_limit_switch_reads_alarm() -> None:
    found = axis_state(None, letter="@", switches=LOWER)
    assert found.state is State.ALARM and "lower limit switch" in found.status


def test_switch_bits_are_sardanas() -> None:
    assert switch_bits((False, False, True)) == UPPER
    assert switch_bits((True, False, False)) == LOWER
    assert switch_bits((False, True, False)) == HOME
    assert switch_bits((True, True, True)) == LOWER | UPPER | HOME
    assert switch_bits((False, False, False)) == 0
    assert describe_switches(LOWER | UPPER) == "lower and upper limit switches"
    assert describe_switches(UPPER) == "upper limit switch"
    assert describe_switches(0) == ""


def test_without_sardana_the_controller_asks_for_the_extra(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "sardana", None)  # import sardana: ModuleNotFoundError
    monkeypatch.delitem(sys.modules, "tango_aio.sardana._controller", raising=False)
    assert tango_aio.sardana.POOL_PATH.endswith("_poolpath")
    with pytest.raises(ImportError, match=r"the sardana extra"):
        _ = tango_aio.sardana.MarzhauserMotorController
