"""``forkrun.run``: a Python program forked from a warm interpreter gives what
``subprocess.run`` gives, and the program runs in a process of its own."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import forkrun
import pytest

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="forkrun forks")

PROGRAMS = [
    ["-c", "import sys; print('out', sys.argv); print('err', file=sys.stderr); sys.exit(3)",
     "a", "b"],
    ["-c", "print(input().upper()); raise SystemExit('bye')"],
    ["-c", "import os, sys; print(os.getcwd(), __name__, sys.path[0] == '')"],
    ["-c", "1 / 0"],
    ["-c", "import atexit, threading, time\n"
           "atexit.register(lambda: print('atexit'))\n"
           "threading.Thread(target=lambda: (time.sleep(0.2), print('thread'))).start()"],
    ["-m", "tango_aio", "info", "sim://?axes=9"],
    ["-m", "tango_aio", "--version"],
]


def test_programs_fork_from_the_warm_server_and_leave_nothing_behind(tmp_path: Path) -> None:
    first = forkrun.run([sys.executable, "-c", "import sys; global_name = 1; "
                         "print(sorted({'tango_aio.cli', 'asyncio'} & set(sys.modules)))"],
                        text=True, timeout=60)
    assert first.stdout == "['asyncio', 'tango_aio.cli']\n", first.stderr  # preloaded
    second = forkrun.run([sys.executable, "-c", "print('global_name' in globals())"],
                         text=True, timeout=60)
    assert second.stdout == "False\n"


@pytest.mark.parametrize("program", PROGRAMS, ids=[" ".join(p)[:40] for p in PROGRAMS])
def test_a_program_forked_from_the_server_matches_a_fresh_one(program: list[str],
                                                              tmp_path: Path) -> None:
    argv = [sys.executable, *program]
    fresh = subprocess.run(argv, input="hello\n", capture_output=True, text=True, timeout=60,
                           cwd=tmp_path, check=False)
    forked = forkrun.run(argv, input=b"hello\n", timeout=60, cwd=tmp_path)
    assert forked.returncode == fresh.returncode
    assert forked.stdout.decode() == fresh.stdout
    assert forked.stderr.decode() == fresh.stderr


def test_a_program_past_its_timeout_is_killed() -> None:
    with pytest.raises(subprocess.TimeoutExpired):
        forkrun.run([sys.executable, "-c", "import time; time.sleep(60)"], timeout=0.5)
    after = forkrun.run([sys.executable, "-c", "print('next')"], text=True, timeout=60)
    assert after.stdout == "next\n"


def test_another_environment_runs_in_a_fresh_interpreter(
        monkeypatch: pytest.MonkeyPatch) -> None:
    probe = [sys.executable, "-c", "import os, sys; "
             "print('tango_aio.cli' in sys.modules, os.environ.get('FORKRUN_PROBE'))"]
    assert forkrun.run(probe, text=True, timeout=60).stdout == "True None\n"
    monkeypatch.setenv("FORKRUN_PROBE", "1")
    assert forkrun.run(probe, text=True, timeout=60).stdout == "False 1\n"


def test_a_variable_read_when_used_is_the_callers() -> None:
    probe = [sys.executable, "-c", "import os, sys; "
             "print('tango_aio.cli' in sys.modules, os.environ.get('TANGO_AIO_HISTORY'))"]
    environment = {**os.environ, "TANGO_AIO_HISTORY": "/nowhere/h"}
    assert forkrun.run(probe, text=True, timeout=60, env=environment).stdout == (
        "True /nowhere/h\n")
    environment.pop("TANGO_AIO_HISTORY")
    assert forkrun.run(probe, text=True, timeout=60, env=environment).stdout == "True None\n"
