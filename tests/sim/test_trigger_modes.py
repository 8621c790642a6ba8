"""The emulator's trigger generation on its own (no driver), in its own virtual time: the
periodic and bidirectional modes, the compensation, triggering on the encoder, the
secondary output's timings, and the encoder's drift (manual chapters 21 and 22)."""

from __future__ import annotations

import itertools

import pytest

from tango_aio.sim.config import SimConfig
from tango_aio.sim.devices import TAKT_OUT, TRIGGER_OUT, Pulse
from tango_aio.sim.model import ControllerModel
from tango_aio.sim.profiles import Firmware

from .test_devices import Model as DeviceModel

#: The default axis: 1 mm per revolution, ``vel`` 10 (10 mm/s), ramps 1 m/s².
SPEED = 10.0


class Model(DeviceModel):
    """A default 3-axis emulated controller driven in virtual time, under ``switches``."""

    def __init__(self, **switches: str) -> None:
        super().__init__()
        config = SimConfig(firmware=Firmware.from_options("manual", **switches))
        self.model = ControllerModel(self.out.append, config, now=0.0)

    def send(self, *lines: str) -> str:
        return "".join(super(Model, self).send(line) for line in lines)

    def out1(self) -> list[Pulse]:
        return self.model.devices.pulses_of(TRIGGER_OUT)

    def out2(self) -> list[Pulse]:
        return self.model.devices.pulses_of(TAKT_OUT)

    def travel(self, *targets: float) -> None:
        for target in targets:
            self.send(f"!moa x {target}")
            self.wait(abs(target) / SPEED + 2.0)
        self.out.clear()  # the reports


def positions(pulses: list[Pulse]) -> list[float]:
    return [p.position if p.position is not None else float("nan") for p in pulses]


# -- periodic modes (100, 101) --------------------------------------------------------------


@pytest.mark.parametrize(("mode", "high"), [(100, True), (101, False)])
@pytest.mark.parametrize("first", ["enable", "period"])
def test_the_periodic_modes_pulse_every_period_from_enabling(mode: int, high: bool,
                                                             first: str) -> None:
    sim = Model(periodic_first=first)
    sim.send("!trigs 120", "!trigf 2500", f"!trigm {mode}", "!trig 1")
    enabled = sim.now
    sim.wait(0.01)
    period = 1 / 2500
    start = enabled if first == "enable" else enabled + period
    expected = [start + k * period for k in range(int((sim.now - start) / period + 1e-6) + 1)]
    pulses = sim.out1()
    assert [p.time for p in pulses] == pytest.approx(expected)
    assert {(p.width, p.active_high, p.position) for p in pulses} == {(120e-6, high, None)}
    assert sim.send("?trigcount") == str(len(sim.out1()))
    sim.send("!trig 0")
    stopped = len(sim.out1())
    sim.wait(0.05)
    assert len(sim.out1()) == stopped and max(p.time for p in sim.out1()) <= sim.now - 0.05


@pytest.mark.parametrize(("rounding", "shown", "period"),
                         [("nearest", "2500.00", 400e-6), ("down", "2777.78", 360e-6)])
def test_the_periodic_frequency_is_whole_40_us_ticks(rounding: str, shown: str,
                                                     period: float) -> None:
    """"2500 exactly meets the frequency, 2600 does not", "?trigf ... the true value"
    (L13240-13278): the pulses come at the frequency read back."""
    sim = Model(trigf_round=rounding)
    sim.send("!trigf 2600")
    assert sim.send("?trigf") == shown
    sim.send("!trigm 100", "!trig 1")
    sim.wait(0.005)
    times = [p.time for p in sim.out1()]
    assert [b - a for a, b in itertools.pairwise(times)] == \
        pytest.approx([period] * (len(times) - 1))


def test_the_periodic_mode_ignores_moves_and_forced_pulses() -> None:
    sim = Model()
    sim.send("!trigf 100", "!trigm 100", "!trig 1", "!trigger 3")
    sim.travel(2.0)
    times = [p.time for p in sim.out1()]
    assert [b - a for a, b in itertools.pairwise(times)] == \
        pytest.approx([0.01] * (len(times) - 1))
    assert {p.position for p in sim.out1()} == {None}


# -- bidirectional distance modes (1, 4, 7, 10) -----------------------------------------------


