"""The pure rules of controller/_restart.py and tango_aio.errors.outcome_unknown."""

from __future__ import annotations

import pytest

from tango_aio.controller._restart import (
    changed_settings,
    report_suggests_restart,
    settings_of,
    timeout_suggests_restart,
    unreported_end_suggests_restart,
)
from tango_aio.errors import (
    ConnectionLostError,
    ControllerTimeoutError,
    MoveAbortedUnknownError,
    MoveLinkLostUnknownError,
    MoveOutcomeUnknown,
    MoveProtocolUnknownError,
    MoveTimeoutUnknownError,
    OutOfRangeError,
    ProtocolError,
    RequestAbortedError,
    TangoError,
    outcome_unknown,
)
from tango_aio.moves._timing import MoveTiming


@pytest.mark.parametrize(("mode", "letters", "suggests"), [
    (0, True, True), (0, False, True),  # mode 0 sends no report at all (L2079-2081)
    (1, True, False), (2, True, False), (4, True, False),
    (3, False, False), (3, True, True),  # mode 3: a bare CR (L2107-2110)
])
def test_a_report_the_mode_does_not_send_suggests_a_restart(
        mode: int, letters: bool, suggests: bool) -> None:
    assert report_suggests_restart(mode, letters) is suggests


def test_changed_settings_name_what_a_restart_replaced() -> None:
    timing = MoveTiming()
    before = settings_of(timing)
    timing.vel[0] = 20.0
    timing.pause_ms = 5.0
    after = settings_of(timing)
    assert before["vel"][0] == 10.0  # a copy, not the list itself
    assert changed_settings(before, after) == {
        "vel": ([10.0] * 4, [20.0, 10.0, 10.0, 10.0]), "pause_ms": (0.0, 5.0)}
    assert changed_settings(after, after) == {}


@pytest.mark.parametrize(("error", "kind"), [
    (ControllerTimeoutError("no reply"), MoveTimeoutUnknownError),
    (RequestAbortedError("resync"), MoveAbortedUnknownError),
    (ProtocolError("odd"), MoveProtocolUnknownError),
    (ConnectionLostError("gone"), MoveLinkLostUnknownError),
])
def test_a_move_whose_line_may_have_run_says_so_and_keeps_its_kind(
        error: TangoError, kind: type[MoveOutcomeUnknown]) -> None:
    wrapped = outcome_unknown(error, "!mor 0.5")
    assert type(wrapped) is kind and isinstance(wrapped, type(error))
    assert isinstance(wrapped, MoveOutcomeUnknown) and wrapped.command == "!mor 0.5"
    assert str(error) in str(wrapped) and "may have executed '!mor 0.5'" in str(wrapped)
    assert outcome_unknown(wrapped, "!mor 0.5") is wrapped


def test_a_refused_move_is_no_unknown_outcome() -> None:
    refused = OutOfRangeError(5, "!moa 400")
    assert outcome_unknown(refused, "!moa 400") is refused


@pytest.mark.parametrize("mode", range(5))
def test_only_an_acknowledging_or_echoing_mode_takes_a_timeout_for_a_restart(
        mode: int) -> None:
    assert timeout_suggests_restart(mode) is (mode in (2, 4))


@pytest.mark.parametrize("mode", range(5))
def test_a_move_that_lost_its_report_suggests_a_restart_where_a_read_can_tell(
        mode: int) -> None:
    """Mode 0 sends no report; in mode 1, the power-on mode, the read cannot tell."""
    assert unreported_end_suggests_restart(mode) is (mode in (2, 3, 4))

