"""The shell and ``tango-aio move`` exit non-zero when a move did not end at its target
(#26 item 5), and the shell's banner stays out of a script's stdout."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import forkrun
import pytest
from helpers import PtySim

CLI = [sys.executable, "-m", "tango_aio"]


def shell(url: str, script: str) -> subprocess.CompletedProcess[str]:
    """``printf SCRIPT | tango-aio shell URL``."""
    return forkrun.run([*CLI, "shell", url], input=script, capture_output=True,
                       text=True, timeout=60, check=False)


@pytest.fixture
def fast(tmp_path: Path) -> str:
    """A sim:// URL whose axes run at 100 mm/s (the switch at +50 mm in half a second)."""
    state = tmp_path / "state.json"
    state.write_text(json.dumps({"format": "tango_aio.sim state", "version": 1,
                                 "axes": {"vel": [[100.0]] * 4, "secvel": [[100.0]] * 4}}))
    return f"sim://?baud=0&state={state}"


def test_end_of_input_stops_a_move_and_the_script_fails() -> None:
    with PtySim() as sim:
        result = shell(sim.path, "!moa 1 1\n?pos\n")
        assert result.returncode == 1, result.stdout + result.stderr
        assert "move failed: X still moving when the shell was left" in result.stderr
        assert sim.moving_axes() == []
    assert "connected to" not in result.stdout and "connected to" in result.stderr


def test_a_script_move_that_ends_on_a_limit_switch_fails(fast: str) -> None:
    result = shell(fast, "!moa 60\nwait\n?pos\n")
    assert result.returncode == 1, result.stdout + result.stderr
    assert ("move failed: X stopped at its upper limit switch (EE) (status S), at "
            in result.stderr)
    assert "target 60" in result.stderr


def test_a_script_whose_moves_arrive_exits_0(fast: str) -> None:
    result = shell(fast, "!moa 1 2\nwait\n!mor 1\nwait\n?pos\n")
    assert result.returncode == 0, result.stdout
    assert "move failed" not in result.stdout + result.stderr
    assert result.stdout.splitlines()[-1] == "2.0000 2.0000 0.0000"


def test_move_exits_1_on_a_limit_switch_and_0_at_the_target(fast: str) -> None:
    bad = forkrun.run([*CLI, "move", fast, "x=60"], capture_output=True, text=True,
                      timeout=60, check=False)
    assert bad.returncode == 1 and "X stopped at its upper limit switch" in bad.stderr
    assert "error:" not in bad.stdout
    good = forkrun.run([*CLI, "move", fast, "x=5", "y=-5"], capture_output=True,
                       text=True, timeout=60, check=False)
    assert good.returncode == 0, good.stdout
    assert good.stdout.split()[-6:] == ["x=", "5.0000", "y=", "-5.0000", "z=", "0.0000"]


def test_a_one_axis_stop_is_described_as_such() -> None:
    from tango_aio.cli._describe import describe_event
    from tango_aio.events import MoveAborted

    assert describe_event(MoveAborted(ctrl_c=False, axes=("x", "z"))) == \
        "stop sent (a x, a z): X Z stop"
    assert describe_event(MoveAborted(ctrl_c=True)) == "abort sent (Ctrl+C): all axes stop"
