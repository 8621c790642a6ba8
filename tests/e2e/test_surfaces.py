"""No false success through any surface (#26): a cross-surface matrix.

Rows are surfaces (the async driver, ``tango_aio.sync``, the shell's script mode,
``tango-aio move``, a Bluesky plan on ``tango_aio.bluesky``); columns are the ways a
move can end (:data:`ENDINGS`). Each cell drives one move of X through its surface into
one ending, then checks two things:

* the outcome the surface reported is the real one: a success only when the emulator's
  own state says X stands at its target; every other ending is reported as a failure
  (an exception, a non-zero exit);
* a position read through the surface after the call ended equals where the emulator's
  X really stands (when the surface gives one).

A new surface (a Bluesky plan, the EPICS IOC through a CA client) adds a row: a function
``(ending, stage) -> Outcome`` registered in :data:`ROWS`, using :class:`Ending`'s
``settings``/``extra``/``disturb`` as the other rows do. The default run takes every
column of the async row and two of the sync row; the whole matrix runs under ``slow``.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pytest
from helpers import Emulated, PtySim, abort_from_outside, ctrl_c_when, one_axis

import tango_aio
import tango_aio.sync
from tango_aio.errors import ConnectionLostError, ControllerError, MoveError
from tango_aio.testing import faults

CLI = [sys.executable, "-m", "tango_aio"]
INSTANT = "sim://?baud=0"

#: Every stage is made fast (100 mm/s, 20 m/s^2) for the cells whose move must end
#: quickly; the cells that disturb a running move use 10 mm/s (a 40 mm move: 4 s).
FAST = {"secvel": 100, "vel": 100, "accel": 20, "stopaccel": 20}
SLOW = {"secvel": 10, "vel": 10, "accel": 20, "stopaccel": 20}


class Kind(enum.Enum):
    """What the emulator must show after a cell, and what the surface must report."""

    ARRIVES = "arrives"  # at the target: success
    FAILS = "fails"  # stands short of the target: a failure, never a success
    LOST = "lost"  # the link is gone: a failure; the stage may still be moving


@dataclass(frozen=True)
class Ending:
    """One way a move of X ends (a column).

    ``target``: where X is sent (from 0). ``settings``: per-axis settings made before the
    move (``FAST`` or ``SLOW``; ``extra`` lines after them). ``disturb``: what happens
    while X moves: ``""`` nothing, ``"abort"`` another client stops every axis (``a``,
    L6785-6844), ``"interrupt"`` the caller gives up (Ctrl+C, a cancelled task),
    ``"cut"`` the link is cut.
    """

    name: str
    target: float
    kind: Kind
    settings: dict[str, int]
    extra: tuple[str, ...] = ()
    disturb: str = ""
    axis: str = "x"


ENDINGS = [
    Ending("target", 5.0, Kind.ARRIVES, FAST),
    # The upper switch is at +50 mm (the emulator's default).
    Ending("limit_switch", 60.0, Kind.FAILS, FAST),
    # `!axis y 0` disables Y (L2711: its status letter reads "-"); a move of Y.
    Ending("disabled_axis", 5.0, Kind.FAILS, FAST, ("!axis y 0",), axis="y"),
    Ending("abort_by_other", 40.0, Kind.FAILS, SLOW, disturb="abort"),
    Ending("interrupt", 40.0, Kind.FAILS, SLOW, disturb="interrupt"),
    Ending("link_lost", 40.0, Kind.LOST, SLOW, disturb="cut"),
    # Soft limits at +-10 mm, enforced: the controller refuses the line (error 5).
    Ending("refused_line", 20.0, Kind.FAILS, FAST, ("!lim x -10 10", "!limctr x 1")),
]


@dataclass
class Outcome:
    """What a surface reported for a cell."""

    ok: bool
    #: The position of the moved axis read through the surface after the call, if any.
    readback: float | None
    detail: str


@dataclass
class Truth:
    """The emulator's own state after a cell."""

    position: float
    moving: bool


def _setup_lines(ending: Ending) -> list[str]:
    lines = [f"!{name} {' '.join(str(value) for value in (v, v, v))}"
             for name, v in ending.settings.items()]
    return lines + list(ending.extra)


