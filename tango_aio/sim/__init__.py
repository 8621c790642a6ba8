"""Emulator of a Märzhäuser TANGO controller: wire model, controller logic and serving layers.

The main names are importable from here (``from tango_aio.sim import serve_tcp``); each is
imported from its module on first use, so importing ``tango_aio.sim`` (or one of its
modules) loads nothing else. The emulator imports nothing of the driver's rules
(``tango_aio.sansio._core``, ``protocol``, ``patterns``, ``controller``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .model import ControllerModel, SimConfig
    from .ptyserve import serve_pty
    from .serve import create_sim_connection, serve_tcp
    from .wire import Wire, WireConfig

__all__ = [
    "ControllerModel",
    "SimConfig",
    "Wire",
    "WireConfig",
    "create_sim_connection",
    "serve_pty",
    "serve_tcp",
]

_HOMES = {
    "ControllerModel": "model", "SimConfig": "model",
    "Wire": "wire", "WireConfig": "wire",
    "create_sim_connection": "serve", "serve_pty": "ptyserve", "serve_tcp": "serve",
}


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use (PEP 562)."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
