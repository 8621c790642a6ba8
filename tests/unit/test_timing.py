"""timing.py: move budgets, moved axes and position tolerance, without I/O."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.moves._timing import (
    CAL_LIMIT,
    MARGIN,
    MOC_LIMIT,
    POLL_GRACE,
    UNKNOWN_TRAVEL,
    Budget,
    MoveTiming,
    cut_short,
    describe_stop,
    move_budget,
    moved_axes,
    polled_during,
    position_tolerance,
    rest_budget,
    too_early,
    travel_time,
    verdict,
)

revs = st.floats(min_value=0.0, max_value=1e6, allow_nan=False)
positive = st.floats(min_value=1e-3, max_value=1e4, allow_nan=False)


@pytest.mark.parametrize(("speed", "accel"), [
    (0.0, 1.0), (1.0, 0.0), (-1.0, 1.0), (math.inf, 1.0), (1.0, math.nan)])
def test_an_unknown_speed_or_acceleration_gives_the_long_budget(speed: float,
                                                                  accel: float) -> None:
    assert travel_time(5.0, speed, accel) == UNKNOWN_TRAVEL == 60.0


def test_a_short_move_is_a_triangle_a_long_one_a_trapezoid() -> None:
    # Speed 10 rev/s reached after 10 s at 1 rev/s²: 100 revs of ramps in all.
    assert travel_time(25.0, 10.0, 1.0) == pytest.approx(10.0)  # 2·sqrt(25/1)
    assert travel_time(1000.0, 10.0, 1.0) == pytest.approx(110.0)  # 100 s + 10 s ramp
    assert travel_time(0.0, 10.0, 1.0) == 0.0


@given(positive, positive)
def test_travel_time_is_continuous_at_the_full_speed_boundary(speed: float,
                                                              accel: float) -> None:
    boundary = speed * speed / accel
    below = 2.0 * math.sqrt(boundary / accel)
    assert travel_time(boundary, speed, accel) == pytest.approx(below, rel=1e-9)


@given(revs, revs, positive, positive)
def test_travel_time_grows_with_the_distance(a: float, b: float, speed: float,
                                             accel: float) -> None:
    short, long = sorted((a, b))
    assert travel_time(short, speed, accel) <= travel_time(long, speed, accel) + 1e-9


def test_an_axis_travels_at_vel_capped_by_secvel() -> None:
    timing = MoveTiming()  # mm, pitch 1: 100 mm are 100 revs; vel 10 rev/s, accel 1 m/s²
    assert timing.travel("x", 100.0) == pytest.approx(travel_time(100.0, 10.0, 1000.0))
    assert timing.travel("x", -100.0) == timing.travel("x", 100.0)
    timing.secvel[0] = 2.0  # 2 mm/s caps the 10 rev/s of vel
    assert timing.travel("x", 100.0) == pytest.approx(travel_time(100.0, 2.0, 1000.0))
    assert timing.travel("y", 100.0) == pytest.approx(travel_time(100.0, 10.0, 1000.0))


def test_the_travel_follows_the_axis_unit() -> None:
    timing = MoveTiming()
    timing.dims[1] = 1  # µm: 100 µm are 0.1 revs at pitch 1 mm
    assert timing.travel("y", 100.0) == pytest.approx(travel_time(0.1, 10.0, 1000.0))


@pytest.mark.parametrize(("line", "present", "moved"), [
    ("!moa z 3", "xyz", ("z",)),
    ("!moa 1 2", "xyz", ("x", "y")),
    ("!mor 1 2 3 4", "xyza", ("x", "y", "z", "a")),
    ("!cal", "xy", ("x", "y")),
    ("!rm x", "xyz", ("x",)),
])
def test_moved_axes(line: str, present: str, moved: tuple[str, ...]) -> None:
    assert moved_axes(parse(line), tuple(present)) == moved


@pytest.mark.parametrize(("text", "tolerance"), [
    ("12", 1.5), ("12.5", 0.15), ("-0.0001", 0.00015), ("3.", 1.5)])
def test_the_tolerance_is_one_and_a_half_printed_digits(text: str, tolerance: float) -> None:
    assert position_tolerance(text) == pytest.approx(tolerance)


def test_the_driver_state_is_a_move_timing() -> None:
    from tango_aio.sansio import _state as state
    assert issubclass(state.DriverState, MoveTiming)


def _waits(delay: float = 0.0, pause: float = 0.0, settle: float = 0.0) -> MoveTiming:
    return MoveTiming(delay_ms=delay * 1000, pause_ms=pause * 1000, settle_ms=settle * 1000)


def test_a_move_budget_is_delay_travel_pause_and_settling() -> None:
    timing = _waits(delay=0.5, pause=0.25, settle=0.125)
    travel = timing.travel("y", 30.0)
    budget = move_budget(timing, parse("!moa 10 -20"), {"x": 10.0, "y": -30.0})
    assert budget == Budget(delay=0.5, travel=travel, after=0.375, settle=0.125,
                            limit=0.5 + 2 * travel + MARGIN + 0.375)
    assert budget.expected == pytest.approx(0.5 + travel + 0.375)
    assert budget.fallback == pytest.approx(2 * travel + MARGIN + 0.375)


def test_the_callers_timeout_replaces_the_limit_only() -> None:
    timing = _waits(delay=0.5)
    budget = move_budget(timing, parse("!mor x 5"), {"x": 5.0}, timeout=3.0)
    assert budget.limit == 3.0
    assert budget.expected == pytest.approx(0.5 + timing.travel("x", 5.0))


def test_delay_and_pause_apply_to_moa_mor_m_and_moc_only() -> None:
    timing = _waits(delay=1.0, pause=2.0, settle=0.5)
    for line in ("!moa x 1", "!mor x 1", "!m", "!moc x"):
        budget = move_budget(timing, parse(line), None)
        assert (budget.delay, budget.after) == (1.0, 2.5), line
    for line in ("!cal x", "!rm"):
        budget = move_budget(timing, parse(line), None)
        assert (budget.delay, budget.after, budget.settle) == (0.0, 0.5, 0.5), line


def test_cal_rm_and_moc_have_fixed_limits() -> None:
    timing = _waits(pause=1.0)
    assert move_budget(timing, parse("!cal"), None).limit == CAL_LIMIT
    assert move_budget(timing, parse("!rm y"), None).limit == CAL_LIMIT
    assert move_budget(timing, parse("!moc"), None).limit == MOC_LIMIT + 1.0
    assert move_budget(timing, parse("!moc"), None).travel == 0.0


def test_the_rest_of_a_move_is_sized_from_where_its_axes_stand() -> None:
    timing = _waits(delay=5.0, pause=0.25)
    rest = rest_budget(timing, {"x": 10.0}, {"x": "4.0", "y": "0"}, fallback=99.0)
    assert rest == pytest.approx(2 * timing.travel("x", 6.0) + MARGIN + 0.25)
    assert rest_budget(timing, {"x": 10.0, "y": 1.0}, {"x": "4.0"}, fallback=99.0) == 99.0


def test_a_move_at_its_targets_with_good_letters_is_a_success() -> None:
    assert verdict(("x", "y"), {"x": 10.0, "y": -2.5}, {}, {"x": "@", "y": "@", "z": "S"},
                   {"x": "10.00", "y": "-2.50"}) is None
    # cal/rm/moc have no targets: only the letters count.
    assert verdict(("x",), None, {}, {"x": "A"}, {}) is None


@pytest.mark.parametrize(("letters", "texts", "words"), [
    ({"x": "S", "y": "@"}, {"x": "50.05", "y": "1.0"},
     "X stopped at its upper limit switch (EE) (status S), at 50.05, target 60"),
    ({"x": "@", "y": "E"}, {"x": "60.0", "y": "1.0"},
     "Y stopped: its move was aborted or not executed (status E), at 1.0, target 1"),
    ({"x": "@", "y": "@"}, {"x": "59.0", "y": "1.0"},
     "X stopped short of its target (status @), at 59.0, target 60"),
    ({"x": "@", "y": "@"}, {"y": "1.0"}, "X stopped short of its target (status @), "
     "position not read, target 60"),
])
def test_a_failed_verdict_says_which_axis_and_why(letters: dict[str, str],
                                                  texts: dict[str, str], words: str) -> None:
    assert verdict(("x", "y"), {"x": 60.0, "y": 1.0}, {}, letters, texts) == (
        "did not end at its target: " + words)


def test_a_wider_tolerance_of_an_axis_is_used() -> None:
    letters = {"x": "@"}
    assert verdict(("x",), {"x": 1.0}, {}, letters, {"x": "1.2"}) is not None
    assert verdict(("x",), {"x": 1.0}, {"x": 0.25}, letters, {"x": "1.2"}) is None


def test_describe_stop_tells_the_switch_from_the_direction_and_takes_a_reason() -> None:
    assert describe_stop("x", "S", "3", 0.0) == (
        "X stopped at its lower limit switch (E0) (status S), at 3, target 0")
    assert describe_stop("z", "S", None, None) == (
        "Z stopped at a limit switch (status S), position not read")
    assert describe_stop("y", "T", "1", None) == "Y timed out (status T), at 1"
    assert describe_stop("y", "@", "1", 2.0, why="was stopped") == (
        "Y was stopped, at 1, target 2")


def test_a_failed_read_during_the_delay_is_read_again_after_it() -> None:
    budget = Budget(delay=1.0, travel=2.0, after=0.0, settle=0.0, limit=10.0)
    letters = {"x": "S"}
    assert too_early(budget, ("x",), letters, checked=5.0, now=5.5,
                     expected_end=8.0) == 6.0 + POLL_GRACE
    assert too_early(budget, ("x",), letters, checked=5.0, now=6.1, expected_end=8.0) is None


def test_a_settling_axis_is_read_again_at_the_expected_end_unless_its_letter_is_final() -> None:
    budget = Budget(delay=0.0, travel=2.0, after=0.5, settle=0.5, limit=10.0)
    assert too_early(budget, ("x",), {"x": "@"}, 0.0, now=1.0,
                     expected_end=2.5) == 2.5 + POLL_GRACE
    for final in "EST-":
        assert too_early(budget, ("x",), {"x": final}, 0.0, 1.0, 2.5) is None, final
    assert too_early(budget, ("x",), {"x": "@"}, 0.0, now=2.6, expected_end=2.5) is None
    no_settling = Budget(delay=0.0, travel=2.0, after=0.0, settle=0.0, limit=10.0)
    assert too_early(no_settling, ("x",), {"x": "@"}, 0.0, 1.0, 2.5) is None


_PLAIN = Budget(delay=0.0, travel=100.0, after=0.0, settle=0.0, limit=202.0)


@pytest.mark.parametrize("final", "EST-")
@pytest.mark.parametrize("stopped", ["x", "y"])
def test_an_axis_that_failed_while_the_others_move_ends_the_move(final: str,
                                                                 stopped: str) -> None:
    # From x = 1.5, y = -0.25: moa 1000 0 (#37 item 5). Whichever axis failed.
    letters = {"x": "M", "y": "M", "z": "@", stopped: final}
    assert cut_short(_PLAIN, ("x", "y"), letters, 0.0, now=5.0,
                     expected_end=100.0) == (stopped,)
    three = {"x": "M", "y": final, "z": final}
    assert cut_short(_PLAIN, ("x", "y", "z"), three, 0.0, 5.0, 100.0) == ("y", "z")


def test_a_move_is_not_cut_short_by_good_letters_or_when_nothing_moves() -> None:
    for letters in ({"x": "M", "y": "M"}, {"x": "@", "y": "M"}, {"x": "A", "y": "M"},
                    {"x": "S", "y": "@"}, {"x": "S", "y": "E"}, {}):
        assert cut_short(_PLAIN, ("x", "y"), letters, 0.0, 5.0, 100.0) == (), letters
    # A letter of an axis the move does not move says nothing of it.
    assert cut_short(_PLAIN, ("x", "y"), {"x": "M", "y": "M", "z": "S"}, 0.0, 5.0,
                     100.0) == ()


def test_a_failure_letter_during_the_delay_does_not_cut_the_move_short_yet() -> None:
    budget = Budget(delay=1.0, travel=100.0, after=0.0, settle=0.0, limit=203.0)
    letters = {"x": "S", "y": "M"}
    assert cut_short(budget, ("x", "y"), letters, checked=5.0, now=5.5,
                     expected_end=106.0) == ()
    assert cut_short(budget, ("x", "y"), letters, checked=5.0, now=6.1,
                     expected_end=106.0) == ("x",)


def test_a_move_is_polled_during_its_travel_without_reports_or_with_several_axes() -> None:
    assert not polled_during(("x",), reports=True)
    assert polled_during(("x",), reports=False)
    assert polled_during(("x", "y"), reports=True)
    assert polled_during(("x", "y", "z"), reports=False)
