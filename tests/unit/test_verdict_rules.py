"""The sans-IO verdicts on a line (tango_aio.moves._timing): what an ``?err`` reply or an
autostatus-2 acknowledgement says of the line before it (accepted, refused, or garbled:
it proves nothing), and whether the state read behind a refused or garbled verdict on a
motion line contradicts it."""

from __future__ import annotations

import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.errors import ERROR_DESCRIPTIONS
from tango_aio.moves._timing import Verdict, ack_verdict, contest, err_verdict
from tango_aio.sim.wire import flip_one_bit

DOCUMENTED = sorted(ERROR_DESCRIPTIONS)
REFUSALS = [n for n in DOCUMENTED if n]
blanks = st.text(" ", max_size=2)
# Replies near the clean ones: digits, blanks, signs, dots, letters and control bytes.
near = st.text(st.sampled_from("0123456789 -+.eEOKRok\x00\x10\x15p"), max_size=6)


@pytest.mark.parametrize("number", DOCUMENTED)
def test_a_documented_err_number_is_clean(number: int) -> None:
    expected = Verdict.ACCEPTED if number == 0 else Verdict.REFUSED
    assert err_verdict(str(number)) == (expected, number)
    assert err_verdict(f" {number} ") == (expected, number)


@given(near)
def test_only_a_documented_number_written_plainly_is_a_clean_err_reply(text: str) -> None:
    verdict, number = err_verdict(text)
    if verdict is not Verdict.GARBLED:
        assert number is not None and text.strip(" ") == str(number)
        assert number in ERROR_DESCRIPTIONS
        assert (verdict is Verdict.ACCEPTED) == (number == 0)


@pytest.mark.parametrize("text", ["07", "00", "-1", "0.5", "1e1", "35", "", " ", "p",
                                  "\x10", "0x", "\x150", "2 2", "+0"])
def test_glued_or_flipped_err_replies_are_garbled(text: str) -> None:
    assert err_verdict(text)[0] is Verdict.GARBLED


@given(st.randoms(use_true_random=False))
def test_a_flipped_bit_never_turns_an_err_zero_into_a_clean_acceptance(
        rng: random.Random) -> None:
    flipped = flip_one_bit(b"0\r", rng)[:-1].decode("latin-1")
    # 1, 2, 4, 8 are documented refusals (the state read behind them decides); every
    # other flip is garbled.
    verdict, number = err_verdict(flipped)
    assert verdict is Verdict.GARBLED or (verdict is Verdict.REFUSED and number in (1, 2, 4, 8))


@given(st.integers(0, 8), st.sampled_from(["OK", "ok", "Ok"]), blanks)
def test_ok_with_dots_in_any_case_accepts(dots: int, ok: str, pad: str) -> None:
    assert ack_verdict(pad + ok + "." * dots + pad) == (Verdict.ACCEPTED, 0)


@pytest.mark.parametrize("number", REFUSALS)
@pytest.mark.parametrize("word", ["ERR", "err", "Err"])
def test_err_with_a_documented_number_refuses(number: int, word: str) -> None:
    assert ack_verdict(f"{word} {number}") == (Verdict.REFUSED, number)


def test_a_bare_err_refuses_without_a_number() -> None:
    """Switch ``err_number=no``: a refused line acknowledged ``ERR`` alone."""
    assert ack_verdict("ERR") == (Verdict.REFUSED, None)


@pytest.mark.parametrize("text", ["ERR 0", "ERR 35", "ERR 07", "ERR5", "OK.,.", "NK...",
                                  "OK...7", "7OK...", "ERR 5x", "", "0"])
def test_garbled_acknowledgements(text: str) -> None:
    assert ack_verdict(text)[0] is Verdict.GARBLED


@given(near)
def test_a_clean_acknowledgement_is_ok_or_err_and_a_documented_number(text: str) -> None:
    verdict, number = ack_verdict(text)
    if verdict is Verdict.ACCEPTED:
        assert text.strip(" ").upper().rstrip(".") == "OK" and number == 0
    elif verdict is Verdict.REFUSED:
        words = text.upper().split()
        assert words[0] == "ERR"
        assert number is None if len(words) == 1 else (
            words[1] == str(number) and number in REFUSALS)


letters = st.sampled_from("@MJSADET-")
axes_letters = st.fixed_dictionaries({a: letters for a in "xyz"})
moved_axes = st.lists(st.sampled_from("xyz"), min_size=1, max_size=3, unique=True)


@given(moved_axes, axes_letters, st.booleans(), st.booleans(),
       st.sets(st.sampled_from("xyz")))
def test_contest(moved: list[str], read: dict[str, str], clean: bool,
                 reported: bool, busy: set[str]) -> None:
    found = contest(moved, read, clean=clean, reported=reported, busy=busy)
    # Motion the driver had in flight before the line does not contradict a refusal;
    # every moving axis of the line counts against a garbled verdict.
    assert found.moving == tuple(a for a in moved if read[a] == "M"
                                 and not (clean and a in busy))
    # A refusal stands only when it was clean and nothing shows the line ran.
    assert found.stands == (clean and not found.moving and not reported)
    if found.stands:  # it names the line's axes that move as before, if any
        assert found.reason == " ".join(a for a in moved if read[a] == "M").upper() + \
            " still moving as before the line" or not found.reason
    else:
        assert found.reason
    for axis in found.moving:
        assert axis.upper() in found.reason


def test_an_axis_the_line_does_not_move_does_not_contest_it() -> None:
    """Y turning at constant speed says nothing of a refused move of X."""
    found = contest(["x"], {"x": "@", "y": "M"}, clean=True)
    assert found.stands and found.moving == ()


def test_a_busy_axis_does_not_contest_a_clean_refusal_but_a_garbled_verdict() -> None:
    """X runs a move of this driver: a move of X refused (busy) stands; a garbled
    verdict with X moving is not taken."""
    stands = contest(["x"], {"x": "M"}, clean=True, busy={"x"})
    assert stands.stands and stands.reason == "X still moving as before the line"
    found = contest(["x"], {"x": "M"}, clean=False, busy={"x"})
    assert found.moving == ("x",) and not found.stands


def test_a_garbled_verdict_with_nothing_moving_says_the_fate_is_unknown() -> None:
    found = contest(["x", "y"], {"x": "@", "y": "@"}, clean=False)
    assert not found.stands and found.moving == ()
    assert "fate is unknown" in found.reason and "X Y standing" in found.reason


def test_a_report_of_e_for_every_axis_of_the_line_does_not_show_it_ran() -> None:
    from tango_aio.moves._timing import report_shows_run

    # Some firmware reports a refused move with E (switch refused_move_report=yes).
    assert not report_shows_run(("x",), {"x": "E", "y": "@"})
    assert not report_shows_run(("x", "y"), {"x": "E", "y": "E"})
    assert report_shows_run(("x", "y"), {"x": "E", "y": "@"})
    assert report_shows_run(("x",), {"x": "S"})
    assert report_shows_run(("x",), None)  # autostatus 3's bare CR
