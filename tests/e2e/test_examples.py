"""The examples run against the embedded emulator, as the README promises.

Every ``examples/*.py`` is run once as a subprocess (cached, so the specific checks below
reuse that run); each must exit with 0 and print something.
"""

from __future__ import annotations

import functools
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


@functools.cache
def run_example(name: str) -> subprocess.CompletedProcess[str]:
    """Run ``examples/<name>`` with no arguments (the emulator) and return the result."""
    return subprocess.run([sys.executable, str(ROOT / "examples" / name)],
                          capture_output=True, text=True, timeout=90, check=False, cwd=ROOT)


def output_of(name: str) -> str:
    """Stdout of a successful run of ``examples/<name>``."""
    result = run_example(name)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    return result.stdout


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_runs(path: Path) -> None:
    result = run_example(path.name)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert result.stdout.strip(), "the example printed nothing"


def test_move_and_watch_shows_events_and_positions() -> None:
    out = output_of("move_and_watch.py")
    assert "move finished" in out
    assert "position:" in out
    assert "refused as expected" in out and "number 5" in out
    assert "final position {'x': 3.0, 'y': 2.5" in out


def test_concurrent_scan_moves_three_controllers_in_lockstep() -> None:
    out = output_of("concurrent_scan.py")
    assert "opened 3 controllers concurrently: stage1, stage2, stage3" in out
    for number in range(1, 10):
        assert f"point {number}/9:" in out
    # Lockstep: at every point all stages are at the same X, each at its own Y offset.
    assert ("point 4/9: stage1 x=1.000 y=0.500  stage2 x=1.000 y=0.750  "
            "stage3 x=1.000 y=1.000") in out
    assert "scanned 9 points on 3 controllers" in out
    assert "final status: {'stage1': '@@', 'stage2': '@@', 'stage3': '@@'}" in out


def test_events_reach_both_subscribers() -> None:
    out = output_of("events.py")
    logged = [line for line in out.splitlines() if line.startswith("[logger]")]
    moves = [line for line in out.splitlines() if line.startswith("[moves]")]
    assert sum("MoveFinished move" in line for line in logged) == 4
    assert "[logger] MoveFinished move {'x': '@', 'y': '@', 'z': 'S'} (FAILED)" in out
    assert "move_to raised MoveError: {'x': '@', 'y': '@', 'z': 'S'}" in out
    assert "[logger] StatusReport {'x': '@', 'y': '@', 'z': '@'} from line '@@@-.'" in out
    assert "[logger] UnsolicitedLine 'hello from the controller'" in out
    assert moves[-1] == "[moves]  move 4 finished, 1 failed so far"
    assert "logger dropped 0 events, move watcher 0" in out


def test_trigger_scan_fires_once_per_position() -> None:
    out = output_of("trigger_scan.py")
    assert "uploaded 40/40 positions" in out
    assert "read back 40 positions: 0.5 ... 4.4 mm" in out
    assert "trigcount = 40 (positions passed: 40)" in out
    assert "trigger scan ok" in out


def test_pytest_fixture_example_runs_its_tests() -> None:
    out = output_of("pytest_fixture_example.py")
    assert "3 passed" in out


def test_examples_are_not_collected_by_the_test_suite() -> None:
    """``pytest`` collects ``tests/`` only; the example module runs via test_example_runs."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert config["tool"]["pytest"]["ini_options"]["testpaths"] == ["tests"]
    result = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q",
                             "-p", "no:cacheprovider", "examples"],
                            capture_output=True, text=True, timeout=60, check=False, cwd=ROOT)
    assert result.returncode == 5, result.stdout  # 5: no tests collected
