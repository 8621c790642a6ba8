"""Scaling benchmark: one driver process keeps N emulated controllers busy at wire speed.

The emulated controllers run in separate *emulator processes* (``--per-process`` of them
in each, default 16), each serving its controllers on ptys at 57600 Bd 8N2 from one event
loop. The benchmark process is the *driver*: it opens every pty with
``tango_aio.connect(path)``, exactly as it would open ``/dev/ttyUSB0``, and then streams a
trigger-list upload of ``--entries`` positions (about 10 s at wire speed) to every
controller at the same time, each through its own write-credit limiter.

Reported per N:

* aggregate throughput: ``!trigp`` payload bytes of all links per second, and its ratio to
  N x the wire bound (57600 / 11 bytes/s per link, host to controller, the saturated
  direction); a ratio of 1.0 means every link ran at wire speed all the time;
* the driver process's CPU seconds per controller-second
  (``time.process_time()`` / (N x elapsed)) and the cores it used; and its CPU seconds per
  second of one link's payload at wire speed (``drv/wire-s``), which does not depend on
  how fast the links actually ran: N x that is what N links at wire speed cost the driver;
* the emulator processes' CPU, summed, and the cores they used, so a limit of the
  emulator is not mistaken for one of the driver;
* how many cores of the whole machine were busy, idle and stolen by the hypervisor
  meanwhile (Linux ``/proc/stat``): busy includes the kernel's pty work and other users;
* bytes the emulators lost to input-buffer overflow (must be 0), and the slowest link's
  own ratio; every link's list is checked with ``?trigc`` afterwards;
* the driver's longest full garbage collection (generation 2, timed with ``gc.callbacks``)
  and longest collection of any generation during the upload: a pause longer than the
  credit slack after a marker (about 17 ms at 57600 Bd) lets a link run dry.

Usage::

    python benchmarks/scaling.py                          # N = 1, 8, 32, 64
    python benchmarks/scaling.py --counts 64 --per-process 8 --entries 3000
    python benchmarks/scaling.py --profile driver.prof --counts 64   # cProfile the driver
    python benchmarks/scaling.py --lean --counts 64 --per-process 64 --gc freeze
    python benchmarks/scaling.py --serve 16               # (internal) an emulator process
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import fcntl
import gc
import json
import math
import os
import pstats
import struct
import subprocess
import sys
import termios
import time
import tty
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass

import tango_aio
from tango_aio.catalog._encode import build
from tango_aio.sansio._flow import DEFAULT_CHUNK

BAUD = 57600
BITS_PER_BYTE = 11
#: Bytes per second one link can carry in one direction at 57600 Bd 8N2.
LINK_BYTES_PER_S = BAUD / BITS_PER_BYTE


# ------------------------------------------------------------------ emulator process


async def serve(count: int) -> None:
    """Serve ``count`` emulated controllers on ptys; talk to the driver over stdio.

    Prints ``{"paths": [...]}`` once serving; then answers each ``stats`` line on stdin
    with ``{"cpu": s, "user": s, "system": s, "lost": n, "lines": n}`` and exits on
    ``quit`` or end of input.
    """
    from tango_aio.sim.model import ControllerModel, SimConfig
    from tango_aio.sim.serve import serve_pty
    from tango_aio.sim.wire import Emit, WireConfig

    def factory(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, SimConfig())

    servers = [await serve_pty(factory, WireConfig(baud=BAUD)) for _ in range(count)]
    print(json.dumps({"paths": [server.path for server in servers]}), flush=True)
    await _answer_stats(lambda: {"lost": sum(s.wire.lost_bytes for s in servers),
                                 "lines": sum(s.wire.lines_processed for s in servers)})
    for server in servers:
        server.close()
    for server in servers:
        await server.wait_closed()


# ------------------------------------------------------------------ lean stand-in

#: Seconds between two turns of the lean stand-in's loop.
LEAN_TICK = 0.004


class LeanLink:
    """A stand-in controller on a pty, for the driver side of the benchmark (``--lean``).

    It takes the host's bytes at wire speed (57600 Bd 8N2) and never faster, as the real
    controller's input buffer fills from the wire, and records how many bytes the host had
    written but the wire had not yet delivered (``peak``): over 256, a real controller
    would have lost bytes (counted in ``lost``). The line an upload repeats,
    ``!trigp -1 pos``, is appended to the trigger list directly; every other line (the
    connect-time reads, the ``err`` markers, ``?trigc``) goes to the full emulator
    (:class:`ControllerModel`), so the driver sees the same replies. Cheap enough that one
    process serves 64 links on a core, which the full emulator cannot.
    """

    def __init__(self) -> None:
        from tango_aio.sim.model import ControllerModel, SimConfig

        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.model = ControllerModel(self._emit, SimConfig())
        self.partial = b""
        self.allowance = 0.0
        self.peak = 0
        self.lost = 0
        self.lines = 0

    def _emit(self, data: bytes) -> None:
        os.write(self.master, data)  # replies are short; the host reads them at once

    def turn(self, elapsed: float, now: float) -> None:
        """Let the wire deliver ``elapsed`` seconds' worth of the host's bytes."""
        waiting = struct.unpack("i", fcntl.ioctl(self.master, termios.FIONREAD, b"\0" * 4))[0]
        self.peak = max(self.peak, waiting)
        self.lost = max(self.lost, waiting - 256)
        if waiting == 0:
            self.allowance = 0.0  # an idle wire carries nothing later
            return
        self.allowance += elapsed * LINK_BYTES_PER_S
        take = min(int(self.allowance), waiting)
        if take == 0:
            return
        # Took all there was: the wire ran idle for the rest of the tick, and what it
        # could have carried then is not carried later (kept, it let the stand-in take a
        # later burst faster than the wire: above 1.0 of the bound under uvloop).
        self.allowance = 0.0 if take == waiting else self.allowance - take
        *lines, self.partial = (self.partial + os.read(self.master, take)).split(b"\r")
        for line in lines:
            self.lines += 1
            if line.startswith(b"!trigp -1 "):
                try:
                    self.model.triggers.write(-1, float(line[10:]))
                    if self.model.autostatus == 2:  # the acknowledgement (L2099-2103)
                        self._emit(b"OK...\r")
                    continue
                except Exception:  # the full emulator then sets the error
                    pass
            self.model.handle_line(line, now)

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)


async def serve_lean(count: int) -> None:
    """Serve ``count`` lean stand-ins from one loop turn every LEAN_TICK (stdio as serve)."""
    links = [LeanLink() for _ in range(count)]
    print(json.dumps({"paths": [link.path for link in links]}), flush=True)

    async def pump() -> None:
        last = time.monotonic()
        while True:
            await asyncio.sleep(LEAN_TICK)
            now = time.monotonic()
            for link in links:
                link.turn(now - last, now)
            last = now

    task = asyncio.create_task(pump())
    await _answer_stats(lambda: {"lost": sum(link.lost for link in links),
                                 "lines": sum(link.lines for link in links)})
    task.cancel()
    for link in links:
        link.close()


async def _answer_stats(counters: Callable[[], dict[str, int]]) -> None:
    """Answer each ``stats`` line on stdin with CPU times and ``counters()``; return on
    ``quit`` or end of input."""
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while (line := (await reader.readline()).decode().strip()) not in ("", "quit"):
        if line == "stats":
            times = os.times()
            print(json.dumps({"cpu": time.process_time(), "user": times.user,
                              "system": times.system, **counters()}), flush=True)


class Emulators:
    """The emulator processes of one run (``per_process`` controllers each)."""

    def __init__(self, count: int, per_process: int, profile_dir: str | None = None,
                 lean: bool = False) -> None:
        extra = ["--emulator-profile", profile_dir] if profile_dir else []
        serve = "--serve-lean" if lean else "--serve"
        sizes = [per_process] * (count // per_process)
        if count % per_process:
            sizes.append(count % per_process)
        self.procs = [subprocess.Popen(
            [sys.executable, __file__, serve, str(size), *extra],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) for size in sizes]
        self.paths: list[str] = []
        for proc in self.procs:
            assert proc.stdout is not None
            self.paths += json.loads(proc.stdout.readline())["paths"]

    def stats(self) -> dict[str, float]:
        """CPU seconds, lost bytes and lines processed, summed over the processes."""
        total = {"cpu": 0.0, "user": 0.0, "system": 0.0, "lost": 0.0, "lines": 0.0}
        for proc in self.procs:
            assert proc.stdin is not None and proc.stdout is not None
            proc.stdin.write("stats\n")
            proc.stdin.flush()
        for proc in self.procs:
            assert proc.stdout is not None
            for key, value in json.loads(proc.stdout.readline()).items():
                total[key] += value
        return total

    def close(self) -> None:
        for proc in self.procs:
            assert proc.stdin is not None
            proc.stdin.write("quit\n")
            proc.stdin.close()
        for proc in self.procs:
            proc.wait(timeout=30)


# ------------------------------------------------------------------ driver


@dataclass
class Result:
    """One run with ``controllers`` links."""

    controllers: int
    emulator_processes: int
    seconds: float
    payload_bytes: int
    lost_bytes: int
    driver_cpu: float
    emulator_cpu: float
    slowest_link_ratio: float
    #: Cores of the whole machine busy, idle and stolen (by the hypervisor) meanwhile.
    machine_busy: float
    machine_idle: float
    machine_steal: float
    #: Longest generation-2 collection and longest collection of any generation (s).
    gc_pause_gen2: float = 0.0
    gc_pause_any: float = 0.0
    gc_gen2_count: int = 0
    #: Event-loop lag, 95th percentile (s).
    loop_lag_p95: float = 0.0
    #: The autostatus mode of the links.
    autostatus: int = 1
    #: With ``trace``: the modelled wires' figures (WireLog.analyse), mean over the links
    #: and the worst link's, keyed ``mean_...`` / ``max_...``.
    wire: dict[str, float] | None = None

    @property
    def throughput(self) -> float:
        """Aggregate payload bytes per second."""
        return self.payload_bytes / self.seconds

    @property
    def bound(self) -> float:
        """N x the wire bound in bytes per second."""
        return self.controllers * LINK_BYTES_PER_S

    @property
    def ratio(self) -> float:
        """Aggregate throughput divided by N x the wire bound."""
        return self.throughput / self.bound

    @property
    def driver_cpu_per_link_second(self) -> float:
        """Driver CPU seconds per controller-second."""
        return self.driver_cpu / (self.controllers * self.seconds)

    @property
    def driver_cpu_per_wire_second(self) -> float:
        """Driver CPU seconds per second of one link's payload at wire speed: what a link
        kept at wire speed would cost, whatever speed the links actually ran at."""
        return self.driver_cpu / (self.payload_bytes / LINK_BYTES_PER_S)

    @property
    def driver_cores(self) -> float:
        return self.driver_cpu / self.seconds

    @property
    def emulator_cores(self) -> float:
        return self.emulator_cpu / self.seconds


def machine_times() -> list[float]:
    """Seconds the machine's CPUs spent busy, idle and stolen (Linux ``/proc/stat``);
    empty where that file does not exist."""
    try:
        with open("/proc/stat") as stat:
            fields = [int(v) for v in stat.readline().split()[1:]]
    except OSError:
        return []
    tick = os.sysconf("SC_CLK_TCK")
    user, nice, system, idle, iowait, irq, softirq, steal = fields[:8]
    return [(user + nice + system + irq + softirq) / tick, (idle + iowait) / tick,
            steal / tick]


class GcPauses:
    """Times every garbage collection while installed (``gc.callbacks``)."""

    def __init__(self) -> None:
        self.started = 0.0
        self.longest = [0.0, 0.0, 0.0]
        self.counts = [0, 0, 0]

    def __enter__(self) -> GcPauses:
        gc.callbacks.append(self._callback)
        return self

    def __exit__(self, *_: object) -> None:
        gc.callbacks.remove(self._callback)

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self.started = time.perf_counter()
            return
        generation = info["generation"]
        self.longest[generation] = max(self.longest[generation],
                                       time.perf_counter() - self.started)
        self.counts[generation] += 1


class WireLog:
    """Every write and read of one link, stamped with ``time.perf_counter()``, to model
    its host -> controller wire afterwards (:meth:`analyse`). Installed on the link's
    protocol object (its ``_write`` and ``data_received``), so nothing else changes."""

    def __init__(self, protocol: object) -> None:
        self.events: list[tuple[float, bool, bytes]] = []
        events = self.events
        write = protocol._write  # type: ignore[attr-defined]
        receive = protocol.data_received  # type: ignore[attr-defined]

        def traced_write(data: bytes) -> None:
            events.append((time.perf_counter(), True, data))
            write(data)

        def traced_receive(data: bytes) -> None:
            events.append((time.perf_counter(), False, data))
            receive(data)

        protocol._write = traced_write  # type: ignore[attr-defined]
        protocol.data_received = traced_receive  # type: ignore[attr-defined]

    def analyse(self, t0: float, autostatus: int) -> dict[str, float]:
        """Model the host -> controller wire as a FIFO at LINK_BYTES_PER_S fed by the
        writes after ``t0`` and split its idle time: ``start`` (from ``t0`` to the first
        ``!trigp -1`` line), ``gaps`` (between the first and the last such line: the link
        ran dry), ``tail`` (after the last one, up to the last reply). Also the bytes by
        kind (payload, markers, other), and per credit marker the delay from its modelled
        arrival at the controller to its reply's arrival at the driver (``answer``), and
        from that reply to the driver's next write (``react``), median and p95 in s."""
        finish = t0
        idle = {"start": 0.0, "gaps": 0.0, "tail": 0.0}
        kinds = {"payload": 0, "marker": 0, "other": 0}
        first = last = None
        owing: list[tuple[bytes, float]] = []  # lines owing a reply, their modelled arrival
        partial = b""
        answers: list[float] = []
        reacts: list[float] = []
        reply_at: float | None = None
        end = t0
        #: Per credit marker: written, modelled arrival, reply, next write (s after t0).
        cycles: dict[float, dict[str, float]] = {}
        self.cycles: list[dict[str, float]] = []
        pending_cycle: dict[str, float] | None = None
        for stamp, written, data in self.events:
            if stamp < t0:
                continue
            if not written:
                *lines, partial = (partial + data).split(b"\r")
                for _line in lines:
                    if owing:
                        line, arrived = owing.pop(0)
                        if line == b"err" or (autostatus == 2 and line.startswith(b"!trigp")):
                            answers.append(stamp - arrived)
                            reply_at = stamp
                            cycle = cycles.get(arrived)
                            if cycle is not None:
                                cycle["reply"] = stamp - t0
                                cycle["busy_until"] = finish - t0
                                pending_cycle = cycle
                end = stamp
                continue
            if reply_at is not None:
                reacts.append(stamp - reply_at)
                reply_at = None
            if pending_cycle is not None:
                pending_cycle["next_write"] = stamp - t0
                pending_cycle["next_bytes"] = len(data)
                pending_cycle = None
            gap = max(0.0, stamp - finish)
            phase = "start" if first is None else "gaps"
            start = max(finish, stamp)
            for line in data.split(b"\r")[:-1]:
                size = len(line) + 1
                start += size / LINK_BYTES_PER_S
                if line.startswith(b"!trigp -1 "):
                    kinds["payload"] += size
                    first = stamp if first is None else first
                    last = stamp
                    if autostatus == 2:
                        owing.append((line, start))
                elif line == b"err":
                    kinds["marker"] += size
                    owing.append((line, start))
                    cycle = {"written": stamp - t0, "write_bytes": len(data),
                             "arrives": start - t0}
                    cycles[start] = cycle
                    self.cycles.append(cycle)
                else:
                    kinds["other"] += size
                    if not line.startswith(b"!") or autostatus == 2:
                        owing.append((line, start))
            idle[phase] += gap
            finish = start
        idle["tail"] = max(0.0, end - finish)
        answers.sort()
        reacts.sort()

        def pick(values: list[float], q: float) -> float:
            return values[min(len(values) - 1, int(len(values) * q))] if values else math.nan

        return {**idle, **{k: float(v) for k, v in kinds.items()},
                "first_payload": (first or t0) - t0, "last_payload": (last or t0) - t0,
                "end": end - t0, "answer_median": pick(answers, 0.5),
                "answer_p95": pick(answers, 0.95), "react_median": pick(reacts, 0.5),
                "react_p95": pick(reacts, 0.95), "markers": float(len(answers))}


