"""tango_aio.mm: TANGO stages and the shutter in pymmcore-plus's UniMMCore (issue 42),
against the emulator: busy until the driver's verdict, errors at the next call, µm
everywhere without touching ``dim``, an MDA with no frame taken mid-move."""

from __future__ import annotations

import concurrent.futures
import gc
import logging
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("tango_aio.mm")  # first: it keeps the root logger's level
pytest.importorskip("useq")

import numpy as np
import useq
from pymmcore_plus.experimental.unicore import SimpleCameraDevice, UniMMCore

import tango_aio.sync
from tango_aio import InvalidInstructionError, MoveError
from tango_aio.mm import (
    TangoHub,
    TangoShutter,
    TangoStrobe,
    TangoXYStage,
    TangoZStage,
    load_tango,
)
from tango_aio.sim.devices import TAKT_OUT, TRIGGER_OUT, Pulse
from tango_aio.sim.profiles import PROFILES, variants
from tango_aio.testing import faults

INSTANT = "sim://?baud=0"
ROOT = Path(__file__).resolve().parents[2]

#: Bound on a wait for the emulator: only a hang reaches it (seconds).
HANG = 30.0


@pytest.fixture
def core() -> Iterator[UniMMCore]:
    mm = UniMMCore()
    mm.setTimeoutMs(60_000)  # waitForDevice's bound: only a hang reaches it
    yield mm
    mm.unloadAllDevices()  # closes the links
    del mm
    # pymmcore's callback thread must not be the one that collects the devices' garbage
    # at interpreter exit (it aborts there, "exception not rethrown").
    gc.collect()


def hub_of(core: UniMMCore, labels: Mapping[str, str]) -> TangoHub:
    hub = core._pydevices[labels["hub"]]  # the loaded object, for the emulator's state
    assert isinstance(hub, TangoHub)
    return hub


def emulated(hub: TangoHub) -> dict[str, tuple[float, bool]]:
    """Where each emulated axis really is now, in µm, and whether it moves: the
    emulator's own state (read in the driver's thread), not a reply."""
    tango = hub.controller

    async def read() -> dict[str, tuple[float, bool]]:
        handle = faults(tango.aio)
        motion = handle.model.motion
        out = {}
        for axis, (where, velocity) in handle.axes().items():
            scale = motion.units(axis)
            um = where / scale.user_per_rev * scale.mm_per_rev * 1000.0
            out[axis] = (um, velocity != 0.0 or motion.is_moving(axis))
        return out

    return tango.portal.call(read)


def make_fast(hub: TangoHub) -> None:
    """100 mm/s and 20 m/s² on every axis, a quick release from the switch after a
    calibration: a run into a limit switch 50 mm away or a calibration takes a moment."""
    tango = hub.controller
    for name, value in (("secvel", 100), ("vel", 100), ("accel", 20), ("stopaccel", 20)):
        tango.set(name, axis=None, check=True, x=value, y=value, z=value)
    tango.set("calbspeed", 8000)


def wait_moving(hub: TangoHub, axis: str) -> None:
    deadline = time.monotonic() + HANG
    while not emulated(hub)[axis][1]:
        assert time.monotonic() < deadline, f"{axis} never moved"


def dims(hub: TangoHub) -> dict[str, int]:
    return {axis: int(value) for axis, value in hub.controller.get("dim").items()}


# ------------------------------------------------------------------ load, move, busy ------

def _profiles() -> list[Any]:
    """Both profiles in the default run, every single-switch variant under ``slow``."""
    return [pytest.param(name, id=name, marks=[] if name in PROFILES else [pytest.mark.slow])
            for name, _ in variants()]


