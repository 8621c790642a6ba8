"""The hub: one TANGO controller and its link, shared by the stages and the shutter."""

from __future__ import annotations

import gc
import threading
import weakref
from collections.abc import Sequence
from typing import Any

from pymmcore_plus.experimental.unicore import HubDevice, pymm_property

import tango_aio.sync

#: The unit of every position this package hands Micro-Manager (the connection's
#: ``units``: the driver converts from each axis's ``dim``, which it never changes).
UNIT = "um"

#: Hubs by label, for peripherals loaded by name (``loadDevice``) that find their hub
#: through their parent label.
_HUBS: weakref.WeakValueDictionary[str, TangoHub] = weakref.WeakValueDictionary()


class TangoHub(HubDevice):
    """A TANGO controller: the one link its stages and shutter share.

    Opens ``tango_aio.sync.connect(url, units="um", **options)`` when initialised (or
    when a peripheral first needs it) and closes it on shutdown. Its properties: ``URL``
    (before initialisation), the controller's identity (``Model``, ``Firmware``,
    ``Axes``) and ``Joystick`` (the HDI, ``!joy``).

    Parameters
    ----------
    url
        Where the controller is (``"sim://"``, ``"/dev/ttyUSB0"``, ``"COM3"``,
        ``"socket://host:port"``); the ``URL`` property may set it before initialisation.
    **options
        Further options of :func:`tango_aio.connect` (not ``units``: positions are
        always in µm here).

    Raises
    ------
    ValueError
        ``units`` among the options.
    """

    def __init__(self, url: str = "sim://", **options: Any) -> None:
        if "units" in options:
            raise ValueError("TangoHub speaks µm to Micro-Manager: leave out 'units'")
        super().__init__()
        self._url = url
        self._options = options
        self._opening = threading.Lock()
        self._controller: tango_aio.sync.Controller | None = None

    @pymm_property(name="URL", is_pre_init=True)
    def url(self) -> str:
        """Where the controller is (serial port, ``socket://host:port``, ``sim://``)."""
        return self._url

    @url.setter  # type: ignore[no-redef]
    def url(self, value: str) -> None:
        if self._controller is not None:
            raise RuntimeError("the hub is connected: set its URL before initialising it")
        self._url = str(value)

    @property
    def controller(self) -> tango_aio.sync.Controller:
        """The blocking controller, connected on first use (thread-safe)."""
        with self._opening:
            if self._controller is None:
                self._controller = tango_aio.sync.connect(self._url, units=UNIT,
                                                          **self._options)
            return self._controller

    def initialize(self) -> None:
        """Connect (once), and make the hub findable by its label."""
        self.controller  # noqa: B018 - connects
        if self.get_label():
            _HUBS[self.get_label()] = self

    def shutdown(self) -> None:
        """Close the link."""
        with self._opening:
            controller, self._controller = self._controller, None
        if controller is not None:
            controller.close()
            # The closed link's reference cycles (its event loop, thread and transport)
            # are collected here, in the caller's thread, rather than by a collection
            # that pymmcore's callback thread may run while the interpreter exits, which
            # aborts the process ("exception not rethrown"; see the how-to).
            gc.collect()

    def get_installed_peripherals(self) -> Sequence[tuple[str, str]]:
        """The device classes a TANGO can carry (loadable by name, parent: this hub).

        Returns
        -------
        Sequence[tuple[str, str]]
            ``(class name, description)`` of each.
        """
        return (("TangoXYStage", "two axes of the controller as an XY stage"),
                ("TangoZStage", "one axis of the controller as a focus (Z) stage"),
                ("TangoShutter", "the AUX I/O shutter output (!shutter)"),
                ("TangoStrobe", "an LED strobe on the AUX I/O TAKT_OUT pin (!flash)"))

    @pymm_property(name="Model", is_read_only=True)
    def model(self) -> str:
        """The controller's model (``?version``)."""
        return self.controller.identity.model

    @pymm_property(name="Firmware", is_read_only=True)
    def firmware(self) -> str:
        """The controller's firmware version (``?version``)."""
        return self.controller.identity.firmware

    @pymm_property(name="Axes", is_read_only=True)
    def axes(self) -> int:
        """How many axes the controller has."""
        return self.controller.identity.axes

    @pymm_property(name="Joystick", allowed_values=("On", "Off"))
    def joystick(self) -> str:
        """Whether the HDI (joystick, trackball) moves the stage (``?joy`` not 0,
        manual L7101-7118)."""
        return "On" if self.controller.joystick.is_enabled() else "Off"

    @joystick.setter  # type: ignore[no-redef]
    def joystick(self, value: str) -> None:
        # ``!joy 2`` / ``!joy 0``, each proven by its read-back (the driver's family).
        if value == "On":
            self.controller.joystick.enable()
        else:
            self.controller.joystick.disable()


def hub_of(label: str) -> TangoHub:
    """The initialised hub with ``label`` (a peripheral's parent).

    Parameters
    ----------
    label
        The hub's label in the core.

    Returns
    -------
    TangoHub
        The hub.

    Raises
    ------
    RuntimeError
        No initialised hub has that label.
    """
    hub = _HUBS.get(label) if label else None
    if hub is None:
        raise RuntimeError(f"no initialised TangoHub labelled {label!r}: give the device "
                           "its hub (TangoXYStage(hub)), or set its parent label to an "
                           "initialised hub's")
    return hub
