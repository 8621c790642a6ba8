"""Per-request driver cost on a canned in-memory transport, against a minimal raw client.

No wire, no emulator in the timed loop: :class:`CannedTransport` answers each line it has
seen before with the reply it recorded then (one ``call_soon`` later, as a socket or pty
read would arrive), so what is measured is the Python work of the client alone. Lines it
has not recorded (the driver's connect-time reads) go to the emulator's interpreter
(:class:`~tango_aio.sim.model.ControllerModel`), so the driver is set up exactly as on a
real link. Side by side, in one run:

* ``?pos``: ``await tango.position()`` against a raw asyncio protocol that writes
  ``?pos\\r`` and resolves a future on the reply line;
* a checked set: ``await tango.set("vel", x=...)`` (the line, its ``?err`` probe and
  the read-back that proves it, see ``tango_aio.sansio._readback``) against the raw client
  writing ``!vel x v\\r?err\\r?vel x\\r`` and waiting for the ``0`` and the value;
* a move: ``await tango.move_to(x=...)``, whose completion report the transport delivers
  2 ms after the move line (and puts the axes at the target, where the driver's
  ``?pos``/``?pos x`` confirming the move finds them), against the raw client writing
  ``!moa x v\\r?err\\r`` and waiting for the ``?err`` reply and the report. Reported are
  CPU per move and the completion latency: from the moment the report is handed to the
  client (``data_received``) until the awaiting coroutine runs again.

CPU is ``time.process_time()`` over the loop divided by the number of calls (best of
``--rounds`` rounds); latency is the median. Usage::

    python benchmarks/canned.py [--calls 2000] [--moves 300] [--rounds 3] [--loop uvloop]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from tango_aio.controller._controller import Controller
from tango_aio.link._protocol import TangoProtocol
from tango_aio.sim.model import ControllerModel, SimConfig

try:  # python -m benchmarks / python benchmarks/canned.py
    from benchmarks.moves import event_loop
except ImportError:  # pragma: no cover
    from moves import event_loop  # type: ignore[no-redef]

#: The completion report of a 3-axis controller in autostatus 1 (all axes reached).
REPORT = b"@@@-.\r"
#: Seconds between a move line and its (canned) completion report.
REPORT_DELAY = 0.002
LoopFactory = Callable[[], asyncio.AbstractEventLoop]


class CannedTransport(asyncio.Transport):
    """An in-memory link: replays recorded replies, asks the emulator for the rest.

    While ``recording`` every line goes to the emulator's interpreter and its reply is
    remembered; afterwards a remembered line is answered from memory without the emulator
    (so the emulator's CPU is not the client's). Lines starting with a prefix of
    ``reports`` get no immediate reply and that completion report ``REPORT_DELAY`` later;
    ``delivered_at`` is the ``perf_counter()`` just before it is handed to the client.
    """

    def __init__(self, protocol: asyncio.Protocol) -> None:
        super().__init__()
        self.protocol = protocol
        self.model = ControllerModel(self._emit, SimConfig())
        self.recording = True
        self.memory: dict[bytes, bytes] = {}
        #: The last set line of each instruction: a read is remembered with it, so that
        #: the read-back behind a set (tango_aio.sansio._readback) replays what that set wrote.
        self.held: dict[bytes, bytes] = {}
        self.reports: tuple[bytes, ...] = ()
        self.delivered_at = 0.0
        self._partial = b""
        self._emitted: list[bytes] = []
        self._closed = False
        self._loop = asyncio.get_running_loop()

    def _emit(self, data: bytes) -> None:
        self._emitted.append(data)

    def write(self, data: bytes | bytearray | memoryview) -> None:
        *lines, self._partial = (self._partial + bytes(data)).split(b"\r")
        replies = []
        reports = 0
        for line in lines:
            if self.reports and line.startswith(self.reports):
                reports += 1
                self._arrive(line)
                continue
            key = self._key(line)
            reply = None if self.recording else self.memory.get(key)
            if reply is None:
                self.model.handle_line(line, time.monotonic())
                reply = b"".join(self._emitted)
                self._emitted.clear()
                if self.recording:
                    self.memory[key] = reply
            replies.append(reply)
        if any(replies) or reports:
            self._loop.call_soon(self._deliver, b"".join(replies), reports)

    def _key(self, line: bytes) -> bytes:
        """``line``, and for a read the last set line of its instruction."""
        name = line[1:].split(b" ", 1)[0]
        if line.startswith(b"!"):
            self.held[name] = line
        elif line.startswith(b"?") and name in self.held:
            return line + b"\r" + self.held[name]
        return line

    def _deliver(self, replies: bytes, reports: int) -> None:
        """Hand over the immediate replies, then start the reports' delay: a report can
        never overtake the ``?err`` reply written before it (uvloop runs due timers
        before the callbacks of the same turn)."""
        if replies:
            self.protocol.data_received(replies)
        for _ in range(reports):
            self._loop.call_later(REPORT_DELAY, self._report)

    def _arrive(self, line: bytes) -> None:
        """Put the emulator's axes at the move's target at once (``!moa`` becomes ``!pos``),
        so that the driver's confirmation of the move (``?pos``, see ``controller/_motion.py``)
        finds them there (outside the timed part of a replayed move: the reply is read
        here, before the report is due)."""
        self.model.handle_line(line.replace(b"moa", b"pos", 1), time.monotonic())
        self._emitted.clear()
        # Replayed from now on: remember the new position (``?pos``, and ``?pos x`` of a
        # confirmation that reads the moved axis alone, #28).
        for read in [line for line in self.memory if line.startswith(b"?pos")]:
            self.model.handle_line(read, time.monotonic())
            self.memory[read] = b"".join(self._emitted)
            self._emitted.clear()

    def _report(self) -> None:
        if not self._closed:
            self.delivered_at = time.perf_counter()
            self.protocol.data_received(REPORT)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._loop.call_soon(self.protocol.connection_lost, None)

    def is_closing(self) -> bool:
        return self._closed


async def canned_driver(separators: bool = True) -> tuple[Controller, CannedTransport]:
    """A :class:`Controller` set up (autostatus 1) over a fresh :class:`CannedTransport`,
    built the way ``tango_aio.connect`` builds it (``separators``: see
    :mod:`tango_aio.sansio._patterns`)."""
    protocol = TangoProtocol(separators=separators)
    transport = CannedTransport(protocol)
    protocol.connection_made(transport)
    controller = Controller(protocol, url="canned://")
    await controller.setup(autostatus=1)
    return controller, transport


class RawClient(asyncio.Protocol):
    """The smallest correct asyncio client: one future per expected reply line, in order."""

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self.waiting: deque[asyncio.Future[bytes]] = deque()
        self.buffer = b""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        while b"\r" in self.buffer:
            line, _, self.buffer = self.buffer.partition(b"\r")
            if self.waiting:
                self.waiting.popleft().set_result(line)

    def request(self, data: bytes, replies: int = 1) -> list[asyncio.Future[bytes]]:
        """Write ``data``; futures of its next ``replies`` reply lines."""
        loop = asyncio.get_running_loop()
        futures = [loop.create_future() for _ in range(replies)]
        self.waiting.extend(futures)
        assert self.transport is not None
        self.transport.write(data)
        return futures

    async def query(self, data: bytes) -> bytes:
        """Write a read and return its reply line."""
        (future,) = self.request(data)
        return await future

    async def checked(self, data: bytes, read: bytes, value: float) -> None:
        """Write a set line, ``?err`` and the read of the setting; raise unless the error
        code is 0 and the read shows ``value``."""
        error, held = self.request(data + b"?err\r" + read, 2)
        if await error != b"0" or float(await held) != value:
            raise RuntimeError(f"{data!r} failed")


async def canned_raw() -> tuple[RawClient, CannedTransport]:
    """A :class:`RawClient` on a fresh :class:`CannedTransport` (autostatus 1, the
    emulator's power-on mode)."""
    client = RawClient()
    transport = CannedTransport(client)
    client.connection_made(transport)
    return client, transport


@dataclass
class Cost:
    """CPU per call of one way of doing something, and latencies if measured."""

    name: str
    cpu_seconds: list[float] = field(default_factory=list)
    latencies: list[float] = field(default_factory=list)

    @property
    def cpu_per_call(self) -> float:
        """Best round's CPU seconds per call."""
        return min(self.cpu_seconds)

    @property
    def latency(self) -> float:
        """Median latency in seconds."""
        return statistics.median(self.latencies)


async def _rounds(cost: Cost, call: Callable[[int], Awaitable[object]], calls: int,
                  rounds: int) -> None:
    for _ in range(rounds):
        cpu = time.process_time()
        for index in range(calls):
            await call(index)
        cost.cpu_seconds.append((time.process_time() - cpu) / calls)


async def _recorded(call: Callable[[int], Awaitable[object]],
                    transport: CannedTransport) -> None:
    """Run ``call`` enough times that every line it writes (credit markers included) is
    recorded, then replay."""
    for index in range(64):
        await call(index)
    transport.recording = False


def _velocity(index: int) -> float:
    return 10.0 + index % 2


async def requests(calls: int, rounds: int) -> list[tuple[Cost, Cost]]:
    """(driver, raw) CPU per ``?pos`` and per checked set; then the same with the
    driver's separators off (``TangoProtocol(separators=False)``: by default every request
    whose reply looks like the previous one's gets a separator line first, a second line
    on the wire and a second reply to route, which the raw client never writes)."""
    pairs = await _requests(calls, rounds, separators=True)
    plain = await _requests(calls, rounds, separators=False)
    for driver, _ in plain:
        driver.name += ", no separators"
    return pairs + plain


async def _requests(calls: int, rounds: int, separators: bool) -> list[tuple[Cost, Cost]]:
    tango, driver_link = await canned_driver(separators)
    raw, raw_link = await canned_raw()
    pairs = []
    try:
        async def position(_: int) -> object:
            return await tango.position()

        async def raw_position(_: int) -> object:
            return await raw.query(b"?pos\r")

        async def set_vel(index: int) -> None:
            await tango.set("vel", x=_velocity(index))

        async def raw_set_vel(index: int) -> None:
            await raw.checked(f"!vel x {_velocity(index)}\r".encode(), b"?vel x\r",
                              _velocity(index))

        for name, driver_call, raw_call in (("?pos", position, raw_position),
                                            ("checked set", set_vel, raw_set_vel)):
            driver_link.recording = raw_link.recording = True
            await _recorded(driver_call, driver_link)
            await _recorded(raw_call, raw_link)
            driver, baseline = Cost(f"driver {name}"), Cost(f"raw {name}")
            for _ in range(rounds):  # alternate, so that noise hits both alike
                await _rounds(driver, driver_call, calls, 1)
                await _rounds(baseline, raw_call, calls, 1)
            pairs.append((driver, baseline))
    finally:
        await tango.aclose()
    return pairs


def _target(index: int) -> float:
    return 0.01 if index % 2 == 0 else 0.0


async def moves(count: int, rounds: int, confirm: bool = False) -> tuple[Cost, Cost]:
    """(driver, raw) CPU per tiny absolute move and completion latency. With
    ``confirm`` the raw client confirms each move as the driver does (#13): after the
    report, ``?statusaxis`` and ``?pos`` in one write, both replies checked."""
    tango, driver_link = await canned_driver()
    raw, raw_link = await canned_raw()
    driver = Cost("driver move_to")
    baseline = Cost("raw !moa + ?err" + (", confirmed" if confirm else ""))
    try:
        async def move(index: int) -> None:
            await tango.move_to(x=_target(index))
            driver.latencies.append(time.perf_counter() - driver_link.delivered_at)

        async def raw_move(index: int) -> None:
            check, report = raw.request(f"!moa x {_target(index)}\r?err\r".encode(), 2)
            if await check != b"0":
                raise RuntimeError("move refused")
            if await report != REPORT[:-1]:
                raise RuntimeError("move failed")
            if confirm:
                letters, where = raw.request(b"?statusaxis\r?pos\r", 2)
                if (await letters)[:1] != b"@" or \
                        float((await where).split()[0]) != _target(index):
                    raise RuntimeError("move not confirmed")
            baseline.latencies.append(time.perf_counter() - raw_link.delivered_at)

        for link in (driver_link, raw_link):
            link.reports = (b"!moa ", b"moa ")
        await _recorded(move, driver_link)
        await _recorded(raw_move, raw_link)
        driver.latencies.clear()
        baseline.latencies.clear()
        for _ in range(rounds):
            await _rounds(driver, move, count, 1)
            await _rounds(baseline, raw_move, count, 1)
    finally:
        await tango.aclose()
    return driver, baseline


def run(calls: int, count: int, rounds: int, loop_factory: LoopFactory | None = None
        ) -> list[tuple[Cost, Cost]]:
    """Every pair, measured in one event loop (``loop_factory``: e.g. uvloop's)."""
    with asyncio.Runner(loop_factory=loop_factory) as runner:
        pairs = runner.run(requests(calls, rounds))
        pairs.append(runner.run(moves(count, rounds)))
    return pairs


def report(pairs: list[tuple[Cost, Cost]]) -> None:
    """Print CPU per call (and latency for moves) with the driver/raw ratios."""
    for driver, raw in pairs:
        print(f"{driver.name:18} {driver.cpu_per_call * 1e6:8.1f} µs CPU | {raw.name:18} "
              f"{raw.cpu_per_call * 1e6:8.1f} µs | ratio "
              f"{driver.cpu_per_call / raw.cpu_per_call:5.2f}")
        if driver.latencies:
            print(f"{'  completion':18} {driver.latency * 1e6:8.1f} µs     | "
                  f"{'':18} {raw.latency * 1e6:8.1f} µs | ratio "
                  f"{driver.latency / raw.latency:5.2f}")


def main() -> None:
    """Parse the options, run, print."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=2000, help="requests per round")
    parser.add_argument("--moves", type=int, default=300, help="moves per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--loop", choices=("asyncio", "uvloop"), default="asyncio")
    args = parser.parse_args()
    factory = event_loop(args.loop)
    report(run(args.calls, args.moves, args.rounds, factory))


if __name__ == "__main__":
    main()
