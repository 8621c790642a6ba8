"""ControllerGroup (many controllers driven concurrently) and discover() (serial probing).

The group tests run several in-process emulators; ``sim://?baud=0`` where only motion
timing matters (motion always runs in real time: about 10 mm/s at the default settings),
the real 57600 Bd where wire timing is part of what is measured. discover() is tested on
emulators served on ptys, plus ptys that stay silent or answer garbage.
"""

from __future__ import annotations

import asyncio
import os
from collections import Counter
from collections.abc import AsyncIterator, Callable, Iterator
from typing import TYPE_CHECKING, Any

import anyio
import pytest
from helpers import Emulated, posix_only, serve_pty, wait_until, wire_of

import tango_aio
import tango_aio.group._group as group_module
from tango_aio.controller._controller import Controller
from tango_aio.errors import (
    ConnectError,
    ConnectionLostError,
    InvalidCommandError,
    MoveError,
    OutOfRangeError,
    TangoError,
)
from tango_aio.events import ConnectionLost, MoveAborted, MoveFinished
from tango_aio.group._discovery import DiscoveredController, discover
from tango_aio.group._group import (
    ControllerGroup,
    GroupError,
    GroupEvent,
)
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.wire import Emit
from tango_aio.testing import faults

if TYPE_CHECKING:
    from tango_aio.sim.ptyserve import PtyServer

pytestmark = [pytest.mark.timeout(30), pytest.mark.virtual_clock]

INSTANT = "sim://?baud=0"
#: Travel between the limit switches of the shortened emulated axes (mm).
TRAVEL = 10.0
#: The completion letters of a 3-axis controller (every present axis reports).
IDLE3 = {"x": "@", "y": "@", "z": "@"}
FOUR = {"a": "sim://?baud=0&axes=1", "b": "sim://?baud=0&axes=2",
        "c": "sim://?baud=0&axes=3", "d": "sim://?baud=0&axes=4"}


def notes(exc: BaseException) -> list[str]:
    return list(getattr(exc, "__notes__", []))


async def wait_moving(controller: Controller) -> None:
    """Wait until an axis of ``controller`` shows M."""
    for _ in range(400):
        if "M" in (await controller.status()).values():
            return
        await asyncio.sleep(0.005)
    raise AssertionError("the move did not start")


async def _expire_when(deadline: asyncio.Timeout, ready: Callable[[], bool]) -> None:
    """Let ``deadline`` expire now once ``ready()`` holds (polled, bounded by 30 s)."""
    await wait_until(ready, timeout=30.0)
    deadline.reschedule(asyncio.get_running_loop().time())


def _under_way(group: ControllerGroup) -> bool:
    """Both members of the move test have left 0 on their way to 20 (their emulators'
    state: past what a stop at the very start would leave)."""
    return faults(group["a"]).axes()["x"][0] > 0.01 and faults(group["b"]).axes()["y"][0] > 0.01


async def next_events(events: tango_aio.GroupSubscription, count: int,
                      kind: type[Any] = object) -> list[GroupEvent]:
    """The next ``count`` events of type ``kind`` (others skipped), within 5 s."""
    seen: list[GroupEvent] = []
    async with asyncio.timeout(5):
        async for item in events:
            if isinstance(item.event, kind):
                seen.append(item)
                if len(seen) == count:
                    return seen
    raise AssertionError(f"the stream ended after {seen}")


# ----------------------------------------------------------------------- open and close


async def test_opens_four_controllers_concurrently(monkeypatch: pytest.MonkeyPatch) -> None:
    slow = "sim://?baud=0&latency=0.01"
    real_connect = tango_aio.connect
    opening = Counter[str]()

    async def counted(url: str, **options: Any) -> Controller:
        opening["now"] += 1
        opening["most"] = max(opening["most"], opening["now"])
        try:
            return await real_connect(url, **options)
        finally:
            opening["now"] -= 1

    monkeypatch.setattr(group_module, "connect", counted)
    specs = {name: f"{slow}&axes={n}" for n, name in enumerate("abcd", start=1)}
    async with ControllerGroup(specs) as group:
        assert opening["most"] == 4  # all four were being opened at once
        assert list(group) == ["a", "b", "c", "d"]
        assert len(group) == 4 and "c" in group and "e" not in group
        for n, (name, controller) in enumerate(group.items(), start=1):
            assert isinstance(controller, Controller)
            assert controller.identity is not None and controller.identity.axes == n
            assert controller.url == specs[name] == group.url(name)
        controllers = list(group.values())
    assert not any(c.protocol.is_connected for c in controllers)
    assert not group.is_open


