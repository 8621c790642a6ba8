"""timing.py: move budgets, moved axes and position tolerance, without I/O."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.instructions import parse
from tango_aio.timing import (
    UNKNOWN_TRAVEL,
    MoveTiming,
    moved_axes,
    position_tolerance,
    travel_time,
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


def test_the_old_import_paths_still_work() -> None:
    from tango_aio import motion, state
    assert motion.MoveTiming is MoveTiming and motion.travel_time is travel_time
    assert motion.moved_axes is moved_axes and motion.position_tolerance is position_tolerance
    assert issubclass(state.DriverState, MoveTiming)
