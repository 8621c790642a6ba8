"""Sans-IO model of the serial link of a TANGO controller.

:class:`Wire` sits between a host and the controller logic (a :class:`LineHandler`). It
models what the manual says, or implies, about the byte level of the link:

* Both directions are paced by the baud rate. The default is 57600 Bd, 8N2, so one byte
  is 11 bit times (manual L8-10). Bytes the host writes go into an unbounded queue (the
  OS/USB buffers and the UART) and reach the controller one byte time apart. Reply bytes
  leave one byte time apart as well. ``baud=None`` (or 0) switches pacing off.
* The controller has a 256-byte input buffer (manual L129-131, L14093). A byte that
  arrives while 256 bytes are held is lost without a trace; :attr:`Wire.lost_bytes`
  counts such bytes.
* The interpreter takes one CR-terminated line at a time, stays busy for the processing
  time of that line, and only then takes the next one.
* Ctrl+C (0x03) bypasses the parser (manual L6808-6814): it clears the input buffer and
  stops all axes. "Most TANGO controllers" do (L6808): a handler whose
  ``ctrl_c_stops`` attribute is False gets 0x03 as an ordinary byte of the line.
* A line that restarts the controller (the handler's optional ``reboots(line)``, e.g.
  ``reset``) makes it deaf while it processes: the rest of the input buffer and every
  byte that arrives meanwhile are lost (L1837-1857), counted in :attr:`Wire.lost_bytes`.

Nothing here does I/O or reads a clock. Every entry point takes ``now`` (seconds, any
monotonic time base), and :meth:`Wire.next_deadline` says when the wire next wants
attention. :mod:`tango_aio.sim.serve` drives a wire in real time.

Choices where the manual is silent are documented where they are implemented:

* ``_try_start``: when bytes are freed, LF, empty lines, over-long lines.
* ``_begin_line``: when the handler runs and when its replies leave.
* ``_ctrl_c``: what Ctrl+C clears.
* ``_schedule_reply``: latency, fragmentation and reply faults.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

__all__ = [
    "BITS_PER_BYTE",
    "CR",
    "CTRL_C",
    "DEFAULT_BAUD",
    "INPUT_BUFFER_SIZE",
    "LF",
    "Emit",
    "Faults",
    "Garbler",
    "HandlerFactory",
    "LineHandler",
    "Wire",
    "WireConfig",
    "flip_one_bit",
]

CR = 0x0D
"""Carriage return: ends a command line and a reply line (manual L28-30, L82)."""
LF = 0x0A
"""Line feed: never mentioned by the manual; the emulated parser skips it."""
CTRL_C = 0x03
"""Ctrl+C: the stop character that bypasses the parser (manual L6808-6814)."""
DEFAULT_BAUD = 57600
"""Default baud rate of every TANGO COM port (manual L8-10)."""
BITS_PER_BYTE = 11
"""Bit times per byte at 8N2: 1 start bit, 8 data bits, 2 stop bits."""
INPUT_BUFFER_SIZE = 256
"""Size of the controller's input buffer in bytes (manual L14093)."""

# Tolerance for comparing event times computed as ``start + k * byte_time``.
_EPS = 1e-9
_CR_BYTE = bytes([CR])
_CTRL_C_BYTE = bytes([CTRL_C])

Emit = Callable[[bytes], None]
"""Callback the controller logic calls with one complete reply, CR included."""