def check(ending: Ending, outcome: Outcome, truth: Truth) -> None:
    """The cell's verdict: the reported outcome is the real one."""
    at_target = not truth.moving and abs(truth.position - ending.target) < 1e-3
    if ending.kind is Kind.ARRIVES:
        assert outcome.ok and at_target, (outcome, truth)
    else:
        assert not outcome.ok, (outcome, truth)
        if ending.kind is Kind.FAILS:
            assert not at_target and not truth.moving, (outcome, truth)
    if outcome.readback is not None and not truth.moving:
        assert outcome.readback == pytest.approx(truth.position, abs=1e-3), (outcome, truth)
    if outcome.ok:
        assert outcome.readback is not None  # a success must be readable


# -- the async driver ----------------------------------------------------------------


async def _prepared(ending: Ending) -> Emulated:
    emu = Emulated(await tango_aio.connect(INSTANT))
    for line in _setup_lines(ending):
        await emu.tango.command(line)
    return emu


def _truth(emu: Emulated, axis: str) -> Truth:
    motion = emu.model.motion
    return Truth(motion.to_user(axis, motion.position(axis)), motion.is_moving(axis))


async def _wait_moving(emu: Emulated, axis: str) -> None:
    for _ in range(2000):
        if emu.model.motion.is_moving(axis):
            return
        await asyncio.sleep(0.002)
    raise AssertionError(f"{axis} did not start moving")


async def async_row(ending: Ending) -> tuple[Outcome, Truth]:
    """``await tango.move_to(...)``; the interrupt is a cancelled task."""
    emu = await _prepared(ending)
    tango = emu.tango
    try:
        move = asyncio.ensure_future(tango.move_to(**one_axis(ending.axis, ending.target)))
        if ending.disturb:
            await _wait_moving(emu, ending.axis)
            if ending.disturb == "abort":
                abort_from_outside(emu)
            elif ending.disturb == "interrupt":
                move.cancel()
            else:
                faults(tango).disconnect()
        try:
            await move
            outcome = Outcome(True, None, "returned")
        except (MoveError, ControllerError, ConnectionLostError,
                asyncio.CancelledError) as error:
            outcome = Outcome(False, None, repr(error))
        truth = _truth(emu, ending.axis)
        if tango.connected:
            outcome.readback = (await tango.position())[ending.axis]
        return outcome, truth
    finally:
        await tango.aclose()


# -- tango_aio.sync ------------------------------------------------------------------


def sync_row(ending: Ending) -> tuple[Outcome, Truth]:
    """``tango.move_to(...)`` of the blocking API; the interrupt is a real Ctrl+C."""
    with tango_aio.sync.connect(INSTANT) as tango:
        for line in _setup_lines(ending):
            tango.command(line)
        emu = Emulated(tango.aio)

        def moving() -> bool:
            return emu.model.motion.is_moving(ending.axis)

        def disturb() -> None:
            while not moving():
                time.sleep(0.002)
            if ending.disturb == "abort":
                tango.portal.portal.call(abort_from_outside, emu)
            else:
                tango.portal.portal.call(faults(tango.aio).disconnect)

        helper = None
        if ending.disturb in ("abort", "cut"):
            helper = _thread(disturb)
        interrupt = (ctrl_c_when(moving) if ending.disturb == "interrupt"
                     else contextlib.nullcontext())
        try:
            with interrupt:
                tango.move_to(**one_axis(ending.axis, ending.target))
            outcome = Outcome(True, None, "returned")
        except (MoveError, ControllerError, ConnectionLostError, KeyboardInterrupt) as error:
            outcome = Outcome(False, None, repr(error))
        finally:
            if helper is not None:
                helper.join()
        truth = tango.portal.call(_async_truth, emu, ending.axis)
        if tango.connected:
            outcome.readback = tango.position()[ending.axis]
        return outcome, truth


async def _async_truth(emu: Emulated, axis: str) -> Truth:
    return _truth(emu, axis)


def _thread(target: Callable[[], None]) -> threading.Thread:
    thread = threading.Thread(target=target)
    thread.start()
    return thread


# -- the CLI: an emulator in a process of its own --------------------------------------