@pytest.mark.parametrize(("mode", "high", "fired"), [
    (1, True, [0.0, 1.0, 2.0, 3.0, 2.0, 1.0]),  # a pulse as the move starts (L12628-12632)
    (4, False, [0.0, 1.0, 2.0, 3.0, 2.0, 1.0]),
    (7, True, [0.5, 1.5, 2.5, 2.5, 1.5, 0.5]),  # shifted by trigd/2 (L12703-12707)
    (10, False, [0.5, 1.5, 2.5, 2.5, 1.5, 0.5]),
    (0, True, [0.0, 1.0, 2.0, 3.0]),  # forward only: nothing on the way back
    (2, True, []),  # backward only: from the start, nothing behind it is reached
])
def test_distance_modes_fire_each_way_as_their_table_says(mode: int, high: bool,
                                                          fired: list[float]) -> None:
    sim = Model()
    sim.send("!triga x", "!trigd 1", "!trigs 40", f"!trigm {mode}", "!trig 1")
    sim.travel(3.0, 0.5)
    pulses = sim.out1()
    assert positions(pulses) == pytest.approx(fired, abs=1e-6)
    assert {p.active_high for p in pulses} <= {high}
    assert [p.time for p in pulses] == sorted(p.time for p in pulses)
    assert sim.send("?trigcount") == str(len(fired))


def test_a_bidirectional_level_reached_and_left_fires_once_each_time() -> None:
    sim = Model()
    sim.send("!trigd 1", "!trigm 1", "!trig 1")
    sim.travel(2.0, 1.5, 2.0, 0.0)  # stops on 2, turns back before it, reaches it again
    assert positions(sim.out1()) == pytest.approx([0.0, 1.0, 2.0, 2.0, 1.0, 0.0])


def test_bidirectional_levels_count_from_where_the_trigger_was_enabled() -> None:
    sim = Model()
    sim.travel(0.25)
    sim.send("!trigd 1", "!trigm 1", "!trig 1")
    sim.travel(-1.0)
    assert positions(sim.out1()) == pytest.approx([0.25, -0.75])


# -- trigcomp: look ahead at the current velocity ----------------------------------------------


@pytest.mark.parametrize("compensation", [10_000, -5_000, 1_234])
def test_compensation_moves_the_pulse_by_its_time_at_the_velocity(compensation: int) -> None:
    """"releases the trigger at an earlier (+) or later (-) time", "based on the current
    velocity" (L13064-13117), in 10 µs steps (L13060)."""
    plain, shifted = Model(), Model()
    for sim, value in ((plain, 0), (shifted, compensation)):
        sim.send("!trigd 1", "!trigs 40", f"!trigcomp {value}", "!trigm 0", "!trig 1")
        sim.travel(4.0)
    lead = round(compensation, -1) / 1e6
    assert shifted.send("?trigcomp") == str(compensation)
    cruising, moved = plain.out1()[1:4], shifted.out1()[1:4]  # at 1, 2, 3, at full speed
    assert [p.time for p in moved] == pytest.approx([p.time - lead for p in cruising])
    assert positions(moved) == pytest.approx([x - SPEED * lead for x in positions(cruising)])


def test_compensation_centres_a_pulse_on_its_position() -> None:
    """"trigs 200, trigcomp 100": active 100 µs before and after the position
    (L13132-13140)."""
    sim = Model()
    sim.send("!trigd 1", "!trigs 200", "!trigcomp 100", "!trigm 0", "!trig 1")
    sim.travel(3.0)
    pulse = sim.out1()[2]
    assert pulse.position == pytest.approx(2.0 - SPEED * 100e-6)
    assert pulse.width == pytest.approx(200e-6)


def test_compensation_applies_to_the_position_list_too() -> None:
    sim = Model()
    sim.send("!trigcomp -2000", "!trigr x 1 3 3", "!trig 1")
    sim.travel(4.0)
    assert positions(sim.out1()) == pytest.approx([1.02, 2.02, 3.02])


# -- trigenc and the encoder's drift ---------------------------------------------------------


def fitted(sim: Model, slip: float = 0.0, offset: float = 0.0) -> None:
    sim.model.devices.encoders.add(0)
    sim.send("!encmask x 1")
    sim.model.set_encoder_drift("x", slip=slip, offset=offset)


