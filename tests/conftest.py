"""Shared test settings and fixtures."""

from __future__ import annotations

import asyncio
import compileall
import gc
import os
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any, Unpack

import as_windows  # first: TANGO_AIO_TEST_AS_WINDOWS=1 (issue #27)
import pytest
from helpers import INSTANT, ConnectOptions, Emulated, EmulatorFactory, FakeLink, FakeTransport
from hypothesis import settings
from virtualclock import VirtualClockLoop

import tango_aio
from tango_aio.controller._connection import connect
from tango_aio.controller._controller import Controller
from tango_aio.link._protocol import TangoProtocol

# Bytecode caches on, whatever PYTHONDONTWRITEBYTECODE says: without them every xdist
# worker and each of the ~100 subprocesses (CLI, examples, docs) compiles the package and
# rewrites the test modules again, about 25 s of CPU on a 2-core machine (tests/README.md).
# The caches go where Python puts them (__pycache__/, ignored by git).
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

# No garbage collection while the tests are collected (each worker builds thousands of
# items and imports every module: the collector would walk them again and again); it is
# back on, with all that frozen, when collection ends (pytest_collection_finish).
gc.disable()


#: xdist workers per usable core for ``-n auto`` (pyproject addopts). The in-process
#: end-to-end tests wait on the virtual clock (virtualclock.py), so the run is CPU-bound:
#: two per core keep the cores busy while subprocesses start and real links wait, and
#: each worker more costs its collection (about 3 s of CPU). ``TANGO_AIO_TEST_WORKERS``
#: sets the count outright. Under uvloop (``TANGO_AIO_TEST_LOOP=uvloop``) there is no
#: virtual clock and the waits are real: :data:`WAITING_WORKERS_PER_CORE` then.
WORKERS_PER_CORE = 2
WAITING_WORKERS_PER_CORE = 5


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """The number of xdist workers for ``-n auto``: it follows the machine's cores."""
    chosen = os.environ.get("TANGO_AIO_TEST_WORKERS")
    if chosen:
        return max(1, int(chosen))
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    per_core = (WAITING_WORKERS_PER_CORE if os.environ.get("TANGO_AIO_TEST_LOOP") == "uvloop"
                else WORKERS_PER_CORE)
    return max(2, min(per_core * cores, 32))


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the package and the test modules once, before the xdist workers start."""
    if hasattr(session.config, "workerinput"):  # a worker: the controller did it
        return
    package = Path(tango_aio.__file__).parent
    compileall.compile_dir(package, quiet=1)  # for subprocesses: plain bytecode
    # In pytest the package (a pytest11 plugin's distribution) and the test modules load
    # with their asserts rewritten, from pytest's own bytecode files: write those too.
    _write_rewritten(session.config, [*package.rglob("*.py"), *_HERE.rglob("test_*.py"),
                                      *_HERE.rglob("conftest.py")])
    if session.config.getoption("dist", "no") != "no":
        gc.enable()  # the xdist controller collects nothing: the collector back on now


def _write_rewritten(config: pytest.Config, files: list[Path]) -> None:
    """What pytest writes when it imports ``files`` (best effort: this uses pytest's
    private rewrite functions; if they change, each worker rewrites as it did before)."""
    try:
        from _pytest.assertion import rewrite

        state = config.stash[rewrite.assertstate_key]
        for path in files:
            pyc = rewrite.get_cache_dir(path) / (path.stem + rewrite.PYC_TAIL)
            if rewrite._read_pyc(path, pyc) is not None:
                continue
            pyc.parent.mkdir(exist_ok=True)
            key, code = rewrite._rewrite_test(path, config)
            rewrite._write_pyc(state, code, key, pyc)
    except (ImportError, AttributeError, TypeError, KeyError, OSError):
        return


# TANGO_AIO_TEST_LOOP=uvloop runs every async test on uvloop's event loop (tango-aio[uvloop]),
# the way CI runs the end-to-end tier under it. Otherwise a test marked virtual_clock runs
# on a loop whose clock jumps over waits that only its own timers can end (virtualclock.py).
if os.environ.get("TANGO_AIO_TEST_LOOP") == "uvloop":
    import uvloop

    def pytest_asyncio_loop_factories(config: pytest.Config, item: pytest.Item
                                      ) -> dict[str, Callable[[], asyncio.AbstractEventLoop]]:
        """Run the async tests on uvloop (a pytest-asyncio hook)."""
        return {"uvloop": uvloop.new_event_loop}
elif os.environ.get("TANGO_AIO_TEST_LOOP", "asyncio") == "asyncio":

    def pytest_asyncio_loop_factories(config: pytest.Config, item: pytest.Item
                                      ) -> dict[str, Callable[[], asyncio.AbstractEventLoop]]:
        """The virtual clock's loop for tests marked ``virtual_clock`` (a pytest-asyncio
        hook), asyncio's own for the others."""
        if item.get_closest_marker("virtual_clock") is not None:
            return {"virtual_clock": VirtualClockLoop}
        return {"asyncio": asyncio.new_event_loop}
