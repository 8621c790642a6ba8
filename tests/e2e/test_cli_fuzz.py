"""Fuzzing the tango-aio command line: random arguments, bad files, bad stdin, and SIGINT
at random moments. Whatever happens, the user sees no traceback, only one-line errors,
and the exit code says what happened (0 ok, 1 error, 2 usage, 130 Ctrl+C).

The default run is a few dozen cases; ``-m slow`` runs many more.
"""

from __future__ import annotations

import io
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tango_aio.cli._main import main

SIM = "sim://?baud=0"

URLS = [SIM, "SIM://?baud=0", "sim://?axes=1&baud=0", "sim://?baud=abc", "sim://?axes=0",
        "sim://?baud=0&baud=0", "sim://?nosuch=1", "sim://?fragment=0.5&seed=3&baud=0",
        "sim://?latency=nan", "[/]", "[bold]x", "loop://", "/dev/null", "/nonexistent",
        "socket://127.0.0.1:1", "socket://", "socket://[::1", "", "x" * 300, "%ff"]
TARGETS = ["x=1", "y=-2", "z=0.5", "a=1", "q=1", "x=nan", "x=inf", "x=", "=", "x=1e9",
           "x=1,5", "X=0.25", "y=1x"]
NUMBERS = ["1", "2", "0", "-1", "nan", "inf", "abc", "0.01", "1e400", ""]
SCRIPT_LINES = [b"?pos", b"!moa 1 2", b"wait", b"help", b"help moa", b"help 99", b"sa",
                b"!vel 1000", b"!moa 1000000", b"?err", b"[/]", b"\xff\xfe", b"!", b"?",
                b"moa", b"exit", b"9" * 5000, b"\x03", b"?help 5", b"!trigp -1 1.5"]


def _files(tmp: Path) -> list[str]:
    good = tmp / "good.txt"
    good.write_text("# positions\n1.0\n2.0\n\n3.5\n")
    bad = tmp / "bad.txt"
    bad.write_text("1.0\n[mm]\n")
    unordered = tmp / "unordered.txt"
    unordered.write_text("1\n3\n2\n")
    binary = tmp / "binary.txt"
    binary.write_bytes(bytes(range(256)) * 4)
    empty = tmp / "empty.txt"
    empty.write_text("")
    return [str(p) for p in (good, bad, unordered, binary, empty)] + [
        "/dev/zero", "/dev/null", str(tmp), str(tmp / "missing.txt")]


def _argv(rng: random.Random, files: list[str]) -> list[str]:
    """A random command line: mostly well-formed commands with random values."""
    url = rng.choice(URLS)
    command = rng.choice(["info", "move", "monitor", "ports", "upload-trigp", "shell",
                          "demo", "garbage", "help"])
    if command == "info":
        argv = ["info", url]
    elif command == "move":
        argv = ["move", url, *rng.sample(TARGETS, rng.randint(0, 3))]
        if rng.random() < 0.3:
            argv.append("--relative")
    elif command == "monitor":
        argv = ["monitor", url, "--count", rng.choice(["1", "2", "0", "-3", "x"])]
        if rng.random() < 0.5:
            argv += ["--interval", rng.choice(NUMBERS)]
    elif command == "ports":
        argv = ["ports"]
        if rng.random() < 0.5:
            argv.append("--probe")
        argv += ["--port", rng.choice(["/dev/null", "/nonexistent", "[/]", ""])]
        if rng.random() < 0.7:
            argv += ["--timeout", rng.choice(["0.05", *NUMBERS[3:]])]
    elif command == "upload-trigp":
        argv = ["upload-trigp", url, rng.choice(files)]
        if rng.random() < 0.3:
            argv += ["--axis", rng.choice(["x", "y", "q", ""])]
    elif command == "shell":
        argv = ["shell", url]
    elif command == "demo":  # only what ends before anything moves
        argv = ["demo", rng.choice(["--rows", "--points"]), rng.choice(NUMBERS[3:]),
                rng.choice([u for u in URLS if u not in (SIM, "SIM://?baud=0")])]
    elif command == "help":
        argv = [rng.choice(["info", "move", "monitor", "ports", "shell", "demo"]), "--help"]
    else:
        pool = ["--version", "-v", "--debug", "--", "-", "info", "move", "x=1", "--count",
                "ports", "--nosuch", "\x00", "é", *URLS[:4]]
        argv = [rng.choice(pool) for _ in range(rng.randint(0, 4))]
    if rng.random() < 0.15:
        argv.insert(0, "-v")
    return argv


