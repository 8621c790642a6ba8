"""A focus stage's position sequence run as the trigger position list: the stage
travels through the positions in one move and the controller pulses its trigger output
as it passes each (manual chapter 21)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

#: The trigger position list holds up to 10000 entries (``trigp`` L13773, ``trigr``
#: L13515).
MAX_LENGTH = 10_000


def run_through(positions: Sequence[float]) -> tuple[float, float]:
    """Where the move that passes ``positions`` starts and ends: one step before the first
    and one step past the last, as the manual's example runs ``!trigr x 10 20 11`` with
    ``moa 9`` then ``moa 21`` (L13700-13720); "the move must start from below the start
    position and travel past the end position" (L13585-13586)."""
    values = [float(value) for value in positions]
    if len(values) < 2:
        raise ValueError(f"a sequence passes at least two positions, got {len(values)}")
    if not all(math.isfinite(value) for value in values):
        raise ValueError(f"a sequence position is not finite: {values!r}")
    steps = [after - before for before, after in itertools.pairwise(values)]
    if not (all(step > 0 for step in steps) or all(step < 0 for step in steps)):
        raise ValueError("a trigger sequence is unidirectional: its positions must be "
                         "strictly increasing or strictly decreasing (manual L13810-13812)")
    return values[0] - steps[0], values[-1] + steps[-1]


async def run_sequence(tango: Any, axis: str, start: float, end: float) -> None:
    """In the driver's thread: move ``axis`` to ``start`` (behind the first position,
    where the list re-arms), reset the trigger counter, switch the trigger output on and
    move to ``end``; each move ends with the driver's verdict."""
    await tango.move_to(**{axis: start})
    await tango.triggers.set_count(0)
    await tango.triggers.set_enabled(True)
    await tango.move_to(**{axis: end})