class LineHandler(Protocol):
    """The controller logic that a :class:`Wire` drives.

    The wire calls these methods; the logic answers through the :data:`Emit` callback it
    received from its :data:`HandlerFactory`. All times are the wire's ``now``.
    """

    def handle_line(self, line: bytes, now: float) -> None:
        """Execute one complete command line: no CR, LFs removed, case as received.

        Parameters
        ----------
        line
            The line.
        now
            The time.
        """

    def line_too_long(self, head: bytes, now: float) -> None:
        """A line had more characters than fit in the input buffer; ``head`` is its start.

        Called in place of :meth:`handle_line` when the line's CR arrives; the logic should
        not execute it and should set error 3 ("too many characters in command line").

        Parameters
        ----------
        head
            The line's start.
        now
            The time.
        """

    def ctrl_c(self, now: float) -> None:
        """0x03 arrived: stop all axes. The wire has already cleared the input buffer.

        Parameters
        ----------
        now
            The time.
        """

    def processing_time(self, line: bytes) -> float:
        """Extra seconds the interpreter is busy with ``line``.

        The wire adds this to :attr:`WireConfig.processing_time_per_line`. Return 0.0 for
        ordinary instructions and more for blocking ones (``brakepos``, ``reset``...).

        Parameters
        ----------
        line
            The line.

        Returns
        -------
        float
            The seconds.
        """

    def poll(self, now: float) -> None:
        """Let time-driven logic (moves finishing, autostatus) run up to ``now``.

        Parameters
        ----------
        now
            The time.
        """

    def next_deadline(self) -> float | None:
        """When :meth:`poll` must next be called, or None if nothing is pending.

        Returns
        -------
        float or None
            The time, or ``None``.
        """


HandlerFactory = Callable[[Emit], LineHandler]
"""Builds the controller logic for one wire, given the wire's :meth:`Wire.emit`."""

Garbler = Callable[[bytes, random.Random], bytes]
"""Turns a reply into a garbled copy, using the wire's seeded random generator."""


def flip_one_bit(data: bytes, rng: random.Random) -> bytes:
    """Flip one of the low 7 bits of one byte of ``data``, never touching or creating a CR.

    Keeping CRs intact leaves the line structure alone, so the host sees a corrupted line
    rather than two lines; the default garbler models noise that corrupts content only.

    Parameters
    ----------
    data
        The bytes.
    rng
        The random source.

    Returns
    -------
    bytes
        The changed bytes.
    """
    candidates = [i for i, byte in enumerate(data) if byte != CR]
    if not candidates:
        return data
    index = rng.choice(candidates)
    out = bytearray(data)
    for bit in rng.sample(range(7), 7):
        if out[index] ^ (1 << bit) != CR:
            out[index] ^= 1 << bit
            break
    return bytes(out)


@dataclass
class WireConfig:
    """Timing and size parameters of an emulated link.

    A benchmark setting: ``WireConfig(processing_time_per_line=0.0005, stall_every_lines=1000,
    stall_duration=0.05, reply_latency=0.002)``.
    """

    baud: int | None = DEFAULT_BAUD
    """Baud rate; None or 0 means instant mode (no pacing at all)."""
    bits_per_byte: int = BITS_PER_BYTE
    """Bit times per byte on the line."""
    input_buffer_size: int = INPUT_BUFFER_SIZE
    """Capacity of the controller's input buffer in bytes."""
    processing_time_per_line: float = 0.0
    """Seconds the interpreter is busy with every line (the handler may add to it)."""
    stall_every_lines: int = 0
    """Every N-th line also stalls the interpreter for :attr:`stall_duration`; 0 = never."""
    stall_duration: float = 0.0
    """Length of the periodic stall in seconds."""
    reply_latency: float = 0.0
    """Constant delay added to every reply byte (e.g. 0.002 for a USB adapter)."""
    fragment_probability: float = 0.0
    """Probability that a reply is split into 2-4 separately delivered pieces."""
    fragment_gap: float = 0.0
    """Upper bound of the random extra delay before each piece after the first."""
    seed: int | None = None
    """Seed of the wire's :class:`random.Random` (fragmentation, garbling)."""

    def __post_init__(self) -> None:
        if self.baud is not None and self.baud < 0:
            raise ValueError("baud must be positive, 0 or None")
        if self.bits_per_byte <= 0:
            raise ValueError("bits_per_byte must be positive")
        if self.input_buffer_size < 2:
            raise ValueError("input_buffer_size must hold at least one character and a CR")
        if not 0.0 <= self.fragment_probability <= 1.0:
            raise ValueError("fragment_probability must be within [0, 1]")
        times = (self.processing_time_per_line, self.stall_duration, self.reply_latency,
                 self.fragment_gap)
        if not all(math.isfinite(t) for t in times):
            raise ValueError("times must be finite numbers of seconds")
        if min(times) < 0.0 or self.stall_every_lines < 0:
            raise ValueError("times and counts must not be negative")

    @property
    def byte_time(self) -> float:
        """Seconds one byte occupies the line; 0.0 in instant mode."""
        if not self.baud:
            return 0.0
        return self.bits_per_byte / self.baud

    @property
    def max_line_length(self) -> int:
        """Longest command line (without CR) that fits in the input buffer: 255."""
        return self.input_buffer_size - 1


