"""An emulated controller's identity and static configuration (``SimConfig``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .motion import MotionConfig
from .profiles import Firmware

#: Option bits of ``?det``: trigger out and snapshot (manual L1119-1185).
DEFAULT_OPTIONS = 0x2800


@dataclass(frozen=True)
class SimConfig:
    """Identity and static configuration of an emulated controller.

    ``firmware`` is the behaviour where the manual is silent (the ``manual`` profile by
    default, see :mod:`tango_aio.sim.profiles`); ``version`` is the version number
    ``?version`` shows.
    """

    axes: int = 3
    model: str = "TANGO-DT"
    firmware: Firmware = field(default_factory=Firmware)
    version: str = "1.71"
    build: str = "Jun  4 2019 , 12:00:00"
    serial: str = "190604001"
    options: int = DEFAULT_OPTIONS
    #: Where ``save`` persists the saved parameters (JSON, written atomically); ``None``:
    #: in memory, for the life of this model.
    state_file: Path | None = None
    #: Extra interpreter time of blocking instructions, in seconds.
    reset_time: float = 1.0
    motion: MotionConfig | None = None
    #: Instructions this unit lacks (an optional module, a smaller model): like any
    #: instruction it does not know, each answers nothing and sets error 4 ("invalid
    #: instruction", L970); the manual does not list which units lack which.
    lacks: frozenset[str] = frozenset()

    @property
    def det(self) -> int:
        """The ``?det`` value: options plus the axis count in bits 4-7."""
        return self.options | (self.axes << 4)
