"""The driver's test matrix (#13): end-to-end scenarios against every firmware variant.

Every scenario runs against each entry of :func:`tango_aio.sim.profiles.variants` (the
``manual`` and ``legacy`` profiles and ``manual`` with each single non-default switch
value), in instant mode (``baud=0``) and at 57600 Bd. The default run keeps the two
profiles in instant mode (the longest scenarios take them in turn: :func:`matrix_on`);
every other combination is marked ``slow`` (CI runs them all:
``python -m pytest -m slow tests/e2e``).

What is asserted are the invariants a caller relies on, checked against the emulator's
own state rather than particular wire traffic:

* **arrived**: a move returns normally only when every moved axis has stopped (velocity 0)
  at its target, in the emulator's motion model;
* **never a false success**: an aborted, cancelled or cut-short move raises;
* **own replies**: no reply reaches the wrong caller (distinct per-axis values, read
  concurrently);
* **typed and bounded**: every failure is a :class:`TangoError` within :data:`BOUND`
  seconds, and the next call works.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Awaitable, Collection, Mapping
from typing import Any, TypeVar, Unpack

import pytest
from helpers import VELS, Axes, Emulated, EmulatorFactory

from tango_aio.controller._connection import connect
from tango_aio.controller._motion import STOP_WAIT
from tango_aio.errors import (
    ConnectError,
    ControllerError,
    InternalControllerError,
    MoveError,
    TangoError,
)
from tango_aio.events import ControllerFault, MoveFinished, Subscription, TangoEvent
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import PROFILES, variants
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import Emit, WireConfig
from tango_aio.testing import faults

pytestmark = [pytest.mark.timeout(120), pytest.mark.virtual_clock]

T = TypeVar("T")

#: Longest time any call of a scenario may take before it must have returned or raised
#: a TangoError: a reply timeout for the call, one for the resync behind it, the stop
#: wait of a move and the longest move of the scenarios (seconds).
REPLY_TIMEOUT = 2.0
BOUND = 2 * REPLY_TIMEOUT + STOP_WAIT + 5.0

#: Travel between the limit switches of the shortened axes (mm): limit switches at ±5.
TRAVEL = 10.0

#: Limits of the fast stage that make_fast sets (mm/s, m/s²).
FAST = 100

BAUDS = (0, 57600)

#: Variants whose instructions are those of the older edition only.
OLDER_INSTRUCTION_SET = ("legacy", "instruction_set=older")


def _variant_query(name: str) -> str:
    return f"profile={name}" if name in PROFILES else f"profile=manual&{name}"


def _params(default: Collection[str] = tuple(PROFILES)) -> list[Any]:
    """Every variant at every baud rate; the ``default`` ones in instant mode are in the
    default run, the others are ``slow``."""
    out = []
    for baud in BAUDS:
        for name, _firmware in variants():
            marks = [] if baud == 0 and name in default else [pytest.mark.slow]
            out.append(pytest.param(name, baud, id=f"{name}-{baud}", marks=marks))
    return out


def matrix_on(*profiles: str) -> pytest.MarkDecorator:
    """Every variant at every baud rate, with ``profiles`` in instant mode in the default
    run. The longer scenarios take the two profiles in turn there (``matrix_on("manual")``)
    and both, with every variant, under ``slow``."""
    return pytest.mark.parametrize(("variant", "baud"), _params(profiles))


MATRIX = matrix_on(*PROFILES)


async def open_variant(emulator: EmulatorFactory, variant: str, baud: int,
                       autostatus: int = 1) -> Emulated:
    """A 3-axis emulator of ``variant`` with short, fast axes."""
    url = f"sim://?baud={baud}&{_variant_query(variant)}"
    emu = await emulator(url, travel=TRAVEL, autostatus=autostatus,
                         reply_timeout=REPLY_TIMEOUT)
    await emu.make_fast()
    await emu.tango.set("vel", **VELS)  # distinct per axis: a misrouted reply shows
    return emu


async def bounded(call: Awaitable[T]) -> T:
    """Await ``call``; it must return or raise a TangoError within :data:`BOUND` s."""
    try:
        async with asyncio.timeout(BOUND):
            return await call
    except TangoError:
        raise
    except TimeoutError as exc:  # the caller's bound, not a ControllerTimeoutError
        raise AssertionError(f"no result and no TangoError within {BOUND} s") from exc


def sim_axes(emu: Emulated) -> dict[str, tuple[float, float]]:
    """The emulator's own state: (position in mm, velocity in rev/s) of each axis, now."""
    return faults(emu.tango).axes()


