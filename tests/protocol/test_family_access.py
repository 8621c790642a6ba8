"""The generated typed access: what each accessor sends through its family port, how it
converts the reply, and that bad values are refused before anything is sent."""

from __future__ import annotations

import inspect
from typing import Any

import pytest

from tango_aio.catalog import INSTRUCTIONS, Context, Value, build
from tango_aio.errors import InvalidCommandError, ProtocolError
from tango_aio.families import (
    ACCESS,
    HAND_MADE,
    AdjustmentsAccess,
    JoystickAccess,
    LimitSwitchAccess,
    ManualEnum,
    OperatingModesAccess,
    TriggerAccess,
)
from tango_aio.families._generated import AxisState, DimUnit, JoyMode

FAMILY_CHAPTERS = {"6", "7", "8", "9", "11", "12", "13", "15", "17", "18", "19", "20",
                   "21", "23"}


class Port:
    """A family port that records every intent and answers reads from a table."""

    def __init__(self, replies: dict[str, Any] | None = None) -> None:
        self.replies = replies or {}
        self.sent: list[tuple[str, str, tuple[Value, ...], str | None, dict[str, Any]]] = []

    @property
    def context(self) -> Context:
        return Context()

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        self.sent.append(("get", name, args, axis, {}))
        reply = self.replies[name]
        return reply[axis] if axis is not None and isinstance(reply, dict) else reply

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        build(name, *args, axis=axis, context=self.context, **axes)  # what the controller does
        self.sent.append(("set", name, args, axis, axes))

    async def query(self, line: str, timeout: float | None = None) -> str:
        raise AssertionError("the generated access sends no raw line")

    async def command(self, line: str, *, check: bool = True,
                      timeout: float | None = None) -> None:
        raise AssertionError("the generated access sends no raw line")


def test_every_family_instruction_has_a_named_api() -> None:
    # Walk the catalog: an instruction of a family chapter without a named method fails.
    reachable: dict[str, list[str]] = {}
    for cls in ACCESS.values():
        for name, methods in cls.ROUTES.items():
            for method in methods:
                assert callable(getattr(cls, method)), (cls.__name__, method)
                reachable.setdefault(name, []).append(f"{cls.__name__}.{method}")
    for name, where in HAND_MADE.items():
        reachable.setdefault(name, []).extend(where)
    missing = sorted({entry.name for entry in INSTRUCTIONS.values()
                      if entry.section.split(".")[0] in FAMILY_CHAPTERS}
                     - set(reachable))
    assert not missing, f"instructions without a named API: {missing}"


def test_every_settable_instruction_has_a_setter_and_every_readable_a_reader() -> None:
    for cls in ACCESS.values():
        for name, methods in cls.ROUTES.items():
            entry = INSTRUCTIONS[name]
            if entry.write and entry.read:
                assert f"set_{name}" in methods, name
            if entry.read and entry.reply.value != "none":
                assert name in methods or f"{name}_" in methods, name


def test_every_accessor_cites_the_manual_lines() -> None:
    for cls in ACCESS.values():
        for methods in cls.ROUTES.values():
            for method in methods:
                doc = inspect.getdoc(getattr(cls, method)) or ""
                assert "manual L" in doc and "\n" not in doc, (cls.__name__, method, doc)


async def test_per_axis_read_gives_a_dict_or_one_value_typed() -> None:
    port = Port({"dim": {"x": 2, "y": 1}, "vel": {"x": 10, "y": 2.5}})
    family = AdjustmentsAccess(port)
    dims = await family.dim()
    assert dims == {"x": DimUnit.MM, "y": DimUnit.UM}
    assert all(type(value) is DimUnit for value in dims.values())
    velocity = await family.vel(axis="y")
    assert velocity == 2.5 and type(velocity) is float
    assert port.sent[-1][:4] == ("get", "vel", (), "y")


async def test_a_value_the_manual_does_not_list_reads_as_undocumented() -> None:
    family = JoystickAccess(Port({"joy": 7}))
    mode = await family.joy()
    assert isinstance(mode, JoyMode) and mode == 7 and mode.name == "UNDOCUMENTED_7"
    assert await JoystickAccess(Port({"joy": 2})).joy() is JoyMode.ON


async def test_a_bool_setting_refuses_a_reply_other_than_0_or_1() -> None:
    family = OperatingModesAccess(Port({"extmode": 2}))
    with pytest.raises(ProtocolError):
        await family.extmode()
    assert await OperatingModesAccess(Port({"extmode": 1})).extmode() is True


async def test_out_of_range_is_refused_before_anything_is_sent() -> None:
    port = Port()
    family = AdjustmentsAccess(port)
    with pytest.raises(InvalidCommandError) as caught:
        await family.set_accel(x=25.0)  # 0.0001 .. 20 m/s² (manual L3298-3347)
    assert isinstance(caught.value, ValueError)
    with pytest.raises(InvalidCommandError):
        await family.set_axis(x=5)  # -1, 0 or 1
    with pytest.raises(InvalidCommandError):
        await family.set_vel()  # no axis given
    assert port.sent == []


async def test_axes_with_a_gap_go_axis_by_axis_all_checked_first() -> None:
    port = Port()
    family = AdjustmentsAccess(port)
    with pytest.raises(InvalidCommandError):
        await family.set_vel(y=5.0, a=500.0)  # a is out of range: y is not written either
    assert port.sent == []
    await family.set_vel(y=5.0, a=6.0)
    assert [(s[1], s[2], s[3]) for s in port.sent] == [("vel", (5.0,), "y"),
                                                       ("vel", (6.0,), "a")]
    port.sent.clear()
    await family.set_axis(x=AxisState.ENABLED, y=0)
    assert port.sent == [("set", "axis", (), None, {"x": 1, "y": 0})]


async def test_groups_lead_values_and_optional_arguments() -> None:
    port = Port()
    await LimitSwitchAccess(port).set_lim(x=(0.0, 100.0))
    await TriggerAccess(port).set_trigr(5.0, 10.0, 6)
    await JoystickAccess(port).set_joyspeed(2, 25.0)
    assert [(s[1], s[2], s[3]) for s in port.sent] == [
        ("lim", (0.0, 100.0), "x"), ("trigr", (5.0, 10.0, 6), None),
        ("joyspeed", (2, 25.0), None)]


def test_manual_enum_pseudo_members_are_stable() -> None:
    assert DimUnit(9) is DimUnit.MM_VELOCITY_MM_S
    assert issubclass(DimUnit, ManualEnum)
    with pytest.raises(ValueError):
        DimUnit("2")  # type: ignore[arg-type]
