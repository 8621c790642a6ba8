"""The AUX I/O shutter output and the LED strobe of a TANGO as Micro-Manager shutters."""

from __future__ import annotations

from pymmcore_plus.experimental.unicore import ShutterDevice, pymm_property

import tango_aio.sync

from ._hub import TangoHub, hub_of

#: ``!flash``: 0.00001 ms (10 ns) to 32500 ms (manual L9861-9913).
PULSE_MS = (0.00001, 32500.0)
HIGH, LOW = "Active high", "Active low"


class _OnHub(ShutterDevice):
    """A shutter on the hub's controller."""

    def __init__(self, hub: TangoHub | None = None) -> None:
        super().__init__()
        self._hub = hub

    @property
    def controller(self) -> tango_aio.sync.Controller:
        """The hub's blocking controller."""
        if self._hub is None:
            self._hub = hub_of(self.get_parent_label())
        return self._hub.controller


class TangoShutter(_OnHub):
    """The AUX I/O shutter output (``!shutter 1`` TTL high = open, ``!shutter 0`` low =
    closed; manual L9837-9860) as a Micro-Manager shutter, through ``tango.io``: each
    setting is proven by its read-back.

    Parameters
    ----------
    hub
        The hub of the controller; ``None``: the initialised hub named by the device's
        parent label.
    """

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
        return self.controller.io.shutter()

    def set_open(self, open: bool) -> None:
        """Drive the output high (open) or low (closed).

        Parameters
        ----------
        open
            ``True`` opens.
        """
        self.controller.io.set_shutter(bool(open))


class TangoStrobe(_OnHub):
    """An LED strobe on the AUX I/O TAKT_OUT pin as a Micro-Manager shutter: opening it
    sends one pulse of ``Pulse (ms)`` (``!flash``, manual L9861-9913: 0.00001 to 32500
    ms, "used e.g. for LED strobes"), active high or low as ``Polarity`` says (the sign
    of the length); closing it sends nothing, the pulse ends by itself.

    The controller reads no pulse back (``!flash`` has no response, L9861-9913): the
    line is proven by the controller's error state, and :meth:`get_open` reports what
    was asked last (open: a pulse was sent since the last close), not a reading of the
    LED. TAKT_OUT is also the trigger's secondary output (``trigo`` 2, 3; L9895-9896):
    with a trigger set up to use it, pulses of both share the pin. The older edition has
    no ``!flash``: initialising raises the controller's error there.

    Parameters
    ----------
    hub
        The hub of the controller; ``None``: the initialised hub named by the device's
        parent label.
    pulse_ms
        The length of a pulse, in ms.
    active_high
        The pulse's polarity.

    Raises
    ------
    ValueError
        ``pulse_ms`` out of the manual's range.
    """

    def __init__(self, hub: TangoHub | None = None, *, pulse_ms: float = 10.0,
                 active_high: bool = True) -> None:
        if not PULSE_MS[0] <= float(pulse_ms) <= PULSE_MS[1]:
            raise ValueError(f"pulse_ms must be {PULSE_MS[0]:g}..{PULSE_MS[1]:g} ms "
                             f"(manual L9861-9913), got {pulse_ms!r}")
        super().__init__(hub)
        self._pulse_ms = float(pulse_ms)
        self._active_high = bool(active_high)
        self._open = False
        self._ready = False

    @pymm_property(name="Pulse (ms)", limits=PULSE_MS)
    def pulse_ms(self) -> float:
        """The length of the pulse an opening sends, in ms."""
        return self._pulse_ms

    @pulse_ms.setter  # type: ignore[no-redef]
    def pulse_ms(self, value: float) -> None:
        self._pulse_ms = float(value)

    @pymm_property(name="Polarity", allowed_values=(HIGH, LOW))
    def polarity(self) -> str:
        """Whether a pulse is active high or active low."""
        return HIGH if self._active_high else LOW

    @polarity.setter  # type: ignore[no-redef]
    def polarity(self, value: str) -> None:
        before, self._active_high = self._active_high, value == HIGH
        if self._ready:
            try:
                self._settle()
            except BaseException:
                self._active_high = before
                raise

    def _settle(self) -> None:
        """One shortest pulse of the polarity, as the manual recommends once when
        initialising "in order to have the correct polarity" (L9890-9891)."""
        self.controller.io.flash(PULSE_MS[0] if self._active_high else -PULSE_MS[0])

    def initialize(self) -> None:
        """Connect through the hub and send the polarity's settling pulse (10 ns), once."""
        if not self._ready:
            self._settle()
            self._ready = True

    def get_open(self) -> bool:
        """Whether the last call opened the strobe (a pulse was sent since the last close).

        Returns
        -------
        bool
            ``True`` after an opening, until a closing.
        """
        return self._open

    def set_open(self, open: bool) -> None:
        """Opening sends one pulse (``!flash``); closing sends nothing.

        Parameters
        ----------
        open
            ``True``: pulse the LED.
        """
        if open:
            self.controller.io.flash(self._pulse_ms if self._active_high
                                     else -self._pulse_ms)
        self._open = bool(open)
