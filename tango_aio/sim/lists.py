"""Trigger position list (``trigp``/``trigc``/``trigi``) and snapshot array (``snsa``...).

Pure list semantics of the manual (L13767-14212, L15136-15389); positions are kept in the
user (dim) units they were written in. Violations raise :class:`ListError` with the error
number the emulator reports.

Decisions where the manual is silent:

* Writing an entry that breaks the monotonic order fixed by the first two entries (equal
  neighbours included: they give no direction), an index beyond ``count + 1``, or more
  than the maximum number of entries: error 5.
* Naming an axis with ``!trigp`` while the list is not empty ("later attempts of change are
  ignored and an error will be returned", L13798; "``!trigp x -1 9``: only possible if the
  list is empty", L13838): error 1, list unchanged.
* ``!trigc n`` / ``!snsc n`` with ``n`` larger than the count: error 5 (only shortening is
  documented).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import TypeVar

from ..catalog import MAX_SNAPSHOTS, MAX_TRIGGERS

__all__ = ["MAX_SNAPSHOTS", "MAX_TRIGGERS", "ListError", "SnapshotList", "TriggerList"]



class ListError(Exception):
    """A list operation was refused; ``code`` is the controller error number."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def _check_monotonic(entries: list[float]) -> None:
    """Every step in the direction of the first one; equal neighbours are refused."""
    if len(entries) < 2:
        return
    rising = entries[1] > entries[0]
    for before, after in itertools.pairwise(entries):
        if (after <= before) if rising else (after >= before):
            raise ListError(5, "trigger positions must be strictly monotonic")


def _check_slot(entries: list[float], slot: int, position: float) -> None:
    """Check writing ``position`` to 1-based ``slot`` in constant time where possible."""
    if slot <= 2:
        candidate = list(entries)
        candidate[slot - 1: slot] = [position]
        _check_monotonic(candidate)
        return
    neighbours = [*entries[slot - 2: slot - 1], position, *entries[slot: slot + 1]]
    rising = entries[1] > entries[0]
    for before, after in itertools.pairwise(neighbours):
        if (after <= before) if rising else (after >= before):
            raise ListError(5, "trigger positions must be strictly monotonic")


T = TypeVar("T")


def _write_slot(entries: list[T], index: int, maximum: int, what: str) -> int:
    """The 1-based slot ``!trigp``/``!snsa`` writes: -1 or count+1 appends."""
    count = len(entries)
    slot = count + 1 if index == -1 else index
    if not 1 <= slot <= count + 1:
        raise ListError(5, f"index {index} outside 1..{count + 1}")
    if slot > maximum:
        raise ListError(5, f"the {what} holds at most {maximum} entries")
    return slot


def _put(entries: list[T], slot: int, value: T) -> None:
    if slot == len(entries) + 1:
        entries.append(value)
    else:
        entries[slot - 1] = value


def _read(entries: list[T], index: int, what: str) -> T:
    """``?trigp n`` / ``?snsa n`` (1-based) or ``-1`` (the last entry)."""
    if not entries:
        raise ListError(5, f"the {what} is empty")
    slot = len(entries) if index == -1 else index
    if not 1 <= slot <= len(entries):
        raise ListError(5, f"index {index} outside 1..{len(entries)}")
    return entries[slot - 1]


def _truncate(entries: list[T], count: int, what: str) -> None:
    """``!trigc n`` / ``!snsc n``: keep the first n entries (only shortening)."""
    if count > len(entries):
        raise ListError(5, f"cannot grow the {what} to {count} entries")
    del entries[count:]



