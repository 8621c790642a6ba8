"""status.py is the one home of the status letters; the other modules use its names."""

from __future__ import annotations

from tango_aio import cli, motion, timing
from tango_aio.status import ABSENT, ARRIVED_LETTERS, FAILED_LETTERS, MOVING, AxisStatus


def test_the_letter_sets_are_the_manuals() -> None:
    # L2676-2711: only M moves; E, S, T end a move short; @, A, D are arrivals.
    assert MOVING == "M" and ABSENT == "-"
    assert {"E", "S", "T"} == FAILED_LETTERS
    assert {"@", "A", "D"} == ARRIVED_LETTERS
    assert not FAILED_LETTERS & ARRIVED_LETTERS and MOVING not in FAILED_LETTERS | ARRIVED_LETTERS
    assert all(type(letter) is str for letter in FAILED_LETTERS | ARRIVED_LETTERS | {MOVING})


def test_motion_and_the_shell_use_the_same_letters() -> None:
    assert vars(motion)["FAILED_LETTERS"] is FAILED_LETTERS
    assert vars(timing)["FAILED_LETTERS"] is FAILED_LETTERS
    assert set(cli.LETTER_MEANINGS) == {*AxisStatus, ABSENT}
    assert cli.describe_letters({"x": "@", "y": "E", "z": "-"}) == (
        "x=@ (ok) y=E (error/aborted) z=- (absent)")
