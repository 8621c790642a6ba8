"""Run the benchmarks of issue 19's targets, each beside its raw baseline, in one run.

``python -m benchmarks`` runs every case under the standard asyncio loop and, when
``uvloop`` is importable, again under uvloop, and prints the Markdown table that
BENCHMARKS.md records: the driver's figure, the raw client's figure measured right after it
in the same process, their ratio, the target, and what uvloop changes.

Each (case, loop) runs in a child process of its own (``--worker``) with a time limit, so a
case that fails or hangs under one loop is reported as such and the others still run.

Cases (``--cases`` picks some, in this order):

* ``compat``: does each kind of link (``sim://``, ``sim://?baud=0``, ``socket://`` to an
  emulator process, a pty) connect and answer ``?pos`` under this loop;
* ``requests``: driver CPU per ``?pos`` and per checked set on a canned transport
  (``benchmarks/canned.py``);
* ``latency``: CPU per tiny ``move_to`` and completion latency, canned transport;
* ``moves``: tiny absolute/relative moves per second on a 57600 Bd pty
  (``benchmarks/moves.py``);
* ``watch``: ``watch_position(0.1)`` CPU during a long move vs raw polling
  (``benchmarks/watch.py``);
* ``upload``: one link's trigger upload under the benchmark's stalls, of the wire bound, in
  autostatus 1 (credit markers) and 2 (every line acknowledged)
  (``benchmarks/upload.py``);
* ``stopwait``: upload vs stop-and-wait on a plain pty and with 2 ms reply latency;
* ``scaling``: N links (default 64) uploading at once to lean stand-ins: throughput of
  N x the bound, driver CPU per link wire-second, longest GC pause
  (``benchmarks/scaling.py``);
* ``bluesky``: a single-axis step-scan point through a RunEngine and
  ``tango_aio.bluesky`` vs the driver's own ``move_to`` plus one read, tiny and tile
  steps on a 57600 Bd pty (``benchmarks/bluesky.py``).

Usage::

    python -m benchmarks                       # everything, asyncio and uvloop
    python -m benchmarks --quick               # every case briefly (about 2 minutes)
    python -m benchmarks --cases requests latency --loop asyncio
    python -m benchmarks --links 64 --entries 1500
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib.util
import json
import math
import os
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass

LoopFactory = Callable[[], asyncio.AbstractEventLoop]
CASES = ("compat", "requests", "latency", "moves", "watch", "upload", "stopwait", "scaling",
         "bluesky")


@dataclass
class Row:
    """One line of the table: the driver's figure beside its raw baseline."""

    case: str
    what: str
    unit: str
    driver: float
    raw: float | None = None
    #: True when more is better (rates, of-bound ratios), False for costs.
    higher_is_better: bool = True
    target: str = ""
    note: str = ""

    @property
    def ratio(self) -> float | None:
        """driver / raw."""
        if self.raw is None or self.raw == 0:
            return None
        return self.driver / self.raw


# ------------------------------------------------------------------ the cases


