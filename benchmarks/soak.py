"""Soak: random operations with injected faults on the emulator, for hours (#14 "Also").

Runs random rounds against ``sim://`` (with ``reconnect=True``) for ``--duration``
seconds (default one hour) and checks, all the time:

* **0 replies to the wrong caller.** Every value read is compared with the emulator's own
  store at that moment (vel and accel are distinct on every axis). A reply counts as own,
  garbled own (one character differs: a garbled reply that still fits its pattern), the
  injected stray line (only the request it reached may take it), or MISDELIVERED.
* **0 hangs.** Every call runs under a deadline (``--hang`` s, far above every documented
  bound); one that outlives it is a hang.
* **Every failure typed.** Any exception other than a ``TangoError`` (or the cancellation
  the soak itself caused) is counted as untyped.
* **0 false successes.** A move that returns normally (also a cancelled one that finished
  first) must leave the emulator's axis standing still at its target
  (``tango_aio.testing.faults(tango).axes()``), or it counts as FALSE SUCCESS.
* **Memory flat.** The process RSS is sampled after the warm-up (``--warmup`` s) and at
  the end; the growth must stay under 5 MB.

Faults, drawn at random per round: dropped replies, garbled replies, noise lines, noise
bytes without CR, stray reply-like lines (fed to the driver as if another program wrote
them), interpreter stalls (some long enough to be declared a dead link), disconnects, and
cancellations of reads, sets and moves. Usage::

    python benchmarks/soak.py [--duration 3600] [--seed 1] [--json out.json]

It is a benchmark, not a CI test: it exits with status 1 when a check failed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import random
import time
from collections import Counter
from pathlib import Path
from typing import Any

import tango_aio
from tango_aio.catalog._instructions import parse
from tango_aio.controller._controller import Controller
from tango_aio.errors import TangoError
from tango_aio.sim.wire import flip_one_bit
from tango_aio.testing import faults

URL = "sim://?baud=0&processing=0.0005&fragment=0.2"
READS = ["?vel x", "?vel y", "?vel z", "?accel x", "?accel y", "?accel z", "?vel", "?accel",
         "?pos", "?statusaxis"]
VELS = {"x": 11.5, "y": 12.25, "z": 13.125}
ACCELS = {"x": 1.5, "y": 2.25, "z": 3.75}
STRAY = "77.777"  # looks like a reply, equals no value


def rss_kib() -> int:
    """The resident set size of this process (KiB)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def truth(tango: Controller, line: str) -> str:
    model = faults(tango).model
    return model.params.read(parse(line, model.context()), model.axes)


#: The outcomes that fail the soak.
FAILURES = ("MISDELIVERED", "HANG", "UNTYPED", "FALSE SUCCESS")


def classify(expected: str, reply: str) -> str:
    if reply == expected:
        return "own"
    if reply == STRAY:
        return "took the stray line"
    if len(reply) == len(expected) and sum(a != b for a, b in zip(reply, expected,
                                                                  strict=True)) == 1:
        return "garbled own"
    return "MISDELIVERED"