@dataclass
class TriggerList:
    """The ``!trigp`` trigger position list of the trigger axis."""

    entries: list[float] = field(default_factory=list)
    axis: str | None = None
    pointer: int = 1
    #: ``?trigr``: start, end and count of the last ``!trigr``.
    span: tuple[float, float, int] = (0.0, 0.0, 0)

    def count(self) -> int:
        """Number of entries (``?trigc``)."""
        return len(self.entries)

    def clear(self, axis: str | None = None) -> None:
        """Discard the list (``!trigp 0``); an axis letter also selects the trigger axis."""
        self.entries.clear()
        self.pointer = 1
        if axis is not None:
            self.axis = axis

    def write(self, index: int, position: float, axis: str | None = None) -> None:
        """``!trigp [axis] index position``: -1 or count+1 appends, 1..count overwrites."""
        if axis is not None and self.entries:
            # "!trigp x -1 9: Only possible if the list is empty" (L13838).
            raise ListError(1, f"trigger axis is {self.axis}; clear the list to name it")
        slot = _write_slot(self.entries, index, MAX_TRIGGERS, "list")
        _check_slot(self.entries, slot, position)
        _put(self.entries, slot, position)
        if axis is not None:
            self.axis = axis

    def fill(self, positions: list[float], axis: str | None = None) -> None:
        """Replace the whole list (``!trigr``); an axis letter selects the trigger axis."""
        _check_monotonic(positions)
        self.entries = list(positions)
        self.pointer = 1
        if axis is not None:
            self.axis = axis

    def read(self, index: int) -> float:
        """``?trigp n`` (1-based) or ``?trigp -1`` (last)."""
        return _read(self.entries, index, "trigger list")

    def shorten(self, count: int) -> None:
        """``!trigc n``: keep the first n entries (0 clears)."""
        _truncate(self.entries, count, "list")
        self.pointer = min(self.pointer, max(1, count))

    def set_pointer(self, index: int) -> None:
        """``!trigi n``: the 1-based list pointer."""
        if not 1 <= index <= max(1, len(self.entries)):
            raise ListError(5, f"pointer {index} outside 1..{len(self.entries)}")
        self.pointer = index


#: One snapshot entry: a position per axis, ``None`` where the entry holds none (the
#: manual's "invalid", L14586-14632): a step leaves that axis where it stands
#: (``!snsa -1 8.5 50.2``: "only X and Y axes will be used for positioning", L15389-15390).
Row = tuple[float | None, ...]


@dataclass
class SnapshotList:
    """The snapshot position array (``snsa``, ``snsc``, ``snsi``, ``snsp``)."""

    entries: list[Row] = field(default_factory=list)
    pointer: int = 0
    last: Row = ()
    voltages: dict[int, int] = field(default_factory=dict)

    def count(self) -> int:
        """Number of entries (``?snsc``)."""
        return len(self.entries)

    def clear(self) -> None:
        """``!snsa 0`` / ``!snsc 0``."""
        self.entries.clear()
        self.pointer = 0

    def write(self, index: int, row: Row) -> None:
        """``!snsa index pos...``: -1 or count+1 appends, 1..count overwrites."""
        _put(self.entries, _write_slot(self.entries, index, MAX_SNAPSHOTS, "array"), row)

    def write_axis(self, index: int, axis: int, value: float, axes: int) -> None:
        """``!snsa x index pos``: one axis of an entry (``!snsa x 1 20.5``, L15384);
        appending makes an entry that holds this axis only."""
        slot = _write_slot(self.entries, index, MAX_SNAPSHOTS, "array")
        old = self.entries[slot - 1] if slot <= len(self.entries) else ()
        row = tuple(value if i == axis else (old[i] if i < len(old) else None)
                    for i in range(axes))
        _put(self.entries, slot, row)

    def step(self, *, advance_first: bool) -> Row | None:
        """A step of modes 1 and 5: the entry to move to, the pointer moved on, wrapping
        at the end (L14520-14526); ``advance_first``: the pointer moves on first (switch
        ``snapshot_pointer``). ``None``: the array is empty, nothing to move to."""
        if not self.entries:
            return None
        count = len(self.entries)
        if advance_first:
            self.pointer = (self.pointer + 1) % count
            return self.entries[self.pointer]
        row = self.entries[self.pointer % count]
        self.pointer = (self.pointer + 1) % count
        return row

    def capture(self, row: Row) -> None:
        """A snapshot event: append the current position (captures always append)."""
        self.last = row
        if len(self.entries) < MAX_SNAPSHOTS:
            self.entries.append(row)

    def read(self, index: int) -> Row:
        """``?snsa n`` (1-based) or ``?snsa -1`` (last)."""
        return _read(self.entries, index, "snapshot array")

    def shorten(self, count: int) -> None:
        """``!snsc n``: keep the first n entries."""
        _truncate(self.entries, count, "array")
        self.pointer = min(self.pointer, max(0, count - 1))

    def set_pointer(self, index: int) -> None:
        """``!snsi n``: the 0-based move pointer."""
        if not 0 <= index <= max(0, len(self.entries) - 1):
            raise ListError(5, f"pointer {index} outside 0..{len(self.entries) - 1}")
        self.pointer = index
