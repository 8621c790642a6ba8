"""Cost of a move through the EPICS IOC beside the driver's own ``move_to`` (#28 target 4).

The same move (X between 0 and ``--step`` mm at ``--speed`` mm/s) is made by the driver's
``move_to`` on one emulated controller and by pyepics' ``caput(P:X, target, wait=True)``
in another process, through the IOC (with the put ordering of #26: the put completes
once RBV/DMOV/MOVN are on the wire) serving a second, identical emulated controller in
this process, on loopback: ``--rounds`` alternating chunks of each, so that both see the
same load of a shared machine. Reported: the median time of one move for each, their
ratio (target: at most 1.1), and the median of as many puts that move nothing (TWV), the
client's and the server's own floor. With ``--emulator process`` each of
the two emulated controllers runs in a process of its own (``tango-aio sim --tcp``, with
the ``--url``'s options), reached over TCP on 127.0.0.1 by both the driver and the IOC: the
emulators' timers then no longer share the event loop with the driver and the IOC, as a
real controller's do not. Usage::

    python -m benchmarks.ioc [--moves 100] [--step 0.01] [--speed 100] [--rounds 10]
                             [--url sim://?baud=57600] [--poll 0.1] [--merge-window 0.02]
                             [--emulator inprocess|process]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import socket
import statistics
import sys
import time
import urllib.parse
from collections.abc import AsyncIterator
from typing import Any

import tango_aio

#: The client: for each line ``N`` on stdin, ``N`` puts with callback, each timed, the
#: seconds printed as one JSON line; for ``-N``, ``N`` puts that move nothing (TWV).
CLIENT = """
import json, sys, time, warnings
warnings.simplefilter("ignore")
import epics
pv, step = sys.argv[1], float(sys.argv[2])
assert epics.PV(pv).wait_for_connection(30)
epics.caput(pv, 0.0, wait=True, timeout=60)
print("ready", flush=True)
done = 0
for line in sys.stdin:
    count = int(line)
    times = []
    for i in range(abs(count)):
        start = time.perf_counter()
        if count > 0:
            epics.caput(pv, step if done % 2 == 0 else 0.0, wait=True, timeout=60)
            done += 1
        else:  # a put that moves nothing: the client's and server's own cost
            epics.caput(pv + ".TWV", 0.5 + (i % 2), wait=True, timeout=60)
        times.append(time.perf_counter() - start)
    print(json.dumps(times), flush=True)