def assert_arrived(emu: Emulated, targets: Mapping[str, float]) -> None:
    """Invariant *arrived*: every moved axis stands still at its target."""
    state = sim_axes(emu)
    for axis, target in targets.items():
        position, velocity = state[axis]
        assert velocity == 0.0, f"{axis} still moving at {position} ({velocity} rev/s)"
        assert math.isclose(position, target, abs_tol=1e-4), (axis, position, target)


def assert_stopped_short(emu: Emulated, targets: Mapping[str, float]) -> None:
    """After an abort or cancel: the axes stand still, and not all at their targets (so
    the success that was refused would have been false)."""
    state = sim_axes(emu)
    assert all(state[axis][1] == 0.0 for axis in targets), state
    assert any(not math.isclose(state[a][0], t, abs_tol=1e-3) for a, t in targets.items()), \
        state


async def assert_next_call_works(emu: Emulated) -> None:
    """Invariant *typed and bounded*, second half: the driver is usable afterwards."""
    vel = await bounded(emu.tango.get("vel"))
    assert (vel["y"], vel["z"]) == (VELS["y"], VELS["z"])  # X may have been slowed down
    await bounded(emu.tango.move_to(x=0.25))
    assert_arrived(emu, {"x": 0.25})


async def start_move(emu: Emulated, **targets: Unpack[Axes]) -> asyncio.Task[dict[str, str]]:
    """Start a move and return once the emulator's axes are under way."""
    task = asyncio.create_task(emu.tango.move_to(**targets))
    await moving(emu, *targets, task=task)
    return task


async def moving(emu: Emulated, *axes: str, task: asyncio.Task[Any] | None = None) -> None:
    """Return once one of ``axes`` moves in the emulator."""
    async with asyncio.timeout(BOUND):
        while all(sim_axes(emu)[axis][1] == 0.0 for axis in axes):
            assert task is None or not task.done(), task
            await asyncio.sleep(0.002)


async def slow_down(emu: Emulated, vel: float = 5.0) -> None:
    """Make X slow enough (mm/s) for something to happen during its move."""
    await emu.tango.set("vel", vel, axis="x")


# --------------------------------------------------------------------------------------
# Scenarios


