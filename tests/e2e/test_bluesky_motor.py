"""tango_aio.bluesky axes as drop-ins for ophyd-async's Motor (#29), and the false-success
fixes of the Bluesky surface (#26).

The side-by-side tests run the same plan once against ophyd-async's ``SimMotor`` and once
against a TANGO axis (in-process emulator) and compare what the documents say; where the
two differ by design, the test says why.
"""

from __future__ import annotations

import asyncio
import logging
import re
import threading
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import pytest

pytest.importorskip("bluesky")
pytest.importorskip("ophyd_async")

import bluesky.plan_stubs as bps
import bluesky.plans as bp
import test_bluesky as tb
from bluesky import RunEngine, RunEngineInterrupted
from bluesky.utils import FailedStatus
from ophyd_async.core import FlyMotorInfo, init_devices
from ophyd_async.sim import SimMotor
from test_bluesky import emulated, events, failure, model_of, run
from test_coalesce import motion_lines

from tango_aio.bluesky import (
    MarzhauserAxis,
    MarzhauserFlyer,
    MarzhauserStage,
    StageLimitsError,
    TriggerScan,
    egu_velocity,
    home,
    measure_range,
    run_up_distance,
)
from tango_aio.errors import MoveError, TangoError
from tango_aio.sim.motion import AxisConfig, MotionConfig
from tango_aio.testing import faults

RE = tb.RE
documents = tb.documents
URL = tb.URL
#: Pitch of the emulated spindles (mm per motor revolution): velocities in EGU/s and
#: the controller's rev/s then differ by a factor of 2.
PITCH = 2.0


def _stage(window: float = 0.0) -> MarzhauserStage:
    with init_devices():
        stage = MarzhauserStage(URL, axes="xy", window=window, progress_interval=0.02)
    return stage


async def _setup(stage: MarzhauserStage, velocity: float = 50.0) -> None:
    """Pitch 2 mm, ``velocity`` rev/s, 10 m/s²; the link reads the new scales again."""
    controller = stage.controller
    await controller.set("pitch", x=PITCH, y=PITCH)
    for name, value in (("secvel", 100), ("vel", velocity), ("accel", 10)):
        await controller.set(name, x=value, y=value)
    await stage.refresh_settings()


@pytest.fixture
def stage(RE: RunEngine) -> Iterator[MarzhauserStage]:
    stage = _stage()
    run(_setup(stage))
    yield stage
    run(stage.aclose())


@pytest.fixture
def moves(caplog: pytest.LogCaptureFixture) -> Callable[[], list[str]]:
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    return lambda: motion_lines(caplog)


def _sim_motors() -> tuple[SimMotor, SimMotor]:
    with init_devices():
        x = SimMotor(instant=True)
        y = SimMotor(instant=True)
    return x, y


Motors = tuple[Any, Any]


@pytest.fixture(params=["SimMotor", "tango"])
def motors(request: pytest.FixtureRequest, RE: RunEngine) -> Iterator[Motors]:
    """Two motors (x, y) of one kind; both start at 0."""
    if request.param == "SimMotor":
        yield _sim_motors()
        return
    stage = _stage()
    run(_setup(stage))
    yield stage.x, stage.y
    run(stage.aclose())


async def _under_way(axis: Any, beyond: float = 0.1) -> None:
    """Return once ``axis``'s readback is past ``beyond`` (it moves)."""
    for _ in range(4000):
        if await axis.user_readback.get_value() > beyond:
            return
        await asyncio.sleep(0.005)
    raise AssertionError(f"{axis.name} did not move")


def _readings(documents: list[Any], *motors: Any) -> list[tuple[float, ...]]:
    return [tuple(row[m.name] for m in motors) for row in events(documents)]


# --------------------------------------------------------------------------------------
# The same scripts against SimMotor and against our axes


def test_scan_side_by_side(RE: RunEngine, motors: Motors, documents: list[Any]) -> None:
    x, _ = motors
    RE(bp.scan([x], x, 0, 1, 3))
    assert _readings(documents, x) == [(0.0,), (0.5,), (1.0,)]
    assert run(x.locate()) == {"setpoint": 1.0, "readback": 1.0}


