"""The emulator's saved parameters on disk (``SimConfig.state_file``, ``--state FILE``).

``save`` stores the saved parameters (the controller's eeprom) as JSON; a new emulator,
``reset`` and ``restore`` load them back. The file looks like::

    {"format": "tango_aio.sim state", "version": 1,
     "axes": {"vel": [[10.0], [10.0], [10.0], [10.0]], ...},
     "global": {"usteps": [40000], ...}}

Choices:

* A file is checked completely before anything is taken from it: it must be our JSON
  (the ``format`` marker and a ``version`` we know), every name a parameter of the
  emulator, every per-axis value one group per axis letter, every value a string, an
  integer or a finite number of the parameter's kind. ``NaN``, ``Infinity`` and numbers
  that overflow to infinity (``1e999``) are refused. Anything else raises
  :class:`StateFileError` naming the file and what is wrong, so a server started with a
  bad file fails once, at start, with one clear message.
* Files written before the marker existed (only ``axes`` and ``global``) are accepted when
  they pass the same checks; the next ``save`` adds the marker.
* An existing file that is not ours is never overwritten: ``save`` refuses (the model
  answers error 73) and leaves it alone. An empty file counts as ours with nothing saved
  (e.g. made by ``touch`` or ``mktemp``); so does a missing one.
* Files are written atomically (a temporary file in the same directory, fsync, rename):
  readers see the old or the new file, never half of one.
* The file is read again by every load (a new emulator, ``reset``, ``restore``). A file
  that turns bad while an emulator runs makes that instruction fail; the emulator then
  keeps its power-on defaults.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ..catalog import AXES
from .params import ParamStore, Value

__all__ = ["FORMAT", "MAX_SIZE", "VERSION", "StateFileError", "load_state", "save_state"]

FORMAT = "tango_aio.sim state"
"""The marker in every state file the emulator writes."""
VERSION = 1
"""The layout version written (and the only one read)."""
MAX_SIZE = 1 << 20
"""Files larger than this (bytes) are not ours: a state file is about 20 kB."""

_LEGACY_KEYS = frozenset({"axes", "global"})


class StateFileError(ValueError):
    """The state file cannot be used: it is not ours, or its content is not valid."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"state file {path}: {reason}")
        self.path = path
        """The file concerned."""
        self.reason = reason
        """What is wrong with it."""


def load_state(path: Path | None, store: ParamStore) -> None:
    """Put the parameters saved in ``path`` into ``store``; nothing if there is no file."""
    if path is None:
        return
    data = _read(path)
    if data is None:
        return
    axes, global_ = _validated(path, data, store)
    store.axis_values.update(axes)
    store.global_values.update(global_)


def save_state(path: Path, store: ParamStore, names: Iterable[str]) -> None:
    """Write the parameters ``names`` of ``store`` to ``path`` atomically."""
    if path.exists():
        _read(path)  # raises if the existing file is not ours
    chosen = list(names)
    data: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "axes": {n: store.axis_values[n] for n in chosen if n in store.axis_values},
        "global": {n: store.global_values[n] for n in chosen if n in store.global_values},
    }
    try:
        text = json.dumps(data, indent=1, allow_nan=False)
    except ValueError as exc:
        raise StateFileError(path, f"cannot save a value that is not finite ({exc})") from exc
    _atomic_write(path, text)


# -- reading -------------------------------------------------------------------------------


def _read(path: Path) -> dict[str, Any] | None:
    """The parsed JSON object of an existing state file; None if missing or empty."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        return None
    if size > MAX_SIZE:
        raise StateFileError(path, f"not a tango_aio emulator state file ({size} bytes)")
    raw = path.read_bytes()
    if not raw.strip():
        return None
    try:
        data = json.loads(raw.decode("utf-8"), parse_constant=_no_constant,
                          parse_float=_finite_float)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StateFileError(path, f"not a tango_aio emulator state file ({exc})") from exc
    except _NotFinite as exc:
        raise StateFileError(path, str(exc)) from exc
    if not isinstance(data, dict):
        raise StateFileError(path, "not a tango_aio emulator state file (not a JSON object)")
    if "format" in data or "version" in data:
        if data.get("format") != FORMAT:
            raise StateFileError(path, f"not a tango_aio emulator state file (format "
                                       f"{data.get('format')!r}, expected {FORMAT!r})")
        if data.get("version") != VERSION:
            raise StateFileError(path, f"unsupported version {data.get('version')!r} "
                                       f"(this emulator reads version {VERSION})")
    elif not set(data) <= _LEGACY_KEYS or not data:
        raise StateFileError(path, f"not a tango_aio emulator state file (no "
                                   f"{FORMAT!r} marker; keys {sorted(data)})")
    return data


class _NotFinite(ValueError):
    pass


def _no_constant(name: str) -> float:
    raise _NotFinite(f"{name} is not a valid value")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NotFinite(f"{text} is not a finite number")
    return value


def _validated(path: Path, data: Mapping[str, Any], store: ParamStore
               ) -> tuple[dict[str, list[tuple[Value, ...]]], dict[str, tuple[Value, ...]]]:
    """The file's parameters, checked against the names and kinds of ``store``."""
    unknown = set(data) - _LEGACY_KEYS - {"format", "version"}
    if unknown:
        raise StateFileError(path, f"unknown key(s) {sorted(unknown)}")
    axes_in = _section(path, data, "axes")
    global_in = _section(path, data, "global")
    axes: dict[str, list[tuple[Value, ...]]] = {}
    for name, groups in axes_in.items():
        if name not in store.axis_values:
            raise StateFileError(path, f"axes: {name!r} is not a per-axis parameter")
        if not isinstance(groups, list) or len(groups) != len(AXES):
            raise StateFileError(path, f"axes.{name}: expected {len(AXES)} value groups "
                                       f"(one per axis {''.join(AXES)})")
        axes[name] = [_group(path, f"axes.{name}[{index}]", group, store.axis(name, index))
                      for index, group in enumerate(groups)]
    global_: dict[str, tuple[Value, ...]] = {}
    for name, values in global_in.items():
        if name not in store.global_values:
            raise StateFileError(path, f"global: {name!r} is not a global parameter")
        global_[name] = _group(path, f"global.{name}", values, store.global_values[name])
    return axes, global_


def _section(path: Path, data: Mapping[str, Any], key: str) -> dict[str, Any]:
    section = data.get(key, {})
    if not isinstance(section, dict):
        raise StateFileError(path, f"{key}: expected an object of parameters")
    return section


def _group(path: Path, where: str, values: Any, template: tuple[Value, ...]
           ) -> tuple[Value, ...]:
    """One value group, each value of the kind (text or number) of the template's."""
    if not isinstance(values, list) or not values:
        raise StateFileError(path, f"{where}: expected a non-empty list of values")
    group: list[Value] = []
    for index, value in enumerate(values):
        like = template[index] if index < len(template) else None
        group.append(_value(path, f"{where}[{index}]", value, like))
    return tuple(group)


def _value(path: Path, where: str, value: Any, like: Value | None) -> Value:
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise StateFileError(path, f"{where}: {value!r} is not a text or a number")
    if isinstance(value, int):
        try:
            float(value)
        except OverflowError:
            raise StateFileError(path, f"{where}: {value} is not a finite number") from None
    if like is not None and isinstance(like, str) != isinstance(value, str):
        kind = "a text" if isinstance(like, str) else "a number"
        raise StateFileError(path, f"{where}: expected {kind}, got {value!r}")
    return value


# -- writing -------------------------------------------------------------------------------


def _atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that readers see the old or the new file, never half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
