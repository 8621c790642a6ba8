"""Numbers as labs have them (issue 14 item 7), through the public API on the emulator.

numpy scalars, Decimal and Fraction work wherever a number goes; strings, lists and bools
where a number goes are refused before a byte is written; positional and per-axis values
are not mixed; timeouts and sizes are checked; integers go on the wire canonically.
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator
from decimal import Decimal
from fractions import Fraction
from typing import Any

import pytest
from helpers import INSTANT, wire_of

import tango_aio
from tango_aio import Controller, InvalidCommandError
from tango_aio.catalog._encode import build
from tango_aio.catalog._instructions import format_number, parse, wire_number

np = pytest.importorskip("numpy")


@pytest.fixture
async def tango() -> AsyncIterator[Controller]:
    async with tango_aio.connect(INSTANT) as controller:
        yield controller


NUMBERS: list[Any] = [np.float64(2.5), np.float32(2.5), np.int64(2), np.int32(3),
                      Decimal("2.5"), Fraction(5, 2), 2.5, 2]


@pytest.mark.parametrize("value", NUMBERS, ids=lambda v: type(v).__name__)
def test_lab_numbers_format_like_python_numbers(value: Any) -> None:
    assert float(format_number(value)) == float(value)
    assert "e" not in format_number(value).lower()


def test_float32_is_written_at_its_own_precision() -> None:
    assert format_number(np.float32(0.1)) == "0.1"
    assert format_number(Decimal("1E-7")) == "0.0000001"
    assert format_number(Fraction(1, 4)) == "0.25"
    assert wire_number(np.int64(7)) == 7 and type(wire_number(np.int64(7))) is int


@pytest.mark.parametrize("value", [True, np.bool_(True), "1", [1.0], 1 + 2j, None],
                         ids=repr)
def test_non_numbers_are_not_formatted(value: Any) -> None:
    with pytest.raises(TypeError):
        format_number(value)


@pytest.mark.parametrize("value", NUMBERS, ids=lambda v: type(v).__name__)
async def test_moves_and_settings_take_lab_numbers(tango: Controller, value: Any) -> None:
    letters = await tango.move_to(x=value, y=value)
    assert letters == {"x": "@", "y": "@", "z": "@"}
    position = await tango.position()
    assert position["x"] == pytest.approx(float(value), abs=1e-3)
    await tango.set("vel", x=value, y=value)
    assert (await tango.get("vel"))["y"] == pytest.approx(abs(float(value)))
    await tango.move_by(z=value)


async def test_numpy_positions_upload(tango: Controller) -> None:
    await tango.triggers.upload_positions(list(np.linspace(0.0, 1.0, 5, dtype=np.float32)))
    assert await tango.triggers.read_positions() == pytest.approx([0, 0.25, 0.5, 0.75, 1])


@pytest.mark.parametrize("bad", ["1 2", "5", "", [1.0, 2.0], (1,), True, None,
                                 np.array([1.0, 2.0])], ids=repr)
async def test_non_numbers_are_refused_before_sending(tango: Controller, bad: Any) -> None:
    wire = wire_of(tango)
    before = wire.lines_processed
    with pytest.raises(InvalidCommandError):
        await tango.move_to(x=bad)
    with pytest.raises(InvalidCommandError):
        await tango.set("vel", x=bad)
    with pytest.raises(InvalidCommandError):
        await tango.go(x=bad)
    assert wire.lines_processed == before
    assert await tango.position() == {"x": 0.0, "y": 0.0, "z": 0.0}


def test_a_string_smuggling_a_second_value_is_refused() -> None:
    with pytest.raises(InvalidCommandError, match="not one value"):
        build("moa", x="1 2")
    with pytest.raises(InvalidCommandError, match="string where a number goes"):
        build("moa", x="1")


async def test_positional_and_per_axis_values_are_not_mixed(tango: Controller) -> None:
    before = wire_of(tango).lines_processed
    with pytest.raises(InvalidCommandError, match="cannot be mixed"):
        await tango.set("vel", 5, x=3)
    assert wire_of(tango).lines_processed == before
    await tango.set("vel", 5, axis="y")
    assert (await tango.get("vel"))["y"] == 5.0


@pytest.mark.parametrize("timeout", [math.nan, -1.0, 0.0, math.inf])
async def test_bad_timeouts_are_refused(tango: Controller, timeout: float) -> None:
    before = wire_of(tango).lines_processed
    with pytest.raises(ValueError, match="timeout"):
        await tango.move_to(x=1, timeout=timeout)
    with pytest.raises(ValueError, match="timeout"):
        await tango.query("?pos", timeout=timeout)
    with pytest.raises(ValueError, match="timeout"):
        await tango.get("vel", timeout=timeout)
    with pytest.raises(ValueError, match="timeout"):
        await tango.wait_idle(timeout=timeout)
    assert wire_of(tango).lines_processed == before


async def test_bad_sizes_are_refused(tango: Controller) -> None:
    for size in (math.nan, 0, 2.5):
        with pytest.raises((ValueError, TypeError), match="maxsize"):
            tango.events(maxsize=size)  # type: ignore[arg-type]


@pytest.mark.parametrize("options", [
    {"credit_limit": math.nan}, {"credit_limit": 0}, {"credit_limit": 3},
    {"reply_timeout": math.nan},
    {"reply_timeout": 0}, {"marker_chunk": -1}, {"autostatus": 7}, {"units": "furlong"},
    {"reconnect": True, "reconnect_initial": math.nan},
], ids=repr)
def test_bad_connect_options_are_refused_before_opening(options: dict[str, Any]) -> None:
    with pytest.raises((ValueError, TypeError)):
        tango_aio.connect(INSTANT, **options)


def test_a_misspelt_connect_option_is_a_type_error() -> None:
    with pytest.raises(TypeError):
        tango_aio.connect(INSTANT, reply_timout=2)  # type: ignore[call-arg]


@pytest.mark.parametrize("line", ["!autostatus -0", "!autostatus +0", "!autostatus 00"])
def test_enumerated_values_are_sent_canonically(line: str) -> None:
    assert parse(line).line == "!autostatus 0"
    assert parse(line).to_bytes() == b"!autostatus 0\r"


async def test_canonical_autostatus_through_the_controller(tango: Controller) -> None:
    await tango.command("!autostatus -0")
    assert tango.autostatus == 0
    assert await tango.get("autostatus") == 0
    await tango.set("autostatus", Decimal("1"))
    assert await tango.get("autostatus") == 1
