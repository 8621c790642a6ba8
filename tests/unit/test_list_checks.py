"""The list checks' fast paths (#28 target 5: 64 uploads check their lists on one loop
before the last can start) against the value-by-value loops they skip: the same lists
pass, the same error for the rest."""

from __future__ import annotations

import math

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from tango_aio import InvalidCommandError
from tango_aio.families._bulk import (
    Column,
    _finite_and_monotonic,
    check_resolution,
    validate_trigger_positions,
)


def _loops_pass(values: list[float]) -> bool:
    """What validate_trigger_positions' loops accept: finite values, strictly rising or
    strictly falling (the step's sign, as the loops compute it)."""
    if not all(math.isfinite(value) for value in values):
        return False
    if len(values) < 2:
        return True
    rising = values[1] > values[0]
    for index in range(1, len(values)):
        step = values[index] - values[index - 1]
        if step == 0 or (step > 0) != rising:
            return False
    return True


floats = st.floats(allow_nan=True, allow_infinity=True)
lists = st.lists(floats, max_size=12) | st.lists(
    st.floats(-1e6, 1e6), max_size=12, unique=True).map(sorted) | st.lists(
    st.floats(-1e6, 1e6), max_size=12, unique=True).map(lambda v: sorted(v, reverse=True))


@given(lists)
@example([1.0, 1.0])
@example([1.0, 2.0, 2.0])
@example([2.0, 1.0, 3.0])
@example([-1e308, 1e308])
@example([5e-324, 0.0, -5e-324])
@example([0.0, -0.0])
@example([1.0, math.nan, 2.0])
def test_the_fast_check_accepts_what_the_loops_accept(values: list[float]) -> None:
    assert _finite_and_monotonic(values) == _loops_pass(values)


def _error(call: object) -> str | None:
    try:
        call()  # type: ignore[operator]
    except InvalidCommandError as exc:
        return str(exc)
    return None


@given(lists)
@example([1.0, 1.0])
@example([0.5, math.inf])
def test_a_list_of_floats_is_validated_as_a_tuple_of_them_is(values: list[float]) -> None:
    # A list of plain floats takes the fast paths; a tuple goes value by value.
    assert _error(lambda: validate_trigger_positions(values)) == _error(
        lambda: validate_trigger_positions(tuple(values)))
    if _error(lambda: validate_trigger_positions(values)) is None:
        assert validate_trigger_positions(values) == values
        assert validate_trigger_positions(values) is not values  # a copy


def test_booleans_and_subclasses_still_go_value_by_value() -> None:
    with pytest.raises(InvalidCommandError, match="entry 1 is not a number"):
        validate_trigger_positions([0.5, True, 1.5])

    class Tagged(float):
        pass

    assert validate_trigger_positions([Tagged(0.5), 1.5]) == [0.5, 1.5]


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=12),
       st.sampled_from([0.0001, 0.001, 0.5]))
@example([0.0, 0.00004, -0.0], 0.0001)
@example([-0.00005, 0.00005], 0.0001)
def test_the_one_column_resolution_check_matches_the_loop(values: list[float],
                                                          step: float) -> None:
    # A Column takes the one-comprehension path; plain one-value rows go through the loop.
    assert _error(lambda: check_resolution(Column(values), [step], "trigp")) == _error(
        lambda: check_resolution([(value,) for value in values], [step], "trigp"))
