"""Cost of a proven set (issue 37: every set is proven), measured beside today's set.

In autostatus 0, 1 and 3 a set line owes no answer of its own, so ``set`` writes the read
of the setting behind its ``?err`` probe (``tango_aio.sansio._readback``) and compares the reply:
``!vel x v``, ``?err``, a separator where the scheduler needs one, ``?vel x``, all in one
write and one round trip. Today's set is the same driver with the read-back left out (the
line and its ``?err`` alone: a lost line returned as a success). Both run interleaved, in
one process, ``--rounds`` times each, medians:

* ``set`` after ``set`` awaited one at a time, against the in-process emulator at
  57600 Bd 8N2 with 2 ms latency and 0.5 ms processing per line (the real wire rate),
  and at ``baud=0`` (the driver's own overhead);
* wall time and CPU (``time.process_time``) per call, and the lines the controller
  processed per call (from the emulator's counter).

Usage::

    python benchmarks/sets.py [--calls 100] [--rounds 3] [--mode 1]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import statistics
import time
from unittest import mock

import tango_aio
from tango_aio.testing import faults

WIRE = "sim://?baud=57600&latency=0.002&processing=0.0005"
INSTANT = "sim://?baud=0"


async def _time(url: str, mode: int, proven: bool, calls: int) -> tuple[float, float, float]:
    """Wall seconds, CPU seconds and controller lines per set, for ``calls`` sets."""
    # Today's set: the same driver with no read-back behind the ?err probe.
    today = mock.patch("tango_aio.link._protocol.read_back", lambda command, context: None)
    async with tango_aio.connect(url, autostatus=mode) as tango:
        wire = faults(tango).wire
        with contextlib.nullcontext() if proven else today:
            for index in range(4):  # warm up
                await tango.set("vel", 10 + index % 7, axis="x")
            lines = wire.lines_processed
            wall, cpu = time.perf_counter(), time.process_time()
            for index in range(calls):
                await tango.set("vel", 10 + index % 7, axis="x")
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            return wall / calls, cpu / calls, (wire.lines_processed - lines) / calls


async def main(calls: int, rounds: int, mode: int) -> dict[str, dict[str, float]]:
    cases = [(f"set after set, 57600 Bd, autostatus {mode}", WIRE, calls),
             (f"set after set, baud=0, autostatus {mode}", INSTANT, calls * 5)]
    results: dict[str, dict[str, float]] = {}
    for name, url, count in cases:
        runs: dict[bool, list[tuple[float, float, float]]] = {True: [], False: []}
        for _ in range(rounds):  # interleaved, so that both see the same machine load
            for proven in (False, True):
                runs[proven].append(await _time(url, mode, proven, count))
        today, proof = ([statistics.median(r[i] for r in runs[p]) for i in range(3)]
                        for p in (False, True))
        results[name] = {
            "today ms/set": round(today[0] * 1e3, 3),
            "proven ms/set": round(proof[0] * 1e3, 3),
            "ratio": round(proof[0] / today[0], 2),
            "today CPU ms/set": round(today[1] * 1e3, 3),
            "proven CPU ms/set": round(proof[1] * 1e3, 3),
            "today lines/set": round(today[2], 2),
            "proven lines/set": round(proof[2], 2),
        }
        print(f"{name:40s} today {today[0] * 1e3:7.3f} ms  proven {proof[0] * 1e3:7.3f} ms"
              f"  ratio {proof[0] / today[0]:5.2f}  lines {today[2]:.2f} -> {proof[2]:.2f}",
              flush=True)
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--mode", type=int, default=1, choices=(0, 1, 3))
    args = parser.parse_args()
    print(json.dumps(asyncio.run(main(args.calls, args.rounds, args.mode)), indent=1))
