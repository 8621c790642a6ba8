"""A concurrent multi-controller scan with anyio: three stages move in lockstep over a grid.

Each grid point is reached by all controllers at once (``ControllerGroup.move_to`` runs the
moves concurrently and returns when every stage has arrived); then every stage is "measured"
concurrently in an anyio task group. The scan takes about as long as one stage alone would.

Runs against three embedded emulators by default; pass URLs to use real controllers:

    python examples/concurrent_scan.py [URL URL ...]
"""

from __future__ import annotations

import sys
import time

import anyio

import tango_aio
from tango_aio import ControllerGroup

#: The grid (mm): 3 x 3 points, 0.5 mm apart, scanned row by row in a serpentine.
XS = (0.0, 0.5, 1.0)
YS = (0.0, 0.5, 1.0)


def serpentine() -> list[tuple[float, float]]:
    """Grid points row by row, every other row backwards (no fly-back moves)."""
    points = []
    for row, y in enumerate(YS):
        for x in XS if row % 2 == 0 else reversed(XS):
            points.append((x, y))
    return points


async def measure(name: str, tango: tango_aio.Controller,
                  results: dict[str, dict[str, float]]) -> None:
    """Stand-in for an acquisition at the current point: read the position."""
    results[name] = await tango.position()


async def main(urls: list[str]) -> None:
    names = [f"stage{index}" for index in range(1, len(urls) + 1)]
    async with ControllerGroup(dict(zip(names, urls, strict=True))) as group:
        print(f"opened {len(group)} controllers concurrently: {', '.join(group)}")
        for name, tango in group.items():
            ident = tango.identity
            assert ident is not None
            print(f"  {name}: {ident.model} {ident.firmware}, {ident.axes} axes")

        # Each stage scans the same grid, shifted by its own offset in Y.
        offsets = {name: 0.25 * index for index, name in enumerate(names)}
        points = serpentine()
        started = time.monotonic()
        for number, (x, y) in enumerate(points, 1):
            targets = {name: {"x": x, "y": y + offsets[name]} for name in names}
            await group.move_to(targets)  # all stages move at once, lockstep

            results: dict[str, dict[str, float]] = {}
            async with anyio.create_task_group() as tg:  # measure everywhere at once
                for name, tango in group.items():
                    tg.start_soon(measure, name, tango, results)
            where = "  ".join(f"{name} x={results[name]['x']:.3f} y={results[name]['y']:.3f}"
                              for name in names)
            print(f"point {number}/{len(points)}: {where}")
        elapsed = time.monotonic() - started

        final = await group.position()
        assert all(abs(final[name]["x"] - points[-1][0]) < 1e-6 for name in names)
        print(f"scanned {len(points)} points on {len(names)} controllers in {elapsed:.2f} s")
        status = await group.status()
        print("final status:", {name: "".join(letters.values())
                                for name, letters in status.items()})


if __name__ == "__main__":
    given = sys.argv[1:]
    anyio.run(main, given or ["sim://?axes=2"] * 3)
