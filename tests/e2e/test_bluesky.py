"""tango_aio.bluesky with a real RunEngine against the in-process emulator.

Synchronous tests: the RunEngine runs its own event loop in a thread; the devices are
connected on it (``init_devices``), and the tests reach the controller and the emulator
through ``call_in_bluesky_event_loop``.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from typing import Any, TypeVar, cast

import pytest

pytest.importorskip("bluesky")
pytest.importorskip("ophyd_async")

import bluesky.plan_stubs as bps
import bluesky.plans as bp
from bluesky import RunEngine, RunEngineInterrupted
from bluesky.protocols import (
    Checkable,
    Collectable,
    Configurable,
    Flyable,
    Locatable,
    Movable,
    Pausable,
    Preparable,
    Readable,
    Stoppable,
)
from bluesky.run_engine import call_in_bluesky_event_loop
from bluesky.utils import FailedStatus
from helpers import wire_of
from ophyd_async.core import Watcher, WatcherUpdate, init_devices
from test_coalesce import motion_lines

from tango_aio.bluesky import (
    MarzhauserFlyer,
    MarzhauserStage,
    MissingAxisError,
    StageLimitsError,
    TriggerScan,
    close_stage,
    fly_raster,
)
from tango_aio.errors import MoveError
from tango_aio.sim.model import ControllerModel

T = TypeVar("T")
URL = "sim://?baud=0"


def run(coro: Coroutine[Any, Any, T]) -> T:
    """Run ``coro`` on the RunEngine's event loop and return its result."""
    return call_in_bluesky_event_loop(coro, timeout=30)


@pytest.fixture
def RE() -> Iterator[RunEngine]:
    loop = asyncio.new_event_loop()
    engine = RunEngine({}, loop=loop, context_managers=[])
    yield engine
    if engine.state not in ("idle", "panicked"):
        engine.halt()
    loop.call_soon_threadsafe(loop.stop)
    engine._th.join()
    loop.close()


@pytest.fixture
def documents(RE: RunEngine) -> list[tuple[str, dict[str, Any]]]:
    collected: list[tuple[str, dict[str, Any]]] = []
    RE.subscribe(lambda name, doc: collected.append((name, doc)))
    return collected


def events(documents: list[tuple[str, dict[str, Any]]],
           stream: str = "primary") -> list[dict[str, Any]]:
    """The data of every event (and event page row) of ``stream``."""
    streams = {doc["uid"]: doc["name"] for name, doc in documents if name == "descriptor"}
    rows: list[dict[str, Any]] = []
    for name, doc in documents:
        if name == "event" and streams[doc["descriptor"]] == stream:
            rows.append(doc["data"])
        elif name == "event_page" and streams[doc["descriptor"]] == stream:
            keys = list(doc["data"])
            rows += [dict(zip(keys, values, strict=True))
                     for values in zip(*doc["data"].values(), strict=True)]
    return rows


@pytest.fixture
def stage(RE: RunEngine, request: pytest.FixtureRequest) -> Iterator[MarzhauserStage]:
    # An indirect parameter sets the longest wait for announced sets (default 0.25 s).
    window = getattr(request, "param", 0.25)
    with init_devices():
        stage = MarzhauserStage(URL, axes="xy", window=window, progress_interval=0.02)
    run(_fast(stage))
    yield stage
    run(stage.aclose())


@pytest.fixture
def flyer(stage: MarzhauserStage) -> MarzhauserFlyer:
    with init_devices():
        flyer = MarzhauserFlyer(stage)
    return flyer


async def _fast(stage: MarzhauserStage, velocity: float = 100) -> None:
    for name, value in (("secvel", 100), ("vel", velocity), ("accel", 20)):
        await stage.controller.set(name, x=value, y=value)


def model_of(stage: MarzhauserStage) -> ControllerModel:
    model = wire_of(stage.controller).handler
    assert isinstance(model, ControllerModel)
    return model


def emulated(stage: MarzhauserStage) -> dict[str, float]:
    """Where the emulator's axes really are (its state, not a reply)."""
    motion = model_of(stage).motion
    return {axis: round(motion.to_user(axis, motion.position(axis)), 9) for axis in "xy"}


async def failure(status: Awaitable[Any]) -> BaseException | None:
    """What ``status`` failed with (None if it succeeded)."""
    try:
        await status
    except BaseException as exc:  # a cancellation counts as a failure here too
        return exc
    return None


@pytest.fixture
def moves(caplog: pytest.LogCaptureFixture) -> Callable[[], list[str]]:
    """The motion lines written so far."""
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    return lambda: motion_lines(caplog)


