"""The committed ``tango_aio/families/_generated.py`` and ``tango_aio/sync/_generated.py``
are exactly what ``tools/gen_families.py`` makes of the catalog and the reference."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest
from helpers import load_tool

ROOT = Path(__file__).resolve().parents[2]
GENERATED = ROOT / "tango_aio" / "families" / "_generated.py"
TWINS = ROOT / "tango_aio" / "sync" / "_generated.py"


@pytest.fixture(scope="module")
def generator() -> ModuleType:
    return load_tool("gen_families")


def test_committed_accessors_are_the_generated_ones(generator: ModuleType) -> None:
    expected = generator.render(generator.load()).encode("utf-8")
    assert GENERATED.read_bytes() == expected, (
        "tango_aio/families/_generated.py is out of date or was edited by hand: "
        "run `.venv/bin/python tools/gen_families.py`")


def test_committed_blocking_twins_are_the_generated_ones(generator: ModuleType) -> None:
    expected = generator.render_twins(generator.load()).encode("utf-8")
    assert TWINS.read_bytes() == expected, (
        "tango_aio/sync/_generated.py is out of date or was edited by hand: "
        "run `.venv/bin/python tools/gen_families.py`")


def test_render_is_deterministic(generator: ModuleType) -> None:
    refs = generator.load()
    assert generator.render(refs) == generator.render(refs)


def test_override_tables_name_real_instructions(generator: ModuleType) -> None:
    from tango_aio.catalog import INSTRUCTIONS

    for table in ("HAND_MADE", "ENUM_NAMES"):
        unknown = set(getattr(generator, table)) - set(INSTRUCTIONS)
        assert not unknown, f"{table} names unknown instructions {sorted(unknown)}"
    for name, members in generator.ENUM_NAMES.items():
        entry = INSTRUCTIONS[name]
        choices = {c for s in (*entry.write, *entry.read) for p in (*s.lead, *s.per_axis)
                   for c in p.choices}
        assert set(members) == choices, name


def test_enum_names_come_from_the_manual_words(generator: ModuleType) -> None:
    notes = "0 = no handshake (default, recommended), 1 = RTS/CTS handshake"
    assert generator.enum_members((0, 1), notes) == [("NO_HANDSHAKE", 0),
                                                     ("RTS_CTS_HANDSHAKE", 1)]
    # a value the notes do not name: every member falls back to its number
    assert generator.enum_members((0, 1, 2), "0 off; 1 on") == [
        ("VALUE_0", 0), ("VALUE_1", 1), ("VALUE_2", 2)]
    assert generator.enum_members((-1, 0), "") == [("VALUE_MINUS_1", -1), ("VALUE_0", 0)]