@pytest.mark.parametrize("variant", _profiles())
def test_load_move_wait_and_read_in_every_profile(core: UniMMCore, variant: str) -> None:
    query = f"profile={variant}" if variant in PROFILES else f"profile=manual&{variant}"
    labels = load_tango(core, f"{INSTANT}&{query}")
    assert labels == {"hub": "TangoHub", "xy": "TangoXY", "z": "TangoZ",
                      "shutter": "TangoShutter"}
    assert core.getXYStageDevice() == "TangoXY" and core.getFocusDevice() == "TangoZ"
    assert core.getShutterDevice() == "TangoShutter"
    assert core.getParentLabel("TangoXY") == "TangoHub"
    hub = hub_of(core, labels)
    before = dims(hub)
    core.setXYPosition(1500.0, -250.0)
    core.setPosition(12.5)
    core.waitForDevice("TangoXY")
    core.waitForDevice("TangoZ")
    assert not core.deviceBusy("TangoXY") and not core.deviceBusy("TangoZ")
    assert core.getXYPosition() == pytest.approx((1500.0, -250.0))
    assert core.getPosition() == pytest.approx(12.5)
    where = emulated(hub)
    assert (where["x"][0], where["y"][0], where["z"][0]) == pytest.approx(
        (1500.0, -250.0, 12.5), abs=0.01)
    core.setRelativeXYPosition(-500.0, 250.0)
    core.waitForSystem()
    assert core.getXYPosition() == pytest.approx((1000.0, 0.0))
    assert core.getProperty("TangoHub", "Model") == hub.controller.identity.model
    assert dims(hub) == before  # never a `dim` written


def _stands_at(hub: TangoHub, target: Mapping[str, float]) -> bool:
    where = emulated(hub)
    return all(not where[a][1] and where[a][0] == pytest.approx(v, abs=0.01)
               for a, v in target.items())


def test_busy_is_false_only_once_the_axes_stand_at_their_target(
        core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, z=None, shutter=False)
    hub = hub_of(core, labels)
    core.setXYPosition(2000.0, 1000.0)  # 0.2 s at the emulator's 10 mm/s
    while core.deviceBusy("TangoXY"):
        pass
    # The emulator is the judge: nothing moves the axes any more, so whatever it shows
    # after the first "not busy" was true when that answer was given.
    assert _stands_at(hub, {"x": 2000.0, "y": 1000.0})


def test_busy_right_after_a_set_while_the_emulator_moves_then_stop(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, z=None, shutter=False)
    hub = hub_of(core, labels)
    core.setXYPosition(40_000.0, 0.0)  # 4 s away: stopped long before
    assert core.deviceBusy("TangoXY")
    wait_moving(hub, "x")
    assert core.deviceBusy("TangoXY")
    core.stop("TangoXY")  # returns once the axes stand; the stopped move is no failure
    assert not core.deviceBusy("TangoXY")
    x, y = core.getXYPosition()
    assert 0.0 < x < 40_000.0  # where it stopped, read: never the target
    # ?pos prints four decimals by default (resolution 4, L4109): 0.1 µm in mm
    assert (x, y) == pytest.approx((emulated(hub)["x"][0], emulated(hub)["y"][0]), abs=0.1)
    assert not emulated(hub)["x"][1]


# ------------------------------------------------------------------ moves that end short --

def test_a_move_into_a_limit_switch_fails_the_next_call_with_the_reason(
        core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, z=None, shutter=False)
    hub = hub_of(core, labels)
    make_fast(hub)
    core.setXYPosition(60_000.0, 0.0)  # the switch is at +50 mm
    with pytest.raises(MoveError, match="upper limit switch"):
        core.waitForDevice("TangoXY")
    x, _ = core.getXYPosition()  # the error was handed over once; the position is read
    assert x == pytest.approx(emulated(hub)["x"][0], abs=0.01) and x < 60_000.0
    core.setXYPosition(1000.0, 0.0)  # the next move works
    core.waitForDevice("TangoXY")
    assert core.getXYPosition() == pytest.approx((1000.0, 0.0))


def test_a_move_of_a_disabled_axis_fails_the_next_call_with_the_reason(
        core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, z=None, shutter=False)
    hub = hub_of(core, labels)
    hub.controller.set("axis", 0, axis="y")
    core.setXYPosition(0.0, 5000.0)
    with pytest.raises(MoveError, match="Y is disabled"):
        core.waitForDevice("TangoXY")
    assert emulated(hub)["y"][0] == 0.0
    assert core.getXYPosition()[1] == 0.0  # the position, never the target


