"""The fault matrix and the randomized soak: the first rule under line faults.

A *cell* is an autostatus mode (0-4) × a line fault × an operation, run against a firmware
variant (:func:`tango_aio.sim.profiles.variants`) on the in-process emulator (``baud=0``)
or on the pty emulator at 57600 Bd. One run of a cell: connect, give every (setting,
axis) a distinct value (saved, so that a power cycle brings the same values back), arm the
fault, run the operation, judge each outcome against the emulator's own state
(:mod:`faultverdict`), then run the same operation again without a fault: the call after
the faulted one must work.

Faults (:class:`tango_aio.testing.Faults` and :class:`tango_aio.sim.wire.Wire`; the
``k``-th reply after arming, ``k`` drawn per run):

* ``drop``: the ``k``-th reply is lost;
* ``lose``: the operation's line (a read, ``!vel``, the move line, ``!speed``, a list
  entry) never reaches the controller;
* ``extra``: a well-formed line (``OK...``, a report; on the pty also a number or
  ``0``) follows the ``k``-th reply;
* ``garble``: one bit of the ``k``-th reply flips;
* ``noise``: bytes without a CR arrive before the operation and join its first reply:
  junk on the instant link; a digit on the paced pty, where the link's timing can show
  that they came before the request could have been answered;
* ``junk``: junk bytes glued in front of the ``k``-th reply;
* ``cycle_idle``: the controller is switched off and on again just before the operation;
* ``cycle_moving``: the same while a move runs (the operation's own, or one started
  before it).

Operations: four pipelined look-alike reads (``?vel y``, ``?accel x``...), a set
(``vel`` of one axis), a move of two axes, ``speed`` on one axis, a list upload
(trigger positions; snapshot rows on the older instruction set).

The default run takes :data:`SAMPLE`: a few cells, each on one variant chosen by a
seeded draw. Under ``slow``: every cell at ``baud=0`` against ``manual`` and two more
variants in turn, so that every variant meets every mode (``TANGO_AIO_MATRIX_ALL=1``:
every cell against every variant, about an hour), and every cell over the pty at 57600 Bd
against ``manual`` or ``legacy``. Switches a unit may combine (:data:`COMBINED`) run
every cell of the mode they act in on their own (a sample by default, every cell with
four seeds under ``slow``) and a soak of their own. Counts per cell are printed and
written to ``$TANGO_AIO_RELIABILITY_DIR/tango_aio_reliability_matrix.json``; the soak
writes ``tango_aio_reliability_soak.json``.

Cells that fail on today's code because of a known failure carry ``xfail(strict=True)``
naming it (:data:`KNOWN`).
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import logging
import math
import os
import random
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import pytest
from faultverdict import (
    DONE,
    NEXT_CALL_FAILED,
    OWN,
    Hang,
    done_verdict,
    error_verdict,
    is_bad,
    read_verdict,
    running_verdict,
)
from helpers import as_axes, posix_only, serve_pty, wait_until

from tango_aio.catalog._instructions import parse
from tango_aio.controller._connection import connect
from tango_aio.controller._controller import Controller
from tango_aio.errors import TangoError
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import PROFILES, Firmware, variants
from tango_aio.sim.wire import Wire, WireConfig, flip_one_bit
from tango_aio.testing import faults

pytestmark = [pytest.mark.timeout(3600), pytest.mark.virtual_clock]

T = TypeVar("T")

MODES = (0, 1, 2, 3, 4)
FAULTS = ("drop", "lose", "extra", "garble", "noise", "junk", "cycle_idle", "cycle_moving")
OPS = ("reads", "set", "move", "speed", "upload")

#: Distinct per (setting, axis), no two within one character of each other: a reply
#: handed to the wrong caller, or a one-bit error, shows.
DISTINCT = {"vel": {"x": 95.5, "y": 96.25, "z": 97.125},
            "accel": {"x": 18.5, "y": 19.25, "z": 17.75}}
#: What the set operation writes (the faulted call, then the call after it).
NEW_VEL = ({"x": 93.375, "y": 92.625, "z": 91.875}, {"x": 94.75, "y": 98.5, "z": 90.25})
#: The look-alike reads: each answers one number.
LOOK_ALIKE = tuple(f"?{name} {axis}" for name in DISTINCT for axis in "xyz")
#: Well-formed lines a controller could send unasked (``extra``). A number that lands
#: where a read's reply is due (behind a separator's reply) is that reply to every rule but
#: the link's timing: it is sent only where the link is paced (the pty).
EXTRA_LINES = (b"OK...\r", b"@@@-.\r")
EXTRA_NUMBERS = (b"88.875\r", b"0\r")
#: How many replies the fault may skip before it strikes, per operation.
REPLIES = {"reads": 6, "set": 2, "move": 3, "speed": 2, "upload": 8}

#: Reply timeout while a fault is armed (a lost reply costs this); the calls around it
#: have :data:`REPLY_TIMEOUT`. Neither is asserted on: a timeout is a typed outcome.
FAULT_TIMEOUT = 0.3
REPLY_TIMEOUT = 3.0
#: Seconds without a result after which a call counts as hung: generous, it only
#: catches hangs.
HANG_BOUND = 60.0
#: Seconds a power-cycled controller stays off.
OFF = 0.2
#: Velocity (mm/s) of X when a move must still run while the power goes (cycle_moving).
SLOW = 20.0


def _report_dir() -> Path:
    return Path(os.environ.get("TANGO_AIO_RELIABILITY_DIR", tempfile.gettempdir()))


#: Outcome counts per cell, written at the end of the module.
COUNTS: defaultdict[str, Counter[str]] = defaultdict(Counter)


@pytest.fixture(scope="module", autouse=True)
def _report_counts() -> Iterator[None]:
    yield
    if not COUNTS:
        return
    data = {cell: dict(sorted(c.items())) for cell, c in sorted(COUNTS.items())}
    path = _report_dir() / "tango_aio_reliability_matrix.json"
    path.write_text(json.dumps(data, indent=2) + "\n")
    print(f"\n--- fault matrix counts (also in {path}) ---")
    for cell, counter in data.items():
        print(f"{cell}: " + ", ".join(f"{k}={v}" for k, v in counter.items()))


# --------------------------------------------------------------------------------------
# The rig: a controller, its emulator, and the faults


@dataclass
class Rig:
    """One connected controller and the emulator behind it."""

    tango: Controller
    wire: Wire
    firmware: Firmware
    timed: bool  # the link is paced (57600 Bd): its timing is evidence
    rng: random.Random
    counts: Counter[str]
    #: Why each bad verdict happened (cell-run details), for the failure message.
    bad: list[str] = field(default_factory=list)
    #: The call after a faulted one: any error is bad too.
    strict: bool = False
    #: When a power-cycled controller is on again (the loop's clock).
    on_at: float = 0.0

    @property
    def model(self) -> ControllerModel:
        handler = self.wire.handler
        assert isinstance(handler, ControllerModel)
        return handler

    @property
    def present(self) -> str:
        return "xyza"[: self.model.axes]

    def truth(self, line: str) -> str:
        """What the emulator answers to ``line`` now (its own formatter)."""
        model = self.model
        text = model.params.read(parse(line, model.context()), model.axes)
        # Switch numbers=plus: "+" before a positive number (every value read here is one).
        return f"+{text}" if self.firmware.numbers == "plus" else text

    def stored(self, name: str, axis: str) -> float:
        return self.model.params.number(name, "xyza".index(axis))

    def moving(self, axis: str) -> bool:
        return self.model.motion.is_moving(axis)

    def axis_state(self, axis: str) -> tuple[float, float]:
        wire, model = self.wire, self.model
        now = wire.clock() if wire.clock is not None else wire.now
        return model.motion.observe("xyza".index(axis), now)

    def record(self, what: str, verdict: str, detail: object = "") -> None:
        self.counts[f"{what}: {verdict}"] += 1
        if is_bad(verdict) or (self.strict and verdict not in (OWN, DONE)):
            self.bad.append(f"{what}: {verdict} {detail}".rstrip())

    def set_timeout(self, seconds: float) -> None:
        self.tango.reply_timeout = self.tango.protocol.reply_timeout = seconds


async def bounded(call: Awaitable[T]) -> T:
    """Await ``call``; :class:`Hang` if it gives no result within :data:`HANG_BOUND`."""
    try:
        async with asyncio.timeout(HANG_BOUND):
            return await call
    except TimeoutError as exc:
        if isinstance(exc, TangoError):
            raise
        raise Hang(f"no result within {HANG_BOUND} s") from exc


async def outcome(call: Awaitable[T]) -> T | BaseException:
    """The call's result, or the exception it raised (cancellation passes)."""
    try:
        return await bounded(call)
    except asyncio.CancelledError:
        raise
    except Exception as exc:  # judged by the verdicts: typed, untyped or a hang
        return exc


