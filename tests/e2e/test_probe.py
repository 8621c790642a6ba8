"""``tango-aio ports --probe`` and :func:`probe_ports`: a result for every port in a few
words, so that the ports that matter (permission denied, busy) are not hidden behind the
"-" of a port where nothing answered (issue 30 item 1)."""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from typing import Any

import pytest
import serial
from helpers import make_model, posix_only, serve_pty

import tango_aio
from tango_aio.cli._main import main
from tango_aio.group._discovery import PortProbe, discover, probe_ports


@pytest.fixture
def silent() -> Iterator[str]:
    """A pty nobody answers on."""
    posix_only("a pty pair nobody answers on (os.openpty)")
    master, slave = os.openpty()
    yield os.ttyname(slave)
    os.close(master)
    os.close(slave)


@pytest.fixture
def denied(monkeypatch: pytest.MonkeyPatch) -> str:
    """A port that this user may not open. The tests run as root, who may open any
    port, so the refusal is made at the open boundary, as pyserial raises it for a port
    of mode 600 owned by someone else."""
    path = "/dev/ttyUSB-not-yours"
    real = serial.serial_for_url

    def open_or_refuse(url: str, *args: Any, **kwargs: Any) -> Any:
        if url == path:
            raise serial.SerialException(
                13, f"could not open port {url}: [Errno 13] Permission denied: {url!r}")
        return real(url, *args, **kwargs)

    monkeypatch.setattr(serial, "serial_for_url", open_or_refuse)
    return path


def _held(path: str) -> int:
    """Hold ``path`` as another program does (an exclusive lock); returns the fd."""
    import fcntl  # POSIX only; the callers need the pty emulator anyway

    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


async def test_every_port_gets_a_result_in_a_few_words(silent: str, denied: str) -> None:
    async with await serve_pty(make_model) as server, await serve_pty(make_model) as busy:
        fd = _held(busy.path)
        try:
            results = await probe_ports(
                ports=[server.path, silent, denied, busy.path, "/dev/ttyUSB-none-such"],
                timeout=2.0)  # the silent port waits it out; the emulator answers within it
        finally:
            os.close(fd)
    assert [(item.port, item.result) for item in results] == [
        (server.path, "TANGO TANGO-DT 1.71"),
        (silent, "no answer"),
        (denied, "permission denied (add yourself to the dialout group)"),
        (busy.path, "busy (held by another program)"),
        ("/dev/ttyUSB-none-such", "not found")]
    assert all(isinstance(item, PortProbe) for item in results)
    assert results[0].controller is not None and results[0].controller.model == "TANGO-DT"
    assert [item.controller for item in results[1:]] == [None] * 4
    assert isinstance(results[2].error, serial.SerialException)


async def test_discover_logs_why_a_port_could_not_be_probed(
        denied: str, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level("INFO", "tango_aio.group._discovery")
    assert await discover(ports=[denied], timeout=0.2) == []
    assert f"{denied}: permission denied" in caplog.text


def test_ports_probe_prints_each_ports_result(capsys: pytest.CaptureFixture[str],
                                              silent: str, denied: str) -> None:
    fd = _held(silent)  # busy now
    try:
        code = main(["ports", "--probe", "--port", silent, "--port", denied,
                     "--port", "/dev/ttyUSB-none-such", "--timeout", "0.2"])
    finally:
        os.close(fd)
    out = capsys.readouterr().out
    assert code == 0, out
    flat = " ".join(out.split())
    assert re.search(rf"{re.escape(silent)} .*busy \(held by another program\)", flat), out
    assert re.search(rf"{re.escape(denied)} .*permission denied", flat), out
    assert re.search(r"/dev/ttyUSB-none-such .*not found", flat), out


def test_probe_ports_is_exported() -> None:
    assert tango_aio.probe_ports is probe_ports and tango_aio.PortProbe is PortProbe
