"""The emulator's power cycle behind a live link (issue 32 item 5): ``Wire.power_cycle``
and :meth:`tango_aio.testing.Faults.power_cycle`."""

from __future__ import annotations

import pytest

from tango_aio.sim.clock import ScaledHandler
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.wire import Emit, Wire, WireConfig

pytestmark = pytest.mark.timeout(30)


class Link:
    """A controller on a wire at 57600 Bd, driven in virtual time."""

    def __init__(self) -> None:
        self.now = 0.0
        self.wire = Wire(lambda emit: ControllerModel(emit, SimConfig(axes=2), now=0.0),
                         WireConfig())
        self._partial = b""

    def lines_after(self, seconds: float, *sent: str) -> list[str]:
        if sent:
            self.wire.feed(b"".join(s.encode() + b"\r" for s in sent), self.now)
        self.now += seconds
        data = self._partial + self.wire.poll(self.now)
        *lines, self._partial = data.split(b"\r")
        return [line.decode() for line in lines]


def test_a_power_cycle_loses_what_was_held_and_restarts_at_power_on() -> None:
    link = Link()
    assert link.lines_after(0.1, "!autostatus 4", "!vel x 3") == ["!vel x 3"]  # echoed
    assert "3.000" in link.lines_after(0.1, "?vel x")  # set, in mode 4 (echo aside)
    link.wire.feed(b"?vel x\r", link.now)
    link.now += 0.0005  # a byte or so of the line has arrived
    link.wire.power_cycle(0.5, link.now)
    assert link.lines_after(0.2, "?autostatus") == []  # off: both lines lost
    assert link.wire.lost_bytes >= len("?autostatus\r")
    assert link.lines_after(0.4) == []  # nothing was owed any more
    # Back at power-on: autostatus 1 (no echo), the setting back to its power-on value.
    assert link.lines_after(0.1, "?autostatus", "?vel x") == ["1", "10.000"]


def test_a_power_cycle_cuts_a_reply_on_its_way() -> None:
    link = Link()
    link.wire.feed(b"?version\r", link.now)
    link.now += 0.004  # the line has arrived, a few reply bytes have left
    link.wire.power_cycle(0.1, link.now)
    assert link.lines_after(0.5) == []  # no CR came: only the start of the reply
    start = link._partial.decode()
    assert start and start.startswith("TANGO")  # the bytes that had left stay
    first = link.lines_after(0.1, "?version")  # the cut start, then a whole reply
    assert len(first) == 1 and first[0].startswith(start)
    whole = first[0][len(start):]
    assert link.lines_after(0.1, "?version") == [whole] and len(start) < len(whole)


def test_a_scaled_controller_reboots_on_its_own_time() -> None:
    def make(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, SimConfig(axes=1), now=0.0)

    handler = ScaledHandler(make, lambda data: None, speed=20.0, origin=0.0)
    model = handler.handler
    assert isinstance(model, ControllerModel)
    model.handle_line(b"!autostatus 3", 0.0)
    handler.reboot(1.0)
    assert model.motion.now == pytest.approx(20.0)
