"""Serve Märzhäuser TANGO controllers as Tango Controls devices.

Tango Controls is the control system toolkit (pytango); the Märzhäuser TANGO is the
stage controller this package drives. ``tango-aio tango-server URL`` (install the extra
``tango-aio[tango-controls]``, which brings pytango) serves one device per axis,
``PREFIX/x`` ... (``MarzhauserAxis``), and ``PREFIX/controller``
(``MarzhauserController``); see ``docs/howto/tango-controls.md``.

* :func:`serve` runs the server (blocking) for a :class:`ServerOptions`;
* :func:`shown` decides an axis device's ``State`` and ``Status`` (pure, no pytango).

Only the device module imports pytango, so the command line and the pure parts work
without it.
"""

from __future__ import annotations

from ._command import add_tango_server_command
from ._server import DEFAULT_PREFIX, ServerOptions, device_names, serve
from ._state import AxisView, Shown, shown

__all__ = ["DEFAULT_PREFIX", "AxisView", "ServerOptions", "Shown", "add_tango_server_command",
           "device_names", "serve", "shown"]
