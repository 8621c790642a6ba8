"""Await moves in an async app, print events and positions while the stage travels.

Runs against the embedded emulator by default; pass a URL to use a real controller:

    python examples/move_and_watch.py [URL]
"""

from __future__ import annotations

import asyncio
import sys

import tango_aio
from tango_aio.events import MoveFinished


async def print_events(tango: tango_aio.Controller) -> None:
    """Print every event the controller pushes."""
    async with tango.events() as events:
        async for event in events:
            if isinstance(event, MoveFinished):
                print(f"event: {event.kind} finished, status {dict(event.statuses)}")
            else:
                print(f"event: {event}")


async def main(url: str) -> None:
    async with tango_aio.connect(url) as tango:
        ident = tango.identity
        assert ident is not None
        print(f"connected to {ident.model} {ident.firmware} with {ident.axes} axes")
        listener = asyncio.create_task(print_events(tango))
        await asyncio.sleep(0)  # let the listener subscribe

        letters = await tango.move_to(x=5.0, y=2.5)
        print(f"move_to done: {letters}, position {await tango.position()}")

        move = asyncio.create_task(tango.move_by(x=-2.0))
        async for update in tango.watch_position(interval=0.05):
            print("position:", {axis: round(value, 4) for axis, value in update.positions.items()})
        await move

        try:
            await tango.move_to(x=1e6)
        except tango_aio.ControllerError as exc:
            print(f"refused as expected: {exc} (number {exc.number})")

        listener.cancel()
        print(f"final position {await tango.position()}")


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1] if len(sys.argv) > 1 else "sim://"))
