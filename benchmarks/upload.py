"""Upload and download benchmark: the write-credit limiter against stop-and-wait.

Runs against the in-process emulator in real-time wire mode (57600 Bd 8N2, 2 ms reply
latency, 0.5 ms processing per line, a 50 ms stall every 1000 lines) and measures, in one
run, side by side:

* uploading N trigger positions with ``triggers.upload_positions`` (pipelined, credit-limited);
* the same upload stop-and-wait: write a line, ``?err``, wait for the reply, next line, which
  is what the manual recommends and what existing drivers do;
* downloading 1024 snapshot rows with ``snapshots.read_positions`` (pipelined) and one row at
  a time.

Each is compared with its wire-time lower bound: payload bytes x 11 / baud (host to
controller for uploads, controller to host for downloads). The emulator's lost-byte counter
is reported too. Usage::

    python benchmarks/upload.py [--entries 10000] [--rows 1024] [--chunk N]
    python benchmarks/upload.py --pty --entries 1000   # plain pty vs 2 ms adapter latency

With ``--pty`` it measures instead the pipelined upload against stop-and-wait on a pty
served by an emulator process (``tango-aio sim --pty``, 57600 Bd), once with no reply
latency (a plain pty) and once with 2 ms (a typical USB serial adapter).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from collections.abc import Awaitable, Callable
from dataclasses import asdict, dataclass
from typing import Any

import tango_aio
from tango_aio.catalog._encode import build

try:  # python -m benchmarks / python benchmarks/upload.py
    from benchmarks.moves import emulator_pty
except ImportError:  # pragma: no cover
    from moves import emulator_pty  # type: ignore[no-redef]

URL = "sim://?baud=57600&latency=0.002&processing=0.0005&stall_every=1000&stall=0.05"
BAUD = 57600
BITS_PER_BYTE = 11


@dataclass
class Result:
    """One measurement."""

    name: str
    seconds: float
    bound_seconds: float
    #: The emulator's lost-byte counter (None: an emulator process, not counted here).
    lost_bytes: int | None

    @property
    def efficiency(self) -> float:
        """Wire bound divided by the measured time (1.0 = wire speed)."""
        return self.bound_seconds / self.seconds


def wire_seconds(byte_count: int) -> float:
    """Time the wire needs for ``byte_count`` bytes at 57600 Bd 8N2."""
    return byte_count * BITS_PER_BYTE / BAUD


def positions(count: int) -> list[float]:
    """A monotonic trigger list with 4-decimal positions (typical scan lines)."""
    return [round(0.0123 + index * 0.0137, 4) for index in range(count)]


async def timed(action: Callable[[], Awaitable[Any]]) -> float:
    """Seconds ``action`` takes."""
    start = time.perf_counter()
    await action()
    return time.perf_counter() - start


async def measure(name: str, bound: float, body: Callable[[tango_aio.Controller],
                                                      Awaitable[Any]],
                  chunk: int | None, autostatus: int = 1) -> Result:
    """Run ``body`` on a fresh emulator (in ``autostatus``) and time it."""
    async with tango_aio.connect(URL, reply_timeout=30.0, autostatus=autostatus) as tango:
        if chunk:
            tango.protocol.credit.chunk = chunk
        wire = tango.protocol.transport.get_extra_info("wire")  # type: ignore[union-attr]
        seconds = await timed(lambda: body(tango))
        return Result(name, seconds, bound, wire.lost_bytes)


def payload_bound(values: list[float]) -> float:
    """Wire seconds of the ``!trigp -1 pos`` lines of ``values``."""
    return wire_seconds(sum(len(build("trigp", -1, v).to_bytes()) for v in values))


async def single_link(entries: int, autostatus: int = 1) -> Result:
    """The pipelined upload of ``entries`` positions under the benchmark's stalls. In
    autostatus 2 the controller acknowledges every ``!trigp`` line, which confirms its
    bytes: no credit markers (L2099-2103)."""
    values = positions(entries)
    return await measure(f"upload trigp, credit-limited pipeline, autostatus {autostatus}",
                         payload_bound(values), lambda t: upload_pipelined(values, t), None,
                         autostatus)


async def pty_pair(path: str, entries: int, latency: float) -> list[Result]:
    """Pipelined and stop-and-wait uploads to the emulator process on ``path``."""
    values = positions(entries)
    bound = payload_bound(values)
    results = []
    for name, body in (("pipelined", upload_pipelined), ("stop-and-wait", upload_stop_and_wait)):
        async with tango_aio.connect(path, reply_timeout=30.0) as tango:
            seconds = await timed(lambda: body(values, tango))  # noqa: B023
        results.append(Result(f"pty, latency {latency * 1e3:g} ms, {name}", seconds, bound,
                              None))
    return results


def pty_comparison(entries: int, latencies: tuple[float, ...] = (0.0, 0.002),
                   loop_factory: Callable[[], asyncio.AbstractEventLoop] | None = None
                   ) -> list[Result]:
    """[pipelined, stop-and-wait] per reply latency, each on a fresh emulator process."""
    results = []
    with asyncio.Runner(loop_factory=loop_factory) as runner:
        for latency in latencies:
            with emulator_pty("--latency", str(latency)) as path:
                results += runner.run(pty_pair(path, entries, latency))
    return results


async def upload_pipelined(values: list[float], tango: tango_aio.Controller) -> None:
    await tango.triggers.upload_positions(values)


async def upload_stop_and_wait(values: list[float], tango: tango_aio.Controller) -> None:
    await tango.command("!trigp x 0")
    for value in values:
        await tango.command(build("trigp", -1, value).line)  # line, ?err, wait
    assert int(await tango.get("trigc")) == len(values)


def snapshot_rows(count: int) -> list[list[float]]:
    """Rows of three positions."""
    return [[round(i * 0.01, 4), round(i * 0.02, 4), round(i * 0.03, 4)] for i in range(count)]


async def download_pipelined(tango: tango_aio.Controller, count: int) -> None:
    rows = await tango.snapshots.read_positions()
    assert len(rows) == count


async def download_one_by_one(tango: tango_aio.Controller, count: int) -> None:
    for index in range(1, count + 1):
        await tango.get("snsa", index)


async def snapshot_case(name: str, rows: list[list[float]], chunk: int | None,
                        pipelined: bool) -> Result:
    async with tango_aio.connect(URL, reply_timeout=30.0) as tango:
        if chunk:
            tango.protocol.credit.chunk = chunk
        await tango.snapshots.upload_positions(rows)
        # Reply bytes (CR included) of every row, read once before the timed run.
        reply_bytes = sum([len(await tango.query(f"?snsa {i}")) + 1
                           for i in range(1, len(rows) + 1)])
        wire = tango.protocol.transport.get_extra_info("wire")  # type: ignore[union-attr]
        action = download_pipelined if pipelined else download_one_by_one
        seconds = await timed(lambda: action(tango, len(rows)))
        return Result(name, seconds, wire_seconds(reply_bytes), wire.lost_bytes)


async def main(entries: int, rows: int, chunk: int | None) -> list[Result]:
    values = positions(entries)
    payload = sum(len(build("trigp", -1, v).to_bytes()) for v in values)
    bound = wire_seconds(payload)
    results = [
        await measure("upload trigp, credit-limited pipeline", bound,
                      lambda t: upload_pipelined(values, t), chunk),
        await measure("upload trigp, stop-and-wait (line, ?err, wait)", bound,
                      lambda t: upload_stop_and_wait(values, t), chunk),
    ]
    snap = snapshot_rows(rows)
    results.append(await snapshot_case("download snsa, pipelined", snap, chunk, True))
    results.append(await snapshot_case("download snsa, one at a time", snap, chunk, False))
    return results


def table(results: list[Result]) -> None:
    """Print one row per result."""
    for r in results:
        lost = "-" if r.lost_bytes is None else str(r.lost_bytes)
        print(f"{r.name:50} {r.seconds:9.2f} {r.bound_seconds:9.2f} {r.efficiency:9.3f} "
              f"{lost:>6}")


def report(results: list[Result], entries: int, rows: int) -> None:
    print(f"emulator: {URL}")
    print(f"{'case':50} {'seconds':>9} {'bound s':>9} {'of bound':>9} {'lost':>6}")
    table(results)
    speedup = results[1].seconds / results[0].seconds
    dl_speedup = results[3].seconds / results[2].seconds
    print(f"upload speed-up over stop-and-wait: {speedup:.2f}x ({entries} entries)")
    print(f"download speed-up over one at a time: {dl_speedup:.2f}x ({rows} rows)")
    print(json.dumps([asdict(r) | {"efficiency": r.efficiency} for r in results]))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--entries", type=int, default=10000)
    parser.add_argument("--rows", type=int, default=1024)
    parser.add_argument("--chunk", type=int, default=None,
                        help="marker chunk in bytes (default: the driver's)")
    parser.add_argument("--pty", action="store_true",
                        help="plain pty vs 2 ms latency, pipelined vs stop-and-wait")
    args = parser.parse_args()
    if args.pty:
        pairs = pty_comparison(args.entries)
        table(pairs)
        for index in range(0, len(pairs), 2):
            print(f"{pairs[index].name.split(',')[1]}: upload is "
                  f"{pairs[index + 1].seconds / pairs[index].seconds:.2f}x stop-and-wait")
        raise SystemExit
    report(asyncio.run(main(args.entries, args.rows, args.chunk)), args.entries, args.rows)
