"""The controller device's values as Tango Controls carries them (pure, no pytango): a
field of what the controller says about itself, and the trigger configuration as JSON."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from ..errors import InvalidCommandError
from ..families import TriggerConfig

__all__ = ["info_field", "trigger_config_json", "updated_trigger_config"]


def info_field(info: Any, name: str) -> Any:
    """The field ``name`` of a ``ControllerInfo``; LookupError if the controller did not
    answer it (a firmware without the instruction)."""
    value = getattr(info, name)
    if value is None:
        raise LookupError(f"the controller does not answer {name} (its firmware has no "
                          "such instruction)")
    return value


def trigger_config_json(config: TriggerConfig) -> str:
    """``config`` as a JSON object, the enumerations as their numbers."""
    fields = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    return json.dumps({name: int(value) if name in ("mode", "output") and value is not None
                       else value for name, value in fields.items()})


def updated_trigger_config(current: TriggerConfig, text: str) -> TriggerConfig:
    """``current`` with the fields of the JSON object ``text`` changed (checked as the
    configuration is made: InvalidCommandError, a ValueError, for a bad value or name)."""
    try:
        changes = json.loads(text)
    except ValueError as exc:
        raise InvalidCommandError(f"the trigger configuration is not JSON: {exc}",
                                  number=5) from exc
    if not isinstance(changes, dict):
        raise InvalidCommandError("the trigger configuration must be a JSON object of the "
                                  "fields to change", number=5)
    known = {f.name for f in dataclasses.fields(TriggerConfig)}
    unknown = sorted(set(changes) - known)
    if unknown:
        raise InvalidCommandError(f"no such trigger setting: {', '.join(unknown)} (known: "
                                  f"{', '.join(sorted(known))})", number=5)
    return dataclasses.replace(current, **changes)
