"""The AUX I/O shutter output of a TANGO as a Micro-Manager shutter."""

from __future__ import annotations

from pymmcore_plus.experimental.unicore import ShutterDevice

import tango_aio.sync

from ._hub import TangoHub, hub_of


class TangoShutter(ShutterDevice):
    """The AUX I/O shutter output (``!shutter 1`` TTL high = open, ``!shutter 0`` low =
    closed; manual L9837-9860) as a Micro-Manager shutter. The driver proves each
    setting by reading it back.

    Parameters
    ----------
    hub
        The hub of the controller; ``None``: the initialised hub named by the device's
        parent label.
    """

    def __init__(self, hub: TangoHub | None = None) -> None:
        super().__init__()
        self._hub = hub

    @property
    def controller(self) -> tango_aio.sync.Controller:
        """The hub's blocking controller."""
        if self._hub is None:
            self._hub = hub_of(self.get_parent_label())
        return self._hub.controller

    def initialize(self) -> None:
        """Connect through the hub and read the output once."""
        self.get_open()

    def get_open(self) -> bool:
        """Whether the output is high (``?shutter``).

        Returns
        -------
        bool
            ``True`` if open.
        """
        return int(self.controller.get("shutter")) == 1

    def set_open(self, open: bool) -> None:
        """Drive the output high (open) or low (closed).

        Parameters
        ----------
        open
            ``True`` opens.
        """
        self.controller.set("shutter", 1 if open else 0)