def test_an_error_is_raised_by_whichever_call_comes_next(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, shutter=False)
    hub = hub_of(core, labels)
    hub.controller.set("axis", 0, axis="z")
    core.setPosition(3000.0)
    stage = core._pydevices[labels["z"]]
    assert isinstance(stage, TangoZStage)
    concurrent.futures.wait(stage._moves._running, timeout=30)  # ended, not yet asked
    with pytest.raises(MoveError, match="Z is disabled"):
        core.getPosition()
    assert core.getPosition() == 0.0 and not core.deviceBusy("TangoZ")


# ------------------------------------------------------------------ properties, units -----

def test_properties_in_micrometres_and_no_dim_written(core: UniMMCore) -> None:
    hub = TangoHub(INSTANT)
    hub.controller.set("dim", axis=None, x=1, y=2, z=9)  # the user's dims, kept
    labels = {"hub": "TangoHub"}
    core.loadPyDevice("TangoHub", hub)
    core.initializeDevice("TangoHub")
    xy, z = TangoXYStage(hub), TangoZStage(hub)
    core.loadPyDevice("XY", xy)
    core.loadPyDevice("Z", z)
    core.initializeDevice("XY")
    core.initializeDevice("Z")
    core.setXYStageDevice("XY")
    core.setFocusDevice("Z")
    tango = hub.controller
    core.setProperty("XY", "X Velocity (um/s)", 5000.0)
    assert tango.get("vel")["x"] == pytest.approx(5.0)  # rev/s at 1 mm a revolution
    assert core.getProperty("XY", "X Velocity (um/s)") == pytest.approx(5000.0)
    core.setProperty("Z", "Z Velocity (um/s)", 2500.0)
    assert tango.get("vel")["z"] == pytest.approx(2.5)  # mm/s in dim 9
    core.setProperty("XY", "Y Acceleration (m/s^2)", 0.5)
    assert tango.get("accel")["y"] == pytest.approx(0.5)
    core.setProperty("XY", "X Backlash (um)", 12.5)
    assert tango.get("backlash")["x"] == pytest.approx(12.5)
    core.setProperty("XY", "Y Lower limit (um)", -3000.0)
    core.setProperty("XY", "Y Upper limit (um)", 4500.0)
    assert tango.get("lim")["y"] == pytest.approx((-3.0, 4.5))  # mm, y's dim
    assert xy.limits_um("y") == pytest.approx((-3000.0, 4500.0))
    assert core.getProperty("XY", "Y Upper limit (um)") == pytest.approx(4500.0)
    core.setXYPosition(1500.0, -250.0)
    core.setPosition(20.0)
    core.waitForSystem()
    assert tango.position() == pytest.approx({"x": 1500.0, "y": -250.0, "z": 20.0})
    assert tango.get("pos") == pytest.approx({"x": 1500.0, "y": -0.25, "z": 0.02})
    assert dims(hub) == {"x": 1, "y": 2, "z": 9}
    assert core.getProperty(labels["hub"], "Firmware") == tango.identity.firmware
    core.setProperty("TangoHub", "Joystick", "Off")
    assert tango.get("joy") == 0
    core.setProperty("TangoHub", "Joystick", "On")
    assert tango.get("joy") == 2


def test_the_older_edition_has_no_backlash_property(core: UniMMCore) -> None:
    load_tango(core, f"{INSTANT}&profile=legacy", z=None, shutter=False)
    names = core.getDevicePropertyNames("TangoXY")
    assert "X Velocity (um/s)" in names and "X Backlash (um)" not in names


# ------------------------------------------------------------------ origin and home -------

def test_origin_and_adapter_origin(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, shutter=False)
    hub = hub_of(core, labels)
    core.setXYPosition(1200.0, 800.0)
    core.setPosition(300.0)
    core.waitForSystem()
    core.setOriginX()
    assert core.getXYPosition() == pytest.approx((0.0, 800.0))
    core.setOriginXY()
    assert core.getXYPosition() == pytest.approx((0.0, 0.0))
    core.setAdapterOriginXY(100.0, -50.0)
    assert core.getXYPosition() == pytest.approx((100.0, -50.0))
    core.setAdapterOrigin(7.5)
    assert core.getPosition() == pytest.approx(7.5)
    core.setOrigin()
    assert core.getPosition() == pytest.approx(0.0)
    assert emulated(hub)["x"][0] == pytest.approx(100.0, abs=0.01)  # what ?pos shows


