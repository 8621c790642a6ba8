"""A trigger configuration written through ``tango.triggers`` produces, in the emulator,
the pulses the manual describes for it: the periodic and bidirectional modes, the
compensation, triggering on a drifting encoder, and the secondary output's precise width,
delay and frequency. Times are the emulator's (its record of pulses), on the virtual
clock."""

from __future__ import annotations

import asyncio
import itertools

import pytest
from helpers import INSTANT, EmulatorFactory

from tango_aio import TriggerConfig, TriggerMode, TriggerOutput
from tango_aio.sim.devices import TAKT_OUT, TRIGGER_OUT, Pulse

pytestmark = [pytest.mark.timeout(60), pytest.mark.virtual_clock]


def gaps(pulses: list[Pulse]) -> list[float]:
    times = [p.time for p in pulses]
    return [b - a for a, b in itertools.pairwise(times)]


async def test_the_periodic_mode_pulses_at_the_frequency_it_reads_back(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()
    triggers, model = emu.tango.triggers, emu.model
    await triggers.write_config(TriggerConfig(mode=TriggerMode.PERIODIC_LOW, width_us=120,
                                              frequency_hz=2600.0))
    config = await triggers.read_config()
    assert config.frequency_hz == pytest.approx(2500.0)  # whole 40 µs ticks (L13278)
    await triggers.set_count(0)
    await triggers.set_enabled(True)
    await asyncio.sleep(0.02)  # virtual time for the output to run
    await triggers.set_enabled(False)
    count = await triggers.count()
    pulses = model.devices.pulses_of(TRIGGER_OUT)
    assert count == len(pulses) >= 40
    assert gaps(pulses) == pytest.approx([1 / 2500] * (count - 1))
    assert {(p.width, p.active_high) for p in pulses} == {(120e-6, False)}
    await asyncio.sleep(0.01)
    assert await triggers.count() == count  # switched off: no more


@pytest.mark.parametrize(("mode", "rule", "fired"), [
    (TriggerMode.BIDIRECTIONAL, "reach", [0.0, 0.5, 1.0, 1.5, 2.0, 1.5, 1.0, 0.5]),
    (TriggerMode.BIDIRECTIONAL, "neighbours", [0.0, 0.5, 1.0, 1.5, 2.0, 1.5, 1.0, 0.5]),
    (TriggerMode.BIDIRECTIONAL_SHIFTED_LOW, "reach",
     [0.25, 0.75, 1.25, 1.75, 1.75, 1.25, 0.75, 0.25]),  # the turn at 2 crosses 1.75 again
    (TriggerMode.BIDIRECTIONAL_SHIFTED_LOW, "neighbours",
     [0.25, 0.75, 1.25, 1.75, 1.25, 0.75, 0.25]),
])
async def test_a_bidirectional_scan_pulses_both_ways(emulator: EmulatorFactory,
                                                     mode: TriggerMode, rule: str,
                                                     fired: list[float]) -> None:
    emu = await emulator(f"{INSTANT}&bidirectional_next={rule}")
    tango, model = emu.tango, emu.model
    await tango.set("vel", x=20)
    await tango.triggers.write_config(TriggerConfig(mode=mode, distance=0.5, width_us=40))
    await tango.triggers.set_count(0)
    await tango.triggers.set_enabled(True)
    await tango.move_to(x=2.0)
    await tango.move_to(x=0.1)
    pulses = model.devices.pulses_of(TRIGGER_OUT)
    assert [p.position for p in pulses] == pytest.approx(fired, abs=1e-6)
    assert {p.active_high for p in pulses} == {mode.active_high}
    assert await tango.triggers.count() == len(fired)


@pytest.mark.parametrize("compensation", [2000, -2000])
async def test_the_compensation_fires_ahead_at_the_velocity(emulator: EmulatorFactory,
                                                            compensation: int) -> None:
    emu = await emulator()
    tango, model = emu.tango, emu.model
    await tango.set("vel", x=10)
    await tango.triggers.write_config(TriggerConfig(distance=1.0, width_us=40,
                                                    compensation_us=compensation))
    await tango.triggers.set_enabled(True)
    await tango.move_to(x=3.5)
    cruising = model.devices.pulses_of(TRIGGER_OUT)[1:4]
    ahead = 10.0 * compensation / 1e6  # mm/s times s (L13100-13112)
    assert [p.position for p in cruising] == pytest.approx([1 - ahead, 2 - ahead, 3 - ahead])


async def test_triggers_on_a_drifting_encoder(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    tango, model = emu.tango, emu.model
    model.devices.encoders.add(0)
    await tango.encoders.set_mask(x=True)
    model.set_encoder_drift("x", slip=0.2)
    await tango.triggers.write_config(TriggerConfig(distance=1.0, encoder=True))
    await tango.triggers.set_enabled(True)
    await tango.move_to(x=3.0)
    pulses = model.devices.pulses_of(TRIGGER_OUT)
    # The encoder sees 80 % of the motor's travel: levels 1 and 2 at 1.25 and 2.5 mm.
    assert [p.position for p in pulses] == pytest.approx([0.0, 1.25, 2.5], abs=1e-6)
    await tango.encoders.set_position_source("x", True)
    assert (await tango.position())["x"] == pytest.approx(2.4)


@pytest.mark.parametrize(("output", "offset", "width"), [
    (TriggerOutput.WIDTH_BOTH, 0.0, 230e-6),  # starts with OUT1, outlasts it (L14337-14345)
    (TriggerOutput.DELAY_BOTH, 25.5e-6, 14.5e-6),  # reset at the next 40 µs (L14377-14394)
])
async def test_the_secondary_output_follows_its_precise_settings(
        emulator: EmulatorFactory, output: TriggerOutput, offset: float,
        width: float) -> None:
    emu = await emulator()
    triggers, model = emu.tango.triggers, emu.model
    await triggers.write_config(TriggerConfig(
        mode=TriggerMode.MANUAL, output=output, width_us=80, secondary_width_us=230.0,
        secondary_delay_us=25.5))
    await triggers.set_enabled(True)
    await triggers.fire(2)
    one, two = model.devices.pulses_of(TRIGGER_OUT), model.devices.pulses_of(TAKT_OUT)
    assert len(one) == len(two) == 2
    assert [b.time - a.time for a, b in zip(one, two, strict=True)] == \
        pytest.approx([offset] * 2, abs=1e-8)
    assert [p.width for p in two] == pytest.approx([width] * 2, abs=1e-8)


async def test_the_secondary_output_runs_its_own_frequency(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    triggers, model = emu.tango.triggers, emu.model
    await triggers.write_config(TriggerConfig(
        mode=TriggerMode.PERIODIC, output=TriggerOutput.FREQUENCY_BOTH, width_us=80,
        frequency_hz=5000.0, secondary_frequency_hz=12500.0))
    await triggers.set_count(0)
    await triggers.set_enabled(True)
    await asyncio.sleep(0.004)
    await triggers.set_enabled(False)
    one, two = model.devices.pulses_of(TRIGGER_OUT), model.devices.pulses_of(TAKT_OUT)
    assert gaps(one) == pytest.approx([1 / 5000] * (len(one) - 1))
    assert gaps(two) == pytest.approx([1 / 12500] * (len(two) - 1))
    assert len(two) >= 2 * len(one) >= 20
    assert [p.width for p in two] == pytest.approx([40e-6] * len(two))  # half the period
    assert await triggers.count() == len(one)  # not the precise events (L13368)


@pytest.mark.parametrize("profile", ["manual", "legacy"])
async def test_the_secondary_settings_round_trip(emulator: EmulatorFactory,
                                                 profile: str) -> None:
    emu = await emulator(f"{INSTANT}&profile={profile}")
    triggers = emu.tango.triggers
    if profile == "legacy":  # the older edition has no secondary output settings
        config = await triggers.read_config()
        assert (config.secondary_width_us, config.secondary_delay_us,
                config.secondary_frequency_hz) == (None, None, None)
        return
    config = TriggerConfig(output=TriggerOutput.DELAY_SECONDARY, secondary_width_us=65.4,
                           secondary_delay_us=112.03, secondary_frequency_hz=50000005.0)
    await triggers.write_config(config)
    assert await triggers.read_config() == config
    params = emu.model.params
    assert (params.first("trigbwidth"), params.first("trigbdelay"),
            params.first("trigbf")) == (65.4, 112.03, 50000005.0)


@pytest.mark.parametrize(("rounding", "held"), [("nearest", 2500.0), ("down", 2777.78)])
async def test_a_frequency_between_ticks_is_proven_on_either_firmware(
        emulator: EmulatorFactory, rounding: str, held: float) -> None:
    emu = await emulator(f"{INSTANT}&trigf_round={rounding}")
    await emu.tango.triggers.write_config(TriggerConfig(mode=TriggerMode.PERIODIC,
                                                        frequency_hz=2600.0))
    assert (await emu.tango.triggers.read_config()).frequency_hz == pytest.approx(held)


@pytest.mark.parametrize("first", ["enable", "period"])
async def test_the_first_periodic_pulse_on_either_firmware(
        emulator: EmulatorFactory, monkeypatch: pytest.MonkeyPatch, first: str) -> None:
    emu = await emulator(f"{INSTANT}&periodic_first={first}")
    model, triggers = emu.model, emu.tango.triggers
    enabled: list[float] = []
    real = model.handle_line

    def spy(line: bytes, now: float) -> None:
        if line.strip() == b"!trig 1":
            enabled.append(now)
        real(line, now)

    monkeypatch.setattr(model, "handle_line", spy)
    await triggers.write_config(TriggerConfig(mode=TriggerMode.PERIODIC, frequency_hz=1000.0))
    await triggers.set_enabled(True)
    await asyncio.sleep(0.005)
    await triggers.set_enabled(False)
    pulses = model.devices.pulses_of(TRIGGER_OUT)
    assert pulses[0].time == pytest.approx(enabled[0] + (0.0 if first == "enable" else 0.001))
    assert await triggers.count() == len(pulses)


@pytest.mark.parametrize("reading", ["written", "step"])
async def test_a_compensation_between_steps_is_proven_on_either_firmware(
        emulator: EmulatorFactory, reading: str) -> None:
    emu = await emulator(f"{INSTANT}&trigcomp_read={reading}")
    await emu.tango.triggers.write_config(TriggerConfig(compensation_us=15))
    held = (await emu.tango.triggers.read_config()).compensation_us
    assert held == (15 if reading == "written" else 20)
