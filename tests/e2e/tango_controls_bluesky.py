"""A Bluesky scan through ``ophyd_async.tango`` over an axis of ``tango-aio tango-server``,
run in a process of its own by ``test_tango_controls.py``: prints one JSON line with the
scan's targets and the positions its events read.

``python tango_controls_bluesky.py tango://127.0.0.1:PORT/marzhauser/stage/x#dbase=no``
"""

from __future__ import annotations

import json
import sys
from typing import Annotated as A
from typing import Any

import bluesky.plans as bp
from bluesky import RunEngine
from ophyd_async.core import (
    AsyncStatus,
    SignalR,
    SignalRW,
    StandardReadable,
    init_devices,
    wait_for_value,
)
from ophyd_async.core import StandardReadableFormat as Format
from ophyd_async.tango.core import DevStateEnum, TangoDevice

#: The states a move ends in.
ENDED = (DevStateEnum.ON, DevStateEnum.ALARM, DevStateEnum.FAULT)


class MarzhauserTangoAxis(TangoDevice, StandardReadable):
    """An axis device of the server, as an ophyd-async movable: ``set`` writes
    ``Position`` (the server starts the move and returns) and waits for the verdict."""

    # The server's attribute names, as they are spelt there.
    Position: A[SignalRW[float], Format.HINTED_SIGNAL]
    State: SignalR[DevStateEnum]

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        await self.Position.set(value)
        await wait_for_value(self.State, lambda state: state in ENDED, timeout=60)
        state = await self.State.get_value()
        if state != DevStateEnum.ON:
            raise RuntimeError(f"the move to {value} ended in {state}")


def main() -> None:
    engine = RunEngine({})
    with init_devices():
        axis = MarzhauserTangoAxis(sys.argv[1], support_events=True)
    documents: list[tuple[str, Any]] = []
    targets = [0.0, 0.5, 1.0, 1.5, 2.0]
    engine(bp.scan([axis], axis, targets[0], targets[-1], len(targets)),
           lambda name, doc: documents.append((name, doc)))
    readings = [doc["data"][f"{axis.name}-Position"] for name, doc in documents
                if name == "event"]
    print(json.dumps({"targets": targets, "readings": readings}), flush=True)


if __name__ == "__main__":
    main()
