"""Physical units at the public boundary (issue 15 item 3): pure conversions and the
controller's ``unit=``/``units=`` parameters on the emulator, whatever ``dim`` and pitch."""

from __future__ import annotations

import asyncio
import logging

import pytest

import tango_aio
from tango_aio.units import (
    Measure,
    UnitScale,
    check_unit,
    from_controller,
    split_unit,
    to_controller,
)

INSTANT = "sim://?baud=0"


@pytest.mark.parametrize(("dim", "expected"), [
    (1, 1500.0), (2, 1.5), (3, 540.0), (4, 1.5), (5, 0.15), (6, 0.0015),
    (7, 1.5 / 25.4), (8, 1500 / 25.4), (9, 1.5),
])
def test_a_length_in_every_dim(dim: int, expected: float) -> None:
    scale = UnitScale(dim=dim, pitch=2.0, gear=1.0)
    assert to_controller(1.5, "mm", Measure.POSITION, scale) == pytest.approx(expected, rel=1e-12)
    assert from_controller(expected, "mm", Measure.POSITION, scale) == pytest.approx(1.5, rel=1e-12)


def test_microsteps_use_pitch_gear_and_usteps() -> None:
    scale = UnitScale(dim=0, pitch=2.0, gear=4.0, usteps=40000)  # 0.5 mm per motor rev
    assert to_controller(1.0, "mm", Measure.POSITION, scale) == 80000.0
    assert to_controller(1.0, "rev", Measure.POSITION, scale) == 40000.0
    assert to_controller(5, "ustep", Measure.POSITION, scale) == 5.0


def test_exact_decimal_results() -> None:
    assert to_controller(2.3, "mm", Measure.POSITION, UnitScale(dim=1)) == 2300.0
    assert to_controller(1, "inch", Measure.POSITION, UnitScale(dim=7)) == 1.0


def test_velocities_are_converted_with_the_pitch() -> None:
    scale = UnitScale(dim=2, pitch=2.0)  # rev/s on the wire
    assert to_controller(4.0, "mm/s", Measure.VELOCITY, scale) == 2.0
    assert to_controller(3.0, "rev/s", Measure.VELOCITY, scale) == 3.0
    assert from_controller(2.0, "um/s", Measure.VELOCITY, scale) == 4000.0
    mm_vel = UnitScale(dim=9, pitch=2.0)  # mm/s on the wire
    assert to_controller(4.0, "mm/s", Measure.VELOCITY, mm_vel) == 4.0
    assert to_controller(3.0, "rev/s", Measure.VELOCITY, mm_vel) == 6.0


def test_accelerations_are_m_per_s2() -> None:
    scale = UnitScale(dim=1, pitch=2.0)
    assert to_controller(500, "mm/s2", Measure.ACCELERATION, scale) == 0.5
    assert to_controller(1, "rev/s^2", Measure.ACCELERATION, scale) == 0.002
    assert from_controller(0.1, "mm/s²", Measure.ACCELERATION, scale) == pytest.approx(100.0)


def test_unit_names() -> None:
    assert split_unit("um/s") == ("um", Measure.VELOCITY)
    assert split_unit("mm/s**2") == ("mm", Measure.ACCELERATION)
    assert check_unit("µm") == "µm"
    for bad in ("furlong", "mm/h", ""):
        with pytest.raises(ValueError, match="unknown unit"):
            split_unit(bad)
    with pytest.raises(ValueError, match="not a position unit"):
        check_unit("mm/s")
    with pytest.raises(ValueError, match="velocity unit where a position goes"):
        to_controller(1.0, "mm/s", Measure.POSITION, UnitScale())
    assert to_controller(1, "um", Measure.POSITION, UnitScale()) == 0.001