async def test_open_and_aclose_without_context_manager() -> None:
    group = await ControllerGroup(FOUR).open()
    try:
        assert group.is_open
        assert await group.position() == {
            "a": {"x": 0.0}, "b": {"x": 0.0, "y": 0.0},
            "c": {"x": 0.0, "y": 0.0, "z": 0.0},
            "d": {"x": 0.0, "y": 0.0, "z": 0.0, "a": 0.0}}
        with pytest.raises(RuntimeError, match="already open"):
            await group.open()
    finally:
        await group.aclose()
    await group.aclose()  # idempotent


async def test_options_per_member_and_common() -> None:
    specs: dict[str, Any] = {"plain": INSTANT,
                             "own": (INSTANT, {"reply_timeout": 1.5, "identify": False})}
    async with ControllerGroup(specs, reply_timeout=3.0) as group:
        assert group["plain"].reply_timeout == 3.0
        assert group["plain"].identity is not None
        assert group["own"].reply_timeout == 1.5
        with pytest.raises(RuntimeError, match="not identified"):
            group["own"].identity  # noqa: B018


async def test_not_open_and_unknown_names() -> None:
    group = ControllerGroup({"a": INSTANT})
    assert list(group) == ["a"] and "closed" in repr(group)
    with pytest.raises(RuntimeError, match="not open"):
        group["a"]
    with pytest.raises(KeyError):
        group["nope"]
    with pytest.raises(RuntimeError, match="not open"):
        await group.calibrate()
    async with group:
        with pytest.raises(KeyError, match="nope"):
            await group.move_to({"nope": {"x": 1}})
        with pytest.raises(KeyError):
            await group.abort(["a", "nope"])
        with pytest.raises(ValueError):
            ControllerGroup({"": INSTANT})


@pytest.fixture
def opened(monkeypatch: pytest.MonkeyPatch) -> list[Controller]:
    """Every controller the group's ``connect`` returns, in order (a spy on it)."""
    controllers: list[Controller] = []
    real_connect = tango_aio.connect

    async def spy(url: str, **options: Any) -> Controller:
        controller = await real_connect(url, **options)
        controllers.append(controller)
        return controller

    monkeypatch.setattr(group_module, "connect", spy)
    return controllers


async def test_failed_open_closes_the_others_and_names_the_failures(
        opened: list[Controller]) -> None:
    group = ControllerGroup({"good1": INSTANT, "bad_sim": "sim://?axes=9",
                             "good2": INSTANT, "refused": "socket://127.0.0.1:1"})
    async with asyncio.timeout(10):
        with pytest.raises(GroupError) as info:
            await group.open()
    error = info.value
    assert set(error.failures) == {"bad_sim", "refused"}
    assert "'bad_sim'" in str(error) and "'refused'" in str(error)
    assert isinstance(error.failures["bad_sim"], ValueError)
    assert isinstance(error.failures["refused"], ConnectError)
    assert notes(error.failures["bad_sim"]) == ["controller 'bad_sim' (sim://?axes=9)"]
    assert len(opened) == 2
    assert not any(c.protocol.is_connected for c in opened)
    assert not group.is_open


async def test_cancelled_open_closes_what_opened(monkeypatch: pytest.MonkeyPatch) -> None:
    opened: list[Controller] = []
    real_connect = tango_aio.connect

    async def spy(url: str, **options: Any) -> Controller:
        if "hang" in url:
            await asyncio.sleep(3600)
        controller = await real_connect(url, **options)
        opened.append(controller)
        return controller

    monkeypatch.setattr(group_module, "connect", spy)
    with pytest.raises(TimeoutError):
        async with asyncio.timeout(None) as deadline:
            # Cancelled once "ok" is open (not after a time a loaded machine may need).
            watch = asyncio.create_task(_expire_when(deadline, lambda: bool(opened)))
            await ControllerGroup({"ok": INSTANT, "stuck": "sim://?hang"}).open()
    await watch
    assert len(opened) == 1 and not opened[0].protocol.is_connected