@MATRIX
async def test_connect_and_identify(emulator: EmulatorFactory, variant: str,
                                    baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    identity = emu.tango.identity
    assert identity is not None and identity.axes == 3
    assert identity.family == ("older" if variant in ("legacy", "version_format=old",
                                                     "instruction_set=older") else "1.71")
    assert identity.detected.get("per_axis_replies") == "exact"
    assert await bounded(emu.tango.get("pos")) == {"x": 0.0, "y": 0.0, "z": 0.0}


async def _connect_left_in(variant: str, baud: int, left: int, local_echo: str,
                           wanted: int | None) -> None:
    """Connect through the TCP emulator to a unit of ``variant`` that an earlier program
    left in autostatus ``left``, selecting ``wanted``; check the mode and a read."""
    firmware = dict(variants(unsupported=True))[variant].with_(local_echo=local_echo)

    def factory(emit: Emit) -> ControllerModel:
        model = ControllerModel(emit, SimConfig(firmware=firmware))
        model.set_autostatus(left)
        return model

    async with await serve_tcp(factory, config=WireConfig(baud=baud)) as server, \
            await bounded(connect(f"socket://127.0.0.1:{server.port}", autostatus=wanted,
                                  reply_timeout=REPLY_TIMEOUT)) as tango:
        handler = server.wires[0].handler
        assert isinstance(handler, ControllerModel)
        assert tango.autostatus == handler.autostatus == (left if wanted is None
                                                         else wanted)
        assert await bounded(tango.get("vel")) == {"x": 10.0, "y": 10.0, "z": 10.0}


@MATRIX
async def test_connect_from_any_mode_left_behind(variant: str, baud: int) -> None:
    # Whatever mode the unit was left in, connect keeps it or selects mode 2 or 4 (which
    # check the link for local echo in mode 1 first)...
    for left in range(5):
        for wanted in (None, 2, 4):
            await _connect_left_in(variant, baud, left, "no", wanted)


@MATRIX
async def test_local_echo_is_refused_at_connect_in_every_mode(variant: str,
                                                             baud: int) -> None:
    # ...and behind a link with local echo (switch local_echo=yes, not served) it is
    # refused in words, whatever the mode left behind and the mode selected, under every
    # variant: the mode-4 echo switches (echo, echo_all, echo_text, echo_report) among
    # them, since mode 4 may echo reads like the adapter does (old L723) or not (L2117),
    # and ack_reads=before, since mode 2 may acknowledge a read before its data.
    for left in range(5):
        for wanted in (None, 1, 2, 4):
            with pytest.raises(ConnectError, match="local echo"):
                await _connect_left_in(variant, baud, left, "yes", wanted)


@matrix_on("manual")
async def test_each_autostatus_mode_and_changes(emulator: EmulatorFactory, variant: str,
                                                baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    position = 0.0
    for mode in (4, 0, 2, 3, 1, 3, 0, 4, 2, 1):
        await bounded(emu.tango.set("autostatus", mode))
        assert emu.tango.autostatus == mode == emu.model.autostatus
        position = 1.0 - position
        await bounded(emu.tango.move_to(x=position))
        assert_arrived(emu, {"x": position})
        assert await bounded(emu.tango.get("vel")) == VELS


@MATRIX
async def test_move_to_move_by_and_subsets(emulator: EmulatorFactory, variant: str,
                                           baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    tango = emu.tango
    await bounded(tango.move_to(x=1.5, y=-2.0))
    assert_arrived(emu, {"x": 1.5, "y": -2.0, "z": 0.0})
    await bounded(tango.move_by(x=-0.5, y=0.25, z=1.0))
    assert_arrived(emu, {"x": 1.0, "y": -1.75, "z": 1.0})
    # #15 item 5: any set of axes, and no other axis moves.
    await bounded(tango.move_to(y=2.0, z=-1.0))
    assert_arrived(emu, {"x": 1.0, "y": 2.0, "z": -1.0})
    await bounded(tango.move_by(z=0.5))
    assert_arrived(emu, {"x": 1.0, "y": 2.0, "z": -0.5})
    await bounded(tango.move_to(x=1.0))  # already there: zero move
    assert_arrived(emu, {"x": 1.0})


@MATRIX
async def test_queued_moves_keep_their_own_timeout(emulator: EmulatorFactory, variant: str,
                                                   baud: int) -> None:
    # #14 item 2: the second move's timeout counts from its own start, not from the
    # call, so it is not cut short while it waits behind the first.
    emu = await open_variant(emulator, variant, baud)
    await slow_down(emu, 20.0)
    first = asyncio.create_task(emu.tango.move_to(x=4.0))
    second = asyncio.create_task(emu.tango.move_to(x=0.5))
    await bounded(first)
    await bounded(second)
    assert_arrived(emu, {"x": 0.5})


@matrix_on("legacy")
async def test_cal_and_rm(emulator: EmulatorFactory, variant: str, baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    letters = await bounded(emu.tango.calibrate("x"))
    assert letters["x"] == "A"
    letters = await bounded(emu.tango.measure_range("x"))
    assert letters["x"] == "D"
    assert all(v == 0.0 for _p, v in sim_axes(emu).values())
    await assert_next_call_works(emu)


@MATRIX
async def test_queries_while_moving_get_their_own_reply(emulator: EmulatorFactory,
                                                        variant: str, baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    await slow_down(emu, 10.0)
    move = await start_move(emu, x=3.0)
    for _ in range(5):
        vel, accel, status = await bounded(asyncio.gather(
            emu.tango.get("vel"), emu.tango.get("accel"), emu.tango.status()))
        assert vel == {**VELS, "x": 10.0}
        assert accel == {"x": 20.0, "y": 20.0, "z": 20.0}
        assert set(status) == {"x", "y", "z"}
    await bounded(move)
    assert_arrived(emu, {"x": 3.0})


@MATRIX
@pytest.mark.parametrize("soft", [True, False], ids=["a", "ctrl_c"])
async def test_abort_never_succeeds(emulator: EmulatorFactory, variant: str, baud: int,
                                    soft: bool) -> None:
    emu = await open_variant(emulator, variant, baud)
    await slow_down(emu)
    move = await start_move(emu, x=4.0)
    await bounded(emu.tango.abort(soft=soft))
    with pytest.raises(MoveError):
        await bounded(move)
    assert_stopped_short(emu, {"x": 4.0})
    await assert_next_call_works(emu)


@MATRIX
async def test_cancelled_moves(emulator: EmulatorFactory, variant: str, baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    await slow_down(emu)
    move = await start_move(emu, x=4.0)
    move.cancel()
    with pytest.raises(asyncio.CancelledError):
        await bounded(move)
    assert_stopped_short(emu, {"x": 4.0})
    # #14 item 3: a move cancelled while it waits behind a detached move
    # (stop_on_cancel=False) must not make the driver forget the detached one.
    detached = asyncio.create_task(emu.tango.move_to(x=-1.0, stop_on_cancel=False))
    await moving(emu, "x")
    detached.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await detached
    waiting = asyncio.create_task(emu.tango.move_to(x=2.0))
    await asyncio.sleep(0.05)
    waiting.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await waiting
    await bounded(emu.tango.move_to(x=0.5))  # sent only after the detached move ended
    assert_arrived(emu, {"x": 0.5})


@MATRIX
async def test_joystick_off_during_a_move_does_not_end_it(emulator: EmulatorFactory,
                                                          variant: str, baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    await slow_down(emu, 10.0)
    move = await start_move(emu, x=3.0)
    await bounded(emu.tango.command("!joy 0"))  # sends @@@-. while X runs (L2093)
    await bounded(move)
    assert_arrived(emu, {"x": 3.0})
    await assert_next_call_works(emu)


def _with_mode(mode: int, default: Collection[str]) -> list[Any]:
    return [pytest.param(mode, *param.values, id=f"{mode}-{param.id}", marks=param.marks)
            for param in _params(default)]


# Mode 0 polls at the expected ends (7-8 s here): the default run takes mode 1 on one
# profile; mode 0 runs under ``slow``.
@pytest.mark.parametrize(("mode", "variant", "baud"),
                         [*_with_mode(1, ("legacy",)), *_with_mode(0, ())])
async def test_pause_and_delay_count_in_the_move(emulator: EmulatorFactory, variant: str,
                                                 baud: int, mode: int) -> None:
    emu = await open_variant(emulator, variant, baud, autostatus=mode)
    await bounded(emu.tango.set("delay", 300))
    await bounded(emu.tango.set("pause", 600))
    for target in (1.0, 1.5, -0.5):
        await bounded(emu.tango.move_to(x=target))
        assert_arrived(emu, {"x": target})
    await bounded(emu.tango.set("pause", 0))
    await bounded(emu.tango.move_to(x=0.0))
    assert_arrived(emu, {"x": 0.0})


#: (mode, variant) pairs of :func:`test_traffic_during_a_move` in the default run: the
#: one that misrouted replies (#32) and mode 4; every other pair runs under ``slow``.
TRAFFIC_DEFAULT = ((2, "move_ok=completion"), (4, "manual"))


def _traffic_params() -> list[Any]:
    out = []
    for mode in (0, 1, 2, 3, 4):
        for param in _with_mode(mode, ()):
            _mode, variant, baud = param.values
            marks = [] if baud == 0 and (mode, variant) in TRAFFIC_DEFAULT \
                else [pytest.mark.slow]
            out.append(pytest.param(mode, variant, baud, id=param.id, marks=marks))
    return out


@pytest.mark.parametrize(("mode", "variant", "baud"), _traffic_params())
async def test_traffic_during_a_move(emulator: EmulatorFactory, variant: str, baud: int,
                                     mode: int) -> None:
    # #32 item 4: reads, an accepted and a refused set, !joy 0 and speed, all while X
    # moves, in every autostatus mode: each reply reaches its own caller (a refused set
    # credited to the move, or an acknowledgement shifted by one, shows here), the move
    # succeeds only at its target, and a call that raises leaves no axis it started
    # running.
    emu = await open_variant(emulator, variant, baud)
    tango = emu.tango
    # (Set here, not at connect: open_variant reboots the emulator behind the link, and
    # set-up after a reboot in mode 2 with acknowledged reads hangs: #32 item 5.)
    await bounded(tango.set("autostatus", mode))
    await slow_down(emu, 5.0)
    move = await start_move(emu, x=3.0)
    vel, accel, status = await bounded(asyncio.gather(
        tango.get("vel"), tango.get("accel"), tango.status()))
    assert vel == {**VELS, "x": 5.0}
    assert accel == {"x": 20.0, "y": 20.0, "z": 20.0}
    assert set(status) == {"x", "y", "z"}
    await bounded(tango.set("vel", 7.5, axis="y"))  # accepted
    with pytest.raises(ControllerError) as refused:  # refused: 5, or 4 on older sets
        await bounded(tango.command("!trigp 5 1.0"))
    assert refused.value.command == "!trigp 5 1.0"
    assert await bounded(tango.get("vel", axis="y")) == 7.5
    await bounded(tango.set("vel", VELS["y"], axis="y"))
    await bounded(tango.command("!joy 0"))  # may send @@@-. while X runs (L2093)
    try:
        await bounded(tango.speed(z=2.0))
    except TangoError:
        pass  # refused while X moves: Z must not run
    finally:
        with contextlib.suppress(TangoError):
            await bounded(tango.speed(z=0.0))
    assert not move.done() or move.exception() is None, move
    await bounded(move)
    assert_arrived(emu, {"x": 3.0})
    await bounded(tango.wait_idle())  # speed 0 decelerates Z
    assert sim_axes(emu)["z"][1] == 0.0
    await assert_next_call_works(emu)


@MATRIX
async def test_internal_error_is_not_blamed_on_the_command(emulator: EmulatorFactory,
                                                           variant: str, baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    async with emu.tango.events() as events:
        emu.model.inject_internal_error(29)
        await bounded(emu.tango.set("vel", 9.5, axis="y"))  # applied: no error raised
        assert await emu.tango.get("vel", axis="y") == 9.5
        with pytest.raises(InternalControllerError) as info:
            await bounded(emu.tango.check_fault())
        assert info.value.number == 29 and info.value.command is None
        await bounded(emu.tango.set("lim", -5.0, 5.0, axis="x"))
        with pytest.raises(ControllerError) as own:  # a real error is still the line's
            await bounded(emu.tango.move_to(x=200.0))
        assert own.value.number < 20 and own.value.command is not None
        await bounded(emu.tango.command("!err"))
        await bounded(emu.tango.check_fault())
        assert emu.tango.fault == 0
        faults = [e for e in _buffered(events) if isinstance(e, ControllerFault)]
    assert [f.number for f in faults] == [29]


@matrix_on("manual")
async def test_events_follow_confirmed_moves(emulator: EmulatorFactory, variant: str,
                                             baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    async with emu.tango.events() as events:
        await bounded(emu.tango.move_to(x=1.0))
        with pytest.raises(MoveError) as info:
            await bounded(emu.tango.move_to(z=-6.0))  # into the E0 switch at -5 mm
        finished = [e for e in _buffered(events) if isinstance(e, MoveFinished)]
    assert info.value.statuses["z"] in "ES"
    assert [(e.kind, e.ok) for e in finished] == [("move", True), ("move", False)]
    await assert_next_call_works(emu)


@MATRIX
async def test_a_refused_move_is_an_error(emulator: EmulatorFactory, variant: str,
                                          baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    await bounded(emu.tango.set("lim", -5.0, 5.0, axis="x"))
    with pytest.raises(TangoError):
        await bounded(emu.tango.move_to(x=200.0))
    assert sim_axes(emu)["x"] == (0.0, 0.0)
    await assert_next_call_works(emu)


@matrix_on("legacy")
async def test_absent_axis_letters_are_not_credited_to_another(
        emulator: EmulatorFactory, variant: str, baud: int) -> None:
    # Y disabled; Z driven into its limit switch must fail as Z, whatever the report.
    emu = await open_variant(emulator, variant, baud)
    await bounded(emu.tango.set("axis", 0, axis="y"))
    with pytest.raises(MoveError) as info:
        await bounded(emu.tango.move_to(z=-6.0))
    assert info.value.statuses.get("z") in ("E", "S")
    await bounded(emu.tango.move_to(x=0.5))
    assert_arrived(emu, {"x": 0.5})


@MATRIX
async def test_list_upload(emulator: EmulatorFactory, variant: str, baud: int) -> None:
    emu = await open_variant(emulator, variant, baud)
    values = [round(0.5 + 0.0137 * i, 4) for i in range(300)]
    if variant in OLDER_INSTRUCTION_SET:
        # The older edition has no trigger position list (trigp, trigc): error 4.
        with pytest.raises(ControllerError):
            await bounded(emu.tango.triggers.upload_positions(values))
    else:
        await bounded(emu.tango.triggers.upload_positions(values))
        assert await bounded(emu.tango.triggers.read_positions()) == values
    rows = [[float(i), -float(i), 0.5] for i in range(1, 30)]
    await bounded(emu.tango.snapshots.upload_positions(rows))
    assert await bounded(emu.tango.snapshots.read_positions()) == rows


def _buffered(subscription: Subscription) -> list[TangoEvent]:
    """Every event a subscription holds now (without waiting)."""
    out: list[TangoEvent] = []
    while (event := subscription.get_nowait()) is not None:
        out.append(event)
    return out
