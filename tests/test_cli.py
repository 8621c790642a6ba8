"""The tango-aio command line, run as a user would."""

from __future__ import annotations

import subprocess
import sys

import serial

CLI = [sys.executable, "-m", "tango_aio"]


def run(*args: str, timeout: float = 90) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout,
                          check=False)


def test_help_of_every_command() -> None:
    for command in ([], ["demo"], ["info"], ["sim"]):
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
