"""A trigger-list scan: upload trigger positions, enable the trigger, move across them,
and check with ``trigcount`` that the controller fired once per position.

The upload goes through the driver's write-credit limiter at wire speed (the emulator runs
at the real 57600 Bd here) and is checked along the way; the list is read back to verify
it. Runs against the embedded emulator by default; pass a URL to use a real controller:

    python examples/trigger_scan.py [URL]
"""

from __future__ import annotations

import asyncio
import sys
import time

import tango_aio

#: 40 trigger positions on X, every 0.1 mm from 0.5 mm on.
POSITIONS = [round(0.5 + 0.1 * index, 4) for index in range(40)]


async def main(url: str) -> None:
    async with tango_aio.connect(url) as tango:
        print(f"connected to {url}")
        await tango.move_to(x=0.0)  # start in front of the first position

        started = time.monotonic()
        await tango.triggers.upload_positions(
            POSITIONS, axis="x",
            progress=lambda done, total: print(f"uploaded {done}/{total} positions"))
        print(f"upload took {time.monotonic() - started:.3f} s")
        read_back = await tango.triggers.read_positions()
        assert read_back == POSITIONS, read_back
        print(f"read back {len(read_back)} positions: {read_back[0]} ... {read_back[-1]} mm")

        await tango.command("!trigcount 0")  # clear the pulse counter
        await tango.command("!trig 1")       # the list only fires once enabled
        end = POSITIONS[-1] + 0.5
        print(f"moving X across the list to {end} mm")
        await tango.move_to(x=end)
        await tango.command("!trig 0")

        fired = int(await tango.get("trigcount"))
        print(f"trigcount = {fired} (positions passed: {len(POSITIONS)})")
        if fired != len(POSITIONS):
            raise SystemExit(f"expected {len(POSITIONS)} trigger pulses, got {fired}")
        print("trigger scan ok")


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1] if len(sys.argv) > 1 else "sim://"))
