"""The catalog's facts that the driver and the emulator share (they replaced hand-written
tables in ``sim/params.py``, ``controller.py`` and ``core.py``): literal values for a
handful of instructions, and the sets as a whole."""

from __future__ import annotations

import pytest

from tango_aio.catalog._instructions import INSTRUCTIONS, MAX_SNAPSHOTS, MAX_TRIGGERS, ModeEffect

#: (name, default, indexed, digits, position_valued, cached)
EXPECTED = [
    ("vel", (10.0,), (), 3, False, "vel"),
    ("dim", (2,), (), None, False, "dims"),
    ("swact", (1, 0, 1), (), None, False, ""),
    ("zwaxis", ("z",), (), None, False, ""),
    ("joyspeed", (1.0,), (1.0, 10.0, 30.0), 3, False, ""),
    ("adiginfunc", (), (0, 0, 1, 2), None, False, ""),
    ("encamp", (), (), 0, False, ""),
    ("pos", (), (), None, True, ""),
    ("trigp", (), (), None, True, ""),
    ("ctrt", (1000,), (), None, False, "settle_ms"),
    ("delay", (), (), None, False, "delay_ms"),
    ("moa", (), (), None, False, ""),
]


@pytest.mark.parametrize(("name", "default", "indexed", "digits", "position", "cached"),
                         EXPECTED)
def test_catalog_facts(name: str, default: tuple[object, ...], indexed: tuple[object, ...],
                       digits: int | None, position: bool, cached: str) -> None:
    entry = INSTRUCTIONS[name]
    assert entry.default == default
    assert entry.indexed == indexed
    assert entry.digits == digits
    assert entry.position_valued is position
    assert entry.cached == cached


def test_fact_sets_have_their_sizes() -> None:
    # The tables they replaced had 70 defaults, 4 indexed settings, 40 digit counts,
    # 23 position-valued replies and 9 cached settings.
    entries = INSTRUCTIONS.values()
    assert sum(bool(e.default) for e in entries) == 70
    assert sum(bool(e.indexed) for e in entries) == 4
    assert sum(e.digits is not None for e in entries) == 40
    assert sum(e.position_valued for e in entries) == 23
    assert sorted(e.cached for e in entries if e.cached) == [
        "accel", "delay_ms", "dims", "extmode", "pause_ms", "pitch", "secvel", "settle_ms",
        "vel"]


def test_mode_effects() -> None:
    effects = {n: e.mode_effect for n, e in INSTRUCTIONS.items()
               if e.mode_effect is not ModeEffect.NONE}
    assert effects == {"autostatus": ModeEffect.VALUE, "reset": ModeEffect.RESTART,
                       "restore": ModeEffect.RESTART_IF_MINUS_ONE}


def test_list_limits_come_from_the_index_ranges() -> None:
    # '!trigp index' 1..10000 (L13767-13802), '!snsa index' 1..1024 (L15324-15389).
    assert (MAX_TRIGGERS, MAX_SNAPSHOTS) == (10000, 1024)