"""


def _free_port() -> int:
    with socket.socket() as tcp:
        tcp.bind(("127.0.0.1", 0))
        return int(tcp.getsockname()[1])


def _loopback(port: int) -> None:
    """A loopback-only CA environment for the IOC and its client process."""
    os.environ.update({
        "EPICS_CA_AUTO_ADDR_LIST": "NO", "EPICS_CA_ADDR_LIST": "127.0.0.1",
        "EPICS_CAS_INTF_ADDR_LIST": "127.0.0.1", "EPICS_CAS_AUTO_BEACON_ADDR_LIST": "NO",
        "EPICS_CAS_BEACON_ADDR_LIST": "127.0.0.1", "EPICS_CA_SERVER_PORT": str(port),
        "EPICS_CAS_SERVER_PORT": str(port)})


#: The ``sim://`` options that ``tango-aio sim`` takes as options of its own.
SIM_OPTIONS = ("axes", "baud", "latency", "processing", "speed", "profile", "fingerprint")


def sim_command(url: str) -> list[str]:
    """The ``tango-aio sim --tcp`` command line serving the emulator of a ``sim://`` URL
    on a free loopback port (the other options become ``--switch``es)."""
    query = urllib.parse.parse_qsl(urllib.parse.urlsplit(url).query)
    command = [sys.executable, "-m", "tango_aio", "sim", "--tcp", "127.0.0.1:0"]
    for name, value in query:
        command += [f"--{name}", value] if name in SIM_OPTIONS else ["--switch",
                                                                     f"{name}={value}"]
    return command


@contextlib.asynccontextmanager
async def emulator(url: str, where: str) -> AsyncIterator[str]:
    """The URL to connect to: ``url`` itself (``inprocess``), or the ``socket://`` URL of
    a ``tango-aio sim --tcp`` process serving it (``process``), ended on leaving."""
    if where == "inprocess":
        yield url
        return
    process = await asyncio.create_subprocess_exec(
        *sim_command(url), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    try:
        assert process.stdout is not None
        first = (await asyncio.wait_for(process.stdout.readline(), 30)).decode().strip()
        if not first.startswith("socket://"):
            assert process.stderr is not None
            raise RuntimeError(f"tango-aio sim did not start: {first!r} "
                               f"{(await process.stderr.read()).decode()}")
        yield first
    finally:
        with contextlib.suppress(ProcessLookupError):
            process.terminate()
        await process.wait()


async def _fast(tango: tango_aio.Controller, speed: float) -> None:
    for name, value in (("secvel", max(speed, 10.0)), ("vel", speed), ("accel", 20),
                        ("stopaccel", 20)):
        await tango.set(name, value, axis="x")


class _Client:
    """The pyepics client process, doing chunks of puts on request."""

    def __init__(self, process: asyncio.subprocess.Process) -> None:
        self.process = process

    async def line(self) -> str:
        assert self.process.stdout is not None
        out = await self.process.stdout.readline()
        if not out:
            assert self.process.stderr is not None
            raise RuntimeError((await self.process.stderr.read()).decode())
        return out.decode()

    async def puts(self, count: int) -> list[float]:
        """``count`` timed puts (negative: that many puts to TWV)."""
        assert self.process.stdin is not None
        self.process.stdin.write(f"{count}\n".encode())
        await self.process.stdin.drain()
        return list(json.loads(await self.line()))


async def side_by_side(url: str, moves: int, step: float, speed: float, window: float,
                       poll: float, rounds: int, merge: str = "turn",
                       where: str = "inprocess"
                       ) -> tuple[list[float], list[float], list[float]]:
    """Seconds per move: the driver's ``move_to`` on one emulated controller, and a
    ``caput(wait=True)`` from another process through the IOC serving an identical one,
    in ``rounds`` alternating chunks; then as many puts that move nothing (TWV). The
    emulators run ``where``: ``inprocess`` (``sim://``) or ``process`` (each in a
    ``tango-aio sim --tcp`` process of its own)."""
    from tango_aio.epics.ioc import build_ioc

    _loopback(_free_port())
    # No caRepeater listens on loopback: caproto's beacon failures are no finding here.
    logging.getLogger("caproto.ctx").addFilter(
        lambda record: not record.getMessage().startswith("Failed to send beacon"))
    chunk = max(1, moves // rounds)
    driver_times: list[float] = []
    ioc_times: list[float] = []
    async with emulator(url, where) as own_url, emulator(url, where) as served_url, \
            tango_aio.connect(own_url) as own, tango_aio.connect(served_url) as served:
        await _fast(own, speed)
        await _fast(served, speed)
        await own.move_to(x=0.0)
        # (merge passed only when not the default: the benchmark also runs an older
        # tango_aio, whose build_ioc has no merge, for side-by-side figures)
        options: dict[str, Any] = {} if merge == "turn" else {"merge": merge}
        ioc = await build_ioc({"": served}, "BENCH:", window=window, poll=poll, **options)
        task = asyncio.create_task(ioc.run(["127.0.0.1"]))
        process = await asyncio.create_subprocess_exec(
            sys.executable, "-c", CLIENT, "BENCH:X", str(step), stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        client = _Client(process)
        try:
            if (await client.line()).strip() != "ready":
                raise RuntimeError("the client did not start")
            for _ in range(rounds):
                for _ in range(chunk):
                    start = time.perf_counter()
                    await own.move_to(x=step if len(driver_times) % 2 == 0 else 0.0)
                    driver_times.append(time.perf_counter() - start)
                ioc_times += await client.puts(chunk)
            quick = await client.puts(-moves)
        finally:
            if process.stdin is not None:
                process.stdin.close()
            with contextlib.suppress(ProcessLookupError):
                await asyncio.wait_for(process.wait(), 30)
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    return driver_times, ioc_times, quick


async def main(argv: list[str] | None = None) -> None:
    """Run both, print the medians and the ratio (and a JSON line)."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--moves", type=int, default=100)
    parser.add_argument("--step", type=float, default=0.01)
    parser.add_argument("--speed", type=float, default=100.0,
                        help="X's vel in mm/s (default 100; --step 1 --speed 40: a tile step)")
    parser.add_argument("--rounds", type=int, default=10,
                        help="alternating chunks of driver and IOC moves (default 10)")
    parser.add_argument("--url", default="sim://?baud=57600",
                        help="the emulated controllers (default sim://?baud=57600, the "
                             "wire's pace; sim://?baud=0 for no wire time)")
    parser.add_argument("--merge-window", type=float, default=0.02,
                        help="the IOC's --merge-window (default 0.02, the IOC's own)")
    parser.add_argument("--merge", choices=("turn", "window"), default="turn",
                        help="the IOC's --merge (default turn, the IOC's own)")
    parser.add_argument("--poll", type=float, default=0.1,
                        help="the IOC's --poll (default 0.1, the IOC's own)")
    parser.add_argument("--emulator", choices=("inprocess", "process"), default="inprocess",
                        help="where the two emulators run: in this process (default, "
                             "sharing its event loop) or each in a tango-aio sim --tcp "
                             "process of its own, over TCP on 127.0.0.1")
    args = parser.parse_args(argv)
    driver_times, moved, quick = await side_by_side(
        args.url, args.moves, args.step, args.speed, args.merge_window, args.poll,
        args.rounds, args.merge, args.emulator)
    driver = statistics.median(driver_times)
    ioc, floor = statistics.median(moved), statistics.median(quick)
    print(f"driver move_to: median {driver * 1e3:.2f} ms; IOC caput(wait=True): median "
          f"{ioc * 1e3:.2f} ms; ratio {ioc / driver:.3f} (target <= 1.1); a caput(wait=True) "
          f"that moves nothing (TWV): median {floor * 1e3:.2f} ms; {args.moves} moves of "
          f"{args.step} mm at {args.speed} mm/s on {args.url} in {args.rounds} alternating "
          f"rounds, merge {args.merge} (window {args.merge_window} s), poll {args.poll} s, "
          f"emulators {args.emulator}")
    print(json.dumps({"driver_s": driver, "ioc_s": ioc, "ratio": ioc / driver,
                      "noop_put_s": floor, "emulator": args.emulator}))


if __name__ == "__main__":
    asyncio.run(main())
