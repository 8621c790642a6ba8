"""Settings of the motor records kept across IOC restarts (pure, no caproto).

``tango-aio ioc ... --autosave FILE`` keeps, per motor record, the fields in
:data:`SAVED`: the user offset, the soft limits (dial), the speed and its maximum. The
file is JSON, ``{"LAB:STAGE:X": {"OFF": 1.5, "DHLM": 100.0, ...}, ...}``; it is rewritten
(atomically: a temporary file, then a rename) after every put that changes one of them,
and read when the IOC starts, which puts the values back (the limits and the speed into
the controller) once the controller is connected. A missing file is an empty one; a file
that cannot be read is an error at start-up, so nothing is silently lost.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

__all__ = ["SAVED", "Autosave"]

#: The fields kept, in the order they are put back (limits before the offset that
#: shifts their user values; VMAX before the VELO it limits).
SAVED = ("DLLM", "DHLM", "OFF", "VMAX", "VELO")


class Autosave:
    """The autosave file of one IOC: :meth:`load` at start, :meth:`store` after a put."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.values: dict[str, dict[str, float]] = {}

    def load(self) -> dict[str, dict[str, float]]:
        """Read the file (``{}`` if it does not exist); raises ``ValueError`` for a file
        that is not an autosave file."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            self.values = {}
            return {}
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{self.path}: not an autosave file ({exc})") from None
        values: dict[str, dict[str, float]] = {}
        if not isinstance(data, dict):
            raise ValueError(f"{self.path}: not an autosave file (no object)")
        for record, fields in data.items():
            if not isinstance(fields, dict):
                raise ValueError(f"{self.path}: {record!r} has no fields")
            values[str(record)] = {
                name: float(value) for name, value in fields.items()
                if name in SAVED and isinstance(value, (int, float))
                and math.isfinite(value)}
        self.values = values
        return values

    def store(self, record: str, fields: dict[str, float]) -> None:
        """Record ``fields`` of ``record`` and rewrite the file atomically."""
        self.values[record] = {name: float(fields[name]) for name in SAVED if name in fields}
        temporary = self.path.with_name(self.path.name + ".tmp")
        temporary.write_text(json.dumps(self.values, indent=1, sort_keys=True) + "\n",
                             encoding="utf-8")
        os.replace(temporary, self.path)