@dataclass
class Faults:
    """Faults the wire injects into its output; the counters count down as they are used.

    A "reply" is one call of :meth:`Wire.emit`.
    """

    drop_replies: int = 0
    """Silently drop this many of the next replies."""
    garble_replies: int = 0
    """Pass this many of the next replies through :attr:`garbler`."""
    garbler: Garbler = flip_one_bit
    """How a reply is garbled."""
    delay_replies: int = 0
    """Delay this many of the next replies by :attr:`reply_delay` (later output waits too)."""
    reply_delay: float = 0.0
    """Seconds a delayed reply waits before its first byte is sent."""
    disconnect_mid_reply: bool = False
    """Send only the first half of the next reply, then close the connection."""
    lose_line: bytes | None = None
    """Lose the next line received that starts with these bytes, as if it never arrived
    (a line garbled or cut on the way in); once. ``None``: lose none."""
    garble_reply_to: tuple[bytes, Garbler] | None = None
    """Pass the first reply to the next line received that starts with these bytes
    through this garbler (e.g. only the ``?err`` reply behind a move line); once.
    ``None``: none."""


@dataclass
class _Segment:
    """A run of bytes on the line: byte ``i`` of ``data`` passes at ``start + (i+1)*bt``."""

    start: float
    data: bytes
    pos: int = 0
    close: bool = False

    def due_at(self, byte_time: float) -> float:
        """Time the next unconsumed byte (or the marker) passes."""
        if self.close:
            return self.start
        return self.start + (self.pos + 1) * byte_time

    def due_count(self, now: float, byte_time: float) -> int:
        """Number of unconsumed bytes that have passed by ``now``."""
        if byte_time == 0.0:
            passed = len(self.data) if self.start <= now + _EPS else 0
        else:
            passed = int((now + _EPS - self.start) / byte_time)
        return max(0, min(len(self.data), passed) - self.pos)


