"""A move line whose acceptance rests only on the ``?err`` behind it (its autostatus-2
``OK...`` or autostatus-4 echo did not come where owed) is proven before
``command()`` returns: firmware that sends them with the completion report (switches
``move_ok=completion``, ``echo=completion``) still succeeds, and a lost move line raises
MoveOutcomeUnknown instead of a false success (prime rule 1)."""

from __future__ import annotations

import pytest
from helpers import settled_position, wait_until

import tango_aio
from tango_aio import MoveOutcomeUnknown, TangoError
from tango_aio.testing import faults

pytestmark = pytest.mark.virtual_clock


@pytest.mark.parametrize("mode", [2, 4])
async def test_a_lost_move_line_is_not_taken_as_accepted(mode: int,
                                                         monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    async with tango_aio.connect("sim://?baud=0", autostatus=mode,
                                 reply_timeout=2.0) as tango:
        fault = faults(tango)
        suspected: list[bool] = []
        watch = tango._restarts
        monkeypatch.setattr(watch, "suspect", lambda: suspected.append(True))
        fault.lose_line("!mor")
        with pytest.raises(MoveOutcomeUnknown, match="could not be proven"):
            await tango.command("!mor 0.5")
        assert fault.wire.lost_lines == 1
        assert suspected  # the restart watch reads the mode
        assert await settled_position(fault) == 0.0
        # The next calls work: the lost move's report is not awaited any more.
        await tango.command("!mor 0.25")
        assert await settled_position(fault) == pytest.approx(0.25, abs=1e-3)
        await tango.move_by(x=0.25)
        assert await settled_position(fault) == pytest.approx(0.5, abs=1e-3)
        assert (await tango.position())["x"] == pytest.approx(0.5, abs=1e-3)


@pytest.mark.parametrize("mode", [2, 4])
@pytest.mark.parametrize(("method", "prefix"), [("move_by", "!mor"), ("move_to", "!moa")])
async def test_a_lost_move_line_fails_a_waiting_move(mode: int, method: str,
                                                     prefix: str) -> None:
    """move_to/move_by wait for the report and confirm the position: a lost line makes
    them fail (typed), never return, and the next move works."""
    async with tango_aio.connect("sim://?baud=0", autostatus=mode,
                                 reply_timeout=2.0) as tango:
        fault = faults(tango)
        fault.lose_line(prefix)
        with pytest.raises(TangoError):
            await getattr(tango, method)(x=0.5)
        assert fault.wire.lost_lines == 1
        assert await settled_position(fault) == 0.0
        await tango.move_by(x=0.25)
        assert await settled_position(fault) == pytest.approx(0.25, abs=1e-3)


@pytest.mark.parametrize(("mode", "switch", "counter"), [
    (2, "move_ok=completion", "ok@completion"),
    (4, "echo=completion", "echo@completion"),
])
async def test_a_deferred_acceptance_is_proven_and_returns(mode: int, switch: str,
                                                           counter: str) -> None:
    async with tango_aio.connect(f"sim://?baud=0&{switch}", autostatus=mode,
                                 reply_timeout=2.0) as tango:
        fault = faults(tango)
        await tango.command("!mor 0.5")
        assert await settled_position(fault) == pytest.approx(0.5, abs=1e-3)
        await tango.command("!mor 0.25")
        assert await settled_position(fault) == pytest.approx(0.75, abs=1e-3)
        await tango.move_by(x=0.25)
        assert await settled_position(fault) == pytest.approx(1.0, abs=1e-3)
        assert (await tango.position())["x"] == pytest.approx(1.0, abs=1e-3)
        # The OK... or echo did come with the report: the deferred path was taken.
        await wait_until(lambda: tango.protocol.core.tolerated.get(counter, 0) >= 3,
                         timeout=30.0)
