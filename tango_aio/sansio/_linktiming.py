"""How long a quiet link must stay quiet before the driver takes it as done (sans-IO).

* its speed: the controller answers a line only once the whole line has reached it
  (CR-terminated lines, L28-30), so the gap between two replies can be as long as the next
  command line takes on the wire; at 1200 Bd 8N2 (L8-10: 11 bits per byte) one byte takes
  9.2 ms, a 14-byte line 128 ms. A fixed 0.05 s would end exchanges early below
  9600 Bd and hand later replies to the wrong request;
* its latency and the way it delivers (a USB adapter's latency timer, a terminal server's
  packets): bytes come in bursts, so the gap between bursts can be a round trip long.

The manual says nothing of either (``!baud`` sets 1200 to 115200 Bd on a true RS232 port;
a USB or PCI unit runs at a fixed, much higher rate whatever the port is opened with:
L10, L1624-1669; nothing bounds a reply's delay). So both are taken into account: the byte
time where the driver knows the baud rate (a serial port it opened; on a USB unit the real
bytes are faster, and the interval errs long, which is safe), and the round trip it
measures on the link
(from writing an exchange to the first byte back), which also covers links whose speed it
cannot know (``socket://`` to a serial-to-TCP adapter, the emulator's ``sim://``).
:class:`LinkTiming` keeps the measurements; :func:`quiet_interval` is the rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ARRIVAL_MARGIN", "BITS_PER_BYTE", "MAX_QUIET", "MIN_QUIET", "QUIET_BYTES",
           "QUIET_ROUND_TRIPS", "LinkTiming", "byte_time", "earliest_reply", "quiet_interval"]

#: Bit times per byte on the TANGO's line: 8 data bits, no parity, 2 stop bits, plus the
#: start bit (L8-10).
BITS_PER_BYTE = 11
#: The shortest quiet interval, for fast links whose byte time and round trip are far
#: below it.
MIN_QUIET = 0.05
#: Byte times a quiet interval spans at least: longer than any line the driver writes in
#: an exchange (``!autostatus 4``, ``?help 12345``: at most 14 bytes), with room for the
#: controller's processing and a reply's first bytes.
QUIET_BYTES = 40
#: Measured round trips a quiet interval spans at least: a reply may come a round trip
#: after the previous one when the link delivers in bursts.
QUIET_ROUND_TRIPS = 3.0
#: The longest quiet interval: a round trip measured while the controller was busy (a
#: reset, L1837) must not slow every later resync beyond this.
MAX_QUIET = 2.0
#: Seconds by which the time a line's first byte is stamped with may precede the byte's
#: arrival: the time is read after the bytes (``data_received``), never before, but uvloop's
#: ``loop.time()`` counts whole milliseconds and is read once per loop iteration, before
#: the reads of that iteration. Only the wire-time part of :func:`earliest_reply` needs it.
ARRIVAL_MARGIN = 0.002


def byte_time(baudrate: int) -> float:
    """Seconds one byte takes on the line at ``baudrate`` (11 bits, 8N2: L8-10)."""
    if baudrate <= 0:
        raise ValueError(f"baudrate must be positive, got {baudrate}")
    return BITS_PER_BYTE / baudrate


def quiet_interval(byte_seconds: float, round_trip: float) -> float:
    """Seconds without a byte after which a link is taken as quiet: at least
    :data:`MIN_QUIET`, :data:`QUIET_BYTES` byte times and :data:`QUIET_ROUND_TRIPS`
    measured round trips, at most :data:`MAX_QUIET`."""
    for value in (byte_seconds, round_trip):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"times must be finite and not negative, got {value}")
    wanted = max(MIN_QUIET, QUIET_BYTES * byte_seconds, QUIET_ROUND_TRIPS * round_trip)
    return min(MAX_QUIET, wanted)


def earliest_reply(sent_at: float, wire_free: float, size: int, byte_seconds: float,
                   margin: float = ARRIVAL_MARGIN) -> tuple[float, float]:
    """The time before which a line that starts is not the reply to a line of ``size``
    bytes written at ``sent_at``, and when that line's last byte has passed.

    * ``sent_at`` is read before the bytes are handed to the transport, and a line's
      arrival time after its bytes were read, both from the one event-loop clock, which
      never goes back. A reply starts only once its request has reached the controller
      (it executes a line when its CR arrives: L28-30), so the first byte of a true reply
      is read after the write, and its time is not earlier than ``sent_at``. This part
      holds on every link, whatever its speed (the core tells it without a clock, by the
      order it handled the chunk and the write: two readings of a coarse clock may be
      equal).
    * With ``byte_seconds`` (a wire known to carry every byte at that rate, 11 bits per
      byte: L8-10), the line's bytes pass one byte time apart, behind what was written
      before it (``wire_free``), and the reply's first byte needs one more byte time
      before the host has it. The controller's own turnaround counts as 0: the manual
      gives no least time to answer, and the round trips the driver measures are longest
      ones, no lower bound. A serial port's opened rate is no such wire: USB and PCI units
      run "much higher baudrates" whatever the port is opened with (L10, L1645-1653), so
      the driver passes 0 there; only the emulator's paced ``sim://`` wire is known.
      That part is lowered by ``margin`` (:data:`ARRIVAL_MARGIN`), and never below
      ``sent_at``."""
    start = max(sent_at, wire_free)
    passed = start + size * byte_seconds
    if byte_seconds <= 0.0:
        return sent_at, passed
    return max(sent_at, passed + byte_seconds - margin), passed


@dataclass(slots=True)
class LinkTiming:
    """What the driver knows of a link's timing: the byte time from a known baud rate (0:
    unknown) and the longest round trip measured (write to first byte back)."""

    byte_seconds: float = 0.0
    round_trip: float = 0.0

    def observe(self, round_trip: float) -> bool:
        """Record a measured round trip."""
        if not (math.isfinite(round_trip) and round_trip > self.round_trip):
            return False
        before = self.quiet_interval
        self.round_trip = round_trip
        return self.quiet_interval > before

    @property
    def quiet_interval(self) -> float:
        """:func:`quiet_interval` of what is known."""
        return quiet_interval(self.byte_seconds, self.round_trip)