class Soak:
    """One soak run: the counters and the rounds."""

    def __init__(self, seed: int, hang: float) -> None:
        self.rng = random.Random(seed)
        self.hang = hang
        self.counts: Counter[str] = Counter()
        self.faults: Counter[str] = Counter()
        self.examples: list[str] = []

    def note(self, what: str, example: str = "") -> None:
        self.counts[what] += 1
        if what in FAILURES and len(self.examples) < 20:
            self.examples.append(f"{what}: {example}")

    async def call(self, what: str, coro: Any) -> Any:
        """Run one call under the hang deadline; count its outcome class."""
        try:
            async with asyncio.timeout(self.hang):
                result = await coro
        except TimeoutError as exc:
            if isinstance(exc, TangoError):
                self.note(f"{what}: {type(exc).__name__}")
            else:
                self.note("HANG", what)
            return None
        except asyncio.CancelledError:
            raise
        except TangoError as exc:
            self.note(f"{what}: {type(exc).__name__}")
            return exc
        except Exception as exc:  # counted, the soak goes on
            self.note("UNTYPED", f"{what}: {exc!r}")
            return exc
        return result

    async def move(self, tango: Controller, what: str, target: float) -> Any:
        """``move_to(z=target)`` under the hang deadline; a normal return is checked
        against where the emulator's z axis really is."""
        result = await self.call(what, tango.move_to(z=target, timeout=5.0))
        if isinstance(result, dict):
            position, velocity = faults(tango).axes()["z"]
            if velocity != 0.0 or abs(position - target) > 5e-4:
                self.note("FALSE SUCCESS", f"z={target}: at {position}, {velocity} rev/s")
            else:
                self.note(f"{what}: arrived")
        return result

    async def setup(self, tango: Controller) -> None:
        await tango.wait_connected(timeout=self.hang)
        await tango.set("vel", **VELS)
        await tango.set("accel", **ACCELS)
        for name, value in (("secvel", 100), ("vel", 20), ("accel", 20)):
            await tango.set(name, value, axis="z")  # z moves; x, y keep distinct values

    async def reads(self, tango: Controller, stray: bool) -> None:
        lines = [self.rng.choice(READS) for _ in range(self.rng.randint(1, 6))]
        tasks = [asyncio.ensure_future(self.call("read", tango.query(line))) for line in lines]
        if stray:
            await asyncio.sleep(0)
            tango.protocol.data_received(f"{STRAY}\r".encode())
            self.faults["stray line"] += 1
        results = await asyncio.gather(*tasks)
        for index, (line, result) in enumerate(zip(lines, results, strict=True)):
            if not isinstance(result, str):
                continue
            if not tango.connected:
                self.note("read: own (link lost meanwhile)")
                continue
            verdict = classify(truth(tango, line), result) if "pos" not in line \
                and "status" not in line else "own (moving value)"
            if verdict == "took the stray line" and (not stray or index > 0):
                # Only the request the stray line reached (the first in flight) may take it.
                verdict = "MISDELIVERED"
            self.note(f"read: {verdict}", f"{line!r} -> {result!r}")

    async def round(self, tango: Controller) -> None:
        rng = self.rng
        wire = faults(tango).wire
        fault = rng.choices(
            ["none", "drop", "garble", "noise", "noise bytes", "stray", "stall", "dead",
             "disconnect", "cancel read", "cancel set", "cancel move", "move"],
            [30, 6, 6, 4, 3, 6, 4, 1, 1, 5, 4, 4, 8])[0]
        self.faults[fault] += 1
        if fault == "drop":
            wire.faults.drop_replies = 1
        elif fault == "garble":
            wire.faults.garbler = flip_one_bit
            wire.faults.garble_replies = 1
        elif fault == "noise":
            wire.emit(bytes(rng.randrange(0x21, 0x7F) for _ in range(rng.randint(1, 12)))
                      + b"\r")
        elif fault == "noise bytes":
            wire.emit(b"\x00\xff")
        elif fault == "stall":
            wire.stall(rng.uniform(0.001, 0.03))
        elif fault == "dead":
            wire.stall(3.0 * tango.reply_timeout)  # a dead link that stays open
        elif fault == "disconnect":
            wire.disconnect(mid_reply=rng.random() < 0.5)
        if fault.startswith("cancel"):
            await self.cancelled(tango, fault)
        elif fault == "move":
            await self.move(tango, "move", round(rng.uniform(-1, 1), 3))
        else:
            await self.reads(tango, stray=fault == "stray")
        wire.faults.drop_replies = wire.faults.garble_replies = 0
        if not tango.connected:
            self.counts["link lost"] += 1
            if await self.call("reconnect", tango.wait_connected(timeout=self.hang)) is None \
                    and tango.connected:
                await self.call("setup", self.setup(tango))

    async def cancelled(self, tango: Controller, kind: str) -> None:
        rng = self.rng
        if kind == "cancel read":
            coro = tango.query(rng.choice(READS))
        elif kind == "cancel set":
            coro = tango.set("vel", VELS["x"], axis="x")
        else:
            coro = self.move(tango, "move", round(rng.uniform(-1, 1), 3))
        task = asyncio.ensure_future(coro if kind == "cancel move"
                                     else self.call(kind.split()[1], coro))
        for _ in range(rng.randint(0, 6)):
            await asyncio.sleep(0)
        await asyncio.sleep(rng.choice([0, 0.0005, 0.002, 0.01]))
        task.cancel()
        try:
            async with asyncio.timeout(self.hang):
                await task
            self.note(f"{kind}: finished first")
        except asyncio.CancelledError:
            self.note(f"{kind}: cancelled")
        except TimeoutError:
            self.note("HANG", f"{kind}: the cancelled call did not end")
        # The next read is its own.
        await self.reads(tango, stray=False)


