"""A controller's settings as data: which settings a snapshot holds, in which order a
restore writes them, how two sets of values differ, and the snapshot's JSON form.

* A snapshot holds every readable setting that ``save`` stores (the catalog's ``saved``,
  the manual's "Save" column, L267-923) and the software limits ``lim``, which it does
  not store but which a restore must bring back after ``dim`` and ``pitch``.
* A restore writes ``extmode`` first (``calvel``, ``rmvel`` and ``joyvel`` act only in
  extmode 1, L499-501, L611, L2196-2267), then what gives every value its unit: ``dim``,
  ``pitch``, ``gear``, ``motorsteps``, ``usteps``, ``resolution`` (L3061-4167); then
  the rest in the manual's order, the limits after them, and the write protection
  (``lock``, ``lockaxis``, L4222-4322) last, so that it protects nothing the restore
  still has to write.
* The link's own settings (``baud``, ``cts``, ``ipreter``, ``configdisplay``,
  L1624-1720, L1986-2057, L2624-2659) are compared but never written by a restore:
  changing them would cut the connection that does the restore.
"""

from __future__ import annotations

import datetime
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..catalog import AXES, INSTRUCTIONS, AxisRule, Form, Instruction, Shape
from ..errors import SnapshotMismatchError

__all__ = ["FIRST", "LAST", "LINK", "SettingDifference", "SettingKey", "SettingsSnapshot",
           "differences", "label", "restore_order", "snapshot_entries"]

#: Written first by a restore, in this order: the mode and the units of every value.
FIRST = ("extmode", "dim", "pitch", "gear", "motorsteps", "usteps", "resolution")
#: Written after everything else: the limits, then the write protection.
LAST = ("lim", "lock", "lockaxis")
#: Compared, never written by a restore (they would cut the link).
LINK = frozenset({"baud", "cts", "ipreter", "configdisplay"})
#: Settings a snapshot holds beside the saved ones.
EXTRA = ("lim",)

FORMAT = "tango_aio settings"
VERSION = 1

#: One value of a setting: ``(instruction, axis or None, index or None)``.
SettingKey = tuple[str, str | None, int | None]


def snapshot_entries() -> list[Instruction]:
    """The instructions a snapshot reads, in restore order."""
    seen: dict[str, Instruction] = {}
    for entry in INSTRUCTIONS.values():
        if (entry.saved or entry.name in EXTRA) and entry.allows(Form.READ) \
                and entry.reply is not Shape.NONE:
            seen.setdefault(entry.name, entry)
    return sorted(seen.values(), key=lambda e: _rank(e.name))


def _rank(name: str) -> tuple[int, int]:
    if name in FIRST:
        return (0, FIRST.index(name))
    if name in LAST:
        return (2, LAST.index(name))
    return (1, _MANUAL_ORDER.get(name, 0))


_MANUAL_ORDER = {name: position for position, name in enumerate(
    dict.fromkeys(entry.name for entry in INSTRUCTIONS.values()))}


def restore_order(keys: Iterable[SettingKey]) -> list[SettingKey]:
    """``keys`` in the order a restore writes them (axes X Y Z A, indices rising)."""
    return sorted(keys, key=lambda k: (*_rank(k[0]), AXES.index(k[1]) if k[1] else -1,
                                       k[2] if k[2] is not None else -1))


def is_indexed(entry: Instruction) -> bool:
    """Whether the setting is read and written per index (``?joyspeed 2``)."""
    return bool(entry.indexed)


def indices(entry: Instruction) -> tuple[int, ...]:
    """The indices of an indexed setting, from its read parameter's choices or range."""
    param = entry.read[0].lead[0]
    if param.choices:
        return tuple(int(c) for c in param.choices)
    assert param.lo is not None and param.hi is not None
    return tuple(range(int(param.lo), int(param.hi) + 1))


def read_per_axis(entry: Instruction) -> bool:
    """Whether a per-axis setting with a reply not per axis is read axis by axis."""
    # ?calbspeed x, ?ctrd x
    signature = entry.write[0] if entry.write else None
    return signature is not None and bool(signature.per_axis) \
        and signature.axis in (AxisRule.ALL, AxisRule.REQUIRED) \
        and entry.reply not in (Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT)


def label(key: SettingKey) -> str:
    """``'vel X'``, ``'joyspeed 2'``, ``'scanvel'``: how a setting is named to a user."""
    name, axis, index = key
    return " ".join([name, *([axis.upper()] if axis else []),
                     *([str(index)] if index is not None else [])])


