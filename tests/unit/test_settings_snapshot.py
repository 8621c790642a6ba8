"""The settings snapshot as data: what it holds, the order a restore writes, differences,
and its JSON form."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.errors import SnapshotMismatchError
from tango_aio.families import SettingsSnapshot
from tango_aio.families._snapshot import (
    LINK,
    differences,
    label,
    restore_order,
    same,
    snapshot_entries,
)


def _snapshot(values: dict[tuple[str, str | None, int | None], object]) -> SettingsSnapshot:
    return SettingsSnapshot("TANGO-DT", "1.71", "190604001", "xyz", "2026-11-28T12:00:00+00:00",
                            dict(values), {"extmode": "not supported"})


def test_a_snapshot_holds_every_saved_readable_setting_and_the_limits() -> None:
    names = [entry.name for entry in snapshot_entries()]
    assert {"vel", "dim", "pitch", "joyspeed", "swtyp", "trigs", "lim", "lock"} <= set(names)
    assert "pos" not in names and "trigcount" not in names  # not settings
    assert len(names) == len(set(names))


def test_restore_order_puts_the_units_first_and_the_write_protection_last() -> None:
    names = [entry.name for entry in snapshot_entries()]
    assert names[:7] == ["extmode", "dim", "pitch", "gear", "motorsteps", "usteps",
                         "resolution"]
    assert names[-3:] == ["lim", "lock", "lockaxis"]
    keys = restore_order([("vel", "y", None), ("lim", "x", None), ("vel", "x", None),
                          ("dim", "z", None), ("joyspeed", None, 3), ("joyspeed", None, 1)])
    assert keys == [("dim", "z", None), ("vel", "x", None), ("vel", "y", None),
                    ("joyspeed", None, 1), ("joyspeed", None, 3), ("lim", "x", None)]


def test_differences_name_each_setting_axis_and_index() -> None:
    snap = {("vel", "x", None): 10.0, ("vel", "y", None): 10.0, ("joyspeed", None, 2): 10.0,
            ("lim", "x", None): (-5.0, 5.0), ("triga", None, None): "x"}
    now = {("vel", "x", None): 10.0 + 1e-12, ("vel", "y", None): 3.0,
           ("joyspeed", None, 2): 25.0, ("lim", "x", None): (-5.0, 5.0),
           ("triga", None, None): "y"}
    found = differences(snap, now)
    assert [label(d.key) for d in found] == ["vel Y", "joyspeed 2", "triga"]
    assert str(found[0]) == "vel Y: snapshot 10.0, unit 3.0"
    assert differences(snap, {})[0].unit is None  # a setting the unit lacks


def test_json_round_trip_keeps_every_value_and_its_kind() -> None:
    values = {("vel", "x", None): 10.5, ("dim", "x", None): 2, ("lim", "y", None): (-1.0, 2.0),
              ("trigs", None, None): (40, 0, 0), ("triga", None, None): "x",
              ("joyspeed", None, 2): 25.0, ("lock", None, None): "0000000000000000"}
    snapshot = _snapshot(values)
    back = SettingsSnapshot.from_json(snapshot.to_json())
    assert back == snapshot
    assert type(back.values[("dim", "x", None)]) is int
    assert json.loads(snapshot.to_json())["settings"][0]["setting"] == "dim"


@given(st.dictionaries(st.sampled_from(["vel", "accel", "pitch", "twi"]),
                       st.floats(allow_nan=False, allow_infinity=False, width=32)))
def test_json_round_trip_of_any_numbers(numbers: dict[str, float]) -> None:
    snapshot = _snapshot({(name, "x", None): value for name, value in numbers.items()})
    assert SettingsSnapshot.from_json(snapshot.to_json()).values == snapshot.values


@pytest.mark.parametrize("text", [
    "not json", "[]", '{"format": "other", "version": 1}',
    '{"format": "tango_aio settings", "version": 2}',
    '{"format": "tango_aio settings", "version": 1, "model": "TANGO-DT"}',
])
def test_from_json_refuses_what_is_not_a_snapshot(text: str) -> None:
    with pytest.raises(SnapshotMismatchError):
        SettingsSnapshot.from_json(text)


@pytest.mark.parametrize("item", [
    {"setting": "nosuch", "axis": None, "index": None, "value": 1},
    {"setting": "vel", "axis": "q", "index": None, "value": 1},
    {"setting": "vel", "axis": "x", "index": None, "value": None},
    {"setting": "vel", "axis": "x", "index": None, "value": True},
])
def test_from_json_refuses_unknown_settings_and_values(item: dict[str, object]) -> None:
    data = json.loads(_snapshot({}).to_json())
    data["settings"] = [item]
    with pytest.raises(SnapshotMismatchError):
        SettingsSnapshot.from_json(json.dumps(data))


def test_values_compare_as_the_controller_prints_them() -> None:
    assert same(1.0, 1) and same((1.0, 2.0), [1, 2]) and not same((1.0,), (1.0, 2.0))
    assert not same("x", "y") and not same(1.0, None)


def test_the_link_settings_are_never_written_by_a_restore() -> None:
    assert {"baud", "cts", "ipreter"} <= LINK
