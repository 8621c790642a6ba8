"""Many controllers at once: ``ControllerGroup``, ``discover`` and move coalescing."""

from __future__ import annotations

from ._coalesce import (
    MoveCoalescer,
)
from ._discovery import (
    DiscoveredController,
    PortProbe,
    discover,
    probe_ports,
)
from ._group import (
    ControllerGroup,
    ControllerSpec,
    GroupError,
    GroupEvent,
    GroupSubscription,
)

__all__ = [
    "ControllerGroup",
    "ControllerSpec",
    "DiscoveredController",
    "GroupError",
    "GroupEvent",
    "GroupSubscription",
    "MoveCoalescer",
    "PortProbe",
    "discover",
    "probe_ports",
]
