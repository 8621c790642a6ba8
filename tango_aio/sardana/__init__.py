"""A Sardana motor controller for Märzhäuser TANGO stage controllers (the ``sardana`` extra).

Sardana (the scan and motor-pool layer over the Tango Controls toolkit, which is not the
Märzhäuser TANGO) loads controller classes from the files in its ``PoolPath``: add
:data:`POOL_PATH` (``python -m tango_aio.sardana`` prints it) and create a controller of
class ``MarzhauserMotorController`` from library ``MarzhauserMotorCtrl.py`` (and, for
hardware-synchronised continuous scans, one of class ``MarzhauserTriggerGateController``
from ``MarzhauserTriggerGateCtrl.py`` with the same URL); see the
how-to "Use TANGO stages in a Sardana pool".
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ._controller import MarzhauserMotorController
    from ._trigger import MarzhauserTriggerGateController

__all__ = ["POOL_PATH", "MarzhauserMotorController", "MarzhauserTriggerGateController"]

#: The folder to add to the pool's ``PoolPath``: it holds ``MarzhauserMotorCtrl.py``.
POOL_PATH = str(Path(__file__).with_name("_poolpath"))


def __getattr__(name: str) -> Any:
    if name not in ("MarzhauserMotorController", "MarzhauserTriggerGateController"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        from ._controller import MarzhauserMotorController
        from ._trigger import MarzhauserTriggerGateController
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.partition(".")[0] not in ("sardana", "tango", "taurus"):
            raise
        raise ImportError("tango_aio.sardana's controller needs Sardana: install the "
                          "sardana extra (pip install -e '.[sardana]' in the checkout, "
                          "or pip install '/path/to/tango_aio[sardana]')") from exc
    return MarzhauserMotorController if name == "MarzhauserMotorController" \
        else MarzhauserTriggerGateController
