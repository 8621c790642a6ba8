"""Controller.validate_move: the checks of a move, before a byte is written."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from helpers import FakeLink, as_axes

from tango_aio.catalog._instructions import Context
from tango_aio.controller._controller import Controller
from tango_aio.errors import InvalidCommandError

pytestmark = pytest.mark.timeout(10)


def two_axes(fake_link: Callable[..., FakeLink]) -> tuple[Controller, FakeLink]:
    link = fake_link()
    link.protocol.context = Context(axes=2)
    return Controller(link.protocol), link


@pytest.mark.parametrize("axes", [
    {"x": 1.0}, {"x": 1, "y": -2.5}, {"y": 3.0},
])
@pytest.mark.parametrize("relative", [False, True])
async def test_valid_targets_pass(fake_link: Callable[..., FakeLink], axes: dict[str, Any],
                                  relative: bool) -> None:
    tango, link = two_axes(fake_link)
    tango.validate_move(relative=relative, **axes)
    assert link.transport.sent == b""


@pytest.mark.parametrize(("axes", "number"), [
    ({}, None),                          # no axis at all
    ({"q": 1.0}, None),                  # not an axis keyword
    ({"z": 1.0}, 1),                     # an axis this controller does not have
    ({"x": 1.0, "a": 2.0}, 1),
    ({"x": float("nan")}, None),         # not finite
    ({"y": float("inf")}, None),
    ({"x": "1 2"}, None),                # wrong types
    ({"x": True}, None),
    ({"x": None}, None),
])
@pytest.mark.parametrize("relative", [False, True])
async def test_invalid_targets_raise_before_anything_is_written(
        fake_link: Callable[..., FakeLink], axes: dict[str, Any], number: int | None,
        relative: bool) -> None:
    tango, link = two_axes(fake_link)
    with pytest.raises(InvalidCommandError) as info:
        tango.validate_move(relative=relative, **axes)
    assert isinstance(info.value, ValueError)
    if number is not None:
        assert info.value.number == number
    assert link.transport.sent == b""


async def test_move_to_refuses_what_validate_move_refuses(
        fake_link: Callable[..., FakeLink]) -> None:
    tango, link = two_axes(fake_link)
    for axes in ({"z": 1.0}, {"x": float("nan")}, {}):
        with pytest.raises(InvalidCommandError) as checked:
            tango.validate_move(**as_axes(axes))
        with pytest.raises(InvalidCommandError) as moved:
            await tango.move_to(**as_axes(axes))
        assert str(checked.value) == str(moved.value)
    assert link.transport.sent == b""