def case_compat(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """Connect and read ``?pos`` over each kind of link."""
    import tango_aio
    from benchmarks.moves import emulator_pty

    async def probe(url: str) -> None:
        async with asyncio.timeout(15):
            async with tango_aio.connect(url) as tango:
                await tango.position()

    rows = []
    with emulator_pty() as pty, _emulator_tcp() as tcp:
        for kind, url in (("sim://", "sim://"), ("sim://?baud=0", "sim://?baud=0"),
                          ("socket://", tcp), ("pty", pty)):
            try:
                with asyncio.Runner(loop_factory=loop) as runner:
                    runner.run(probe(url))
                rows.append(Row("compat", f"connect + ?pos over {kind}", "works", 1.0))
            except Exception as exc:  # the finding is the failure itself
                rows.append(Row("compat", f"connect + ?pos over {kind}", "works", 0.0,
                                note=_where(exc)))
    return rows


def _where(exc: BaseException) -> str:
    """``Type: message`` and the innermost frame that raised it."""
    while exc.__context__ is not None and not str(exc):
        exc = exc.__context__
    frames = traceback.extract_tb(exc.__traceback__)
    where = ""
    if frames:
        path = frames[-1].filename
        where = f" at {path[path.find('tango_aio/'):] if 'tango_aio/' in path else path}" \
                f":{frames[-1].lineno}"
    return f"{type(exc).__name__}: {exc}"[:120] + where


@contextlib.contextmanager
def _emulator_tcp() -> Iterator[str]:
    """``tango-aio sim --tcp 127.0.0.1:0`` in its own process; yield its URL."""
    process = subprocess.Popen([sys.executable, "-m", "tango_aio", "sim", "--tcp",
                                "127.0.0.1:0"], stdout=subprocess.PIPE,
                               stdin=subprocess.DEVNULL, text=True)
    try:
        assert process.stdout is not None
        yield process.stdout.readline().strip()
    finally:
        process.terminate()
        process.wait(timeout=10)


def case_requests(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """CPU per ``?pos`` and per checked set, canned transport."""
    from benchmarks import canned

    calls, rounds = (200, 1) if args.quick else (2000, 3)
    with asyncio.Runner(loop_factory=loop) as runner:
        pairs = runner.run(canned.requests(calls, rounds))
    return [Row("requests", f"driver CPU per {driver.name.removeprefix('driver ')}"
                f" (canned transport)", "µs", driver.cpu_per_call * 1e6,
                raw.cpu_per_call * 1e6, False, "≤ 3× raw")
            for driver, raw in pairs]


def case_latency(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """CPU per tiny move and completion latency, canned transport."""
    from benchmarks import canned

    count, rounds = (30, 1) if args.quick else (300, 3)
    with asyncio.Runner(loop_factory=loop) as runner:
        driver, raw = runner.run(canned.moves(count, rounds))
        again, confirmed = runner.run(canned.moves(count, rounds, confirm=True))
    return [Row("latency", "driver CPU per move_to (canned transport)", "µs",
                driver.cpu_per_call * 1e6, raw.cpu_per_call * 1e6, False),
            Row("latency", "completion report delivered → await returns (median)", "µs",
                driver.latency * 1e6, raw.latency * 1e6, False, "≤ 2× raw"),
            Row("latency", "… raw confirms like the driver (?statusaxis + ?pos)", "µs",
                again.latency * 1e6, confirmed.latency * 1e6, False, "≤ 2× raw"),
            Row("latency", "… driver CPU per move_to, raw confirming", "µs",
                again.cpu_per_call * 1e6, confirmed.cpu_per_call * 1e6, False)]


def case_moves(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """Tiny and tile moves per second on a pty."""
    from benchmarks import moves

    pairs = moves.run(20 if args.quick else 200, loop)
    kinds = ("tiny absolute moves (move_to vs raw !moa)",
             "tiny absolute moves (move_to vs raw !moa + ?err)",
             "tiny relative moves (move_by vs raw !mor)",
             "tiny relative moves, HDI off (move_by after !joy 0 vs raw !mor)",
             "tiny absolute moves (move_to vs raw !moa + ?err, confirmed like the driver)",
             "tiny relative moves (move_by vs raw !mor + ?err, confirmed like the driver)")
    targets = ("≥ 0.70", "", "≥ 0.70", "≥ 0.70", "", "")
    rows = [Row("moves", kind, "moves/s", driver.per_second, raw.per_second, True, target)
            for kind, target, (driver, raw) in zip(kinds, targets, pairs, strict=True)]
    # Issue 28: tile steps (1 mm at 40 mm/s) against the raw
    # client that trusts the report.
    tiles = moves.run(10 if args.quick else 100, loop, confirmed=False, step=1.0,
                      speed=40.0)
    kinds = ("tile steps, 1 mm at 40 mm/s (move_to vs raw !moa)",
             "tile steps, 1 mm at 40 mm/s (move_to vs raw !moa + ?err)",
             "tile steps, 1 mm at 40 mm/s (move_by vs raw !mor)",
             "tile steps, 1 mm at 40 mm/s, HDI off (move_by after !joy 0 vs raw !mor)")
    targets = ("≥ 0.90", "", "≥ 0.90", "≥ 0.90")
    return rows + [Row("moves", kind, "moves/s", driver.per_second, raw.per_second, True,
                       target)
                   for kind, target, (driver, raw) in zip(kinds, targets, tiles, strict=True)]


def case_watch(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """``watch_position(0.1)`` CPU vs raw polling."""
    from benchmarks import watch

    driver, raw, pipelined = watch.run(1.0 if args.quick else 5.0, loop)
    rates = " vs ".join(f"{w.updates / w.seconds:.1f}" for w in (driver, raw, pipelined))
    return [Row("watch", "watch_position(0.1) during a move: CPU (raw: ?statusaxis + ?pos)",
                "ms/s", driver.cpu_ms_per_second, raw.cpu_ms_per_second, False,
                "≤ 1.2× raw", f"{rates} updates/s (driver, raw, raw pipelined)"),
            Row("watch", "… raw: both reads in one write (pipelined)", "ms/s",
                driver.cpu_ms_per_second, pipelined.cpu_ms_per_second, False)]


def case_upload(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """One link's upload under the benchmark's stalls."""
    from benchmarks import upload

    entries = 300 if args.quick else 3000
    with asyncio.Runner(loop_factory=loop) as runner:
        markers = runner.run(upload.single_link(entries))
        acknowledged = runner.run(upload.single_link(entries, autostatus=2))
    return [Row("upload", f"1 link, {entries} trigp under stalls, of the wire bound", "",
                markers.efficiency, None, True, "≥ 0.97, 0 lost",
                f"autostatus 1 (credit markers); lost bytes {markers.lost_bytes}"),
            Row("upload", f"1 link, {entries} trigp under stalls, autostatus 2", "",
                acknowledged.efficiency, None, True, "≥ 0.97, 0 lost",
                f"every line acknowledged, no markers; lost bytes "
                f"{acknowledged.lost_bytes}")]


def case_stopwait(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """Upload against stop-and-wait, plain pty and 2 ms latency."""
    from benchmarks import upload

    entries = 100 if args.quick else 1000
    results = upload.pty_comparison(entries, (0.0, 0.002), loop)
    rows = []
    for pipelined, stop in zip(results[::2], results[1::2], strict=True):
        latency = pipelined.name.split(",")[1].strip()
        rows.append(Row("stopwait", f"upload {entries} trigp, pty, {latency}: of bound "
                        "(raw: stop-and-wait)", "", pipelined.efficiency, stop.efficiency,
                        True, "", f"{stop.seconds / pipelined.seconds:.2f}× stop-and-wait"))
    return rows


def case_scaling(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """N links at once against lean stand-ins."""
    from benchmarks import scaling

    links = 8 if args.quick else args.links
    entries = 200 if args.quick else args.entries
    with asyncio.Runner(loop_factory=loop) as runner:
        result = runner.run(scaling.run(links, entries, links, None, lean=True))
    where = f"{links} links × {entries} trigp, lean stand-ins"
    return [
        Row("scaling", f"{where}: of N × wire bound", "", result.ratio, None, True,
            "≥ 0.95", f"slowest link {result.slowest_link_ratio:.3f}, "
            f"lost {result.lost_bytes}"),
        Row("scaling", f"{where}: driver CPU per link wire-second", "s",
            result.driver_cpu_per_wire_second, None, False, "≤ 0.003",
            f"{result.driver_cores:.2f} cores"),
        Row("scaling", f"{where}: longest gen-2 GC pause", "ms", result.gc_pause_gen2 * 1e3,
            None, False, "< credit slack (~17 ms)",
            f"{result.gc_gen2_count} gen-2 collections; longest of any gen "
            f"{result.gc_pause_any * 1e3:.1f} ms"),
        Row("scaling", f"{where}: event-loop lag p95", "ms", result.loop_lag_p95 * 1e3, None,
            False, "", f"machine busy {result.machine_busy:.2f} / idle "
            f"{result.machine_idle:.2f} / steal {result.machine_steal:.2f} cores"),
    ]


def case_bluesky(loop: LoopFactory | None, args: argparse.Namespace) -> list[Row]:
    """A Bluesky step-scan point vs the driver's move_to plus one read."""
    from benchmarks import bluesky

    pairs = bluesky.run(10 if args.quick else 100, loop)
    return [Row("bluesky", f"step-scan point, {scan.name.split(', ')[1]} (Bluesky list_scan "
                "vs driver move_to + ?pos)", "ms", scan.ms_per_point, driver.ms_per_point,
                False, "≤ 1.2× driver") for scan, driver in pairs]


RUNNERS: dict[str, Callable[[LoopFactory | None, argparse.Namespace], list[Row]]] = {
    "compat": case_compat, "requests": case_requests, "latency": case_latency,
    "moves": case_moves, "watch": case_watch, "upload": case_upload,
    "stopwait": case_stopwait, "scaling": case_scaling, "bluesky": case_bluesky}


# ------------------------------------------------------------------ running


def worker(case: str, loop: str, args: argparse.Namespace) -> None:
    """Run one case under one loop; print its rows as JSON on the last line."""
    from benchmarks.moves import event_loop

    rows = RUNNERS[case](event_loop(loop), args)
    print(json.dumps([asdict(row) for row in rows]), flush=True)


def run_case(case: str, loop: str, args: argparse.Namespace) -> list[Row]:
    """Run ``case`` under ``loop`` in a child process; a failure or hang becomes a row."""
    command = [sys.executable, "-m", "benchmarks", "--worker", case, "--loop", loop,
               "--links", str(args.links), "--entries", str(args.entries)]
    if args.quick:
        command.append("--quick")
    limit = args.case_timeout
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=limit,
                              cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    except subprocess.TimeoutExpired:
        return [Row(case, f"{case}: did not finish", "", math.nan,
                    note=f"hung: no result within {limit:g} s")]
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return [Row(case, f"{case}: failed", "", math.nan, note=last[:160])]
    return [Row(**row) for row in json.loads(lines[-1])]


def _number(value: float | None, unit: str) -> str:
    if value is None:
        return "—"
    if math.isnan(value):
        return "failed"
    if unit == "works":
        return "yes" if value else "**no**"
    if unit == "s" and value < 0.1:
        return f"{value:.4f}"
    if abs(value) >= 100:
        return f"{value:.0f}"
    if abs(value) >= 10:
        return f"{value:.1f}"
    return f"{value:.3f}" if unit == "" else f"{value:.2f}"


def _ratio(row: Row | None) -> str:
    ratio = None if row is None else row.ratio
    return "—" if ratio is None else f"**{ratio:.2f}**"


def _gain(base: Row, other: Row | None) -> str:
    """How much better ``other`` is than ``base`` (> 1: better)."""
    if other is None or other.unit == "works" or not base.driver or not other.driver:
        return "—"
    if math.isnan(base.driver) or math.isnan(other.driver):
        return "—"
    gain = other.driver / base.driver if base.higher_is_better else base.driver / other.driver
    return f"{gain:.2f}"


def table(results: dict[str, list[Row]]) -> str:
    """The Markdown table: one row per figure, the loops side by side."""
    loops = list(results)
    base = results[loops[0]]
    head = ["what", "unit", f"driver ({loops[0]})", "raw", "ratio", "target"]
    others = {loop: {(r.case, r.what): r for r in results[loop]} for loop in loops[1:]}
    # A case that failed or hung under a loop gives one row; it stands for all its rows.
    failures = {loop: {r.case: r for r in results[loop] if math.isnan(r.driver)}
                for loop in loops}
    for loop in loops[1:]:
        head += [f"driver ({loop})", f"raw ({loop})", f"ratio ({loop})",
                 f"{loop} gain on the driver"]
    head.append("notes")
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join("---" if i in (0, 1, 5, len(head) - 1) else "---:"
                            for i in range(len(head))) + "|"]
    for row in base:
        cells = [row.what, row.unit or "—", _number(row.driver, row.unit),
                 _number(row.raw, row.unit), _ratio(row), row.target]
        notes = [row.note] if row.note else []
        for loop in loops[1:]:
            other = others[loop].get((row.case, row.what)) or failures[loop].get(row.case)
            cells += [_number(other.driver, row.unit) if other else "—",
                      _number(other.raw, row.unit) if other else "—", _ratio(other),
                      _gain(row, other)]
            if other is not None and other.note and other.note != row.note:
                notes.append(f"{loop}: {other.note}")
        cells.append("; ".join(notes).replace("|", "/"))
        lines.append("| " + " | ".join(cells) + " |")
    # Rows only another loop produced (a case that failed under the first one).
    seen = {(r.case, r.what) for r in base}
    for loop in loops[1:]:
        for row in results[loop]:
            if (row.case, row.what) not in seen and row.case not in failures[loops[0]]:
                cells = [f"{row.what} (only under {loop})", row.unit or "—",
                         *["—"] * 3, row.target, *["—"] * (4 * len(loops) - 4), row.note]
                lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    """Parse the options; run the cases (as workers, or one case with ``--worker``)."""
    uvloop_there = importlib.util.find_spec("uvloop") is not None
    parser = argparse.ArgumentParser(prog="python -m benchmarks",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES),
                        metavar="CASE", help=f"cases to run (default all: {', '.join(CASES)})")
    parser.add_argument("--loop", choices=("asyncio", "uvloop", "both"),
                        default="both" if uvloop_there else "asyncio",
                        help="event loop(s) (default: both when uvloop is importable)")
    parser.add_argument("--quick", action="store_true", help="run each case briefly")
    parser.add_argument("--links", type=int, default=64, help="links of 'scaling' (64)")
    parser.add_argument("--entries", type=int, default=1500,
                        help="trigger positions per link of 'scaling' (1500: about 5 s)")
    parser.add_argument("--case-timeout", type=float, default=600.0,
                        help="seconds before a case counts as hung (600)")
    parser.add_argument("--json", metavar="FILE", help="also write every row as JSON")
    parser.add_argument("--worker", choices=CASES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.loop, args)
        return
    loops = ["asyncio", "uvloop"] if args.loop == "both" else [args.loop]
    results: dict[str, list[Row]] = {loop: [] for loop in loops}
    start = time.perf_counter()
    for case in args.cases:
        for loop in loops:  # the loops one right after the other, per case
            case_start = time.perf_counter()
            results[loop] += run_case(case, loop, args)
            print(f"{case} ({loop}): {time.perf_counter() - case_start:.0f} s",
                  file=sys.stderr, flush=True)
    print(f"{time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, "
          f"{time.perf_counter() - start:.0f} s; ratio = driver / raw, measured side by side")
    print(table(results))
    if args.json:
        with open(args.json, "w") as out:
            json.dump({loop: [asdict(r) for r in rows] for loop, rows in results.items()},
                      out, indent=1)


if __name__ == "__main__":
    main()
