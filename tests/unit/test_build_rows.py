"""build_rows and encode_rows (the fast paths of list uploads) give exactly what build
gives (encode_rows: its bytes)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog import _encode as encoding
from tango_aio.catalog._encode import build, build_rows, check_rows, encode_rows
from tango_aio.catalog._instructions import Command, Context, Form
from tango_aio.errors import InvalidCommandError
from tango_aio.families._bulk import Column

NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-1e6, 1e6),
    st.integers(-20000, 20000),
    st.integers(),
    st.sampled_from([0, 0.0, -0.0, 1, -1, 2.5, 1e-6, 1e-7, 32500.0, 1e300, True]),
)


def _one_by_one(name: str, lead: Sequence[object], rows: Sequence[Sequence[object]],
                form: Form, ctx: Context) -> list[Command | tuple[str, str]]:
    out: list[Command | tuple[str, str]] = []
    for row in rows:
        try:
            out.append(build(name, *lead, *row, form=form, context=ctx))  # type: ignore[arg-type]
        except (InvalidCommandError, OverflowError, TypeError) as exc:
            out.append((type(exc).__name__, str(exc)))
    return out


def _fast(name: str, lead: Sequence[object], rows: Sequence[Sequence[object]], form: Form,
          ctx: Context, rows_of: Callable[..., Iterator[Any]] = build_rows) -> list[Any]:
    # build_rows is a generator that an error ends (an upload stops at the first bad row
    # anyway), so each row goes through after the good rows before it, which made the plans.
    out: list[Any] = []
    good: list[Sequence[object]] = []
    for row in rows:
        try:
            made = list(rows_of(name, lead, [*good, row], form=form, context=ctx))
        except (InvalidCommandError, OverflowError, TypeError) as exc:
            out.append((type(exc).__name__, str(exc)))
        else:
            out.append(made[-1])
            good.append(row)
    return out


def _same(a: list[Command | tuple[str, str]], b: list[Command | tuple[str, str]]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        if isinstance(x, Command) and isinstance(y, Command):
            assert (x.to_bytes(), x.values, x.axis, x.form, x.instruction) == \
                (y.to_bytes(), y.values, y.axis, y.form, y.instruction)
            assert [type(v) for v in x.values] == [type(v) for v in y.values]
        else:
            assert x == y


def _first_error(call: Callable[[], object]) -> tuple[str, str] | None:
    try:
        call()
    except (InvalidCommandError, OverflowError, TypeError) as exc:
        return type(exc).__name__, str(exc)
    return None


def _check(name: str, lead: Sequence[object], rows: Sequence[Sequence[object]], form: Form,
           ctx: Context) -> None:
    """build_rows gives build's commands, encode_rows their bytes (and both its errors)."""
    plain = _one_by_one(name, lead, rows, form, ctx)
    _same(_fast(name, lead, rows, form, ctx), plain)
    # check_rows raises build_rows' first error, and after it encode_rows cannot fail.
    whole = _first_error(lambda: list(build_rows(name, lead, rows, form=form, context=ctx)))  # type: ignore[arg-type]
    assert _first_error(lambda: list(check_rows(name, lead, rows, form=form, context=ctx))) == whole  # type: ignore[arg-type]
    if whole is None:
        list(encode_rows(name, lead, rows, form=form, context=ctx))  # type: ignore[arg-type]
    assert _fast(name, lead, rows, form, ctx, encode_rows) == [
        x.to_bytes() if isinstance(x, Command) else x for x in plain]


@settings(max_examples=300)
@given(rows=st.lists(st.lists(NUMBERS, min_size=1, max_size=1), min_size=1, max_size=6))
def test_trigger_rows(rows: list[list[object]]) -> None:
    ctx = Context()
    _check("trigp", [-1], rows, Form.SET, ctx)


@settings(max_examples=150)
@given(rows=st.lists(st.lists(NUMBERS, min_size=1, max_size=5), min_size=1, max_size=6),
       dims=st.tuples(*[st.sampled_from([0, 1, 2, 9])] * 4))
def test_snapshot_rows(rows: list[list[object]], dims: tuple[int, int, int, int]) -> None:
    ctx = Context(dims=dims)
    _check("snsa", [-1], rows, Form.SET, ctx)


@pytest.mark.parametrize(("name", "lead"), [("vel", []), ("accel", []), ("trigp", [5]),
                                            ("pos", []), ("moa", []), ("flash", [])])
@settings(max_examples=60)
@given(rows=st.lists(st.lists(NUMBERS, min_size=1, max_size=4), min_size=1, max_size=5))
def test_other_instructions(name: str, lead: list[object], rows: list[list[object]]) -> None:
    """Per-axis settings with dim-dependent limits (vel in dim 9), moves, positions, a
    value that may not be closer to 0 than a bound (flash)."""
    ctx = Context(dims=(9, 2, 1, 0))
    _check(name, lead, rows, Form.SET, ctx)


def test_rows_after_the_first_take_the_fast_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """Not a timing test: only the first row (and a row that fails the direct check) is
    built in full."""
    full: list[tuple[object, ...]] = []
    original = encoding._build

    def recorded(*args: Any) -> Command:
        full.append(args)
        return original(*args)

    monkeypatch.setattr(encoding, "_build", recorded)
    rows: list[list[float]] = [[0.5 + i / 1000] for i in range(50)]
    commands = list(build_rows("trigp", [-1], rows))
    assert len(full) == 1
    assert [c.line for c in commands] == [build("trigp", -1, r[0]).line for r in rows]
    assert commands[3].values == (-1, 0.503)
    full.clear()
    assert list(encode_rows("trigp", [-1], rows)) == [c.to_bytes() for c in commands]
    assert len(full) == 1
    full.clear()
    with pytest.raises(InvalidCommandError):
        list(build_rows("snsa", [-1], [[1.0, 2.0], [1.0, 3.0], [1.0, math.inf]]))
    assert len(full) == 2  # the first row, and the row that failed the direct check


def test_a_column_is_rows_of_one_value() -> None:
    values = [0.5, 1.0, 1.5, 2.0]
    rows = Column(values)
    assert len(rows) == 4 and rows[1] == (1.0,) and rows[-1] == (2.0,)
    assert rows[1:3] == [(1.0,), (1.5,)] and list(rows) == [(v,) for v in values]
    assert list(encode_rows("trigp", [-1], rows)) == list(
        encode_rows("trigp", [-1], [[v] for v in values]))