class Wire:
    """The sans-IO link and input buffer of one emulated controller.

    Use :meth:`feed` for bytes from the host, :meth:`poll` (or :meth:`poll_chunks`) for
    bytes to the host, and :meth:`next_deadline` to know when to call :meth:`poll` next.
    ``now`` must not decrease between calls (a smaller value is treated as the last one).

    Parameters
    ----------
    make_handler
        Makes the controller logic, given the wire's ``emit``.
    config
        The timing configuration; ``None`` for the default.
    """

    def __init__(self, make_handler: HandlerFactory, config: WireConfig | None = None) -> None:
        self.config: WireConfig = config if config is not None else WireConfig()
        """The timing configuration (read once: change it before the first call)."""
        self.faults: Faults = Faults()
        """Fault injection settings, consulted for every reply."""
        self.rng: random.Random = random.Random(self.config.seed)
        """Random generator for fragmentation and garbling."""
        self.lost_bytes = 0
        """Bytes lost because they arrived while the input buffer was full."""
        self.lines_processed = 0
        """Lines taken by the interpreter, over-long lines included."""
        self.ctrl_c_count = 0
        """Ctrl+C characters received."""
        self.dropped_replies = 0
        """Replies swallowed by :attr:`Faults.drop_replies`."""
        self.lost_lines = 0
        """Lines received and lost by :attr:`Faults.lose_line`."""
        self.closed = False
        """True once the connection was cut (:meth:`disconnect` or a mid-reply fault)."""
        self.notify: Callable[[], None] | None = None
        """Called when something changes outside :meth:`feed`/:meth:`poll` (serving hook)."""
        self.clock: Callable[[], float] | None = None
        """Time source for fault calls made without ``now`` (set by the serving layer)."""
        self._bt = self.config.byte_time
        self._now = float("-inf")
        self._rx: deque[_Segment] = deque()
        self._rx_free_at = float("-inf")
        self._tx: deque[_Segment] = deque()
        self._tx_free_at = float("-inf")
        self._buffer = bytearray()
        self._busy_until: float | None = None
        self._busy_len = 0
        self._held: list[bytes] = []
        self._discard_head: bytes | None = None
        self._handler_polled_at = float("-inf")
        self._deaf = False  # rebooting: input is lost
        self._garble_first: Garbler | None = None  # for the line being handled
        self.handler: LineHandler = make_handler(self.emit)
        """The controller logic built by the factory."""
        self._ctrl_c_stops: bool = getattr(self.handler, "ctrl_c_stops", True)
        self._local_echo: bool = getattr(self.handler, "local_echo", False)
        self._reboots: Callable[[bytes], bool] | None = getattr(self.handler, "reboots", None)
        self._handler_deadline = self.handler.next_deadline()

    # ------------------------------------------------------------------ public API

    @property
    def now(self) -> float:
        """The latest time the wire has been advanced to."""
        return self._now

    @property
    def buffered(self) -> int:
        """Bytes in the input buffer, the line being processed included."""
        return len(self._buffer) + self._busy_len

    @property
    def busy(self) -> bool:
        """True while the interpreter processes a line (or stalls)."""
        return self._busy_until is not None

    @property
    def rx_pending(self) -> int:
        """Bytes written by the host that have not reached the controller yet."""
        return sum(len(seg.data) - seg.pos for seg in self._rx)

    @property
    def tx_pending(self) -> int:
        """Reply bytes that have not reached the host yet."""
        return sum(len(seg.data) - seg.pos for seg in self._tx)

    def feed(self, data: bytes, now: float) -> None:
        """The host wrote ``data`` at ``now``; it reaches the controller at the baud rate.

        Parameters
        ----------
        data
            The bytes.
        now
            The time.
        """
        self._advance(now)
        if self.closed or not data:
            return
        start = max(self._now, self._rx_free_at)
        self._rx.append(_Segment(start, bytes(data)))
        self._rx_free_at = start + len(data) * self._bt
        if self._local_echo:
            # An adapter with local echo (switch local_echo): every byte comes back as
            # it goes out, interleaved with the replies at the byte level.
            echo_at = max(start, self._tx_free_at)
            self._tx.append(_Segment(echo_at, bytes(data)))
            self._tx_free_at = echo_at + len(data) * self._bt
        self._advance(self._now)

    def poll_chunks(self, now: float) -> list[bytes]:
        """Advance to ``now`` and return the reply bytes that reached the host by then.

        Each chunk comes from one piece of one reply, so fragmentation is visible to a
        serving layer that writes chunks separately.

        Parameters
        ----------
        now
            The time.

        Returns
        -------
        list[bytes]
            The chunks, in order.
        """
        self._advance(now)
        out: list[bytes] = []
        while self._tx and not self.closed:
            seg = self._tx[0]
            if seg.close:
                if seg.start <= self._now + _EPS:
                    self._cut()
                break
            count = seg.due_count(self._now, self._bt)
            if count:
                out.append(seg.data[seg.pos : seg.pos + count])
                seg.pos += count
            if seg.pos < len(seg.data):
                break
            self._tx.popleft()
        return out

    def poll(self, now: float) -> bytes:
        """Advance to ``now`` and return the reply bytes that reached the host by then.

        Parameters
        ----------
        now
            The time.

        Returns
        -------
        bytes
            The bytes.
        """
        return b"".join(self.poll_chunks(now))

    def handler_changed(self) -> None:
        """The handler's state changed outside a line (a test drove an input): read its
        next deadline again and wake whoever serves the wire."""
        self._handler_deadline = self.handler.next_deadline()
        self._notify()

    def next_deadline(self) -> float | None:
        """When :meth:`poll` should next be called, or None if only new input can matter.

        Returns
        -------
        float or None
            The time, or ``None``.
        """
        if self.closed:
            return None
        tx_next = self._tx[0].due_at(self._bt) if self._tx else None
        candidates = (self._rx_next(), self._busy_until, self._handler_due(), tx_next)
        times = [t for t in candidates if t is not None]
        return min(times) if times else None

    def next_wakeup(self) -> float | None:
        """When a real-time driver must next call :meth:`poll`: :meth:`next_deadline`
        without the input bytes that only go into the buffer.

        Input is still taken byte by byte at its exact times, whenever the wire is next
        advanced; calling :meth:`poll` at these times instead of every deadline gives the
        same output at the same times, the same handler calls and the same counters once
        the input has arrived. It wakes for: output due, the interpreter finishing, the
        handler's deadline, the next input byte that can run the handler (Ctrl+C; while
        the interpreter is idle also CR, and the byte that fills the buffer), and the last
        input byte in flight (so the counters are up to date when input has arrived).

        Returns
        -------
        float or None
            The time, or ``None`` if only new input can matter.
        """
        if self.closed:
            return None
        tx_next = self._tx[0].due_at(self._bt) if self._tx else None
        candidates = (self._rx_wakeup(), self._busy_until, self._handler_due(), tx_next)
        times = [t for t in candidates if t is not None]
        return min(times) if times else None

    def _rx_wakeup(self) -> float | None:
        """Due time of the first pending input byte that can run the handler, or of the
        last pending one."""
        if not self._rx:
            return None
        bt = self._bt
        idle = self._busy_until is None
        # Bytes to go (1-based) until the one that fills the buffer of an idle interpreter;
        # a skipped over-long line keeps the buffer empty.
        to_fill = self.config.input_buffer_size - self.buffered \
            if idle and self._discard_head is None else None
        for seg in self._rx:
            data, pos = seg.data, seg.pos
            first = data.find(_CTRL_C_BYTE, pos) if self._ctrl_c_stops else -1
            if idle:
                cr = data.find(_CR_BYTE, pos)
                if cr >= 0 and (first < 0 or cr < first):
                    first = cr
            if to_fill is not None:
                if to_fill <= 0:
                    first = pos
                elif pos + to_fill - 1 < len(data):
                    fill = pos + to_fill - 1
                    first = fill if first < 0 else min(first, fill)
                else:
                    to_fill -= len(data) - pos
            if first >= 0:
                return seg.start + (first + 1) * bt
        last = self._rx[-1]
        return last.start + len(last.data) * bt

    def emit(self, data: bytes) -> None:
        """Queue one reply from the controller logic (CR included).

        While the interpreter is busy the reply is held until processing ends, so replies
        leave in order and only after the processing time.

        Parameters
        ----------
        data
            The reply.
        """
        if self.closed or not data:
            return
        garbler, self._garble_first = self._garble_first, None
        if garbler is not None:
            data = garbler(bytes(data), self.rng)
            if not data:
                return
        if self._busy_until is not None:
            self._held.append(bytes(data))
        else:
            self._schedule_reply(bytes(data), self._now)
        self._notify()

    def stall(self, seconds: float, now: float | None = None) -> None:
        """Freeze the interpreter for ``seconds`` more (from now if it is idle).

        Input still fills the buffer and overflows; output the logic emits meanwhile is
        held. Time-driven logic (moves) keeps running, as motion is done by hardware.
        Without ``now`` the time is taken from :attr:`clock`, else the last time seen.

        Parameters
        ----------
        seconds
            How long.
        now
            The time; ``None`` as described.
        """
        if now is None and self.clock is not None:
            now = self.clock()
        if now is not None:
            self._advance(now)
        if self._busy_until is not None:
            self._busy_until += seconds
        else:
            self._busy_until = self._now + seconds
        self._notify()

    def power_cycle(self, off: float, now: float | None = None) -> None:
        """The controller loses its power now and answers again ``off`` seconds later,
        behind a link that stays up (a USB adapter powered by the host, a serial-to-TCP
        adapter): the connection is not cut.

        What the controller held is lost: the line it was processing, its input buffer,
        the output it had not sent yet (reply bytes that had not reached the host by now;
        their latency is the link's, but cutting at arrival keeps this simple), and every
        byte that arrives while it is off (counted in :attr:`lost_bytes`). The logic
        restarts as at power-on through its optional ``reboot(now)`` (the emulator's:
        settings from the state file, autostatus 1 (L2069), counters 0; the manual says
        nothing of a power cycle behind a live link: it is what a restart does, L1837-1857).
        Without ``now`` the time is taken from :attr:`clock`, else the last time seen.

        Parameters
        ----------
        off
            Seconds the controller stays off.
        now
            When the power goes off.

        Raises
        ------
        ValueError
            ``off`` is negative or not finite.
        """
        if not (math.isfinite(off) and off >= 0.0):
            raise ValueError(f"off must be a finite number of seconds >= 0, got {off!r}")
        if now is None and self.clock is not None:
            now = self.clock()
        if now is not None:
            self._advance(now)
        if self.closed:
            return
        kept: deque[_Segment] = deque()
        for seg in self._tx:  # what reached the host by now stays; the rest is lost
            sent = seg.pos + seg.due_count(self._now, self._bt)
            if seg.close or sent > seg.pos:
                kept.append(seg if seg.close else _Segment(seg.start, seg.data[:sent], seg.pos))
        self._tx = kept
        self._tx_free_at = self._now
        self.lost_bytes += len(self._buffer)
        self._buffer.clear()
        self._discard_head = None
        self._held.clear()
        self._busy_len = 0
        self._busy_until = self._now + off
        self._deaf = True  # until _finish_line: the interpreter is back
        reboot: Callable[[float], None] | None = getattr(self.handler, "reboot", None)
        if reboot is not None:
            reboot(self._now)
        self._handler_deadline = self.handler.next_deadline()
        self._notify()

    def disconnect(self, mid_reply: bool = False) -> None:
        """Cut the connection now, or (``mid_reply``) halfway through the next reply.

        Parameters
        ----------
        mid_reply
            Cut halfway through the next reply instead of now.
        """
        if mid_reply:
            self.faults.disconnect_mid_reply = True
        else:
            self._cut()
        self._notify()

    # ------------------------------------------------------------------ event loop

    def _advance(self, until: float) -> None:
        """Run every event up to ``until`` in time order, then poll the handler at it."""
        until = max(until, self._now)
        if self.closed:
            self._now = until
            return
        self._handler_deadline = self.handler.next_deadline()
        while not self.closed and self._step(until):
            pass
        self._now = max(self._now, until)
        if not self.closed:
            self._poll_handler(self._now)

    def _step(self, until: float) -> bool:
        """Run the earliest event due by ``until``; False if there is none."""
        busy, handler, rx = self._busy_until, self._handler_due(), self._rx_next()
        candidates = [(t, rank) for rank, t in enumerate((busy, handler, rx)) if t is not None]
        if not candidates:
            return False
        when, rank = min(candidates)
        if when > until + _EPS:
            return False
        self._now = max(self._now, when)
        if rank == 0:
            self._finish_line()
            self._try_start()
        elif rank == 1:
            self._poll_handler(self._now)
        else:
            others = [t for t in (busy, handler) if t is not None]
            self._rx_run(until, min(others, default=float("inf")))
        return True

    def _poll_handler(self, now: float) -> None:
        self._handler_polled_at = now
        self.handler.poll(now)
        self._handler_deadline = self.handler.next_deadline()

    def _handler_due(self) -> float | None:
        """The handler's deadline, ignoring one it already had its poll for."""
        deadline = self._handler_deadline
        if deadline is None or deadline <= self._handler_polled_at:
            return None
        return deadline

    def _notify(self) -> None:
        if self.notify is not None:
            self.notify()

    # ------------------------------------------------------------------ input side

    def _rx_next(self) -> float | None:
        return self._rx[0].due_at(self._bt) if self._rx else None

    def _rx_run(self, until: float, before: float) -> None:
        """Deliver input bytes due by ``until`` and before ``before`` (the next other event)."""
        while self._rx:
            seg = self._rx[0]
            when = seg.due_at(self._bt)
            if when > until + _EPS or when >= before:
                return
            plain = self._plain_run(seg, until, before)
            if plain:
                self._take_plain(seg, plain)
                continue
            self._now = max(self._now, when)
            byte = seg.data[seg.pos]
            seg.pos += 1
            if seg.pos == len(seg.data):
                self._rx.popleft()
            if self._receive(byte):
                return

    def _due_end(self, seg: _Segment, until: float, before: float) -> int:
        """End (exclusive index into ``seg.data``) of the bytes that :meth:`_rx_run` would
        take one by one now: due by ``until`` and before ``before``. The next byte is due."""
        bt, start, size, pos = self._bt, seg.start, len(seg.data), seg.pos

        def due(index: int) -> bool:  # the very test _rx_run applies to each byte
            when = start + (index + 1) * bt
            return when <= until + _EPS and when < before

        if bt == 0.0:
            return size  # every byte passes at ``start``, and the first one is due
        span = (min(until + _EPS, before) - start) / bt
        end = size if span >= size else max(pos + 1, int(span))
        while end > pos + 1 and not due(end - 1):
            end -= 1
        while end < size and due(end):
            end += 1
        return end

    def _plain_run(self, seg: _Segment, until: float, before: float) -> int:
        """How many of the next due bytes of ``seg`` :meth:`_receive` would only buffer
        (or count as lost) without running anything: no Ctrl+C, and while the interpreter
        is idle no CR, no byte that fills the buffer and no over-long line being skipped.
        They are taken in one go (:meth:`_take_plain`), which is what makes a busy link
        cheap to emulate; the result is the same as byte by byte."""
        data, pos = seg.data, seg.pos
        end = self._due_end(seg, until, before)
        stop = data.find(_CTRL_C_BYTE, pos, end) if self._ctrl_c_stops else -1
        end = end if stop < 0 else stop
        if self._busy_until is not None:
            return end - pos
        if self._discard_head is not None:
            return 0
        stop = data.find(_CR_BYTE, pos, end)
        end = end if stop < 0 else stop
        room = self.config.input_buffer_size - self.buffered - 1
        return max(0, min(end - pos, room))

    def _take_plain(self, seg: _Segment, count: int) -> None:
        """Take ``count`` bytes found by :meth:`_plain_run` (as ``count`` calls of
        :meth:`_receive` would)."""
        pos = seg.pos
        new = pos + count
        if self._busy_until is not None:
            kept = 0 if self._deaf else \
                max(0, min(count, self.config.input_buffer_size - self.buffered))
            self.lost_bytes += count - kept
        else:
            kept = count
        self._buffer += seg.data[pos : pos + kept]
        seg.pos = new
        self._now = max(self._now, seg.start + new * self._bt)  # when the last one passed
        if new == len(seg.data):
            self._rx.popleft()

    def _receive(self, byte: int) -> bool:
        """One byte reaches the controller's UART; True if the handler was called."""
        if self._deaf:
            self.lost_bytes += 1
            return False
        if byte == CTRL_C and self._ctrl_c_stops:
            self._ctrl_c()
            return True
        if self.buffered >= self.config.input_buffer_size:
            self.lost_bytes += 1
            return False
        self._buffer.append(byte)
        if self._busy_until is not None:
            return False
        full = self.buffered >= self.config.input_buffer_size
        if byte == CR or full or self._discard_head is not None:
            return self._try_start()
        return False

    def _ctrl_c(self) -> None:
        """Clear everything not yet taken by the interpreter, then tell the handler."""
        self._buffer.clear()
        self._discard_head = None
        self.ctrl_c_count += 1
        self.handler.ctrl_c(self._now)
        self._handler_deadline = self.handler.next_deadline()

    # ------------------------------------------------------------------ interpreter

    def _try_start(self) -> bool:
        """Let an idle interpreter take lines from the buffer; True if the handler ran."""
        ran = False
        while self._busy_until is None and not self.closed:
            cr = self._buffer.find(CR)
            if self._discard_head is not None:
                if cr < 0:
                    self._buffer.clear()
                    return ran
                del self._buffer[: cr + 1]
                head, self._discard_head = self._discard_head, None
                self._begin_line(head, 0, too_long=True)
            elif cr >= 0:
                line = bytes(self._buffer[:cr]).replace(b"\n", b"")
                del self._buffer[: cr + 1]
                self._begin_line(line, cr + 1, too_long=False)
            elif len(self._buffer) >= self.config.input_buffer_size:
                content = bytes(self._buffer).replace(b"\n", b"")
                self._discard_head = content[: self.config.max_line_length]
                self._buffer.clear()
                continue
            else:
                return ran
            ran = True
        return ran

    def _begin_line(self, line: bytes, size: int, *, too_long: bool) -> None:
        """Start processing one line that occupied ``size`` buffer bytes."""
        lose = self.faults.lose_line
        if lose is not None and not too_long and line.startswith(lose):
            self.faults.lose_line = None
            self.lost_lines += 1
            self.lost_bytes += size
            return
        self.lines_processed += 1
        duration = self._duration(line, too_long)
        self._busy_len = size
        self._busy_until = self._now + duration
        if not too_long and self._reboots is not None and self._reboots(line):
            # Rebooting: what is buffered behind the line is lost, and so is what arrives
            # until the restart ends (L1837-1857).
            self._deaf = True
            self.lost_bytes += len(self._buffer)
            self._buffer.clear()
            self._discard_head = None
        if too_long:
            self.handler.line_too_long(line, self._now)
        else:
            self._garble_first = self._reply_garbler(line)
            try:
                self.handler.handle_line(line, self._now)
            finally:
                self._garble_first = None
        self._handler_deadline = self.handler.next_deadline()
        if duration <= 0.0:
            self._finish_line()

    def _reply_garbler(self, line: bytes) -> Garbler | None:
        """The garbler of the first reply to ``line`` (:attr:`Faults.garble_reply_to`)."""
        target = self.faults.garble_reply_to
        if target is None or not line.startswith(target[0]):
            return None
        self.faults.garble_reply_to = None
        return target[1]

    def _duration(self, line: bytes, too_long: bool) -> float:
        """Processing time of one line: base + handler's extra (not for over-long lines)."""
        config = self.config
        duration = config.processing_time_per_line
        if not too_long:
            duration += max(0.0, self.handler.processing_time(line))
        if config.stall_every_lines and self.lines_processed % config.stall_every_lines == 0:
            duration += config.stall_duration
        return duration

    def _finish_line(self) -> None:
        """Processing ended: free the line's bytes and send what was emitted meanwhile."""
        self._busy_until = None
        self._busy_len = 0
        self._deaf = False
        held, self._held = self._held, []
        for reply in held:
            self._schedule_reply(reply, self._now)

    # ------------------------------------------------------------------ output side

    def _schedule_reply(self, data: bytes, ready: float) -> None:
        """Put one reply on the line, applying faults, latency and fragmentation."""
        faults = self.faults
        if faults.drop_replies > 0:
            faults.drop_replies -= 1
            self.dropped_replies += 1
            return
        if faults.garble_replies > 0:
            faults.garble_replies -= 1
            data = faults.garbler(data, self.rng)
        if faults.delay_replies > 0:
            faults.delay_replies -= 1
            ready += faults.reply_delay
        cut = faults.disconnect_mid_reply
        if cut:
            faults.disconnect_mid_reply = False
            data = data[: max(1, len(data) // 2)]
        start = max(ready, self._tx_free_at)
        for index, piece in enumerate(self._fragments(data)):
            if index and self.config.fragment_gap:
                start += self.rng.uniform(0.0, self.config.fragment_gap)
            self._tx.append(_Segment(start + self.config.reply_latency, piece))
            start += len(piece) * self._bt
        self._tx_free_at = start
        if cut:
            self._tx.append(_Segment(start + self.config.reply_latency, b"", close=True))

    def _fragments(self, data: bytes) -> list[bytes]:
        """Split ``data`` at 1-3 random points with :attr:`WireConfig.fragment_probability`."""
        probability = self.config.fragment_probability
        if len(data) < 2 or not probability or self.rng.random() >= probability:
            return [data]
        count = self.rng.randint(1, min(3, len(data) - 1))
        cuts = sorted(self.rng.sample(range(1, len(data)), count))
        return [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]

    def _cut(self) -> None:
        """The connection is gone: drop everything in flight and stop driving the handler."""
        self.closed = True
        self._rx.clear()
        self._tx.clear()
        self._buffer.clear()
        self._held.clear()
        self._busy_until = None
        self._busy_len = 0
        self._discard_head = None
