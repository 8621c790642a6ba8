"""``watch_position`` CPU during a long move, against raw polling at the same rate.

The emulator runs in a process of its own (``tango-aio sim --pty``, 57600 Bd 8N2), so its
CPU is not the client's. On the same pty, one after the other:

* the driver: ``move_to`` a far target at 0.5 mm/s as a task, and ``watch_position(0.1)``
  iterated for ``--seconds``;
* the raw client: a minimal asyncio reader on the pty's file descriptor (``add_reader``,
  ``os.write``) that starts the same kind of move (``!moa``) and every 0.1 s writes
  ``?statusaxis``, waits for its line, writes ``?pos`` and waits for its line;
* the same raw client pipelined: ``?statusaxis\r?pos\r`` in one write, then both lines
  (the two replies have different shapes, so they cannot be mixed up): what pipelining
  the two reads would buy.

Reported: CPU milliseconds (``time.process_time()``) per second of watching, and updates
per second. Usage::

    python benchmarks/watch.py [--seconds 5] [--loop uvloop]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import termios
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import tango_aio

try:  # python -m benchmarks / python benchmarks/watch.py
    from benchmarks.moves import emulator_pty, event_loop
except ImportError:  # pragma: no cover
    from moves import emulator_pty, event_loop  # type: ignore[no-redef]

INTERVAL = 0.1
SLOW = 0.5  # mm/s: a move that outlasts the measurement
LoopFactory = Callable[[], asyncio.AbstractEventLoop]


@dataclass
class Watch:
    """CPU and updates of one way of watching."""

    name: str
    cpu: float
    seconds: float
    updates: int

    @property
    def cpu_ms_per_second(self) -> float:
        """CPU milliseconds per second of watching."""
        return self.cpu * 1e3 / self.seconds


async def driver_watch(path: str, seconds: float) -> Watch:
    """``watch_position`` during a driver move."""
    async with tango_aio.connect(path) as tango:
        await tango.set("vel", x=SLOW)
        start = await tango.position()
        move = asyncio.create_task(tango.move_to(x=-40.0 if start["x"] > 0 else 40.0))
        updates = 0
        cpu, t0 = time.process_time(), time.perf_counter()
        async for _ in tango.watch_position(INTERVAL):
            updates += 1
            if time.perf_counter() - t0 >= seconds:
                break
        result = Watch("driver watch_position(0.1)", time.process_time() - cpu,
                       time.perf_counter() - t0, updates)
        move.cancel()  # stops the axes
        with contextlib.suppress(asyncio.CancelledError):
            await move
    return result


class RawPty:
    """A minimal asyncio client on a pty: ``add_reader`` and ``os.write``."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        attrs = termios.tcgetattr(self.fd)
        attrs[4] = attrs[5] = termios.B57600
        termios.tcsetattr(self.fd, termios.TCSANOW, attrs)
        self.buffer = b""
        self.waiting: deque[asyncio.Future[bytes]] = deque()
        self.loop = asyncio.get_running_loop()
        self.loop.add_reader(self.fd, self._readable)

    def _readable(self) -> None:
        self.buffer += os.read(self.fd, 4096)
        while b"\r" in self.buffer:
            line, _, self.buffer = self.buffer.partition(b"\r")
            if self.waiting:
                self.waiting.popleft().set_result(line)

    async def ask(self, data: bytes, *more: asyncio.Future[bytes]) -> bytes:
        """Write a read and return its reply line; ``more`` get the lines after it."""
        future = self.loop.create_future()
        self.waiting.extend((future, *more))
        os.write(self.fd, data)
        return await future

    def close(self) -> None:
        self.loop.remove_reader(self.fd)
        os.close(self.fd)


async def raw_watch(path: str, seconds: float, pipelined: bool = False) -> Watch:
    """Poll ``?statusaxis`` and ``?pos`` every INTERVAL during a raw move (one after the
    other, or both in one write)."""
    raw = RawPty(path)
    try:
        x = float((await raw.ask(b"?pos\r")).split()[0])
        os.write(raw.fd, f"!vel x {SLOW}\r!moa x {-40.0 if x > 0 else 40.0}\r".encode())
        updates = 0
        cpu, t0 = time.process_time(), time.perf_counter()
        while True:
            if pipelined:
                position = raw.loop.create_future()
                letters = await raw.ask(b"?statusaxis\r?pos\r", position)
                await position
            else:
                letters = await raw.ask(b"?statusaxis\r")
                await raw.ask(b"?pos\r")
            updates += 1
            if b"M" not in letters or time.perf_counter() - t0 >= seconds:
                break
            await asyncio.sleep(INTERVAL)
        result = Watch(f"raw ?statusaxis + ?pos{', pipelined' if pipelined else ''}",
                       time.process_time() - cpu,
                       time.perf_counter() - t0, updates)
        os.write(raw.fd, b"a\r")  # stop; the report "E..." goes unread
        await asyncio.sleep(0.2)
    finally:
        raw.close()
    return result


def run(seconds: float, loop_factory: LoopFactory | None = None
        ) -> tuple[Watch, Watch, Watch]:
    """(driver, raw, raw pipelined), one after the other on one emulator process."""
    with emulator_pty() as path, asyncio.Runner(loop_factory=loop_factory) as runner:
        driver = runner.run(driver_watch(path, seconds))
        raw = runner.run(raw_watch(path, seconds))
        pipelined = runner.run(raw_watch(path, seconds, pipelined=True))
    return driver, raw, pipelined


def main() -> None:
    """Parse the options, run, print."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--loop", choices=("asyncio", "uvloop"), default="asyncio")
    args = parser.parse_args()
    factory = event_loop(args.loop)
    for watch in run(args.seconds, factory):
        print(f"{watch.name:30} {watch.cpu_ms_per_second:6.2f} ms CPU/s "
              f"{watch.updates / watch.seconds:5.2f} updates/s")


if __name__ == "__main__":
    main()
