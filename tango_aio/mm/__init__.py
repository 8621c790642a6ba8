"""TANGO stages, the AUX shutter and the LED strobe as pure-Python devices of pymmcore-plus's
``UniMMCore`` (``pip install 'tango-aio[mm]'``), for Micro-Manager programs in Python
(napari-micromanager, pymmcore-gui, scripts).

::

    from pymmcore_plus.experimental.unicore import UniMMCore
    from tango_aio.mm import load_tango

    core = UniMMCore()
    labels = load_tango(core, "/dev/ttyUSB0")   # {"hub": "TangoHub", "xy": "TangoXY", ...}
    core.setXYPosition(1500, -250)              # µm
    core.waitForDevice(labels["xy"])            # until the driver's verdict: there

Tested with pymmcore-plus 0.18 (its ``unicore`` API is experimental; the extra pins the
tested range). See docs/howto/micro-manager.md.
"""

from __future__ import annotations

from . import _unicore  # noqa: F401 - first: pymmcore-plus, the root logger's level kept
from ._hub import TangoHub, hub_of
from ._load import load_tango
from ._shutter import TangoShutter, TangoStrobe
from ._stages import TangoXYStage, TangoZStage

__all__ = ["TangoHub", "TangoShutter", "TangoStrobe", "TangoXYStage", "TangoZStage",
           "hub_of", "load_tango"]