else:
    raise pytest.UsageError("TANGO_AIO_TEST_LOOP must be asyncio or uvloop")

def pytest_report_header(config: pytest.Config) -> str | None:
    """Say so when the run is "as if on Windows" (tests/as_windows.py)."""
    return "as if on Windows (TANGO_AIO_TEST_AS_WINDOWS=1)" if as_windows.ACTIVE else None


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int,
                            config: pytest.Config) -> None:
    """As if on Windows: how many tests skipped, of how many, and why (issue #27 keeps
    it under 5 % of the tier; .ci/run checks the line)."""
    if not as_windows.ACTIVE:
        return
    stats = terminalreporter.stats
    skipped = stats.get("skipped", [])
    total = sum(len(stats.get(key, [])) for key in
                ("passed", "failed", "skipped", "error", "xfailed", "xpassed"))
    reasons: dict[str, int] = {}
    for report in skipped:
        reason = str(report.longrepr[2]) if isinstance(report.longrepr, tuple) else "?"
        reasons[reason] = reasons.get(reason, 0) + 1
    share = 100.0 * len(skipped) / total if total else 0.0
    terminalreporter.write_sep("-", "as if on Windows")
    for reason, count in sorted(reasons.items(), key=lambda item: -item[1]):
        terminalreporter.write_line(f"{count:5d}  {reason}")
    terminalreporter.write_line(
        f"as if on Windows: {len(skipped)} of {total} tests skipped ({share:.1f} %)")


# No per-example deadline: the first examples pay for imports and would flake on a busy CI.
settings.register_profile("tango_aio", deadline=None)
settings.load_profile("tango_aio")


# --------------------------------------------------------------------------------------
# Tiers: every test carries the marker of its directory (tests/README.md)

TIERS = ("unit", "protocol", "e2e", "sim")
_HERE = Path(__file__).parent


def pytest_collection_finish(session: pytest.Session) -> None:
    """Move what collection made (thousands of items, the modules) out of the garbage
    collector's sight: every full collection during the run would walk it again. (The
    collector is off while collecting: see the top of this module.)"""
    gc.collect()
    gc.freeze()
    gc.enable()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark each test with its tier, the name of the directory below ``tests/`` it is in;
    in an xdist worker, spread the end-to-end tests over the workers' shares."""
    for item in items:
        parts = item.path.relative_to(_HERE).parts
        if len(parts) > 1 and parts[0] in TIERS:
            item.add_marker(parts[0])
    workers = getattr(config, "workerinput", {}).get("workercount", 1)
    if workers > 1:
        items[:] = _spread(items, workers)


def _spread(items: list[pytest.Item], workers: int) -> list[pytest.Item]:
    """Each of ``workers`` consecutive shares of the result (xdist's worksteal hands out
    such shares first) starts with its part of the end-to-end tests, the ones that wait,
    and ends with its part of the quick ones, which are left for the others to steal at
    the end. In collection order, the end-to-end tests come first and would all land in
    the first shares. Every worker computes the same order, as xdist requires."""
    slow = [item for item in items if item.get_closest_marker("e2e")]
    quick = [item for item in items if not item.get_closest_marker("e2e")]
    spread: list[pytest.Item] = []
    for share in range(workers):
        spread += slow[share * len(slow) // workers:(share + 1) * len(slow) // workers]
        spread += quick[share * len(quick) // workers:(share + 1) * len(quick) // workers]
    return spread


# --------------------------------------------------------------------------------------
# Shared fixtures of the driver tests (their helpers live in helpers.py)


@pytest.fixture
def fake_link() -> Callable[..., FakeLink]:
    """Factory: ``fake_link(autostatus=1)`` (call it inside the test's event loop)."""

    def make(**options: Any) -> FakeLink:
        # Hand-fed tests answer each line themselves: separators between look-alike
        # requests (answered like markers) only where a test asks for them.
        options.setdefault("separators", False)
        protocol = TangoProtocol(**options)
        link = FakeLink(protocol, FakeTransport(protocol))
        protocol.set_callbacks(lambda event, sub: link.events.append((event, sub)),
                               link.lost.append)
        protocol.connection_made(link.transport)
        return link

    return make


@pytest.fixture
async def emulator() -> AsyncIterator[EmulatorFactory]:
    """Factory: ``await emulator(url=INSTANT, travel=None, **connect_options)``; closed at
    teardown. ``travel`` (mm) shortens the axes so that cal/rm take a fraction of a second.
    """
    opened: list[Controller] = []

    async def open_one(url: str = INSTANT, *, travel: float | None = None,
                       **options: Unpack[ConnectOptions]) -> Emulated:
        tango = await connect(url, **options)
        opened.append(tango)
        emulated = Emulated(tango)
        if travel is not None:
            await emulated.shorten(travel, options.get("autostatus", 1))
        return emulated

    yield open_one
    for tango in opened:
        await tango.aclose()
