"""Physical units on firmware of the older edition, which has no ``usteps`` (old L863-900):
the conversion reads dim, pitch and gear only, instead of waiting for a reply to
``?usteps`` that never comes."""

from __future__ import annotations

import pytest
from helpers import EmulatorFactory

from tango_aio.units import DEFAULT_USTEPS


async def test_units_work_on_the_older_edition(emulator: EmulatorFactory) -> None:
    emu = await emulator("sim://?baud=0&profile=legacy", units="um")
    tango = emu.tango
    assert tango.identity.family == "older"
    await tango.move_to(x=1500.0, y=-250.0)
    assert await tango.position() == pytest.approx({"x": 1500.0, "y": -250.0, "z": 0.0})
    assert (await tango.get("pos"))["x"] == pytest.approx(1.5)  # dim 2: mm
    assert {scale.usteps for scale in (await tango.unit_scales()).values()} == {
        DEFAULT_USTEPS}
