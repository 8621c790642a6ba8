"""Cost of the separators between look-alike requests (#14 item 1), measured side by side.

Two consecutive requests whose replies look alike (``?vel x`` then ``?accel y``: one
number each) are bracketed by a separator, ``?help N``, whose reply ``ERROR N,...`` nothing
else looks like, so that a stray line between them is detected instead of shifting every
later reply. This measures what that costs, in one run, against the previous rule (the
second request only waits until the first is answered, no extra line):

* ``get`` after ``get`` awaited one at a time (the common case: every call pays a
  separator);
* a burst of N look-alike reads issued at once (with separators they are pipelined; the
  wait rule sends them one round trip at a time);
* checked sets (``set`` writes ``!vel ...`` and an ``?err`` probe; probes look alike).

Against the in-process emulator at 57600 Bd 8N2 with 2 ms latency and 0.5 ms processing
per line (the real wire rate), and at ``baud=0`` (the driver's own overhead), in the
driver's default autostatus mode (1) or the one given. Usage::

    python benchmarks/separators.py [--calls 200] [--burst 32] [--rounds 3] [--autostatus 4]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import time
from collections.abc import Awaitable, Callable

import tango_aio
from tango_aio.controller._controller import Controller

WIRE = "sim://?baud=57600&latency=0.002&processing=0.0005"
INSTANT = "sim://?baud=0"


async def _sequential_gets(tango: Controller, calls: int) -> None:
    for index in range(calls):
        await tango.get("vel" if index % 2 else "accel", axis="x")


async def _burst(tango: Controller, calls: int) -> None:
    await asyncio.gather(*(tango.get("vel" if i % 2 else "accel", axis="xyz"[i % 3])
                           for i in range(calls)))


async def _sets(tango: Controller, calls: int) -> None:
    for index in range(calls):
        await tango.set("vel", 10 + index % 7, axis="x")


async def _time(url: str, separators: bool, run: Callable[[Controller, int], Awaitable[None]],
                calls: int, autostatus: int = 1) -> float:
    async with tango_aio.connect(url, autostatus=autostatus) as tango:
        tango.protocol.separators = separators
        await run(tango, 4)  # warm up
        start = time.perf_counter()
        await run(tango, calls)
        return (time.perf_counter() - start) / calls


async def main(calls: int, burst: int, rounds: int, autostatus: int = 1
               ) -> dict[str, dict[str, float]]:
    cases: list[tuple[str, str, Callable[[Controller, int], Awaitable[None]], int]] = [
        ("get after get, 57600 Bd", WIRE, _sequential_gets, calls),
        (f"burst of {burst} reads, 57600 Bd", WIRE, _burst, burst),
        ("checked set after set, 57600 Bd", WIRE, _sets, calls // 2),
        ("get after get, baud=0", INSTANT, _sequential_gets, calls * 5),
        ("checked set after set, baud=0", INSTANT, _sets, calls * 2),
    ]
    results: dict[str, dict[str, float]] = {}
    for name, url, run, count in cases:
        timings: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(rounds):  # interleaved, so that both see the same machine load
            for separators in (False, True):
                timings[separators].append(await _time(url, separators, run, count,
                                                       autostatus))
        wait = statistics.median(timings[False]) * 1e3
        bracket = statistics.median(timings[True]) * 1e3
        results[name] = {"wait rule ms/call": round(wait, 3),
                         "separators ms/call": round(bracket, 3),
                         "ratio": round(bracket / wait, 2)}
        print(f"{name:34s} wait {wait:7.3f} ms  separators {bracket:7.3f} ms  "
              f"ratio {bracket / wait:5.2f}", flush=True)
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=200)
    parser.add_argument("--burst", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--autostatus", type=int, choices=range(5), default=1)
    args = parser.parse_args()
    print(json.dumps(asyncio.run(main(args.calls, args.burst, args.rounds, args.autostatus)),
                     indent=1))