def test_the_encoder_drifts_from_the_motor_as_set() -> None:
    sim = Model()
    fitted(sim, slip=0.1, offset=0.05)
    sim.travel(2.0)
    assert sim.send("?pos x") == "2.0000"  # the motor position by default
    sim.send("!encpos x 1")  # ?pos reads the active encoder (L11193-11247)
    assert sim.send("?pos x") == "1.8500"
    sim.send("!ctr x 0")
    assert sim.send("?ctrdiff x") == "0.0000"  # only in closed loop (L12418-12420)
    sim.send("!ctr x 1")
    assert sim.send("?ctrdiff x") == "0.1500"
    sim.send("!encmask x 0")  # no active encoder: the motor position
    assert sim.send("?pos x") == "2.0000"
    with pytest.raises(ValueError, match="below 1"):
        sim.model.set_encoder_drift("x", slip=1.0)


@pytest.mark.parametrize(("encoder", "active", "fired"), [
    (1, True, [0.0, 1 / 0.9, 2 / 0.9, 3 / 0.9]),  # the encoder's positions (L13181)
    (0, True, [0.0, 1.0, 2.0, 3.0]),  # the motor's (L13179)
    (1, False, [0.0, 1.0, 2.0, 3.0]),  # no active encoder: the motor's (L13207)
])
def test_trigenc_compares_the_encoder_position(encoder: int, active: bool,
                                               fired: list[float]) -> None:
    sim = Model()
    if active:
        fitted(sim, slip=0.1)
    sim.send("!trigd 1", f"!trigenc {encoder}", "!trigm 0", "!trig 1")
    sim.travel(3.5)
    assert positions(sim.out1()) == pytest.approx(fired, abs=1e-6)


def test_trigenc_applies_to_the_position_list_and_to_a_drift_set_later() -> None:
    sim = Model()
    fitted(sim)
    sim.send("!trigenc 1", "!trigp x 0", "!trigp x 1", "!trigp -1 2", "!trig 1")
    sim.model.set_encoder_drift("x", offset=0.5)  # the encoder reads 0.5 mm ahead
    sim.travel(3.0)
    assert positions(sim.out1()) == pytest.approx([0.5, 1.5])


# -- the secondary output (trigo, trigs' 1:1 options, trigbwidth, trigbdelay, trigbf) --------


def forced(sim: Model, *settings: str) -> tuple[list[Pulse], list[Pulse]]:
    sim.send(*settings, "!trigm 102", "!trig 1", "!trigger")
    return sim.out1(), sim.out2()


@pytest.mark.parametrize(("trigs", "out2"), [
    ("200", (0.0, 200e-6)),  # 1:1: the same signal (L12873, L14271-14275)
    ("200 40 80", (40e-6, 80e-6)),  # a delay and width of its own (L12994-13001)
    ("200 160 80", (160e-6, 40e-6)),  # inactive latest with OUT1 (L12987-12990)
    ("200 200 80", None),  # no room within OUT1's pulse
])
def test_the_one_to_one_mode_and_its_options(trigs: str, out2: tuple[float, float] | None
                                             ) -> None:
    sim = Model()
    (one,), two = forced(sim, "!trigo 3", f"!trigs {trigs}")
    assert one.width == pytest.approx(200e-6)
    if out2 is None:
        assert two == []
    else:
        assert [(p.time - one.time, p.width) for p in two] == [pytest.approx(out2)]
    assert sim.send("?trigs") == "200"


@pytest.mark.parametrize(("outputs", "on1", "on2"), [
    (5, True, False), (6, False, True), (7, True, True), (4, False, False)])
def test_precise_width_starts_with_out1_and_may_outlast_it(outputs: int, on1: bool,
                                                           on2: bool) -> None:
    """trigo 4-7, ``trigbwidth`` (L13318-13350, L14334-14345), on 1/132 µs steps."""
    sim = Model()
    one, two = forced(sim, f"!trigo {outputs}", "!trigs 40", "!trigbwidth 230.003")
    assert bool(one) == on1 and bool(two) == on2
    for pulse in two:
        assert pulse.width == pytest.approx(round(230.003 * 132) / 132 * 1e-6, abs=1e-15)
    if one and two:
        assert two[0].time == one[0].time


@pytest.mark.parametrize(("delay", "width"), [(25.5, 14.5), (112.03, 7.97), (80.0, 40.0)])
def test_precise_delay_sets_an_edge_reset_at_the_next_40_us_tick(delay: float,
                                                                 width: float) -> None:
    """trigo 8-11, ``trigbdelay`` (L13279-13316): "The OUT2 pulse width can't be
    specified, it is resetted in 40µs intervals" (L14377-14394)."""
    sim = Model()
    (one,), (two,) = forced(sim, "!trigo 11", "!trigs 80", f"!trigbdelay {delay}")
    assert two.time - one.time == pytest.approx(delay * 1e-6, abs=1e-8)
    assert two.width == pytest.approx(width * 1e-6, abs=1e-8)


