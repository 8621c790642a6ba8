"""The command line's one convention, for every command: results on stdout, diagnostics on
stderr; exit 0 success, 1 the operation failed, 2 usage (checked before anything opens),
130 interrupted (docs/reference/cli.md, "Exit codes"). Each command of the parser has a
usage case here, and a failure case where it can fail; a new command without them fails
``test_every_command_has_its_cases``."""

from __future__ import annotations

import argparse
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from tango_aio._install import install_hint
from tango_aio._platform import WINDOWS
from tango_aio.cli._main import _parser, main

#: Nothing listens on TCP port 1 of the loopback: a connect fails at once, refused.
REFUSED = "socket://127.0.0.1:1"

#: A bad value for every command (exit 2, before anything opens).
USAGE: dict[str, list[list[str]]] = {
    "demo": [["demo", "--rows", "0"], ["demo", "socket://host:notaport"]],
    "info": [["info", "socket://localhost:notaport"], ["info", "sim://?baud=abc"],
             ["info", "socket://:4001"]],
    "sim": [["sim", "--axes", "9"], ["sim", "--axes", "0"], ["sim", "--baud", "-1"],
            ["sim", "--latency", "nan"], ["sim", "--speed", "0"]],
    "shell": [["shell", "socket://localhost:99999"]],
    "move": [["move", "sim://", "q=1"], ["move", "sim://?axes=x", "x=1"]],
    "monitor": [["monitor", "sim://", "--count", "0"], ["monitor", "sim://", "--interval", "nan"]],
    "ports": [["ports", "--timeout", "-1"]],
    "upload-trigp": [["upload-trigp", "sim://", "{tmp}/missing.txt"]],
    "ioc": [["ioc", "--prefix", "P:"], ["ioc", "sim://", "--prefix", "P:", "--allow-user", ""]],
    "probe": [["probe", "sim://?baud=abc"], ["probe", "sim://", "--settle", "nan"],
              ["probe", "sim://", "--settle", "-1"], ["probe", "sim://", "--move-time", "-5"],
              ["probe", "sim://", "-o", "{tmp}/no/such/folder/f.json"],
              ["probe", "sim://", "--baudrate", "-1"]],
    "tango-server": [["tango-server", "sim://?baud=abc", "--nodb"],
                     ["tango-server", "sim://", "--nodb", "--prefix", "one"],
                     ["tango-server", "sim://", "--nodb", "--port", "70000"],
                     ["tango-server", "sim://", "--nodb", "--poll", "0"]],
    "settings": [["settings", "dump", "sim://?baud=abc"], ["settings", "diff", "sim://"],
                 ["settings", "diff", "sim://", "{tmp}/missing.json"],
                 ["settings", "restore", "sim://", "{tmp}/empty.txt", "--yes"],
                 ["settings", "dump", "sim://", "-o", "{tmp}/no/such/folder/f.json"]],
}

#: An operation that fails (exit 1, one ``error:`` line on stderr, nothing on stdout).
FAILS: dict[str, list[list[str]]] = {
    "demo": [["demo", REFUSED, "--yes"]],
    "info": [["info", REFUSED], ["info", "/dev/does-not-exist"]],
    "sim": [["sim", "--tcp", "{busy}"]],
    "shell": [["shell", REFUSED]],
    "move": [["move", REFUSED, "x=1"], ["move", "sim://?baud=0", "x=1000000"]],
    "monitor": [["monitor", REFUSED, "--count", "1"]],
    "upload-trigp": [["upload-trigp", "sim://?baud=0", "{tmp}/empty.txt"]],
    "probe": [["probe", REFUSED, "-o", "{tmp}/f.json"]],
    "tango-server": [["tango-server", REFUSED, "--nodb"]],
    "settings": [["settings", "dump", REFUSED]],
}

#: Commands that have no failure of their own to provoke: ``ports`` lists what it finds
#: (a port that does not answer is a row, not an error); ``ioc`` serves an unreachable
#: controller as CONNECTED=0 until it answers.
NO_FAILURE = {"ports", "ioc"}