def test_grid_and_rel_scan_side_by_side(RE: RunEngine, motors: Motors,
                                        documents: list[Any]) -> None:
    x, y = motors
    RE(bp.grid_scan([x, y], y, 0, 1, 2, x, 0, 2, 3, snake_axes=True))
    assert _readings(documents, y, x) == [
        (0.0, 0.0), (0.0, 1.0), (0.0, 2.0), (1.0, 2.0), (1.0, 1.0), (1.0, 0.0)]
    documents.clear()
    RE(bps.mv(x, 1.5))
    RE(bp.rel_scan([x], x, -1, 1, 3))
    assert _readings(documents, x) == [(0.5,), (1.5,), (2.5,)]
    # Both return to the start after a rel_scan (bluesky's reset_positions_wrapper).
    assert run(x.locate())["readback"] == 1.5


def test_velocity_is_in_egu_per_second_side_by_side(RE: RunEngine, motors: Motors) -> None:
    x, _ = motors
    RE(bps.mv(x.velocity, 5))
    assert run(x.velocity.get_value()) == 5.0
    RE(bps.mv(x, 1.0))
    assert run(x.locate()) == {"setpoint": 1.0, "readback": 1.0}
    if isinstance(x, MarzhauserAxis):  # and the controller runs at 5 mm/s: 2.5 rev/s
        controller = x._link.controller
        assert run(controller.get("vel", axis="x")) == 5.0 / PITCH
        motion = model_of_axis(x).motion
        assert motion.vel_to_user(0, float(run(controller.get("vel", axis="x")))) \
            * PITCH == pytest.approx(5.0)