def _query(variant: str) -> str:
    return f"profile={variant}" if variant in PROFILES else f"profile=manual&{variant}"


@contextlib.asynccontextmanager
async def opened_rig(variant: str, mode: int, *, pty: bool, seed: int,
                     counts: Counter[str], state: Path) -> AsyncIterator[Rig]:
    """A controller in ``mode`` on a fresh emulator of ``variant`` (in-process at
    ``baud=0``, or over a pty at 57600 Bd), every (setting, axis) distinct and saved."""
    firmware = firmware_of(variant)
    server = None
    if pty:
        def factory(emit: Callable[[bytes], None]) -> ControllerModel:
            return ControllerModel(emit, SimConfig(firmware=firmware, state_file=state))

        server = await serve_pty(factory, WireConfig(baud=57600))
        url = server.path
    else:
        url = f"sim://?baud=0&{_query(variant)}&state={state}&seed={seed}"
    try:
        tango = await bounded(connect(url, autostatus=mode, reply_timeout=REPLY_TIMEOUT))
        try:
            wire = server.wire if server is not None else faults(tango).wire
            rig = Rig(tango, wire, firmware, pty, random.Random(seed), counts)
            present = rig.present
            await bounded(tango.set("secvel", **as_axes(dict.fromkeys(present, 100.0))))
            await bounded(tango.set("stopaccel", **as_axes(dict.fromkeys(present, 20.0))))
            for name, values in DISTINCT.items():
                await bounded(tango.set(name, **as_axes(values)))
            rig.model.save()  # the emulator's eeprom: a power cycle brings them back
            yield rig
        finally:
            await tango.aclose()
    finally:
        if server is not None:
            server.close()
            await server.wait_closed()


class Armed:
    """A fault armed on the emulator's output: the ``k``-th reply from now changed by
    ``change`` (an empty result drops it)."""

    def __init__(self, rig: Rig, k: int, change: Callable[[bytes], bytes]) -> None:
        self.fired = False
        index = 0

        def garbler(data: bytes, rng: random.Random) -> bytes:
            nonlocal index
            index += 1
            if index != k:
                return data
            self.fired = True
            return change(data)

        rig.wire.faults.garbler = garbler
        rig.wire.faults.garble_replies = k


