"""The tango-aio command line, run as a user would."""

from __future__ import annotations

import fcntl
import os
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest
import serial

from tango_aio.cli import describe_event, describe_line, describe_reply, letters_of_line
from tango_aio.events import ConnectionLost, MoveAborted, MoveFinished, UnsolicitedLine
from tango_aio.instructions import parse

CLI = [sys.executable, "-m", "tango_aio"]


def run(*args: str, timeout: float = 90) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout,
                          check=False)


def test_help_of_every_command() -> None:
    for command in ([], ["demo"], ["info"], ["sim"], ["shell"], ["move"], ["monitor"],
                    ["ports"]):
        result = run(*command, "--help")
        assert result.returncode == 0, result.stderr
        assert "usage: tango-aio" in result.stdout


def test_demo_runs_on_the_emulator() -> None:
    result = run("demo", "--rows", "2", "--points", "3")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Connected to TANGO-DT firmware 1.71, 3 axes" in result.stdout
    assert "calibrate (cal): {'x': 'A', 'y': 'A', 'z': 'A'}" in result.stdout
    assert "range measure (rm): {'x': 'D', 'y': 'D', 'z': 'D'}" in result.stdout
    # One forward pass over three trigger positions (the back pass does not fire).
    assert "trigger pulses │ 3" in result.stdout


def test_info_prints_identity() -> None:
    result = run("info", "sim://?baud=0&axes=2")
    assert result.returncode == 0, result.stderr
    assert "TANGO-DT" in result.stdout and "1.71" in result.stdout
    assert "axes" in result.stdout and "2" in result.stdout


def test_errors_are_one_line_with_nonzero_exit() -> None:
    result = run("info", "/dev/does-not-exist")
    assert result.returncode == 1
    assert result.stdout.strip().startswith("error:")
    assert len(result.stdout.strip().splitlines()) == 1
    bad = run("info", "sim://?axes=9")
    assert bad.returncode == 1 and "axes must be 1..4" in bad.stdout


def test_sim_pty_prints_the_device_path_first() -> None:
    with subprocess.Popen([*CLI, "sim", "--pty", "--baud", "0"], stdout=subprocess.PIPE,
                          text=True) as proc:
        _check_pty(proc)


def _check_pty(proc: subprocess.Popen[str]) -> None:
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        with serial.Serial(path, 57600, stopbits=2, timeout=2) as port:
            port.write(b"?version\r")
            assert port.read_until(b"\r").startswith(b"TANGO-DT, Version 1.71")
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_sim_tcp_serves_socket_urls() -> None:
    with subprocess.Popen([*CLI, "sim", "--tcp", "127.0.0.1:0", "--baud", "0"],
                          stdout=subprocess.PIPE, text=True) as proc:
        _check_tcp(proc)


def _check_tcp(proc: subprocess.Popen[str]) -> None:
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:")
        port = serial.serial_for_url(url, timeout=2)
        try:
            port.write(b"?det\r")
            assert port.read_until(b"\r") == b"10288\r"
        finally:
            port.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


# -- shell ------------------------------------------------------------------------------

SIM = "sim://?baud=0"
_ANSI = re.compile(r"\x1b\[[0-9;?<>=]*[ -/]*[@-~]|\x1b[()][0-9A-Za-z]|\x1b[=>78]|[\r\x07]")


class Terminal:
    """The CLI on a real pty (its controlling terminal), read with a timeout."""

    def __init__(self, *args: str, env: dict[str, str]) -> None:
        self.master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 200, 0, 0))
        # A session leader that makes the pty its controlling terminal, so that Ctrl+C
        # typed in cooked mode raises SIGINT as in a real terminal.
        code = ("import fcntl, sys, termios; fcntl.ioctl(0, termios.TIOCSCTTY, 0); "
                "from tango_aio.cli import main; sys.exit(main(sys.argv[1:]))")
        self.proc = subprocess.Popen([sys.executable, "-c", code, *args], stdin=slave,
                                     stdout=slave, stderr=slave, start_new_session=True,
                                     env={**os.environ, **env})
        os.close(slave)
        self.raw = ""
        self.text = ""  # everything read, without escape sequences
        self.seen = 0   # how far expect() has matched

    def __enter__(self) -> Terminal:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=15)
        os.close(self.master)

    def send(self, data: str) -> None:
        os.write(self.master, data.encode())

    def expect(self, pattern: str, timeout: float = 10.0) -> str:
        """Wait for ``pattern`` (a regex) after the previous match; return the match."""
        deadline = time.monotonic() + timeout
        while True:
            match = re.compile(pattern).search(self.text, self.seen)
            if match:
                self.seen = match.end()
                return match.group()
            left = deadline - time.monotonic()
            assert left > 0, f"{pattern!r} not seen in:\n{self.text[self.seen:]}"
            if select.select([self.master], [], [], min(left, 0.2))[0]:
                try:
                    chunk = os.read(self.master, 65536)
                except OSError:  # EIO: the child closed the pty
                    chunk = b""
                self.raw += chunk.decode(errors="replace")
                self.text = _ANSI.sub("", self.raw)

    def type(self, line: str, *patterns: str) -> list[str]:
        """Type ``line`` and Enter, wait for ``patterns`` in turn, then for the prompt (so
        that the next keys reach the prompt, not the terminal in cooked mode)."""
        self.send(line + "\r")
        found = [self.expect(pattern) for pattern in patterns]
        self.expect("tango>")
        return found

    def wait(self) -> int:
        """The exit code of the CLI."""
        return self.proc.wait(timeout=15)