# --------------------------------------------------------------------------------------
# Devices


def keywords(function: Callable[..., object]) -> Watcher[float]:
    """``function`` as an ophyd-async Watcher: AsyncStatus.watch calls it with keywords only,
    which a ``**update`` lambda takes (mypy wants the positional form of the protocol)."""
    return cast("Watcher[float]", function)


def test_stage_has_one_child_per_axis_with_units_and_precision(
        stage: MarzhauserStage) -> None:
    assert [name for name, _ in stage.children()] == ["x", "y"]
    assert stage.axis("x") is stage.x
    described = run(stage.describe())
    assert set(described) == {"stage-x", "stage-y"}
    assert described["stage-x"]["units"] == "mm"
    assert described["stage-x"]["precision"] == 4
    assert stage.x.hints == {"fields": ["stage-x"]}
    config = run(stage.x.describe_configuration())
    assert config["stage-x-velocity"]["units"] == "mm/s"
    assert config["stage-x-acceleration"]["units"] == "m/s^2"


def test_axes_follow_the_bluesky_protocols(
        stage: MarzhauserStage, flyer: MarzhauserFlyer) -> None:
    for protocol in (Movable, Locatable, Stoppable, Readable, Configurable, Checkable,
                     Flyable, Preparable, Pausable):
        assert isinstance(stage.x, protocol), protocol
    for flyer_protocol in (Flyable, Preparable, Collectable, Stoppable, Pausable):
        assert isinstance(flyer, flyer_protocol), flyer_protocol


def test_axes_do_not_keep_the_parent_device(stage: MarzhauserStage) -> None:
    assert [name for name, _ in stage.x.children()] == [
        "user_readback", "user_setpoint", "motor_egu", "motor_resolution",
        "steps_per_revolution", "units_per_revolution", "velocity", "offset",
        "acceleration", "low_limit_travel", "high_limit_travel", "max_velocity",
        "acceleration_time", "precision", "motor_done_move", "dial_low_limit_travel",
        "dial_high_limit_travel", "low_limit_switch", "high_limit_switch", "motor_stop"]
    assert stage.x.parent is stage


def test_connect_checks_that_the_axes_exist(RE: RunEngine) -> None:
    stage = MarzhauserStage("sim://?baud=0&axes=2", axes="xyz")
    with pytest.raises(MissingAxisError, match="no z"):
        run(stage.connect())
    with pytest.raises(ValueError):
        MarzhauserStage(URL, axes="xq")


def test_units_and_precision_follow_dim(RE: RunEngine, tmp_path: Any) -> None:
    url = f"{URL}&state={tmp_path / 'state.json'}"
    first = MarzhauserStage(url, axes="xy")
    run(first.connect())
    run(first.controller.set("dim", 1, 0))  # x in µm, y in µsteps
    run(first.controller.command("save"))
    run(first.aclose())
    stage = MarzhauserStage(url, axes="xy")
    run(stage.connect())
    described = run(stage.describe())
    assert (described["stage-x"]["units"], described["stage-y"]["units"]) == ("µm", "µstep")
    assert described["stage-y"]["precision"] == 0
    run(stage.aclose())