@pytest.mark.parametrize("outputs", [15, 14])
def test_precise_frequency_runs_out2_on_its_own(outputs: int) -> None:
    """trigo 14, 15: OUT2 at ``trigbf`` with "fixed width of 50%", OUT1 in its own mode
    (L14444-14486); "Trigcount does not count the precise trigger events" (L13368)."""
    sim = Model()
    sim.send(f"!trigo {outputs}", "!trigs 80", "!trigf 5000", "!trigbf 12500", "!trigm 100",
             "!trig 1")
    enabled = sim.now
    sim.wait(0.002)
    two = sim.out2()
    assert [p.time - enabled for p in two] == pytest.approx(
        [k / 12500 for k in range(len(two))])
    assert [p.width for p in two] == pytest.approx([40e-6] * len(two)) and len(two) >= 25
    one = sim.out1()
    assert (len(one) > 0) == (outputs == 15)
    assert sim.send("?trigcount") == str(int((sim.now - enabled) * 5000 + 1e-6) + 1)


def test_the_record_keeps_the_latest_pulses_of_a_fast_output() -> None:
    sim = Model()
    sim.model.devices.limit = 1000
    sim.send("!trigo 14", "!trigbf 66000000", "!trigm 102", "!trig 1")
    enabled = sim.now
    sim.wait(1.0)
    devices = sim.model.devices
    assert len(devices.pulses) <= 1000 * 9 // 8
    assert len(devices.pulses) + devices.dropped == int((sim.now - enabled) * 66e6) + 1
    assert devices.pulses[-1].time == pytest.approx(sim.now, abs=1 / 66e6)


def test_a_bidirectional_grid_follows_a_drift_set_while_armed() -> None:
    sim = Model()
    fitted(sim)
    sim.send("!trigd 1", "!trigenc 1", "!trigm 1", "!trig 1", "?trig")
    sim.model.set_encoder_drift("x", offset=0.3)  # the encoder now reads 0.3 mm ahead
    sim.travel(2.0, 0.0)
    assert positions(sim.out1()) == pytest.approx([0.7, 1.7, 1.7, 0.7])


@pytest.mark.parametrize(("reading", "shown"), [("written", ["15", "-15"]),
                                                ("step", ["20", "-10"])])
def test_trigcomp_reads_as_written_or_on_its_step_and_works_on_its_step(
        reading: str, shown: list[str]) -> None:
    """"smallest step is 10µs" (L13060): what ``?trigcomp`` shows the manual does not say
    (switch ``trigcomp_read``); the pulse moves by the step either way."""
    for value, text in zip((15, -15), shown, strict=True):
        sim = Model(trigcomp_read=reading)
        sim.send("!trigd 1", f"!trigcomp {value}", "!trigm 0", "!trig 1")
        assert sim.send("?trigcomp") == text
        sim.travel(2.5)
        step = 20 if value > 0 else -10
        assert sim.out1()[1].position == pytest.approx(1.0 - SPEED * step / 1e6)


@pytest.mark.parametrize(("rule", "targets", "fired"), [
    ("reach", (2.0, 1.5, 2.0, 0.0), [0.0, 1.0, 2.0, 2.0, 1.0, 0.0]),  # 2 again
    ("neighbours", (2.0, 1.5, 2.0, 0.0), [0.0, 1.0, 2.0, 1.0, 0.0]),  # after 2: 1 or 3
    ("reach", (3.2, 0.0), [0.0, 1.0, 2.0, 3.0, 3.0, 2.0, 1.0, 0.0]),  # back across 3
    ("neighbours", (3.2, 0.0), [0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 0.0]),
])
def test_which_bidirectional_level_fires_next_on_either_firmware(
        rule: str, targets: tuple[float, ...], fired: list[float]) -> None:
    sim = Model(bidirectional_next=rule)
    sim.send("!trigd 1", "!trigm 1", "!trig 1")
    sim.travel(*targets)
    assert positions(sim.out1()) == pytest.approx(fired)


def test_a_level_where_the_encoder_ends_a_move_fires() -> None:
    sim = Model()
    fitted(sim, slip=0.2)
    sim.send("!trigd 1", "!trigenc 1", "!trigm 0", "!trig 1")
    sim.travel(2.5)  # the encoder ends on 2.0 exactly
    assert positions(sim.out1()) == pytest.approx([0.0, 1.25, 2.5], abs=1e-6)
