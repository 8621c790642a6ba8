"""tango_aio.mm's camera-triggered sequences (Micro-Manager's convention: the stage steps to
the next position on each trigger from the camera) through the snapshot array in step
mode 5, against the emulator in each of its readings where the manual is silent; and a
pymmcore-plus MDA with hardware z sequencing."""

from __future__ import annotations

import asyncio
import gc
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import pytest

pytest.importorskip("tango_aio.mm")  # first: it keeps the root logger's level
pytest.importorskip("useq")

import numpy as np
import useq
from pymmcore_plus.experimental.unicore import UniMMCore
from test_mm import HANG, INSTANT, Camera, emulated, hub_of, make_fast

import tango_aio
from tango_aio import MoveError
from tango_aio.errors import NotSupportedByFirmwareError
from tango_aio.mm import TangoHub, TangoXYStage, TangoZStage, load_tango
from tango_aio.mm._stepseq import StepArray, start, upload
from tango_aio.testing import faults


@pytest.fixture
def core() -> Iterator[UniMMCore]:
    """A core (as test_mm's), unloaded and collected here, not in pymmcore's thread."""
    mm = UniMMCore()
    mm.setTimeoutMs(60_000)  # waitForDevice's bound: only a hang reaches it
    yield mm
    mm.unloadAllDevices()
    del mm
    gc.collect()


#: The emulator's readings where the manual is silent about a step (sim/profiles.py).
STEP_VARIANTS = ["", "snapshot_pointer=advance", "snapshot_step_report=yes",
                 "snapshot_while_moving=ignore"]


def trigger(hub: TangoHub, count: int = 1) -> None:
    """``count`` pulses of the camera's trigger output on the emulator's snapshot input,
    at one instant."""
    tango = hub.controller

    async def pulse() -> None:
        for _ in range(count):
            faults(tango.aio).pulse_snapshot_input()

    tango.portal.call(pulse)


def standing(hub: TangoHub) -> dict[str, float]:
    """Where the emulated axes stand, in µm, once none moves (bounded: a hang)."""
    deadline = time.monotonic() + HANG
    while True:
        where = emulated(hub)
        if not any(moving for _, moving in where.values()):
            return {axis: um for axis, (um, _) in where.items()}
        assert time.monotonic() < deadline, "the stage never stood still"


def snapshot_state(hub: TangoHub) -> tuple[int, bool]:
    snapshots = hub.controller.snapshots
    return int(snapshots.snsm()), bool(snapshots.sns())


def loaded(core: UniMMCore, variant: str = "", **parts: Any) -> TangoHub:
    url = f"{INSTANT}&{variant}" if variant else INSTANT
    labels = load_tango(core, url, **parts)
    hub = hub_of(core, labels)
    hub.controller.snapshots.set_snsf(0)  # a camera's clean edges need no debounce
    return hub


# ------------------------------------------------------------------ a z sequence ----------

@pytest.mark.parametrize("variant", STEP_VARIANTS, ids=lambda v: v or "manual")
def test_the_z_stage_steps_on_each_camera_trigger(core: UniMMCore, variant: str) -> None:
    hub = loaded(core, variant, xy=None, shutter=False)
    before = snapshot_state(hub)
    assert not core.isStageSequenceable("TangoZ")  # off unless asked for
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    assert core.isStageSequenceable("TangoZ")
    assert core.getStageSequenceMaxLength("TangoZ") == 1024  # L14550
    z = [10.0, 22.5, 30.0, 47.5]
    core.loadStageSequence("TangoZ", z)
    core.startStageSequence("TangoZ")
    core.waitForDevice("TangoZ")  # armed at the first position
    seen = [standing(hub)["z"]]
    for _ in z:
        trigger(hub)
        seen.append(standing(hub)["z"])
    assert seen == pytest.approx([*z, z[0]], abs=0.01)  # each trigger: the next; wraps
    assert hub.controller.position()["x"] == 0.0  # the entries hold Z only
    core.stopStageSequence("TangoZ")
    assert core.getProperty("TangoZ", "Sequence stopped at") == "entry 1 of 4 (z=10 um)"
    assert snapshot_state(hub) == before  # the user's snapshot mode is back
    trigger(hub)  # no step once stopped
    assert standing(hub)["z"] == pytest.approx(10.0, abs=0.01)


