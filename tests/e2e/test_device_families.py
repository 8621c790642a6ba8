"""The device families (joystick, I/O, encoders, closed loop, triggers, snapshots) against
the emulator: setters change its state as the manual says, getters read it back, bad
values are refused before any byte, and the semantics hold (joystick moves seen, closed
loop's preconditions, trigger pulses as configured)."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from helpers import INSTANT, EmulatorFactory, wait_moving

import tango_aio
import tango_aio.sync
from tango_aio import (
    ClosedLoopPreconditionError,
    InputsChanged,
    InvalidCommandError,
    InvalidInstructionError,
    JoystickMoved,
    PositionUpdate,
    SnapshotConfig,
    SnapshotMode,
    TriggerConfig,
    TriggerMode,
    TriggerOutput,
)
from tango_aio.families import DevicePort
from tango_aio.sim.devices import TAKT_OUT, TRIGGER_OUT

PROFILES = ["manual", "legacy"]


def url(profile: str) -> str:
    return f"{INSTANT}&profile={profile}"


def lines_seen(emu: Any, monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    """Every line the emulator receives from now on."""
    seen: list[bytes] = []
    model = emu.model
    real = model.handle_line

    def spy(line: bytes, now: float) -> None:
        seen.append(line)
        real(line, now)

    monkeypatch.setattr(model, "handle_line", spy)
    return seen


@pytest.mark.parametrize("profile", PROFILES)
async def test_io_setters_change_the_emulator_and_getters_read_it(
        emulator: EmulatorFactory, profile: str) -> None:
    emu = await emulator(url(profile))
    io, model = emu.tango.io, emu.model
    await io.set_shutter(True)
    assert model.params.first("shutter") == 1 and await io.shutter() is True
    await io.set_shutter(False)
    assert await io.shutter() is False
    await io.set_analog_out(1, 42.5)
    assert model.params.first("anaout", 0) is not None
    assert await io.analog_out(1) == 42.5
    model.devices.analog[10] = 300
    assert await io.analog_in(10) == 300.0
    assert await io.analog_in(15) == 512.0  # the 2.5 V reference (L9340-9380)
    model.devices.set_input("digin", 5, True)
    levels = await io.digital_in()
    assert len(levels) == 24 and levels[5] and not any(levels[:5])
    await io.set_digital_out(3, True)
    assert (await io.digital_out())[3] is True
    if profile == "legacy":  # not in the older edition: the controller says so
        with pytest.raises(InvalidInstructionError):
            await io.flash(2.5)
        with pytest.raises(InvalidInstructionError):
            await io.set_pump(True)
        return
    await io.flash(2.5)
    await io.flash(-0.01)
    pulses = model.devices.pulses_of(TAKT_OUT)
    assert [(p.width, p.active_high) for p in pulses] == [(0.0025, True), (0.00001, False)]
    await io.set_pump(True)
    assert await io.pump() is True


BAD_CALLS: list[tuple[str, Callable[[tango_aio.Controller], Awaitable[Any]]]] = [
    ("shutter 1", lambda t: t.io.set_shutter(1)),  # type: ignore[arg-type]
    ("flash 0", lambda t: t.io.flash(0)),
    ("flash too long", lambda t: t.io.flash(40000)),
    ("flash text", lambda t: t.io.flash("1")),  # type: ignore[arg-type]
    ("anaout channel", lambda t: t.io.set_analog_out(3, 10)),
    ("anaout level", lambda t: t.io.set_analog_out(0, 100.5)),
    ("anain channel", lambda t: t.io.analog_in(32)),
    ("digout", lambda t: t.io.set_digital_out(16, True)),
    ("trigger pulses", lambda t: t.triggers.fire(128)),
    ("trigger axis", lambda t: t.triggers.write_config(TriggerConfig(axis="a"))),
    ("trigger list mode", lambda t: t.triggers.write_config(
        TriggerConfig(mode=TriggerMode.LIST_RISING))),
    ("closed loop mode", lambda t: t.closed_loop.enable(mode=0, x=True)),  # type: ignore[arg-type]
    ("closed loop axis", lambda t: t.closed_loop.enable(a=True)),
    ("closed loop value", lambda t: t.closed_loop.enable(x=1)),  # type: ignore[arg-type]
]


@pytest.mark.parametrize(("what", "call"), BAD_CALLS, ids=[what for what, _ in BAD_CALLS])
async def test_out_of_range_is_refused_before_any_byte(
        emulator: EmulatorFactory, monkeypatch: pytest.MonkeyPatch, what: str,
        call: Callable[[tango_aio.Controller], Awaitable[Any]]) -> None:
    emu = await emulator()
    seen = lines_seen(emu, monkeypatch)
    with pytest.raises(InvalidCommandError):
        await call(emu.tango)
    assert seen == []


@pytest.mark.parametrize(("field", "value"), [
    ("width_us", 2_500_040), ("width_us", 1.5), ("distance", 0.0), ("frequency_hz", 0.001),
    ("compensation_us", 10_010), ("mode", 12), ("output", 16), ("axis", "q"),
    ("encoder", 1), ("secondary_width_us", 32_500_000.5), ("secondary_width_us", -1.0),
    ("secondary_delay_us", 32_500_001.0), ("secondary_delay_us", "1"),
    ("secondary_frequency_hz", 0.005), ("secondary_frequency_hz", 66_000_001.0)])
def test_a_trigger_configuration_is_checked_when_made(field: str, value: Any) -> None:
    with pytest.raises(InvalidCommandError):
        TriggerConfig(**{field: value})


def test_snapshot_configuration_is_checked_when_made() -> None:
    bad_values: list[dict[str, Any]] = [{"filter_ms": 256}, {"mode": 12}, {"enabled": 1}]
    for bad in bad_values:
        with pytest.raises(InvalidCommandError):
            SnapshotConfig(**bad)


@pytest.mark.parametrize("profile", PROFILES)
async def test_trigger_configuration_round_trip(emulator: EmulatorFactory,
                                                profile: str) -> None:
    emu = await emulator(url(profile))
    triggers = emu.tango.triggers
    legacy = profile == "legacy"
    config = TriggerConfig(mode=TriggerMode.BACKWARD_SHIFTED_LOW, axis="y", width_us=120,
                           distance=0.25, frequency_hz=50.0,
                           output=None if legacy else TriggerOutput.BOTH,
                           compensation_us=None if legacy else -30,
                           encoder=None if legacy else True,
                           list_active_high=None if legacy else False,
                           secondary_width_us=None if legacy else 5.01,
                           secondary_delay_us=None if legacy else 0.35,
                           secondary_frequency_hz=None if legacy else 0.01)
    await triggers.write_config(config)
    assert await triggers.read_config() == config
    assert emu.model.params.first("triga") == "y"
    assert TriggerMode.BACKWARD_SHIFTED_LOW.active_high is False
    assert TriggerMode.PERIODIC.active_high is True


@pytest.mark.parametrize("profile", PROFILES)
async def test_snapshot_configuration_round_trip(emulator: EmulatorFactory,
                                                 profile: str) -> None:
    emu = await emulator(url(profile))
    config = SnapshotConfig(enabled=False, active_high=False, filter_ms=0,
                            mode=SnapshotMode.CAPTURE_INPUT)
    await emu.tango.snapshots.write_config(config)
    assert await emu.tango.snapshots.read_config() == config
    assert emu.model.params.first("snsm") == 4


async def test_a_scan_sends_the_pulses_the_configuration_describes(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()
    tango, model = emu.tango, emu.model
    await tango.set("vel", x=50)
    await tango.triggers.write_config(TriggerConfig(output=TriggerOutput.BOTH, width_us=200,
                                                    list_active_high=False))
    await tango.triggers.upload_positions([1.0, 2.0, 3.0], axis="x")
    await tango.triggers.set_count(0)
    await tango.triggers.set_enabled(True)
    await tango.move_to(x=4.0)
    assert await tango.triggers.count() == 3
    for output in (TRIGGER_OUT, TAKT_OUT):
        pulses = model.devices.pulses_of(output)
        assert [p.position for p in pulses] == pytest.approx([1.0, 2.0, 3.0])
        assert {(p.width, p.active_high) for p in pulses} == {(0.0002, False)}
        assert [p.time for p in pulses] == sorted(p.time for p in pulses)


async def test_pulses_forced_by_hand_in_the_manual_mode(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    triggers = emu.tango.triggers
    await triggers.write_config(TriggerConfig(mode=TriggerMode.MANUAL_LOW, width_us=40,
                                              frequency_hz=100.0))
    await triggers.set_enabled(True)
    await triggers.fire(3)
    pulses = emu.model.devices.pulses_of(TRIGGER_OUT)
    assert len(pulses) == 3 and not any(p.active_high for p in pulses)
    assert pulses[1].time - pulses[0].time == pytest.approx(0.01)
    assert await triggers.count() == 3


@pytest.mark.parametrize("profile", ["manual", "legacy"])
async def test_joystick_switch(emulator: EmulatorFactory, profile: str,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    emu = await emulator(url(profile))
    seen: list[bytes] = []
    handle = emu.model.handle_line

    def recording(line: bytes, now: float) -> Any:
        seen.append(bytes(line))
        return handle(line, now)

    monkeypatch.setattr(emu.model, "handle_line", recording)
    joystick = emu.tango.joystick
    assert await joystick.is_enabled() is True  # on at power-on (L7111)
    await joystick.disable()
    assert emu.model.params.first("joy") == 0 and await joystick.is_enabled() is False
    await joystick.enable()
    assert emu.model.params.first("joy") == 2
    # After '!joy 0' the driver asks whether the inputs can move the stage; the older
    # edition has no 'tvr', which it would never answer (a reply timeout): not asked there.
    assert any(line.startswith(b"?tvr") for line in seen) is (profile == "manual")


async def test_disabling_the_joystick_during_a_move(emulator: EmulatorFactory) -> None:
    # '!joy 0' reports '@@@-.' while the axis still runs (L7124-7154): the move still
    # ends on its own report, where it was going.
    emu = await emulator()
    tango = emu.tango
    await tango.set("vel", x=4)
    move = asyncio.ensure_future(tango.move_to(x=3.0))
    await wait_moving(emu, "x")
    await tango.joystick.disable()
    assert await move == {"x": "@", "y": "@", "z": "@"}
    assert (await tango.position())["x"] == pytest.approx(3.0, abs=1e-3)


async def test_a_joystick_deflection_during_a_program(emulator: EmulatorFactory) -> None:
    emu = await emulator()
    tango, model = emu.tango, emu.model
    await tango.set("joyvel", x=20)
    await tango.move_to(x=1.0)
    assert tango.last_positions is not None and float(tango.last_positions["x"]) == 1.0
    events = tango.events()
    watch = tango.io.watch_inputs(0.005)
    first = asyncio.ensure_future(anext(watch))
    await asyncio.sleep(0.02)  # the watch has read where the stage stands
    model.deflect("x", 0.5)
    moved = await asyncio.wait_for(first, 30)
    assert isinstance(moved, JoystickMoved) and moved.positions["x"] > 1.0
    model.deflect("x", 0.0)
    model.devices.set_input("digin", 2, True)
    change = await asyncio.wait_for(_next_of(watch, InputsChanged), 30)
    assert change.changed == (2,) and change.levels[2]
    await watch.aclose()
    seen = [e async for e in _drain(events)]
    assert any(isinstance(e, PositionUpdate) and e.positions["x"] > 1.0 for e in seen)
    assert any(isinstance(e, JoystickMoved) for e in seen)
    await tango.wait_idle()
    here = (await tango.position())["x"]
    assert here > 1.0
    assert float((tango.last_positions or {})["x"]) > 1.0  # no stale position cached
    # A move started afterwards runs from where the joystick left the stage.
    await tango.move_by(x=0.5)
    assert (await tango.position())["x"] == pytest.approx(here + 0.5, abs=1e-3)


async def _next_of(watch: Any, kind: type[Any]) -> Any:
    async for event in watch:
        if isinstance(event, kind):
            return event
    raise AssertionError("the watch ended")


async def _drain(events: tango_aio.Subscription) -> Any:
    while True:
        try:
            yield await asyncio.wait_for(anext(events), 0.5)
        except TimeoutError:
            return


@pytest.mark.parametrize("profile", PROFILES)
async def test_closed_loop_preconditions(emulator: EmulatorFactory, profile: str) -> None:
    emu = await emulator(url(profile))
    tango, model = emu.tango, emu.model
    await tango.encoders.set_mask(x=False)
    with pytest.raises(ClosedLoopPreconditionError, match="encmask") as caught:
        await tango.closed_loop.enable(x=True)
    assert (caught.value.axis, caught.value.missing) == ("x", "encmask")
    await tango.encoders.set_mask(x=True)
    with pytest.raises(ClosedLoopPreconditionError) as caught:
        await tango.closed_loop.enable(x=True)
    assert caught.value.missing == "enc"
    model.devices.encoders.add(0)
    assert (await tango.encoders.active())["x"] is True
    await tango.closed_loop.enable(x=False)
    assert model.params.first("ctr", 0) == 0
    await tango.closed_loop.enable(x=True)
    assert model.params.first("ctr", 0) == 2
    assert (await tango.closed_loop.mode())["x"] == 2


async def test_closed_loop_settles_and_reports_the_position_error(
        emulator: EmulatorFactory) -> None:
    emu = await emulator()
    tango, model = emu.tango, emu.model
    model.devices.encoders.add(0)
    await tango.encoders.set_mask(x=True)
    await tango.closed_loop.enable(x=True)
    await tango.set("ctrd", 300, axis="x")
    await tango.set("vel", x=50)
    start = model.motion.now
    await tango.move_to(x=0.5)
    # The report came only after the settle delay (ctrd, L11986-12060): the travel alone
    # takes well under it at 50 mm/s.
    assert model.motion.now - start >= 0.3
    model.devices.position_error[0] = 0.0125
    assert (await tango.encoders.position_error())["x"] == pytest.approx(0.0125)
    windows, delays = await tango.closed_loop.settle()
    assert set(windows) == {"x", "y", "z"} and 300 in delays


def test_blocking_twins() -> None:
    with tango_aio.sync.connect(INSTANT) as tango:
        tango.io.set_shutter(True)
        assert tango.io.shutter() is True
        assert tango.joystick.is_enabled() is True
        config = TriggerConfig(width_us=80, secondary_width_us=40.0, secondary_delay_us=0.0,
                               secondary_frequency_hz=1000.0)
        tango.triggers.write_config(config)
        assert tango.triggers.read_config() == config
        tango.triggers.upload_positions([1.0, 2.0])
        assert tango.triggers.read_positions() == [1.0, 2.0]
        assert tango.snapshots.read_config().enabled is True
        assert tango.io.set_shutter.__doc__ == tango.aio.io.set_shutter.__doc__
        # the generated typed access, blocking too
        assert tango.joystick.joy() == 2
        tango.io.set_pump(True)
        assert tango.io.pump() is True
        with pytest.raises(AttributeError):
            tango.io.no_such_method()  # type: ignore[attr-defined]


async def test_the_device_families_reach_the_controller_itself(
        emulator: EmulatorFactory) -> None:
    # One way to the link: every family's port is the controller, no wrapper of it.
    emu = await emulator(f"{INSTANT}&axes=2")
    tango = emu.tango
    for family in (tango.settings, tango.info, tango.joystick, tango.io, tango.encoders,
                   tango.closed_loop, tango.triggers, tango.snapshots):
        assert family._port is tango
    assert tango.axes == ("x", "y")
    await tango.move_to(x=1.5)
    port: DevicePort = tango  # the intents are private: the families are its parts
    letters, texts = await port._status_and_positions()
    assert letters == {"x": "@", "y": "@"} and tango.last_positions == texts
    assert await port._user_positions(texts) == await tango.position()
    assert await port._read_if_known("trigcomp") is not None
    assert len(await port._resolution()) == 2 and not port._in_motion()
    with pytest.raises(InvalidCommandError):
        port._check_axes(tango_aio.catalog.build("trigp", 0, axis="z"))


async def test_generated_bool_setters_reach_the_controller(emulator: EmulatorFactory) -> None:
    # A bool goes on the wire as 0/1, for one value and per axis alike.
    emu = await emulator()
    await emu.tango.triggers.set_trig(True)
    assert emu.model.params.first("trig") == 1
    await emu.tango.encoders.set_encmask(x=True, y=False)
    assert [emu.model.params.first("encmask", i) for i in (0, 1)] == [1, 0]
