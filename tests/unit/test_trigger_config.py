"""``TriggerConfig``'s lines and checks, without I/O: the secondary output's precise
settings (``trigbwidth``, ``trigbdelay``, ``trigbf``) beside the others."""

from __future__ import annotations

from typing import Any

import pytest

from tango_aio import InvalidCommandError, TriggerConfig, TriggerOutput


def test_the_secondary_settings_are_written_after_the_output_they_serve() -> None:
    config = TriggerConfig(output=TriggerOutput.FREQUENCY_BOTH, secondary_width_us=65.4,
                           secondary_delay_us=0.35, secondary_frequency_hz=50000005.0)
    assert [line.line for line in config.lines()] == [
        "!triga x", "!trigm 0", "!trigo 15", "!trigbwidth 65.4", "!trigbdelay 0.35",
        "!trigbf 50000005.0", "!trigs 0", "!trigd 1.0", "!trigf 1000.0", "!trigcomp 0",
        "!trigenc 0", "!trigl 1"]


def test_secondary_settings_left_none_are_not_written() -> None:
    names = [line.name for line in TriggerConfig(secondary_delay_us=25.5).lines()]
    assert "trigbdelay" in names and "trigbwidth" not in names and "trigbf" not in names


@pytest.mark.parametrize(("field", "value"), [
    ("secondary_width_us", 0.0), ("secondary_width_us", 32_500_000),
    ("secondary_delay_us", 0), ("secondary_frequency_hz", 0.01),
    ("secondary_frequency_hz", 66_000_000)])
def test_the_manual_s_limits_are_accepted(field: str, value: Any) -> None:
    assert getattr(TriggerConfig(**{field: value}), field) == value


@pytest.mark.parametrize(("field", "value"), [
    ("secondary_width_us", True), ("secondary_width_us", float("nan")),
    ("secondary_delay_us", float("inf")), ("secondary_delay_us", -0.01),
    ("secondary_frequency_hz", 0.0), ("secondary_frequency_hz", "12500")])
def test_values_outside_the_manual_are_refused_when_made(field: str, value: Any) -> None:
    with pytest.raises(InvalidCommandError, match="trigb"):
        TriggerConfig(**{field: value})