@pytest.mark.parametrize(("variant", "stopped"), [
    ("", None),  # the second step refused: Z moves (move_during_move=refuse)
    ("snapshot_while_moving=ignore", "entry 2 of 4 (z=1000 um)"),
    ("move_during_move=retarget", "entry 3 of 4 (z=2000 um)")],
    ids=["refused", "ignored", "retargeted"])
def test_a_trigger_while_the_stage_steps(core: UniMMCore, variant: str,
                                         stopped: str | None) -> None:
    hub = loaded(core, variant, xy=None, shutter=False)
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    core.setStageLinearSequence("TangoZ", 1000.0, 4)  # from where it stands: 0, 1, 2, 3 mm
    core.startStageSequence("TangoZ")
    core.waitForDevice("TangoZ")
    trigger(hub, 2)  # the second at once, while the first step moves
    if stopped is None:  # the pointer went on, the stage did not: reported, with where
        with pytest.raises(MoveError, match="at Z=1000 um, not at entry 3 of 4"):
            core.stopStageSequence("TangoZ")
    else:
        core.stopStageSequence("TangoZ")  # the step under way ends; nothing moves after
        assert core.getProperty("TangoZ", "Sequence stopped at") == stopped
    where = standing(hub)["z"]
    assert where == pytest.approx(2000.0 if "retarget" in variant else 1000.0, abs=0.01)
    assert core.getPosition() == pytest.approx(where, abs=0.01)
    assert not core.deviceBusy("TangoZ")


def test_a_step_refused_at_a_limit_is_reported_at_the_stop(core: UniMMCore) -> None:
    hub = loaded(core, xy=None, shutter=False)
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    core.setProperty("TangoZ", "Z Upper limit (um)", 30.0)
    core.loadStageSequence("TangoZ", [10.0, 20.0, 40.0])
    core.startStageSequence("TangoZ")
    core.waitForDevice("TangoZ")
    trigger(hub)
    assert standing(hub)["z"] == pytest.approx(20.0, abs=0.01)
    trigger(hub)  # to 40 µm: beyond the limit, refused
    with pytest.raises(MoveError, match=r"Z E .*standing at Z=20 um"):
        core.stopStageSequence("TangoZ")
    assert standing(hub)["z"] == pytest.approx(20.0, abs=0.01)
    assert snapshot_state(hub) == (0, True)  # put back all the same


def test_a_step_into_a_limit_switch_is_reported_at_the_stop(core: UniMMCore) -> None:
    hub = loaded(core, xy=None, shutter=False)
    make_fast(hub)
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    core.loadStageSequence("TangoZ", [10.0, 60_000.0])  # the switch is at +50 mm
    core.startStageSequence("TangoZ")
    core.waitForDevice("TangoZ")
    trigger(hub)
    with pytest.raises(MoveError, match="Z S"):
        core.stopStageSequence("TangoZ")
    assert 10.0 < standing(hub)["z"] < 60_000.0


# ------------------------------------------------------------------ XY, and XY with Z ------

@pytest.mark.parametrize("variant", ["", "snapshot_pointer=advance"],
                         ids=["manual", "advance"])