def test_config_signals_read_and_write_the_controller(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    RE(bps.mv(stage.x.velocity, 42.5, stage.y.acceleration, 3))
    assert run(stage.controller.get("vel", axis="x")) == 42.5
    assert run(stage.controller.get("accel", axis="y")) == 3
    assert run(stage.x.velocity.get_value()) == 42.5
    config = run(stage.read_configuration())
    assert config["stage-x-low_limit_travel"]["value"] == -2600.0
    assert config["stage-x-high_limit_travel"]["value"] == 2600.0


# --------------------------------------------------------------------------------------
# Step scans


def test_scan_over_two_axes_reads_exact_positions(
        RE: RunEngine, stage: MarzhauserStage, documents: list[Any]) -> None:
    RE(bp.scan([stage], stage.x, 0, 1, stage.y, 0, -2, 3))
    assert events(documents) == [{"stage-x": 0.0, "stage-y": 0.0},
                                 {"stage-x": 0.5, "stage-y": -1.0},
                                 {"stage-x": 1.0, "stage-y": -2.0}]
    assert emulated(stage) == {"x": 1.0, "y": -2.0}


def test_grid_scan(RE: RunEngine, stage: MarzhauserStage, documents: list[Any]) -> None:
    RE(bp.grid_scan([stage], stage.y, 0, 1, 2, stage.x, 0, 2, 3, snake_axes=True))
    assert [(row["stage-y"], row["stage-x"]) for row in events(documents)] == [
        (0.0, 0.0), (0.0, 1.0), (0.0, 2.0), (1.0, 2.0), (1.0, 1.0), (1.0, 0.0)]
    assert emulated(stage) == {"x": 0.0, "y": 1.0}


def test_mv_merges_the_axes_into_one_line(
        RE: RunEngine, stage: MarzhauserStage, moves: Callable[[], list[str]]) -> None:
    RE(bps.mv(stage.x, 1.25, stage.y, -0.75))
    assert moves() == ["!moa 1.25 -0.75"]
    assert emulated(stage) == {"x": 1.25, "y": -0.75}
    assert run(stage.x.read())["stage-x"]["value"] == 1.25
    assert run(stage.y.locate()) == {"setpoint": -0.75, "readback": -0.75}


def test_limits_are_checked_before_anything_moves(
        RE: RunEngine, stage: MarzhauserStage, moves: Callable[[], list[str]]) -> None:
    run(stage.controller.set("lim", -5, 5, axis="x"))
    with pytest.raises(StageLimitsError, match="outside the limits"):
        run(stage.x.check_value(6))
    with pytest.raises(FailedStatus) as info:
        RE(bps.mv(stage.x, 6))
    assert isinstance(info.value.__cause__, StageLimitsError)
    assert moves() == []
    assert emulated(stage)["x"] == 0.0
    RE(bps.mv(stage.x, 5))
    assert emulated(stage)["x"] == 5.0


def test_a_step_scan_checks_its_points_without_reading_the_limits_again(
        RE: RunEngine, stage: MarzhauserStage, caplog: pytest.LogCaptureFixture) -> None:
    def lim_reads() -> int:
        return sum(1 for r in caplog.records if r.name == "tango_aio.wire"
                   and " -> " in r.getMessage() and "?lim" in r.getMessage())

    run(stage.x.check_value(0.0))  # the limits known after the fixture's set lines
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        RE(bp.scan([stage.x], stage.x, 0.5, 1.0, 2))
        short = lim_reads()  # the run's configuration reads them (limit signals)
        RE(bp.scan([stage.x], stage.x, 0.5, 3.0, 6))
        assert lim_reads() == 2 * short  # none per point: nothing changed them
        run(stage.controller.set("lim", -1, 1, axis="x"))  # any caller, any path
        with pytest.raises(FailedStatus) as info:
            RE(bp.scan([stage.x], stage.x, 0.5, 1.5, 2))
        assert isinstance(info.value.__cause__, StageLimitsError)
    assert emulated(stage)["x"] == 0.5


def test_set_reports_progress_and_publishes_the_final_readback(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    run(_fast(stage, velocity=4))  # 1 mm at 4 mm/s: several polls
    updates: list[WatcherUpdate[float]] = []

    async def move() -> None:
        status = stage.x.set(1.0)
        status.watch(keywords(lambda **update: updates.append(WatcherUpdate(**update))))
        await status

    run(move())
    assert updates[-1].current == 1.0
    assert {(u.initial, u.target, u.unit, u.name) for u in updates} == {
        (0.0, 1.0, "mm", "stage-x")}
    assert any(0.0 < u.current < 1.0 for u in updates)
    currents = [u.current for u in updates]
    assert currents == sorted(currents)


def test_stop_during_a_move_stops_the_axes_and_fails_the_status(
        RE: RunEngine, stage: MarzhauserStage) -> None:
    run(_fast(stage, velocity=2))
    started = threading.Event()

    async def move_and_stop() -> BaseException | None:
        status = stage.x.set(20.0)
        def note_start(**update: Any) -> None:
            if update["current"] > 0.05:
                started.set()

        status.watch(keywords(note_start))
        for _ in range(1000):
            if started.is_set():
                break
            await asyncio.sleep(0.01)
        await stage.x.stop(success=False)
        return await failure(status)

    error = run(move_and_stop())
    assert isinstance(error, RuntimeError)
    assert set(run(stage.controller.status()).values()) <= {"@", "E"}
    position = emulated(stage)["x"]
    assert 0.05 < position < 20
    assert run(stage.x.read())["stage-x"]["value"] == pytest.approx(position, abs=1e-4)
    RE(bps.mv(stage.x, 0))  # the next move works
    assert emulated(stage)["x"] == 0.0


def test_pause_during_a_move_then_resume(
        RE: RunEngine, stage: MarzhauserStage, documents: list[Any]) -> None:
    run(_fast(stage, velocity=2))
    paused = threading.Event()

    def pause_while_moving(reading: dict[str, Any]) -> None:
        if reading["stage-x"]["value"] > 0.6 and not paused.is_set():
            paused.set()
            threading.Thread(target=RE.request_pause).start()

    async def subscribe() -> None:  # subscriptions need the RunEngine's loop
        stage.x.subscribe_reading(pause_while_moving)

    async def unsubscribe() -> None:
        stage.x.clear_sub(pause_while_moving)

    run(subscribe())
    try:
        with pytest.raises(RunEngineInterrupted):
            RE(bp.scan([stage], stage.x, 0, 1.5, stage.y, 0, -3, 3))
        assert RE.state == "paused"
        # Paused: every axis stands still between the steps.
        assert set(run(stage.controller.status()).values()) <= {"@", "E"}
        assert 0.5 < emulated(stage)["x"] < 1.5
        RE.resume()
    finally:
        run(unsubscribe())
    # The interrupted step is repeated from its checkpoint: exact readings, no extra rows.
    assert events(documents) == [{"stage-x": 0.0, "stage-y": 0.0},
                                 {"stage-x": 0.75, "stage-y": -1.5},
                                 {"stage-x": 1.5, "stage-y": -3.0}]
    assert emulated(stage) == {"x": 1.5, "y": -3.0}
    stops = [doc for name, doc in documents if name == "stop"]
    assert stops[-1]["exit_status"] == "success"


# --------------------------------------------------------------------------------------
# Fly scans


def test_fly_scan_counts_the_uploaded_trigger_list(
        RE: RunEngine, stage: MarzhauserStage, flyer: MarzhauserFlyer,
        documents: list[Any]) -> None:
    positions = [0.0, 0.4, 1.1, 1.5, 2.75]
    scan = TriggerScan("x", start=-0.5, end=3.0, positions=positions)

    def plan() -> Any:
        yield from bps.prepare(flyer, scan, wait=True)
        return (yield from bp.fly([flyer]))

    RE(plan())
    assert events(documents, "flyer") == [
        {"flyer-trigger_count": 5, "flyer-triggers_expected": 5}]
    assert run(stage.controller.triggers.read_positions()) == positions
    assert model_of(stage).motion.trigger_count == 5
    assert emulated(stage)["x"] == 3.0


def test_fly_scan_collects_snapshot_positions(
        RE: RunEngine, stage: MarzhauserStage, flyer: MarzhauserFlyer,
        documents: list[Any]) -> None:
    run(_fast(stage, velocity=5))
    scan = TriggerScan("x", start=-0.2, end=1.0, trigger_range=(0.0, 0.8, 3),
                       snapshots=True)

    def capture() -> Any:  # what a signal on the snapshot input would do
        return stage.controller.command("!snse 2")

    def plan() -> Any:
        yield from bps.open_run()
        yield from bps.prepare(flyer, scan, wait=True)
        yield from bps.kickoff(flyer, wait=True)
        yield from bps.wait_for([capture])
        yield from bps.wait_for([capture])
        yield from bps.complete(flyer, wait=True)
        yield from bps.collect(flyer)
        yield from bps.close_run()

    RE(plan())
    assert events(documents, "flyer") == [
        {"flyer-trigger_count": 3, "flyer-triggers_expected": 3}]
    latched = model_of(stage).snapshots.entries
    assert len(latched) == 2
    rows = events(documents, "flyer_snapshots")
    assert [(row["flyer-snapshot_x"], row["flyer-snapshot_y"]) for row in rows] == [
        pytest.approx(tuple(entry[:2]), abs=1e-4) for entry in latched]
    assert -0.2 <= rows[0]["flyer-snapshot_x"] <= rows[1]["flyer-snapshot_x"] <= 1.0


def test_raster_fly_scan(RE: RunEngine, stage: MarzhauserStage, flyer: MarzhauserFlyer,
                         documents: list[Any], moves: Callable[[], list[str]]) -> None:
    RE(fly_raster(stage, flyer, 0, 2, 5, 0, 1, 3, run_up=0.25))
    assert [row["stage-y"] for row in events(documents)] == [0.0, 0.5, 1.0]
    assert events(documents, "flyer") == [
        {"flyer-trigger_count": 5, "flyer-triggers_expected": 5}] * 3
    start = next(doc for name, doc in documents if name == "start")
    assert start["shape"] == [3, 5]
    # Snake: the middle row flies backwards; the slow move merges with the run-up move.
    assert emulated(stage) == {"x": 2.25, "y": 1.0}
    assert "!moa 2.25 0.5" in moves()


def test_trigger_scan_validates_the_pass() -> None:
    with pytest.raises(ValueError, match="either"):
        TriggerScan("x", 0, 1)
    with pytest.raises(ValueError, match="before the first"):
        TriggerScan("x", 0, 2, positions=[0, 1])
    with pytest.raises(ValueError, match="before the first"):
        TriggerScan("x", 3, -1, positions=[0, 1])
    assert TriggerScan("x", 3, -1, trigger_range=(2, 0, 3)).trigger_positions == (2, 1, 0)


def test_stopping_the_flyer_stops_the_pass(
        RE: RunEngine, stage: MarzhauserStage, flyer: MarzhauserFlyer,
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
    run(_fast(stage, velocity=2))
    scan = TriggerScan("x", start=-0.1, end=10.0, trigger_range=(0.0, 9.0, 10))

    async def fly_and_stop() -> BaseException | None:
        await flyer.prepare(scan)
        await flyer.kickoff()
        completing = flyer.complete()
        await stage.x.user_readback.get_value()  # the pass runs (kickoff saw it move)
        await flyer.stop()
        return await failure(completing)

    error = run(fly_and_stop())
    assert isinstance(error, MoveError)
    assert set(run(stage.controller.status()).values()) <= {"@", "E"}
    assert emulated(stage)["x"] < 10.0
    assert run(stage.controller.get("trig")) == 0
    assert run(stage.controller.get("trigcount")) < 10
    written = [r.getMessage() for r in caplog.records if r.name == "tango_aio.wire"]
    assert any(line.endswith("-> b'!a x'") for line in written)  # the pass's axis only
    assert not any(line.endswith("-> b'!a'") for line in written)


def test_pause_during_a_fly_pass_then_resume(
        RE: RunEngine, stage: MarzhauserStage, flyer: MarzhauserFlyer,
        documents: list[Any]) -> None:
    run(_fast(stage, velocity=5))
    latest = {"stage-x": 0.0, "stage-y": 0.0}
    paused = threading.Event()

    def pause_in_the_second_row(reading: dict[str, Any]) -> None:
        latest.update({key: value["value"] for key, value in reading.items()})
        if latest["stage-y"] == 1.0 and 0.2 < latest["stage-x"] < 0.8 and \
                not paused.is_set():
            paused.set()
            threading.Thread(target=RE.request_pause).start()

    async def subscribe() -> None:
        stage.x.subscribe_reading(pause_in_the_second_row)
        stage.y.subscribe_reading(pause_in_the_second_row)

    async def unsubscribe() -> None:
        stage.x.clear_sub(pause_in_the_second_row)
        stage.y.clear_sub(pause_in_the_second_row)

    run(subscribe())
    try:
        with pytest.raises(RunEngineInterrupted):
            RE(fly_raster(stage, flyer, 0, 1, 3, 0, 1, 2, run_up=0.25))
        # The pass was stopped mid-row (the RunEngine paused the flyer).
        assert set(run(stage.controller.status()).values()) <= {"@", "E"}
        assert 0.1 < emulated(stage)["x"] < 0.9
        RE.resume()
    finally:
        run(unsubscribe())
    assert events(documents, "flyer") == [
        {"flyer-trigger_count": 3, "flyer-triggers_expected": 3}] * 2
    assert emulated(stage) == {"x": -0.25, "y": 1.0}
    assert [doc for name, doc in documents if name == "stop"][-1]["exit_status"] == "success"


def test_mock_mode_needs_no_controller(RE: RunEngine, documents: list[Any]) -> None:
    with init_devices(mock=True):
        stage = MarzhauserStage("sim://?baud=0", axes="xy")
    RE(bps.mv(stage.x.velocity, 3))
    RE(bp.scan([stage], stage.x, 0, 1, stage.y, 2, 3, 2))
    assert events(documents) == [{"stage-x": 0.0, "stage-y": 2.0},
                                 {"stage-x": 1.0, "stage-y": 3.0}]
    assert run(stage.x.velocity.get_value()) == 3.0
    assert not stage.link.connected


def test_close_stage_plan_closes_the_controller(RE: RunEngine) -> None:
    with init_devices():
        stage = MarzhauserStage(URL, axes="x")
    controller = stage.controller
    RE(close_stage(stage))
    assert not stage.link.connected
    assert not controller.connected
