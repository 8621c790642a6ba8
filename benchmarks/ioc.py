"""Cost of a move through the EPICS IOC beside the driver's own ``move_to`` (#28 target 4).

The same short move (X between 0 and ``--step`` mm, fast motion) is made ``--moves`` times
by the driver's ``move_to`` on one emulated controller, then ``--moves`` times by pyepics'
``caput(P:X, target, wait=True)`` in another process, through the IOC (with the put
ordering of #26: the put completes once RBV/DMOV/MOVN are on the wire) serving a second,
identical emulated controller in this process, on loopback. Reported: the median time
of one move for each, and their ratio (target: at most 1.1). Usage::

    python -m benchmarks.ioc [--moves 100] [--step 0.01] [--url 'sim://?baud=0']
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import socket
import statistics
import sys
import time

import tango_aio

#: The client: ``moves`` puts with callback, each timed, medians printed as JSON.
CLIENT = """
import json, sys, time, warnings
warnings.simplefilter("ignore")
import epics
pv, moves, step = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
assert epics.PV(pv).wait_for_connection(30)
epics.caput(pv, 0.0, wait=True, timeout=60)
times = []
for i in range(moves):
    start = time.perf_counter()
    epics.caput(pv, step if i % 2 == 0 else 0.0, wait=True, timeout=60)
    times.append(time.perf_counter() - start)
quick = []
for i in range(moves):  # a put that moves nothing: the client's and server's own cost
    start = time.perf_counter()
    epics.caput(pv + ".TWV", 0.5 + (i % 2), wait=True, timeout=60)
    quick.append(time.perf_counter() - start)
print(json.dumps([times, quick]))
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


async def _fast(tango: tango_aio.Controller) -> None:
    for name, value in (("vel", 100), ("accel", 20), ("stopaccel", 20)):
        await tango.set(name, value, axis="x")


async def driver_moves(url: str, moves: int, step: float) -> list[float]:
    """Seconds per ``move_to`` of the driver, alternating 0 and ``step``."""
    async with tango_aio.connect(url) as tango:
        await _fast(tango)
        await tango.move_to(x=0.0)
        times = []
        for i in range(moves):
            start = time.perf_counter()
            await tango.move_to(x=step if i % 2 == 0 else 0.0)
            times.append(time.perf_counter() - start)
        return times


async def ioc_moves(url: str, moves: int, step: float, window: float,
                    poll: float = 0.1) -> tuple[list[float], list[float]]:
    """Seconds per ``caput(wait=True)`` through the IOC, from another process: of the
    moves, and of as many puts that move nothing (TWV), the client's own floor."""
    from tango_aio.epics.ioc import build_ioc

    _loopback(_free_port())
    async with tango_aio.connect(url) as tango:
        await _fast(tango)
        ioc = await build_ioc({"": tango}, "BENCH:", window=window, poll=poll)
        task = asyncio.create_task(ioc.run(["127.0.0.1"]))
        try:
            process = await asyncio.create_subprocess_exec(
                sys.executable, "-c", CLIENT, "BENCH:X", str(moves), str(step),
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
            out, err = await process.communicate()
            if process.returncode != 0:
                raise RuntimeError(err.decode())
            moved, quick = json.loads(out.decode().strip().splitlines()[-1])
            return list(moved), list(quick)
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


async def main(argv: list[str] | None = None) -> None:
    """Run both, print the medians and the ratio (and a JSON line)."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--moves", type=int, default=100)
    parser.add_argument("--step", type=float, default=0.01)
    parser.add_argument("--url", default="sim://?baud=0")
    parser.add_argument("--merge-window", type=float, default=0.02,
                        help="the IOC's --merge-window (default 0.02, the IOC's own)")
    args = parser.parse_args(argv)
    driver = statistics.median(await driver_moves(args.url, args.moves, args.step))
    moved, quick = await ioc_moves(args.url, args.moves, args.step, args.merge_window)
    ioc, floor = statistics.median(moved), statistics.median(quick)
    print(f"driver move_to: median {driver * 1e3:.2f} ms; IOC caput(wait=True): median "
          f"{ioc * 1e3:.2f} ms; ratio {ioc / driver:.2f} (target <= 1.1); a caput(wait=True) "
          f"that moves nothing (TWV): median {floor * 1e3:.2f} ms; "
          f"{args.moves} moves of {args.step} mm on {args.url}, merge window "
          f"{args.merge_window} s")
    print(json.dumps({"driver_s": driver, "ioc_s": ioc, "ratio": ioc / driver,
                      "noop_put_s": floor}))


if __name__ == "__main__":
    asyncio.run(main())
