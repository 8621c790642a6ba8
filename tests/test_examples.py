"""The examples run against the embedded emulator, as the README promises."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).parent.parent / "examples").glob("*.py"))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_runs(path: Path) -> None:
    result = subprocess.run([sys.executable, str(path)], capture_output=True, text=True,
                            timeout=90, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip(), "the example printed nothing"


def test_move_and_watch_shows_events_and_positions() -> None:
    path = Path(__file__).parent.parent / "examples" / "move_and_watch.py"
    result = subprocess.run([sys.executable, str(path)], capture_output=True, text=True,
                            timeout=90, check=True)
    out = result.stdout
    assert "move finished" in out
    assert "position:" in out
    assert "refused as expected" in out and "code 5" in out
    assert "final position {'x': 3.0, 'y': 2.5" in out