class TcpSim(PtySim):
    """``tango-aio sim --tcp 127.0.0.1:0``: one shared controller; a new connection takes
    the controller over and closes the previous one (a lost link for that one)."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen([*CLI, "sim", "--tcp", "127.0.0.1:0", "--baud", "0"],
                                     stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()


def _on_stage(url: str, *lines: str) -> None:
    """Send ``lines`` to the emulator on a connection of its own."""
    async def run() -> None:
        async with tango_aio.connect(url) as tango:
            for line in lines:
                await tango.command(line)
    asyncio.run(run())


def _stage_truth(url: str, axis: str) -> Truth:
    async def run() -> Truth:
        async with tango_aio.connect(url) as tango:
            before = (await tango.position())[axis]
            await asyncio.sleep(0.05)
            after = (await tango.position())[axis]
            moving = (await tango.status()).get(axis) == "M" or before != after
            return Truth(after, moving)
    return asyncio.run(run())


def _run_cli(args: list[str], ending: Ending, url: str, script: str | None
             ) -> subprocess.CompletedProcess[str]:
    """Run the CLI; disturb it once it has written its move line (seen in the ``-v``
    trace on stderr)."""
    proc = subprocess.Popen([*CLI, "-v", *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdin is not None and proc.stderr is not None
    if script is not None:
        proc.stdin.write(script)
        proc.stdin.flush()
    if not ending.disturb:
        out, err = proc.communicate(timeout=60)  # closes stdin: the script ends
        return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
    seen = ""
    deadline = time.monotonic() + 30
    while f"b'!moa {ending.axis}" not in seen and "b'!moa " not in seen:
        assert time.monotonic() < deadline, seen
        line = proc.stderr.readline()
        assert line, seen
        seen += line
    time.sleep(0.3)  # under way
    if ending.disturb == "abort":
        other = os.open(url, os.O_WRONLY | os.O_NOCTTY)  # a second host on the line
        try:
            os.write(other, b"a\r")
        finally:
            os.close(other)
    elif ending.disturb == "interrupt":
        proc.send_signal(signal.SIGINT)
    else:  # a second connection takes the TCP emulator over: this link is lost
        _stage_truth(url, ending.axis)
    out, err = proc.communicate(timeout=60)  # the script ends here (after `wait`)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, seen + err)


def _sim_for(ending: Ending) -> PtySim:
    return TcpSim() if ending.disturb == "cut" else PtySim()


def _last_position(out: str, axis: str) -> float | None:
    """The position of ``axis`` in the last ``?pos`` reply of a shell script's output."""
    index = "xyz".index(axis)
    for line in reversed(out.splitlines()):
        words = line.split()
        if len(words) == 3 and all(w.replace(".", "").replace("-", "").isdigit()
                                   for w in words):
            return float(words[index])
    return None


def shell_row(ending: Ending) -> tuple[Outcome, Truth]:
    """``printf '!moa ...\\nwait\\n?pos\\n' | tango-aio shell URL``."""
    with _sim_for(ending) as sim:
        _on_stage(sim.path, *_setup_lines(ending))
        line = f"!moa {ending.axis} {ending.target:g}"
        result = _run_cli(["shell", sim.path], ending, sim.path, f"{line}\nwait\n?pos\n")
        truth = _stage_truth(sim.path, ending.axis)
    ok = result.returncode == 0
    readback = _last_position(result.stdout, ending.axis)
    return Outcome(ok, readback, result.stdout + result.stderr[-2000:]), truth


def move_row(ending: Ending) -> tuple[Outcome, Truth]:
    """``tango-aio move URL x=...``; it prints the position after a success."""
    with _sim_for(ending) as sim:
        _on_stage(sim.path, *_setup_lines(ending))
        result = _run_cli(["move", sim.path, f"{ending.axis}={ending.target:g}"], ending,
                          sim.path, None)
        truth = _stage_truth(sim.path, ending.axis)
    ok = result.returncode == 0
    readback = None
    if ok:
        words = result.stdout.split()
        readback = float(words[words.index(f"{ending.axis}=") + 1])
    return Outcome(ok, readback, result.stdout + result.stderr[-2000:]), truth


# -- a Bluesky plan (tango_aio.bluesky) ---------------------------------------------------------


