"""Instructions per request, counted by valgrind: a side-by-side figure the machine's load
cannot move.

CPU seconds per request (``benchmarks/canned.py``) scatter by 10-40 % between two runs of
the same tree on this shared 2-core machine, so a 3 % regression cannot be seen in them.
The number of machine instructions the interpreter executes for one request can: valgrind's
cachegrind counts them (``I refs``), the same from run to run to within 0.3 % with
``PYTHONHASHSEED=0``. What is counted is the canned-transport request of
``benchmarks/canned.py`` (the driver's whole per-request path, no wire): ``?pos``
(``Controller.position``), a checked set (``Controller.set("vel", x=...)``) and a tiny
``move_to``. Each figure is (count of ``N`` calls - count of 0 calls) / ``N``, so the
interpreter's start-up, imports and connect cancel out.

Usage (each tree is a directory holding ``tango_aio`` and ``benchmarks``; this file need
not be in it)::

    git archive cece61a tango_aio benchmarks pyproject.toml | tar -x -C /tmp/base_tree
    python -m benchmarks.instructions /tmp/base_tree .          # ~1 minute per tree/call
    python -m benchmarks.instructions --calls set --count 500 .

Needs ``valgrind`` on PATH (``apt-get install valgrind``); not part of ``python -m
benchmarks``.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

CALLS = ("pos", "set", "move")
_REFS = re.compile(r"I\s+refs:\s+([\d,]+)")


async def _work(call: str, count: int, separators: bool) -> None:
    """Connect on the canned transport, warm up, then make ``count`` calls of ``call``."""
    from benchmarks import canned  # the tree's own, from the working directory

    tango, link = await canned.canned_driver(separators)

    async def position(_: int) -> None:
        await tango.position()

    async def set_vel(index: int) -> None:
        await tango.set("vel", x=canned._velocity(index))

    async def move(index: int) -> None:
        await tango.move_to(x=canned._target(index))

    function = {"pos": position, "set": set_vel, "move": move}[call]
    if call == "move":
        link.reports = (b"!moa ", b"moa ")
    link.recording = True
    await canned._recorded(function, link)
    for index in range(50):
        await function(index)
    for index in range(count):
        await function(index)
    await tango.aclose()


def _refs(tree: Path, call: str, count: int, separators: bool) -> int:
    """Instructions of one run of :func:`_work` in ``tree`` under cachegrind."""
    env = dict(os.environ, PYTHONHASHSEED="0", PYTHONPATH=str(tree))
    command = ["valgrind", "--tool=cachegrind", "--cache-sim=no",
               "--cachegrind-out-file=/dev/null", sys.executable, "-c",
               "import sys; sys.path.insert(0, '.'); "
               "import asyncio, benchmarks.instructions as b; "
               f"asyncio.run(b._work({call!r}, {count}, {separators}))"]
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True,
                          check=False)
    match = _REFS.search(done.stderr)
    if done.returncode != 0 or match is None:
        raise RuntimeError(f"cachegrind failed in {tree}: {done.stderr[-2000:]}")
    return int(match.group(1).replace(",", ""))


def per_call(tree: Path, call: str, count: int, separators: bool = True) -> float:
    """Instructions per call of ``call`` in ``tree``.

    Parameters
    ----------
    tree
        A directory holding ``tango_aio`` and ``benchmarks``.
    call
        ``pos``, ``set`` or ``move``.
    count
        Calls counted (the difference of two runs, ``count`` calls and none).
    separators
        Whether the driver writes its separators (the default).

    Returns
    -------
    float
        Machine instructions per call.
    """
    return (_refs(tree, call, count, separators) - _refs(tree, call, 0, separators)) / count


def main() -> None:
    """Print instructions per call for each tree and call, and each tree's ratio to the
    first."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", nargs="+", type=Path, help="trees; the first is the base")
    parser.add_argument("--calls", nargs="+", choices=CALLS, default=list(CALLS))
    parser.add_argument("--count", type=int, default=1000, help="calls counted (1000)")
    parser.add_argument("--no-separators", action="store_true")
    args = parser.parse_args()
    if shutil.which("valgrind") is None:
        sys.exit("valgrind is not on PATH")
    # The workload comes from benchmarks/instructions.py of each tree; a tree from before
    # this file existed gets this one copied in.
    for tree in args.trees:
        target = tree / "benchmarks" / "instructions.py"
        if not target.exists():
            shutil.copy(__file__, target)
    print("| call | " + " | ".join(str(tree) for tree in args.trees) + " |")
    print("|---|" + "---:|" * len(args.trees))
    for call in args.calls:
        counts = [per_call(tree.resolve(), call, args.count, not args.no_separators)
                  for tree in args.trees]
        cells = [f"{counts[0] / 1000:.1f}k"] + [
            f"{value / 1000:.1f}k ({value / counts[0]:.3f})" for value in counts[1:]]
        print(f"| {call} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