async def test_open_cancelled_mid_setup_leaves_nothing_behind(
        opened: list[Controller], monkeypatch: pytest.MonkeyPatch) -> None:
    # The slow members' setup takes minutes (each reply waits 30 s): the open is cancelled
    # once the fast one has connected, so the slow ones are surely mid-setup, on a loaded
    # machine too (no wall-clock window).
    slow = "sim://?baud=0&latency=30"
    fast_open = asyncio.Event()
    spy = group_module.connect  # type: ignore[attr-defined]  # the fixture's spy

    async def tell(url: str, **options: Any) -> Controller:
        controller = await spy(url, **options)
        fast_open.set()
        return controller

    monkeypatch.setattr(group_module, "connect", tell)
    opening = asyncio.ensure_future(
        ControllerGroup({"fast": INSTANT, "a": slow, "b": slow}).open())
    await fast_open.wait()
    opening.cancel()
    with pytest.raises(asyncio.CancelledError):
        await opening
    assert len(opened) == 1 and not any(c.protocol.is_connected for c in opened)
    others = {t for t in asyncio.all_tasks() if t is not asyncio.current_task()}
    if others:  # the emulator tasks wind down (a bound, not a speed)
        await asyncio.wait(others, timeout=30)
    assert [t for t in asyncio.all_tasks() if t is not asyncio.current_task()] == []


# ------------------------------------------------------------------------------ motion


async def test_concurrent_moves_take_the_longest_not_the_sum() -> None:
    # Real wire timing (57600 Bd) and real motion.
    specs = {name: "sim://?axes=2" for name in "abcd"}
    distances = {"a": 1.0, "b": 2.0, "c": 3.0, "d": 4.0}
    async with asyncio.timeout(20), ControllerGroup(specs) as group:
        for name, distance in distances.items():
            await group[name].move_to(x=distance, y=distance / 2)
        # Concurrent: every member's move is under way before any has ended (recorded
        # as the moves run, not sampled by polling, which a loaded machine can miss).
        timeline: list[tuple[str, str]] = []
        for name, controller in group.items():
            real = controller._run_motion

            async def recorded(*args: Any, _name: str = name, _real: Any = real) -> Any:
                timeline.append(("start", _name))
                try:
                    return await _real(*args)
                finally:
                    timeline.append(("end", _name))

            controller._run_motion = recorded  # type: ignore[method-assign,assignment]
        letters = await group.move_to({name: {"x": 0.0, "y": 0.0} for name in distances})
        assert sorted(timeline[:4]) == [("start", name) for name in "abcd"], timeline
        assert [kind for kind, _ in timeline[4:]] == ["end"] * 4, timeline
        # ... and the group returned once the longest move had ended too.
        assert letters == {name: {"x": "@", "y": "@"} for name in distances}
        positions = await group.position()
        assert all(p == pytest.approx({"x": 0.0, "y": 0.0}, abs=1e-3)
                   for p in positions.values())


async def test_move_by_calibrate_measure_range_each() -> None:
    async with ControllerGroup({"a": INSTANT, "b": INSTANT}) as group:
        assert await group.move_by({"a": {"x": 0.5}, "b": {"y": -0.5}}) == {
            "a": IDLE3, "b": IDLE3}
        assert await group.position() == {
            "a": pytest.approx({"x": 0.5, "y": 0.0, "z": 0.0}, abs=1e-3),
            "b": pytest.approx({"x": 0.0, "y": -0.5, "z": 0.0}, abs=1e-3)}
        # Short, fast axes so that cal and rm take a fraction of a second.
        await group.each(lambda c: Emulated(c).shorten(TRAVEL, autostatus=1))
        await group.each(lambda c: Emulated(c).make_fast())
        assert await group.each(lambda c: c.get("calbspeed"), ["b"]) == {"b": [8000.0]}
        async with asyncio.timeout(25):
            assert await group.calibrate() == {name: {"x": "A", "y": "A", "z": "A"}
                                               for name in "ab"}
            assert await group.measure_range(["b"]) == {"b": {"x": "D", "y": "D", "z": "D"}}
        assert await group.status() == {"a": dict.fromkeys("xyz", "A"),
                                        "b": dict.fromkeys("xyz", "D")}
        lims = await group.each(lambda c: c.get("lim"))
        low, high = lims["b"]["x"]
        assert low == 0.0 and TRAVEL - 1 < high <= TRAVEL  # less the switch release


