"""tango_aio.mm's camera-triggered sequences without I/O: what a sequence may hold, how the
stages of one controller share its snapshot array, and what the stop says."""

from __future__ import annotations

import pytest

pytest.importorskip("tango_aio.mm")  # first: it keeps the root logger's level

from tango_aio.mm._stepseq import MAX_LENGTH, StepArray, StepStop, checked


def test_a_sequence_holds_1_to_1024_finite_positions() -> None:
    assert checked([1, 2.5]) == (1.0, 2.5)
    assert len(checked([0.0] * MAX_LENGTH)) == 1024  # L14550
    for bad in ([], [0.0] * (MAX_LENGTH + 1), [1.0, float("inf")], [float("nan")]):
        with pytest.raises(ValueError):
            checked(bad)


def test_sequences_of_one_length_share_the_entries_in_axis_order() -> None:
    array = StepArray()
    array.load(("z",), [(5.0, 6.0)])
    assert array.load(("x", "y"), [(1.0, 2.0), (3.0, 4.0)]) == {
        "x": (1.0, 2.0), "y": (3.0, 4.0), "z": (5.0, 6.0)}
    assert list(array.columns) == ["x", "y", "z"]  # the order of !snsa's values


def test_a_sequence_of_another_length_replaces_the_others() -> None:
    array = StepArray()
    array.load(("x", "y"), [(1.0, 2.0), (3.0, 4.0)])
    assert array.load(("z",), [(5.0, 6.0, 7.0)]) == {"z": (5.0, 6.0, 7.0)}
    assert array.load(("z",), [(8.0, 9.0)]) == {"z": (8.0, 9.0)}  # its own: replaced


def test_nothing_loads_while_a_sequence_runs() -> None:
    array = StepArray()
    array.load(("z",), [(5.0, 6.0)])
    array.running.add("z")
    with pytest.raises(RuntimeError, match="stop it first"):
        array.load(("x", "y"), [(1.0, 2.0), (3.0, 4.0)])
    assert array.columns == {"z": (5.0, 6.0)}


def test_the_stop_names_the_entry_from_1_and_the_positions() -> None:
    assert str(StepStop(0, 5, {"z": 10.0})) == "entry 1 of 5 (z=10 um)"
    assert str(StepStop(2, 3, {"x": 300.0, "y": -70.5})) == \
        "entry 3 of 3 (x=300 um, y=-70.5 um)"
