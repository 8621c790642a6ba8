"""Move-rate benchmark: tiny moves through the driver against a minimal raw client.

The emulator runs in a process of its own (``tango-aio sim --pty``, 57600 Bd 8N2, 3 axes),
so that its CPU is not the driver's. On the same pty, in one run, side by side:

* ``move_to``: ``await tango.move_to(x=...)`` alternating between two targets 0.01 mm
  apart, autostatus 1;
* ``move_by``: ``await tango.move_by(x=±0.01)``;
* the raw client: pyserial, blocking, the smallest correct loop a lab script would write:
  write ``!moa x`` (or ``!mor``), read until the completion report ``...\\r``;
* the raw client with the move's check: ``!moa x`` then ``?err`` read back, then the report;
* the raw client with the driver's guarantee (``--confirmed`` rows): the move and its
  check, the report, then ``?statusaxis`` and ``?pos`` in one write, both read back and
  compared (stopped, at the target). This is what ``move_to``/``move_by`` do since #19
  (the report is only a hint, #13), so it is the like-for-like baseline; the rows above
  compare with clients that trust the report. For ``!mor`` the raw client takes its start
  from its own previous confirmation (a script that assumes nobody moves the stage in
  between); the driver reads ``?pos`` before a ``move_by`` (the target of a relative move
  is start + distance, and a hand on the joystick would make a remembered start wrong).

Each is reported in moves per second and as the driver's ratio to the raw client of the same
kind. Usage::

    python benchmarks/moves.py [--moves 200]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import serial

import tango_aio

STEP = 0.01


@dataclass
class Rate:
    """Moves per second of one way of moving."""

    name: str
    moves: int
    seconds: float

    @property
    def per_second(self) -> float:
        """Moves per second."""
        return self.moves / self.seconds


def event_loop(name: str) -> Callable[[], asyncio.AbstractEventLoop] | None:
    """The loop factory of ``--loop NAME`` (``asyncio``: ``None``, the default loop;
    ``uvloop``: uvloop's, which must be installed)."""
    if name == "uvloop":
        import uvloop

        return uvloop.new_event_loop  # type: ignore[no-any-return]
    return None


@contextlib.contextmanager
def emulator_pty(*options: str) -> Iterator[str]:
    """Start ``tango-aio sim --pty [options]`` in its own process; yield the device path."""
    process = subprocess.Popen(
        [sys.executable, "-m", "tango_aio", "sim", "--pty", *options],
        stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
    try:
        assert process.stdout is not None
        path = process.stdout.readline().strip().split()[-1]
        if not path.startswith("/dev/"):
            raise RuntimeError(f"the emulator did not print a device path: {path!r}")
        yield path
    finally:
        process.terminate()
        process.wait(timeout=10)


def raw_moves(path: str, moves: int, line: Callable[[int], str], check: bool,
              confirm: bool = False) -> Rate:
    """A pyserial loop: write the move (and ``?err``), read until the completion report
    (with ``confirm``: then ``?statusaxis`` and ``?pos`` in one write, checked)."""
    with serial.Serial(path, 57600, stopbits=2, timeout=5) as port:
        port.write(b"\r")
        port.reset_input_buffer()
        port.write(b"?pos\r")
        position = float(_read_line(port).split()[0])
        start = time.perf_counter()
        for index in range(moves):
            text = line(index)
            port.write(text.encode() + (b"\r?err\r" if check else b"\r"))
            # A move to where the axis already is may report before ?err is answered.
            seen = {"check": not check, "report": False}
            while not all(seen.values()):
                reply = _read_line(port)
                seen["check"] |= reply.isdigit()
                seen["report"] |= reply.endswith(".")
            if confirm:
                value = float(text.split()[-1])
                position = position + value if text.startswith("!mor") else value
                port.write(b"?statusaxis\r?pos\r")
                letters, where = _read_line(port), _read_line(port)
                if letters[0] != "@" or abs(float(where.split()[0]) - position) > 1.5e-4:
                    raise RuntimeError(f"{text!r} ended at {where!r} with {letters!r}")
        seconds = time.perf_counter() - start
    kind = "confirmed " if confirm else "check " if check else ""
    return Rate(f"raw {kind}{line(0).split()[0]}", moves, seconds)


def set_speed(path: str, speed: float) -> None:
    """Set X's ``secvel`` and ``vel`` to ``speed`` mm/s (pitch 1, dim 2) and check it."""
    with serial.Serial(path, 57600, stopbits=2, timeout=5) as port:
        port.write(b"\r")
        port.reset_input_buffer()
        port.write(f"!secvel x {speed}\r!vel x {speed}\r?err\r".encode())
        if (reply := _read_line(port)) != "0":
            raise RuntimeError(f"setting the speed to {speed} failed: error {reply}")


def _read_line(port: serial.Serial) -> str:
    raw = port.read_until(b"\r")
    if not raw.endswith(b"\r"):
        raise TimeoutError("no reply from the emulator")
    return raw[:-1].decode("latin-1")


async def driver_moves(path: str, moves: int, relative: bool, step: float = STEP,
                       hdi_off: bool = False) -> Rate:
    """``move_to`` / ``move_by`` through the driver, steps of ``step`` mm. ``hdi_off``:
    ``!joy 0`` first (and ``!joy 2`` after), so that a ``move_by`` may start from the
    position its previous move's confirmation read (#28 target 2)."""
    async with tango_aio.connect(path) as tango:
        if hdi_off:
            await tango.set("joy", 0)
            await tango.move_by(x=0.0)  # its confirmation reads the first start
        start = time.perf_counter()
        for index in range(moves):
            if relative:
                await tango.move_by(x=step if index % 2 == 0 else -step)
            else:
                await tango.move_to(x=step if index % 2 == 0 else 0.0)
        seconds = time.perf_counter() - start
        if hdi_off:
            await tango.set("joy", 2)
    name = "driver move_by" if relative else "driver move_to"
    return Rate(f"{name}, HDI off" if hdi_off else name, moves, seconds)


def absolute(index: int, step: float = STEP) -> str:
    """The raw client's absolute move line."""
    return f"!moa x {step if index % 2 == 0 else 0.0}"


def relative(index: int, step: float = STEP) -> str:
    """The raw client's relative move line."""
    return f"!mor x {step if index % 2 == 0 else -step}"


def run(moves: int, loop_factory: Callable[[], asyncio.AbstractEventLoop] | None = None,
        confirmed: bool = True, step: float = STEP, speed: float | None = None
        ) -> list[tuple[Rate, Rate]]:
    """Every pair (driver, raw baseline), measured one after the other on one emulator;
    the driver runs in a loop made by ``loop_factory`` (default asyncio's). With
    ``confirmed``, also the pairs against the raw client with the driver's guarantee.
    ``step``: the distance of each move in mm (0.01: tiny steps, the wire is all there
    is; 1.0: tile steps of a tiled microscope scan, issue 28); ``speed``: X's ``vel``
    and ``secvel`` in mm/s (issue 28's tile steps: 40; default: the emulator's)."""
    def moa(index: int) -> str:
        return absolute(index, step)

    def mor(index: int) -> str:
        return relative(index, step)

    with emulator_pty() as path, asyncio.Runner(loop_factory=loop_factory) as runner:
        if speed is not None:
            set_speed(path, speed)
        pairs = [
            (runner.run(driver_moves(path, moves, relative=False, step=step)),
             raw_moves(path, moves, moa, check=False)),
            (runner.run(driver_moves(path, moves, relative=False, step=step)),
             raw_moves(path, moves, moa, check=True)),
            (runner.run(driver_moves(path, moves, relative=True, step=step)),
             raw_moves(path, moves, mor, check=False)),
            (runner.run(driver_moves(path, moves, relative=True, step=step, hdi_off=True)),
             raw_moves(path, moves, mor, check=False)),
        ]
        if confirmed:
            pairs += [
                (runner.run(driver_moves(path, moves, relative=False, step=step)),
                 raw_moves(path, moves, moa, check=True, confirm=True)),
                (runner.run(driver_moves(path, moves, relative=True, step=step)),
                 raw_moves(path, moves, mor, check=True, confirm=True)),
            ]
        return pairs


def table(pairs: list[tuple[Rate, Rate]]) -> str:
    """The Markdown table BENCHMARKS.md records."""
    rows = ["| driver | moves/s | raw client | moves/s | ratio |", "|---|---:|---|---:|---:|"]
    for driver, raw in pairs:
        rows.append(f"| {driver.name} | {driver.per_second:.1f} | {raw.name} | "
                    f"{raw.per_second:.1f} | **{driver.per_second / raw.per_second:.2f}** |")
    return "\n".join(rows)


def main() -> None:
    """Run the benchmark and print its table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--moves", type=int, default=200, help="moves per case")
    parser.add_argument("--step", type=float, default=STEP,
                        help="mm per move (0.01: tiny steps; 1: tile steps)")
    parser.add_argument("--speed", type=float, default=None,
                        help="X's vel and secvel in mm/s (issue 28's tile steps: 40)")
    args = parser.parse_args()
    print(table(run(args.moves, step=args.step, speed=args.speed)))


if __name__ == "__main__":
    main()
