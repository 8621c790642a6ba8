"""status.py is the one home of the status letters; the other modules use its names."""

from __future__ import annotations

from tango_aio.cli import _describe as cli
from tango_aio.moves import _timing as timing
from tango_aio.moves import _tracker as tracker
from tango_aio.status import (
    ABSENT,
    ARRIVED_LETTERS,
    FAILED_LETTERS,
    MOVING,
    AxisStatus,
    switch_states,
)


def test_the_letter_sets_are_the_manuals() -> None:
    # L2676-2711: only M moves; E, S, T end a move short; @, A, D are arrivals.
    assert MOVING == "M" and ABSENT == "-"
    assert {"E", "S", "T"} == FAILED_LETTERS
    assert {"@", "A", "D"} == ARRIVED_LETTERS
    assert not FAILED_LETTERS & ARRIVED_LETTERS and MOVING not in FAILED_LETTERS | ARRIVED_LETTERS
    assert all(type(letter) is str for letter in FAILED_LETTERS | ARRIVED_LETTERS | {MOVING})


def test_motion_and_the_shell_use_the_same_letters() -> None:
    assert vars(tracker)["ARRIVED_LETTERS"] is ARRIVED_LETTERS
    assert vars(timing)["FAILED_LETTERS"] is FAILED_LETTERS
    assert set(cli.LETTER_MEANINGS) == {*AxisStatus, ABSENT}
    assert cli.describe_letters({"x": "@", "y": "E", "z": "-"}) == (
        "x=@ (ok) y=E (error/aborted) z=- (absent)")


def test_a_completion_report_may_hold_every_documented_letter_and_no_other() -> None:
    from tango_aio.sansio._core import is_completion_line
    from tango_aio.status import LETTERS

    assert {*AxisStatus, ABSENT} == LETTERS
    for letter in LETTERS:
        assert is_completion_line(f"{letter}@.") and is_completion_line(f"{letter}.")
    for other in "BFGKNOPQRVWXYZ0 ":
        assert not is_completion_line(f"{other}@.")


def test_switch_states_reads_one_axis_of_readsw() -> None:
    # E0 of X Y Z A, Ref of X Y Z A, EE of X Y Z A (L5027-5078)
    reply = "0100" "0010" "1001\r"
    assert switch_states(reply, "x") == (False, False, True)
    assert switch_states(reply, "y") == (True, False, False)
    assert switch_states(reply, "z") == (False, True, False)
    assert switch_states(reply, "a") == (False, False, True)
    for other in ("", "0" * 11, "0" * 13, "00000000000x", "ERROR 0"):
        assert switch_states(other, "x") is None