def arm(rig: Rig, fault: str, op: str, lines: list[str]) -> Armed | None:
    """Arm ``fault`` for operation ``op`` (``lines``: the reads it makes). The power
    cycles are not armed here (:func:`run_once` switches the power)."""
    rng = rig.rng
    k = rng.randint(1, REPLIES[op])
    if fault == "drop":
        return Armed(rig, k, lambda _data: b"")
    if fault == "garble":
        return Armed(rig, k, lambda data: flip_in_line(data, rng))
    if fault == "extra":
        line = rng.choice(EXTRA_LINES + EXTRA_NUMBERS if rig.timed else EXTRA_LINES)
        return Armed(rig, k, lambda data: data + line)
    if fault == "junk":
        return Armed(rig, k, lambda data: b"#%" + data)
    if fault == "noise":
        rig.wire.emit(b"1" if rig.timed else b"\x15~")
        return None
    if fault == "lose":
        lost = {"reads": rng.choice(lines) if lines else "?", "set": "!vel",
                "move": "!mo", "speed": "!speed",
                "upload": "!trigp -1" if _triggers(rig) else "!snsa -1"}[op]
        rig.wire.faults.lose_line = lost.encode("ascii")
        return None
    raise AssertionError(fault)


def flip_in_line(data: bytes, rng: random.Random) -> bytes:
    """One bit flipped in the text of a reply, not in its line end: with CR LF line ends
    a flipped LF would garble the line after it (the next call's reply)."""
    text = data.rstrip(b"\r\n")
    return flip_one_bit(text, rng) + data[len(text):] if text else data


def disarm(rig: Rig) -> None:
    wire_faults = rig.wire.faults
    wire_faults.garble_replies = 0
    wire_faults.garbler = flip_one_bit
    wire_faults.drop_replies = 0
    wire_faults.lose_line = None


def _triggers(rig: Rig) -> bool:
    """The variant has the trigger list (the older instruction set has not)."""
    return rig.firmware.instruction_set == "full"


# --------------------------------------------------------------------------------------
# The operations: each runs once, judges its outcome and says whether it all held


async def op_reads(rig: Rig, lines: list[str], *, bit_flips: bool, what: str) -> None:
    results = await asyncio.gather(*(outcome(rig.tango.query(line)) for line in lines))
    for line, result in zip(lines, results, strict=True):
        own = rig.truth(line)
        others = [rig.truth(other) for other in LOOK_ALIKE if other != line]
        verdict = read_verdict(result, own, others, bit_flips=bit_flips)
        rig.record(what, verdict, f"{line} -> {result!r} (own {own!r})")


async def op_set(rig: Rig, axis: str, value: float, what: str) -> None:
    result = await outcome(rig.tango.set("vel", value, axis=axis))
    held = rig.stored("vel", axis)
    rig.record(what, done_verdict(result, math.isclose(held, value)),
               f"set vel {axis} {value} -> {result!r}, controller holds {held}")


async def op_move(rig: Rig, targets: dict[str, float], what: str,
                  started: Callable[[asyncio.Future[Any]], Awaitable[None]] | None = None
                  ) -> None:
    call = asyncio.ensure_future(rig.tango.move_to(**as_axes(targets)))
    if started is not None:
        await started(call)
    result = await outcome(call)
    await judge_motion(rig, what, result, targets)


async def judge_motion(rig: Rig, what: str, result: object,
                       targets: dict[str, float]) -> None:
    """A move that returned stands at its targets; one that raised left no axis running
    on to its target that its error does not name."""
    if not isinstance(result, BaseException):
        state = {axis: rig.axis_state(axis) for axis in targets}
        held = all(v == 0.0 and math.isclose(p, targets[a], abs_tol=1e-3)
                   for a, (p, v) in state.items())
        rig.record(what, done_verdict(result, held), f"{targets} -> {state}")
        return
    rig.record(what, error_verdict(result), repr(result))
    running = [axis for axis in targets if rig.moving(axis)]
    await settle_axes(rig)
    ran_on = [axis for axis in running
              if math.isclose(rig.axis_state(axis)[0], targets[axis], abs_tol=1e-3)]
    verdict = running_verdict(result, ran_on)
    if verdict is not None:
        rig.record(what, verdict, f"{ran_on} ran on to {targets} after {result!r}")


async def op_speed(rig: Rig, what: str) -> None:
    result = await outcome(rig.tango.speed(z=2.0))
    if not isinstance(result, BaseException):
        rig.record(what, done_verdict(result, rig.moving("z")), "speed z 2 -> not moving")
        stopped = await outcome(rig.tango.speed(z=0.0))
        if isinstance(stopped, BaseException):
            rig.record(f"{what} (its stop)", error_verdict(stopped), repr(stopped))
        await settle_axes(rig)
        return
    rig.record(what, error_verdict(result), repr(result))
    running = rig.moving("z")
    await asyncio.sleep(0.3)  # a stop ramp from 2 mm/s lasts well under a millisecond
    verdict = running_verdict(result, ["z"] if running and rig.moving("z") else [])
    if verdict is not None:
        rig.record(what, verdict, f"z still runs after {result!r}")
        stop_from_outside(rig)
    await settle_axes(rig)