def test_home_calibrates_and_busy_follows_it(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, z="x", shutter=False)
    hub = hub_of(core, labels)
    make_fast(hub)
    core.setPosition(500.0)
    core.waitForDevice("TangoZ")
    core.home("TangoZ")
    while core.deviceBusy("TangoZ"):
        pass
    # not busy: the emulator has the axis calibrated and standing
    assert hub.controller.is_calibrated("x") and not emulated(hub)["x"][1]
    assert core.getPosition() == pytest.approx(emulated(hub)["x"][0], abs=0.01)


# ------------------------------------------------------------------ the shutter -----------

def test_the_shutter_drives_the_aux_shutter_output(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, z=None)
    hub = hub_of(core, labels)
    core.setShutterOpen(True)
    assert core.getShutterOpen() and hub.controller.get("shutter") == 1
    assert _emulated_shutter(hub) == 1
    core.setShutterOpen(False)
    assert not core.getShutterOpen() and _emulated_shutter(hub) == 0


def _emulated_shutter(hub: TangoHub) -> int:
    tango = hub.controller

    async def read() -> int:
        return int(faults(tango.aio).model.params.first("shutter"))

    return tango.portal.call(read)


def test_devices_find_their_hub_by_the_parent_label(core: UniMMCore) -> None:
    core.loadPyDevice("Hub", TangoHub(INSTANT))
    core.initializeDevice("Hub")
    core.loadDevice("XY", "tango_aio.mm", "TangoXYStage")  # by name, as a config file does
    core.loadPyDevice("Shutter", TangoShutter())
    for label in ("XY", "Shutter"):
        core.setParentLabel(label, "Hub")
        core.initializeDevice(label)
    core.setXYStageDevice("XY")
    core.setXYPosition(100.0, 200.0)
    core.waitForDevice("XY")
    assert core.getXYPosition() == pytest.approx((100.0, 200.0))


def test_load_tango_refuses_an_axis_the_controller_lacks(core: UniMMCore) -> None:
    with pytest.raises(ValueError, match="has axes x, y only, not z"):
        load_tango(core, "sim://?baud=0&axes=2", z="z")
    assert core.getLoadedDevices() == ("Core",)
    with pytest.raises(ValueError, match="two axes"):
        load_tango(core, INSTANT, xy="x")


# ------------------------------------------------------------------ an MDA ---------------

class Camera(SimpleCameraDevice):
    """Records, at each snap, where the emulator's axes are and whether they move."""

    def __init__(self, hub: TangoHub) -> None:
        super().__init__()
        self.hub = hub
        self.seen: list[dict[str, tuple[float, bool]]] = []
        self._exposure = 1.0

    def dtype(self) -> Any:
        return np.uint16

    def sensor_shape(self) -> tuple[int, int]:
        return (4, 4)

    def snap(self, buffer: np.ndarray[Any, Any]) -> Mapping[str, Any]:
        self.seen.append(emulated(self.hub))
        buffer[:] = len(self.seen)
        return {}

    def get_exposure(self) -> float:
        return self._exposure

    def set_exposure(self, exposure: float) -> None:
        self._exposure = exposure


def test_an_mda_takes_no_frame_while_a_stage_moves(core: UniMMCore) -> None:
    # With the shutter: pymmcore-plus 0.18's engine closes the core's shutter after each
    # snap, and fails without one.
    labels = load_tango(core, INSTANT)
    hub = hub_of(core, labels)
    camera = Camera(hub)
    core.loadPyDevice("Camera", camera)
    core.initializeDevice("Camera")
    core.setCameraDevice("Camera")
    sequence = useq.MDASequence(
        stage_positions=(useq.AbsolutePosition(x=500.0, y=-300.0, z=10.0),
                         useq.AbsolutePosition(x=-1200.0, y=800.0, z=40.0)),
        z_plan=useq.ZRangeAround(range=20.0, step=10.0))
    frames: list[tuple[useq.MDAEvent, Mapping[str, Any]]] = []
    core.mda.events.frameReady.connect(lambda _img, event, meta: frames.append((event, meta)))
    core.mda.run(sequence)
    assert len(frames) == len(camera.seen) == 6
    assert _emulated_shutter(hub) == 0  # the engine closes the shutter after each snap
    for (event, meta), seen in zip(frames, camera.seen, strict=True):
        assert not any(moving for _, moving in seen.values())  # no frame mid-move
        at_snap = (seen["x"][0], seen["y"][0], seen["z"][0])
        assert at_snap == pytest.approx((event.x_pos, event.y_pos, event.z_pos), abs=0.01)
        recorded = meta["position"]
        assert (recorded["x"], recorded["y"], recorded["z"]) == pytest.approx(at_snap,
                                                                              abs=0.01)