def same(a: object, b: object) -> bool:
    """Whether two values of a setting are equal (numbers to 1e-9 relative)."""
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    if isinstance(a, Sequence) and isinstance(b, Sequence):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


@dataclass(frozen=True)
class SettingDifference:
    """One setting whose value differs between a snapshot and the unit.

    Parameters
    ----------
    setting
        The instruction (``'vel'``).
    axis
        Its axis (``None``: a global setting).
    index
        Its index (``joyspeed 2``; ``None``: not indexed).
    snapshot
        The snapshot's value.
    unit
        The unit's value now.
    """

    setting: str
    axis: str | None
    index: int | None
    snapshot: Any
    unit: Any

    @property
    def key(self) -> SettingKey:
        """``(setting, axis, index)``."""
        return (self.setting, self.axis, self.index)

    def __str__(self) -> str:
        return f"{label(self.key)}: snapshot {_text(self.snapshot)}, unit {_text(self.unit)}"


def _text(value: object) -> str:
    if isinstance(value, list | tuple):
        return " ".join(_text(v) for v in value)
    return str(value)


def differences(snapshot: Mapping[SettingKey, Any], unit: Mapping[SettingKey, Any]
                ) -> list[SettingDifference]:
    """The settings of ``snapshot`` whose value ``unit`` does not hold, in restore order."""
    return [SettingDifference(*key, snapshot[key], unit.get(key))
            for key in restore_order(snapshot) if not same(snapshot[key], unit.get(key))]


@dataclass(frozen=True)
class SettingsSnapshot:
    """Every readable setting of one controller at one moment.

    Parameters
    ----------
    model
        The controller's model (``TANGO-DT``).
    firmware
        Its firmware version.
    serial_number
        Its serial number (``None``: not read).
    axes
        The axes present (``"xyz"``).
    taken
        When it was taken (UTC, ISO 8601).
    values
        Each setting's value by ``(instruction, axis, index)``.
    absent
        Settings this unit did not answer, and why.
    """

    model: str
    firmware: str
    serial_number: str | None
    axes: str
    taken: str
    values: dict[SettingKey, Any] = field(default_factory=dict)
    absent: dict[str, str] = field(default_factory=dict)

    @staticmethod
    def now() -> str:
        """The current time as a snapshot records it.

        Returns
        -------
        str
            UTC, ISO 8601, seconds.
        """
        return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")

    def to_json(self) -> str:
        """The snapshot as JSON text (one setting per entry, in restore order).

        Returns
        -------
        str
            The JSON text.
        """
        settings = [{"setting": k[0], "axis": k[1], "index": k[2],
                     "value": _plain(self.values[k])} for k in restore_order(self.values)]
        return json.dumps({"format": FORMAT, "version": VERSION, "model": self.model,
                           "firmware": self.firmware, "serial_number": self.serial_number,
                           "axes": self.axes, "taken": self.taken, "settings": settings,
                           "absent": self.absent}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> SettingsSnapshot:
        """Read a snapshot written by :meth:`to_json`.

        Parameters
        ----------
        text
            The JSON text.

        Returns
        -------
        SettingsSnapshot
            The snapshot.

        Raises
        ------
        SnapshotMismatchError
            The text is not a settings snapshot, or names an unknown setting or axis.
        """
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise SnapshotMismatchError(f"not a settings snapshot: {exc}") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT \
                or data.get("version") != VERSION:
            raise SnapshotMismatchError(
                f"not a settings snapshot (format {FORMAT!r} version {VERSION})")
        values: dict[SettingKey, Any] = {}
        try:
            for item in data["settings"]:
                name, axis, index = item["setting"], item["axis"], item["index"]
                if name not in INSTRUCTIONS or (axis is not None and axis not in AXES) \
                        or not (index is None or isinstance(index, int)):
                    raise SnapshotMismatchError(f"unknown setting {label((name, axis, index))!r}")
                values[(INSTRUCTIONS[name].name, axis, index)] = _value(item["value"])
            return cls(str(data["model"]), str(data["firmware"]),
                       data.get("serial_number"), str(data["axes"]), str(data["taken"]),
                       values, dict(data.get("absent") or {}))
        except (KeyError, TypeError) as exc:
            raise SnapshotMismatchError(f"not a settings snapshot: missing {exc}") from None


def _plain(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return int(value)  # an IntEnum as its number
    return value


def _value(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_value(v) for v in value)
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise SnapshotMismatchError(f"not a setting value: {value!r:.40}")
    if isinstance(value, float) and not math.isfinite(value):
        raise SnapshotMismatchError(f"not a finite value: {value!r}")
    return value