async def test_one_member_refusing_a_move_does_not_stop_the_others() -> None:
    async with ControllerGroup({"a": "sim://?baud=0&axes=2", "bad": INSTANT,
                                "c": INSTANT}) as group:
        await group["bad"].command("!lim x -5 5")
        with pytest.raises(GroupError) as info:
            async with asyncio.timeout(10):
                await group.move_to({"a": {"x": 3.0, "y": 1.0}, "bad": {"x": 10.0},
                                     "c": {"x": 3.0}})
        error = info.value
        assert list(error.failures) == ["bad"]
        refused = error.failures["bad"]
        assert isinstance(refused, OutOfRangeError)
        assert notes(refused) == [f"controller 'bad' ({INSTANT})"]
        assert "1 of 3" in str(error) and "'bad'" in str(error)
        assert error.results == {"a": {"x": "@", "y": "@"}, "c": IDLE3}
        assert error.cancelled == ()
        # The group raised after the others had arrived (their letters above, and:)
        positions = await group.position()
        assert positions["a"] == pytest.approx({"x": 3.0, "y": 1.0}, abs=1e-3)
        assert positions["c"]["x"] == pytest.approx(3.0, abs=1e-3)
        assert positions["bad"]["x"] == pytest.approx(0.0, abs=1e-3)

        # except* sees the original exception types, and the names survive the split.
        caught: list[GroupError] = []
        try:
            await group.move_to({"a": {"x": 0.0}, "bad": {"x": -10.0}})
        except* OutOfRangeError as group_error:
            assert isinstance(group_error, GroupError)
            caught.append(group_error)
        assert list(caught[0].failures) == ["bad"]


async def test_fail_fast_cancels_and_stops_the_others() -> None:
    async with ControllerGroup({"far": INSTANT, "bad": INSTANT}) as group:
        await group["bad"].command("!lim x -5 5")
        with pytest.raises(GroupError) as info:
            async with asyncio.timeout(10):
                await group.move_to({"far": {"x": 20.0}, "bad": {"x": 10.0}},
                                    fail_fast=True)
        assert list(info.value.failures) == ["bad"]
        assert info.value.cancelled == ("far",)
        assert info.value.results == {}
        assert "M" not in (await group["far"].status()).values()
        assert (await group["far"].position())["x"] < 5.0


@pytest.mark.parametrize("how", ["asyncio", "anyio"])
async def test_cancelling_a_group_move_stops_every_member(how: str) -> None:
    async with ControllerGroup({"a": INSTANT, "b": "sim://?baud=0&axes=2"}) as group:
        targets = {"a": {"x": 20.0, "y": -20.0}, "b": {"y": 20.0}}
        # Cancelled once both members move (their emulators say so), not after a time.
        if how == "anyio":  # level-triggered: every await in the scope is cancelled
            with anyio.CancelScope() as scope:
                async def cancel_when_under_way() -> None:
                    await wait_until(lambda: _under_way(group), timeout=30.0)
                    scope.cancel()
                watch = asyncio.create_task(cancel_when_under_way())
                await group.move_to(targets)
            assert scope.cancelled_caught
        else:
            with pytest.raises(TimeoutError):
                async with asyncio.timeout(None) as deadline:
                    watch = asyncio.create_task(
                        _expire_when(deadline, lambda: _under_way(group)))
                    await group.move_to(targets)
        await watch
        # Each member stopped its axes before the cancellation went on.
        statuses = await group.status()
        assert all("M" not in letters.values() for letters in statuses.values()), statuses
        positions = await group.position()
        assert 0 < positions["a"]["x"] < 10 and 0 < positions["b"]["y"] < 10


async def test_invalid_input_is_refused_before_anything_moves() -> None:
    async with ControllerGroup({"one": "sim://?baud=0&axes=1",
                                "two": "sim://?baud=0&axes=2"}) as group:
        async with group.events() as events:
            with pytest.raises(GroupError) as info:
                await group.move_to({"two": {"x": 1.0}, "one": {"y": 1.0}})
            assert list(info.value.failures) == ["one"]
            assert isinstance(info.value.failures["one"], InvalidCommandError)
            assert "nothing was sent" in str(info.value)
            with pytest.raises(GroupError) as info:
                await group.move_by({"one": {"x": float("nan")}, "two": {"q": 1.0}})
            assert set(info.value.failures) == {"one", "two"}
            await asyncio.sleep(0.2)
            assert events.get_nowait() is None
        assert await group.position() == {"one": {"x": 0.0}, "two": {"x": 0.0, "y": 0.0}}


# ------------------------------------------------------------------------------ events


