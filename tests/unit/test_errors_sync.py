"""The error-number classes in ``tango_aio/errors.py`` are exactly what
``tools/gen_errors.py`` makes from ``reference/errors.json``."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from helpers import load_tool

from tango_aio import errors

ROOT = Path(__file__).resolve().parents[2]
ERRORS = ROOT / "tango_aio" / "errors.py"
REFERENCE = ROOT / "reference" / "errors.json"


@pytest.fixture(scope="module")
def generator() -> ModuleType:
    return load_tool("gen_errors")


@pytest.fixture(scope="module")
def entries(generator: ModuleType) -> list[dict[str, Any]]:
    loaded: list[dict[str, Any]] = generator.load(REFERENCE)
    return loaded


def test_generator_reads_the_repository_reference(generator: ModuleType) -> None:
    assert generator.DEFAULT_JSON.resolve() == REFERENCE.resolve()
    assert generator.OUTPUT.resolve() == ERRORS.resolve()


def test_committed_classes_are_the_generated_ones(
    generator: ModuleType, entries: list[dict[str, Any]]
) -> None:
    current = ERRORS.read_text(encoding="utf-8")
    assert generator.render(entries, current) == current, (
        "the error classes in tango_aio/errors.py are out of date or were edited by hand: "
        "run `.venv/bin/python tools/gen_errors.py`"
    )


def test_a_changed_text_is_seen(generator: ModuleType, entries: list[dict[str, Any]]) -> None:
    changed = [dict(entry) for entry in entries]
    changed[5]["description"] += " (edited)"
    current = ERRORS.read_text(encoding="utf-8")
    assert generator.render(changed, current) != current


def test_every_number_has_a_name_and_its_category(
    generator: ModuleType, entries: list[dict[str, Any]]
) -> None:
    assert set(generator.NAMES) == {int(e["number"]) for e in entries}
    for number, name in generator.NAMES.items():
        cls = getattr(errors, name)
        assert cls.number == number
        assert cls.__bases__[0].__name__ == generator.category(number)
        assert name in errors.__all__
