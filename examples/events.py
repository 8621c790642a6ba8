"""Subscribe to a controller's events: two subscribers, each sees every event.

One subscriber logs everything (MoveFinished, StatusReport, UnsolicitedLine, ...); the
other only waits for moves to finish and counts the failed ones. Each subscription has its
own bounded buffer, so a slow subscriber never holds up the driver or the other one.

Runs against the embedded emulator by default; pass a URL to use a real controller (the
unsolicited line is then only shown if the controller happens to send one):

    python examples/events.py [URL]
"""

from __future__ import annotations

import asyncio
import sys

import tango_aio
from tango_aio.events import (
    MoveFinished,
    StatusReport,
    Subscription,
    TangoEvent,
    UnsolicitedLine,
)
from tango_aio.sim.wire import Wire


def describe(event: TangoEvent) -> str:
    """One line per event."""
    if isinstance(event, MoveFinished):
        state = "ok" if event.ok else "FAILED"
        return f"MoveFinished {event.kind} {dict(event.statuses)} ({state})"
    if isinstance(event, StatusReport):
        return f"StatusReport {dict(event.statuses)} from line {event.line!r}"
    if isinstance(event, UnsolicitedLine):
        return f"UnsolicitedLine {event.line!r}"
    return type(event).__name__


async def logger(events: Subscription) -> None:
    """Subscriber 1: print every event."""
    async for event in events:
        print(f"[logger] {describe(event)}")


async def move_watcher(events: Subscription, done: asyncio.Event) -> None:
    """Subscriber 2: only moves; stop after the fourth."""
    finished = failed = 0
    async for event in events:
        if isinstance(event, MoveFinished):
            finished += 1
            failed += not event.ok
            print(f"[moves]  move {finished} finished, {failed} failed so far")
            if finished == 4:
                done.set()
                return


async def main(url: str) -> None:
    async with tango_aio.connect(url) as tango:
        print(f"connected to {url}")
        # Subscribe before anything happens: a subscription sees the events published
        # after it was created.
        log_sub, move_sub = tango.events(), tango.events(maxsize=16)
        done = asyncio.Event()
        async with log_sub, move_sub:
            tasks = [asyncio.create_task(logger(log_sub)),
                     asyncio.create_task(move_watcher(move_sub, done))]

            await tango.move_to(x=1.0, y=0.5)
            await tango.move_by(x=-0.5)
            # A fast Z, then a move that runs into its lower limit switch (at -50 mm in the
            # emulator): the move finishes with status S and move_to raises MoveError.
            for name, value in (("secvel", 100), ("vel", 100), ("accel", 20),
                                ("stopaccel", 20)):
                await tango.set(name, value, axis="z")
            try:
                await tango.move_to(z=-55.0)
            except tango_aio.MoveError as exc:
                print(f"move_to raised MoveError: {dict(exc.statuses)}")
            await tango.move_to(z=0.0)

            # Disabling an enabled joystick makes the controller push a status report that
            # no move waits for: a StatusReport event.
            await tango.command("!joy 1")
            await tango.command("!joy 0")

            # A line no request waits for becomes an UnsolicitedLine. The emulator can
            # push one on demand; a real controller rarely sends such lines.
            transport = tango.protocol.transport
            wire = transport.get_extra_info("wire") if transport is not None else None
            if isinstance(wire, Wire):
                wire.emit(b"hello from the controller\r")

            await asyncio.wait_for(done.wait(), 5.0)
            await asyncio.sleep(0.1)  # let the logger print the last events
            for task in tasks:
                task.cancel()
            print(f"logger dropped {log_sub.dropped} events, move watcher {move_sub.dropped}")


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1] if len(sys.argv) > 1 else "sim://?baud=0"))