@pytest.fixture
def history(tmp_path: Path) -> Path:
    return tmp_path / "history"


def _shell(url: str, history: Path) -> Terminal:
    term = Terminal("shell", url, env={"TANGO_AIO_HISTORY": str(history), "TERM": "xterm",
                                       "PROMPT_TOOLKIT_NO_CPR": "1"})
    term.expect(r"connected to TANGO-DT firmware 1\.71, 3 axes")
    term.expect("tango>")
    return term


def test_shell_on_a_pty(history: Path) -> None:
    with _shell(SIM, history) as term:
        term.type("?pos", r"0\.0000 0\.0000 0\.0000")
        term.type("!vel 1000", r"invalid: vel: velocity=1000\.0 is above 200 \(nothing sent\)")
        term.type("!moa 1 2", "sent", r"move finished: x=@ \(ok\) y=@ \(ok\) z=@ \(ok\)")
        term.type("!moa 1000000", "sent")
        term.type("?err", r"5  → error 5: number is not inside allowed range")
        term.type("sa", r"@@@-\.-  → x=@ \(ok\) y=@ \(ok\) z=@ \(ok\)")
        term.send("exit\r")
        assert term.wait() == 0
    lines = history.read_text().splitlines()
    assert [line for line in lines if line.startswith("+")] == [
        "+?pos", "+!vel 1000", "+!moa 1 2", "+!moa 1000000", "+?err", "+sa", "+exit"]


def test_shell_ctrl_c_at_the_prompt_aborts_a_move(history: Path) -> None:
    with _shell(SIM, history) as term:
        term.type("!moa 50 50", "sent")
        time.sleep(0.3)
        term.send("\x03")  # Ctrl+C (the prompt has the terminal in raw mode)
        term.expect(r"abort sent \(Ctrl\+C\): all axes stop")
        term.expect(r"move finished: x=E \(error/aborted\) y=E \(error/aborted\) z=@ \(ok\)")
        term.expect("tango>")
        x, y = map(float, term.type("?pos", r"\d+\.\d+ \d+\.\d+")[0].split())
        assert 0 < x < 50 and 0 < y < 50  # stopped on the way
        term.send("\x04")  # Ctrl+D leaves
        assert term.wait() == 0


def test_shell_ctrl_c_while_a_command_runs_aborts(history: Path) -> None:
    with _shell(SIM + "&latency=0.25", history) as term:
        term.send("?version\r")
        time.sleep(0.1)     # the read waits for its reply; the terminal is in cooked mode,
        term.send("\x03")   # so Ctrl+C raises SIGINT
        term.expect(r"interrupted: \?version")
        term.expect(r"abort sent \(Ctrl\+C\)")
        term.expect("tango>")
        term.type("?pos", r"0\.0000 0\.0000 0\.0000")
        term.send("quit\r")
        assert term.wait() == 0


def test_shell_reads_a_script_from_a_pipe(tmp_path: Path) -> None:
    script = "?pos\n!vel 1000\n!moa 1000000\n?err\n?help 5\nnot-an-instruction\n"
    result = subprocess.run([*CLI, "shell", SIM], input=script, capture_output=True,
                            text=True, timeout=60, check=False,
                            env={**os.environ, "TANGO_AIO_HISTORY": str(tmp_path / "h")})
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "0.0000 0.0000 0.0000" in out
    assert "invalid: vel: velocity=1000.0 is above 200 (nothing sent)" in out
    assert "5  → error 5: number is not inside allowed range" in out
    assert "ERROR 5,number outside range  → error 5: number is not inside allowed range" in out
    assert out.count("invalid:") == 2
    assert not (tmp_path / "h").exists()  # no history for non-interactive input


