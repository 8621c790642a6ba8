"""The emulator's I/O lines, encoders, joystick and trigger outputs on their own (no
driver): the model in virtual time, lines in, replies and its devices' record out."""

from __future__ import annotations

import pytest

from tango_aio.sim.devices import TAKT_OUT, TRIGGER_OUT
from tango_aio.sim.model import ControllerModel


class Model:
    """A default 3-axis emulated controller driven in virtual time."""

    def __init__(self) -> None:
        self.out: list[bytes] = []
        self.now = 0.0
        self.model = ControllerModel(self.out.append, now=0.0)

    def send(self, line: str) -> str:
        self.now += 0.001
        self.model.handle_line(line.encode(), self.now)
        self.model.poll(self.now)
        text = b"".join(self.out).decode()
        self.out.clear()
        return text.strip("\r")

    def wait(self, seconds: float) -> None:
        self.now += seconds
        self.model.poll(self.now)

    def x(self) -> float:
        return float(self.send("?pos x"))


def test_inputs_read_what_was_set() -> None:
    sim = Model()
    devices = sim.model.devices
    assert sim.send("?digin") == "0" * 24
    devices.set_input("digin", 23, True)
    devices.set_input("adigin", 1, True)
    assert sim.send("?digin") == "0" * 23 + "1" and sim.send("?digin 23") == "1"
    assert sim.send("?adigin") == "0100"
    devices.analog[3] = 700
    assert sim.send("?anain c 3") == "700" and sim.send("?anain v 3") == "700.00"
    assert sim.send("?anain c 15") == "512"


def test_flash_sends_a_pulse_of_its_length_and_polarity() -> None:
    sim = Model()
    assert sim.send("!flash 0.001") == "" and sim.send("?flash") == ""
    sim.send("!flash -12.5")
    pulses = sim.model.devices.pulses_of(TAKT_OUT)
    assert [(p.width, p.active_high) for p in pulses] == [(1e-6, True), (0.0125, False)]
    assert sim.model.devices.pulses_of(TRIGGER_OUT) == []


@pytest.mark.parametrize(("mode", "high"), [(102, True), (103, False)])
def test_forced_pulses_follow_the_settings(mode: int, high: bool) -> None:
    sim = Model()
    sim.send("!trigger 2")  # mode 0: no pulse by hand (L13414-13420)
    assert sim.model.devices.pulses == []
    for line in (f"!trigm {mode}", "!trigo 3", "!trigs 80", "!trigf 200", "!trig 1",
                 "!trigger 2"):
        sim.send(line)
    pulses = sim.model.devices.pulses
    assert sorted({p.output for p in pulses}) == [TAKT_OUT, TRIGGER_OUT] and len(pulses) == 4
    assert {(p.width, p.active_high) for p in pulses} == {(80e-6, high)}
    times = sorted({p.time for p in pulses})
    assert times[1] - times[0] == pytest.approx(1 / 200)
    assert sim.send("?trigcount") == "2"


def test_list_pulses_carry_their_positions_and_the_list_polarity() -> None:
    sim = Model()
    for line in ("!vel x 20", "!trigl 0", "!trigs 120", "!trigp x 0", "!trigp x 1.5",
                 "!trigp -1 2.5", "!trig 1", "!moa x 3"):
        sim.send(line)
    sim.wait(2.0)
    pulses = sim.model.devices.pulses_of(TRIGGER_OUT)
    assert [p.position for p in pulses] == pytest.approx([1.5, 2.5])
    assert {(p.width, p.active_high) for p in pulses} == {(120e-6, False)}


def test_encoders_and_the_position_error_in_closed_loop() -> None:
    sim = Model()
    devices = sim.model.devices
    devices.position_error[0] = 0.02
    assert sim.send("?enc") == "0 0 0" and sim.send("?ctrdiff x") == "0.0000"
    sim.send("!encmask x 1")
    assert sim.send("?enc") == "0 0 0"  # masked but none fitted
    devices.encoders.add(0)
    assert sim.send("?enc") == "1 0 0" and sim.send("?ctrdiff x") == "0.0200"
    sim.send("!ctr x 0")
    assert sim.send("?ctrdiff x") == "0.0000"  # closed loop off


def test_a_deflection_moves_the_axis_while_the_hdi_is_on() -> None:
    sim = Model()
    sim.send("!joyvel x 4")
    sim.model.deflect("x", 0.5, now=sim.now)
    sim.wait(2.0)
    travelled = sim.x()
    assert 3.5 < travelled <= 4.0  # 2 mm/s for 2 s, less the ramp
    sim.send("!joy 0")  # switched off: the axis stops, and the report comes (L7142-7154)
    sim.wait(1.0)
    stopped = sim.x()
    sim.wait(1.0)
    assert sim.x() == stopped
    sim.send("!joy 2")  # still held: it moves again
    sim.wait(1.0)
    assert sim.x() > stopped
    sim.model.deflect("x", 0.0, now=sim.now)
    sim.wait(1.0)
    released = sim.x()
    sim.wait(1.0)
    assert sim.x() == released
    with pytest.raises(ValueError, match=r"-1\.\.1"):
        sim.model.deflect("x", 1.5)


def test_an_axis_the_joystick_is_not_assigned_to_stays() -> None:
    sim = Model()
    sim.send("!joydir y 0")
    sim.model.deflect("y", -1.0, now=sim.now)
    sim.wait(1.0)
    assert float(sim.send("?pos y")) == 0.0


@pytest.mark.parametrize(("mode", "target", "expected"), [
    (0, 2.2, [0.0, 0.5, 1.0, 1.5, 2.0]),  # forward, the first as the move starts
    (6, 2.2, [0.25, 0.75, 1.25, 1.75]),   # shifted by half a distance
    (2, -1.2, [0.0, -0.5, -1.0]),         # backward
    (0, -1.2, []),                       # forward only: nothing backward
])
def test_distance_modes_pulse_every_distance_from_the_start(
        mode: int, target: float, expected: list[float]) -> None:
    sim = Model()
    for line in ("!vel x 20", f"!trigm {mode}", "!trigd 0.5", "!triga x", "!trig 1",
                 f"!moa x {target}"):
        sim.send(line)
    sim.wait(2.0)
    fired = [p.position for p in sim.model.devices.pulses_of(TRIGGER_OUT)]
    assert fired == pytest.approx(expected, abs=1e-6)


def test_the_arrival_modes_pulse_with_the_completion_report() -> None:
    sim = Model()
    for line in ("!vel x 20", "!trigm 105", "!trig 1", "!moa x 1"):
        sim.send(line)
    sim.wait(1.0)
    assert b"".join(sim.out) == b"@@@-.\r"  # the report the pulse comes with
    sim.out.clear()
    pulses = sim.model.devices.pulses_of(TRIGGER_OUT)
    assert len(pulses) == 1 and not pulses[0].active_high
    assert sim.send("?trigcount") == "1"
    sim.send("!autostatus 0")  # no report, no pulse (L12595-12836)
    sim.send("!moa x 2")
    sim.wait(1.0)
    assert len(sim.model.devices.pulses_of(TRIGGER_OUT)) == 1