def test_a_pitch_changed_through_the_controller_reaches_the_axis(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    x = stage.x
    run(stage.controller.command("!pitch x 4"))  # not through the stage
    RE(bps.mv(x.velocity, 8))  # 8 mm/s at 4 mm per revolution: 2 rev/s
    assert run(stage.controller.get("vel", axis="x")) == 2.0
    assert run(x.velocity.get_value()) == 8.0
    run(stage.controller.settings.set_pitch(x=PITCH))
    assert run(x.velocity.get_value()) == 4.0


def model_of_axis(axis: MarzhauserAxis) -> Any:
    return faults(axis._link.controller).model


def test_fly_motor_info_side_by_side(RE: RunEngine, motors: Motors) -> None:
    x, _ = motors
    info = FlyMotorInfo(start_position=0.5, end_position=2.5, time_for_move=0.5)
    speed = info.speed  # 4 EGU/s
    if isinstance(x, SimMotor):
        # SimMotor keeps an acceleration *time*; our controller keeps the acceleration
        # (accel, m/s²). With the time that gives the same ramp, both fly the same path.
        accel = 10 * 1000 / PITCH * PITCH  # 10 m/s² in mm/s² (pitch cancels out)
        RE(bps.mv(x.acceleration_time, speed / accel))
    else:
        accel = run(x.acceleration_egu())
    ramp = run_up_distance(speed, accel)
    kicked: list[float] = []

    def plan() -> Any:
        yield from bps.open_run()
        yield from bps.prepare(x, info, wait=True)
        kicked.append((yield from bps.rd(x)))
        assert (yield from bps.rd(x.velocity)) == pytest.approx(speed)
        yield from bps.kickoff(x, wait=True)
        yield from bps.complete(x, wait=True)
        yield from bps.close_run()

    RE(plan())
    assert kicked == [pytest.approx(0.5 - ramp)]
    assert run(x.locate())["readback"] == pytest.approx(2.5 + ramp)


def test_locate_and_stop_side_by_side(RE: RunEngine, motors: Motors) -> None:
    x, _ = motors
    # SimMotor moves at 1 EGU/s when not instant; ours at 1 mm/s (0.5 rev/s).
    if isinstance(x, SimMotor):
        RE(bps.mv(x.velocity, 1.0))
    else:
        RE(bps.mv(x.velocity, 1.0))

    async def move_and_stop() -> BaseException | None:
        status = x.set(10.0)
        await _under_way(x, 0.05)
        await x.stop(success=False)
        return await failure(status)

    error = run(move_and_stop())
    assert isinstance(error, RuntimeError)
    location = run(x.locate())
    # Both (and the motor record) take where the motor stopped as the new setpoint.
    assert location["setpoint"] == location["readback"]
    assert 0.0 < location["readback"] < 10.0


# --------------------------------------------------------------------------------------
# Motor's signals on our axes


def test_signals_of_motor(RE: RunEngine, stage: MarzhauserStage) -> None:
    x = stage.x
    values = run(_values(x))
    assert values["motor_egu"] == "mm"
    assert values["max_velocity"] == 200 * PITCH  # vel's catalog bound, 200 rev/s
    assert values["units_per_revolution"] == PITCH
    assert values["steps_per_revolution"] == 40000
    assert values["motor_resolution"] == PITCH / 40000
    assert values["velocity"] == 50 * PITCH
    # 100 mm/s at 10 m/s² (10000 mm/s²): 0.01 s
    assert values["acceleration_time"] == pytest.approx(0.01)
    assert values["motor_done_move"] == 1
    assert (values["low_limit_switch"], values["high_limit_switch"]) == (0, 0)
    assert values["offset"] == 0.0
    assert (values["dial_low_limit_travel"], values["dial_high_limit_travel"]) == (
        -2600.0, 2600.0)
    RE(bps.mv(x.acceleration_time, 0.1))
    assert run(stage.controller.get("accel", axis="x")) == pytest.approx(1.0)  # m/s²
    described = run(x.describe_configuration())
    assert described["stage-x-velocity"]["units"] == "mm/s"


async def _values(axis: MarzhauserAxis) -> dict[str, Any]:
    names = ["motor_egu", "max_velocity", "units_per_revolution", "steps_per_revolution",
             "motor_resolution", "velocity", "acceleration_time", "motor_done_move",
             "low_limit_switch", "high_limit_switch", "offset", "dial_low_limit_travel",
             "dial_high_limit_travel", "low_limit_travel", "high_limit_travel",
             "precision"]
    return {name: await getattr(axis, name).get_value() for name in names}


def test_velocity_above_max_is_refused_before_anything_moves(
        RE: RunEngine, stage: MarzhauserStage, moves: Callable[[], list[str]]) -> None:
    info = FlyMotorInfo(start_position=0, end_position=500, time_for_move=0.5)  # 1000/s
    with pytest.raises(FailedStatus) as raised:
        RE(bps.prepare(stage.x, info, wait=True))
    assert isinstance(raised.value.__cause__, StageLimitsError)
    assert "max velocity" in str(raised.value.__cause__)
    assert moves() == []


def test_travel_limits_are_writable(RE: RunEngine, stage: MarzhauserStage) -> None:
    RE(bps.mv(stage.x.high_limit_travel, 5.0, stage.x.low_limit_travel, -1.0))
    assert run(stage.controller.get("lim", axis="x")) == (-1.0, 5.0)
    with pytest.raises(StageLimitsError):
        run(stage.x.check_value(6.0))
    RE(bps.mv(stage.x.dial_high_limit_travel, 7.0))  # offset 0: dial == user
    assert run(stage.x.high_limit_travel.get_value()) == 7.0


def test_offset_redefines_the_position(RE: RunEngine, stage: MarzhauserStage) -> None:
    RE(bps.mv(stage.x, 1.0))
    RE(bps.mv(stage.x.offset, 10.0))
    assert run(stage.controller.get("posclr", axis="x")) == pytest.approx(10.0)
    assert run(stage.x.locate()) == {"setpoint": 11.0, "readback": 11.0}
    # nothing moved: the emulator's position less the offset is where it was
    assert emulated(stage)["x"] - run(stage.controller.get("posclr", axis="x")) == \
        pytest.approx(1.0)
    assert run(stage.x.dial_high_limit_travel.get_value()) == pytest.approx(
        run(stage.x.high_limit_travel.get_value()) - 10.0)
    RE(bps.wait_for([lambda: stage.x.clear_offset()]))
    assert run(stage.x.locate()) == {"setpoint": 1.0, "readback": 1.0}


def test_init_devices_mock_backs_every_signal(RE: RunEngine, documents: list[Any]) -> None:
    with init_devices(mock=True):
        stage = MarzhauserStage(URL, axes="xy")
    values = run(_values(stage.x))
    assert values["velocity"] == values["max_velocity"] == 1000.0
    assert values["motor_done_move"] == 1
    RE(bps.mv(stage.x.velocity, 3, stage.x.offset, 1, stage.x.high_limit_travel, 9))
    assert run(stage.x.velocity.get_value()) == 3.0
    RE(bp.scan([stage], stage.x, 0, 1, 2))
    assert [row["stage-x"] for row in events(documents)] == [0.0, 1.0]
    info = FlyMotorInfo(start_position=0, end_position=1, time_for_move=1)
    RE(bps.prepare(stage.x, info, wait=True))
    assert not stage.link.connected


def test_egu_velocity_follows_pitch_gear_and_dim() -> None:
    from tango_aio.units import UnitScale
    assert egu_velocity(5, UnitScale(dim=2, pitch=2, gear=1)) == 10.0
    assert egu_velocity(5, UnitScale(dim=1, pitch=2, gear=4)) == 2500.0  # µm/s
    assert egu_velocity(5, UnitScale(dim=9, pitch=2, gear=4)) == 5.0  # already mm/s
    assert egu_velocity(1, UnitScale(dim=0, pitch=2, gear=4, usteps=100)) == 100.0


# --------------------------------------------------------------------------------------
# Homing, events, done-move


def _shorten(stage: MarzhauserStage, travel: float = 10.0) -> None:
    """Limit switches at ±travel/2 mm (quick cal/rm), as tests/helpers does."""
    async def reboot() -> None:
        model = model_of(stage)
        axis = AxisConfig(e0_position=-travel / 2, ee_position=travel / 2)
        model.config = replace(model.config, motion=MotionConfig(
            n_axes=model.axes, axes=(axis,) * 4))
        model.reboot()
        await stage.controller.setup(autostatus=1)
        await _setup(stage, velocity=20)
        await stage.controller.set("calbspeed", 8000)

    run(reboot())


def test_home_and_measure_range(RE: RunEngine, stage: MarzhauserStage) -> None:
    _shorten(stage)
    RE(bps.mv(stage.x, 3.0))
    RE(home(stage.x))
    # The origin is set at the lower switch (the emulator's cal), and the signals show it.
    assert run(stage.x.locate()) == {"setpoint": 0.0, "readback": 0.0}
    assert run(stage.x.low_limit_travel.get_value()) == 0.0
    RE(measure_range(stage.x))
    high = run(stage.x.high_limit_travel.get_value())
    assert high == run(stage.x.user_readback.get_value()) > 3.0  # the upper switch


def test_home_fails_when_the_controller_reports_failure(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    _shorten(stage)
    run(stage.controller.set("axis", 0, axis="x"))  # a disabled axis cannot calibrate
    with pytest.raises(MoveError, match=r"status '?-"):
        RE(home(stage.x))
    with pytest.raises(MoveError):
        RE(measure_range(stage.x))


def test_idle_readback_follows_events_without_polling(
        RE: RunEngine, stage: MarzhauserStage, caplog: pytest.LogCaptureFixture) -> None:
    seen: list[float] = []
    arrived = threading.Event()

    def note(reading: dict[str, Any]) -> None:
        seen.append(reading["stage-x"]["value"])
        if seen[-1] == 3.0:
            arrived.set()

    async def subscribe() -> None:
        stage.x.subscribe_reading(note)

    run(subscribe())
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    # Another caller of the same controller moves X (not through the device).
    run(stage.controller.move_to(x=3.0))
    assert arrived.wait(10)
    caplog.clear()
    run(asyncio.sleep(0.3))  # idle: nothing is polled
    assert [r.getMessage() for r in caplog.records if "?pos" in r.getMessage()] == []


def test_motor_done_move_follows_a_move(RE: RunEngine, stage: MarzhauserStage) -> None:
    seen: list[int] = []

    async def subscribe() -> None:
        stage.x.motor_done_move.subscribe_reading(
            lambda reading: seen.append(reading["stage-x-motor_done_move"]["value"]))

    run(subscribe())
    RE(bps.mv(stage.x, 1.0))
    assert seen[0] == 1 and 0 in seen and seen[-1] == 1


# --------------------------------------------------------------------------------------
# #26: no false success, words in the errors


def test_fly_timeout_stops_the_pass_and_names_where(
        RE: RunEngine, stage: MarzhauserStage, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    # 10 mm in 5 s (2 mm/s), bounded to 0.3 s as a FlyMotorInfo may be (Motor's timeout).
    info = FlyMotorInfo(start_position=0.0, end_position=10.0, time_for_move=5.0,
                        timeout=0.3)

    async def fly() -> BaseException | None:
        await stage.x.prepare(info)
        await stage.x.kickoff()
        return await failure(stage.x.complete())

    error = run(fly())
    assert isinstance(error, TimeoutError)
    assert "stage-x" in str(error) and "stopped at" in str(error)
    assert run(stage.controller.status())["x"] != "M"
    assert emulated(stage)["x"] < 10.0
    _assert_one_axis_stop(caplog)


def _assert_one_axis_stop(caplog: pytest.LogCaptureFixture) -> None:
    """X was stopped with the one-axis stop, and nothing stopped every axis."""
    written = [r.getMessage() for r in caplog.records if r.name == "tango_aio.wire"]
    assert any(line.endswith("-> b'!a x'") for line in written), written
    assert not any(line.endswith("-> b'!a'") for line in written)


def test_pause_during_an_axis_fly_pass_then_resume(
        RE: RunEngine, stage: MarzhauserStage, documents: list[Any]) -> None:
    # 2 mm in 1 s: the pause lands in the pass; on resume the plan flies it again.
    info = FlyMotorInfo(start_position=0.0, end_position=2.0, time_for_move=1.0)
    paused = threading.Event()

    def pause_in_the_pass(reading: dict[str, Any]) -> None:
        if 0.5 < reading["stage-x"]["value"] < 1.5 and not paused.is_set():
            paused.set()
            threading.Thread(target=RE.request_pause).start()

    async def subscribe() -> None:
        stage.x.subscribe_reading(pause_in_the_pass)

    def plan() -> Any:
        yield from bps.open_run()
        yield from bps.checkpoint()
        yield from bps.prepare(stage.x, info, wait=True)
        yield from bps.kickoff(stage.x, wait=True)
        yield from bps.complete(stage.x, wait=True)
        yield from bps.close_run()

    run(subscribe())
    with pytest.raises(RunEngineInterrupted):
        RE(plan())
    assert run(stage.controller.status())["x"] != "M"  # the pass was stopped
    assert 0.5 < emulated(stage)["x"] < 2.0
    RE.resume()
    ramp = run_up_distance(info.speed, run(stage.x.acceleration_egu()))
    assert emulated(stage)["x"] == pytest.approx(2.0 + ramp, abs=1e-3)
    assert [doc for name, doc in documents if name == "stop"][-1]["exit_status"] == \
        "success"


def test_set_timeout_names_axis_target_and_where_it_stopped(
        RE: RunEngine, stage: MarzhauserStage, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    run(stage.controller.set("vel", 0.5, axis="x"))  # 1 mm/s

    async def move() -> BaseException | None:
        return await failure(stage.x.set(20.0, timeout=0.3))

    error = run(move())
    assert isinstance(error, TimeoutError)
    where = emulated(stage)["x"]
    assert 0 < where < 20
    message = str(error)
    assert "stage-x" in message and "20.0" in message and "stopped at" in message
    stopped = re.search(r"stopped at (-?[0-9.]+) mm", message)
    assert stopped is not None, message
    assert abs(float(stopped.group(1)) - where) < 1e-3, (message, where)
    # The limit is what was left of the caller's 0.3 s when the move was written.
    within = re.search(r"within ([0-9.]+) s", message)
    assert within is not None and 0 < float(within.group(1)) <= 0.3, message
    _assert_one_axis_stop(caplog)
    RE(bps.mv(stage.x, 0))  # the next move works
    assert emulated(stage)["x"] == 0.0


def test_stopping_an_idle_axis_leaves_another_axis_move_alone(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    run(stage.controller.set("vel", 2.5, axis="y"))  # 5 mm/s

    async def move_y_stop_x() -> BaseException | None:
        status = stage.y.set(2.0)
        await _under_way(stage.y)
        await stage.x.stop()
        return await failure(status)

    assert run(move_y_stop_x()) is None
    assert emulated(stage)["y"] == 2.0


def test_stopping_x_stops_x_only_and_a_y_move_goes_on(
        RE: RunEngine, stage: MarzhauserStage, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    run(stage.controller.set("vel", 1.0, axis="x"))  # 2 mm/s
    run(stage.controller.set("vel", 1.0, axis="y"))

    async def move_both_stop_x() -> tuple[BaseException | None, BaseException | None]:
        x_status = stage.x.set(10.0)
        await _under_way(stage.x)
        # Y runs a line of its own behind X's (!moa y 1.0 after X's move ends).
        y_status = stage.y.set(1.0)
        await stage.x.stop()
        return await failure(x_status), await failure(y_status)

    x_error, y_error = run(move_both_stop_x())
    assert isinstance(x_error, RuntimeError)
    assert y_error is None
    assert emulated(stage)["y"] == 1.0
    assert 0.1 < emulated(stage)["x"] < 10.0
    _assert_one_axis_stop(caplog)


def test_stopping_x_of_a_merged_line_lets_y_arrive_and_succeed(
        RE: RunEngine, stage: MarzhauserStage, moves: Callable[[], list[str]]) -> None:
    run(stage.controller.set("vel", x=1.0, y=1.0))  # 2 mm/s

    async def move_both_stop_x() -> tuple[BaseException | None, BaseException | None]:
        # One line; Y travels at half X's speed (the line's vector interpolation).
        x_status, y_status = stage.x.set(1.0), stage.y.set(0.5)
        await _under_way(stage.x)
        await stage.x.stop()
        return await failure(x_status), await failure(y_status)

    x_error, y_error = run(move_both_stop_x())
    assert moves() == ["!moa 1 0.5"]
    assert isinstance(x_error, RuntimeError)
    assert y_error is None  # Y was confirmed at its target after the line failed
    assert emulated(stage)["y"] == 0.5
    assert 0.1 < emulated(stage)["x"] < 1.0


def test_pause_landing_in_a_flyer_kickoff_is_no_failure(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    with init_devices():
        flyer = MarzhauserFlyer(stage)
    scan = TriggerScan("x", start=-0.5, end=3.0, trigger_range=(0.0, 2.0, 3))

    async def kickoff_then_pause() -> tuple[BaseException | None, BaseException | None]:
        await flyer.prepare(scan)
        kickoff = flyer.kickoff()
        await asyncio.sleep(0)  # kickoff has started the pass, not yet seen it move
        await flyer.pause()
        kicked = await failure(kickoff)
        return kicked, await failure(flyer.complete())

    assert run(kickoff_then_pause()) == (None, None)
    assert list(flyer.collect()) == []  # a paused pass gives no data: the plan replays it


@pytest.mark.slow
def test_pause_during_kickoff_then_resume_many_rounds(
        RE: RunEngine, stage: MarzhauserStage, documents: list[Any]) -> None:
    state = {"pause": True}

    class PausingFlyer(MarzhauserFlyer):
        """Requests a RunEngine pause as its kickoff starts (once per round)."""

        def kickoff(self) -> Any:
            status = super().kickoff()
            if state["pause"]:
                state["pause"] = False
                threading.Thread(target=RE.request_pause).start()
            return status

    with init_devices():
        flyer = PausingFlyer(stage)
    scan = TriggerScan("x", start=-0.5, end=1.0, trigger_range=(0.0, 0.5, 2))

    def plan() -> Any:
        yield from bps.open_run()
        yield from bps.checkpoint()
        yield from bps.prepare(flyer, scan, wait=True)
        yield from bps.kickoff(flyer, wait=True)
        yield from bps.complete(flyer, wait=True)
        yield from bps.collect(flyer)
        yield from bps.close_run()

    for _ in range(60):
        state["pause"] = True
        documents.clear()
        try:
            RE(plan())
        except RunEngineInterrupted:
            RE.resume()
        stops = [doc for name, doc in documents if name == "stop"]
        assert stops[-1]["exit_status"] == "success", stops
        assert events(documents, "flyer")[-1]["flyer-trigger_count"] == 2


# --------------------------------------------------------------------------------------
# Fly-scan documents map to positions


def test_fly_documents_carry_the_trigger_positions_and_axis_keys(
        RE: RunEngine, stage: MarzhauserStage, documents: list[Any]) -> None:
    with init_devices():
        flyer = MarzhauserFlyer(stage)
    positions = [0.0, 0.4, 1.1, 1.5, 2.75]
    scan = TriggerScan("x", start=-0.5, end=3.0, positions=positions, snapshots=True)

    def plan() -> Any:
        yield from bps.open_run()
        yield from bps.prepare(flyer, scan, wait=True)
        yield from bps.kickoff(flyer, wait=True)
        yield from bps.wait_for([lambda: stage.controller.command("!snse 2")])
        yield from bps.complete(flyer, wait=True)
        yield from bps.collect(flyer)
        yield from bps.close_run()

    RE(plan())
    triggers = events(documents, "flyer_triggers")
    assert [row["flyer-trigger_position"] for row in triggers] == positions
    assert [row["flyer-trigger_index"] for row in triggers] == list(range(5))
    assert positions == run(stage.controller.triggers.read_positions())
    descriptors = {doc["name"]: doc for name, doc in documents if name == "descriptor"}
    key = descriptors["flyer_triggers"]["data_keys"]["flyer-trigger_position"]
    assert key["units"] == "mm" and "x" in key["source"]
    snapshots = events(documents, "flyer_snapshots")
    assert snapshots and all(set(row) == {"flyer-snapshot_x", "flyer-snapshot_y"}
                             for row in snapshots)  # an "xy" stage: no snapshot_z
    pass_end = min(_times(documents, descriptors["flyer"]["uid"]))
    snapshot_times = _times(documents, descriptors["flyer_snapshots"]["uid"])
    assert snapshot_times and min(snapshot_times) >= pass_end  # read after the pass
    assert "read" in descriptors["flyer_snapshots"]["data_keys"][
        "flyer-snapshot_x"]["source"]


def _times(documents: list[Any], descriptor: str) -> list[float]:
    """The event times of one descriptor (events and event pages)."""
    out: list[float] = []
    for name, doc in documents:
        if name == "event" and doc["descriptor"] == descriptor:
            out.append(doc["time"])
        elif name == "event_page" and doc["descriptor"] == descriptor:
            out += doc["time"]
    return out


# --------------------------------------------------------------------------------------
# Cross-surface matrix, Bluesky row: a plan's move ends ...


@pytest.mark.slow  # the default run has tests/e2e/test_surfaces.py's Bluesky cells
def test_matrix_at_target(RE: RunEngine, stage: MarzhauserStage) -> None:
    RE(bps.mv(stage.x, 2.0))
    assert emulated(stage)["x"] == 2.0
    assert run(stage.x.read())["stage-x"]["value"] == 2.0


def test_matrix_limit_switch(RE: RunEngine, stage: MarzhauserStage) -> None:
    _shorten(stage)  # the switches sit at ±5 rev: ±10 mm with the 2 mm pitch
    with pytest.raises(FailedStatus) as raised:
        RE(bps.mv(stage.x, -15.0))
    assert isinstance(raised.value.__cause__, MoveError)
    assert emulated(stage)["x"] > -15.0
    assert run(stage.x.read())["stage-x"]["value"] == pytest.approx(emulated(stage)["x"])
    assert run(stage.x.low_limit_switch.get_value()) == 1


@pytest.mark.slow  # the default run has tests/e2e/test_surfaces.py's Bluesky cells
def test_matrix_disabled_axis(RE: RunEngine, stage: MarzhauserStage) -> None:
    run(stage.controller.set("axis", 0, axis="x"))
    with pytest.raises(FailedStatus) as raised:
        RE(bps.mv(stage.x, 2.0))
    assert isinstance(raised.value.__cause__, TangoError)
    assert emulated(stage)["x"] == 0.0


@pytest.mark.slow  # the default run has tests/e2e/test_surfaces.py's Bluesky cells
def test_matrix_abort_by_another_client(RE: RunEngine, stage: MarzhauserStage) -> None:
    run(stage.controller.set("vel", 1.0, axis="x"))  # 2 mm/s

    async def move_and_abort() -> BaseException | None:
        status = stage.x.set(10.0)
        await _under_way(stage.x)
        faults(stage.controller).model.motion.abort()  # as the controller's own stop
        return await failure(status)

    error = run(move_and_abort())
    assert isinstance(error, MoveError)
    assert emulated(stage)["x"] < 10.0


@pytest.mark.slow  # the default run has tests/e2e/test_surfaces.py's Bluesky cells
def test_matrix_link_lost(RE: RunEngine, stage: MarzhauserStage) -> None:
    run(stage.controller.set("vel", 1.0, axis="x"))

    async def move_and_cut() -> BaseException | None:
        status = stage.x.set(10.0)
        await _under_way(stage.x)
        faults(stage.controller).disconnect()
        return await failure(status)

    error = run(move_and_cut())
    assert isinstance(error, TangoError)


@pytest.mark.slow  # the default run has tests/e2e/test_surfaces.py's Bluesky cells
def test_matrix_refused_line(RE: RunEngine, stage: MarzhauserStage) -> None:
    run(stage.controller.set("lim", -5, 5, axis="x"))
    with pytest.raises(FailedStatus) as raised:
        RE(bps.mv(stage.x, 200.0))
    assert isinstance(raised.value.__cause__, StageLimitsError | TangoError)
    assert emulated(stage)["x"] == 0.0

