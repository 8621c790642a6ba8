"""Profiles of the driver's hot paths (cProfile), as BENCHMARKS.md describes them.

* ``move``: tiny ``move_to`` on the canned transport of ``benchmarks/canned.py``;
* ``query``: ``position()`` (``?pos``) on the canned transport;
* ``set``: ``set("vel", x=...)`` with its ``?err`` check on the canned transport;
* ``upload``: N links (default 32) uploading trigger lists at once to the lean stand-ins
  of ``benchmarks/scaling.py``.

For each, the functions with the most own time (``tottime``) are printed with their
calls per operation and own microseconds per operation (an operation is one request or
move, or one uploaded line), and the top of the cumulative view. cProfile itself slows
Python calls down (about 2x here), so the split, not the absolute figure, is what counts.
Usage::

    python -m benchmarks.profiles [--cases move query set upload] [--calls 2000]
                                  [--links 32] [--entries 1000] [--out DIR]
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import os
import pstats
from collections.abc import Awaitable, Callable

from benchmarks import canned, scaling

#: Functions that wait rather than work (left out of the totals).
IDLE = ("<method 'poll' of 'select.epoll' objects>", "<method 'select' of 'select.epoll' "
        "objects>")


def _short(key: tuple[str, int, str]) -> str:
    """``module.py:line(function)`` with the path cut to the package."""
    path, line, name = key
    if path == "~":
        return name
    for marker in ("tango_aio/", "asyncio/", "serial_asyncio/", "benchmarks/"):
        if marker in path:
            path = path[path.index(marker):]
            break
    else:
        path = os.path.basename(path)
    return f"{path}:{line}({name})"


def summary(profile: cProfile.Profile, operations: int, title: str, top: int = 15) -> str:
    """The top functions by own time, per operation, and the largest cumulative ones."""
    stats = pstats.Stats(profile)
    entries = dict(stats.stats)  # type: ignore[attr-defined]
    idle = sum(entries.pop(key)[2] for key in list(entries) if key[2] in IDLE)
    total = sum(own for _, _, own, _, _ in entries.values())
    modules: dict[str, float] = {}
    for key, (_, _, own, _, _) in entries.items():
        module = _short(key).split(":")[0] if key[0] != "~" else "builtins"
        if module.startswith("asyncio/"):
            module = "asyncio"
        modules[module] = modules.get(module, 0.0) + own
    lines = [f"## {title}: {operations} operations, {total / operations * 1e6:.1f} µs "
             f"profiled time per operation (and {idle / operations * 1e6:.1f} µs waiting "
             "in select)",
             "by module (own µs/op): " + ", ".join(
                 f"{name} {own / operations * 1e6:.1f}"
                 for name, own in sorted(modules.items(), key=lambda i: -i[1])[:8]),
             f"{'own µs/op':>9} {'share':>6} {'calls/op':>8} {'cum µs/op':>9}  function"]
    by_own = sorted(entries.items(), key=lambda item: -item[1][2])
    for key, (_, calls, own, cumulative, _) in by_own[:top]:
        lines.append(f"{own / operations * 1e6:9.2f} {own / total:6.1%} "
                     f"{calls / operations:8.2f} {cumulative / operations * 1e6:9.2f}  "
                     f"{_short(key)}")
    lines.append("largest cumulative (tango_aio only):")
    ours = [item for item in entries.items() if "tango_aio/" in item[0][0]]
    for key, (_, calls, _, cumulative, _) in sorted(ours, key=lambda i: -i[1][3])[:top]:
        lines.append(f"{'':9} {'':6} {calls / operations:8.2f} "
                     f"{cumulative / operations * 1e6:9.2f}  {_short(key)}")
    return "\n".join(lines)


async def _profile_canned(operation: str, calls: int, profile: cProfile.Profile) -> None:
    tango, link = await canned.canned_driver()
    try:
        call: Callable[[int], Awaitable[object]]
        if operation == "move":
            link.reports = (b"!moa ",)

            async def call(index: int) -> object:
                return await tango.move_to(x=0.01 if index % 2 == 0 else 0.0)
        elif operation == "query":
            async def call(index: int) -> object:
                return await tango.position()
        else:
            async def call(index: int) -> object:
                return await tango.set("vel", x=10.0 + index % 2)
        for index in range(64):  # record the replies, then replay them
            await call(index)
        link.recording = False
        profile.enable()
        for index in range(calls):
            await call(index)
        profile.disable()
    finally:
        await tango.aclose()


def run(cases: list[str], calls: int, links: int, entries: int, out: str | None) -> str:
    """Profile ``cases``; return the summaries (and dump ``.prof`` files into ``out``)."""
    parts = []
    for case in cases:
        profile = cProfile.Profile()
        if case == "upload":
            asyncio.run(scaling.run(links, entries, links, profile, lean=True))
            operations, title = links * entries, f"{links}-link upload, per uploaded line"
        else:
            asyncio.run(_profile_canned(case, calls, profile))
            operations = calls
            title = {"move": "move_to (canned transport)", "query": "?pos (canned transport)",
                     "set": "checked set (canned transport)"}[case]
        if out:
            os.makedirs(out, exist_ok=True)
            profile.dump_stats(os.path.join(out, f"{case}.prof"))
        parts.append(summary(profile, operations, title))
    return "\n\n".join(parts)


def main() -> None:
    """Parse the options, profile, print."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", default=["move", "query", "set", "upload"],
                        choices=["move", "query", "set", "upload"])
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--links", type=int, default=32)
    parser.add_argument("--entries", type=int, default=1000)
    parser.add_argument("--out", metavar="DIR", help="write DIR/<case>.prof")
    args = parser.parse_args()
    print(run(args.cases, args.calls, args.links, args.entries, args.out))


if __name__ == "__main__":
    main()
