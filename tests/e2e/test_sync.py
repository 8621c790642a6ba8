"""tango_aio.sync (issue 15 item 2): the blocking API on its own driver thread."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import inspect
import os
import signal
import subprocess
import sys
import textwrap
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from helpers import Emulated

import tango_aio
import tango_aio.sync
from tango_aio import MoveError
from tango_aio.controller._controller import Controller as AsyncController
from tango_aio.group._group import ControllerGroup as AsyncGroup
from tango_aio.sim.motion import MotionModel

INSTANT = "sim://?baud=0"


@pytest.fixture
def tango() -> Iterator[tango_aio.sync.Controller]:
    with tango_aio.sync.connect(INSTANT) as controller:
        yield controller


def _async_methods(cls: type) -> set[str]:
    return {name for name, member in inspect.getmembers(cls)
            if not name.startswith("_")
            and (inspect.iscoroutinefunction(member) or inspect.isasyncgenfunction(member))}


def test_every_async_method_has_a_blocking_twin() -> None:
    for async_cls, sync_cls, skip in (
            (AsyncController, tango_aio.sync.Controller, {"aclose"}),
            (AsyncGroup, tango_aio.sync.ControllerGroup, {"aclose", "open"})):
        missing = {name for name in _async_methods(async_cls) - skip
                   if not hasattr(sync_cls, name)}
        assert not missing, f"{sync_cls.__name__} lacks {sorted(missing)}"
        assert hasattr(sync_cls, "close")


def test_same_signatures_and_docstrings(tango: tango_aio.sync.Controller) -> None:
    for name in ("move_to", "get", "set", "position", "calibrate"):
        blocking, aio = getattr(tango, name), getattr(tango.aio, name)
        assert blocking.__doc__ == aio.__doc__
        assert inspect.signature(blocking) == inspect.signature(aio)
    assert tango_aio.sync.Controller.move_to.__doc__ == AsyncController.move_to.__doc__
    assert "concurrent.futures.Future" in (tango.start_move_to.__doc__ or "")


def test_blocking_moves_reads_and_units(tango: tango_aio.sync.Controller) -> None:
    assert tango.identity.model == "TANGO-DT"
    assert tango.move_to(x=1.5, y=2, unit="mm") == {"x": "@", "y": "@", "z": "@"}
    assert tango.position(unit="um") == pytest.approx({"x": 1500.0, "y": 2000.0, "z": 0.0})
    tango.set("vel", x=3.5)
    assert tango.get("vel")["x"] == 3.5
    assert tango.settings.velocity(unit="mm/s")["x"] == 3.5
    assert tango.info.readsn() == tango.read_info().serial_number
    snapshot = tango.settings.snapshot()
    tango.settings.check(snapshot)
    tango.command("!vel y 2")
    assert [str(d) for d in tango.settings.diff(snapshot)] == ["vel Y: snapshot 10.0, unit 2.0"]
    assert tango.settings.restore(snapshot)[0].setting == "vel"
    updates = list(tango.watch_position(0.01))
    assert updates[-1].positions == {"x": 1.5, "y": 2.0, "z": 0.0}
    with pytest.raises(tango_aio.InvalidCommandError):
        tango.move_to(x="1 2")  # type: ignore[arg-type]


def test_start_returns_a_future_and_wait_idle_waits_for_it(
        tango: tango_aio.sync.Controller) -> None:
    future = tango.start_move_to(x=0.5)
    assert isinstance(future, concurrent.futures.Future)
    letters = tango.wait_idle()  # never returns before the started move has finished
    assert future.done() and future.result() == {"x": "@", "y": "@", "z": "@"}
    assert letters["x"] == "@"
    assert tango.position()["x"] == 0.5


def test_wait_idle_raises_a_started_move_failure(tango: tango_aio.sync.Controller) -> None:
    tango.set("lim", x=[0, 1])
    tango.command("!limctr x 1")  # moves beyond the limit are refused or end in error
    future = tango.start_move_to(x=5)
    with pytest.raises((MoveError, tango_aio.ControllerError)):
        tango.wait_idle()
    assert future.done()


def test_a_started_move_cut_short_by_a_switch_is_done_when_the_stop_is_read(
        tango: tango_aio.sync.Controller) -> None:
    """#37 item 5 through the blocking API: a host polling the started move's future
    (Micro-Manager's "busy") sees it fail once X stops at its switch, while Y (a quarter
    of a millimetre over the whole vector move) would still run for seconds."""
    emu = Emulated(tango.aio)
    tango._portal.call(emu.shorten, 4.0, 1)  # switches at +-2 mm
    tango.move_to(x=1.5, y=-0.25)
    motion = emu.model.motion
    start = tango._portal.call(lambda: _now(motion))
    future = tango.start_move_to(x=60, y=0)
    error = future.exception(timeout=60)  # a bound that only catches a hang
    ended = tango._portal.call(lambda: _now(motion))
    assert isinstance(error, MoveError) and error.statuses["x"] == "S"
    # Done long before the emulator's clock reached the planned end of the move.
    assert ended - start < tango.aio._settings.travel("x", 58.5) / 2
    assert tango.status() == {"x": "S", "y": "E", "z": "@"}


async def _now(motion: MotionModel) -> float:
    return motion.now


@contextlib.contextmanager
def _ctrl_c_once(ready: Callable[[], bool]) -> Iterator[None]:
    """Press Ctrl+C (a real SIGINT to this process) as soon as ``ready()`` holds, from a
    helper thread, while the body blocks in the main thread."""
    def press() -> None:
        while not ready():
            pass
        os.kill(os.getpid(), signal.SIGINT)

    helper = threading.Thread(target=press)
    helper.start()
    try:
        yield
    finally:
        helper.join()


def test_ctrl_c_during_a_blocking_move_stops_the_axes(tango: tango_aio.sync.Controller
                                                      ) -> None:
    tango.set("vel", x=0.5)  # 100 mm at 0.5 rev/s and 1 mm pitch: minutes of travel
    with _ctrl_c_once(lambda: tango.status()["x"] == "M"), pytest.raises(KeyboardInterrupt):
        tango.move_to(x=100)
    # The interrupt came back only once the axes were stopped by the cancelled move.
    assert "M" not in tango.status().values()  # "E": aborted
    assert 0 < tango.position()["x"] < 100
    assert tango.move_to(x=0) == {"x": "@", "y": "@", "z": "@"}  # the next call works


def test_ctrl_c_before_the_move_is_handed_back_still_stops_the_axes(
        tango: tango_aio.sync.Controller, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl+C can land while the portal still waits for the call's task to be spawned,
    when the move is already written (seen about once in 40 presses): it stops the axes
    all the same."""
    tango.set("vel", x=0.5)
    portal = tango._portal.portal
    spawn = portal.start_task_soon

    def spawn_then_interrupt(*args: Any, **kwargs: Any) -> Any:
        monkeypatch.setattr(portal, "start_task_soon", spawn)  # only this once
        spawn(*args, **kwargs)
        while portal.call(tango.aio.status)["x"] != "M":
            pass
        raise KeyboardInterrupt  # before start_task_soon returned the future

    monkeypatch.setattr(portal, "start_task_soon", spawn_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        tango.move_to(x=100)
    assert "M" not in tango.status().values()  # "E": aborted
    assert tango.move_to(x=0) == {"x": "@", "y": "@", "z": "@"}


def test_cancelling_a_started_move_stops_it(tango: tango_aio.sync.Controller) -> None:
    tango.set("vel", x=0.5)
    future = tango.start_move_to(x=100)
    while tango.status()["x"] != "M":
        pass
    assert future.cancel() or future.done()
    # wait_idle joins the cancelled future (no error) and sees the stopped axes
    assert tango.wait_idle(timeout=10)["x"] != "M"
    assert tango.position()["x"] < 100


async def test_works_inside_a_running_event_loop() -> None:
    # As in Jupyter: the caller's thread runs a loop; the driver runs in its own.
    asyncio.get_running_loop()
    with tango_aio.sync.connect(INSTANT) as tango:
        assert tango.move_to(x=0.25) == {"x": "@", "y": "@", "z": "@"}
        assert tango.position()["x"] == 0.25


def test_events_iterator(tango: tango_aio.sync.Controller) -> None:
    events = tango.events()
    tango.move_to(x=0.1)
    for event in events:
        if isinstance(event, tango_aio.MoveFinished):
            assert event.ok
            break


def test_options_are_checked_before_a_thread_starts() -> None:
    before = threading.active_count()
    with pytest.raises(TypeError):
        tango_aio.sync.connect(INSTANT, reply_timout=1)  # type: ignore[call-arg]
    with pytest.raises(ValueError, match="reply_timeout"):
        tango_aio.sync.connect(INSTANT, reply_timeout=float("nan"))
    assert threading.active_count() == before


def test_a_failed_connect_stops_its_thread() -> None:
    before = threading.active_count()
    with pytest.raises(tango_aio.ConnectError, match="Connection refused"):
        tango_aio.sync.connect("socket://127.0.0.1:1")
    assert threading.active_count() == before


def test_group() -> None:
    with tango_aio.sync.ControllerGroup({"stage": INSTANT, "focus": "sim://?baud=0&axes=1"}
                                        ) as group:
        assert sorted(group) == ["focus", "stage"]
        result = group.move_to({"stage": {"x": 1.0}, "focus": {"x": 0.5}})
        assert result == {"stage": {"x": "@", "y": "@", "z": "@"}, "focus": {"x": "@"}}
        assert group["focus"].position() == {"x": 0.5}
        future = group.start_move_by({"stage": {"x": 1.0}})
        assert group.wait_idle()["stage"]["x"] == "@"
        assert future.result() == {"stage": {"x": "@", "y": "@", "z": "@"}}
        assert group.position()["stage"]["x"] == 2.0
        assert group.url("focus").endswith("axes=1")


@pytest.mark.slow
def test_in_a_real_ipython_kernel() -> None:
    """In Jupyter the main thread already runs an event loop; the blocking API works
    there (and a top-level ``await tango_aio.connect(...)`` does too)."""
    manager_module = pytest.importorskip("jupyter_client.manager")
    pytest.importorskip("ipykernel")
    manager, client = manager_module.start_new_kernel(kernel_name="python3")
    try:
        code = textwrap.dedent('''
            import asyncio, tango_aio, tango_aio.sync
            asyncio.get_running_loop()  # the kernel's own loop runs in this thread
            with tango_aio.sync.connect("sim://?baud=0") as tango:
                print("moved", tango.move_to(x=1.25)["x"], tango.position()["x"])
            tango = await tango_aio.connect("sim://?baud=0")
            print("async", (await tango.position())["x"])
            await tango.aclose()
        ''')
        reply = client.execute_interactive(code, timeout=60, output_hook=_collect)
        assert reply["content"]["status"] == "ok", reply["content"]
        assert "moved @ 1.25" in "".join(_OUTPUT)
        assert "async 0.0" in "".join(_OUTPUT)
    finally:
        client.stop_channels()
        manager.shutdown_kernel(now=True)


_OUTPUT: list[str] = []


def _collect(message: dict[str, Any]) -> None:
    if message["msg_type"] == "stream":
        _OUTPUT.append(message["content"]["text"])
    elif message["msg_type"] == "error":
        _OUTPUT.append("\n".join(message["content"]["traceback"]))


def test_a_script_that_forgets_close_still_exits() -> None:
    script = ("import tango_aio.sync\n"
              "tango = tango_aio.sync.connect('sim://?baud=0')\n"
              "print(tango.move_to(x=0.5))\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    assert "'x': '@'" in result.stdout


def test_the_driver_loop_can_be_uvloop() -> None:
    pytest.importorskip("uvloop")
    script = ("import asyncio, tango_aio.sync\n"
              "with tango_aio.sync.connect('sim://?baud=0') as tango:\n"
              "    loop = tango.portal.portal.call(asyncio.get_running_loop)\n"
              "    print(type(loop).__module__, tango.get('vel')['x'])\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            timeout=60, check=False,
                            env={**os.environ, "TANGO_AIO_LOOP": "uvloop"})
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["uvloop", "10.0"]


def test_ctrl_c_during_a_blocking_group_move_stops_every_member() -> None:
    specs = {"stage": INSTANT, "focus": "sim://?baud=0&axes=1"}
    with tango_aio.sync.ControllerGroup(specs) as group:
        for member in group.values():
            member.set("vel", x=0.5)
        moving = lambda: all(member.status()["x"] == "M" for member in group.values())  # noqa: E731
        with _ctrl_c_once(moving), pytest.raises(KeyboardInterrupt):
            group.move_to({"stage": {"x": 100.0}, "focus": {"x": 100.0}})
        for member in group.values():
            assert "M" not in member.status().values()
            assert 0 < member.position()["x"] < 100