def test_the_xy_stage_steps_and_shares_the_array_with_z(core: UniMMCore,
                                                        variant: str) -> None:
    hub = loaded(core, variant, shutter=False)
    for label in ("TangoXY", "TangoZ"):
        core.setProperty(label, "Camera trigger sequence", "On")
    assert core.isXYStageSequenceable("TangoXY")
    assert core.getXYStageSequenceMaxLength("TangoXY") == 1024
    xs, ys, zs = [100.0, -200.0, 300.0], [50.0, 60.0, -70.0], [5.0, 6.0, 7.0]
    core.loadXYStageSequence("TangoXY", xs, ys)
    core.loadStageSequence("TangoZ", zs)  # as long: the rows hold X, Y and Z
    core.startXYStageSequence("TangoXY")
    core.startStageSequence("TangoZ")
    core.waitForSystem()
    seen = [standing(hub)]
    for _ in range(2):
        trigger(hub)
        seen.append(standing(hub))
    assert [w["x"] for w in seen] == pytest.approx(xs, abs=0.01)
    assert [w["y"] for w in seen] == pytest.approx(ys, abs=0.01)
    assert [w["z"] for w in seen] == pytest.approx(zs, abs=0.01)
    core.stopXYStageSequence("TangoXY")
    core.stopStageSequence("TangoZ")
    assert core.getProperty("TangoXY", "Sequence stopped at") == \
        "entry 3 of 3 (x=300 um, y=-70 um, z=7 um)"
    assert snapshot_state(hub) == (0, True)


def test_a_z_sequence_of_another_length_replaces_the_xy_one(core: UniMMCore) -> None:
    hub = loaded(core, shutter=False)
    for label in ("TangoXY", "TangoZ"):
        core.setProperty(label, "Camera trigger sequence", "On")
    core.loadXYStageSequence("TangoXY", [100.0, 200.0], [0.0, 0.0])
    core.loadStageSequence("TangoZ", [5.0, 6.0, 7.0])
    core.startXYStageSequence("TangoXY")
    with pytest.raises(RuntimeError, match="another length replaced it"):
        core.waitForDevice("TangoXY")
    assert hub.controller.position()["x"] == 0.0


# ------------------------------------------------------------------ refusals ---------------

@pytest.mark.parametrize("sequence", [[], [10.0, float("nan")], [1.0] * 1025],
                         ids=["empty", "nan", "too-long"])
def test_a_sequence_the_array_cannot_hold_is_refused_before_any_byte(
        core: UniMMCore, sequence: list[float]) -> None:
    hub = loaded(core, xy=None, shutter=False)
    hub.controller.snapshots.upload_positions([[1.0, 2.0, 3.0]])
    stage = core._pydevices["TangoZ"]
    assert isinstance(stage, TangoZStage)
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    with pytest.raises(ValueError):
        stage.send_sequence(tuple(sequence))  # the core checks the length itself too
    assert hub.controller.snapshots.read_positions() == [[1.0, 2.0, 3.0]]


def test_one_kind_of_sequence_at_a_time(core: UniMMCore) -> None:
    loaded(core, xy=None, shutter=False)
    core.setProperty("TangoZ", "Trigger sequence", "On")
    with pytest.raises(Exception, match="'Trigger sequence' off first"):
        core.setProperty("TangoZ", "Camera trigger sequence", "On")
    core.setProperty("TangoZ", "Trigger sequence", "Off")
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    with pytest.raises(Exception, match="'Camera trigger sequence' off first"):
        core.setProperty("TangoZ", "Trigger sequence", "On")
    assert core.getStageSequenceMaxLength("TangoZ") == 1024


def test_the_older_edition_has_no_camera_triggered_sequence(core: UniMMCore) -> None:
    load_tango(core, f"{INSTANT}&profile=legacy", xy=None, shutter=False)
    with pytest.raises(NotSupportedByFirmwareError):
        core.setProperty("TangoZ", "Camera trigger sequence", "On")
    assert not core.isStageSequenceable("TangoZ")


def test_starting_without_the_property_is_refused(core: UniMMCore) -> None:
    loaded(core, shutter=False)
    with pytest.raises(RuntimeError, match="'Camera trigger sequence' property to 'On'"):
        stage = core._pydevices["TangoXY"]
        assert isinstance(stage, TangoXYStage)
        stage.start_sequence()


# ------------------------------------------------------------------ an MDA -----------------

