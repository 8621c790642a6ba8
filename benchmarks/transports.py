"""Request latency through the two serial transports: the POSIX descriptor transport
(``transports/_fdlink.py``) and the Windows thread transport
(``transports/_threadlink.py``),
side by side on the same pty (issue #27: "made for them and measured").

The emulator runs in a process of its own (``tango-aio sim --pty``), so that its CPU is not
the driver's. For each transport, in alternating rounds, ``connect()`` opens the pty
(taking that transport's branch) and awaits ``tango.query("?pos")`` ``--requests`` times,
one after the other; each request's round trip is timed. Reported per transport: median,
90th and 99th percentile of the round trip, and the driver process's CPU time per request
(the thread transport pays two thread hand-offs per request, the descriptor transport
none). At ``--baud 0`` the emulator answers at once, so the numbers are the transports'
own; at 57600 Bd the wire's byte times dominate both. Linux only (a pty); on Windows the
thread transport is the only one. Usage::

    python -m benchmarks.transports [--requests 2000] [--rounds 3] [--baud 0]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from dataclasses import dataclass, field

import tango_aio
import tango_aio.controller._connection as connection

try:
    from benchmarks.moves import emulator_pty
except ImportError:  # run as a script from benchmarks/
    from moves import emulator_pty  # type: ignore[no-redef]

TRANSPORTS = ("fdlink (POSIX)", "threadlink (Windows)")


@dataclass
class Timings:
    """Round trips (seconds) and CPU seconds of one transport, over all rounds."""

    trips: list[float] = field(default_factory=list)
    cpu: float = 0.0


def _choose(windows: bool) -> None:
    """Make ``connect()`` take the Windows branch (the thread transport) or the POSIX one."""
    vars(connection).update(WINDOWS=windows, POSIX=not windows)


async def measure(path: str, transport: str, requests: int, timings: Timings) -> None:
    """One round: connect through ``transport``'s branch, time ``requests`` queries."""
    windows = transport.startswith("threadlink")
    _choose(windows)
    async with tango_aio.connect(path, autostatus=None) as tango:
        for _ in range(50):  # warm up
            await tango.query("?pos")
        cpu = time.process_time()
        for _ in range(requests):
            start = time.perf_counter()
            await tango.query("?pos")
            timings.trips.append(time.perf_counter() - start)
        timings.cpu += time.process_time() - cpu


def report(results: dict[str, Timings]) -> str:
    """A Markdown table of the results."""
    rows = ["| transport | median | p90 | p99 | CPU per request |",
            "|---|---|---|---|---|"]
    for name, timings in results.items():
        trips = sorted(timings.trips)
        cuts = statistics.quantiles(trips, n=100)
        rows.append(f"| {name} | {statistics.median(trips) * 1e6:.0f} µs "
                    f"| {cuts[89] * 1e6:.0f} µs | {cuts[98] * 1e6:.0f} µs "
                    f"| {timings.cpu / len(trips) * 1e6:.0f} µs |")
    return "\n".join(rows)


def main() -> None:
    """Run the benchmark and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--baud", default="0", help="the emulator's wire speed (0: instant)")
    args = parser.parse_args()
    results = {name: Timings() for name in TRANSPORTS}
    saved = connection.__dict__["WINDOWS"]
    with emulator_pty("--baud", args.baud) as path:
        try:
            for _ in range(args.rounds):
                for name in TRANSPORTS:
                    asyncio.run(measure(path, name, args.requests, results[name]))
        finally:
            _choose(saved)
    print(f"?pos round trips, {args.rounds} x {args.requests} per transport, "
          f"emulator at baud={args.baud}")
    print(report(results))


if __name__ == "__main__":
    main()
