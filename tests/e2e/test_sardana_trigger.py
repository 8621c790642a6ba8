"""tango_aio.sardana's trigger/gate controller in Sardana's own in-process pool (its
``sardana.pool.test`` harness and its ``PoolSynchronization`` action, as a continuous scan
runs it) beside the motor controller of the same TANGO (one shared link to the emulator):
a position-domain description becomes trigger positions on the axis, the state follows
the trigger counter against the pulses expected, and the emulator's record of pulses
matches the description."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest
from test_sardana import HANG, Stage, pool_case

from tango_aio.sim.devices import TRIGGER_OUT
from tango_aio.testing import emulator_url

pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning:taurus"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning:sardana")]


class Synchronised:
    """The pool's motor controller, the trigger/gate controller, its element and a
    ``PoolSynchronization`` action over it."""

    def __init__(self, case: Any) -> None:
        from sardana.pool.poolacquisition import get_acq_ctrls
        from sardana.pool.poolsynchronization import PoolSynchronization
        from sardana.pool.test.helper import createControllerConfiguration

        url = emulator_url(axes=3)
        motors = case.createController("tango", "MarzhauserMotorController",
                                       "MarzhauserMotorCtrl.py", {"URL": url})
        assert motors.is_online(), motors.get_ctrl_error_str()
        self.stage = Stage(case, motors)
        self.stage.slow(5.0)
        self.element = case.createController(
            "tangotg", "MarzhauserTriggerGateController", "MarzhauserTriggerGateCtrl.py",
            {"URL": url})
        assert self.element.is_online(), self.element.get_ctrl_error_str()
        self.tg = case.createTGElement(self.element, "tg01", 1)
        self.configuration = createControllerConfiguration(self.element, [self.tg])
        self.ctrls = get_acq_ctrls([self.configuration])  # which holds it by weak reference
        self.action = PoolSynchronization(self.tg)
        self.action.add_element(self.tg)

    def pulses(self) -> list[Any]:
        """The pulses the emulated trigger output sent (read in the driver's loop)."""
        async def read() -> list[Any]:
            return self.stage.faults.model.devices.pulses_of(TRIGGER_OUT)
        pulses: list[Any] = self.stage.tango.portal.call(read)
        return pulses

    def run(self, description: list[dict[Any, Any]], target: float) -> None:
        """Load ``description``, start the output, move X to ``target`` beside it and run
        the action's loop until the trigger/gate is no longer Moving."""
        from sardana import State
        from sardana.pool.poolsynchronization import SynchDescription

        self.action.start_action(self.ctrls, {"tg01": SynchDescription(description)})
        assert self.tg.get_state() == State.Moving
        mover = threading.Thread(target=self.stage.tango.move_to, kwargs={"x": target})
        mover.start()
        try:
            self.action.action_loop()
        finally:
            mover.join(HANG)


@pytest.fixture
def synchronised() -> Iterator[Synchronised]:
    pytest.importorskip("sardana.pool.test", reason="Sardana is not installed")
    case = pool_case()
    case.setUp()
    built = None
    try:
        built = Synchronised(case)
        yield built
    finally:
        case.tearDown()
        if built is not None:
            built.element.ctrl.close()
            built.stage.ctrl.close()


def group(initial: float, total: float, repeats: int, active: float | None = None
          ) -> dict[Any, Any]:
    from sardana.pool.pooldefs import SynchDomain, SynchParam

    found: dict[Any, Any] = {
        SynchParam.Initial: {SynchDomain.Position: initial},
        SynchParam.Total: {SynchDomain.Position: total},
        SynchParam.Repeats: repeats,
        SynchParam.Delay: {SynchDomain.Time: 0.0}}
    if active is not None:
        found[SynchParam.Active] = {SynchDomain.Time: active}
    return found


def test_one_group_becomes_a_trigger_range_and_the_pulses_follow_it(
        synchronised: Synchronised) -> None:
    from sardana import State

    synchronised.run([group(0.5, 0.25, 5, active=0.0002)], target=2.0)
    pulses = synchronised.pulses()
    assert [p.position for p in pulses] == pytest.approx([0.5, 0.75, 1.0, 1.25, 1.5],
                                                         abs=1e-6)
    assert [p.width for p in pulses] == pytest.approx([0.0002] * 5)
    tango = synchronised.stage.tango
    assert tango.triggers.count() == 5
    assert tango.triggers.enabled() is False  # switched off once all were sent
    assert synchronised.tg.get_state() == State.On
    assert tango.triggers.read_config().axis == "x"


def test_several_groups_become_a_trigger_list_backwards(
        synchronised: Synchronised) -> None:
    from sardana import State

    synchronised.stage.tango.move_to(x=3.0)
    synchronised.run([group(2.5, -0.5, 2), group(1.2, -0.2, 3)], target=0.5)
    assert synchronised.stage.tango.triggers.read_positions() == \
        pytest.approx([2.5, 2.0, 1.2, 1.0, 0.8])
    assert [p.position for p in synchronised.pulses()] == \
        pytest.approx([2.5, 2.0, 1.2, 1.0, 0.8], abs=1e-6)
    assert synchronised.tg.get_state() == State.On


def test_the_state_is_moving_until_the_count_is_reached_and_stop_ends_it(
        synchronised: Synchronised) -> None:
    from sardana import State

    ctrl, tango = synchronised.element.ctrl, synchronised.stage.tango
    ctrl.SynchOne(1, [group(1.0, 1.0, 3)])
    ctrl.StartOne(1)
    tango.move_to(x=2.5)  # two of the three positions passed
    state, status = ctrl.StateOne(1)
    assert (state, tango.triggers.count()) == (State.Moving, 2), status
    assert "2 of 3" in status
    ctrl.StopOne(1)
    state, status = ctrl.StateOne(1)
    assert state == State.On and "stopped on request" in status
    assert tango.triggers.enabled() is False


def test_a_time_domain_description_is_refused_before_anything_is_written(
        synchronised: Synchronised) -> None:
    from sardana.pool.pooldefs import SynchDomain, SynchParam

    ctrl, tango = synchronised.element.ctrl, synchronised.stage.tango
    before = tango.triggers.read_config()
    with pytest.raises(ValueError, match="position domain"):
        ctrl.SynchOne(1, [{SynchParam.Initial: {SynchDomain.Time: 0.0},
                           SynchParam.Total: {SynchDomain.Time: 0.1},
                           SynchParam.Repeats: 3}])
    assert tango.triggers.read_config() == before


def test_the_trigger_axis_is_one_the_controller_has_and_the_pulses_follow_it(
        synchronised: Synchronised) -> None:
    ctrl, tango = synchronised.element.ctrl, synchronised.stage.tango
    with pytest.raises(ValueError, match="no axis"):
        ctrl.SetAxisExtraPar(1, "TriggerAxis", "a")  # a 3-axis controller
    ctrl.SetAxisExtraPar(1, "TriggerAxis", "Y")
    assert ctrl.GetAxisExtraPar(1, "TriggerAxis") == "y"
    ctrl.SynchOne(1, [group(0.5, 0.5, 2)])
    assert tango.triggers.read_config().axis == "y"
    ctrl.StartOne(1)
    tango.move_to(x=2.0)  # not the trigger axis: no pulse
    assert tango.triggers.count() == 0
    tango.move_to(y=1.5)
    assert [p.position for p in synchronised.pulses()] == pytest.approx([0.5, 1.0], abs=1e-6)