def _commands() -> list[str]:
    subparsers = next(action for action in _parser()._actions
                      if isinstance(action, argparse._SubParsersAction))
    return list(subparsers.choices)


@pytest.fixture
def busy_port() -> Iterator[str]:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        yield f"127.0.0.1:{held.getsockname()[1]}"


def _run(argv: list[str], capsys: pytest.CaptureFixture[str], tmp: Path,
         busy: str) -> tuple[int, str, str]:
    (tmp / "empty.txt").write_text("# no positions\n")
    argv = [word.format(tmp=tmp, busy=busy) for word in argv]
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's usage errors
        code = int(exit_.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_every_command_has_its_cases() -> None:
    commands = set(_commands())
    assert commands == set(USAGE), "a usage case for every command"
    assert commands == set(FAILS) | NO_FAILURE, "a failure case for every command that can fail"


@pytest.mark.parametrize("argv", [argv for cases in USAGE.values() for argv in cases],
                         ids=lambda argv: " ".join(argv))
def test_a_usage_error_exits_2_on_stderr(argv: list[str], capsys: pytest.CaptureFixture[str],
                                         tmp_path: Path, busy_port: str) -> None:
    code, out, err = _run(argv, capsys, tmp_path, busy_port)
    assert code == 2, (out, err)
    assert out == "", out
    assert "error" in err and "Traceback" not in err, err
    assert "invalid literal" not in err and "could not convert" not in err, err


@pytest.mark.parametrize("argv", [argv for cases in FAILS.values() for argv in cases],
                         ids=lambda argv: " ".join(argv))
def test_a_failure_exits_1_with_one_error_line_on_stderr(
        argv: list[str], capsys: pytest.CaptureFixture[str], tmp_path: Path,
        busy_port: str) -> None:
    code, out, err = _run(argv, capsys, tmp_path, busy_port)
    assert code == 1, (out, err)
    assert "error:" not in out and "warning:" not in out, out
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, err
    assert "[Errno" not in err and "Unknown error" not in err, err


def test_messages_name_the_next_step(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                     busy_port: str) -> None:
    _, _, err = _run(["sim", "--tcp", busy_port], capsys, tmp_path, busy_port)
    assert "already in use" in err and ":0 for any free port" in err, err
    _, _, err = _run(["info", "socket://localhost:notaport"], capsys, tmp_path, busy_port)
    assert "PORT a number 1-65535" in err, err
    _, _, err = _run(["upload-trigp", "sim://", "{tmp}/missing.txt"], capsys, tmp_path,
                     busy_port)
    assert "no such file" in err and "check the path" in err, err
    _, _, err = _run(["probe", "sim://", "-o", "{tmp}/no/f.json"], capsys, tmp_path, busy_port)
    assert "create it first" in err, err


def test_the_install_hint_is_what_works_from_this_installation() -> None:
    hint = install_hint("epics")
    checkout = Path(__file__).resolve().parents[2]
    # The tests run from a checkout, where the extra goes into that checkout's install.
    assert hint == f"pip install -e '{checkout}[epics]'", hint


def test_an_echoing_adapter_is_one_error_line_and_nothing_else(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, busy_port: str) -> None:
    code, out, err = _run(["info", "sim://?baud=0&local_echo=yes"], capsys, tmp_path,
                          busy_port)
    assert code == 1 and out == "", out
    assert err.count("\n") == 1 and err.startswith("error: ") and "echo" in err, err


def test_permission_advice_fits_the_kind_of_port() -> None:
    from tango_aio.controller._connection import port_error

    denied = PermissionError(13, "Permission denied")
    pty = str(port_error("/dev/pts/3", denied))
    assert "dialout" not in pty, pty
    if not WINDOWS:  # (Windows has no owner and mode to show)
        assert "ls -l /dev/pts/3" in pty, pty
    plain = str(port_error("/tmp/not-a-port", denied))
    assert "dialout" not in plain, plain
