"""tango_aio.sardana's motor controller in Sardana's own in-process pool (its
``sardana.pool.test`` harness: ``BasePoolTestCase``'s element factories on a
``FakePool``), against the emulator: motion of one and of several motors, stop, abort, a
limit switch, the axis parameters; and the first rule: a motor never reads stopped while
its axis runs or before its final position can be read."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import pytest
from helpers import PTY_EMULATOR, make_model, posix_only

from tango_aio.sardana import POOL_PATH
from tango_aio.sync import Portal
from tango_aio.testing import Faults, emulator_url

# Sardana and taurus call deprecated functions (in the pool's threads too, where an error
# would end the motion loop): their own warnings are not this project's.
pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning:taurus"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning:sardana")]

#: Generous bound that only catches a hang (the pool's loop polls every 0.1 s).
HANG = 60.0


class _States:
    """``sardana.State``, imported when a test first looks at it."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # pytest's probes while collecting: no import for those
            raise AttributeError(name)
        from sardana import State as States

        return getattr(States, name)


State = _States()


def pool_case() -> Any:
    """Sardana's ``BasePoolTestCase`` on a ``FakePool`` holding only this project's
    controller library (not the base's dummy controllers). Skips without Sardana, which is
    imported here and not at collection (it takes a second in every worker)."""
    test = pytest.importorskip("sardana.pool.test",
                               reason="Sardana is not installed (the sardana extra)")

    class Pool(test.BasePoolTestCase):  # type: ignore[misc,name-defined]
        POOLPATH: ClassVar[list[str]] = [POOL_PATH]

        def setUp(self) -> None:
            self.pool = test.FakePool(self.POOLPATH, self.LOGLEVEL)
            self.ctrls: dict[str, Any] = {}
            self.mots: dict[str, Any] = {}
            self.cts: dict[str, Any] = {}
            self.tgs: dict[str, Any] = {}

    return Pool()


class Stage:
    """The pool, its TANGO controller element and motors, and the emulator behind them."""

    def __init__(self, case: Any, element: Any) -> None:
        self.case = case
        self.element = element
        self.ctrl = element.ctrl
        self.tango = self.ctrl.tango
        portal = self.tango.portal

        async def call_soon(action: Callable[[], None]) -> None:
            action()

        self.faults = Faults(self.tango.aio, lambda action: portal.call(call_soon, action))
        self.motors = [case.createMotorElement(element, f"m{axis}", axis) for axis in (1, 2, 3)]

    def truth(self) -> dict[str, tuple[float, float]]:
        """Where the emulated axes really are (position, velocity), read in the loop."""
        async def read() -> dict[str, tuple[float, float]]:
            return self.faults.axes()
        truth: dict[str, tuple[float, float]] = self.tango.portal.call(read)
        return truth

    def slow(self, speed: float) -> None:
        """Every axis at ``speed`` rev/s (mm/s at the default 1 mm pitch)."""
        self.tango.set("vel", x=speed, y=speed, z=speed)


@pytest.fixture
def stage(request: pytest.FixtureRequest) -> Iterator[Stage]:
    """The pool and its TANGO controller (extra properties: ``indirect`` parameters)."""
    case = pool_case()
    case.setUp()
    properties = {"URL": emulator_url(axes=3), **getattr(request, "param", {})}
    element = case.createController("tango", "MarzhauserMotorController",
                                    "MarzhauserMotorCtrl.py", properties)
    assert element.is_online(), element.get_ctrl_error_str()
    try:
        built = Stage(case, element)
        for name, value in (("vel", 100), ("secvel", 100), ("accel", 20), ("stopaccel", 20)):
            built.tango.set(name, x=value, y=value, z=value)
        yield built
    finally:
        case.tearDown()
        element.ctrl.close()


def wait_idle(*motors: Any) -> None:
    """Until the pool's motion of ``motors`` has ended (bounded only against a hang)."""
    deadline = time.monotonic() + HANG
    while any(m.is_in_operation() for m in motors):
        assert time.monotonic() < deadline, "the motion never ended"
        time.sleep(0.02)


def wait_true(check: Callable[[], bool]) -> None:
    deadline = time.monotonic() + HANG
    while not check():
        assert time.monotonic() < deadline, "never happened"
        time.sleep(0.02)


Seen = list[tuple[int, Any, dict[str, tuple[float, float]]]]


def watch_states(stage: Stage) -> Seen:
    """Record, each time ``StateOne`` answers, its state and where the emulated axes
    really were at that moment (after the answer was decided)."""
    seen: Seen = []
    ctrl = stage.ctrl
    original = ctrl.StateOne
    lock = threading.Lock()

    def state_one(axis: int) -> tuple[Any, str, int]:
        answer = original(axis)
        truth = stage.truth()
        with lock:
            seen.append((axis, answer[0], truth))
        return answer  # type: ignore[no-any-return]

    ctrl.StateOne = state_one
    return seen