def bluesky_row(ending: Ending) -> tuple[Outcome, Truth]:
    """A plan that moves the axis (``bps.mv``) and reads it, on a MarzhauserStage; the
    interrupt is Ctrl+C as the RunEngine takes it: a pause, then ``RE.abort()``. A
    success is a run whose stop document says "success"."""
    pytest.importorskip("bluesky")
    pytest.importorskip("ophyd_async")
    import bluesky.plan_stubs as bps
    from bluesky import RunEngine, RunEngineInterrupted
    from bluesky.run_engine import call_in_bluesky_event_loop
    from ophyd_async.core import init_devices

    from tango_aio.bluesky import MarzhauserStage

    loop = asyncio.new_event_loop()
    engine = RunEngine({}, loop=loop, context_managers=[])
    stops: list[str] = []
    engine.subscribe(lambda name, doc: stops.append(doc["exit_status"])
                     if name == "stop" else None)

    def call(coro: Any) -> Any:
        return call_in_bluesky_event_loop(coro, timeout=30)

    try:
        with init_devices():
            stage = MarzhauserStage(INSTANT, axes="xy")
        for line in _setup_lines(ending):
            call(stage.controller.command(line))
        emu = Emulated(stage.controller)
        axis = stage.axis(ending.axis)

        async def abort() -> None:
            abort_from_outside(emu)

        async def cut() -> None:
            faults(stage.controller).disconnect()

        def disturb() -> None:
            for _ in range(5000):
                if emu.model.motion.is_moving(ending.axis):
                    break
                time.sleep(0.002)
            if ending.disturb == "abort":
                call(abort())
            elif ending.disturb == "interrupt":
                engine.request_pause()
            else:
                call(cut())

        def plan() -> Any:
            yield from bps.open_run()
            yield from bps.mv(axis, ending.target)
            yield from bps.trigger_and_read([axis])
            yield from bps.close_run()

        helper = _thread(disturb) if ending.disturb else None
        try:
            engine(plan())
            outcome = Outcome(stops[-1:] == ["success"], None, f"stop: {stops}")
        except RunEngineInterrupted:
            engine.abort()
            outcome = Outcome(False, None, f"paused, aborted: {stops}")
        except Exception as error:
            outcome = Outcome(False, None, repr(error))
        finally:
            if helper is not None:
                helper.join()
        truth = call(_async_truth(emu, ending.axis))
        if stage.controller.connected:
            outcome.readback = call(axis.user_readback.get_value())
        call(stage.aclose())
        return outcome, truth
    finally:
        if engine.state not in ("idle", "panicked"):
            engine.halt()
        loop.call_soon_threadsafe(loop.stop)
        engine._th.join()
        loop.close()


# -- the matrix ------------------------------------------------------------------------

#: The rows: surface name -> its cell runner (async rows are coroutine functions).
ROWS: dict[str, Callable[[Ending], object]] = {
    "async": async_row, "sync": sync_row, "shell_script": shell_row, "move": move_row,
    "bluesky": bluesky_row}

#: The cells of the default run (the rest run under ``slow``).
#: (The CLI rows cost 3-4 s a cell on a loaded machine; tests/e2e/test_cli_exit.py
#: samples them in the default run.)
QUICK = {("async", e.name) for e in ENDINGS} | {("sync", "limit_switch"),
                                               ("sync", "interrupt"),
                                               ("bluesky", "limit_switch"),
                                               ("bluesky", "interrupt")}


def _cells(rows: list[str]) -> list[object]:
    return [pytest.param(row, ending, id=f"{row}-{ending.name}",
                         marks=() if (row, ending.name) in QUICK else (pytest.mark.slow,))
            for row in rows for ending in ENDINGS]


@pytest.mark.parametrize(("row", "ending"), _cells(["async"]))
async def test_async_cell(row: str, ending: Ending) -> None:
    check(ending, *await async_row(ending))


@pytest.mark.parametrize(("row", "ending"),
                         _cells(["sync", "shell_script", "move", "bluesky"]))
def test_blocking_cell(row: str, ending: Ending) -> None:
    """Run in the main thread: the sync row's Ctrl+C is a real SIGINT."""
    run = {"sync": sync_row, "shell_script": shell_row, "move": move_row,
           "bluesky": bluesky_row}[row]
    check(ending, *run(ending))