def positions(count: int) -> list[float]:
    """A monotonic trigger list with 4-decimal positions (as in benchmarks/upload.py)."""
    return [round(0.0123 + index * 0.0137, 4) for index in range(count)]


async def run(count: int, entries: int, per_process: int,
              profile: cProfile.Profile | None, profile_dir: str | None = None,
              lean: bool = False, marker_chunk: int | None = None,
              collector: str = "on", autostatus: int = 1, trace: bool = False) -> Result:
    """Upload to ``count`` links at once; ``collector`` is what the garbage collector does
    during the upload: ``on`` (as always), ``off`` (``gc.disable()``) or ``freeze``
    (``gc.freeze()`` first: what exists before the upload is never scanned again), so
    that what a change of the driver's allocations would buy can be measured.
    ``autostatus`` is the links' mode (2: every ``!trigp`` acknowledged, no credit
    markers); ``trace`` logs every link's writes and reads (:class:`WireLog`), prints one
    credit cycle of the first link and where each link's wire stood idle."""
    emulators = Emulators(count, per_process, profile_dir, lean)
    chunk = DEFAULT_CHUNK if marker_chunk is None else marker_chunk
    try:
        controllers = await asyncio.gather(*(tango_aio.connect(path, reply_timeout=30.0,
                                                               autostatus=autostatus,
                                                               marker_chunk=chunk)
                                             for path in emulators.paths))
        logs = [WireLog(tango.protocol) for tango in controllers] if trace else []
        try:
            values = positions(entries)
            payload = sum(len(build("trigp", -1, v).to_bytes()) for v in values)
            link_seconds: list[float] = []

            async def upload(tango: tango_aio.Controller) -> None:
                start = time.perf_counter()
                await tango.triggers.upload_positions(values)
                link_seconds.append(time.perf_counter() - start)

            lags: list[float] = []
            probe = asyncio.create_task(_loop_lag(lags))
            before = emulators.stats()
            machine0 = machine_times()
            cpu0, t0 = time.process_time(), time.perf_counter()
            if profile is not None:
                profile.enable()
            if collector == "freeze":
                gc.freeze()
            elif collector == "off":
                gc.disable()
            try:
                with GcPauses() as pauses:
                    await asyncio.gather(*(upload(tango) for tango in controllers))
            finally:
                gc.enable()
                gc.unfreeze()
            if profile is not None:
                profile.disable()
            seconds, cpu = time.perf_counter() - t0, time.process_time() - cpu0
            probe.cancel()
            lags.sort()
            print(f"N={count}: event-loop lag median {lags[len(lags) // 2] * 1e3:.1f} ms, "
                  f"p95 {lags[int(len(lags) * 0.95)] * 1e3:.1f} ms", file=sys.stderr)
            machine = [b - a for a, b in zip(machine0, machine_times(), strict=False)]
            after = emulators.stats()
            counts = await asyncio.gather(*(tango.get("trigc") for tango in controllers))
            assert all(int(c) == entries for c in counts), counts
        finally:
            await asyncio.gather(*(tango.aclose() for tango in controllers))
        wire_seconds = payload / LINK_BYTES_PER_S
        wire = None
        if logs:
            figures = [log.analyse(t0, autostatus) for log in logs]
            wire = {f"{how}_{key}": fold(f[key] for f in figures)
                    for key in figures[0] for how, fold in (("mean", _mean), ("max", max))}
            print_cycle(logs[0].cycles)
        busy, idle, steal = (value / seconds for value in machine or [math.nan] * 3)
        return Result(count, len(emulators.procs), seconds, payload * count,
                      int(after["lost"]), cpu, after["cpu"] - before["cpu"],
                      wire_seconds / max(link_seconds), busy, idle, steal,
                      gc_pause_gen2=pauses.longest[2], gc_pause_any=max(pauses.longest),
                      gc_gen2_count=pauses.counts[2],
                      loop_lag_p95=lags[int(len(lags) * 0.95)], autostatus=autostatus,
                      wire=wire)
    finally:
        emulators.close()