def test_the_blocking_controller_is_shared_by_the_devices(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT)
    hub = hub_of(core, labels)
    devices = [core._pydevices[labels[role]] for role in ("xy", "z", "shutter")]
    assert all(isinstance(device.controller, tango_aio.sync.Controller)  # type: ignore[attr-defined]
               and device.controller is hub.controller  # type: ignore[attr-defined]
               for device in devices)


# ------------------------------------------------------------------ interpreter exit ------

EXITS = """
from pymmcore_plus.experimental.unicore import UniMMCore
from tango_aio.mm import load_tango
core = UniMMCore()
load_tango(core, "sim://?baud=0")
core.setXYPosition(10.0, 10.0)
core.waitForSystem()
core.unloadAllDevices()
del core
"""


def test_a_program_that_releases_its_core_exits_cleanly(tmp_path: Path) -> None:
    """pymmcore 12.5's callback thread may run a garbage collection while the interpreter
    exits, and the process aborts ("FATAL: exception not rethrown", SIGABRT; a core and a
    tango_aio.sync link alone are enough): the how-to's programs release the core first
    (``del core``), which stops that thread."""
    result = subprocess.run([sys.executable, "-c", EXITS], capture_output=True, text=True,
                            timeout=120, cwd=tmp_path, check=False,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr[-2000:]


def test_an_mda_stops_with_the_reason_at_a_move_that_ends_short(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT)
    hub = hub_of(core, labels)
    make_fast(hub)
    camera = Camera(hub)
    core.loadPyDevice("Camera", camera)
    core.initializeDevice("Camera")
    core.setCameraDevice("Camera")
    sequence = useq.MDASequence(stage_positions=(
        useq.AbsolutePosition(x=100.0, y=0.0, z=0.0),
        useq.AbsolutePosition(x=60_000.0, y=0.0, z=0.0),  # beyond the switch at +50 mm
        useq.AbsolutePosition(x=200.0, y=0.0, z=0.0)))
    with pytest.raises(MoveError, match="upper limit switch"):
        core.mda.run(sequence)
    assert len(camera.seen) == 1  # the first position only: none at the switch
    assert camera.seen[0]["x"][0] == pytest.approx(100.0, abs=0.01)


def test_the_end_of_a_move_is_announced_to_the_core_listeners(core: UniMMCore) -> None:
    load_tango(core, INSTANT, shutter=False)
    xy_seen: list[tuple[str, float, float]] = []
    z_seen: list[tuple[str, float]] = []
    core.events.XYStagePositionChanged.connect(lambda *args: xy_seen.append(args))
    core.events.stagePositionChanged.connect(lambda *args: z_seen.append(args))
    core.setXYPosition(300.0, -400.0)
    core.setPosition(25.0)
    core.waitForSystem()
    core.waitForSystem()  # once per move
    assert [label for label, *_ in xy_seen] == ["TangoXY"]
    assert xy_seen[0][1:] == pytest.approx((300.0, -400.0))
    assert z_seen == [("TangoZ", 25.0)]


def test_importing_keeps_the_root_loggers_level() -> None:
    """pymmcore-plus sets the root logger to DEBUG on import; tango_aio.mm puts it back,
    so the driver's wire trace stays off unless asked for."""
    code = "import logging, tango_aio.mm; print(logging.getLogger().level)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120).stdout
    assert out.strip() == str(logging.WARNING)


# ------------------------------------------------------------------ the joystick ----------

def test_the_joystick_property_switches_the_emulators_hdi(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, z=None, shutter=False)
    hub = hub_of(core, labels)
    core.setProperty("TangoHub", "Joystick", "Off")
    assert _emulated(hub, "joy") == 0 and core.getProperty("TangoHub", "Joystick") == "Off"
    core.setProperty("TangoHub", "Joystick", "On")
    assert _emulated(hub, "joy") == 2 and core.getProperty("TangoHub", "Joystick") == "On"


# ------------------------------------------------------------------ the LED strobe --------

def _emulated(hub: TangoHub, name: str) -> Any:
    """A parameter as the emulator holds it."""
    tango = hub.controller

    async def read() -> Any:
        return faults(tango.aio).model.params.first(name)

    return tango.portal.call(read)


def _pulses(hub: TangoHub, output: str) -> list[Pulse]:
    """The pulses the emulator has sent on ``output``, in order."""
    tango = hub.controller

    async def read() -> list[Pulse]:
        return list(faults(tango.aio).model.devices.pulses_of(output))

    return tango.portal.call(read)


def test_the_strobe_pulses_takt_out_once_per_opening(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, z=None, shutter=False, strobe=True)
    hub = hub_of(core, labels)
    assert labels["strobe"] == "TangoStrobe" and core.getShutterDevice() == "TangoStrobe"
    # initialising sends one settling pulse of the polarity (manual L9890-9891)
    assert [(p.width, p.active_high) for p in _pulses(hub, TAKT_OUT)] == [(1e-8, True)]
    core.setProperty("TangoStrobe", "Pulse (ms)", 2.5)
    core.setShutterOpen(True)
    assert core.getShutterOpen()
    core.setShutterOpen(False)  # nothing sent: the pulse ends by itself
    assert not core.getShutterOpen()
    core.setProperty("TangoStrobe", "Polarity", "Active low")  # settles the polarity
    core.setShutterOpen(True)
    pulses = _pulses(hub, TAKT_OUT)
    assert [p.width for p in pulses] == pytest.approx([1e-8, 0.0025, 1e-8, 0.0025])
    assert [p.active_high for p in pulses] == [True, True, False, False]
    assert _pulses(hub, TRIGGER_OUT) == []


def test_the_older_edition_has_no_strobe_and_nothing_stays_loaded(core: UniMMCore) -> None:
    with pytest.raises(InvalidInstructionError):
        load_tango(core, f"{INSTANT}&profile=legacy", xy=None, z=None, strobe=True)
    assert core.getLoadedDevices() == ("Core",)


def test_a_strobe_pulse_out_of_range_is_refused() -> None:
    with pytest.raises(ValueError, match="L9861-9913"):
        TangoStrobe(pulse_ms=40_000)


# ------------------------------------------------------------------ z sequences -----------

def _set_dim(hub: TangoHub, dim: int) -> None:
    hub.controller.set("dim", axis=None, z=dim)


@pytest.mark.parametrize(("dim", "per_um"), [(2, 0.001), (1, 1.0)], ids=["mm", "um"])
def test_a_z_sequence_pulses_the_trigger_output_at_each_position(
        core: UniMMCore, dim: int, per_um: float) -> None:
    labels = load_tango(core, INSTANT, xy=None, shutter=False)
    hub = hub_of(core, labels)
    _set_dim(hub, dim)
    tango = hub.controller
    assert not core.isStageSequenceable("TangoZ")  # off unless asked for
    core.setProperty("TangoZ", "Trigger sequence", "On")
    assert core.isStageSequenceable("TangoZ")
    assert core.getStageSequenceMaxLength("TangoZ") == 10_000  # L13773
    z = [10.0, 22.5, 30.0, 47.5]
    core.loadStageSequence("TangoZ", z)
    # the list in the axis's dim unit, written by the family (the emulator's copy)
    assert tango.triggers.read_positions() == pytest.approx([v * per_um for v in z])
    core.startStageSequence("TangoZ")
    assert core.deviceBusy("TangoZ")
    core.waitForDevice("TangoZ")
    pulses = _pulses(hub, TRIGGER_OUT)
    # one pulse at each position, in order, as the stage passed it: the emulator's record
    assert [p.position for p in pulses] == pytest.approx([v * per_um for v in z])
    assert [p.time for p in pulses] == sorted(p.time for p in pulses)
    assert tango.triggers.count() == 4 and _emulated(hub, "trig") == 1
    assert core.getPosition() == pytest.approx(65.0)  # one step past the last
    assert emulated(hub)["z"][0] == pytest.approx(65.0, abs=0.01)
    core.stopStageSequence("TangoZ")
    assert _emulated(hub, "trig") == 0


def test_a_linear_z_sequence_is_a_trigger_range_from_where_the_stage_stands(
        core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, shutter=False)
    hub = hub_of(core, labels)
    core.setPosition(100.0)
    core.waitForDevice("TangoZ")
    assert not core.isStageLinearSequenceable("TangoZ")
    core.setProperty("TangoZ", "Trigger sequence", "On")
    assert core.isStageLinearSequenceable("TangoZ")
    core.setStageLinearSequence("TangoZ", -5.0, 5)  # downwards: 100, 95, ... 80
    assert _emulated(hub, "trigm") == 21  # the controller's down list (L13519-13520)
    core.startStageSequence("TangoZ")
    core.waitForDevice("TangoZ")
    assert [p.position for p in _pulses(hub, TRIGGER_OUT)] == pytest.approx(
        [0.1, 0.095, 0.09, 0.085, 0.08])  # mm, z's default dim
    assert core.getPosition() == pytest.approx(75.0)
    core.stopStageSequence("TangoZ")


@pytest.mark.parametrize("sequence", [[10.0], [10.0, 20.0, 15.0], [10.0, 10.0],
                                      [10.0, float("nan")]],
                         ids=["one", "turns", "repeats", "nan"])
def test_a_sequence_the_list_cannot_hold_is_refused_before_any_byte(
        core: UniMMCore, sequence: list[float]) -> None:
    labels = load_tango(core, INSTANT, xy=None, shutter=False)
    hub = hub_of(core, labels)
    hub.controller.triggers.upload_positions([0.5, 0.6], axis="z")
    core.setProperty("TangoZ", "Trigger sequence", "On")
    with pytest.raises(ValueError):
        core.loadStageSequence("TangoZ", sequence)
    assert hub.controller.triggers.read_positions() == [0.5, 0.6]  # untouched
    with pytest.raises(RuntimeError, match="no sequence loaded"):
        core.startStageSequence("TangoZ")
    with pytest.raises(ValueError):
        core.setStageLinearSequence("TangoZ", 0.0, 3)
    with pytest.raises(ValueError):
        core.setStageLinearSequence("TangoZ", 1.0, 1)


def test_stopping_a_running_sequence_stops_the_stage_and_the_output(
        core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, shutter=False)
    hub = hub_of(core, labels)
    core.setProperty("TangoZ", "Trigger sequence", "On")
    core.setProperty("TangoZ", "Z Velocity (um/s)", 1000.0)  # the run: 40 s, stopped first
    core.loadStageSequence("TangoZ", [1000.0 * k for k in range(1, 40)])
    core.startStageSequence("TangoZ")
    deadline = time.monotonic() + HANG
    while not _pulses(hub, TRIGGER_OUT):
        assert time.monotonic() < deadline, "no pulse"
    core.stopStageSequence("TangoZ")
    assert not core.deviceBusy("TangoZ")  # the stopped run is no failure
    assert not emulated(hub)["z"][1] and _emulated(hub, "trig") == 0
    seen = len(_pulses(hub, TRIGGER_OUT))
    assert 0 < seen < 39
    assert core.getPosition() < 39_000.0


def test_a_sequence_needs_the_trigger_sequence_property(core: UniMMCore) -> None:
    labels = load_tango(core, INSTANT, xy=None, shutter=False)
    stage = core._pydevices[labels["z"]]
    assert isinstance(stage, TangoZStage)
    with pytest.raises(RuntimeError, match="'Trigger sequence' property to 'On'"):
        stage.send_sequence((1.0, 2.0))
    with pytest.raises(RuntimeError, match="'Trigger sequence' property to 'On'"):
        stage.set_linear_sequence(1.0, 3)
    assert hub_of(core, labels).controller.triggers.read_positions() == []