async def test_merged_events_are_tagged_with_names() -> None:
    async with ControllerGroup(FOUR) as group:
        async with group.events() as events:
            await group.move_by({"a": {"x": 0.1}, "c": {"z": 0.2}, "d": {"a": 0.1}})
            finished = await next_events(events, 3, MoveFinished)
        assert sorted(item.name for item in finished) == ["a", "c", "d"]
        by_name = {name: event for name, event in finished if isinstance(event, MoveFinished)}
        assert by_name["a"].statuses == {"x": "@"}
        assert by_name["c"].statuses == {"x": "@", "y": "@", "z": "@"}
        assert all(event.ok and event.kind == "move" for event in by_name.values())
        # After the subscription is closed, iteration ends at once.
        assert await anext(aiter(events), None) is None


async def test_merged_events_drop_the_oldest_when_full() -> None:
    async with ControllerGroup({"a": INSTANT, "b": INSTANT, "c": INSTANT}) as group:
        events = group.events(maxsize=2)
        for _ in range(2):
            await group.move_by({name: {"x": 0.05} for name in group})
        await wait_until(lambda: events.dropped >= 4, timeout=30.0)  # the forwarders ran
        assert events.pending == 2
        assert events.dropped == 4
        assert all(isinstance(item.event, MoveFinished) for item in
                   (events.get_nowait(), events.get_nowait()) if item is not None)
        assert events.get_nowait() is None
        await events.aclose()


async def test_merged_stream_ends_when_the_group_closes() -> None:
    async with ControllerGroup({"a": INSTANT, "b": INSTANT}) as group:
        events = group.events()
    async with asyncio.timeout(30):  # a bound on a hang only
        remaining = [item async for item in events]
    assert all(not isinstance(item.event, MoveFinished) for item in remaining)
    await events.aclose()


# ------------------------------------------------------------------------------- abort


@pytest.mark.parametrize("soft", [False, True])
async def test_abort_stops_every_member(soft: bool) -> None:
    async with ControllerGroup({"a": "sim://?baud=0&axes=2", "b": INSTANT,
                                "c": "sim://?baud=0&axes=1"}) as group:
        async with group.events() as events:
            moving = asyncio.create_task(group.move_to(
                {"a": {"x": 20.0, "y": 10.0}, "b": {"z": -20.0}, "c": {"x": 20.0}}))
            for controller in group.values():
                await wait_moving(controller)
            async with asyncio.timeout(10):
                await group.abort(soft=soft)
                with pytest.raises(GroupError) as info:
                    await moving
            assert set(info.value.failures) == {"a", "b", "c"}
            assert all(isinstance(exc, MoveError) for exc in info.value.failures.values())
            aborted = await next_events(events, 3, MoveAborted)
            assert sorted(item.name for item in aborted) == ["a", "b", "c"]
            assert all(isinstance(item.event, MoveAborted) and item.event.ctrl_c is not soft
                       for item in aborted)
        statuses = await group.status()
        for letters in statuses.values():
            assert set(letters.values()) <= {"@", "E"}, statuses
        positions = await group.position()
        assert abs(positions["a"]["x"]) < 19 and abs(positions["b"]["z"]) < 19


# ---------------------------------------------------------------------- connection loss


@pytest.mark.parametrize("side", ["driver", "emulator"])
async def test_lost_member_fails_alone_and_nothing_hangs(side: str) -> None:
    async with asyncio.timeout(15), ControllerGroup(
            {"a": INSTANT, "lost": INSTANT, "c": "sim://?baud=0&axes=2"}) as group:
        async with group.events() as events:
            moving = asyncio.create_task(group.move_to(
                {"a": {"x": 2.0}, "lost": {"x": 20.0}, "c": {"y": 2.5}}))
            await wait_moving(group["lost"])
            if side == "driver":
                group["lost"].protocol.close()
            else:
                wire_of(group["lost"]).disconnect()
            with pytest.raises(GroupError) as info:
                await moving
            error = info.value
            assert list(error.failures) == ["lost"]
            assert isinstance(error.failures["lost"], ConnectionLostError)
            assert "controller 'lost'" in notes(error.failures["lost"])[0]
            assert error.results == {"a": IDLE3, "c": {"x": "@", "y": "@"}}
            lost = await next_events(events, 1, ConnectionLost)
            assert lost[0].name == "lost"

        positions = await group.position(["a", "c"])
        assert positions["a"]["x"] == pytest.approx(2.0, abs=1e-3)
        assert positions["c"]["y"] == pytest.approx(2.5, abs=1e-3)

        # Later operations report the lost member and still serve the others.
        with pytest.raises(GroupError) as info:
            await group.move_by({"a": {"x": -1.0}, "lost": {"x": 1.0}})
        assert list(info.value.failures) == ["lost"]
        assert info.value.results == {"a": IDLE3}
        with pytest.raises(GroupError) as info:
            await group.abort()
        assert list(info.value.failures) == ["lost"]
        assert isinstance(info.value.failures["lost"], TangoError)