def never_stopped_while_moving(seen: Seen) -> None:
    """No answer but Moving while the emulated axis still moved (the pool ends its motion
    on any other state and reads the final position then)."""
    assert seen
    for axis, state, truth in seen:
        if state != State.Moving:
            assert truth["xyz"[axis - 1]][1] == 0.0, (axis, state, truth)


def stands_at(truth: tuple[float, float], target: float) -> bool:
    position, velocity = truth
    return velocity == 0.0 and math.isclose(position, target, abs_tol=1e-3)


def test_one_motor_moves_and_reads_on_only_at_its_target(stage: Stage) -> None:
    m1 = stage.motors[0]
    seen = watch_states(stage)
    m1.position = 5.0
    wait_idle(m1)
    assert m1.state == State.On, m1.status
    assert m1.position.value == pytest.approx(5.0, abs=1e-3)
    assert stands_at(stage.truth()["x"], 5.0)
    # (the pool's loop may first ask once the move has ended, on a loaded machine)
    assert [state for axis, state, _ in seen if axis == 1][-1] == State.On
    for axis, state, truth in seen:
        if axis == 1 and state == State.On:
            assert stands_at(truth["x"], 5.0), truth  # On only once it stands at 5


def test_several_motors_move_in_one_interpolated_line(stage: Stage) -> None:
    m1, m2, _ = stage.motors
    lines: list[bytes] = []

    def record() -> None:
        model = stage.faults.model
        handle = model.handle_line

        def handle_line(line: bytes, now: float) -> None:
            lines.append(line)
            handle(line, now)

        model.handle_line = handle_line  # type: ignore[method-assign]

    stage.faults._do(lambda wire: record())
    seen = watch_states(stage)
    group = xy_group(stage)
    group.position = [3.0, -2.0]
    wait_true(lambda: not group.is_in_operation())
    assert (m1.state, m2.state) == (State.On, State.On), (m1.status, m2.status)
    assert stands_at(stage.truth()["x"], 3.0) and stands_at(stage.truth()["y"], -2.0)
    never_stopped_while_moving(seen)
    moves = [line for line in lines if line.lstrip(b"!").startswith(b"moa")]
    assert len(moves) == 1 and moves[0].split()[1:] == [b"3.0", b"-2.0"], moves


def test_stop_leaves_the_motor_on_where_it_stands(stage: Stage) -> None:
    m1 = stage.motors[0]
    stage.slow(2)
    seen = watch_states(stage)
    m1.position = 40.0
    wait_true(lambda: stage.truth()["x"][1] != 0.0)
    m1.stop()
    wait_idle(m1)
    never_stopped_while_moving(seen)
    assert m1.state == State.On, m1.status
    assert "stopped on request" in m1.status
    position, velocity = stage.truth()["x"]
    assert velocity == 0.0 and position < 40.0
    assert m1.position.value == pytest.approx(position, abs=1e-3)


def test_stop_stops_an_axis_moved_outside_the_pool(stage: Stage) -> None:
    m1 = stage.motors[0]
    m1.position = 1.0  # a move of the pool first, ended well
    wait_idle(m1)
    stage.slow(2)
    elsewhere = stage.tango.start_move_to(x=40.0)  # another client's move
    wait_true(lambda: stage.truth()["x"][1] != 0.0)
    assert m1.get_state(cache=False) == State.Moving
    assert "not started by this pool" in m1.get_status(cache=False)
    m1.stop()
    wait_true(elsewhere.done)
    assert stage.truth()["x"][1] == 0.0 and stage.truth()["x"][0] < 40.0
    assert m1.get_state(cache=False) != State.Moving


def xy_group(stage: Stage) -> Any:
    """A motor group of X and Y in the pool."""
    pool = stage.case.pool
    m1, m2, _ = stage.motors
    from sardana.pool.test import createPoolMotorGroup

    group = createPoolMotorGroup(pool, {"id": pool.get_free_id(), "name": "xy",
                                        "full_name": "xy"}, [m1.id, m2.id])
    pool.add_element(group)
    return group


def test_abort_stops_every_axis(stage: Stage) -> None:
    m1, m2, _ = stage.motors
    stage.slow(2)
    group = xy_group(stage)
    group.position = [40.0, -40.0]
    wait_true(lambda: all(stage.truth()[a][1] != 0.0 for a in "xy"))
    seen = watch_states(stage)
    group.abort()
    wait_true(lambda: not group.is_in_operation())
    never_stopped_while_moving(seen)
    truth = stage.truth()
    assert truth["x"][1] == truth["y"][1] == 0.0
    for motor, axis in ((m1, "x"), (m2, "y")):
        assert motor.state == State.On and "stopped on request" in motor.status, motor.status
        assert motor.position.value == pytest.approx(truth[axis][0], abs=1e-3)


