"""The proof of a ``speed`` or ``go`` line answered by ``?err`` 0 alone (autostatus 0,
1, 3), from the state read behind it: :func:`tango_aio.moves._timing.acceptance`,
:func:`~tango_aio.moves._timing.stop_time`, :func:`~tango_aio.moves._timing.speed_shown`."""

from __future__ import annotations

from collections.abc import Collection, Mapping

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.moves._timing import (
    MARGIN,
    Acceptance,
    MoveTiming,
    acceptance,
    speed_shown,
    stop_time,
)

XYZ = ("x", "y", "z")


def judge(line: str, letters: str, busy: Collection[str] = (),
          positions: Mapping[str, str] | None = None) -> Acceptance:
    return acceptance(parse(line), dict(zip(XYZ, letters, strict=True)), XYZ, busy=busy,
                      positions=positions)


def test_an_axis_the_line_set_running_moving_proves_it() -> None:
    found = judge("!speed z 2", "@@M")
    assert found.shown and found.moving == ("z",) and found.reason == ""


def test_a_lost_speed_line_leaves_its_axis_standing() -> None:
    found = judge("!speed z 2", "@@@")
    assert not found.shown and found.unshown == ("z",) and not found.moving
    assert found.reason == "?statusaxis shows Z standing (@)"


@pytest.mark.parametrize("letter", ["@", "S", "E", "-"])
def test_an_axis_that_cannot_run_shows_nothing_of_the_line(letter: str) -> None:
    """At a switch or a soft limit in its direction, or not enabled: no motion, and
    nothing tells the line from a lost one."""
    assert judge("!speed z -2", f"@@{letter}").unshown == ("z",)


def test_an_axis_that_moved_before_the_line_shows_nothing_new() -> None:
    found = judge("!speed z 3", "@@M", busy={"z"})
    assert found.unshown == ("z",) and found.moving == ("z",)
    assert "Z moving as before the line" in found.reason


def test_one_axis_moving_proves_the_whole_line() -> None:
    """The line arrived whole: an axis of it standing was not run by the controller."""
    assert judge("!speed 2 2", "M@@").shown
    assert judge("!speed 2 0 2", "@MM", busy={"y"}).shown


def test_an_axis_a_speed_line_stops_must_stand() -> None:
    assert judge("!speed z 0", "@@@").shown
    found = judge("!speed z 0", "@@M")
    assert found.stopping == ("z",) and not found.unshown and not found.shown
    assert found.reason == "?statusaxis shows Z still moving"
    assert judge("!speed 0 0 0", "M@@").stopping == ("x",)


def test_a_go_without_target_stops() -> None:
    assert judge("go z", "@@@").shown
    assert judge("go", "@M@").stopping == ("y",)


def test_a_go_that_ended_already_stands_at_its_target() -> None:
    assert not judge("go x 1.5", "@@@").shown
    assert judge("go x 1.5", "@@@", positions={"x": "1.5000"}).shown
    assert not judge("go x 1.5", "@@@", positions={"x": "1.4000"}).shown
    assert not judge("go x 1.5", "@@@", positions={"x": "1,5000"}).shown
    assert judge("go 1.5 2", "@M@").shown


def test_the_stop_ramp_follows_the_acceleration_and_the_unit() -> None:
    slow = MoveTiming(accel=[0.001] * 4)  # 1 mm/s², 1 mm pitch: 100 rev/s in 100 s
    assert stop_time(slow, ["x"]) == pytest.approx(100.0 + MARGIN)
    assert stop_time(MoveTiming(), ["x"]) == pytest.approx(0.1 + MARGIN)
    dim9 = MoveTiming(dims=[9, 2, 2, 2], pitch=[4.0] * 4)  # 100 mm/s at 4 mm/rev
    assert stop_time(dim9, ["x"]) < stop_time(MoveTiming(pitch=[4.0] * 4), ["x"])
    assert stop_time(MoveTiming(accel=[0.0] * 4), ["y"]) > 60.0
    assert stop_time(MoveTiming(), []) == MARGIN


@given(st.floats(-100, 100, allow_nan=False))
def test_the_speed_in_force_shows_the_speed_written(value: float) -> None:
    assert speed_shown(value, f" {value:.3f}")
    assert not speed_shown(value, f"{value + 0.01:.3f}")
    assert not speed_shown(value, "2,000")
