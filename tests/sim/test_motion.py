"""Tests of the sans-IO motion model of the emulator (tango_aio.sim.motion)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.sim.motion import (
    ERR_INVALID_AXIS,
    ERR_LIMIT_SWITCH,
    ERR_MOVE_NOT_ALLOWED,
    ERR_NOT_EXECUTABLE,
    ERR_OUT_OF_RANGE,
    AxisConfig,
    MotionConfig,
    MotionEvent,
    MotionModel,
    MotionRefused,
    MoveFinished,
    TriggerFired,
    plan_to_target,
)
from tango_aio.units import UnitScale

# Defaults: vel 10 rev/s, accel 1 m/s² = 1000 rev/s² at pitch 1 mm, stopaccel 1 m/s².
A = 1000.0
V = 10.0


def free_model(n_axes: int = 3) -> MotionModel:
    """Model without enabled limit switches: pure kinematics, never secvel-capped."""
    model = MotionModel(MotionConfig(n_axes=n_axes))
    for i in range(n_axes):
        model.settings(i).swact = (0, 0, 0)
    return model


def run(model: MotionModel, until: float = 1e6) -> list[MotionEvent]:
    """Jump from event to event until nothing is left (or ``until``)."""
    events: list[MotionEvent] = []
    t = model.next_event_time()
    while t is not None and t <= until:
        events += model.advance(t)
        t = model.next_event_time()
    return events


def finished(events: list[MotionEvent]) -> list[MoveFinished]:
    return [e for e in events if isinstance(e, MoveFinished)]


def trapezoid_time(dist: float, vel: float, acc: float) -> float:
    if dist >= vel * vel / acc:
        return vel / acc + dist / vel
    return 2.0 * math.sqrt(dist / acc)


# ----------------------------------------------------------------------------- units


def test_units_dims() -> None:
    mm = UnitScale(dim=2, pitch=2.0, gear=4.0)  # 0.5 mm per motor rev
    assert mm.pos_to_user(10.0) == pytest.approx(5.0)
    assert UnitScale(dim=1, pitch=2.0, gear=4.0).pos_to_user(10.0) == pytest.approx(5000.0)
    assert UnitScale(dim=0, pitch=2.0, usteps=50000).pos_to_user(2.0) == pytest.approx(100000.0)
    assert UnitScale(dim=3, pitch=1.0, gear=2.0).pos_to_user(1.0) == pytest.approx(180.0)
    assert UnitScale(dim=4, pitch=1.0, gear=1.0).pos_from_user(3.0) == pytest.approx(3.0)
    assert UnitScale(dim=7, pitch=25.4).pos_to_user(1.0) == pytest.approx(1.0)
    assert UnitScale(dim=8, pitch=25.4).pos_to_user(1.0) == pytest.approx(1000.0)
    assert UnitScale(dim=5).pos_to_user(10.0) == pytest.approx(1.0)
    assert UnitScale(dim=6).pos_from_user(0.001) == pytest.approx(1.0)
    # velocities: rev/s except dim 9 (mm/s)
    assert UnitScale(dim=2, pitch=4.0).vel_to_user(3.0) == 3.0
    assert UnitScale(dim=9, pitch=4.0).vel_to_user(3.0) == pytest.approx(12.0)
    assert UnitScale(dim=9, pitch=4.0).vel_from_user(12.0) == pytest.approx(3.0)
    assert UnitScale(pitch=2.0).accel_to_rev(1.0) == pytest.approx(500.0)
    with pytest.raises(ValueError):
        UnitScale(dim=10).pos_to_user(1.0)


def test_model_unit_helpers_follow_settings() -> None:
    m = MotionModel()
    m.settings("y").dim = 1
    m.settings("y").pitch = 2.0
    assert m.to_user("y", 1.5) == pytest.approx(3000.0)
    assert m.from_user("y", 3000.0) == pytest.approx(1.5)
    m.settings("y").dim = 9
    assert m.vel_to_user("y", 5.0) == pytest.approx(10.0)
    assert m.vel_from_user("y", 10.0) == pytest.approx(5.0)


# ----------------------------------------------------------------------------- profiles


@pytest.mark.parametrize("dist", [10.0, 0.5, 0.1, 0.01, -3.0])
def test_single_axis_timing_matches_formula(dist: float) -> None:
    m = free_model()
    m.move_relative({"x": dist})
    expected = trapezoid_time(abs(dist), V, A)
    assert m.next_event_time() == pytest.approx(expected, rel=1e-12)
    events = run(m)
    assert events == [MoveFinished(events[0].time, "move", "@@@-", 1)]
    assert m.position("x") == dist  # snapped exactly onto the target


def test_trapezoid_and_triangle_shapes() -> None:
    m = free_model()
    m.move_absolute({"x": 10.0})
    m.advance(0.005)  # accelerating
    assert m.position("x") == pytest.approx(0.5 * A * 0.005**2)
    m.advance(0.5)
    assert m.velocity("x") == pytest.approx(V)
    assert m.position("x") == pytest.approx(0.05 + V * 0.49)

    tri = free_model()
    tri.move_absolute({"x": 0.01})  # shorter than vel²/accel = 0.1: triangle
    half = math.sqrt(0.01 / A)
    tri.advance(half)
    assert tri.velocity("x") == pytest.approx(math.sqrt(0.01 * A))
    assert tri.velocity("x") < V
    assert tri.next_event_time() == pytest.approx(2 * half)


def test_plan_to_target_handles_moving_starts() -> None:
    # moving away from the target: brake, come back
    phases = plan_to_target(0.0, -5.0, 1.0, 10.0, 100.0)
    assert phases[0].v0 == -5.0 and phases[0].accel == 100.0
    # too fast to stop: overshoot and return; the end is exactly the target
    from tango_aio.sim.motion import Trajectory

    traj = Trajectory.from_phases(0.0, 0.0, plan_to_target(0.0, 10.0, 0.1, 10.0, 100.0), 0.1)
    assert max(s.x1 for s in traj.segments) == pytest.approx(0.5)
    assert traj.end_pos == 0.1
    # every segment is monotonic
    for seg in traj.segments:
        assert seg.v0 * (seg.v0 + seg.accel * (seg.t1 - seg.t0)) >= -1e-12


def test_vector_move_arrives_together_within_limits() -> None:
    m = free_model()
    m.settings("y").vel = 2.0
    m.move_absolute({"x": 10.0, "y": 5.0})
    # normalised: V = min(10/10, 2/5) = 0.4, A = min(1000/10, 1000/5) = 100
    expected = 0.4 / 100 + 1 / 0.4
    assert m.next_event_time() == pytest.approx(expected, rel=1e-12)
    m.advance(1.0)
    assert m.velocity("y") == pytest.approx(2.0)  # leading axis at its own vel
    assert m.velocity("x") == pytest.approx(4.0)  # follower scaled by its share
    m.advance(expected - 1e-3)
    assert m.is_moving("x") and m.is_moving("y")
    assert abs(m.position("x") / m.position("y") - 2.0) < 1e-9
    events = run(m)
    assert [e.letters for e in finished(events)] == ["@@@-"]
    assert events[0].time == pytest.approx(expected)
    assert (m.position("x"), m.position("y")) == (10.0, 5.0)


def test_vector_move_respects_each_axis_accel() -> None:
    m = free_model()
    m.settings("y").accel = 0.1  # 100 rev/s²
    m.move_absolute({"x": 1.0, "y": 1.0})
    m.advance(0.001)
    assert m.velocity("y") == pytest.approx(0.1)  # y accelerates at its own 100 rev/s²
    assert m.velocity("x") == pytest.approx(0.1)


def test_scanmode_3_axes_finish_independently() -> None:
    m = free_model()
    m.global_settings.scanmode = 3
    m.settings("y").vel = 2.0
    m.move_absolute({"x": 10.0, "y": 5.0})
    tx, ty = trapezoid_time(10.0, V, A), trapezoid_time(5.0, 2.0, A)
    assert m.next_event_time() == pytest.approx(tx)
    m.advance(1.0)
    assert m.velocity("x") == pytest.approx(10.0)
    assert m.advance(tx + 0.01) == []
    assert m.status_letters() == "@M@-"
    assert m.position("x") == 10.0
    events = run(m)
    assert len(events) == 1
    assert events[0].time == pytest.approx(ty)
    assert isinstance(events[0], MoveFinished) and events[0].letters == "@@@-"


def test_scanmode_1_and_2_use_scanvel() -> None:
    m = free_model()
    m.global_settings.scanmode = 1
    m.global_settings.scanvel = 2.0
    m.move_relative({"x": 20.0, "y": 20.0})
    m.advance(1.0)
    assert m.velocity("x") == pytest.approx(2.0 / math.sqrt(2))
    assert m.velocity("y") == pytest.approx(2.0 / math.sqrt(2))
    run(m)

    m.move_relative({"z": 5.0})  # scanmode 1: single axes also at scanvel
    m.advance(m.now + 1.0)
    assert m.velocity("z") == pytest.approx(2.0)
    run(m)

    m.global_settings.scanmode = 2  # single-axis moves at own vel
    m.move_relative({"z": 5.0})
    m.advance(m.now + 0.2)
    assert m.velocity("z") == pytest.approx(V)
    run(m)
    m.move_relative({"x": 3.0, "z": 4.0})
    m.advance(m.now + 1.0)
    assert math.hypot(m.velocity("x"), m.velocity("z")) == pytest.approx(2.0)


# ----------------------------------------------------------------------------- move kinds


def test_mor_sets_distance_and_m_repeats() -> None:
    m = free_model(4)
    m.move_absolute({"x": 1, "y": 2, "z": 3, "a": 4})
    run(m)
    m.move_relative({"x": 1, "y": 1, "z": 1, "a": 1})
    run(m)
    m.move_repeat()
    run(m)
    assert [m.position(a) for a in "xyza"] == [3, 4, 5, 6]
    for axis, d in zip("xyza", (1, 2, 0, 0), strict=True):
        m.set_distance(axis, d)
    m.move_repeat()
    events = run(m)
    assert [m.position(a) for a in "xyza"] == [4, 6, 5, 6]
    assert [e.letters for e in finished(events)] == ["@@@@"]


def test_moc_and_mol() -> None:
    cfg = MotionConfig(axes=(AxisConfig(lock_position=10.0),) + (AxisConfig(),) * 3)
    m = MotionModel(cfg)
    m.settings("y").swact = (0, 0, 0)
    m.set_limits("y", 0.0, 30.0)
    m.move_center(["y"])
    run(m)
    assert m.position("y") == pytest.approx(15.0)

    m.move_lock()  # nothing calibrated: every axis reports E and stays
    events = run(m)
    assert [e.letters for e in finished(events)] == ["EEE-"]
    m.calibrate(["x"])
    run(m)
    m.move_lock(["x"])
    events = run(m)
    assert [e.letters for e in finished(events)] == ["@@@-"]
    assert m.position("x") == pytest.approx(10.0)


def test_zero_distance_move_still_reports_once() -> None:
    m = free_model()
    m.move_absolute({"x": 0.0})
    assert m.next_event_time() == 0.0
    assert [e.letters for e in finished(run(m))] == ["@@@-"]


def test_busy_axis_refuses_new_move_and_bad_axis() -> None:
    m = free_model()
    m.move_absolute({"x": 10.0})
    with pytest.raises(MotionRefused) as err:
        m.move_absolute({"x": 1.0})
    assert err.value.code == ERR_NOT_EXECUTABLE
    m.move_absolute({"y": 1.0})  # other axes are free
    with pytest.raises(MotionRefused) as err:
        m.move_absolute({"a": 1.0})  # 3-axis controller
    assert err.value.code == ERR_INVALID_AXIS
    assert len(finished(run(m))) == 2


# ----------------------------------------------------------------------------- go / speed


def test_go_retarget_reverses_without_report() -> None:
    m = free_model()
    m.go({"x": 100.0})
    m.advance(0.5)
    assert m.position("x") == pytest.approx(4.95)
    m.go({"x": 2.0})
    # brake 10 rev/s at 1000 rev/s² (0.01 s, 0.05 rev), then 3 rev back: 0.01 + 0.3 s
    assert m.next_event_time() == pytest.approx(0.5 + 0.01 + trapezoid_time(3.0, V, A))
    m.advance(0.6)
    assert m.velocity("x") < 0
    assert m.status_letter("x") == "M"
    assert run(m) == []
    assert m.position("x") == 2.0
    assert m.status_letters() == "@@@-"


def test_vel_change_applies_to_running_go_and_zero_ends_it() -> None:
    m = free_model()
    m.go({"x": 100.0})
    m.advance(1.0)
    m.set_vel("x", 1.0)
    m.advance(1.1)
    assert m.velocity("x") == pytest.approx(1.0)
    m.set_vel("x", 0.0)
    assert m.settings("x").vel == 1.0  # 0 is not stored
    run(m)
    assert not m.is_moving("x")
    with pytest.raises(MotionRefused) as err:
        m.set_vel("x", 0.0)  # no go running: out of range
    assert err.value.code == ERR_OUT_OF_RANGE


def test_go_stop_uses_normal_accel() -> None:
    m = free_model()
    m.go({"x": 100.0, "y": 50.0})
    m.advance(0.5)
    m.go_stop(["x"])
    assert m.next_event_time() == pytest.approx(0.51)
    m.advance(0.51)
    assert m.position("x") == pytest.approx(5.0)
    assert m.is_moving("y")
    m.go_stop()
    assert run(m) == []
    assert m.position("y") == pytest.approx(5.1)  # 0.01 s longer at 10 rev/s, then 0.05


def test_speed_runs_reverses_and_stops_at_soft_limit() -> None:
    m = free_model()
    m.speed({"x": 5.0})
    m.advance(1.0)
    assert m.velocity("x") == pytest.approx(5.0)
    m.speed({"x": -5.0})
    m.advance(1.005)
    assert m.velocity("x") == pytest.approx(0.0, abs=1e-9)
    m.advance(1.5)
    assert m.velocity("x") == pytest.approx(-5.0)
    m.speed({"x": 0.0})
    assert run(m) == []
    assert not m.is_moving("x")

    m.set_limits("y", -10.0, 10.0)
    m.speed({"y": 10.0})
    assert run(m) == []
    assert m.position("y") == 10.0
    m.speed({"y": 3.0})  # already at the limit: no motion
    assert m.next_event_time() == m.now
    run(m)
    assert m.position("y") == 10.0


def test_speed_zero_stops_go() -> None:
    m = free_model()
    m.go({"x": 50.0})
    m.advance(0.5)
    m.speed({"x": 0.0})
    run(m)
    assert m.position("x") == pytest.approx(5.0)


# ----------------------------------------------------------------------------- abort


def test_abort_reports_e_with_stopaccel() -> None:
    m = free_model()
    m.settings("x").stopaccel = 2.0  # 2000 rev/s²
    m.move_absolute({"x": 100.0})
    m.advance(1.0)
    m.abort()
    assert m.next_event_time() == pytest.approx(1.005)
    events = run(m)
    assert [e.letters for e in finished(events)] == ["E@@-"]
    assert events[0].time == pytest.approx(1.005)
    assert m.position("x") == pytest.approx(9.95 + 100 / 4000)
    assert m.status_letters() == "E@@-"


def test_abort_minus_one_uses_accel_and_single_axis_abort() -> None:
    m = free_model()
    m.settings("x").stopaccel = 5.0
    m.move_absolute({"x": 100.0, "y": 50.0})
    m.advance(1.0)
    x_at_abort = m.position("x")
    m.abort("x", use_accel=True)
    m.advance(1.0 + 0.025)
    assert m.is_moving("y")
    events = run(m)
    assert [e.letters for e in finished(events)] == ["E@@-"]
    vx = 10.0  # x leads the vector at 10 rev/s
    assert m.position("x") == pytest.approx(x_at_abort + vx * vx / (2 * A))
    assert m.position("y") == 50.0


def test_abort_with_nothing_moving_gives_no_event() -> None:
    m = free_model()
    m.abort()
    m.emergency_stop()
    assert m.next_event_time() is None
    assert m.advance(5.0) == []


def test_abort_go_and_speed() -> None:
    m = free_model()
    m.go({"x": 100.0})
    m.speed({"y": -3.0})
    m.advance(0.5)
    m.emergency_stop()
    assert run(m) == []
    assert m.status_letters() == "EE@-"
    assert m.velocity("x") == 0.0


# ----------------------------------------------------------------------------- limits


def test_soft_limit_refusal_and_return_towards_range() -> None:
    m = free_model()
    m.set_limits("x", -5.0, 5.0)
    assert m.statuslimit() == "--------L---L---"
    with pytest.raises(MotionRefused) as err:
        m.move_absolute({"x": 6.0, "y": 1.0})
    assert err.value.code == ERR_OUT_OF_RANGE
    assert m.next_event_time() is None  # nothing started, not even y
    with pytest.raises(MotionRefused):
        m.go({"x": -5.5})
    m.move_absolute({"x": 4.0})
    run(m)
    m.set_limits("x", None, 3.0)  # now beyond the upper limit
    with pytest.raises(MotionRefused):
        m.move_absolute({"x": 4.5})
    m.move_absolute({"x": 3.5})  # towards the range is fine
    run(m)
    assert m.position("x") == 3.5
    with pytest.raises(MotionRefused):
        m.set_limits("x", 4.0, 3.0)


def test_limctr_zero_ignores_soft_limits() -> None:
    m = free_model()
    m.set_limits("x", -1.0, 1.0)
    m.settings("x").limctr = 0
    m.move_absolute({"x": 3.0})
    run(m)
    assert m.position("x") == 3.0


def test_limit_switch_stops_axis_with_s() -> None:
    m = MotionModel()  # E0 at -50, EE at +50, swact 1 0 1
    m.move_absolute({"x": 60.0, "y": 5.0})
    t_hit = 0.01 + (50.0 - 0.05) / V  # x leads at 10 rev/s
    m.advance(t_hit + V / A - 1e-6)  # braking with stopaccel
    assert m.velocity("x") > 0
    m.advance(t_hit + V / A)
    assert m.velocity("x") == 0.0
    assert m.position("x") == pytest.approx(50.0 + V * V / (2 * A))
    assert m.status_letters() == "SM@-"  # x stopped, y still on its vector profile
    events = run(m)
    assert len(events) == 1 and isinstance(events[0], MoveFinished)
    assert events[0].letters == "S@@-"
    assert events[0].time == pytest.approx(0.01 + 60.0 / V)
    assert m.position("y") == 5.0  # the other axis completed its move
    assert m.status_letters() == "S@@-"
    assert m.switch_state("x") == (False, True)
    with pytest.raises(MotionRefused) as err:
        m.move_relative({"x": 1.0})
    assert err.value.code == ERR_LIMIT_SWITCH
    m.move_absolute({"x": 0.0})  # away from the switch is allowed
    assert [e.letters for e in finished(run(m))] == ["@@@-"]
    assert m.status_letters() == "@@@-"


def test_target_exactly_on_switch_counts_as_switch() -> None:
    m = MotionModel()
    m.move_absolute({"x": 50.0})  # reaching EE at the very end of the move
    assert [e.letters for e in finished(run(m))] == ["S@@-"]
    assert m.position("x") == 50.0


def test_go_into_switch_reports_status_s() -> None:
    m = MotionModel()
    m.go({"y": -70.0})
    assert run(m) == []
    assert m.status_letter("y") == "S"
    assert m.switch_state("y") == (True, False)


# ----------------------------------------------------------------------------- cal / rm


def cal_time(dist: float, vel: float, release: float, offset: float = 0.0) -> float:
    """Time of an ideal cal from rest ``dist`` away from the switch (default settings)."""
    approach = vel / A + (dist - vel * vel / (2 * A)) / vel
    brake = vel / A  # stopaccel = accel = 1000 rev/s²
    overshoot = vel * vel / (2 * A)
    ramp = release / A
    leave = ramp + (overshoot - release * release / (2 * A)) / release
    settle = release / A
    if offset > release * release / (2 * A):
        settle = trapezoid_time(offset, vel, A)  # (approximately: starts at release speed)
    return approach + brake + leave + settle


def test_cal_sets_origin_lower_limit_and_letters() -> None:
    m = MotionModel()
    job = m.calibrate()
    assert m.status_letters() == "MMM-"
    events = run(m)
    assert events == [MoveFinished(events[0].time, "cal", "AAA-", job)]
    assert events[0].time == pytest.approx(cal_time(50.0, V, 0.32), rel=1e-9)
    assert [m.position(a) for a in "xyz"] == [0.0, 0.0, 0.0]
    assert m.limits("x")[0] == 0.0
    assert m.statuslimit() == "AAA-------------"
    assert m.calst("x") == 1
    assert m.status_letters() == "AAA-"
    assert not m.is_released("x")  # EE is enabled as well: rm still needed
    with pytest.raises(MotionRefused):
        m.move_absolute({"x": -1.0})  # below the new lower limit


def test_rm_sets_upper_limit_and_releases() -> None:
    m = MotionModel()
    m.calibrate(["y"])
    assert [e.letters for e in finished(run(m))] == ["@A@-"]
    m.range_measure(["y"])
    assert [e.letters for e in finished(run(m))] == ["@D@-"]
    stop = 0.32**2 / (2 * A)  # release speed stopping distance beyond the switch
    assert m.limits("y")[1] == pytest.approx(100.0 - 2 * stop)
    assert m.position("y") == pytest.approx(100.0 - 2 * stop)
    assert m.calst("y") == 3
    assert m.statuslimit() == "-A---D----------"
    assert m.is_released("y")


def test_caliboffset_moves_origin() -> None:
    m = MotionModel()
    m.settings("x").caliboffset = 2.0
    m.settings("y").nosetlimit = 1
    m.settings("z").calmode = 1
    m.calibrate()
    run(m)
    # x: origin 2 rev beyond E0 (physical -48): the switch is at -2
    m.settings("x").limctr = 0
    m.move_absolute({"x": -1.99})
    run(m)
    assert m.switch_state("x") == (False, False)
    m.move_absolute({"x": -2.01})
    assert [e.letters for e in finished(run(m))] == ["S@@-"]
    # y: nosetlimit → lower limit stays at -maxpos
    assert m.limits("y")[0] == pytest.approx(-2600.0)
    # z: calmode 1 keeps the power-on zero; the switch is at -50 there
    assert m.position("z") == pytest.approx(-50.0 + 0.32**2 / (2 * A))
    assert m.limits("z")[0] == pytest.approx(m.position("z"))


def test_cal_timeout_reports_t() -> None:
    m = MotionModel()
    m.settings("x").caltimeout = 2.0
    m.calibrate(["x", "y"])
    events = finished(run(m))
    assert [e.letters for e in events] == ["TA@-"]
    assert m.calst("x") == 0 and m.calst("y") == 1
    m2 = MotionModel()
    m2.settings("x").caltimeout = 2.0
    m2.calibrate(["x"])
    assert finished(run(m2))[0].time == pytest.approx(2.0 + V / A)
    assert m2.status_letter("x") == "T"


def test_cal_skips_disabled_switch_and_disabled_axis() -> None:
    m = MotionModel()
    m.settings("x").swact = (0, 0, 1)
    m.settings("y").enable = 0
    m.calibrate()
    assert [e.letters for e in finished(run(m))] == ["@@A-"]
    assert m.calst("x") == 0
    assert m.status_letters() == "@-A-"
    m.range_measure(["x"])
    assert [e.letters for e in finished(run(m))] == ["D@@-"]
    assert m.is_released("x")  # only EE enabled: rm releases it


def test_cal_abort_reports_e_and_keeps_state() -> None:
    m = MotionModel()
    m.calibrate()
    m.advance(1.0)
    m.abort("z")
    events = finished(run(m))
    assert [e.letters for e in events] == ["AAE-"]
    assert m.statuslimit() == "AA--------------"


def test_cal_starting_on_the_switch_only_releases() -> None:
    cfg = MotionConfig(axes=(AxisConfig(start_position=-50.5),) + (AxisConfig(),) * 3)
    m = MotionModel(cfg)
    assert m.status_letter("x") == "S"
    m.calibrate(["x"])
    events = finished(run(m))
    assert events[0].letters == "A@@-"
    release = 0.32
    assert events[0].time == pytest.approx(release / A + (0.5 - release**2 / (2 * A)) / release
                                           + release / A)


def test_extmode_calvel() -> None:
    m = MotionModel()
    m.global_settings.extmode = 1
    m.settings("x").calvel = (5.0, 1.0)
    m.calibrate(["x"])
    m.advance(1.0)
    assert m.velocity("x") == pytest.approx(-5.0)
    events = finished(run(m))
    assert events[0].time == pytest.approx(cal_time(50.0, 5.0, 1.0), rel=1e-9)


def test_vrm_needs_cal_and_sets_upper_limit() -> None:
    m = MotionModel()
    with pytest.raises(MotionRefused) as err:
        m.virtual_range_measure({"x": 300.0})
    assert err.value.code == ERR_NOT_EXECUTABLE
    m.calibrate(["x", "y"])
    run(m)
    m.move_absolute({"x": 10.0, "y": 10.0})
    run(m)
    m.set_position("x", 0.0)
    m.set_position("y", 0.0)
    assert m.limits("x")[0] == pytest.approx(-10.0)
    m.virtual_range_measure({"x": 300.0, "y": 300.0})
    assert m.next_event_time() is None  # no autostatus reply
    assert m.limits("x") == pytest.approx((-10.0, 290.0))
    assert m.statuslimit() == "AA--DD----------"
    assert m.is_released("x")
    assert m.position_offset("x") == pytest.approx(-10.0)
    m.clear_position_offset("x")
    assert m.position("x") == pytest.approx(10.0)


def test_calrequired() -> None:
    m = MotionModel()
    m.settings("x").calrequired = 1
    with pytest.raises(MotionRefused) as err:
        m.move_absolute({"x": 1.0})
    assert err.value.code == ERR_MOVE_NOT_ALLOWED
    m.calibrate(["x"])
    run(m)
    m.move_absolute({"x": 1.0})
    run(m)
    assert m.position("x") == 1.0


# ----------------------------------------------------------------------------- secvel


def test_secvel_caps_until_released() -> None:
    m = MotionModel()
    m.settings("x").vel = 40.0
    m.move_absolute({"x": 20.0})
    m.advance(1.0)
    assert m.velocity("x") == pytest.approx(10.0)  # secvel 10 mm/s at pitch 1
    run(m)
    m.settings("x").pitch = 2.0  # cap is in mm/s: 5 rev/s now
    m.move_absolute({"x": 0.0})
    m.advance(m.now + 1.0)
    assert m.velocity("x") == pytest.approx(-5.0)
    run(m)
    m.settings("x").pitch = 1.0
    m.calibrate(["x"])
    m.advance(m.now + 1.0)
    assert m.velocity("x") == pytest.approx(-10.0)  # cal approach is capped as well
    run(m)
    m.virtual_range_measure({"x": 100.0})
    m.move_absolute({"x": 60.0})
    m.advance(m.now + 1.0)
    assert m.velocity("x") == pytest.approx(40.0)


def test_secvel_release_rules() -> None:
    m = MotionModel()
    m.settings("x").swact = (0, 0, 0)
    m.settings("y").swact = (1, 0, 0)
    assert m.is_released("x")
    assert not m.is_released("y") and not m.is_released("z")
    m.calibrate(["y", "z"])
    run(m)
    assert m.is_released("y")
    assert not m.is_released("z")
    m.settings("z").vel = 40.0
    m.speed({"z": 40.0})
    m.advance(m.now + 1.0)
    assert m.velocity("z") == pytest.approx(10.0)  # speed is capped too


# ----------------------------------------------------------------------------- timing


def test_delay_and_pause() -> None:
    m = free_model()
    m.global_settings.delay_ms = 500
    m.global_settings.pause_ms = 200
    m.move_absolute({"x": 10.0})
    assert m.next_event_time() == pytest.approx(0.5)
    m.advance(0.4)
    assert m.position("x") == 0.0 and m.status_letter("x") == "M"
    m.advance(0.6)
    assert m.velocity("x") == pytest.approx(V)
    end = 0.5 + trapezoid_time(10.0, V, A)
    assert m.advance(end + 0.1) == []
    assert m.position("x") == 10.0
    assert m.status_letter("x") == "M"  # settling pause
    m.abort()  # nothing moves during the pause: no effect
    events = run(m)
    assert [e.letters for e in finished(events)] == ["@@@-"]
    assert events[0].time == pytest.approx(end + 0.2)
    assert m.status_letter("x") == "@"
    # cal/rm ignore delay and pause
    m2 = MotionModel()
    m2.global_settings.delay_ms = 500
    m2.calibrate(["x"])
    m2.advance(0.1)
    assert m2.velocity("x") < 0


def test_abort_during_delay_reports_immediately() -> None:
    m = free_model()
    m.global_settings.delay_ms = 1000
    m.global_settings.pause_ms = 1000
    m.move_absolute({"x": 10.0, "y": 1.0})
    m.advance(0.3)
    m.abort("x")
    m.advance(0.5)
    events = run(m)
    assert m.position("x") == 0.0
    assert m.position("y") == 1.0
    assert [e.letters for e in finished(events)] == ["E@@-"]
    # aborted job: no pause after y stopped
    assert events[0].time == pytest.approx(1.0 + trapezoid_time(1.0, V, A))

    m.move_absolute({"x": 1.0})
    m.advance(m.now + 0.1)
    m.abort()
    assert [e.letters for e in finished(m.advance(m.now))] == ["E@@-"]


def test_advance_rejects_going_back_and_events_are_ordered() -> None:
    m = free_model()
    m.move_absolute({"x": 1.0})
    m.move_absolute({"y": 5.0})
    m.move_absolute({"z": 3.0})
    events = m.advance(100.0)
    assert [e.letters for e in finished(events)] == ["@@@-"] * 3
    assert [e.time for e in events] == sorted(e.time for e in events)
    assert [e.job_id for e in finished(events)] == [1, 3, 2]
    with pytest.raises(ValueError):
        m.advance(50.0)


# ----------------------------------------------------------------------------- positions


def test_pos_offset_zero_clearpos() -> None:
    m = free_model()
    m.move_absolute({"x": 1.0, "y": 2.0, "z": 3.0})
    run(m)
    m.set_position("y", 8.0)
    assert m.position("y") == 8.0
    assert m.position_offset("y") == pytest.approx(6.0)
    m.clear_position_offset("y")
    assert m.position("y") == 2.0
    m.set_limits("z", -1.0, 1.0)
    m.zero("z")
    assert m.position("z") == 0.0
    assert m.limits("z") == (-1.0, 1.0)  # limits stay numeric in the counter frame
    m.move_absolute({"z": 1.0})
    run(m)


def test_status_letters_for_fewer_axes() -> None:
    m = free_model(n_axes=2)
    m.move_absolute({"y": 1.0})
    assert m.status_letters() == "@M--"
    assert [e.letters for e in finished(run(m))] == ["@@--"]
    assert m.statuslimit() == "----------------"


# ----------------------------------------------------------------------------- triggers


def test_trigger_range_counts_crossings_and_rearms() -> None:
    m = free_model()
    m.set_trigger_range("x", 1.0, 9.0, 9)
    assert m.trigger_index() == 1
    m.move_absolute({"x": 10.0})
    events = run(m)
    fired = [e for e in events if isinstance(e, TriggerFired)]
    assert [e.index for e in fired] == list(range(1, 10))
    assert [e.position for e in fired] == pytest.approx([float(p) for p in range(1, 10)])
    for e in fired:  # x(t) = 0.05 + 10 (t - 0.01) on the cruise
        assert e.time == pytest.approx((e.position - 0.05) / V + 0.01)
    assert m.trigger_count == 9
    assert m.trigger_index() == 10
    m.move_absolute({"x": 0.5})  # backwards: no triggers, but re-arms behind the start
    assert not [e for e in run(m) if isinstance(e, TriggerFired)]
    assert m.trigger_index() == 1
    m.move_absolute({"x": 5.0})
    run(m)
    assert m.trigger_count == 14
    m.set_trigger_count(0)
    assert m.trigger_count == 0


def test_trigger_not_rearmed_without_going_behind_start() -> None:
    m = free_model()
    m.set_trigger_positions("x", [1.0, 2.0, 3.0])
    m.move_absolute({"x": 3.0})  # stops exactly on the last entry: fires
    run(m)
    assert m.trigger_count == 3
    m.move_absolute({"x": 1.0})  # back to the first entry, not behind it
    run(m)
    m.move_absolute({"x": 4.0})
    run(m)
    assert m.trigger_count == 3


def test_trigger_decreasing_list_and_single_entry() -> None:
    m = free_model()
    m.set_trigger_positions("y", [-1.0, -2.0])
    m.go({"y": -5.0})
    run(m)
    assert m.trigger_count == 2
    m.set_trigger_positions("y", [-3.0])  # one entry: direction from the position (up)
    m.go({"y": 0.0})
    run(m)
    assert m.trigger_count == 3
    with pytest.raises(MotionRefused):
        m.set_trigger_positions("y", [1.0, 2.0, 1.5])
    m.clear_triggers()
    assert m.trigger_index() == 0


def test_trigger_counts_during_go_reversal_only_once() -> None:
    m = free_model()
    m.set_trigger_positions("x", [5.0])
    m.go({"x": 10.0})
    m.advance(0.52)  # at 5.15: fired once
    assert m.trigger_count == 1
    m.go({"x": 4.0})  # overshoots to 5.2, comes back through 5 (no fire) and re-arms
    events = run(m)
    assert not [e for e in events if isinstance(e, TriggerFired)]
    assert m.trigger_index() == 1
    m.go({"x": 6.0})
    run(m)
    assert m.trigger_count == 2


# ----------------------------------------------------------------------------- exactness

COMMAND_TIMES = (0.0, 0.7, 1.3, 1.9, 2.2, 3.1)
END = 12.0


def scripted(model: MotionModel, step: int) -> None:
    """A command script exercising vector moves, go, speed, abort, switches, triggers."""
    if step == 0:
        model.settings("y").vel = 3.0
        model.set_trigger_range("x", 2.0, 20.0, 37)
        model.move_absolute({"x": 30.0, "y": -20.0})
        model.go({"z": 15.0})
    elif step == 1:
        model.go({"z": -7.5})
    elif step == 2:
        model.abort("y")
    elif step == 3:
        model.set_vel("z", 4.0)
    elif step == 4:
        model.speed({"y": 7.0})
    elif step == 5:
        model.go({"z": 3.0})


def play(splits: list[float]) -> tuple[list[MotionEvent], list[float]]:
    model = MotionModel()
    model.settings("x").swact = (0, 0, 0)
    points = sorted({*splits, *COMMAND_TIMES, END})
    events: list[MotionEvent] = []
    for t in points:
        events += model.advance(t)
        if t in COMMAND_TIMES:
            scripted(model, COMMAND_TIMES.index(t))
    return events, [model.position(a) for a in "xyz"]


def play_cal(splits: list[float]) -> tuple[list[MotionEvent], list[float], str]:
    model = MotionModel()
    model.settings("z").caltimeout = 3.0
    model.settings("y").caliboffset = 0.75
    model.set_trigger_positions("x", [-10.0, -20.0, -30.0])
    events = model.advance(0.0)
    model.calibrate()
    for t in sorted({*splits, 20.0}):
        events += model.advance(t)
    model.range_measure(["x"])
    events += model.advance(40.0)
    return events, [model.position(a) for a in "xyz"], model.statuslimit()


@settings(max_examples=60)
@given(st.lists(st.floats(0.0, END, allow_nan=False), max_size=40))
def test_step_splitting_is_exact(splits: list[float]) -> None:
    reference = play([])
    assert play(splits) == reference
    events, _ = reference
    assert any(isinstance(e, TriggerFired) for e in events)
    assert [e.letters for e in finished(events)] == ["@E@-"]


@settings(max_examples=30)
@given(st.lists(st.floats(0.0, 20.0, allow_nan=False), max_size=30))
def test_step_splitting_is_exact_for_cal(splits: list[float]) -> None:
    reference = play_cal([])
    assert play_cal(splits) == reference
    events, _, status = reference
    assert [e.letters for e in finished(events)] == ["AAT-", "D@@-"]
    assert status == "AA--D-----------"
