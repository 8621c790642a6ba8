"""The examples run against the embedded emulator, as getting-started.md promises.

Every ``examples/*.py`` runs once, in a process of its own (forked from a warm
interpreter, ``forkrun``); each must exit with 0 and print
something, and what it prints is checked by the example's function in ``CHECKS`` (one run
per example, whichever xdist worker it lands on).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from collections.abc import Callable
from pathlib import Path

import forkrun
import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


def run_example(name: str) -> subprocess.CompletedProcess[str]:
    """Run ``examples/<name>`` with no arguments (the emulator) and return the result."""
    # One pytest process for the example that runs its own tests: this repository's
    # addopts would start 8 xdist workers for its three tests.
    environment = {**os.environ, "PYTEST_ADDOPTS": "-n 0"}
    return forkrun.run([sys.executable, str(ROOT / "examples" / name)],
                       capture_output=True, text=True, timeout=90, check=False, cwd=ROOT,
                       env=environment)


def move_and_watch_shows_events_and_positions(out: str) -> None:
    assert "move finished" in out
    assert "position:" in out
    assert "refused as expected" in out and "number 5" in out
    assert "final position {'x': 3.0, 'y': 2.5" in out


def concurrent_scan_moves_three_controllers_in_lockstep(out: str) -> None:
    assert "opened 3 controllers concurrently: stage1, stage2, stage3" in out
    for number in range(1, 10):
        assert f"point {number}/9:" in out
    # Lockstep: at every point all stages are at the same X, each at its own Y offset.
    assert ("point 4/9: stage1 x=1.000 y=0.500  stage2 x=1.000 y=0.750  "
            "stage3 x=1.000 y=1.000") in out
    assert "scanned 9 points on 3 controllers" in out
    assert "final status: {'stage1': '@@', 'stage2': '@@', 'stage3': '@@'}" in out


def events_reach_both_subscribers(out: str) -> None:
    logged = [line for line in out.splitlines() if line.startswith("[logger]")]
    moves = [line for line in out.splitlines() if line.startswith("[moves]")]
    assert sum("MoveFinished move" in line for line in logged) == 4
    assert "[logger] MoveFinished move {'x': '@', 'y': '@', 'z': 'S'} (FAILED)" in out
    assert "move_to raised MoveError: {'x': '@', 'y': '@', 'z': 'S'}" in out
    assert "[logger] StatusReport {'x': '@', 'y': '@', 'z': '@'} from line '@@@-.'" in out
    assert "[logger] UnsolicitedLine 'hello from the controller'" in out
    assert moves[-1] == "[moves]  move 4 finished, 1 failed so far"
    assert "logger dropped 0 events, move watcher 0" in out


def trigger_scan_fires_once_per_position(out: str) -> None:
    assert "uploaded 40/40 positions" in out
    assert "read back 40 positions: 0.5 ... 4.4 mm" in out
    assert "trigcount = 40 (positions passed: 40)" in out
    assert "trigger scan ok" in out


def pytest_fixture_example_runs_its_tests(out: str) -> None:
    assert "3 passed" in out


#: What each example must print, beyond something.
CHECKS: dict[str, Callable[[str], None]] = {
    "move_and_watch.py": move_and_watch_shows_events_and_positions,
    "concurrent_scan.py": concurrent_scan_moves_three_controllers_in_lockstep,
    "events.py": events_reach_both_subscribers,
    "trigger_scan.py": trigger_scan_fires_once_per_position,
    "pytest_fixture_example.py": pytest_fixture_example_runs_its_tests,
}


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_runs(path: Path) -> None:
    result = run_example(path.name)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert result.stdout.strip(), "the example printed nothing"
    check = CHECKS.get(path.name)
    if check is not None:
        check(result.stdout)


def test_every_check_names_an_example() -> None:
    assert set(CHECKS) <= {path.name for path in EXAMPLES}


def test_examples_are_not_collected_by_the_test_suite() -> None:
    """``pytest`` collects ``tests/`` only; the example module runs via test_example_runs."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert config["tool"]["pytest"]["ini_options"]["testpaths"] == ["tests"]
    result = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q",
                             "-p", "no:cacheprovider", "examples"],
                            capture_output=True, text=True, timeout=60, check=False, cwd=ROOT)
    assert result.returncode == 5, result.stdout  # 5: no tests collected