# ----------------------------------------------------------------------------- discover


def make_model(model: str) -> Any:
    def factory(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, SimConfig(model=model))
    return factory


class RawPty:
    """A pty pair nobody serves; ``garbage=True`` answers every input with junk lines."""

    def __init__(self, garbage: bool = False) -> None:
        posix_only("a raw pty pair (os.openpty, tty)")
        import tty

        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self._loop = asyncio.get_running_loop()
        if garbage:
            self._loop.add_reader(self.master, self._answer)
        self.garbage = garbage

    def _answer(self) -> None:
        try:
            data = os.read(self.master, 1024)
        except OSError:
            return
        if data:
            os.write(self.master, b"\x00\xfe?? 1.71 junk\rERR 4\rVersion\r")

    def close(self) -> None:
        if self.garbage:
            self._loop.remove_reader(self.master)
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture
async def ptys() -> AsyncIterator[dict[str, Any]]:
    """Two emulators on ptys, a silent pty and a garbage-answering pty."""
    servers: list[PtyServer] = [await serve_pty(make_model("TANGO-DT")),
                                await serve_pty(make_model("TANGO-MINI3"))]
    silent, garbage = RawPty(), RawPty(garbage=True)
    yield {"servers": servers, "silent": silent, "garbage": garbage}
    for server in servers:
        server.close()
        await server.wait_closed()
    silent.close()
    garbage.close()


async def test_discover_finds_the_emulators_and_skips_the_rest(
        ptys: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    servers: list[PtyServer] = ptys["servers"]
    ports = [ptys["silent"].path, servers[0].path, "/dev/does-not-exist",
             ptys["garbage"].path, servers[1].path]
    probing: set[object] = set()  # the first argument of each worker-thread call
    seen_together: list[set[object]] = []
    real_run_sync = anyio.to_thread.run_sync

    async def counted(func: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        probing.add(args[0] if args else func)
        seen_together.append(set(probing))
        try:
            return await real_run_sync(func, *args, **kwargs)
        finally:
            probing.discard(args[0] if args else func)

    monkeypatch.setattr(anyio.to_thread, "run_sync", counted)
    # The silent port's probe waits it out, the others answer within it: not short.
    found = await discover(ports=ports, timeout=2.0)
    assert [item.port for item in found] == [servers[0].path, servers[1].path]
    assert [item.model for item in found] == ["TANGO-DT", "TANGO-MINI3"]
    assert all(item.firmware == "1.71" and item.version.firmware_tuple == (1, 71)
               for item in found)
    assert all(isinstance(item, DiscoveredController) for item in found)
    # Probed concurrently: the silent and the garbage port were probed at the same time.
    assert any({ptys["silent"].path, ptys["garbage"].path} <= seen for seen in seen_together)
    # A discovered port can be connected to.
    async with tango_aio.connect(found[1].port) as tango:
        assert tango.identity is not None and tango.identity.model == "TANGO-MINI3"


async def test_discover_lists_the_serial_ports(ptys: dict[str, Any],
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from serial.tools import list_ports
    from serial.tools.list_ports_common import ListPortInfo

    def infos() -> Iterator[ListPortInfo]:
        for path, description in ((ptys["servers"][1].path, "USB TANGO"),
                                  (ptys["silent"].path, "modem")):
            info = ListPortInfo(path, skip_link_detection=True)
            info.description, info.hwid = description, "USB VID:PID=0403:6001"
            yield info

    monkeypatch.setattr(list_ports, "comports", lambda: list(infos()))
    found = await discover(timeout=2.0)  # the silent port waits it out; the other answers
    assert [(item.port, item.model, item.description) for item in found] == [
        (ptys["servers"][1].path, "TANGO-MINI3", "USB TANGO")]
    assert found[0].hwid == "USB VID:PID=0403:6001"


async def test_discover_without_ports() -> None:
    assert await discover(ports=[]) == []