def _script(rng: random.Random) -> bytes:
    lines = [rng.choice(SCRIPT_LINES) for _ in range(rng.randint(0, 6))]
    noise = bytes(rng.randrange(256) for _ in range(rng.randint(0, 20)))
    return b"\n".join(lines) + rng.choice([b"\n", b"", noise])


def _check_output(argv: list[str], code: int, out: str, err: str) -> None:
    assert "Traceback" not in out + err, (argv, out, err)
    assert "never retrieved" not in out + err, (argv, out, err)
    assert "warning:" not in out + err, (argv, out, err)  # an error no task awaited
    assert "error:" not in out, (argv, out)  # diagnostics go to stderr
    assert code in (0, 1, 2), (argv, code, out, err)
    if code == 1 and argv[-2:-1] != ["shell"] and "shell" not in argv:
        errors = [line for line in err.splitlines() if line.startswith("error: ")]
        assert len(errors) == 1, (argv, err)


def _run_in_process(argv: list[str], stdin: bytes, monkeypatch: pytest.MonkeyPatch,
                    capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(stdin)))
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 2)
    out, err = capsys.readouterr()
    _check_output(argv, code, out, err)


def _fuzz(seed: int, cases: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
          capsys: pytest.CaptureFixture[str]) -> None:
    rng = random.Random(seed)
    files = _files(tmp_path)
    for _ in range(cases):
        _run_in_process(_argv(rng, files), _script(rng), monkeypatch, capsys)