class TriggeringCamera(Camera):
    """A camera whose trigger output drives the TANGO's snapshot input: in a sequence it
    pulses it after each frame's exposure. Its frame interval outlasts a step (it waits
    until the emulated stage stands before the next exposure); at each exposure it
    records where the emulated axes are and whether they move."""

    def __init__(self, hub: TangoHub) -> None:
        super().__init__(hub)
        self._sequence = False

    def snap(self, buffer: np.ndarray[Any, Any]) -> Mapping[str, Any]:
        if self._sequence:
            standing(self.hub)
        meta = super().snap(buffer)
        if self._sequence:
            trigger(self.hub)
        return meta

    def start_sequence(self, n: int | None, get_buffer: Any) -> Iterator[Mapping[str, Any]]:
        self._sequence = True
        try:
            yield from super().start_sequence(n, get_buffer)
        finally:
            self._sequence = False


def _mda(core: UniMMCore, z_plan: Any) -> tuple[TangoHub, TriggeringCamera,
                                                 list[useq.MDAEvent]]:
    hub = loaded(core)  # the shutter too: the engine fails without one
    camera = TriggeringCamera(hub)
    core.loadPyDevice("Camera", camera)
    core.initializeDevice("Camera")
    core.setCameraDevice("Camera")
    core.setProperty("TangoZ", "Camera trigger sequence", "On")
    events: list[useq.MDAEvent] = []
    core.mda.events.frameReady.connect(lambda _img, event, _meta: events.append(event))
    core.mda.run(useq.MDASequence(stage_positions=(useq.AbsolutePosition(x=100.0, y=-50.0,
                                                                         z=20.0),),
                                  z_plan=z_plan))
    return hub, camera, events


def _sequenced(core: UniMMCore) -> Sequence[Any]:
    return [event for event in core.mda.engine.event_iterator(  # type: ignore[union-attr]
        useq.MDASequence(z_plan=useq.ZRangeAround(range=10.0, step=5.0)))]


def test_an_mda_with_hardware_z_sequencing_takes_each_frame_at_its_position(
        core: UniMMCore) -> None:
    hub, camera, events = _mda(core, useq.ZRangeAround(range=20.0, step=5.0))
    assert len(_sequenced(core)) == 1  # the engine sequenced the z-stack: one event
    planned = [event.z_pos for event in events]
    assert planned == pytest.approx([10.0, 15.0, 20.0, 25.0, 30.0])
    assert len(camera.seen) == 5
    assert not any(moving for seen in camera.seen for _, moving in seen.values())
    assert [seen["z"][0] for seen in camera.seen] == pytest.approx(planned, abs=0.01)
    assert all((seen["x"][0], seen["y"][0]) == pytest.approx((100.0, -50.0), abs=0.01)
               for seen in camera.seen)
    # the stop after the last frame: the wrap step back to the first entry, nothing after
    assert core.getProperty("TangoZ", "Sequence stopped at") == "entry 1 of 5 (z=10 um)"
    assert snapshot_state(hub) == (0, True)


async def test_two_stages_starting_together_arm_the_array_one_after_the_other() -> None:
    # Micro-Manager starts the XY and the Z stage's sequences together, on one array:
    # without turns both would find the pointer's reading at once (two steps of F2).
    async with tango_aio.connect(INSTANT, units="um") as tango:  # as the hub's
        array = StepArray()
        array.load(("x", "y"), [(100.0, -200.0, 300.0), (50.0, 60.0, -70.0)])
        await upload(tango, array, array.load(("z",), [(5.0, 6.0, 7.0)]))
        keys: list[str] = []
        submit = tango.protocol.submit

        def spy(command: Any, *args: Any, **kwargs: Any) -> Any:
            if "snse" in command.line:
                keys.append(command.line)
            return submit(command, *args, **kwargs)

        tango.protocol.submit = spy  # type: ignore[method-assign]
        await asyncio.gather(start(tango, array, ("x", "y")), start(tango, array, ("z",)))
        assert keys == ["!snse 2"]  # one step finds the reading
        assert array.running == {"x", "y", "z"}
        assert await tango.snapshots.sns()