async def test_moves_in_mm_whatever_dim_and_pitch() -> None:
    async with tango_aio.connect(INSTANT) as tango:
        await tango.set("pitch", x=2.0, y=4.0)
        await tango.set("dim", x=1, y=0)  # X in µm, Y in microsteps
        await tango.move_to(x=1.5, y=0.25, unit="mm")
        assert await tango.position() == pytest.approx({"x": 1500.0, "y": 2500.0, "z": 0.0})
        assert await tango.position(unit="mm") == pytest.approx(
            {"x": 1.5, "y": 0.25, "z": 0.0})
        await tango.move_by(x=-500, unit="um")
        assert (await tango.position(unit="mm"))["x"] == pytest.approx(1.0)


async def test_connection_wide_units_for_positions_and_velocities() -> None:
    async with tango_aio.connect(INSTANT, units="um") as tango:
        await tango.set("pitch", x=2.0)
        await tango.settings.set_velocity(x=4000)  # 4 mm/s with 2 mm per rev: 2 rev/s
        assert (await tango.get("vel"))["x"] == pytest.approx(2.0)
        assert (await tango.settings.velocity())["x"] == pytest.approx(4000.0)
        assert (await tango.settings.velocity(unit="rev/s"))["x"] == pytest.approx(2.0)
        await tango.move_to(x=250)
        assert (await tango.position(unit="mm"))["x"] == pytest.approx(0.25)
        assert (await tango.get("pos"))["x"] == pytest.approx(0.25)  # dim 2 is mm
        await tango.settings.set_acceleration(x=200_000)  # µm/s² → 0.2 m/s²
        assert (await tango.get("accel"))["x"] == pytest.approx(0.2)
        assert (await tango.settings.acceleration(unit="mm/s2"))["x"] == pytest.approx(200.0)


async def test_limits_in_units() -> None:
    async with tango_aio.connect(INSTANT) as tango:
        await tango.set("dim", x=1)
        await tango.settings.set_limits(x=(-1.0, 2.0), unit="mm")
        limits = await tango.settings.limits(unit="mm")
        assert limits["x"] == pytest.approx((-1.0, 2.0))
        assert (await tango.settings.limits())["x"] == pytest.approx((-1000.0, 2000.0))


async def test_pint_quantities() -> None:
    pint = pytest.importorskip("pint")
    ureg = pint.UnitRegistry()
    async with tango_aio.connect(INSTANT) as tango:
        await tango.set("dim", x=1)
        await tango.move_to(x=ureg.Quantity(0.5, "mm"), y=ureg.Quantity(200, "um"))
        position = await tango.position()
        assert position["x"] == pytest.approx(500.0)
        assert position["y"] == pytest.approx(0.2)  # Y stays in dim 2 (mm)
        await tango.settings.set_velocity(x=ureg.Quantity(3, "mm/s"))
        assert (await tango.get("vel"))["x"] == pytest.approx(3.0)  # pitch 1 mm
        with pytest.raises(ValueError, match="not a length"):
            await tango.move_to(x=ureg.Quantity(1, "s"))


def _written(caplog: pytest.LogCaptureFixture) -> list[str]:
    """The instructions written so far (the ``tango_aio.wire`` trace), then forget them."""
    names = [record.getMessage().split("-> b'", 1)[1].split()[0].rstrip("'")
             for record in caplog.records
             if record.name == "tango_aio.wire" and "-> b'" in record.getMessage()]
    caplog.clear()
    return names


async def test_no_unit_reads_nothing_extra(caplog: pytest.LogCaptureFixture) -> None:
    """A move with a unit reads the four conversion settings once each; one without reads
    none of them. Instruction names, not line counts: separators and the status polls of
    the move's confirmation vary in number."""
    settings = ["?dim", "?pitch", "?gear", "?usteps"]
    async with tango_aio.connect(INSTANT) as tango:
        caplog.set_level(logging.DEBUG, logger="tango_aio.wire")
        caplog.clear()
        await tango.move_to(x=1)
        plain = _written(caplog)
        await tango.move_to(x=2, unit="mm")
        with_unit = _written(caplog)
    assert "!moa" in plain and "!moa" in with_unit
    assert not set(settings) & set(plain)
    assert sorted(name for name in with_unit if name in settings) == sorted(settings)
    assert set(with_unit) - set(plain) == set(settings)