def test_a_move_stopped_by_another_client_ends_in_alarm(stage: Stage) -> None:
    m1 = stage.motors[0]
    stage.slow(2)
    m1.position = 40.0
    wait_true(lambda: stage.truth()["x"][1] != 0.0)
    stage.tango.stop("x")  # not through the pool
    wait_idle(m1)
    assert m1.state == State.Alarm and "failed" in m1.status, m1.status
    assert m1.position.value == pytest.approx(stage.truth()["x"][0], abs=1e-3)


def test_a_limit_switch_ends_the_move_in_alarm(stage: Stage) -> None:
    m1 = stage.motors[0]
    seen = watch_states(stage)
    m1.position = 500.0
    wait_idle(m1)
    never_stopped_while_moving(seen)
    assert m1.state == State.Alarm
    assert "upper limit switch" in m1.status
    assert m1.limit_switches.value == (False, True, False)
    position, velocity = stage.truth()["x"]
    assert velocity == 0.0 and m1.position.value == pytest.approx(position, abs=1e-3)
    m1.position = 0.0  # away from the switch: the next move clears the alarm
    wait_idle(m1)
    assert m1.state == State.On and m1.limit_switches.value == (False, False, False)


@pytest.mark.parametrize("stage", [{"Reconnect": False}], indirect=True)
def test_a_lost_link_reads_fault_with_the_reason(stage: Stage) -> None:
    ctrl = stage.ctrl
    stage.faults.disconnect()
    wait_true(lambda: not stage.tango.connected)
    ctrl.PreStateAll()
    state, status, _ = ctrl.StateOne(1)
    assert state == State.Fault and "lost" in status


def test_the_link_comes_back_by_itself(stage: Stage) -> None:
    m1 = stage.motors[0]
    stage.faults.disconnect()
    wait_true(lambda: stage.tango.connected and stage.tango.aio.reconnect_attempt > 0)
    m1.position = 0.5
    wait_idle(m1)
    assert m1.state == State.On, m1.status
    assert m1.position.value == pytest.approx(0.5, abs=1e-3)


def test_the_axis_parameters(stage: Stage) -> None:
    m1 = stage.motors[0]
    m1.velocity = 40.0
    assert m1.get_velocity(cache=False) == pytest.approx(40.0)
    m1.acceleration = 0.5  # seconds to reach 40 mm/s: accel 80 mm/s²
    assert stage.tango.settings.acceleration()["x"] == pytest.approx(80.0)
    assert m1.get_acceleration(cache=False) == pytest.approx(0.5)
    assert m1.get_deceleration(cache=False) == pytest.approx(0.5)
    m1.deceleration = 0.5  # the same as the acceleration: taken
    with pytest.raises(ValueError, match="Acceleration"):
        m1.deceleration = 0.2
    assert m1.get_base_rate(cache=False) == 0.0
    with pytest.raises(ValueError, match="standstill"):
        m1.base_rate = 1.0
    # 200 motor steps per 1 mm pitch, gear 1
    assert m1.get_step_per_unit(cache=False) == pytest.approx(200.0)
    with pytest.raises(ValueError, match="read-only"):
        m1.step_per_unit = 100.0
    m1.set_extra_par("ControllerBacklash", 5.0)
    assert m1.get_extra_par("ControllerBacklash") == pytest.approx(5.0)
    assert m1.get_extra_par("Calibrated") is False


def test_an_axis_the_controller_lacks_is_refused(stage: Stage) -> None:
    with pytest.raises(ValueError, match="axes 1-3"):
        stage.ctrl.AddDevice(4)


def test_initialising_the_controller_again_frees_its_serial_port() -> None:
    """The pool initialises a controller again (its Init) by deleting every motor and
    making a new controller object while the old one may still live: the last motor's
    deletion closes the link, so the new object can open the port (opened exclusively)."""
    posix_only(PTY_EMULATOR)
    from tango_aio.sim.ptyserve import serve_pty

    portal = Portal()
    server = portal.call(serve_pty, make_model)
    case = pool_case()
    case.setUp()
    try:
        element = case.createController("tango", "MarzhauserMotorController",
                                        "MarzhauserMotorCtrl.py", {"URL": server.path})
        assert element.is_online(), element.get_ctrl_error_str()
        motor = case.createMotorElement(element, "m1", 1)
        old = element.ctrl
        element.re_init()
        assert element.is_online(), element.get_ctrl_error_str()
        assert element.ctrl is not old
        motor.position = 0.5
        wait_idle(motor)
        assert motor.state == State.On, motor.status
        assert motor.position.value == pytest.approx(0.5, abs=1e-3)
        element.ctrl.close()
    finally:
        case.tearDown()

        async def close() -> None:
            server.close()
            await server.wait_closed()

        portal.call(close)
        portal.stop()


def test_the_package_prints_the_folder_for_the_pool_path() -> None:
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run([sys.executable, "-m", "tango_aio.sardana"], cwd=root,
                            capture_output=True, text=True, timeout=120, check=True)
    assert result.stdout.strip() == POOL_PATH
    assert (Path(POOL_PATH) / "MarzhauserMotorCtrl.py").is_file()