async def op_upload(rig: Rig, second: bool, what: str) -> None:
    base = 1.5 if second else 0.5
    tango = rig.tango
    if _triggers(rig):
        values = [round(base + 0.0137 * i, 4) for i in range(24)]
        result = await outcome(tango.triggers.upload_positions(values))
        rows = [[value] for value in values]
        held = [[value] for value in rig.model.triggers.entries]
    else:
        rows = [[base + i, -float(i), 0.25] for i in range(1, 9)]
        result = await outcome(tango.snapshots.upload_positions(rows))
        held = [[math.nan if value is None else value for value in row]  # None: no value
                for row in rig.model.snapshots.entries]
    same = len(held) == len(rows) and all(
        len(h) == len(r) and all(math.isclose(a, b) for a, b in zip(h, r, strict=True))
        for h, r in zip(held, rows, strict=True))
    rig.record(what, done_verdict(result, same), f"{result!r}, list holds {len(held)}")


async def settle_axes(rig: Rig) -> None:
    """Wait until no axis of the emulator moves; a speed left running is stopped from the
    emulator's side (it was counted already)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + 10.0
    while any(rig.moving(axis) for axis in rig.present):
        if loop.time() > deadline:
            stop_from_outside(rig)
            deadline = loop.time() + 10.0
        await asyncio.sleep(0.005)


def stop_from_outside(rig: Rig) -> None:
    """Stop every axis as the keypad would (``a`` into the emulator's interpreter)."""
    rig.model.handle_line(b"a", asyncio.get_running_loop().time())
    if rig.wire.notify is not None:
        rig.wire.notify()


# --------------------------------------------------------------------------------------
# One run of a cell


async def run_operation(rig: Rig, op: str, fault: str | None, what: str,
                        second: bool = False) -> None:
    """Run ``op`` once (with ``fault`` armed, or none) and judge it."""
    rng = rig.rng
    lines = rng.sample(LOOK_ALIKE, 4) if op == "reads" else []
    axis = rng.choice("xyz")
    targets = {"x": round(rng.uniform(0.5, 2.0), 3) * rng.choice((-1, 1)),
               "y": round(rng.uniform(0.5, 2.0), 3) * rng.choice((-1, 1))}
    rig.set_timeout(FAULT_TIMEOUT if fault is not None else REPLY_TIMEOUT)
    cycling = fault in ("cycle_idle", "cycle_moving")
    background: asyncio.Future[Any] | None = None
    background_target = {"x": 3.0}
    if fault == "cycle_moving":
        await bounded(rig.tango.set("vel", SLOW, axis="x"))
        if op != "move":
            background = asyncio.ensure_future(rig.tango.move_to(**as_axes(background_target)))
            await until_moving(rig, "x", background)
            if not background.done():  # (one that ended first is judged where it ended)
                power_cycle(rig)
    elif fault == "cycle_idle":
        power_cycle(rig)
    elif fault is None:
        # The call after the faulted one meets neither the fault's leftovers (an extra
        # line still on its way) nor a controller that is still off.
        await drained(rig)
    armed = arm(rig, fault, op, lines) if fault is not None and not cycling else None

    async def power_goes(call: asyncio.Future[Any]) -> None:
        await until_moving(rig, "x", call)
        if not call.done():
            # A move that returned first is judged where it ended: a restart after it
            # puts the positions to 0 (L1837-1857), which is no verdict on the move.
            power_cycle(rig)

    if op == "reads":
        await op_reads(rig, lines, bit_flips=fault == "garble", what=what)
    elif op == "set":
        await op_set(rig, axis, NEW_VEL[second][axis], what)
    elif op == "move":
        await op_move(rig, targets, what,
                      power_goes if fault == "cycle_moving" else None)
    elif op == "speed":
        await op_speed(rig, what)
    else:
        await op_upload(rig, second, what)
    if background is not None:
        await judge_motion(rig, f"{what} (the move under way)", await outcome(background),
                           background_target)
    if armed is not None and not armed.fired:
        rig.counts["fault did not strike"] += 1
    disarm(rig)
    await settle_axes(rig)
    rig.set_timeout(REPLY_TIMEOUT)


async def drained(rig: Rig) -> None:
    """Wait until the emulator's link is quiet (nothing to read or to send, the
    interpreter idle) and a power-cycled controller is on again."""
    loop = asyncio.get_running_loop()
    await asyncio.sleep(max(0.0, rig.on_at - loop.time()))
    wire = rig.wire
    await wait_until(lambda: not (wire.tx_pending or wire.rx_pending or wire.busy),
                     timeout=HANG_BOUND)
    if rig.timed:
        await asyncio.sleep(0.02)  # the pty's bytes reach the driver's reader


def power_cycle(rig: Rig) -> None:
    """Switch the controller off for :data:`OFF` seconds, now."""
    rig.wire.power_cycle(OFF)
    rig.on_at = asyncio.get_running_loop().time() + OFF + 0.01


async def until_moving(rig: Rig, axis: str, call: asyncio.Future[Any] | None) -> None:
    """Return once ``axis`` moves in the emulator (or ``call`` ended first)."""
    async with asyncio.timeout(HANG_BOUND):
        while not rig.moving(axis):
            if call is not None and call.done():
                return
            await asyncio.sleep(0.001)


async def run_cell(mode: int, fault: str, op: str, variant: str, *, pty: bool, seed: int,
                   counts: Counter[str], state: Path) -> list[str]:
    """One run of a cell; the bad verdicts, each with what happened."""
    async with opened_rig(variant, mode, pty=pty, seed=seed, counts=counts,
                          state=state) as rig:
        await run_operation(rig, op, fault, op)
        await next_call(rig, op)
        return [f"{variant} seed {seed}: {b}" for b in rig.bad]


async def next_call(rig: Rig, op: str, second: bool = True) -> None:
    """The call after the faulted one (the same operation, no fault) works."""
    before = len(rig.bad)
    rig.strict = True
    try:
        await run_operation(rig, op, None, "next call", second=second)
    finally:
        rig.strict = False
    if len(rig.bad) > before:
        rig.record("cell", NEXT_CALL_FAILED)


# --------------------------------------------------------------------------------------
# The cells and the failures known on today's code


_NOISE_AFTER_WRITE = ("#37, timing as evidence: noise glued to a reply after its request "
                      "was written fits the reply's shape; a serial link gives no timing "
                      "to tell it")
_EXTRA_NUMBER = ("#37, timing as evidence: an extra number line where a read's reply is "
                 "due is taken for it; whether the link's timing can show it is open")

#: Cells that fail on today's code, by (mode, fault, op, transport), with the failure of
#: issue #37 that makes them fail (checked on every run of the cell: ``strict``).
KNOWN: dict[tuple[int, str, str, str], str] = {
}

#: Cells over the pty that fail on some runs of today's code only (the timing of an
#: extra line against the reads), or that a fix may leave failing: ``xfail`` without
#: ``strict``.
SOMETIMES: dict[tuple[int, str, str, str], str] = {
    # An extra number where a read's reply is due: the line's structure cannot tell it
    # from the reply; the link's timing may (in mode 4 replies shift as well).
    **{(mode, "extra", "reads", "pty"): _EXTRA_NUMBER for mode in (0, 3, 4)},
    # Noise that reaches the pty after the read was written: it joins the reply, and a
    # serial link gives no timing to tell it (RELIABILITY.md, "What the driver can and
    # cannot detect"); caught only when it came before the write.
    **{(mode, "noise", "reads", "pty"): _NOISE_AFTER_WRITE for mode in (2, 4)},
}


#: The default run's cells, each against one variant drawn by its seed: every mode, fault
#: and operation once, none of them failing on today's code.
SAMPLE = ((0, "garble", "reads"), (1, "lose", "move"), (2, "extra", "set"),
          (3, "junk", "speed"), (4, "noise", "upload"), (1, "drop", "reads"),
          (4, "cycle_idle", "reads"), (2, "cycle_moving", "move"))


def _cells() -> list[tuple[int, str, str]]:
    return [(mode, fault, op) for mode in MODES for fault in FAULTS for op in OPS]


def _params(transport: str) -> list[Any]:
    out = []
    for cell in _cells():
        mode, fault, op = cell
        marks: list[pytest.MarkDecorator] = []
        if transport == "pty" or cell not in SAMPLE:
            marks.append(pytest.mark.slow)
        key = (mode, fault, op, transport)
        if transport == "pty" or cell not in SAMPLE:
            if key in KNOWN:
                marks.append(pytest.mark.xfail(strict=True, reason=KNOWN[key]))
            elif key in SOMETIMES:
                marks.append(pytest.mark.xfail(strict=False, reason=SOMETIMES[key]))
        out.append(pytest.param(mode, fault, op, id=f"{transport}-{mode}-{fault}-{op}",
                                marks=marks))
    return out


#: Switch values the manual leaves open that a real unit may combine, where no single
#: variant shows what they do together: mode 2's acknowledged reads with a move's
#: ``OK...`` at its completion (L2099-2103), mode 4's echo at a move's completion with
#: each other echo switch (L2117, L2168, old L723). Named ``switch=value&switch=value``.
COMBINED = ("ack_reads=before&move_ok=completion", "ack_reads=after&move_ok=completion",
            "echo=completion&echo_report=no", "echo=completion&echo_all=yes",
            "echo=completion&echo_text=normalized", "echo=completion&echo_text=nobang")

#: Every variant, ``manual`` first, then the combined ones.
VARIANTS = [*(name for name, _ in variants()), *COMBINED]


def firmware_of(variant: str) -> Firmware:
    """The firmware of a variant of :func:`variants` or of :data:`COMBINED`."""
    if variant in PROFILES:
        return PROFILES[variant]
    return Firmware().with_(**dict(pair.split("=", 1) for pair in variant.split("&")))


def cell_runs(mode: int, fault: str, op: str, transport: str, slow: bool
              ) -> list[tuple[str, int]]:
    """The (variant, seed) runs of a cell. The default run: one variant, drawn by the
    cell's seed. ``slow``: ``manual`` and two more in turn, so that every variant meets
    every mode (``TANGO_AIO_MATRIX_ALL=1``: every variant); over the pty, ``manual`` or
    ``legacy`` in turn."""
    seed = mode * 1000 + FAULTS.index(fault) * 10 + OPS.index(op)
    index = FAULTS.index(fault) * len(OPS) + OPS.index(op)
    if transport == "pty":
        chosen = [VARIANTS[index % 2]]
    elif not slow:
        chosen = [random.Random(seed).choice(VARIANTS)]
    elif os.environ.get("TANGO_AIO_MATRIX_ALL") == "1":
        chosen = VARIANTS
    else:
        others = VARIANTS[1:]
        chosen = [VARIANTS[0], *(others[(2 * index + i) % len(others)] for i in (0, 1))]
    return [(variant, seed + 100 * i) for i, variant in enumerate(chosen)]


async def _check_cell(request: pytest.FixtureRequest, tmp_path: Path, mode: int,
                      fault: str, op: str, transport: str) -> None:
    slow = request.node.get_closest_marker("slow") is not None
    counts = COUNTS[f"{transport} mode {mode} {fault} {op}"]
    bad: list[str] = []
    for index, (variant, seed) in enumerate(cell_runs(mode, fault, op, transport, slow)):
        bad += await run_cell(mode, fault, op, variant, pty=transport == "pty", seed=seed,
                              counts=counts, state=tmp_path / f"{index}.json")
        counts["runs"] += 1
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(("mode", "fault", "op"), _params("sim"))
async def test_fault_matrix(request: pytest.FixtureRequest, tmp_path: Path, mode: int,
                            fault: str, op: str) -> None:
    await _check_cell(request, tmp_path, mode, fault, op, "sim")


@pytest.mark.parametrize(("mode", "fault", "op"), _params("pty"))
async def test_fault_matrix_pty(request: pytest.FixtureRequest, tmp_path: Path, mode: int,
                                fault: str, op: str) -> None:
    posix_only("the pty emulator at 57600 Bd")
    await _check_cell(request, tmp_path, mode, fault, op, "pty")


#: The mode each combined variant's switches act in (elsewhere they change nothing).
COMBINED_MODE = {name: 4 if name.startswith("echo=") else 2 for name in COMBINED}
#: The combined cells of the default run: a move's acknowledgement or echo lost, garbled
#: or cut off by a power cycle, and a read's acknowledgement lost, on each combination.
COMBINED_SAMPLE = (("lose", "move"), ("garble", "move"), ("cycle_moving", "speed"),
                   ("drop", "reads"))
#: Seeds of each combined cell under ``slow``.
COMBINED_SEEDS = 4


def _combined_params() -> list[Any]:
    return [pytest.param(variant, fault, op, id=f"{variant}-{fault}-{op}",
                         marks=[] if (fault, op) in COMBINED_SAMPLE else [pytest.mark.slow])
            for variant in COMBINED for fault in FAULTS for op in OPS]


@pytest.mark.parametrize(("variant", "fault", "op"), _combined_params())
async def test_fault_matrix_on_combined_switches(
        request: pytest.FixtureRequest, tmp_path: Path, variant: str, fault: str, op: str
        ) -> None:
    """Every cell of the mode a :data:`COMBINED` variant's switches act in, on that
    variant (one seed in the default run, :data:`COMBINED_SEEDS` under ``slow``)."""
    mode = COMBINED_MODE[variant]
    slow = request.node.get_closest_marker("slow") is not None
    counts = COUNTS[f"sim mode {mode} {fault} {op} {variant}"]
    base = 7000 + FAULTS.index(fault) * 10 + OPS.index(op)
    bad: list[str] = []
    for i in range(COMBINED_SEEDS if slow else 1):
        bad += await run_cell(mode, fault, op, variant, pty=False, seed=base + 100 * i,
                              counts=counts, state=tmp_path / f"{i}.json")
        counts["runs"] += 1
    assert not bad, "\n".join(bad)


#: Combined-switch runs that failed before the core told a move's deferred ``OK...``
#: from the ``OK...`` of the ``?err`` behind it (reads acknowledged before their data,
#: ``move_ok=completion``): every move put the stream out of step, and after a fault the
#: call after it timed out. The last two failed also while a mode read took the move's
#: ``OK...`` that came with its report after the help reply for reads acknowledged after
#: their data (:func:`~tango_aio.sansio._exchange.reads_acknowledged`).
COMBINED_FAILURES = [
    pytest.param("cycle_moving", "reads", 7070, id="cycle-moving-reads"),
    pytest.param("extra", "move", 7122, id="extra-move"),
    pytest.param("drop", "move", 7302, id="drop-move"),
    pytest.param("junk", "move", 7152, id="junk-move"),
]


@pytest.mark.parametrize(("fault", "op", "seed"), COMBINED_FAILURES)
async def test_the_call_after_a_fault_with_reads_acknowledged_and_moves_at_completion(
        tmp_path: Path, fault: str, op: str, seed: int) -> None:
    counts: Counter[str] = Counter()
    bad = await run_cell(2, fault, op, "ack_reads=before&move_ok=completion", pty=False,
                         seed=seed, counts=counts, state=tmp_path / "state.json")
    assert not bad, "\n".join(bad)


#: Mode 2 on firmware that acknowledges reads after their data (``ack_reads=after``): a
#: unit back in its power-on mode 1 answers the resync marker without the ``OK...``
#: behind it, which must not keep the restart check from reading the mode. The reads
#: after an idle power cycle run in the default tier, the other cells under ``slow``.
_RESTART_ACK_AFTER = [
    pytest.param(op, fault, id=f"{op}-{fault}",
                 marks=[] if (op, fault) == ("reads", "cycle_idle") else [pytest.mark.slow])
    for op in ("reads", "speed") for fault in ("cycle_idle", "cycle_moving")]


@pytest.mark.parametrize(("op", "fault"), _RESTART_ACK_AFTER)
async def test_the_call_after_a_restart_in_mode_2_with_reads_acknowledged_after_data(
        tmp_path: Path, fault: str, op: str) -> None:
    counts: Counter[str] = Counter()
    bad = await run_cell(2, fault, op, "ack_reads=after", pty=False, seed=7, counts=counts,
                         state=tmp_path / "state.json")
    assert not bad, "\n".join(bad)



#: Histories the mode-2 soak drew on one connection (variant, its seed, and per run the
#: fault, the operation and which values the call after it writes), each ending in the
#: run whose next call failed. The first three: a move line lost, or its ``OK...``
#: garbled, looks like a move acknowledged only at completion (switch ``move_ok``), and
#: the acknowledgements after it were counted against an ``OK...`` that never came.
#: Reads acknowledged after their data: the last ``OK...`` in was held with nothing
#: behind it to tell whose it was, and the next move waited for it ("it was not
#: written, a reply owed before it did not come"); before their data: a later line's
#: ``OK...`` went to the phantom, and the ``?err`` behind that line waited for ever.
SOAK_HISTORIES = [
    pytest.param("ack_reads=after", 400335278,
                 (("noise", "set", False), ("lose", "reads", True), ("extra", "set", False),
                  ("garble", "set", True), ("lose", "move", False)), id="after-lost-move"),
    pytest.param("ack_reads=after", 5016179,
                 (("noise", "move", True), ("junk", "upload", False),
                  ("cycle_idle", "speed", True), ("cycle_moving", "upload", False),
                  ("extra", "set", True), ("lose", "move", False)),
                 id="after-lost-move-after-cycles"),
    pytest.param("ack_reads=before", 930568548,
                 (("cycle_idle", "speed", True), ("garble", "upload", False),
                  ("extra", "upload", True), ("drop", "set", False),
                  ("cycle_idle", "speed", True), ("noise", "move", False)),
                 id="before-garbled-move-ok"),
    # The faulted run's drop takes the reply of a read the driver makes on its own (the
    # settings read again after the restart the run before found); the next call's set,
    # written behind that read, puts its OK... where the read's number is owed: the
    # mismatch resyncs the stream with the set in flight, which its read-back proves.
    pytest.param("ack_case=lower", 494902982,
                 (("extra", "speed", False), ("cycle_moving", "speed", True),
                  ("cycle_moving", "set", False), ("cycle_idle", "reads", True),
                  ("drop", "set", False)),
                 id="drop-after-restart-reread"),
    # A set line lost while that read runs behind it: the read's number came where the
    # set's OK... was owed and was passed over, and the read's OK... acknowledged the
    # set (a false success, on main too); it now puts the stream out of step.
    pytest.param("ack_reads=after", 226313994,
                 (("cycle_idle", "speed", False), ("lose", "speed", True),
                  ("noise", "set", False), ("drop", "upload", True),
                  ("cycle_idle", "upload", False), ("lose", "set", True)),
                 id="after-lost-set-behind-a-reread"),
    # The power cycled while a move runs: the unit, back in mode 1, sends no OK..., and
    # the number of the next line came where one was owed. Out of step (above), which
    # must also suspect the restart, as the timeout it replaces did: otherwise every
    # later line meets the mode-1 replies and is aborted in turn.
    pytest.param("ack_reads=after", 607421839,
                 (("drop", "set", False), ("noise", "speed", True), ("drop", "speed", False),
                  ("lose", "reads", True), ("garble", "reads", False),
                  ("cycle_idle", "speed", True), ("cycle_moving", "move", False)),
                 id="after-power-cycle-while-moving"),
]


@pytest.mark.slow
async def test_the_call_after_a_power_cycle_while_moving_on_the_pty_in_mode_2(
        tmp_path: Path) -> None:
    """``ack_reads=after``, ``speed`` while a move runs and the power goes, over the pty
    at 57600 Bd, twelve runs: where the power went between the number of the ``?err``
    the core writes behind the move and its ``OK...``, the ``!speed`` behind it waited
    for that ``OK...`` and was withdrawn without a resync, and so was every later call
    (it failed in 2 to 5 of the 12 runs, depending on the timing)."""
    posix_only("the pty emulator at 57600 Bd")
    counts: Counter[str] = Counter()
    bad: list[str] = []
    for seed in range(12):
        bad += await run_cell(2, "cycle_moving", "speed", "ack_reads=after", pty=True,
                              seed=seed, counts=counts, state=tmp_path / f"{seed}.json")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(("variant", "seed", "runs"), SOAK_HISTORIES)
async def test_the_call_after_a_faulted_one_after_a_faulted_history_in_mode_2(
        tmp_path: Path, variant: str, seed: int, runs: tuple[tuple[str, str, bool], ...]
        ) -> None:
    counts: Counter[str] = Counter()
    async with opened_rig(variant, 2, pty=False, seed=seed, counts=counts,
                          state=tmp_path / "state.json") as rig:
        for fault, op, second in runs:
            await run_operation(rig, op, fault, f"{fault} {op}")
            await next_call(rig, op, second=second)
            assert not rig.bad, f"{variant} seed {seed} {fault} {op}: " + "\n".join(rig.bad)
            await bounded(reset_values(rig))


# --------------------------------------------------------------------------------------
# The soak


def soak_seconds() -> float:
    """The soak's length per mode: ``TANGO_AIO_SOAK_SECONDS`` divided by the five modes
    (default 150 s in all)."""
    return float(os.environ.get("TANGO_AIO_SOAK_SECONDS", "150")) / len(MODES)


def rss_kib() -> int | None:
    """This process's resident set size (KiB; ``None`` where /proc is missing)."""
    with contextlib.suppress(OSError):
        for row in Path("/proc/self/status").read_text().splitlines():
            if row.startswith("VmRSS:"):
                return int(row.split()[1])
    return None


SOAK: dict[str, Any] = {}


def soak_variants() -> list[str]:
    """The variants the soak draws from: every one, or those named (comma-separated) in
    ``TANGO_AIO_SOAK_VARIANTS``."""
    chosen = os.environ.get("TANGO_AIO_SOAK_VARIANTS", "")
    names = [name.strip() for name in chosen.split(",") if name.strip()]
    unknown = [name for name in names if name not in VARIANTS]
    assert not unknown, f"TANGO_AIO_SOAK_VARIANTS: unknown variants {unknown}"
    return names or VARIANTS


async def soak(tmp_path: Path, mode: int, rng: random.Random, choices: list[str],
               more: Callable[[int], bool], counts: Counter[str]) -> tuple[int, list[str]]:
    """Random cells of ``mode``, one after another on one connection per variant (ten
    runs, or fewer after a bad verdict), drawn by ``rng`` from ``choices`` while
    ``more(runs)``; the runs and the bad verdicts."""
    bad: list[str] = []
    runs = 0
    while more(runs):
        variant = rng.choice(choices)
        seed = rng.randrange(1 << 30)
        async with opened_rig(variant, mode, pty=False, seed=seed, counts=counts,
                              state=tmp_path / "soak.json") as rig:
            for _ in range(10):
                fault, op = rng.choice(FAULTS), rng.choice(OPS)
                before = len(rig.bad)
                await run_operation(rig, op, fault, f"{fault} {op}")
                await next_call(rig, op, second=runs % 2 == 1)
                runs += 1
                if len(rig.bad) > before:
                    bad += [f"{variant} seed {seed} {fault} {op}: {b}"
                            for b in rig.bad[before:]]
                    break  # a fresh connection for the next runs
                if isinstance(await outcome(reset_values(rig)), BaseException):
                    break
    return runs, bad


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
async def test_soak(tmp_path: Path, caplog: pytest.LogCaptureFixture, mode: int) -> None:
    """Random cells, one after another on one connection per variant, for
    :func:`soak_seconds`: no bad verdict, RSS about flat. The driver's warnings (each
    resync after a fault) are not captured: pytest keeps every record of a test, which
    grew the RSS by about 16 MiB a minute."""
    caplog.set_level(logging.ERROR, logger="tango_aio")
    rng = random.Random(mode)
    counts: Counter[str] = Counter()
    gc.collect()
    rss_start = rss_kib()
    end = time.monotonic() + soak_seconds()
    runs, bad = await soak(tmp_path, mode, rng, soak_variants(),
                           lambda _runs: time.monotonic() < end, counts)
    gc.collect()
    rss_end = rss_kib()
    summary = soak_summary(counts, runs, rss_start, rss_end)
    SOAK[f"mode {mode}"] = {"summary": summary, "counts": dict(sorted(counts.items()))}
    path = _report_dir() / "tango_aio_reliability_soak.json"
    path.write_text(json.dumps(SOAK, indent=2) + "\n")
    print(f"\n--- soak, mode {mode} (also in {path}): "
          + ", ".join(f"{k}={v}" for k, v in summary.items()))
    assert not bad, "\n".join(bad[:40])
    if rss_start is not None and rss_end is not None:  # flat: a bound that only catches a leak
        assert rss_end - rss_start < 64 * 1024, summary


#: Runs of the soak on each :data:`COMBINED` variant (a count, not a time: the same
#: histories on any machine).
COMBINED_SOAK_RUNS = 600


@pytest.mark.slow
@pytest.mark.parametrize("variant", COMBINED)
async def test_soak_on_combined_switches(tmp_path: Path, caplog: pytest.LogCaptureFixture,
                                         variant: str) -> None:
    """The soak's random cells on one :data:`COMBINED` variant, in the mode its switches
    act in, :data:`COMBINED_SOAK_RUNS` runs: no bad verdict."""
    caplog.set_level(logging.ERROR, logger="tango_aio")
    mode = COMBINED_MODE[variant]
    counts: Counter[str] = Counter()
    runs, bad = await soak(tmp_path, mode, random.Random(f"{mode} {variant}"), [variant],
                           lambda runs: runs < COMBINED_SOAK_RUNS, counts)
    summary = soak_summary(counts, runs, None, None)
    print(f"\n--- soak, mode {mode}, {variant}: "
          + ", ".join(f"{k}={v}" for k, v in summary.items() if not k.startswith("rss")))
    assert not bad, "\n".join(bad[:40])


def soak_summary(counts: Counter[str], runs: int, rss_start: int | None,
                 rss_end: int | None) -> dict[str, Any]:
    """The soak's headline counts from its verdict counts."""
    def total(word: str) -> int:
        return sum(n for key, n in counts.items() if key.endswith(f": {word}"))
    return {"runs": runs, "misdelivered": total("MISDELIVERED"),
            "wrong values": total("WRONG VALUE"), "false successes": total("FALSE SUCCESS"),
            "unstopped axes": total("UNSTOPPED"), "hangs": total("HANG"),
            "untyped errors": total("UNTYPED ERROR"),
            "next call failed": total(NEXT_CALL_FAILED),
            "rss_kib_start": rss_start, "rss_kib_end": rss_end}


async def reset_values(rig: Rig) -> None:
    """Every (setting, axis) distinct again after a run that changed some."""
    for name, values in DISTINCT.items():
        await bounded(rig.tango.set(name, **as_axes(values)))

