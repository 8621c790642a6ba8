"""The virtual clock of the end-to-end tests (tests/virtualclock.py): waits that only the
loop's timers can end take no real time, and anything outside the loop that may wake it
(another thread, a watched file descriptor) keeps real time."""

from __future__ import annotations

import asyncio
import os
import socket
import threading
import time

import pytest
from helpers import EmulatorFactory
from virtualclock import VirtualClockLoop

from tango_aio.errors import MoveError

pytestmark = [pytest.mark.virtual_clock, pytest.mark.skipif(
    os.environ.get("TANGO_AIO_TEST_LOOP") == "uvloop",
    reason="uvloop runs keep real time (the marker chooses no loop there)")]


async def test_the_marker_gives_the_virtual_clock() -> None:
    assert isinstance(asyncio.get_running_loop(), VirtualClockLoop)


async def test_a_long_sleep_takes_no_real_time() -> None:
    loop = asyncio.get_running_loop()
    assert isinstance(loop, VirtualClockLoop)
    started, real = loop.time(), time.monotonic()
    await asyncio.sleep(3600)
    # a timer is due within the loop's clock resolution of its time (asyncio's rule)
    assert loop.time() - started >= 3600 - time.get_clock_info("monotonic").resolution
    assert time.monotonic() - real < 600  # far less than the hour (a hang bound only)
    assert loop.jumped > 3500


async def test_the_clock_stands_still_while_the_loop_works() -> None:
    loop = asyncio.get_running_loop()
    before = loop.time()
    time.sleep(0.05)  # noqa: ASYNC251 (a slow turn of the loop: a loaded machine)
    assert loop.time() == before
    fired = loop.create_future()
    loop.call_later(0.01, fired.set_result, None)
    time.sleep(0.05)  # noqa: ASYNC251 (longer than the timer: the clock stood still)
    await asyncio.sleep(0)
    assert not fired.done()
    await fired


async def test_timers_fire_in_order_of_their_virtual_times() -> None:
    fired: list[str] = []
    loop = asyncio.get_running_loop()
    loop.call_later(30, fired.append, "late")
    loop.call_later(10, fired.append, "early")
    await asyncio.sleep(40)
    assert fired == ["early", "late"]


async def test_ready_callbacks_run_before_the_clock_jumps() -> None:
    # A chain of callbacks never waits: a 1 s timeout cannot expire in between.
    loop = asyncio.get_running_loop()
    done = loop.create_future()

    def step(left: int) -> None:
        if left:
            loop.call_soon(step, left - 1)
        else:
            done.set_result(None)

    step(1000)
    async with asyncio.timeout(1.0):
        await done


async def test_a_thread_of_its_own_keeps_real_time() -> None:
    loop = asyncio.get_running_loop()
    assert isinstance(loop, VirtualClockLoop)
    answer = loop.create_future()
    release = threading.Event()

    def work() -> None:
        release.wait(30)
        loop.call_soon_threadsafe(answer.set_result, 42)

    thread = threading.Thread(target=work)
    thread.start()
    # While the thread lives the 5 s timer is not jumped to: the thread answers first.
    loop.call_later(0.05, release.set)
    async with asyncio.timeout(5.0):
        assert await answer == 42
    thread.join()
    assert loop.jumped == 0.0


async def test_a_watched_socket_keeps_real_time_for_good() -> None:
    loop = asyncio.get_running_loop()
    assert isinstance(loop, VirtualClockLoop)
    first, second = socket.socketpair()
    first.setblocking(False)
    with first, second:
        reader, writer = await asyncio.open_connection(sock=first)
        loop.call_later(0.05, second.send, b"late\n")
        async with asyncio.timeout(5.0):
            assert await reader.readline() == b"late\n"
        writer.close()
    assert loop.jumped == 0.0
    await asyncio.sleep(0.01)
    assert loop.jumped == 0.0


async def test_the_emulator_moves_on_the_virtual_clock(emulator: EmulatorFactory) -> None:
    emu = await emulator(travel=400.0)  # limit switches at +-200 mm, 10 mm/s
    loop = asyncio.get_running_loop()
    assert isinstance(loop, VirtualClockLoop)
    real = time.monotonic()
    with pytest.raises(MoveError, match="upper limit switch"):
        await emu.tango.move_to(x=250.0)  # 20 s of travel to the switch
    assert loop.jumped >= 15.0
    assert time.monotonic() - real < 15.0  # a bound on a hang only


def test_the_clock_only_moves_forward() -> None:
    loop = VirtualClockLoop()
    try:
        with pytest.raises(ValueError, match="only moves forward"):
            loop.advance(-1.0)
    finally:
        loop.close()
