"""Ctrl+C in any blocking call of ``tango_aio.sync`` stops what the program started
(#26 item 4): moves started with ``start_move_to`` stop too when the press lands in
``wait_idle()``, ``get()``, ``position()``, while the move is being started, or anywhere
in a ``with`` block."""

from __future__ import annotations

import contextlib
import os
import random
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from helpers import PtySim

import tango_aio.sync
from tango_aio.testing import faults

INSTANT = "sim://?baud=0"


@pytest.fixture
def tango() -> Iterator[tango_aio.sync.Controller]:
    with tango_aio.sync.connect(INSTANT) as controller:
        controller.set("vel", x=0.5, y=0.5)  # 100 mm at 0.5 mm/s: minutes of travel
        yield controller


@contextlib.contextmanager
def ctrl_c_when(ready: Callable[[], bool]) -> Iterator[None]:
    """Press Ctrl+C (a real SIGINT to this process) once ``ready()`` holds, from a helper
    thread, while the body blocks in the main thread."""
    entered = threading.Event()

    def press() -> None:
        entered.wait()
        while not ready():
            time.sleep(0.001)
        time.sleep(0.02)  # the main thread is in the body's blocking call by now
        os.kill(os.getpid(), signal.SIGINT)

    helper = threading.Thread(target=press)
    helper.start()
    try:
        entered.set()
        yield
    finally:
        helper.join()


def x_moves(tango: tango_aio.sync.Controller) -> Callable[[], bool]:
    """Whether the emulator's X axis moves (its own state, read from the helper thread)."""
    model = faults(tango.aio).model
    return lambda: model.motion.is_moving("x")


def assert_stopped(tango: tango_aio.sync.Controller, future: Any) -> None:
    """The started move was stopped on its way, and the next call works."""
    assert future.done()
    assert "M" not in tango.status().values()
    assert 0 < tango.position()["x"] < 100
    assert tango.move_to(x=0) == {"x": "@", "y": "@", "z": "@"}


def test_ctrl_c_in_wait_idle_stops_a_started_move(tango: tango_aio.sync.Controller) -> None:
    future = tango.start_move_to(x=100)
    with ctrl_c_when(x_moves(tango)), pytest.raises(KeyboardInterrupt):
        tango.wait_idle()
    assert_stopped(tango, future)


@pytest.mark.parametrize("read", ["get", "position", "status"])
def test_ctrl_c_in_a_read_stops_a_started_move(tango: tango_aio.sync.Controller,
                                               read: str) -> None:
    future = tango.start_move_to(x=100)
    calls = {"get": lambda: tango.get("vel"), "position": tango.position,
             "status": tango.status}
    with ctrl_c_when(x_moves(tango)), pytest.raises(KeyboardInterrupt):
        while True:
            calls[read]()
    assert_stopped(tango, future)


def test_ctrl_c_while_a_move_is_being_started_stops_it(
        tango: tango_aio.sync.Controller, monkeypatch: pytest.MonkeyPatch) -> None:
    portal = tango._portal.portal
    spawn = portal.start_task_soon
    moving = x_moves(tango)

    def spawn_then_interrupt(*args: Any, **kwargs: Any) -> Any:
        monkeypatch.setattr(portal, "start_task_soon", spawn)  # only this once
        spawn(*args, **kwargs)
        while not moving():
            time.sleep(0.001)
        raise KeyboardInterrupt  # before start_task_soon handed the future back

    monkeypatch.setattr(portal, "start_task_soon", spawn_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        tango.start_move_to(x=100)
    assert "M" not in tango.status().values()
    assert 0 < tango.position()["x"] < 100


def test_ctrl_c_between_two_calls_of_a_with_block_stops_the_started_moves() -> None:
    with pytest.raises(KeyboardInterrupt), tango_aio.sync.connect(INSTANT) as tango:
        tango.set("vel", x=0.5)
        model = faults(tango.aio).model
        future = tango.start_move_to(x=100)
        while not model.motion.is_moving("x"):
            time.sleep(0.001)
        raise KeyboardInterrupt  # as if pressed between two lines of the script
    assert future.cancelled()
    assert model.motion.status_letter("x") != "M"  # stopped before the link was closed


def test_a_started_move_goes_on_without_ctrl_c(tango: tango_aio.sync.Controller) -> None:
    """The stop is Ctrl+C's alone: a read that ends normally leaves the move running."""
    tango.set("vel", x=10)
    future = tango.start_move_to(x=2)
    while not x_moves(tango)():
        time.sleep(0.001)
    tango.position()
    assert future.result(timeout=10) == {"x": "@", "y": "@", "z": "@"}
    assert tango.position()["x"] == 2


def _script(tango: tango_aio.sync.Controller, rng: random.Random) -> None:
    """What a user's script does: start moves, then wait for them or read meanwhile."""
    while True:
        tango.start_move_to(x=rng.uniform(-20, 20))
        if rng.random() < 0.5:
            tango.start_move_to(y=rng.uniform(-20, 20))
        if rng.random() < 0.4:
            tango.wait_idle()
        else:
            for _ in range(rng.randint(1, 20)):
                rng.choice((tango.position, tango.status, lambda: tango.get("vel")))()


@pytest.mark.slow
def test_ctrl_c_at_random_points_of_a_script_leaves_no_axis_moving() -> None:
    rng = random.Random(26)
    left_moving = []
    with PtySim() as sim:
        for round_ in range(200):
            timer: threading.Timer | None = None
            with contextlib.suppress(KeyboardInterrupt), \
                    tango_aio.sync.connect(sim.path) as tango:
                timer = threading.Timer(rng.uniform(0.0, 0.6), os.kill,
                                        (os.getpid(), signal.SIGINT))
                timer.start()
                _script(tango, rng)
            assert timer is not None
            timer.join()
            with tango_aio.sync.connect(sim.path) as check:
                status = check.status()
            if "M" in status.values():
                left_moving.append((round_, status))
    assert left_moving == []
