"""Bluesky on a TANGO stage: step scan, grid scan, fly scan, pause/resume and stop.

Runs against the in-process emulator; pass a port to use a real controller
(``python examples/bluesky_scan.py /dev/ttyUSB0``). Needs the bluesky extra
(``pip install -e '.[bluesky]'`` in the checkout).
"""

from __future__ import annotations

import asyncio
import sys
import threading
from typing import Any

import bluesky.plan_stubs as bps
import bluesky.plans as bp
from bluesky import RunEngine, RunEngineInterrupted
from bluesky.run_engine import call_in_bluesky_event_loop
from ophyd_async.core import init_devices

from tango_aio.bluesky import MarzhauserFlyer, MarzhauserStage, fly_raster

URL = sys.argv[1] if len(sys.argv) > 1 else "sim://?baud=0"


def print_rows(name: str, doc: dict[str, Any]) -> None:
    """A tiny document callback: one line per event (row of an event page)."""
    if name == "start":
        print(f"-- run {doc['plan_name']}")
    elif name == "event":
        print("   ", {key: round(value, 4) for key, value in doc["data"].items()})
    elif name == "event_page":
        for row in zip(*doc["data"].values(), strict=True):
            print("   ", dict(zip(doc["data"], row, strict=True)))
    elif name == "stop":
        print(f"-- {doc['exit_status']}, {sum(doc['num_events'].values())} events")


async def set_speed(stage: MarzhauserStage, velocity: float) -> None:
    """Velocity and acceleration of both axes (also: ``bps.mv(stage.x.velocity, ...)``)."""
    for name, value in (("secvel", 100), ("vel", velocity), ("accel", 20)):
        await stage.controller.set(name, x=value, y=value)


def main() -> None:
    RE = RunEngine({})
    RE.subscribe(print_rows)
    with init_devices():  # connects on the RunEngine's event loop
        stage = MarzhauserStage(URL, axes="xy")
        flyer = MarzhauserFlyer(stage)
    call_in_bluesky_event_loop(set_speed(stage, 50))

    # 1. Step scan of two axes together: each step is one merged "!moa x y" line.
    RE(bp.scan([stage], stage.x, 0, 2, stage.y, 0, 1, 5))

    # 2. Grid scan (snake), and a plain move of both axes.
    RE(bp.grid_scan([stage], stage.y, 0, 1, 3, stage.x, 0, 2, 3, snake_axes=True))
    RE(bps.mv(stage.x, 0.5, stage.y, 0.25))

    # 3. Raster fly scan: 3 rows, 11 trigger pulses per row on X (hardware triggered).
    RE(fly_raster(stage, flyer, 0, 2, 11, 0, 1, 3, run_up=0.25))

    # 4. Pause during a step, then resume: the step is repeated from its checkpoint.
    RE(bps.mv(stage.x, 0, stage.y, 0))
    call_in_bluesky_event_loop(set_speed(stage, 5))
    requested = threading.Event()

    def pause_while_moving(reading: dict[str, Any]) -> None:
        if 0.3 < reading["stage-x"]["value"] < 0.9 and not requested.is_set():
            requested.set()
            threading.Thread(target=RE.request_pause).start()  # not from the loop thread

    async def watch(subscribe: bool) -> None:
        if subscribe:
            stage.x.subscribe_reading(pause_while_moving)
        else:
            stage.x.clear_sub(pause_while_moving)

    call_in_bluesky_event_loop(watch(True))
    try:
        RE(bp.scan([stage], stage.x, 0, 2, 3))
    except RunEngineInterrupted:
        position = call_in_bluesky_event_loop(stage.controller.position())
        print(f"paused ({RE.state}) with x standing at {position['x']:.3f}; resuming")
        RE.resume()
    finally:
        call_in_bluesky_event_loop(watch(False))

    # 5. Stop during a move: the axes stop at once and the move's status fails.
    async def move_and_stop() -> None:
        status = stage.x.set(0.0)
        await asyncio.sleep(0.1)
        await stage.x.stop(success=False)
        try:
            await status
        except RuntimeError as exc:
            where = await stage.controller.position()
            print(f"stopped: {exc} (x at {where['x']:.3f})")

    call_in_bluesky_event_loop(move_and_stop())
    call_in_bluesky_event_loop(stage.aclose())
    print("bluesky example done")


if __name__ == "__main__":
    main()