def test_random_command_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    _fuzz(16, 15, tmp_path, monkeypatch, capsys)  # a sample: 10 x 40 under slow


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(10))
def test_many_random_command_lines(seed: int, tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    _fuzz(1000 + seed, 40, tmp_path, monkeypatch, capsys)


# -- SIGINT at random moments -------------------------------------------------------------

#: Runs the CLI after its imports, and says so on stderr: Ctrl+C before that point hits
#: Python's own start-up (importing the package), which no program code can intercept.
_HARNESS = ("import sys; from tango_aio.cli._main import main; "
            "print('ready', file=sys.stderr, flush=True); sys.exit(main(sys.argv[1:]))")

#: Commands that run for a while on the emulator, so that SIGINT lands inside them.
_LONG = [["info", "sim://?baud=57600&latency=0.02"],
         ["move", SIM, "x=8", "y=-6"],
         ["move", SIM, "--relative", "z=3"],
         ["monitor", SIM, "--interval", "0.05"],
         ["shell", SIM],
         ["upload-trigp", "sim://?baud=57600", "POSITIONS"],
         ["demo", SIM, "--rows", "2", "--points", "3"]]


def _output_of(proc: subprocess.Popen[bytes]) -> str:
    """Everything ``proc`` writes until it exits (killed after a minute)."""
    try:
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    return out.decode(errors="replace") + err.decode(errors="replace")


def _interrupt_at_random(rng: random.Random, positions: Path) -> None:
    argv = [str(positions) if a == "POSITIONS" else a for a in rng.choice(_LONG)]
    with subprocess.Popen([sys.executable, "-c", _HARNESS, *argv], stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        assert proc.stderr is not None and proc.stdin is not None
        assert proc.stderr.readline() == b"ready\n"
        if argv[0] == "shell":  # a script that keeps the controller busy
            proc.stdin.write(b"!moa 10 10\nwait\n?pos\n")
            proc.stdin.flush()
        time.sleep(rng.uniform(0.0, 1.5))
        proc.send_signal(signal.SIGINT)
        if rng.random() < 0.3:  # an impatient user presses Ctrl+C again
            time.sleep(rng.uniform(0.0, 0.3))
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        text = _output_of(proc)
    assert "Traceback" not in text and "never retrieved" not in text, (argv, text)
    assert "warning:" not in text, (argv, text)
    # -SIGINT: a Ctrl+C that came after main() returned ended the interpreter's exit
    # quietly (a shell shows it as 130, too).
    assert proc.returncode in (0, 1, 130, -signal.SIGINT), (argv, proc.returncode, text)


#: Does what the ``tango-aio`` console script does (its name in argv[0], then the package),
#: says "start" on stderr, then imports the command line: SIGINT soon after lands while
#: the command line and its dependencies load.
_EARLY = ("import sys; sys.argv[0] = '/usr/bin/tango-aio'; import tango_aio; "
          "print('start', file=sys.stderr, flush=True); "
          "from tango_aio.cli._main import main; sys.exit(main(sys.argv[1:]))")


def _run_probe(probe: str) -> tuple[int, str, str]:
    """Run ``probe`` with ``python -c``; its exit code, stdout and stderr."""
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60, check=False)
    return done.returncode, done.stdout, done.stderr


def test_ctrl_c_while_the_command_line_loads_ends_quietly() -> None:
    # The interrupt arrives, deterministically, right after the start-up guard is in place
    # and before the rest of the command line has been imported.
    probe = ("import os, signal, sys; import tango_aio._startup as s; s.install(); "
             "os.kill(os.getpid(), signal.SIGINT); import tango_aio.cli._main; "
             "print('not interrupted')")
    assert _run_probe(probe) == (130, "", "interrupted\n")


def test_ctrl_c_after_the_command_line_loaded_but_before_main_ends_quietly() -> None:
    # The module's body (its class and function definitions, after the imports) is part
    # of start-up: seen under load, an interrupt there printed a traceback from a class
    # statement of tango_aio.cli._main.
    probe = ("import os, signal, sys; import tango_aio._startup as s; s.install(); "
             "import tango_aio.cli._main; "
             "os.kill(os.getpid(), signal.SIGINT); print('not interrupted')")
    assert _run_probe(probe) == (130, "", "interrupted\n")


def test_importing_the_command_line_leaves_ctrl_c_to_the_importer() -> None:
    # A program (or a pytest worker) that imports tango_aio.cli._main without running the
    # command keeps Python's KeyboardInterrupt: the quiet exit of start-up is only the
    # command's (it once ended a test worker that later pressed Ctrl+C on purpose).
    probe = ("import os, signal, sys, time; import tango_aio.cli._main\n"
             "try:\n    os.kill(os.getpid(), signal.SIGINT); time.sleep(5)\n"
             "except KeyboardInterrupt:\n    print('caught')")
    assert _run_probe(probe) == (0, "caught\n", "")


def test_ctrl_c_while_the_event_loop_is_built_ends_quietly() -> None:
    # Deterministically in the middle of building the event loop (seen under load at a
    # random moment: a half-built loop printed a traceback from its __del__).
    probe = ("import os, signal, sys; import asyncio.selector_events as se; "
             "from tango_aio.cli._main import main; "
             "original = se.BaseSelectorEventLoop._make_self_pipe\n"
             "def interrupted(self):\n"
             "    os.kill(os.getpid(), signal.SIGINT)\n"
             "    original(self)\n"
             "se.BaseSelectorEventLoop._make_self_pipe = interrupted\n"
             "sys.exit(main(['info', 'sim://?baud=0']))")
    done = subprocess.run([sys.executable, "-W", "error", "-c", probe], capture_output=True,
                          text=True, timeout=60, check=False)
    assert (done.returncode, done.stdout, done.stderr) == (130, "", "interrupted\n")


def test_a_second_ctrl_c_while_interrupted_is_printed_ends_quietly() -> None:
    # Deterministically: the second Ctrl+C of an impatient user lands while main() says
    # "interrupted" (seen in CI at a random moment: a traceback from inside rich).
    probe = ("import os, signal, sys; import tango_aio.cli._main as m; "
             "import tango_aio.cli._output as o\n"
             "def first(args):\n    raise KeyboardInterrupt\n"
             "said = o._complain\n"
             "def complain(text, style=''):\n"
             "    os.kill(os.getpid(), signal.SIGINT)\n"
             "    said(text, style)\n"
             "m._run_loop = first; m._complain = complain\n"
             "sys.exit(m.main(['info', 'sim://?baud=0']))")
    assert _run_probe(probe) == (130, "", "interrupted\n")


@pytest.mark.parametrize("delay", [0.0, 0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.25])
def test_ctrl_c_at_any_moment_of_start_up_shows_no_traceback(delay: float) -> None:
    with subprocess.Popen([sys.executable, "-c", _EARLY, "info", "sim://?baud=0"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        assert proc.stderr is not None
        assert proc.stderr.readline() == b"start\n"
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        text = _output_of(proc)
    assert "Traceback" not in text, (delay, text)
    assert proc.returncode in (0, 130, -signal.SIGINT), (delay, proc.returncode, text)


def _positions(tmp_path: Path) -> Path:
    path = tmp_path / "positions.txt"
    path.write_text("\n".join(f"{i * 0.01:.2f}" for i in range(1, 2001)))
    return path


def test_sigint_at_random_moments(tmp_path: Path) -> None:
    rng = random.Random(130)
    positions = _positions(tmp_path)
    for _ in range(3):  # a sample: 8 x 6 moments under slow
        _interrupt_at_random(rng, positions)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_sigint_at_many_random_moments(seed: int, tmp_path: Path) -> None:
    rng = random.Random(2000 + seed)
    positions = _positions(tmp_path)
    for _ in range(6):
        _interrupt_at_random(rng, positions)