async def test_watch_position_follows_a_whole_scan() -> None:
    """follow=True goes on through the idle moments between the moves of a scan (issue 15
    item 6); the default stops at the first idle moment."""
    async with tango_aio.connect(INSTANT, units="mm") as tango:
        await tango.set("vel", x=100, axis=None, check=True)
        targets = (0.5, 1.0, 1.5)
        reached = {target: asyncio.Event() for target in targets}
        seen: list[float] = []

        async def scan() -> None:
            for target in targets:
                await tango.move_to(x=target)
                await reached[target].wait()  # idle until the watcher has seen it

        task = asyncio.create_task(scan())
        async for update in tango.watch_position(0.01, follow=True):
            x = update.positions["x"]
            seen.append(x)
            if x in reached:
                reached[x].set()
            if x == targets[-1]:
                break
        await task
        assert set(targets) <= set(seen)  # the watch went on through every idle stop
        assert seen == sorted(seen)
        once = [u async for u in tango.watch_position(0.01)]  # idle: one update, then done
        assert len(once) == 1 and once[0].positions["x"] == 1.5


async def test_bad_values_and_units_are_refused_before_anything_is_sent() -> None:
    from helpers import wire_of

    async with tango_aio.connect(INSTANT) as tango:
        before = wire_of(tango).lines_processed
        for call in (tango.move_to(x="1 2", unit="mm"),  # type: ignore[arg-type]
                     tango.move_to(x=True, unit="mm"),
                     tango.move_to(x=1.0, unit="furlong"),
                     tango.move_to(x=1.0, unit="mm/s"),
                     tango.settings.set_velocity(x=1.0, unit="mm"),
                     tango.position(unit="parsec")):
            with pytest.raises(tango_aio.InvalidCommandError):
                await call
        assert wire_of(tango).lines_processed == before


def test_each_dim_has_one_unit_spelt_for_each_surface() -> None:
    from tango_aio.bluesky._link import DIM_UNITS as bluesky_units
    from tango_aio.epics.record import EGU_BY_DIM
    from tango_aio.units import DIM_UNITS, user_per_rev

    assert sorted(DIM_UNITS) == list(range(10))
    assert all(unit.ascii.isascii() for unit in DIM_UNITS.values())
    assert {dim: unit.ascii for dim, unit in DIM_UNITS.items()} == EGU_BY_DIM
    assert bluesky_units == {dim: unit.symbol for dim, unit in DIM_UNITS.items()}
    assert (EGU_BY_DIM[7], bluesky_units[7], bluesky_units[0]) == ("inch", "in", "µstep")
    # The user-per-mm factors are the inverse of the mm-per-unit table, bit for bit.
    assert [user_per_rev(dim, 1.0, 1.0, 40000) for dim in (1, 3, 5, 6, 7, 8)] == [
        1000.0, 360.0, 0.1, 0.001, 1.0 / 25.4, 1000.0 / 25.4]


def test_the_velocity_unit_follows_the_dim() -> None:
    from tango_aio.catalog._instructions import lookup, upper_bound
    from tango_aio.units import DIM_MM_VEL, velocity_unit

    assert [velocity_unit(dim) for dim in (0, 2, 8, DIM_MM_VEL)] == [
        "rev/s", "rev/s", "rev/s", "mm/s"]
    vel = lookup("vel").write[0].per_axis[0]
    assert vel.hi_dim9 is not None and vel.hi_dim9 != vel.hi
    assert upper_bound(vel, DIM_MM_VEL) == vel.hi_dim9 and upper_bound(vel, 2) == vel.hi