def _mean(values: Iterable[float]) -> float:
    items = list(values)
    return sum(items) / len(items)


def print_cycle(cycles: list[dict[str, float]]) -> None:
    """Print the credit cycle in the middle of one link's upload (ms after the start):
    the write that carried the marker, the marker's modelled arrival at the controller,
    its reply at the driver, until when the wire had bytes to carry, the next write."""
    done = [c for c in cycles if "next_write" in c]
    if not done:
        return
    c = done[len(done) // 2]
    print(f"one credit cycle (link 0, marker {len(done) // 2 + 1} of {len(done)}): "
          f"write of {c['write_bytes']:.0f} B ending in the marker at "
          f"{c['written'] * 1e3:.1f} ms; marker reaches the controller (modelled wire) "
          f"{c['arrives'] * 1e3:.1f} ms; its reply at the driver {c['reply'] * 1e3:.1f} ms "
          f"(+{(c['reply'] - c['arrives']) * 1e3:.1f}); the wire has bytes until "
          f"{c['busy_until'] * 1e3:.1f} ms (slack {(c['busy_until'] - c['arrives']) * 1e3:.1f}"
          f" ms); next write of {c['next_bytes']:.0f} B at {c['next_write'] * 1e3:.1f} ms "
          f"(+{(c['next_write'] - c['reply']) * 1e3:.2f}); dry "
          f"{max(0.0, c['next_write'] - c['busy_until']) * 1e3:.1f} ms", file=sys.stderr)
    dry = sorted(max(0.0, c["next_write"] - c["busy_until"]) for c in done)
    slack = sorted(c["busy_until"] - c["arrives"] for c in done)
    late = sorted(c["reply"] - c["arrives"] for c in done)
    print(f"link 0, {len(done)} cycles: reply after arrival median {late[len(late) // 2] * 1e3:.1f}"
          f" / p95 {late[int(len(late) * 0.95)] * 1e3:.1f} ms; slack median "
          f"{slack[len(slack) // 2] * 1e3:.1f} ms; ran dry in {sum(d > 0 for d in dry)} cycles, "
          f"{sum(dry) * 1e3:.0f} ms in all", file=sys.stderr)
    worst = sorted(done, key=lambda c: c["busy_until"] - c["next_write"])[:6]
    print("link 0, the longest dry spells (ms after the start: reply, dry ms): " + ", ".join(
        f"{c['reply'] * 1e3:.0f}: {(c['next_write'] - c['busy_until']) * 1e3:.1f}"
        for c in worst if c["next_write"] > c["busy_until"]), file=sys.stderr)


async def _loop_lag(lags: list[float], period: float = 0.005) -> None:
    """Record how late the driver's event loop wakes a sleeper (its latency under load)."""
    while True:
        start = time.perf_counter()
        await asyncio.sleep(period)
        lags.append(time.perf_counter() - start - period)


def report(results: list[Result], entries: int) -> None:
    print(f"{entries} trigger positions per controller, 57600 Bd 8N2 ptys; "
          f"wire bound {LINK_BYTES_PER_S:.0f} B/s per link; {os.cpu_count()} cores")
    print(f"{'N':>3} {'emu':>4} {'seconds':>8} {'aggr B/s':>9} {'N x bound':>9} "
          f"{'of bound':>8} {'slowest':>7} {'drv cores':>9} {'drv/ctl-s':>9} "
          f"{'drv/wire-s':>10} {'emu cores':>9} {'busy':>5} {'idle':>5} {'steal':>5} "
          f"{'lost':>4} {'gc2 ms':>6} {'gc ms':>6}")
    for r in results:
        print(f"{r.controllers:3d} {r.emulator_processes:4d} {r.seconds:8.2f} "
              f"{r.throughput:9.0f} {r.bound:9.0f} {r.ratio:8.3f} "
              f"{r.slowest_link_ratio:7.3f} {r.driver_cores:9.3f} "
              f"{r.driver_cpu_per_link_second:9.5f} {r.driver_cpu_per_wire_second:10.5f} "
              f"{r.emulator_cores:9.3f} {r.machine_busy:5.2f} {r.machine_idle:5.2f} "
              f"{r.machine_steal:5.2f} {r.lost_bytes:4d} {r.gc_pause_gen2 * 1e3:6.1f} "
              f"{r.gc_pause_any * 1e3:6.1f}")
    print("columns: emu = emulator processes; slowest = the slowest link's own ratio; "
          "drv/ctl-s = driver CPU s per controller-second; drv/wire-s = driver CPU s per "
          "second of one link's payload at wire speed; busy/idle/steal = cores of the "
          "whole machine; gc2 ms / gc ms = the driver's longest generation-2 / any "
          "garbage collection")
    for r in results:
        if r.wire is None:
            continue
        w = r.wire
        wire_s = r.payload_bytes / r.controllers / LINK_BYTES_PER_S
        sent = w["mean_payload"] + w["mean_marker"] + w["mean_other"]
        print(f"N={r.controllers} autostatus {r.autostatus}, modelled wire per link (mean / "
              f"worst): payload {wire_s:.3f} s; markers {w['mean_marker'] / sent:.4f} and "
              f"other lines {w['mean_other'] / sent:.4f} of the bytes; idle at the start "
              f"{w['mean_start'] * 1e3:.0f} / {w['max_start'] * 1e3:.0f} ms (first payload "
              f"line {w['mean_first_payload'] * 1e3:.0f} / {w['max_first_payload'] * 1e3:.0f}"
              f" ms), dry between payload lines {w['mean_gaps'] * 1e3:.0f} / "
              f"{w['max_gaps'] * 1e3:.0f} ms, tail {w['mean_tail'] * 1e3:.0f} / "
              f"{w['max_tail'] * 1e3:.0f} ms, end {w['mean_end']:.3f} / {w['max_end']:.3f} s;"
              f" reply after the marker's arrival median {w['mean_answer_median'] * 1e3:.1f},"
              f" p95 {w['mean_answer_p95'] * 1e3:.1f} / {w['max_answer_p95'] * 1e3:.1f} ms; "
              f"next write after a reply p95 {w['max_react_p95'] * 1e3:.2f} ms")
    print(json.dumps([asdict(r) | {"ratio": r.ratio, "driver_cores": r.driver_cores,
                                   "emulator_cores": r.emulator_cores,
                                   "driver_cpu_per_wire_second": r.driver_cpu_per_wire_second}
                      for r in results]))


async def main(args: argparse.Namespace) -> list[Result]:
    profile = cProfile.Profile() if args.profile else None
    results = []
    for count in args.counts:
        results.append(await run(count, args.entries, args.per_process, profile,
                                 args.emulator_profile, args.lean, args.marker_chunk,
                                 args.gc, args.autostatus, args.trace))
        print(f"N={count}: {results[-1].ratio:.3f} of the bound", file=sys.stderr)
    if profile is not None:
        profile.dump_stats(args.profile)
        pstats.Stats(profile).sort_stats("tottime").print_stats(25)
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 8, 32, 64])
    parser.add_argument("--entries", type=int, default=3000,
                        help="trigger positions per controller (3000: about 10 s)")
    parser.add_argument("--per-process", type=int, default=16,
                        help="controllers per emulator process (default 16)")
    parser.add_argument("--profile", metavar="FILE", help="cProfile the driver's uploads")
    parser.add_argument("--emulator-profile", metavar="DIR",
                        help="cProfile each emulator process into DIR/emulator-PID.prof")
    parser.add_argument("--lean", action="store_true",
                        help="serve lean stand-ins (LeanLink) instead of full emulators")
    parser.add_argument("--gc", choices=("on", "off", "freeze"), default="on",
                        help="garbage collector during the upload (default on)")
    parser.add_argument("--marker-chunk", type=int, metavar="BYTES",
                        help="reply-less bytes between credit markers (default: the driver's)")
    parser.add_argument("--autostatus", type=int, choices=(1, 2), default=1,
                        help="the links' autostatus mode (2: every line acknowledged, no "
                             "credit markers)")
    parser.add_argument("--trace", action="store_true",
                        help="log every link's writes and reads: one credit cycle, and "
                             "where the wire stood idle (start-up, gaps, tail)")
    parser.add_argument("--serve", type=int, metavar="N", help=argparse.SUPPRESS)
    parser.add_argument("--serve-lean", type=int, metavar="N", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve and args.emulator_profile:
        cProfile.run("asyncio.run(serve(args.serve))",
                     os.path.join(args.emulator_profile, f"emulator-{os.getpid()}.prof"))
    elif args.serve:
        asyncio.run(serve(args.serve))
    elif args.serve_lean:
        asyncio.run(serve_lean(args.serve_lean))
    else:
        report(asyncio.run(main(args)), args.entries)