async def run(duration: float, warmup: float, seed: int, hang: float) -> dict[str, Any]:
    soak = Soak(seed, hang)
    tango = await tango_aio.connect(URL, reply_timeout=0.3, reconnect=True,
                                    reconnect_initial=0.01, reconnect_max=0.2,
                                    keepalive=1.0)
    start = time.monotonic()
    rss_start = rss_kib()
    rss_warm: int | None = None
    rounds = 0
    try:
        await soak.setup(tango)
        while (elapsed := time.monotonic() - start) < duration:
            if rss_warm is None and elapsed >= warmup:
                rss_warm = rss_kib()
            await soak.round(tango)
            rounds += 1
            if rounds % 2000 == 0:
                print(f"{elapsed:7.0f} s  {rounds} rounds  rss {rss_kib()} KiB  "
                      f"misdelivered {soak.counts['MISDELIVERED']}  "
                      f"hangs {soak.counts['HANG']}  untyped {soak.counts['UNTYPED']}  "
                      f"false successes {soak.counts['FALSE SUCCESS']}",
                      flush=True)
    finally:
        await tango.aclose()
    rss_end = rss_kib()
    warm = rss_warm if rss_warm is not None else rss_start
    misdelivered = soak.counts["MISDELIVERED"]
    return {
        "duration_s": round(time.monotonic() - start, 1),
        "rounds": rounds,
        "seed": seed,
        "misdelivered": misdelivered,
        "hangs": soak.counts["HANG"],
        "untyped": soak.counts["UNTYPED"],
        "false_successes": soak.counts["FALSE SUCCESS"],
        "moves_arrived": soak.counts["move: arrived"],
        "rss_kib": {"start": rss_start, "after_warmup": warm, "end": rss_end,
                    "growth_after_warmup": rss_end - warm},
        "ok": all(soak.counts[what] == 0 for what in FAILURES) and rss_end - warm < 5 * 1024,
        "faults": dict(sorted(soak.faults.items())),
        "outcomes": dict(sorted(soak.counts.items())),
        "examples": soak.examples,
    }


class _WarningCounter(logging.Handler):
    """Counts the driver's warnings by their first words instead of printing them."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.counts: Counter[str] = Counter()

    def emit(self, record: logging.LogRecord) -> None:
        self.counts[" ".join(record.getMessage().split()[:3])] += 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3600.0)
    parser.add_argument("--warmup", type=float, default=None,
                        help="seconds before the RSS baseline (default: 10%% of duration)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--hang", type=float, default=20.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    warmup = args.warmup if args.warmup is not None else args.duration / 10
    warnings = _WarningCounter()
    logging.getLogger("tango_aio").addHandler(warnings)
    logging.getLogger("tango_aio").propagate = False
    report = asyncio.run(run(args.duration, warmup, args.seed, args.hang))
    report["warnings logged"] = dict(warnings.counts.most_common())
    text = json.dumps(report, indent=1)
    print(text)
    if args.json is not None:
        args.json.write_text(text)
    raise SystemExit(0 if report["ok"] else 1)


if __name__ == "__main__":
    main()