def test_decoding_of_replies_and_events() -> None:
    assert letters_of_line("@E--.") == {"x": "@", "y": "E"}
    assert describe_reply(parse("?err"), "12") == "12  → error 12: limit switch active"
    assert describe_reply(parse("?err"), "0") == "0  → no error"
    assert describe_reply(parse("?statusaxis z"), "M") == "M  → z=M (moving)"
    assert describe_reply(parse("?vel"), "10.0 10.0") == "10.0 10.0"
    assert describe_line("AAD-.") == ("status report: x=A (ok, calibrated) "
                                      "y=A (ok, calibrated) z=D (ok, range measured)")
    assert describe_line("ERR 27") == "controller reports error 27: emergency STOP is active"
    assert describe_line("hello") == "unsolicited line: 'hello'"
    finished = MoveFinished("cal", {"x": "A", "y": "T"}, ok=False)
    assert describe_event(finished) == "calibration finished: x=A (ok, calibrated) y=T (timeout)"
    assert describe_event(MoveAborted(ctrl_c=False)) == "abort sent (a): all axes stop"
    assert describe_event(UnsolicitedLine("@@@-.")) == (
        "status report: x=@ (ok) y=@ (ok) z=@ (ok)")
    assert describe_event(ConnectionLost(None)) == "connection lost: closed"


# -- move, monitor, ports ----------------------------------------------------------------


def test_move_prints_the_status_letters() -> None:
    result = run("move", SIM, "x=1", "y=2")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "done: x=@ (ok) y=@ (ok) z=@ (ok)" in result.stdout
    assert "x=   1.0000  y=   2.0000  z=   0.0000" in result.stdout
    relative = run("move", SIM, "--relative", "y=-0.5")
    assert relative.returncode == 0, relative.stdout + relative.stderr
    assert "y=  -0.5000" in relative.stdout


def test_move_beyond_the_limits_is_a_one_line_error() -> None:
    result = run("move", SIM, "x=1000000")
    assert result.returncode == 1
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: controller error 5"), lines
    usage = run("move", SIM, "q=1")
    assert usage.returncode == 2 and "expected AXIS=VALUE" in usage.stderr


def test_monitor_shows_a_table_of_the_axes() -> None:
    result = run("monitor", SIM, "--count", "2", "--interval", "0.05")
    assert result.returncode == 0, result.stdout + result.stderr
    for axis in "xyz":
        assert re.search(rf"│ {axis}\s+│\s+0\.0000 │ @\s+│ ok", result.stdout), result.stdout


def test_monitor_exits_cleanly_on_ctrl_c() -> None:
    with Terminal("monitor", SIM, "--interval", "0.05", env={"TERM": "xterm"}) as term:
        term.expect(r"│ z\s+│\s+0\.0000 │ @")  # the live table is up
        term.send("\x03")  # Ctrl+C in a terminal: SIGINT
        assert term.wait() == 0


def test_ports_lists_and_probes() -> None:
    assert run("ports").returncode == 0
    with subprocess.Popen([*CLI, "sim", "--pty", "--baud", "0"], stdout=subprocess.PIPE,
                          text=True) as proc:
        try:
            assert proc.stdout is not None
            path = proc.stdout.readline().strip()
            result = run("ports", "--probe", "--port", path, "--timeout", "2")
            assert result.returncode == 0, result.stdout + result.stderr
            assert re.search(rf"{re.escape(path)}.*TANGO-DT 1\.71", result.stdout)
        finally:
            proc.terminate()
            proc.wait(timeout=10)


def test_upload_trigp_uploads_a_file(tmp_path: Path) -> None:
    path = tmp_path / "positions.txt"
    values = [round(1.0 + i * 0.25, 4) for i in range(300)]
    path.write_text("# scan line\n" + "\n".join(str(v) for v in values) + "\n\n")
    result = run("upload-trigp", "sim://?baud=0", str(path), "--axis", "y")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "uploaded 300 trigger positions to axis y" in result.stdout


def test_upload_trigp_reports_bad_input_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "positions.txt"
    path.write_text("1.0\n2.0\n1.5\n")
    result = run("upload-trigp", "sim://?baud=0", str(path))
    assert result.returncode == 1
    assert "breaks the monotonic order" in result.stdout
    assert len(result.stdout.strip().splitlines()) == 1
    path.write_text("1.0\nabc\n")
    result = run("upload-trigp", "sim://?baud=0", str(path))
    assert result.returncode == 1 and ":2: not a number" in result.stdout
