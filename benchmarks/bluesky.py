"""Bluesky step-scan benchmark (#28 target 3): a single-axis step-scan point through
``tango_aio.bluesky`` against the driver's own ``move_to`` plus one read.

The emulator runs in a process of its own (``tango-aio sim --pty``, 57600 Bd 8N2, 3 axes,
its default kinematics). On the same pty, in one run, side by side:

* the driver: ``await tango.move_to(x=p)`` then ``await tango.position()`` per point
  (a script's step scan: move, then read where the axis is);
* Bluesky: a ``RunEngine`` running ``bp.list_scan([stage.x], stage.x, points)`` on a
  :class:`~tango_aio.bluesky.MarzhauserStage` (each point: the axis's ``set()``, whose
  limit check reads ``?lim``, then ``trigger_and_read`` of the axis), the run's open and
  close included and spread over the points.

Both are measured in ``--rounds`` alternating chunks (each Bluesky chunk one run). The
points alternate between two positions ``step`` apart: tiny steps (0.01 mm, the wire
is all there is) and tile steps (1 mm, as in a tiled microscope scan). Reported in ms per
point and as Bluesky / driver (target ≤ 1.2). Usage::

    python -m benchmarks.bluesky [--points 100] [--rounds 4]
"""

from __future__ import annotations

import argparse
import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass

import tango_aio
from benchmarks.moves import emulator_pty

TINY, TILE = 0.01, 1.0


@dataclass
class PointCost:
    """Seconds per point of one way of scanning."""

    name: str
    points: int
    seconds: float

    @property
    def ms_per_point(self) -> float:
        """Milliseconds per point."""
        return self.seconds / self.points * 1e3


def targets(points: int, step: float) -> list[float]:
    """``points`` positions alternating between ``step`` and 0."""
    return [step if index % 2 == 0 else 0.0 for index in range(points)]


async def driver_points(path: str, points: int, step: float) -> PointCost:
    """The driver's own step scan: ``move_to`` then ``position()`` per point."""
    async with tango_aio.connect(path) as tango:
        await tango.move_to(x=0.0)
        start = time.perf_counter()
        for target in targets(points, step):
            await tango.move_to(x=target)
            await tango.position()
        seconds = time.perf_counter() - start
    return PointCost(f"driver move_to + ?pos, {step:g} mm steps", points, seconds)


def bluesky_points(path: str, points: int, step: float,
                   loop_factory: Callable[[], asyncio.AbstractEventLoop] | None = None
                   ) -> PointCost:
    """``bp.list_scan`` of one axis through a RunEngine."""
    import bluesky.plans as bp
    from bluesky import RunEngine
    from bluesky.run_engine import call_in_bluesky_event_loop
    from ophyd_async.core import init_devices

    from tango_aio.bluesky import MarzhauserStage

    loop = loop_factory() if loop_factory is not None else asyncio.new_event_loop()
    engine = RunEngine({}, loop=loop, context_managers=[])
    try:
        with init_devices():
            stage = MarzhauserStage(path, axes="x")
        engine(bp.list_scan([], stage.x, [0.0]))
        events: list[float] = []
        token = engine.subscribe(lambda name, doc: events.append(time.perf_counter()),
                                 "event")
        engine(bp.list_scan([stage.x], stage.x, targets(points + 1, step)))
        engine.unsubscribe(token)
        # From the first point's event to the last one's: whole points (set, read, the
        # event), the run's open and close left out.
        seconds = events[-1] - events[0]
        call_in_bluesky_event_loop(stage.aclose(), timeout=30)
    finally:
        loop.call_soon_threadsafe(loop.stop)
        engine._th.join()
        loop.close()
    return PointCost(f"bp.list_scan point, {step:g} mm steps", points, seconds)


def run(points: int, loop_factory: Callable[[], asyncio.AbstractEventLoop] | None = None,
        rounds: int = 4) -> list[tuple[PointCost, PointCost]]:
    """(Bluesky, driver) per step size on one emulator, in ``rounds`` alternating chunks
    of ``points / rounds`` points each (so that both see the same load of a shared
    machine; each Bluesky chunk is a run of its own, timed from its first event to its last)."""
    pairs = []
    chunk = max(1, points // rounds)
    with emulator_pty() as path, asyncio.Runner(loop_factory=loop_factory) as runner:
        for step in (TINY, TILE):
            driver = scan = None
            for _ in range(rounds):
                driver = _add(driver, runner.run(driver_points(path, chunk, step)))
                scan = _add(scan, bluesky_points(path, chunk, step, loop_factory))
            assert scan is not None and driver is not None
            pairs.append((scan, driver))
    return pairs


def _add(total: PointCost | None, part: PointCost) -> PointCost:
    if total is None:
        return part
    return PointCost(total.name, total.points + part.points, total.seconds + part.seconds)


def table(pairs: list[tuple[PointCost, PointCost]]) -> str:
    """The Markdown table BENCHMARKS.md records."""
    rows = ["| Bluesky | ms/point | driver | ms/point | ratio (target ≤ 1.2) |",
            "|---|---:|---|---:|---:|"]
    for scan, driver in pairs:
        rows.append(f"| {scan.name} | {scan.ms_per_point:.1f} | {driver.name} | "
                    f"{driver.ms_per_point:.1f} | "
                    f"**{scan.ms_per_point / driver.ms_per_point:.2f}** |")
    return "\n".join(rows)


def main() -> None:
    """Run the benchmark and print its table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=100, help="points per step size")
    parser.add_argument("--rounds", type=int, default=4,
                        help="alternating chunks of driver and Bluesky points (default 4)")
    args = parser.parse_args()
    print(table(run(args.points, rounds=args.rounds)))


if __name__ == "__main__":
    main()
